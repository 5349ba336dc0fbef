"""Anchor attributes as coded symbols (spec clause 9): channel layout, reconstruction,
and the coding of attribute-unit chunks (offset masks and residual symbols).

Channel layout of an anchor's attribute vector (M = C + 6 + 3K channels):
  [0, C)            feature
  [C, C + 6)        scaling (log scales)
  [C + 6, M)        offsets, offset k axis a at C + 6 + 3k + a

Reconstruction (normative): value = float32(q) * float32(step of the channel's group),
one IEEE binary32 multiplication, so every machine gets the same bits.
Dead offsets (offset mask present and 0) are not coded and reconstruct to 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lghcc.common.entropy.range_coder import TOTAL_FREQUENCY, RangeDecoder, RangeEncoder, exact_model
from lghcc.common.entropy.symbol_coder import decode_symbols, encode_symbols
from lghcc.common.errors import BitstreamError
from lghcc.common.scene import NUM_SCALINGS
from lghcc.common.units import MASK_PROB_BITS, SceneParameterSet


@dataclass(frozen=True)
class ChannelLayout:
    feature_dim: int
    num_offsets: int

    @property
    def num_channels(self) -> int:
        return self.feature_dim + NUM_SCALINGS + 3 * self.num_offsets

    @property
    def scaling_start(self) -> int:
        return self.feature_dim

    @property
    def offset_start(self) -> int:
        return self.feature_dim + NUM_SCALINGS

    def steps(self, sps: SceneParameterSet) -> np.ndarray:
        """float32 [M]: the quantization step of each channel."""
        s = np.empty(self.num_channels, dtype=np.float32)
        s[: self.scaling_start] = np.float32(sps.feature_step)
        s[self.scaling_start: self.offset_start] = np.float32(sps.scaling_step)
        s[self.offset_start:] = np.float32(sps.offset_step)
        return s

    def live_channels(self, offset_mask: np.ndarray | None, n: int) -> np.ndarray:
        """bool [N, M]: which attribute values are coded."""
        live = np.ones((n, self.num_channels), dtype=bool)
        if offset_mask is not None:
            live[:, self.offset_start:] = np.repeat(offset_mask.astype(bool), 3, axis=1)
        return live

    def join(self, features: np.ndarray, scalings: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        n = features.shape[0]
        return np.concatenate([features, scalings, offsets.reshape(n, -1)], axis=1)

    def split(self, values: np.ndarray):
        n = values.shape[0]
        return (values[:, : self.scaling_start], values[:, self.scaling_start: self.offset_start],
                values[:, self.offset_start:].reshape(n, self.num_offsets, 3))


def layout_of(sps: SceneParameterSet) -> ChannelLayout:
    return ChannelLayout(sps.feature_dim, sps.num_offsets)


def reconstruct(q: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Normative reconstruction: float32(q) * step, elementwise, steps broadcast over rows."""
    return (q.astype(np.float32) * steps.astype(np.float32)).astype(np.float32)


# --- offset masks -------------------------------------------------------------------------

def mask_models(mask_live_prob: list[int]):
    """One binary model per offset slot: symbol 1 (live) has frequency p * 2^(24-12)."""
    shift = 24 - MASK_PROB_BITS
    models = []
    for p in mask_live_prob:
        live = int(p) << shift
        models.append(exact_model(np.array([TOTAL_FREQUENCY - live, live], dtype=np.int64)))
    return models


def encode_mask_chunk(mask: np.ndarray, models) -> bytes:
    """mask: bool [rows, K]; coded slot by slot (k = 0..K-1), rows in order."""
    enc = RangeEncoder()
    for k, model in enumerate(models):
        enc.encode(mask[:, k].astype(np.int32), model)
    return enc.to_bytes()


def decode_mask_chunk(data: bytes, rows: int, models, what: str) -> np.ndarray:
    dec = RangeDecoder(data, what)
    mask = np.zeros((rows, len(models)), dtype=bool)
    for k, model in enumerate(models):
        mask[:, k] = dec.decode(rows, model).astype(bool)
    return mask


# --- residual chunks ------------------------------------------------------------------------

def encode_residual_chunk(residuals: np.ndarray, levels: np.ndarray, live: np.ndarray) -> bytes:
    """Code the live entries of [rows, M] residuals in row-major order."""
    return encode_symbols(residuals[live], levels[live])


def decode_residual_chunk(data: bytes, levels: np.ndarray, live: np.ndarray, what: str) -> np.ndarray:
    out = np.zeros(levels.shape, dtype=np.int64)
    out[live] = decode_symbols(data, levels[live], what)
    return out


def split_chunks(payload: bytes, sizes: list[int], what: str) -> list[bytes]:
    total = sum(sizes)
    if total != len(payload):
        raise BitstreamError(f"{what}: chunk sizes add up to {total} bytes but the unit holds {len(payload)}")
    out, pos = [], 0
    for s in sizes:
        out.append(payload[pos:pos + s])
        pos += s
    return out


def check_levels(levels: np.ndarray, what: str) -> None:
    if levels.size and (levels.min() < 0 or levels.max() >= 64):
        raise BitstreamError(f"{what}: a scale level is outside [0, 63]")
