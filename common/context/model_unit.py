"""The context-model unit (spec clause 7.3.7): the integer parameters of the level-2
context model (R_model). Each parameter is an integer array with a shape, a bit width
and a signedness; all values are entropy coded in one chunk, mean 0, one scale level
per array. Array names are not written: they follow from the model and its layer counts,
in the fixed order of ``array_names``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..entropy.symbol_coder import best_level, decode_symbols, encode_symbols
from ..errors import BitstreamError
from ..syntax import SyntaxStructure, SyntaxVisitor
from ..units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP, MAX_CONTEXT_MODEL_ID, NUM_SCALE_LEVELS_BITS

MAX_ARRAY_DIMS = 4
MAX_MODEL_LAYERS = 8
MAX_CONTEXT_PARAMETERS = 1 << 24  # level limit
MAX_VALUE_BITS = 62  # |value| < 2^62: the symbol coder's range


@dataclass(frozen=True)
class NamedIntArray:
    """One parameter: integer values of ``bits`` bits, signed or unsigned."""

    name: str
    values: np.ndarray  # int64, any shape
    bits: int
    signed: bool


def mlp_arrays(name: str, mlp) -> list[NamedIntArray]:
    """The arrays of an integer MLP (common/intnn.py IntMLP) named ``name``, layer by layer:
    {name}.{l}.weight (s8 or s16 [out, in]), {name}.{l}.bias (s32 [out]), {name}.{l}.shift (u8)."""
    out: list[NamedIntArray] = []
    for l, layer in enumerate(mlp.layers):
        out += [NamedIntArray(f"{name}.{l}.weight", layer.weight.copy(), layer.weight_bits, True),
                NamedIntArray(f"{name}.{l}.bias", layer.bias.copy(), 32, True),
                NamedIntArray(f"{name}.{l}.shift", np.array(layer.shift, dtype=np.int64), 8, False)]
    return out


def array_names(model_id: int, feat_layers: int, head_layers: int) -> list[str]:
    """The normative order of a context model's arrays."""
    def mlp(name: str, layers: int) -> list[str]:
        return [f"{name}.{l}.{part}" for l in range(layers) for part in ("weight", "bias", "shift")]
    if model_id == CONTEXT_GGCONV:
        return (["num_features", "neighbour_level", "parent_base", "k", "radius_sq", "h_shift", "table"]
                + mlp("feat", feat_layers) + mlp("head", head_layers))
    if model_id == CONTEXT_PARENT_MLP:
        return ["num_features", "parent_base"] + mlp("head", head_layers)
    raise ValueError(f"context model {model_id} has no parameters")


@dataclass
class IntArrayHeader(SyntaxStructure):
    syntax_name = "int_array_header"
    clause = "7.3.8"
    array_ndim: int = 0
    array_dim_minus1: list = field(default_factory=list)
    array_bits_minus1: int = 0
    array_signed_flag: int = 0
    array_level: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(3, self, "array_ndim", hi=MAX_ARRAY_DIMS)
        for d in v.loop(self.array_ndim, "array_ndim", self, ("array_dim_minus1",), index="d"):
            v.ue(self, "array_dim_minus1", d, hi=MAX_CONTEXT_PARAMETERS - 1)
        v.u(6, self, "array_bits_minus1", hi=MAX_VALUE_BITS - 1)
        v.flag(self, "array_signed_flag")
        v.u(NUM_SCALE_LEVELS_BITS, self, "array_level")

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(d + 1 for d in self.array_dim_minus1)


@dataclass
class ContextModelUnit(SyntaxStructure):
    syntax_name = "context_model_unit"
    clause = "7.3.7"
    context_model_id: int = CONTEXT_GGCONV
    feat_num_layers_minus1: int = 0
    head_num_layers_minus1: int = 0
    arrays: list = field(default_factory=list)
    coded_size: int = 0
    coded_data: bytes = b""

    @property
    def num_arrays(self) -> int:
        feat = self.feat_num_layers_minus1 + 1 if self.context_model_id == CONTEXT_GGCONV else 0
        return len(array_names(self.context_model_id, feat, self.head_num_layers_minus1 + 1))

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(3, self, "context_model_id", lo=CONTEXT_PARENT_MLP, hi=MAX_CONTEXT_MODEL_ID)
        for _ in v.when(self.context_model_id == CONTEXT_GGCONV, "context_model_id == 2"):
            v.ue(self, "feat_num_layers_minus1", hi=MAX_MODEL_LAYERS - 1)
        v.ue(self, "head_num_layers_minus1", hi=MAX_MODEL_LAYERS - 1)
        for a in v.loop(self.num_arrays, "NumArrays", self, ("arrays",), index="a"):
            v.struct(self, "arrays", a, IntArrayHeader)
        v.ue(self, "coded_size")
        v.byte_align()
        v.payload(self, "coded_data", self.coded_size)


def write_context_model_unit(model_id: int, arrays: list[NamedIntArray], feat_layers: int,
                             head_layers: int) -> bytes:
    names = array_names(model_id, feat_layers, head_layers)
    if [a.name for a in arrays] != names:
        raise ValueError(f"context model arrays must come in the order {names}")
    unit = ContextModelUnit(context_model_id=model_id, feat_num_layers_minus1=max(feat_layers - 1, 0),
                            head_num_layers_minus1=head_layers - 1)
    symbols, levels = [], []
    for a in arrays:
        v = np.asarray(a.values, dtype=np.int64).reshape(-1)
        if a.bits > MAX_VALUE_BITS:
            raise ValueError(f"{a.name}: {a.bits}-bit values exceed the {MAX_VALUE_BITS}-bit limit")
        lv = best_level(v)
        shape = np.shape(a.values) or ()
        unit.arrays.append(IntArrayHeader(array_ndim=len(shape), array_dim_minus1=[d - 1 for d in shape],
                                          array_bits_minus1=a.bits - 1, array_signed_flag=int(a.signed),
                                          array_level=lv))
        symbols.append(v)
        levels.append(np.full(v.size, lv, dtype=np.int64))
    unit.coded_data = encode_symbols(np.concatenate(symbols), np.concatenate(levels))
    unit.coded_size = len(unit.coded_data)
    return unit.to_bytes()


def read_context_model_unit(payload: bytes, trace=None) -> tuple[int, list[NamedIntArray]]:
    unit = ContextModelUnit.from_bytes(payload, trace, what="context model unit")
    feat = unit.feat_num_layers_minus1 + 1 if unit.context_model_id == CONTEXT_GGCONV else 0
    names = array_names(unit.context_model_id, feat, unit.head_num_layers_minus1 + 1)
    sizes = []
    for a in unit.arrays:
        if any(d > MAX_CONTEXT_PARAMETERS for d in a.shape):
            raise BitstreamError("context model unit: an array dimension exceeds the level limit")
        sizes.append(int(np.prod(a.shape, dtype=np.int64)))
        if sum(sizes) > MAX_CONTEXT_PARAMETERS:
            raise BitstreamError(f"context model unit: more than {MAX_CONTEXT_PARAMETERS} parameters (level limit)")
    levels = np.concatenate([np.full(s, a.array_level, np.int64) for s, a in zip(sizes, unit.arrays)]) \
        if sizes else np.zeros(0, np.int64)
    values = decode_symbols(unit.coded_data, levels, "context model coded data")
    out, pos = [], 0
    for name, a, s in zip(names, unit.arrays, sizes):
        v = values[pos:pos + s].reshape(a.shape)
        pos += s
        bits = a.array_bits_minus1 + 1
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if a.array_signed_flag else (0, (1 << bits) - 1)
        if v.size and (int(v.min()) < lo or int(v.max()) > hi):
            raise BitstreamError(f"context model unit: {name} has values outside its {bits}-bit range")
        out.append(NamedIntArray(name, v, bits, bool(a.array_signed_flag)))
    return unit.context_model_id, out
