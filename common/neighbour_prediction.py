"""Neighbour prediction of an explicit-Gaussian tile's attributes (normative; spec clause 11.7).

A Gaussian's attributes resemble those of the Gaussians around it (a surface's colour, its
Gaussians' sizes and orientations). With the neighbour_prediction unit (version 1.1), the
attribute unit of a tile without the hierarchy codes its rows in levels of detail:

* LoD(i) of row i (0 <= i < N) for L levels: 0 when i is a multiple of 2^(L-1) (row 0
  included), else L - 1 - ctz(i), with ctz the number of trailing zero bits. The rows are in
  the geometry's normative (Morton) order, so every LoD is spread over the whole tile and each
  finer LoD doubles the density.
* LoD 0 is coded with the unit header's per-channel prior. A row of LoD l >= 1 is coded with
  a mean and a scale level from its neighbours: the (at most) k points of LoD < l nearest to
  it (canonical Ball k-NN, common/knn.py, with the ball covering the whole extent), whose
  values are already decoded:

      n     = number of neighbours found (>= 1: row 0 is of LoD 0)
      mean  = floor((sum of the neighbours' q + floor(n / 2)) / n)        per channel c with
              neighbour_mean_flag[c] = 1; the header's prior_mean[c] otherwise
      a     = max - min of the neighbours' q                                per channel
      bucket = min(bit_length(a), B - 1)
      level = bucket_level[c * B + bucket]

  so where the neighbours agree the residual is coded with a narrow distribution, where they
  differ (an edge) with a wide one.

All of it is integer arithmetic; |q| <= 2^40 and k <= 32 keep every sum within 64 bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attributes import (ChannelPrediction, CodingParams, decode_chunk_values, encode_residual_chunk, prior_params,
                         reconstruct_chunk, split_chunks)
from .bitio import BitReader
from .entropy.symbol_coder import decode_symbols, encode_symbols, escape_class
from .errors import BitstreamError
from .knn import MAX_EXTENT, ball_knn
from .sh_degree import (coded_channels, decode_degree_chunk, decode_flag_chunk, encode_degree_chunk, encode_flag_chunk,
                        flag_weights, neighbour_degrees)
from .syntax import TraceEntry
from .units import (CONTEXT_PER_CHANNEL_PRIOR, LEVEL_ALL, AttributeUnitHeader, NeighbourPredictionUnit, ShDegreeUnit,
                    StepAdjustFlagsUnit, StepAdjustUnit)

# the whole extent of a tile lies in this ball (every d2 of an admissible tile is below it)
WHOLE_EXTENT_RADIUS_SQ = 3 * MAX_EXTENT * MAX_EXTENT


def lod_of_rows(num_rows: int, num_lods: int) -> np.ndarray:
    """LoD of each row: 0 for multiples of 2^(L-1), else L - 1 - ctz(i) (int64 [N])."""
    i = np.arange(num_rows, dtype=np.int64)
    lod = np.full(num_rows, num_lods - 1, dtype=np.int64)
    for t in range(1, num_lods):  # rows divisible by 2^t are at LoD L - 1 - t or coarser
        lod[i % (1 << t) == 0] = num_lods - 1 - t
    return lod


def lod_rows(num_rows: int, num_lods: int) -> list[np.ndarray]:
    """The rows of each LoD, ascending (the coding order is LoD 0's rows, then LoD 1's, ...)."""
    lod = lod_of_rows(num_rows, num_lods)
    return [np.nonzero(lod == level)[0] for level in range(num_lods)]


def level_table(unit: NeighbourPredictionUnit) -> np.ndarray:
    """bucket_level as int64 [NumChannels, B]."""
    return np.asarray(unit.bucket_level, dtype=np.int64).reshape(unit.num_channels, unit.num_buckets)


def mean_flags(unit: NeighbourPredictionUnit) -> np.ndarray:
    return np.asarray(unit.neighbour_mean_flag, dtype=bool)


@dataclass
class NeighbourGraph:
    """Per LoD: its rows and, for LoD >= 1, each row's neighbours (rows of coarser LoDs, int64
    [n_l, k], -1 where fewer than k exist) in (distance, row) order."""
    rows: list[np.ndarray]
    neighbours: list[np.ndarray | None]

    def neighbours_of(self, level: int) -> np.ndarray:
        """The neighbours of LoD ``level`` >= 1 (LoD 0 has none)."""
        nb = self.neighbours[level]
        assert nb is not None, "LoD 0 has no neighbours"
        return nb

    @property
    def coding_order(self) -> np.ndarray:
        return np.concatenate(self.rows) if self.rows else np.zeros(0, np.int64)


def check_extent(coords: np.ndarray, what: str) -> str | None:
    """Why the tile's points are beyond the neighbour graph's extent limit (clause 8.1), or None."""
    if coords.shape[0] == 0:
        return None
    extent = int((coords.max(axis=0) - coords.min(axis=0)).max())
    if extent > MAX_EXTENT:
        return f"{what}: the points span {extent} voxels along an axis, beyond the neighbour prediction's " \
               f"limit of {MAX_EXTENT}"
    return None


def neighbour_graph(coords: np.ndarray, num_lods: int, k: int) -> NeighbourGraph:
    """The LoDs of the tile's points (rows in normative order) and each finer row's k nearest
    coarser points. ValueError beyond the extent limit (check_extent first)."""
    rows = lod_rows(coords.shape[0], num_lods)
    neighbours: list[np.ndarray | None] = [None]
    coarser = rows[0]
    for level in range(1, num_lods):
        cur = rows[level]
        if cur.size == 0:
            neighbours.append(np.zeros((0, k), np.int64))
            continue
        idx, valid = ball_knn(coords[coarser], k, WHOLE_EXTENT_RADIUS_SQ, query=coords[cur], exclude_self=False)
        neighbours.append(np.where(valid, coarser[np.where(valid, idx, 0)], -1))
        coarser = np.sort(np.concatenate([coarser, cur]))  # ball_knn breaks ties by the lower data index
    return NeighbourGraph(rows, neighbours)


# Step adjustment (version 1.2, clause 11.8): row i's values are in steps of
# step(c) * STEP_ADJUST_FACTORS[a_i]. Neighbours in other steps are compared in fixed point:
# ADJUST_FIXED_POINT[a] = round(2^12 * 2^(a/4)) (a value q of a row with index a is q * FP[a] in
# 1/4096 of its channel's step).
ADJUST_FIXED_POINT = np.array([4096, 4871, 5793, 6889, 8192, 9742, 11585, 13777], dtype=np.int64)
ADJUST_FIXED_POINT.setflags(write=False)
# The scale level of a prior-coded value of a row with index a is max(0, level - shift[a]): a
# step 2^(a/4) times coarser narrows the distribution by as many levels (5.17 levels per octave).
ADJUST_LEVEL_SHIFT = np.array([0, 1, 3, 4, 5, 6, 8, 9], dtype=np.int64)
ADJUST_LEVEL_SHIFT.setflags(write=False)


def _round_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """floor((num + floor(den / 2)) / den) for den >= 1 (int64)."""
    return (num + den // 2) // den


def prior_mean_in_steps(prior_mean: np.ndarray, adjust: np.ndarray) -> np.ndarray:
    """int64 [n, M]: the prior means [M] (or [1, M]) in the steps of rows with step-adjustment
    indices ``adjust`` [n]: floor((mean * 4096 + floor(FP[a] / 2)) / FP[a]) (clause 11.8)."""
    prior_mean = np.asarray(prior_mean, np.int64).reshape(1, -1)
    return _round_div(prior_mean * ADJUST_FIXED_POINT[0], ADJUST_FIXED_POINT[adjust][:, None])


def prior_level_in_steps(level, adjust):
    """max(0, level - ADJUST_LEVEL_SHIFT[a]) (clause 11.8), broadcast: levels [M] (or [1, M]) and
    indices [n, 1] give [n, M]; a scalar index lowers every level alike."""
    return np.maximum(np.asarray(level, np.int64) - ADJUST_LEVEL_SHIFT[adjust], 0)


def adjusted_prior(prior: CodingParams, adjust: np.ndarray) -> CodingParams:
    """The per-channel prior of rows with step-adjustment indices ``adjust`` [n]: the mean and the
    level in the rows' steps. -> arrays [n, M]."""
    return CodingParams(prior_mean_in_steps(prior.mean, adjust),
                        prior_level_in_steps(np.asarray(prior.level).reshape(1, -1), adjust[:, None]))


def neighbour_means_and_buckets(q: np.ndarray, neighbours: np.ndarray, num_buckets: int, neighbour_mean: np.ndarray,
                                prior_mean: np.ndarray, adjust: np.ndarray | None = None,
                                row_adjust: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and activity bucket of each value of a LoD's rows from their neighbours' decoded
    values ``q`` [N, M] (int64; rows of coarser LoDs filled). ``neighbour_mean`` bool [M]: the
    channels whose mean is the neighbours'; ``prior_mean`` int64 [M]: the others'. With step
    adjustment (clause 11.8), ``adjust`` int64 [N] holds every row's index and ``row_adjust``
    [n_l] the LoD's rows': the neighbours' values are taken in fixed point (q * FP[a], 1/4096 of a
    step), their mean and spread in the row's own steps (F = FP of the row's index); without it
    F = 1 and the values are q itself: the same formulas. |q| <= 2^40, FP < 2^14 and k <= 32 keep
    every sum within 2^59. -> int64 [n_l, M] each."""
    valid = neighbours >= 0
    n = valid.sum(axis=1, keepdims=True).astype(np.int64)  # >= 1
    if n.size and int(n.min()) == int(n.max()):
        n = n[0, 0]  # every row has as many: a scalar divisor (numpy divides by one 10x faster than by a column)
    safe = np.where(valid, neighbours, 0)
    unit = None if adjust is None else ADJUST_FIXED_POINT[row_adjust][:, None]  # F (None: 1)
    own_prior = prior_mean[None, :] if row_adjust is None else prior_mean_in_steps(prior_mean, row_adjust)
    factor = None if adjust is None else ADJUST_FIXED_POINT[adjust[safe]]  # [n_l, k]: each neighbour's FP
    total, spread = _neighbour_sum_and_spread(q, safe, valid, factor)
    den = n if unit is None else n * unit
    mean = np.where(neighbour_mean[None, :], (total + den // 2) // den, own_prior)  # floor division
    if unit is not None:
        spread //= unit
    return mean, np.minimum(escape_class(spread), num_buckets - 1)  # escape_class(a) = bit_length(a)


def _neighbour_sum_and_spread(q: np.ndarray, safe: np.ndarray, valid: np.ndarray,
                              factor: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Sum and max - min over each row's valid neighbours of their values (in fixed point with step
    adjustment: times ``factor`` [n_l, k], each neighbour's FP), one neighbour column at a time:
    [n_l, M] arrays throughout (a reduction over the k axis of an [n_l, k, M] gather took twice as
    long). ``q`` may be int32 (the encoder's RDOQ values, within 2^26): the sums stay within it, and
    the fill of a missing neighbour is an int64 (a Python int would be cast to q's dtype and wrap)."""
    big = np.int64(np.iinfo(np.int64).max)
    every = bool(valid.all())
    total = hi = lo = None
    for j in range(safe.shape[1]):
        v = np.take(q, safe[:, j], axis=0)  # q[safe[:, j]], gathered many times faster
        if factor is not None:
            v = v * factor[:, j, None]
        ok = None if every else valid[:, j, None]
        add, vh, vl = (v, v, v) if ok is None else (np.where(ok, v, 0), np.where(ok, v, -big), np.where(ok, v, big))
        if total is None:
            total, hi, lo = add.copy(), vh.copy(), vl.copy()
        else:
            assert hi is not None and lo is not None
            total += add
            np.maximum(hi, vh, out=hi)
            np.minimum(lo, vl, out=lo)
    assert total is not None and hi is not None and lo is not None, "at least one neighbour slot"
    return total, hi - lo


# rows per block of lod_coding_params: a block's [rows, M] int64 temporaries (the neighbours' values, their sum
# and extremes, the mean, the bucket) stay a few MB each, where a whole LoD's were 40 MB each (86k rows at SH
# degree 3: 190 MB at once) and slower out of the cache; each row's parameters are its own
LOD_BLOCK_ROWS = 8192


def lod_coding_params(q: np.ndarray, neighbours: np.ndarray, bucket_level: np.ndarray, num_buckets: int,
                      neighbour_mean: np.ndarray, prior_mean: np.ndarray, adjust: np.ndarray | None = None,
                      row_adjust: np.ndarray | None = None) -> CodingParams:
    """Mean and scale level (``bucket_level`` int64 [M, B] at the value's bucket) of each value
    of a LoD's rows (neighbour_means_and_buckets), in blocks of rows."""
    n = neighbours.shape[0]
    if n <= LOD_BLOCK_ROWS:
        return _lod_block_params(q, neighbours, bucket_level, num_buckets, neighbour_mean, prior_mean, adjust,
                                 row_adjust)
    mean = np.empty((n, q.shape[1]), np.int64)
    level = np.empty((n, q.shape[1]), np.int64)
    for lo in range(0, n, LOD_BLOCK_ROWS):
        hi = min(n, lo + LOD_BLOCK_ROWS)
        p = _lod_block_params(q, neighbours[lo:hi], bucket_level, num_buckets, neighbour_mean, prior_mean, adjust,
                              None if row_adjust is None else row_adjust[lo:hi])
        mean[lo:hi], level[lo:hi] = p.mean, p.level
    return CodingParams(mean, level)


def _lod_block_params(q: np.ndarray, neighbours: np.ndarray, bucket_level: np.ndarray, num_buckets: int,
                      neighbour_mean: np.ndarray, prior_mean: np.ndarray, adjust: np.ndarray | None,
                      row_adjust: np.ndarray | None) -> CodingParams:
    mean, bucket = neighbour_means_and_buckets(q, neighbours, num_buckets, neighbour_mean, prior_mean, adjust,
                                               row_adjust)
    level = np.take_along_axis(bucket_level.T, bucket, axis=0) if bucket.size else np.zeros(bucket.shape, np.int64)
    return CodingParams(mean, level)


# --- the attribute unit of a tile coded with neighbour prediction ---------------------------

def chunk_segments(h: AttributeUnitHeader, graph: NeighbourGraph):
    """(LoD, first and last+1 index into the LoD's rows) of each chunk, in stream order: each
    LoD's rows are cut into chunks of rows_per_chunk on their own (clause 7.3.12)."""
    rpc = h.rows_per_chunk
    for level, rows in enumerate(graph.rows):
        for lo in range(0, rows.size, rpc):
            yield level, lo, min(rows.size, lo + rpc)


def _lod_params(level: int, q: np.ndarray, graph: NeighbourGraph, prior: CodingParams, table: np.ndarray,
                flags: np.ndarray, num_buckets: int) -> CodingParams:
    if level == 0:
        return prior
    return lod_coding_params(q, graph.neighbours_of(level), table, num_buckets, flags, prior.mean[0])


def _adjusted_chunk_params(level: int, lo: int, hi: int, q: np.ndarray, graph: NeighbourGraph, prior: CodingParams,
                           table: np.ndarray, flags: np.ndarray, num_buckets: int, adjust: np.ndarray) -> CodingParams:
    """With step adjustment (clause 11.8): the parameters of rows lo..hi-1 of the LoD, each in its
    own steps (``adjust``: every row's index, those of coarser LoDs and of these rows filled)."""
    rows = graph.rows[level][lo:hi]
    if level == 0:
        return adjusted_prior(prior, adjust[rows])
    return lod_coding_params(q, graph.neighbours_of(level)[lo:hi], table, num_buckets, flags, prior.mean[0], adjust,
                             adjust[rows])


def _adjust_levels(h: AttributeUnitHeader, n: int) -> np.ndarray:
    return np.full((n, 1), h.adjust_level, dtype=np.int64)


def chunk_neighbours(graph: NeighbourGraph, level: int, lo: int, hi: int) -> np.ndarray | None:
    """The neighbours of rows lo..hi-1 of LoD ``level`` (None for LoD 0, which has none)."""
    return None if level == 0 else graph.neighbours_of(level)[lo:hi]


def chunk_coded_channels(layout, row_degrees: np.ndarray) -> np.ndarray | None:
    """The coded channels of a chunk's rows (clause 11.9); None when every channel of every row is
    coded (the rows all have D = d), so that the symbols take the paths without a mask."""
    if not row_degrees.size or int(row_degrees.min()) == layout.sh_degree:
        return None
    return coded_channels(layout.sh_channels, layout.num_channels, row_degrees)


def _check_chunk_options(h: AttributeUnitHeader, adjust, degrees, degree_unit) -> None:
    if (adjust is not None) != bool(h.step_adjust_present):
        raise ValueError("step-adjustment indices must be given exactly when the header has StepAdjustPresent")
    if (degrees is not None) != bool(h.sh_degree_present) or (degrees is None) != (degree_unit is None):
        raise ValueError("SH degrees and the sh_degree unit must be given exactly when the header has "
                         "ShDegreePresent")


def write_predicted_attribute_unit(h: AttributeUnitHeader, layout, q: np.ndarray, graph: NeighbourGraph,
                                   unit: NeighbourPredictionUnit,
                                   prediction: ChannelPrediction | None = None,
                                   adjust: np.ndarray | None = None, degrees: np.ndarray | None = None,
                                   degree_unit: ShDegreeUnit | None = None,
                                   step_flags: StepAdjustFlagsUnit | None = None, lod_params=None) -> bytes:
    """Code q [N, M] (rows in the tile's normative order) LoD by LoD; LoD 0 with the header's
    per-channel prior. Fills the header's chunk sizes (and cross-channel prediction entries).
    ``lod_params(level)`` (informative, without step adjustment): the CodingParams of LoD ``level``
    >= 1's rows that lod_coding_params gives, where the encoder has them already (None: made here).
    ``adjust``: each row's step-adjustment index (h.step_adjust_present, with the header's
    adjust_mean and adjust_level set), coded in a chunk before each chunk of values (as flags with the
    stream's ``step_flags`` unit, version 1.5, the header's adjust_mean and adjust_level 0). ``degrees``:
    each row's SH degree (h.sh_degree_present, with the stream's ``degree_unit``), coded in a chunk
    before each chunk of values, which then holds only the rows' coded channels (the values of the
    others must be 0 in q)."""
    prediction = prediction or ChannelPrediction.none()
    if h.channel_prediction_allowed:
        prediction.to_header(h)
    _check_chunk_options(h, adjust, degrees, degree_unit)
    h.num_lods = unit.num_lods
    table, prior = level_table(unit), prior_params(h)
    chunks: list[bytes] = []
    h.mask_chunk_size, h.adjust_chunk_size, h.degree_chunk_size, h.chunk_size = [], [], [], []
    params = None
    for level, lo, hi in chunk_segments(h, graph):
        rows = graph.rows[level][lo:hi]
        if adjust is not None:
            chunks.append(encode_adjust_chunk(adjust, rows, h, graph, level, lo, hi, step_flags))
            h.adjust_chunk_size.append(len(chunks[-1]))
            p = _adjusted_chunk_params(level, lo, hi, q, graph, prior, table, mean_flags(unit), unit.num_buckets,
                                       adjust)
        else:
            if lo == 0:
                params = _lod_params(level, q, graph, prior, table, mean_flags(unit), unit.num_buckets) \
                    if level == 0 or lod_params is None else lod_params(level)
            assert params is not None  # a LoD's first chunk starts at row 0 (chunk_segments)
            p = params.rows(lo, hi, layout.num_channels)
        coded = None
        if degrees is not None:
            assert degree_unit is not None  # _check_chunk_options: degrees come with the stream's sh_degree unit
            nd = neighbour_degrees(chunk_neighbours(graph, level, lo, hi), degrees)
            chunks.append(encode_degree_chunk(degrees[rows], nd, degree_unit))
            h.degree_chunk_size.append(len(chunks[-1]))
            coded = chunk_coded_channels(layout, degrees[rows])
        chunks.append(encode_residual_chunk(prediction.residuals(q[rows], p.mean, coded), p.level, coded))
        h.chunk_size.append(len(chunks[-1]))
    return h.to_bytes() + b"".join(chunks)


def chunk_piece_sizes(h: AttributeUnitHeader) -> list[int]:
    """The sizes of the unit's chunk data in stream order: per chunk, [its step-adjustment data],
    [its SH-degree data], then its symbol data (clause 7.3.5)."""
    columns = [h.adjust_chunk_size] * bool(h.step_adjust_present) + [h.degree_chunk_size] * bool(h.sh_degree_present)
    return [x for sizes in zip(*columns, h.chunk_size) for x in sizes]


def _decode_chunk_degrees(piece: bytes, graph: NeighbourGraph, level: int, lo: int, hi: int, degrees: np.ndarray,
                          unit: ShDegreeUnit, layout, i: int) -> np.ndarray | None:
    """Chunk i's SH degrees into ``degrees`` (clause 11.9) -> its rows' coded channels (None: all)."""
    nd = neighbour_degrees(chunk_neighbours(graph, level, lo, hi), degrees)
    d = decode_degree_chunk(piece, hi - lo, nd, unit, f"SH-degree chunk {i}")
    degrees[graph.rows[level][lo:hi]] = d
    return chunk_coded_channels(layout, d)


def encode_adjust_chunk(adjust: np.ndarray, rows: np.ndarray, h: AttributeUnitHeader, graph: NeighbourGraph, level: int,
                        lo: int, hi: int, flags: StepAdjustFlagsUnit | None) -> bytes:
    """The step-adjustment data of the chunk of rows lo..hi-1 of LoD ``level`` (``adjust``: every
    row's index): symbols around the header's adjust_mean, or with a step_adjust_flags unit
    (version 1.5) flags "a >= b" in the contexts of the rows' neighbours' indices (clause 11.8)."""
    if flags is None:
        return encode_symbols(adjust[rows, None] - h.adjust_mean, _adjust_levels(h, rows.size))
    nd = neighbour_degrees(chunk_neighbours(graph, level, lo, hi), adjust)
    return encode_flag_chunk(adjust[rows], nd, flags.max_step_adjust, step_flag_weights(flags))


def step_flag_weights(flags: StepAdjustFlagsUnit) -> np.ndarray:
    """The flag models [max_step_adjust, 6, 2] of a step_adjust_flags unit (clause 7.3.16)."""
    return flag_weights(flags.step_flag_prob, flags.max_step_adjust)


def check_flag_header(h: AttributeUnitHeader, what: str) -> None:
    """With a step_adjust_flags unit the header's adjust_mean and adjust_level are 0 (clause 7.3.5, E67)."""
    if h.adjust_mean or h.adjust_level:
        raise BitstreamError(f"{what}: adjust_mean {h.adjust_mean} and adjust_level {h.adjust_level} in a stream with "
                             "a step_adjust_flags unit, where both shall be 0 (clause 7.3.5)", condition="E67")


def decode_adjust_chunk(piece: bytes, h: AttributeUnitHeader, step_adjust: StepAdjustUnit, num_rows: int,
                        i: int, flags: StepAdjustFlagsUnit | None = None, nd: np.ndarray | None = None) -> np.ndarray:
    """The step-adjustment indices (int64 [num_rows]) of chunk i (clause 11.8; above max_step_adjust: E65);
    with the stream's step_adjust_flags unit ``flags`` (version 1.5) decoded as flags, ``nd`` the
    indices of the rows' neighbours (None: LoD 0)."""
    if flags is not None:
        return decode_flag_chunk(piece, num_rows, nd, flags.max_step_adjust, step_flag_weights(flags),
                                 f"step-adjustment flags chunk {i}")
    a = decode_symbols(piece, _adjust_levels(h, num_rows), f"step-adjustment chunk {i}")[:, 0] + h.adjust_mean
    if a.size and (a.min() < 0 or a.max() > step_adjust.max_step_adjust):
        raise BitstreamError(f"step-adjustment chunk {i}: an index is outside [0, max_step_adjust = "
                             f"{step_adjust.max_step_adjust}]", condition="E65")
    return a


def _check_predicted_header(h: AttributeUnitHeader, coords: np.ndarray, what: str,
                            step_flags: StepAdjustFlagsUnit | None) -> None:
    """The header of a tile's neighbour-predicted attribute unit against the tile and the stream
    (clauses 7.3.5, 8.1, 8.3)."""
    n = coords.shape[0]
    if h.attribute_level != LEVEL_ALL:
        raise BitstreamError(f"{what}: attribute_level {h.attribute_level} where level 0 is expected", condition="E45")
    if step_flags is not None:
        check_flag_header(h, what)
    assert h.num_rows_minus1 is not None  # parsed
    if h.num_rows_minus1 + 1 != n:  # clause 8.3 rule 8
        raise BitstreamError(f"{what}: num_rows_minus1 + 1 = {h.num_rows_minus1 + 1}, but the tile has {n} rows", condition="E59")
    if h.context_model_id != CONTEXT_PER_CHANNEL_PRIOR:
        raise BitstreamError(f"{what}: context_model_id {h.context_model_id}; a stream with neighbour prediction "
                             "codes LoD 0 with the per-channel prior (context_model_id 0)", condition="E62")
    why = check_extent(coords, what)
    if why:
        raise BitstreamError(why, condition="E64")


def read_predicted_attribute_unit(payload: bytes, layout, steps: np.ndarray, coords: np.ndarray,
                                  unit: NeighbourPredictionUnit, values_out: np.ndarray,
                                  trace: list[TraceEntry] | None = None, on_chunk=None,
                                  step_adjust: StepAdjustUnit | None = None,
                                  sh_degree: ShDegreeUnit | None = None,
                                  step_flags: StepAdjustFlagsUnit | None = None) -> AttributeUnitHeader:
    """Parse and decode the attribute unit of a tile of ``coords`` (normative order) coded with
    neighbour prediction (clause 13.2 with 11.7): the values of row i go to values_out[i]. With
    the stream's ``step_adjust`` unit, each chunk of values follows the chunk of its rows'
    step-adjustment indices (clause 11.8; as flags with its ``step_flags`` unit, version 1.5); with
    its ``sh_degree`` unit, the chunk of their SH degrees (clause 11.9)."""
    n = coords.shape[0]
    what = "attribute unit (neighbour prediction)"
    reader = BitReader(payload, what)
    h = AttributeUnitHeader.parse(reader, trace, num_channels=layout.num_channels, num_offsets=layout.num_offsets,
                                  offset_mask_present=layout.offset_mask_present,
                                  channel_prediction_allowed=layout.channel_prediction_allowed, num_rows=n,
                                  num_lods=unit.num_lods, step_adjust_present=int(step_adjust is not None),
                                  sh_degree_present=int(sh_degree is not None))
    _check_predicted_header(h, coords, what, step_flags)
    prediction = ChannelPrediction.from_header(h, what)
    graph = neighbour_graph(coords, unit.num_lods, unit.num_neighbours)
    table, prior = level_table(unit), prior_params(h)
    pieces = iter(split_chunks(payload[reader.bit_position // 8:], chunk_piece_sizes(h), what))
    q_all = np.zeros((n, layout.num_channels), dtype=np.int64)
    adjust = None if step_adjust is None else np.zeros(n, dtype=np.int64)
    degrees = None if sh_degree is None else np.zeros(n, dtype=np.int64)
    params = None
    for i, (level, lo, hi) in enumerate(chunk_segments(h, graph)):
        rows = graph.rows[level][lo:hi]
        row_adjust = None
        if adjust is not None:
            assert step_adjust is not None  # adjust exists with the step_adjust unit (above)
            nd = None if step_flags is None else neighbour_degrees(chunk_neighbours(graph, level, lo, hi), adjust)
            a = decode_adjust_chunk(next(pieces), h, step_adjust, hi - lo, i, step_flags, nd)
            adjust[rows] = a
            row_adjust = a[:, None]
            p = _adjusted_chunk_params(level, lo, hi, q_all, graph, prior, table, mean_flags(unit),
                                       unit.num_buckets, adjust)
        else:
            if lo == 0:
                params = _lod_params(level, q_all, graph, prior, table, mean_flags(unit), unit.num_buckets)
            assert params is not None  # a LoD's first chunk starts at row 0 (chunk_segments)
            p = params.rows(lo, hi, layout.num_channels)
        coded = None
        if degrees is not None:
            assert sh_degree is not None  # degrees exist with the sh_degree unit (above)
            coded = _decode_chunk_degrees(next(pieces), graph, level, lo, hi, degrees, sh_degree, layout, i)
        q = decode_chunk_values(next(pieces), h, layout, p, prediction, None, hi - lo, i, LEVEL_ALL, coded)
        q_all[rows] = q
        target = np.empty((hi - lo, layout.num_channels), np.float32)
        reconstruct_chunk(q, steps, row_adjust, target, i, LEVEL_ALL, layout)
        values_out[rows] = target
        if on_chunk is not None:
            on_chunk(hi - lo)
    return h
