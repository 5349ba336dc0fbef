"""Coding of integer residuals with the frozen scale tables (normative; spec/entropy.md).

A residual r = q - mean is coded with the table of its scale level i (known to both sides
from the context model): bin r + L_i when |r| <= L_i, else the escape bin ESC = 2 L_i + 1
followed, in the chunk's escape section, by the sign, the magnitude class and the raw
remainder bits of m = |r| - L_i - 1.

One chunk is one range-coder stream:

1. level groups: for i = 0..63, the bins of all symbols of level i, in the order of the
   symbols (row-major), coded with level i's table;
2. escape section, over the escaped symbols in the order of the symbols:
   all signs (1 raw bit each, 1 = negative), then all classes k = bit_length(m) with the
   class table, then all remainders m - 2^(k-1) as k - 1 raw bits (nothing when k = 0).

Any |r| <= 2^62 - 1 can be coded; the encoder rejects anything else with ValueError.
The decoder raises BitstreamError on data that cannot come from an encoder.
"""

from __future__ import annotations

import numpy as np

from .range_coder import RangeDecoder, RangeEncoder, exact_model
from .tables import (
    HALF_WIDTHS,
    MAX_ABS_RESIDUAL,
    NUM_SCALE_LEVELS,
    PRECISION_BITS,
    TABLES,
)
from ..errors import BitstreamError

__all__ = [
    "encode_symbols", "decode_symbols", "encode_chunked", "decode_chunked", "escape_class", "code_lengths_bits",
    "best_level", "best_level_and_bits",
]

_ESC = 2 * HALF_WIDTHS + 1                      # escape bin index per level
_LEVEL_MODELS: list = [None] * NUM_SCALE_LEVELS
_CLASS_MODEL = None
# informative: ideal code length of every bin (bits), for code_lengths_bits
_BIN_BITS = PRECISION_BITS - np.log2(TABLES.freqs.astype(np.float64))
_CLASS_BITS = PRECISION_BITS - np.log2(TABLES.escape_class_freqs.astype(np.float64))


def _level_model(i: int):
    m = _LEVEL_MODELS[i]
    if m is None:
        m = _LEVEL_MODELS[i] = exact_model(TABLES.level(i))
    return m


def _class_model():
    global _CLASS_MODEL
    if _CLASS_MODEL is None:
        _CLASS_MODEL = exact_model(TABLES.escape_class_freqs)
    return _CLASS_MODEL


# --- input checks ------------------------------------------------------------------------

def _levels(levels: np.ndarray, shape: tuple | None = None, dtype: type[np.integer] = np.uint8) -> np.ndarray:
    lv = np.asarray(levels)
    if shape is not None and lv.shape != shape:
        raise ValueError(f"levels have shape {lv.shape}, residuals {shape}")
    if lv.size == 0:
        return np.zeros(lv.shape, dtype=dtype)
    if not np.issubdtype(lv.dtype, np.integer):
        raise ValueError(f"levels must be integers, not {lv.dtype}")
    if int(lv.min()) < 0 or int(lv.max()) >= NUM_SCALE_LEVELS:
        raise ValueError(f"levels must lie in [0, {NUM_SCALE_LEVELS}) (found {int(lv.min())}..{int(lv.max())})")
    return lv.astype(dtype, copy=False)


def _residuals(residuals: np.ndarray) -> np.ndarray:
    return _residuals_and_range(residuals)[0]


def _residuals_and_range(residuals: np.ndarray) -> tuple[np.ndarray, int, int]:
    """The residuals checked, as int64 (not copied where they are already), and their least and
    largest values (0, 0 where there are none)."""
    r = np.asarray(residuals)
    if r.size == 0:
        return np.zeros(r.shape, dtype=np.int64), 0, 0
    if not np.issubdtype(r.dtype, np.integer):
        raise ValueError(f"residuals must be integers, not {r.dtype}")
    if np.issubdtype(r.dtype, np.unsignedinteger):
        hi = int(r.max())
        if hi > MAX_ABS_RESIDUAL:
            raise ValueError(f"residual {hi} exceeds the codable range |r| <= 2^62 - 1")
        return r.astype(np.int64), 0, hi
    r = r.astype(np.int64, copy=False)
    lo, hi = int(r.min()), int(r.max())
    if lo < -MAX_ABS_RESIDUAL or hi > MAX_ABS_RESIDUAL:
        raise ValueError(f"residual {lo if lo < -MAX_ABS_RESIDUAL else hi} exceeds the codable range "
                         f"|r| <= 2^62 - 1")
    return r, lo, hi


_EXACT_IN_FLOAT64 = 1 << 53
# the bit length of each m < 2^16, looked up (frexp's exponent: exact, and 0 for 0)
_BIT_LENGTH_16 = np.frexp(np.arange(1 << 16, dtype=np.float64))[1].astype(np.int64)
_BIT_LENGTH_16.setflags(write=False)


def escape_class(m: np.ndarray) -> np.ndarray:
    """k = bit length of m (0 for m = 0), for 0 <= m < 2^63; exact integer arithmetic."""
    x = np.asarray(m)
    if x.size and 0 <= int(x.min()) and int(x.max()) < _BIT_LENGTH_16.size:
        # one look-up per value, 10x faster than frexp: a decoder takes it of every value's neighbour
        # spread, which is mostly small (tools/results/decode.md, issue 53)
        return np.take(_BIT_LENGTH_16, x)
    if x.size and int(x.max()) < _EXACT_IN_FLOAT64:
        # below 2^53 a float64 holds m exactly and frexp's exponent is its bit length (17x faster:
        # the rate estimates take it of every value's neighbour spread)
        return np.frexp(x.astype(np.float64))[1].astype(np.int64)
    x = np.asarray(m, dtype=np.uint64).copy()
    k = np.zeros(x.shape, dtype=np.int64)
    for s in (32, 16, 8, 4, 2, 1):
        big = x >= np.uint64(1 << s)
        k[big] += s
        x[big] >>= np.uint64(s)
    return k + (x > 0)


def _bins(r: np.ndarray, lv: np.ndarray):
    L = HALF_WIDTHS[lv]
    esc = (r > L) | (r < -L)
    bins = np.where(esc, _ESC[lv], r + L)
    return bins, esc, L


def _escape_parts(r: np.ndarray, L: np.ndarray):
    """sign (1 = negative), class k, remainder, remainder width for escaped residuals."""
    neg = r < 0
    m = np.abs(r) - L - 1                     # >= 0; |r| <= 2^62 - 1 so no overflow
    k = escape_class(m)
    width = np.maximum(k - 1, 0)
    rem = np.where(k > 0, m - np.left_shift(np.int64(1), width), 0)
    return neg.astype(np.uint64), k, rem.astype(np.uint64), width


# --- one chunk ---------------------------------------------------------------------------

def encode_symbols(residuals: np.ndarray, levels: np.ndarray) -> bytes:
    """Code one chunk of residuals (row-major order), each with the table of its level."""
    r = _residuals(residuals).ravel()
    lv = _levels(levels, np.shape(residuals)).ravel()
    if r.size == 0:
        return b""
    bins, esc, L = _bins(r, lv)
    enc = RangeEncoder()
    lv_in = np.asarray(levels)
    if lv_in.ndim == 2 and lv_in.shape[0] > 1 and lv_in.strides[0] == 0:
        # one level per column: group i is the columns of level i, row-major (no sort needed)
        row = lv_in[0]
        b2 = bins.reshape(lv_in.shape)
        for i in np.unique(row):
            cols = np.flatnonzero(row == i)
            enc.encode((b2 if cols.size == row.size else b2[:, cols]).ravel(), _level_model(int(i)))
    else:
        order = np.argsort(lv, kind="stable")
        counts = np.bincount(lv, minlength=NUM_SCALE_LEVELS)
        sorted_bins = bins[order].astype(np.int32)
        start = 0
        for i in np.flatnonzero(counts):
            end = start + int(counts[i])
            enc.encode(sorted_bins[start:end], _level_model(int(i)))
            start = end
    if esc.any():
        sign, k, rem, width = _escape_parts(r[esc], L[esc])
        enc.encode_bits(sign, 1)
        enc.encode(k, _class_model())
        enc.encode_bits(rem, width)
    return enc.to_bytes()


def _decode_bins_by_column(dec: RangeDecoder, row_levels: np.ndarray, rows: int) -> np.ndarray:
    """Bins [rows, M] of a chunk whose levels are the same in every row (one level per column):
    the group of level i is then the columns of level i, row-major, so each group decodes
    straight into its columns; the same order as the general path, without a sort."""
    m = row_levels.size
    bins = np.empty((rows, m), dtype=np.int32)
    for i in np.unique(row_levels):
        cols = np.flatnonzero(row_levels == i)
        seg = dec.decode(rows * cols.size, _level_model(int(i)))
        if cols.size == m:
            bins[:] = seg.reshape(rows, m)
        else:
            bins[:, cols] = seg.reshape(rows, cols.size)
    return bins


def decode_symbols(data: bytes, levels: np.ndarray, what: str = "chunk") -> np.ndarray:
    """Decode one chunk; ``levels`` (from the context model) give the count and the tables.
    Returns int64 residuals of the shape of ``levels``."""
    lv_in = np.asarray(levels)
    dec = RangeDecoder(bytes(data), what)
    if lv_in.ndim == 2 and lv_in.shape[0] > 1 and lv_in.strides[0] == 0:  # one row, broadcast
        row = _levels(lv_in[0])
        bins = _decode_bins_by_column(dec, row, lv_in.shape[0])
        half, esc_bin = HALF_WIDTHS[row], _ESC[row].astype(np.int32)  # per column, broadcast over rows
        out = np.subtract(bins, half, dtype=np.int64)  # bins become residuals (one pass)
        esc = bins == esc_bin
        _finish_escapes(dec, out, esc, lambda: np.broadcast_to(half, bins.shape)[esc], what)
    else:
        lv = _levels(lv_in).ravel()
        out, esc = _decode_residuals_by_level(dec, lv)
        _finish_escapes(dec, out, esc, lambda: HALF_WIDTHS[lv[esc]], what)
    dec.check_exhausted()
    return out.reshape(lv_in.shape)


def _decode_residuals_by_level(dec: RangeDecoder, lv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symbols with a level each (uint8, row-major): the group of level i (its symbols in
    row-major order) is decoded with table i, groups in increasing level; -> (bins made
    residuals, int64; escape flags), in row-major order. The residual and the escape test are
    computed per group, with the group's constants, before the one scatter back to row-major."""
    n = lv.size
    out = np.empty(n, dtype=np.int64)
    esc = np.empty(n, dtype=bool)
    if not n:
        return out, esc
    order = np.argsort(lv, kind="stable")  # uint8: a radix sort
    counts = np.bincount(lv, minlength=NUM_SCALE_LEVELS)
    sorted_res = np.empty(n, dtype=np.int64)
    sorted_esc = np.empty(n, dtype=bool)
    start = 0
    for i in np.flatnonzero(counts):
        end = start + int(counts[i])
        seg = dec.decode(end - start, _level_model(int(i)))
        np.subtract(seg, HALF_WIDTHS[i], out=sorted_res[start:end], casting="unsafe")
        np.equal(seg, _ESC[i], out=sorted_esc[start:end])
        start = end
    out[order] = sorted_res
    esc[order] = sorted_esc
    return out, esc


def _finish_escapes(dec: RangeDecoder, out: np.ndarray, esc: np.ndarray, half_of_escaped, what: str) -> None:
    """The escape section of a chunk (clause 10.5): sign, class and remainder of every escaped
    symbol, in row-major order, into ``out``. ``half_of_escaped()``: the half-widths L of the
    escaped symbols' levels."""
    if out.size:
        ne = int(esc.sum())
        if ne:
            neg = dec.decode_bits(1, ne).astype(bool)
            k = dec.decode(ne, _class_model())
            width = np.maximum(k - 1, 0)
            rem = dec.decode_bits(width)
            # k <= 62 and rem < 2^(k-1): m < 2^62, magnitude < 2^62 + 2^13, no overflow
            m = np.where(k > 0, np.left_shift(np.uint64(1), width.astype(np.uint64)) + rem, np.uint64(0))
            mag = m + (half_of_escaped() + 1).astype(np.uint64)
            if int(mag.max()) > MAX_ABS_RESIDUAL:
                raise BitstreamError(f"{what}: escaped residual magnitude {int(mag.max())} exceeds 2^62 - 1", condition="E37")
            mag = mag.astype(np.int64)
            out[esc] = np.where(neg, -mag, mag)


def _code_lengths_bits(r: np.ndarray, lv: np.ndarray) -> np.ndarray:
    """code_lengths_bits of checked flat residuals (int64) and levels (uint8)."""
    bins, esc, L = _bins(r, lv)
    bits = _BIN_BITS[TABLES.offsets[lv] + bins]
    if esc.any():
        _, k, _, width = _escape_parts(r[esc], L[esc])
        bits[esc] += 1.0 + _CLASS_BITS[k] + width
    return bits


# informative: the code length of every residual |r| <= _LUT_R at every level, row per level
# (the encoder's rate estimates look up millions of them per trial)
_LUT_R = 1024
_LUT = _code_lengths_bits(np.tile(np.arange(-_LUT_R, _LUT_R + 1, dtype=np.int64), NUM_SCALE_LEVELS),
                          np.repeat(np.arange(NUM_SCALE_LEVELS, dtype=np.uint8), 2 * _LUT_R + 1))


_LUT_BY_LEVEL = _LUT.reshape(NUM_SCALE_LEVELS, 2 * _LUT_R + 1)
# the residuals |r| <= TABLE_RADIUS whose code lengths come from the table (the others are computed)
TABLE_RADIUS = _LUT_R


def code_lengths_bits(residuals: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Per residual, -log2 of the probability the tables give it at its level, escape class and
    raw remainder bits included (float64, the shape of residuals)."""
    r, lo, hi = _residuals_and_range(residuals)
    lv = _levels(levels, np.shape(residuals), np.int64)
    if r.size == 0:
        return np.zeros(r.shape, dtype=np.float64)
    if -_LUT_R <= lo and hi <= _LUT_R:  # every residual in the table (RDOQ's hot path: no copies to clip)
        index = lv * (2 * _LUT_R + 1) + r
        index += _LUT_R
        return _LUT[index]
    rf, lf = r.ravel(), lv.ravel()
    far = np.abs(rf) > _LUT_R
    bits = _LUT[lf.astype(np.int64) * (2 * _LUT_R + 1) + np.clip(rf, -_LUT_R, _LUT_R) + _LUT_R]
    if far.any():
        bits[far] = _code_lengths_bits(rf[far], lf[far])
    return bits.reshape(r.shape)


# --- chunks ------------------------------------------------------------------------------

def _chunk_count(rows: int, rows_per_chunk: int) -> int:
    if isinstance(rows_per_chunk, bool) or int(rows_per_chunk) != rows_per_chunk or rows_per_chunk < 1:
        raise ValueError(f"rows_per_chunk must be a positive integer, not {rows_per_chunk!r}")
    return -(-rows // int(rows_per_chunk))


def encode_chunked(residuals: np.ndarray, levels: np.ndarray, rows_per_chunk: int) -> list[bytes]:
    """[N, ...] arrays; chunk k codes rows k*S .. (k+1)*S - 1 (row-major) as one stream."""
    r = np.asarray(residuals)
    lv = np.asarray(levels)
    if r.ndim < 1 or r.shape != lv.shape:
        raise ValueError(f"residuals {r.shape} and levels {lv.shape} must have the same shape (ndim >= 1)")
    _chunk_count(r.shape[0], rows_per_chunk)
    S = int(rows_per_chunk)
    return [encode_symbols(r[a:a + S], lv[a:a + S]) for a in range(0, r.shape[0], S)]


def decode_chunked(chunks: list[bytes], levels: np.ndarray, rows_per_chunk: int) -> np.ndarray:
    lv = np.asarray(levels)
    if lv.ndim < 1:
        raise ValueError("levels must have at least one dimension (rows)")
    expected = _chunk_count(lv.shape[0], rows_per_chunk)
    if len(chunks) != expected:
        raise BitstreamError(f"{len(chunks)} chunks where {lv.shape[0]} rows in chunks of "
                             f"{rows_per_chunk} make {expected}", condition="E59")
    S = int(rows_per_chunk)
    out = np.zeros(lv.shape, dtype=np.int64)
    for c, data in enumerate(chunks):
        out[c * S:(c + 1) * S] = decode_symbols(data, lv[c * S:(c + 1) * S], f"chunk {c}")
    return out


# --- informative: the level of fewest bits ------------------------------------------------
# (write_context_model_unit codes each array at best_level; the encoder's other rate estimates
# are encoder/context/code_lengths.py)

def best_level(residuals: np.ndarray) -> int:
    """Informative (encoder choice): the one scale level that codes these residuals in the
    fewest ideal bits, over all 64 levels (searching only near the level of their RMS missed
    heavy-tailed channels, mostly zeros with a few large values: on a rate-trained lego scene
    the per-channel prior of level 1 cost 69.1 instead of 43.3 bits per anchor)."""
    return best_level_and_bits(residuals)[0]


def best_level_and_bits(residuals: np.ndarray) -> tuple[int, float]:
    """best_level and the ideal bits of the residuals at that level."""
    r = np.asarray(residuals, dtype=np.int64).ravel()
    if r.size == 0:
        return 0, 0.0
    lo, hi = int(r.min()), int(r.max())
    if -_LUT_R <= lo and hi <= _LUT_R:  # the same values and counts as np.unique's, without its sort
        counts = np.bincount(r - lo)
        values = np.flatnonzero(counts)
        return level_and_bits(bits_by_level(values + lo, counts[values]))
    return level_and_bits(bits_by_level(*np.unique(r, return_counts=True)))


def bits_by_level(values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """float64 [NUM_SCALE_LEVELS]: the ideal bits at each level of residuals taking the distinct
    ascending int64 ``values`` ``counts`` times: a function of the histogram alone, so the same sums
    to the last bit however the counts were gathered (whole, by bucket or block by block)."""
    if -_LUT_R <= values[0] and values[-1] <= _LUT_R:
        return _LUT_BY_LEVEL[:, values + _LUT_R] @ counts
    lv = np.repeat(np.arange(NUM_SCALE_LEVELS, dtype=np.int64), values.size)
    return code_lengths_bits(np.tile(values, NUM_SCALE_LEVELS), lv).reshape(NUM_SCALE_LEVELS, -1) @ counts


def level_and_bits(bits: np.ndarray) -> tuple[int, float]:
    """The level of fewest bits in bits_by_level's ``bits`` (the lowest among equal costs) and its bits."""
    level = int(np.argmin(bits))
    return level, float(bits[level])
