"""Per-Gaussian SH degree (normative; spec clauses 7.3.14 and 11.9, version 1.3).

With an sh_degree unit, every row i of a Gaussian tile coded with neighbour prediction has an SH
degree D_i in [0, d]: its coded channels are the SH channels c < 3 (D_i + 1)^2 and the eight
channels from 3S on (opacity, log scales, rotation); the bands above D_i are not coded (q = 0).

Each chunk's degrees are coded, before its symbol data, in a range-coded chunk of binary flags
"the row has band b", band by band: for b = 1 .. d, the flags of the chunk's rows with D = b - 1
(every row for b = 1), in the chunk's row order; a row whose flag is 1 has D = b. The flag of band
b of a row is coded with the probability ``degree_flag_prob[(b - 1) * 6 + x]`` of its context x:
0 in LoD 0; for a row of LoD l >= 1 with n neighbours (clause 11.7.2), m of which have a degree of
at least b: 1 when m = 0, 5 when m = n, else 2 + (3 m) // n. Its frequency table is
f[1] = 4096 p + 2048, f[0] = 2^24 - f[1]. Band-major order lets a decoder decode one band of a
chunk's rows in one call, as the symbol data's level groups (row-major flags would need one call
per row).

The same flags code version 1.5's step-adjustment indices (clause 11.8, a step_adjust_flags unit):
encode_flag_chunk and decode_flag_chunk take the largest level and the flag models, so one
implementation serves both tools.
"""

from __future__ import annotations

import numpy as np

from .entropy.range_coder import TOTAL_FREQUENCY, RangeDecoder, RangeEncoder, binary_weights
from .units import DEGREE_PROB_BITS, NUM_DEGREE_CONTEXTS, ShDegreeUnit

# f[1] = FLAG_PROB_UNIT * p + FLAG_PROB_UNIT / 2: p in units of 2^-12 of the 2^24 total, plus half a unit
FLAG_PROB_UNIT = TOTAL_FREQUENCY >> DEGREE_PROB_BITS


def coded_channels(sh_channels: int, num_channels: int, degrees: np.ndarray) -> np.ndarray:
    """bool [n, M]: the coded channels of rows of SH degrees ``degrees`` [n] (clause 11.9): the SH
    channels c < 3 (D + 1)^2 and every channel from 3S on."""
    c = np.arange(num_channels)[None, :]
    d = np.asarray(degrees, np.int64)[:, None]
    return (c < 3 * (d + 1) ** 2) | (c >= sh_channels)


def flag_weights(probs, levels: int) -> np.ndarray:
    """The constriction weights [levels, NumDegreeContexts, 2] of the flag models of every level b =
    1 .. levels and context from the unit's probabilities ``probs`` (``degree_flag_prob``, or version
    1.5's ``step_flag_prob``, clause 11.8), (b - 1) * 6 + x each."""
    p = np.asarray(probs, np.int64)
    f1 = FLAG_PROB_UNIT * p + FLAG_PROB_UNIT // 2
    return binary_weights(f1).reshape(levels, NUM_DEGREE_CONTEXTS, 2)


def neighbour_degrees(neighbours: np.ndarray | None, degrees: np.ndarray) -> np.ndarray | None:
    """int64 [n, k]: the degree of each neighbour of a chunk's rows (-1 where a slot is empty), from
    ``degrees`` [N] (rows of coarser LoDs filled); None for LoD 0 (no neighbours)."""
    if neighbours is None:
        return None
    return np.where(neighbours >= 0, degrees[np.maximum(neighbours, 0)], -1)


def flag_contexts(band: int, nd: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """The context x (int64) of band ``band``'s flag of the chunk's rows ``rows`` (indices into the
    chunk), from their neighbours' degrees ``nd`` (None: LoD 0, x = 0)."""
    if nd is None:
        return np.zeros(rows.size, np.int64)
    sub = nd[rows]
    n = (sub >= 0).sum(axis=1)
    m = (sub >= band).sum(axis=1)
    return np.where(m == 0, 1, np.where(m == n, 5, 2 + (3 * m) // np.maximum(n, 1)))


def band_flags(row_degrees: np.ndarray, nd: np.ndarray | None, sh_degree: int):
    """Encoding: per band b = 1 .. d, (b, contexts, flags) of the rows that code a flag of band b
    (those with D >= b - 1, in chunk order): the order of the chunk (clause 11.9)."""
    active = np.arange(row_degrees.size)
    for band in range(1, sh_degree + 1):
        if not active.size:
            return
        flags = (row_degrees[active] >= band).astype(np.int32)
        yield band, flag_contexts(band, nd, active), flags
        active = active[flags == 1]


def encode_flag_chunk(row_levels: np.ndarray, nd: np.ndarray | None, levels: int, weights: np.ndarray) -> bytes:
    """The flags of a chunk whose rows have levels ``row_levels`` [n] in [0, ``levels``] (SH degrees,
    or step-adjustment indices, clause 11.8), ``weights`` from flag_weights."""
    enc = RangeEncoder()
    for band, x, flags in band_flags(np.asarray(row_levels, np.int64), nd, levels):
        enc.encode_binary_models(flags, weights[band - 1][x])
    return enc.to_bytes()


def decode_flag_chunk(data: bytes, num_rows: int, nd: np.ndarray | None, levels: int, weights: np.ndarray,
                      what: str) -> np.ndarray:
    """The levels (int64 [num_rows]) of a chunk's rows from its flags (clause 11.9, and 11.8 for the
    step-adjustment indices of version 1.5); the chunk must be exhausted after the last flag
    (clause 10.6.5)."""
    dec = RangeDecoder(data, what)
    out = np.zeros(num_rows, np.int64)
    active = np.arange(num_rows)
    for band in range(1, levels + 1):
        if not active.size:
            break
        flags = dec.decode_binary_models(weights[band - 1][flag_contexts(band, nd, active)])
        active = active[flags == 1]
        out[active] = band
    dec.check_exhausted()
    return out


def encode_degree_chunk(row_degrees: np.ndarray, nd: np.ndarray | None, unit: ShDegreeUnit) -> bytes:
    """The SH-degree data of a chunk whose rows have degrees ``row_degrees`` [n]."""
    return encode_flag_chunk(row_degrees, nd, unit.sh_degree, flag_weights(unit.degree_flag_prob, unit.sh_degree))


def decode_degree_chunk(data: bytes, num_rows: int, nd: np.ndarray | None, unit: ShDegreeUnit,
                        what: str) -> np.ndarray:
    """The SH degrees (int64 [num_rows]) of a chunk's rows from its SH-degree data."""
    return decode_flag_chunk(data, num_rows, nd, unit.sh_degree, flag_weights(unit.degree_flag_prob, unit.sh_degree),
                             what)
