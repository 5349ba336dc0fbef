"""The render-model unit (R_model, spec clause 7.3.2 and 10): the render MLPs as
integers q with a power-of-two exponent per tensor, value = float32(q) * 2^exponent
(exact in binary32 for |q| < 2^24), entropy coded with the frozen scale tables.

Coded order: for each MLP in unit order, for each layer: weight [out, in] row-major,
then bias [out]; each tensor with its own scale level, mean 0.
"""

from __future__ import annotations

import numpy as np

from .entropy.symbol_coder import decode_symbols, encode_symbols
from .errors import BitstreamError
from .scene import ACTIVATIONS, MLP_ROLES, RenderMLP
from .units import RenderMlpHeader, RenderModelUnit

MAX_MODEL_PARAMETERS = 1 << 24  # level limit: all render MLPs together
MAX_WEIGHT_MAGNITUDE = (1 << 24) - 1  # so that float32(q) is exact


def dequantize(q: np.ndarray, exponent: int) -> np.ndarray:
    """float32(q) * 2^exponent, exact (a power-of-two scaling of an exact binary32 integer)."""
    return np.ldexp(q.astype(np.float32), np.int32(exponent)).astype(np.float32)


def _tensor_shapes(h: RenderMlpHeader) -> list[tuple[int, ...]]:
    shapes, fan_in = [], h.input_dim_minus1 + 1
    for l in range(h.num_layers_minus1 + 1):
        out = h.output_dim_minus1[l] + 1
        shapes += [(out, fan_in), (out,)]
        fan_in = out
    return shapes


def write_render_model_unit(headers: list[RenderMlpHeader], tensors: list[list[np.ndarray]]) -> bytes:
    """headers: one per MLP (exponents and levels chosen by the encoder); tensors: per MLP the
    integer tensors [w0, b0, w1, b1, ...] in coded order."""
    symbols, levels = [], []
    for h, ts in zip(headers, tensors):
        lv = [x for l in range(h.num_layers_minus1 + 1) for x in (h.weight_level[l], h.bias_level[l])]
        for t, shape, level in zip(ts, _tensor_shapes(h), lv):
            if t.shape != shape:
                raise ValueError(f"tensor shape {t.shape} does not match its header {shape}")
            if t.size and np.abs(t).max() > MAX_WEIGHT_MAGNITUDE:
                raise ValueError("a quantized MLP weight exceeds 2^24 - 1 in magnitude")
            symbols.append(t.reshape(-1).astype(np.int64))
            levels.append(np.full(t.size, level, dtype=np.int64))
    coded = encode_symbols(np.concatenate(symbols) if symbols else np.zeros(0, np.int64),
                           np.concatenate(levels) if levels else np.zeros(0, np.int64))
    unit = RenderModelUnit(num_mlps=len(headers), mlps=list(headers), coded_size=len(coded), coded_data=coded)
    return unit.to_bytes()


def read_render_model_unit(payload: bytes, trace=None) -> dict[str, RenderMLP]:
    unit = RenderModelUnit.from_bytes(payload, trace, what="render model unit")
    shapes_all, levels, roles = [], [], []
    total = 0
    for m, h in enumerate(unit.mlps):
        role = MLP_ROLES[h.mlp_role]
        if role in roles:
            raise BitstreamError(f"render model unit: MLP role {role!r} appears twice", condition="E23")
        roles.append(role)
        shapes = _tensor_shapes(h)
        total += sum(int(np.prod(s)) for s in shapes)
        if total > MAX_MODEL_PARAMETERS:
            raise BitstreamError(f"render model unit: more than {MAX_MODEL_PARAMETERS} parameters (level limit)", condition="E24")
        shapes_all.append(shapes)
        for l in range(h.num_layers_minus1 + 1):
            levels += [np.full(int(np.prod(shapes[2 * l])), h.weight_level[l]),
                       np.full(shapes[2 * l + 1][0], h.bias_level[l])]
    lv = np.concatenate(levels).astype(np.int64) if levels else np.zeros(0, np.int64)
    q = decode_symbols(unit.coded_data, lv, "render model coded data")
    if q.size and np.abs(q).max() > MAX_WEIGHT_MAGNITUDE:
        raise BitstreamError("render model unit: a weight exceeds 2^24 - 1 in magnitude", condition="E25")
    mlps, pos = {}, 0
    for role, h, shapes in zip(roles, unit.mlps, shapes_all):
        ws, bs = [], []
        for l in range(h.num_layers_minus1 + 1):
            ws_n = int(np.prod(shapes[2 * l]))
            ws.append(dequantize(q[pos:pos + ws_n].reshape(shapes[2 * l]), h.weight_exponent[l]))
            pos += ws_n
            bs.append(dequantize(q[pos:pos + shapes[2 * l + 1][0]], h.bias_exponent[l]))
            pos += shapes[2 * l + 1][0]
        mlps[role] = RenderMLP(ws, bs, [ACTIVATIONS[a] for a in h.activation])
    return mlps
