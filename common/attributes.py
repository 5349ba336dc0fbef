"""Attributes as coded symbols (spec clause 11): channel layouts, reconstruction, cross-channel
prediction, and the coding of attribute-unit chunks (offset masks and residual symbols).

Channel layout of an anchor's attribute vector (M = C + 6 + 3K channels):
  [0, C)            feature
  [C, C + 6)        scaling (log scales)
  [C + 6, M)        offsets, offset k axis a at C + 6 + 3k + a

Channel layout of a Gaussian's attribute vector (explicit-Gaussian scenes, SH degree d,
S = (d + 1)^2 coefficients per colour, M = 3S + 8 channels):
  [0, 3S)           SH coefficients, coefficient-major: 3i + c is coefficient i of colour c
                    (i = 0: the DC term f_dc)
  3S                opacity (logit)
  [3S + 1, 3S + 4)  log scales
  [3S + 4, 3S + 8)  rotation quaternion w, x, y, z (with a rotation_length unit, format 1.4:
                    the length index k in place of w, and w implied, clause 11.10)

Reconstruction (normative): value = float32(q) * float32(step of the channel's group),
one IEEE binary32 multiplication, so every machine gets the same bits.
Dead offsets (offset mask present and 0) are not coded and reconstruct to 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .entropy.range_coder import PRECISION_BITS, TOTAL_FREQUENCY, RangeDecoder, RangeEncoder, exact_model
from .entropy.scale_levels import NUM_SCALE_LEVELS
from .entropy.symbol_coder import decode_symbols, encode_symbols
from .errors import BitstreamError
from .scene import NUM_SCALINGS, GaussianScene, sh_coeffs_per_channel
from .bitio import BitReader
from .syntax import TraceEntry
from .units import (CHANNEL_PREDICTION_SHIFT, CONTEXT_PER_CHANNEL_PRIOR, MASK_PROB_BITS,
                                MAX_PREDICTED_MAGNITUDE, MAX_ROTATION_LENGTH_INDEX, AttributeUnitHeader, GaussianParameterSet,
                                SceneParameterSet, ShTransformUnit)

# Quantization-step adjustment (context models with a step output): the step of a value is
# float32(step(c)) * STEP_ADJUST_FACTORS[a], one binary32 multiplication. The factors are
# 2^(a/4), a = 0..7, frozen here as binary32 constants.
STEP_ADJUST_FACTORS = np.array([1.0, 1.18920708, 1.41421354, 1.68179286, 2.0, 2.37841415, 2.82842708, 3.36358571],
                               dtype=np.float32)
STEP_ADJUST_FACTORS.setflags(write=False)
NUM_STEP_ADJUST = len(STEP_ADJUST_FACTORS)


@dataclass(frozen=True)
class ChannelLayout:
    """The attribute channels of an anchor scene. ``offset_mask_present`` and
    ``channel_prediction_allowed`` are what the attribute unit's syntax depends on."""

    feature_dim: int
    num_offsets: int
    offset_mask_present: int = 0
    channel_prediction_allowed = 0
    max_rotation_length_index = -1  # anchors have no rotation channels
    sh_transform = None  # nor SH channels

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

    def live_channels(self, offset_mask: np.ndarray | None, n: int) -> np.ndarray | None:
        """bool [N, M]: which attribute values are coded; None when all of them are."""
        if offset_mask is None or offset_mask.all():
            return None
        live = np.ones((n, self.num_channels), dtype=bool)
        live[:, self.offset_start:] = np.repeat(offset_mask.astype(bool), 3, axis=1)
        return live

    def join(self, features: np.ndarray, scalings: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        n = features.shape[0]
        return np.concatenate([features, scalings, offsets.reshape(n, -1)], axis=1)

    def split(self, values: np.ndarray):
        n = values.shape[0]
        return (values[:, : self.scaling_start], values[:, self.scaling_start: self.offset_start],
                values[:, self.offset_start:].reshape(n, self.num_offsets, 3))


@dataclass(frozen=True)
class GaussianLayout:
    """The attribute channels of an explicit-Gaussian scene (module doc). The SH coefficients
    are the "features" a context model compares between neighbours."""

    sh_degree: int
    # >= 0 with a rotation_length unit (its max_rotation_length_index): channel rotation_start then
    # carries the length index k and w is implied (clause 11.10); -1 without one
    max_rotation_length_index: int = -1
    # with an sh_transform unit (format 1.6): the SH-rest channels carry transform coefficients and
    # the values are its integer inverse (clause 11.11); None without one
    sh_transform: "ShTransform | None" = None
    num_offsets = 0
    offset_mask_present = 0
    channel_prediction_allowed = 1

    @property
    def sh_channels(self) -> int:
        return 3 * sh_coeffs_per_channel(self.sh_degree)

    @property
    def feature_dim(self) -> int:
        return self.sh_channels

    @property
    def opacity_channel(self) -> int:
        return self.sh_channels

    @property
    def scale_start(self) -> int:
        return self.sh_channels + 1

    @property
    def rotation_start(self) -> int:
        return self.sh_channels + 4

    @property
    def num_channels(self) -> int:
        return self.sh_channels + 8

    def band_of_channel(self) -> np.ndarray:
        """int [3S]: the SH band (degree) of each SH channel."""
        i = np.arange(self.sh_channels) // 3  # coefficient index
        return np.floor(np.sqrt(i)).astype(np.int64)

    def steps(self, gps: GaussianParameterSet) -> np.ndarray:
        """float32 [M]: the quantization step of each channel."""
        band_steps = [gps.sh_dc_step] + list(gps.sh_band_step)
        s = np.empty(self.num_channels, dtype=np.float32)
        s[:self.sh_channels] = np.asarray(band_steps, dtype=np.float32)[self.band_of_channel()]
        s[self.opacity_channel] = np.float32(gps.opacity_step)
        s[self.scale_start:self.rotation_start] = np.float32(gps.scale_step)
        s[self.rotation_start:] = np.float32(gps.rotation_step)
        return s

    def live_channels(self, offset_mask, n: int) -> None:
        return None  # every value of a Gaussian is coded

    def join(self, scene: GaussianScene) -> np.ndarray:
        n = scene.num_gaussians
        return np.concatenate([scene.sh.reshape(n, self.sh_channels), scene.opacity.reshape(n, 1),
                               scene.log_scales, scene.rotations], axis=1)

    def split(self, values: np.ndarray):
        """-> (sh [N, S, 3], opacity [N], log scales [N, 3], rotations [N, 4]) as views of ``values``
        (S named: N may be 0, a box that selects no tile)."""
        n = values.shape[0]
        return (values[:, :self.sh_channels].reshape(n, self.sh_channels // 3, 3), values[:, self.opacity_channel],
                values[:, self.scale_start:self.rotation_start], values[:, self.rotation_start:])


def layout_of(sps: SceneParameterSet) -> ChannelLayout:
    return ChannelLayout(sps.feature_dim, sps.num_offsets, sps.offset_mask_present_flag)


def gaussian_layout_of(gps: GaussianParameterSet, max_rotation_length_index: int = -1) -> GaussianLayout:
    return GaussianLayout(gps.sh_degree, max_rotation_length_index)


# --- the SH rest as transform coefficients (clause 11.11, format 1.6) ---------------------------

SH_REST_START = 3  # the first SH-rest channel: coefficient 1 of R (the DC term takes channels 0 .. 2)


@dataclass(frozen=True)
class ShTransform:
    """The integer matrix T [NumShRest, NumShRest] and rounding shift R of an sh_transform unit
    (clause 7.3.17): row j of T maps the row's transform coefficients t (its quantized values of the
    SH-rest channels 3 .. 3S - 1) to the quantized value of SH-rest channel 3 + j."""

    shift: int
    matrix: tuple  # T row-major (j slowest), Python ints

    @classmethod
    def from_unit(cls, unit: ShTransformUnit) -> "ShTransform":
        offset = 1 << unit.sh_transform_bits_minus1
        return cls(unit.sh_transform_shift, tuple(int(c) - offset for c in unit.sh_transform_coeff))

    def to_unit(self, sh_degree: int) -> ShTransformUnit:
        """The unit with the fewest entry bits that holds the matrix."""
        top = max([0] + [c if c >= 0 else -c - 1 for c in self.matrix])  # offset binary: -2^(B-1) .. 2^(B-1) - 1
        bits = top.bit_length() + 1
        unit = ShTransformUnit(sh_degree=sh_degree, sh_transform_shift=self.shift, sh_transform_bits_minus1=bits - 1,
                               sh_transform_coeff=[c + (1 << (bits - 1)) for c in self.matrix])
        if unit.num_sh_rest ** 2 != len(self.matrix):
            raise ValueError(f"a transform of {len(self.matrix)} entries at SH degree {sh_degree}")
        return unit

    @property
    def size(self) -> int:
        return int(round(len(self.matrix) ** 0.5))

    @cached_property
    def array(self) -> np.ndarray:
        """int64 [NumShRest, NumShRest]: T."""
        return np.asarray(self.matrix, dtype=np.int64).reshape(self.size, self.size)


_EXACT_IN_FLOAT64 = 1 << 53
# rows per float64 product in exact_matmul: 128 x 45 x 45 stays under OpenBLAS's threshold for threads
# (2^18 multiply-adds), which spin on a decoder's busy cores; blocks were also faster than one call
EXACT_MATMUL_ROWS = 128


def exact_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b for int64 matrices, exact. Where every |a_ik| * (sum over k of |b_kj|) is below 2^53,
    every product and partial sum is an integer that binary64 holds exactly, whatever the order of
    the sums (or fused multiply-adds): the float64 product (BLAS, 8x less CPU than numpy's integer
    loop) is then the integer one; else numpy's int64 product."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if not (a.size and b.size) or max(int(a.max()), -int(a.min())) * int(np.abs(b).sum(axis=0).max()) \
            >= _EXACT_IN_FLOAT64:
        return a @ b
    af, bf = a.astype(np.float64), b.astype(np.float64)
    out = np.empty((a.shape[0], b.shape[1]), np.float64)
    for lo in range(0, a.shape[0], EXACT_MATMUL_ROWS):
        np.dot(af[lo:lo + EXACT_MATMUL_ROWS], bf, out=out[lo:lo + EXACT_MATMUL_ROWS])
    return out.astype(np.int64)


def inverse_sh_transform(q: np.ndarray, layout, what: str) -> np.ndarray:
    """Clause 11.11: the quantized values [rows, M] whose SH-rest channels are reconstructed, from the
    decoded ``q`` whose SH-rest channels hold transform coefficients t: for each SH-rest channel 3 + j,
    (sum_k T[j][k] t_k + floor(2^R / 2)) >> R, exact in int64 (|t| <= 2^40, |T| <= 2^15, at most 45
    terms: below 2^61), each checked against |q| <= 2^40 (E68). ``q`` itself without a transform."""
    transform = layout.sh_transform
    if transform is None or transform.size == 0:
        return q
    end = SH_REST_START + transform.size
    u = exact_matmul(q[:, SH_REST_START:end], transform.array.T)
    v = (u + ((1 << transform.shift) >> 1)) >> transform.shift
    if v.size and int(np.abs(v).max()) > MAX_PREDICTED_MAGNITUDE:
        raise BitstreamError(f"{what}: an SH value's inverse transform exceeds the limit of 2^40 quantization steps", condition="E68")
    out = q.astype(np.int64)  # (the encoder's q may be narrower than the values)
    out[:, SH_REST_START:end] = v
    return out


# --- rotations as a length index and x, y, z (clause 11.10, format 1.4) ------------------------

# The squared lengths 2^-k of the index k, exact in binary64: the lengths are 2^(-k/2)
ROTATION_LENGTH_SQ = tuple(2.0 ** -k for k in range(MAX_ROTATION_LENGTH_INDEX + 1))


def check_rotation_length_index(k: np.ndarray, max_index: int, what: str) -> None:
    if k.size and (int(k.min()) < 0 or int(k.max()) > max_index):
        raise BitstreamError(f"{what}: a rotation length index outside [0, max_rotation_length_index = {max_index}]", condition="E66")


def implied_w(k: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """float32 [n]: the rotation's w component from the length indices ``k`` (int [n], checked) and
    the reconstructed x, y, z (float32 [n, 3]): float32(sqrt(max(0, 2^-k - ((x*x + y*y) + z*z)))),
    every operation in binary64 (correctly rounded, so every machine gets the same bits)."""
    x, y, z = (xyz[:, a].astype(np.float64) for a in range(3))
    t = np.asarray(ROTATION_LENGTH_SQ)[k] - ((x * x + y * y) + z * z)
    return np.sqrt(np.maximum(t, 0.0)).astype(np.float32)


def reconstruct_rotations(q: np.ndarray, values: np.ndarray, layout, what: str) -> None:
    """Clause 11.10, in place: with a rotation_length unit (``layout.max_rotation_length_index`` >=
    0), channel w of the reconstructed ``values`` [n, M] becomes the implied w of each row's index
    q[:, w]."""
    if layout.max_rotation_length_index < 0:
        return
    w = layout.rotation_start
    check_rotation_length_index(q[:, w], layout.max_rotation_length_index, what)
    values[:, w] = implied_w(q[:, w], values[:, w + 1:w + 4])


# --- cross-channel prediction (clause 11.6) --------------------------------------------------

@dataclass(frozen=True)
class ChannelPrediction:
    """Linear prediction of a value's deviation from its mean by the deviations of earlier
    channels of the same row: for channels c in increasing order,

        q_c = r_c + mean_c + ((sum over entries (c, j, w) of w * (q_j - mean_j)) + 2^(S-1)) >> S

    with S = CHANNEL_PREDICTION_SHIFT and >> the arithmetic shift (floor). Entries are
    (target, source, weight) with source < target, in strictly increasing (target, source) order."""

    targets: np.ndarray  # int64 [P]
    sources: np.ndarray  # int64 [P]
    weights: np.ndarray  # int64 [P]

    @classmethod
    def none(cls) -> "ChannelPrediction":
        e = np.zeros(0, np.int64)
        return cls(e, e.copy(), e.copy())

    @classmethod
    def from_header(cls, h: AttributeUnitHeader, what: str) -> "ChannelPrediction":
        t = np.asarray(h.pred_target_channel, np.int64)
        s = np.asarray(h.pred_source_channel, np.int64)
        w = np.asarray(h.pred_weight, np.int64)
        if t.size:
            if (s >= t).any():
                raise BitstreamError(f"{what}: a cross-channel prediction's source channel is not before its target", condition="E48")
            key = t * h.num_channels + s
            if (np.diff(key) <= 0).any():
                raise BitstreamError(f"{what}: cross-channel predictions are not in strictly increasing "
                                     "(target, source) order", condition="E49")
        return cls(t, s, w)

    def to_header(self, h: AttributeUnitHeader) -> None:
        h.num_channel_predictions = int(self.targets.size)
        h.pred_target_channel = [int(x) for x in self.targets]
        h.pred_source_channel = [int(x) for x in self.sources]
        h.pred_weight = [int(x) for x in self.weights]

    @property
    def empty(self) -> bool:
        return self.targets.size == 0

    def _term(self, dev: np.ndarray, c: int, entries: np.ndarray) -> np.ndarray:
        acc = np.zeros(dev.shape[0], dtype=np.int64)
        for e in entries:
            acc += self.weights[e] * dev[:, self.sources[e]]
        return (acc + (1 << (CHANNEL_PREDICTION_SHIFT - 1))) >> CHANNEL_PREDICTION_SHIFT

    def reconstruct(self, r: np.ndarray, mean: np.ndarray, what: str, coded: np.ndarray | None = None) -> np.ndarray:
        """Decoding: q [rows, M] from residuals r and means (broadcastable int64 arrays), checking
        |q| <= MAX_PREDICTED_MAGNITUDE channel by channel (so no sum can overflow 64 bits).
        ``coded`` (bool [rows, M], clause 11.9; None: every value): a value not coded is q = 0
        whatever its mean and predictions, and a term whose source is not coded is 0."""
        q = r + mean
        if coded is not None:
            q *= coded
        if self.empty:
            _check_magnitude(q, what)
            return q
        # the channels no entry reads or changes keep q = r + mean: checked at once by their extremes (the
        # same verdict as value by value, and 10x faster than 59 strided columns at SH degree 3)
        involved = np.union1d(self.targets, self.sources)
        others = np.setdiff1d(np.arange(q.shape[1]), involved)
        if others.size and q.shape[0]:
            _check_magnitude(np.concatenate([q.max(axis=0)[others], q.min(axis=0)[others]]), what)
        dev = np.empty_like(q)
        for c in involved.tolist():
            entries = np.nonzero(self.targets == c)[0]
            if entries.size:
                q[:, c] += self._term(dev, c, entries)
                if coded is not None:
                    q[:, c] *= coded[:, c]
            _check_magnitude(q[:, c], what)
            dev[:, c] = q[:, c] - np.broadcast_to(mean, q.shape)[:, c]
            if coded is not None:
                dev[:, c] *= coded[:, c]
        return q

    def residuals(self, q: np.ndarray, mean: np.ndarray, coded: np.ndarray | None = None) -> np.ndarray:
        """Encoding: the residuals r that ``reconstruct`` turns back into q (with ``coded``: those
        of the coded values; an uncoded source's deviation counts 0)."""
        mean = np.broadcast_to(mean, q.shape)
        dev = q - mean
        if coded is not None:
            dev *= coded
        r = dev.copy() if self.targets.size else dev  # (the terms read dev)
        for c in np.unique(self.targets):
            r[:, c] -= self._term(dev, int(c), np.nonzero(self.targets == c)[0])
        return r


def _check_magnitude(q: np.ndarray, what: str) -> None:
    if q.size and int(np.abs(q).max()) > MAX_PREDICTED_MAGNITUDE:
        raise BitstreamError(f"{what}: a decoded value exceeds the limit of 2^40 quantization steps of a "
                             "Gaussian scene", condition="E51")


@dataclass
class CodingParams:
    """What a context model gives each value of an attribute unit: an integer mean, a scale
    level in [0, 64) and, optionally, a step-adjustment index in [0, 8). Arrays [rows, M]
    (or broadcastable to it)."""

    mean: np.ndarray
    level: np.ndarray
    step_adjust: np.ndarray | None = None

    def rows(self, lo: int, hi: int, num_channels: int) -> "CodingParams":
        """The parameters of rows lo..hi-1 (arrays with one row apply to every row)."""
        def take(a: np.ndarray) -> np.ndarray:
            return np.broadcast_to(a, (hi - lo, num_channels)) if a.shape[0] == 1 else a[lo:hi]
        return CodingParams(take(self.mean), take(self.level),
                            None if self.step_adjust is None else take(self.step_adjust))


def effective_steps(steps: np.ndarray, step_adjust: np.ndarray | None) -> np.ndarray:
    """float32 steps per value: float32(step(c)) * STEP_ADJUST_FACTORS[a]."""
    s = steps.astype(np.float32)
    if step_adjust is None or not np.any(step_adjust):  # factor 1.0: the product is the step itself
        return s
    return (s * STEP_ADJUST_FACTORS[step_adjust]).astype(np.float32)


def reconstruct(q: np.ndarray, steps: np.ndarray, step_adjust: np.ndarray | None = None,
                out: np.ndarray | None = None) -> np.ndarray:
    """Normative reconstruction: float32(q) * effective step, one binary32 multiplication
    per value (into ``out`` when given)."""
    return np.multiply(q.astype(np.float32), effective_steps(steps, step_adjust), out=out, dtype=np.float32)


# --- offset masks -------------------------------------------------------------------------

def mask_models(mask_live_prob: list[int]):
    """One binary model per offset slot: symbol 1 (live) has frequency p * 2^(24-12)."""
    shift = PRECISION_BITS - MASK_PROB_BITS
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
    dec.check_exhausted()  # clause 10.6.5: words left over are a corrupt chunk, as in a symbol chunk
    return mask


# --- residual chunks ------------------------------------------------------------------------

def encode_residual_chunk(residuals: np.ndarray, levels: np.ndarray, live: np.ndarray | None) -> bytes:
    """Code the live entries of [rows, M] residuals in row-major order (live None: all)."""
    if live is None:
        return encode_symbols(residuals, levels)
    return encode_symbols(residuals[live], levels[live])


def decode_residual_chunk(data: bytes, levels: np.ndarray, live: np.ndarray | None, what: str) -> np.ndarray:
    if live is None:
        return decode_symbols(data, levels, what)
    out = np.zeros(levels.shape, dtype=np.int64)
    out[live] = decode_symbols(data, levels[live], what)
    return out


def split_chunks(payload: bytes, sizes: list[int], what: str) -> list[bytes]:
    total = sum(sizes)
    if total != len(payload):
        raise BitstreamError(f"{what}: chunk sizes add up to {total} bytes but the unit holds {len(payload)}", condition="E50")
    out, pos = [], 0
    for s in sizes:
        out.append(payload[pos:pos + s])
        pos += s
    return out


def check_levels(levels: np.ndarray, what: str) -> None:
    if levels.size and (levels.min() < 0 or levels.max() >= NUM_SCALE_LEVELS):
        raise BitstreamError(f"{what}: a scale level is outside [0, 63]", condition="E19")


# --- the attribute unit ---------------------------------------------------------------------

def prior_params(h: AttributeUnitHeader) -> CodingParams:
    return CodingParams(np.asarray(h.prior_mean, dtype=np.int64)[None, :],
                        np.asarray(h.prior_level, dtype=np.int64)[None, :])


def new_attribute_header(layout, num_rows: int, level: int) -> AttributeUnitHeader:
    """An attribute unit header with the context its syntax depends on (from the parameter set)."""
    return AttributeUnitHeader(num_channels=layout.num_channels, num_offsets=layout.num_offsets,
                               offset_mask_present=layout.offset_mask_present,
                               channel_prediction_allowed=layout.channel_prediction_allowed,
                               num_rows=num_rows, attribute_level=level)


def write_attribute_unit(h: AttributeUnitHeader, layout, q: np.ndarray, mask: np.ndarray | None,
                         params: CodingParams, prediction: ChannelPrediction | None = None) -> bytes:
    """Code q [rows, M] (dead values ignored) in chunks; fills the header's chunk sizes (and its
    cross-channel prediction entries). ``mask`` must be given exactly when h.offset_mask_present."""
    prediction = prediction or ChannelPrediction.none()
    if not prediction.empty and not h.channel_prediction_allowed:
        raise ValueError("cross-channel prediction in a scene that does not allow it")
    if h.channel_prediction_allowed:
        prediction.to_header(h)
    if h.offset_mask_present and mask is None:
        raise ValueError("an attribute unit with offset masks needs the mask")
    models = mask_models(h.mask_live_prob) if h.offset_mask_present else None
    chunks: list[bytes] = []
    h.mask_chunk_size, h.chunk_size = [], []
    for i in range(h.num_chunks):
        lo, hi = i * h.rows_per_chunk, min(h.num_rows, (i + 1) * h.rows_per_chunk)
        if models is not None and mask is not None:
            chunks.append(encode_mask_chunk(mask[lo:hi], models))
            h.mask_chunk_size.append(len(chunks[-1]))
        live = layout.live_channels(None if mask is None else mask[lo:hi], hi - lo)
        p = params.rows(lo, hi, layout.num_channels)
        chunks.append(encode_residual_chunk(prediction.residuals(q[lo:hi], p.mean), p.level, live))
        h.chunk_size.append(len(chunks[-1]))
    return h.to_bytes() + b"".join(chunks)


def read_attribute_unit(payload: bytes, layout, steps: np.ndarray, num_rows: int, level: int,
                        values_out: np.ndarray, rows: np.ndarray | None = None, context=None,
                        trace: list[TraceEntry] | None = None, keep_q: bool = False, on_chunk=None):
    """Parse and decode an attribute unit of ``num_rows`` rows at hierarchy ``level``; write
    the reconstructed values of row r to ``values_out[rows[r]]`` (``rows`` None: row r).

    ``layout``: the scene's channel layout (ChannelLayout or GaussianLayout), ``steps`` its
    float32 [M] quantization steps. ``context``: a callable context_model_id -> CodingParams
    (None when the stream has no context model). ``on_chunk(rows)`` is called after each
    chunk (progress). Returns (header, mask bool [rows, K] or None, q int64 [rows, M] when
    ``keep_q`` else None). Chunk by chunk, so memory stays proportional to the output.
    """
    what = f"attribute unit (level {level})"
    reader = BitReader(payload, what)
    h = AttributeUnitHeader.parse(reader, trace, num_channels=layout.num_channels, num_offsets=layout.num_offsets,
                                  offset_mask_present=layout.offset_mask_present,
                                  channel_prediction_allowed=layout.channel_prediction_allowed, num_rows=num_rows)
    if h.attribute_level != level:
        raise BitstreamError(f"attribute unit: attribute_level {h.attribute_level} where level {level} is expected", condition="E45")
    assert h.num_rows_minus1 is not None  # parsed
    if h.num_rows_minus1 + 1 != num_rows:  # clause 8.3 rule 8
        raise BitstreamError(f"{what}: num_rows_minus1 + 1 = {h.num_rows_minus1 + 1}, but the tile's level has "
                             f"{num_rows} rows", condition="E59")
    prediction = ChannelPrediction.from_header(h, what)
    if h.context_model_id == CONTEXT_PER_CHANNEL_PRIOR:
        params = prior_params(h)
    else:
        if context is None:
            raise BitstreamError(f"attribute unit (level {level}) uses context model {h.context_model_id}, "
                                 "but the stream has no matching context model unit",
                                 condition="E47" if level == 2 else "E46")  # levels 0 and 1 have no context model
        params = context(h.context_model_id)
    pieces = iter(split_chunks(payload[reader.bit_position // 8:], _chunk_sizes(h), what))
    models = mask_models(h.mask_live_prob) if h.offset_mask_present else None
    mask = np.ones((num_rows, layout.num_offsets), dtype=bool) if h.offset_mask_present else None
    q_all = np.zeros((num_rows, layout.num_channels), dtype=np.int64) if keep_q else None
    for i in range(h.num_chunks):
        lo, hi = i * h.rows_per_chunk, min(num_rows, (i + 1) * h.rows_per_chunk)
        if models is not None and mask is not None:
            mask[lo:hi] = decode_mask_chunk(next(pieces), hi - lo, models, f"attribute mask chunk {i}")
        p = params.rows(lo, hi, layout.num_channels)
        q = decode_chunk_values(next(pieces), h, layout, p, prediction, None if mask is None else mask[lo:hi],
                                 hi - lo, i, level)
        target = values_out[lo:hi] if rows is None else np.empty((hi - lo, layout.num_channels), np.float32)
        reconstruct_chunk(q, steps, p.step_adjust, target, i, level, layout)
        if rows is not None:
            values_out[rows[lo:hi]] = target
        if q_all is not None:
            q_all[lo:hi] = q
        if on_chunk is not None:
            on_chunk(hi - lo)
    return h, mask, q_all


def _chunk_sizes(h: AttributeUnitHeader) -> list[int]:
    """The sizes of the unit's chunk payloads in stream order (mask chunk i before chunk i)."""
    return [x for pair in zip(h.mask_chunk_size, h.chunk_size) for x in pair] if h.offset_mask_present \
        else list(h.chunk_size)


def decode_chunk_values(data: bytes, h: AttributeUnitHeader, layout, p: CodingParams, prediction: ChannelPrediction,
                         mask: np.ndarray | None, num_rows: int, i: int, level: int,
                         coded: np.ndarray | None = None) -> np.ndarray:
    """The quantized values q [rows, M] of chunk i: its residuals decoded with the scale levels
    of ``p``, plus the means (and the cross-channel prediction); values not coded are 0. ``coded``:
    the rows' coded channels of a stream with an sh_degree unit (clause 11.9), None otherwise."""
    live = layout.live_channels(mask, num_rows) if coded is None else coded
    check_levels(np.asarray(p.level), f"attribute unit (level {level})")
    r = decode_residual_chunk(data, p.level, live, f"attribute chunk {i}")
    if h.channel_prediction_allowed:
        q = prediction.reconstruct(r, np.asarray(p.mean, dtype=np.int64), f"attribute chunk {i} (level {level})", live)
    else:
        q = r + p.mean
        if live is not None:
            q *= live  # values that are not coded are 0 (with cross-channel prediction: reconstruct's rule)
    return q


def reconstruct_chunk(q: np.ndarray, steps: np.ndarray, step_adjust: np.ndarray | None, target: np.ndarray,
                       i: int, level: int, layout=None) -> None:
    """Reconstruction (clause 11.5) of chunk i into ``target``, of the SH rest's inverse transform
    with an sh_transform unit (clause 11.11); every value must be finite. Then, with a
    rotation_length unit, the rotations' w (clause 11.10; ``layout`` the scene's)."""
    values_q = q if layout is None else inverse_sh_transform(q, layout, f"attribute chunk {i} (level {level})")
    with np.errstate(over="ignore", invalid="ignore"):
        reconstruct(values_q, steps, step_adjust, out=target)
    if not np.isfinite(target).all():
        raise BitstreamError(f"attribute chunk {i} (level {level}): a decoded value overflows binary32 "
                             "(a conforming stream decodes to finite values only)", condition="E52")
    if layout is not None:
        reconstruct_rotations(q, target, layout, f"attribute chunk {i} (level {level})")
