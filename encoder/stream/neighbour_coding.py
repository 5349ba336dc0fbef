"""Neighbour prediction in the encoder (informative; the prediction is normative,
common/neighbour_prediction.py, spec clause 11.7).

The encoder chooses the unit's table: for each channel and activity bucket, the scale level
that codes the residuals of that bucket (over every LoD >= 1) in the fewest bits; LoD 0 gets
the per-channel prior as without the tool. Cross-channel prediction (clause 11.6) is fitted on
the deviations from the neighbours' means, then the table and the prior are chosen again for
the residuals it leaves. The tool is used only where it codes smaller than the per-channel
prior alone (a scene it does not help pays nothing for it).

Measured on the real scenes' streams at their own steps (tools/results/neighbour_prediction.md):
the donut's attributes -15 to -20%, playbot's -0.3 to -2% (its Gaussians are far apart).
"""

from __future__ import annotations

import functools

import numpy as np

from ...common import attributes as attr
from ...common.entropy.symbol_coder import best_level, code_lengths_bits, level_and_bits
from ..context.code_lengths import ResidualHistograms, ideal_code_length_bits, ideal_code_length_bits_by_rows
from ...common.entropy.scale_levels import NUM_SCALE_LEVELS
from ...common.neighbour_prediction import (ADJUST_FIXED_POINT, NeighbourGraph, check_extent, level_table,
                                           mean_flags, neighbour_graph, neighbour_means_and_buckets,
                                           prior_level_in_steps, prior_mean_in_steps,
                                           write_predicted_attribute_unit)
from ...common.attributes import NUM_STEP_ADJUST
from ...common.container import UNIT_CRC_BYTES, UNIT_HEADER_BYTES
from ...common.sh_degree import FLAG_PROB_UNIT, band_flags, coded_channels, neighbour_degrees
from ...common.units import (DEGREE_PROB_BITS, NUM_DEGREE_CONTEXTS, PRIOR_MEAN_MAX, NeighbourPredictionUnit, ShDegreeUnit,
                             StepAdjustFlagsUnit)
from .memory import CODING_BLOCK_ROWS
from .prediction import fit_rows, fit_sampled_prediction

UNIT_FRAMING_BYTES = UNIT_HEADER_BYTES + UNIT_CRC_BYTES


def _coding_params(q: np.ndarray, graph: NeighbourGraph, num_buckets: int, prior_mean: np.ndarray,
                   adjust: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per row: the neighbours' mean of each channel (LoD 0: the prior's) and its activity bucket
    (LoD 0: -1). ``adjust``: every row's step-adjustment index (clause 11.8), or None. A block of
    a LoD's rows at a time (each row's from its own neighbours: peak memory)."""
    n, m = q.shape
    mean = prior_rows(prior_mean, n, adjust, _means_dtype(q))
    bucket = np.full((n, m), -1, dtype=BUCKET_DTYPE)
    every = np.ones(m, dtype=bool)
    for level in range(1, len(graph.rows)):
        for block in row_blocks(graph.rows[level].size):
            rows = graph.rows[level][block]
            mean[rows], bucket[rows] = neighbour_means_and_buckets(
                q, graph.neighbours[level][block], num_buckets, every, prior_mean, adjust,
                None if adjust is None else adjust[rows])
    return mean, bucket


def _means_dtype(q: np.ndarray) -> type[np.integer]:
    """int32 where it holds every mean of the values ``q``: a neighbours' mean is within 4 x their
    largest |q| (in another row's steps, 2^(7/4) at most: clause 11.8), the prior's within
    PRIOR_MEAN_MAX; int64 otherwise. Half the bytes of the coding's [N, M] means."""
    top = max(int(q.max()), -int(q.min())) if q.size else 0
    return np.int32 if 4 * top < PRIOR_MEAN_MAX else np.int64


def row_blocks(n: int):
    """Slices of CODING_BLOCK_ROWS rows covering 0 .. n - 1 (working arrays a block at a time)."""
    return (slice(lo, min(lo + CODING_BLOCK_ROWS, n)) for lo in range(0, n, CODING_BLOCK_ROWS))


# The activity buckets (-2 .. 15: prediction_buckets <= 16) in one byte each: 8x less memory than int64
BUCKET_DTYPE = np.int8
# The scale levels (0 .. 63) of a coding's values in one byte each
LEVEL_DTYPE = np.uint8


def prior_rows(prior_mean: np.ndarray, n: int, adjust: np.ndarray | None, dtype=np.int64) -> np.ndarray:
    """[n, M] of ``dtype`` (int64, or int32 where it holds the means: _means_dtype): the prior mean in
    each row's steps."""
    if adjust is None:
        return np.broadcast_to(prior_mean, (n, prior_mean.size)).astype(dtype)
    return prior_mean_in_steps(prior_mean, adjust).astype(dtype, copy=False)


def best_prior_level(r: np.ndarray, adjust: np.ndarray | None) -> int:
    """The prior level that codes one channel's residuals ``r`` of LoD 0 in the fewest bits, each
    row's level lowered by its step adjustment's shift."""
    if adjust is None or not adjust.any():
        return best_level(r)
    costs = np.empty(NUM_SCALE_LEVELS)
    # several levels per call (a call per level was most of a search trial's prior levels at SH 3); each
    # row of bits summed alone, as np.sum sums a 1-D array (pairwise along the row): the same costs
    per = max(1, min(NUM_SCALE_LEVELS, PRIOR_LEVEL_VALUES // max(r.size, 1)))
    for lo in range(0, NUM_SCALE_LEVELS, per):
        lv = np.arange(lo, min(lo + per, NUM_SCALE_LEVELS))[:, None]
        costs[lv[:, 0]] = code_lengths_bits(np.broadcast_to(r, (lv.size, r.size)),
                                            prior_level_in_steps(lv, adjust[None, :])).sum(axis=1)
    return int(np.argmin(costs))


# The code lengths best_prior_level makes at once (levels x rows): 8 MB of float64
PRIOR_LEVEL_VALUES = 1 << 20


def _total_bits(per_bucket: list[np.ndarray | None]) -> float:
    """The ideal bits of a channel with the best level per bucket (summed in bucket order)."""
    total = 0.0
    for bits in per_bucket:
        if bits is not None:
            total += level_and_bits(bits)[1]
    return total


def _best_levels(per_bucket: list[np.ndarray | None]) -> np.ndarray:
    """The best level of each bucket (0 where it is empty)."""
    return np.array([0 if bits is None else level_and_bits(bits)[0] for bits in per_bucket], dtype=np.int64)


def _flags_and_table(q: np.ndarray, neighbour_mean: np.ndarray, prior_mean: np.ndarray, bucket: np.ndarray,
                     num_buckets: int, choose: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: whether the neighbours' mean codes it in fewer bits than the prior's (noisy
    channels, e.g. higher SH bands of a sparse scene, are not predicted by their neighbours;
    ``choose`` False: every channel's mean the neighbours'), and the best scale level of each
    bucket's residuals from the mean chosen (int64 [M, B]). One histogram per channel, bucket and
    mean serves both, gathered a block of rows at a time, every channel at once (the bits of each
    bucket are best_level_and_bits's of its rows to the last bit; buckets -1 and -2, LoD 0 and the
    values not coded, count in none)."""
    n, m = q.shape
    groups = num_buckets + 2  # buckets -2 .. num_buckets - 1
    prior = np.broadcast_to(prior_mean, q.shape)  # [M] or, with step adjustment, [N, M]
    by_mean, by_prior = ResidualHistograms(m * groups), ResidualHistograms(m * groups)
    first = np.arange(m)[None, :] * groups + 2  # each channel's bucket 0
    for block in row_blocks(n):
        group = first + bucket[block]
        by_mean.add(group, q[block] - neighbour_mean[block])
        if choose:
            by_prior.add(group, q[block] - prior[block])
    flags, table = np.ones(m, dtype=bool), np.zeros((m, num_buckets), dtype=np.int64)
    for c in range(m):
        chosen = [by_mean.bits(c * groups + 2 + b) for b in range(num_buckets)]
        if choose:
            with_prior = [by_prior.bits(c * groups + 2 + b) for b in range(num_buckets)]
            flags[c] = _total_bits(chosen) < _total_bits(with_prior)
            chosen = chosen if flags[c] else with_prior
        table[c] = _best_levels(chosen)
    return flags, table


def flag_counts(graph: NeighbourGraph, values: np.ndarray, levels: int) -> np.ndarray:
    """int64 [levels, NumDegreeContexts, 2]: how many flags "value >= b" of each b and context are 0 and 1
    (clause 11.9's SH degrees, or clause 11.8's step-adjustment indices as flags; a flag's context
    depends on its row's neighbours only, not on the chunking)."""
    counts = np.zeros((levels, NUM_DEGREE_CONTEXTS, 2), np.int64)
    for level, rows in enumerate(graph.rows):
        nd = neighbour_degrees(graph.neighbours[level], values) if level else None
        for band, x, flags in band_flags(values[rows], nd, levels):
            counts[band - 1] += np.bincount(2 * x + flags, minlength=2 * NUM_DEGREE_CONTEXTS).reshape(-1, 2)
    return counts


def flag_probabilities(counts: np.ndarray) -> list[int]:
    """The probabilities (u(12) each, (b - 1) * 6 + x) that code the counted flags in the fewest bits:
    f[1] = 4096 p + 2048 nearest the flags' share of ones (p = floor(4096 * ones / flags)); 2048
    where a context has no flag."""
    total = counts.sum(axis=2)
    top = (1 << DEGREE_PROB_BITS) - 1
    p = np.where(total > 0, np.minimum((counts[..., 1] << DEGREE_PROB_BITS) // np.maximum(total, 1), top), 1 << 11)
    return [int(x) for x in p.ravel()]


def degree_unit_of(counts: np.ndarray) -> ShDegreeUnit:
    """The sh_degree unit of the counted SH-degree flags (flag_probabilities)."""
    return ShDegreeUnit(sh_degree=counts.shape[0], degree_flag_prob=flag_probabilities(counts))


def flag_bits(counts: np.ndarray, probs) -> float:
    """The ideal code length of the counted flags with the probabilities ``probs``."""
    f1 = FLAG_PROB_UNIT * np.asarray(probs, np.float64).reshape(counts.shape[:2]) + FLAG_PROB_UNIT / 2
    p1 = f1 / (FLAG_PROB_UNIT << DEGREE_PROB_BITS)
    return float(-(counts[..., 1] * np.log2(p1)).sum() - (counts[..., 0] * np.log2(1 - p1)).sum())


def unit_bytes(unit) -> int:
    """The bytes of a parameter unit in the stream, its header and CRC included."""
    return UNIT_FRAMING_BYTES + len(unit.to_bytes())


def _levels(bucket: np.ndarray, table: np.ndarray, prior_level: np.ndarray, adjust: np.ndarray | None = None
            ) -> np.ndarray:
    """The scale level of each value: its bucket's in ``table``, the prior's in LoD 0 (a block of rows at
    a time: peak memory)."""
    out = np.empty(bucket.shape, dtype=LEVEL_DTYPE)
    for block in row_blocks(bucket.shape[0]):
        prior = prior_level[None, :] if adjust is None else \
            prior_level_in_steps(prior_level[None, :], adjust[block, None])
        b = bucket[block]
        out[block] = np.where(b >= 0, np.take_along_axis(table.T, np.maximum(b, 0), axis=0), prior)
    return out


def _chosen_means(neighbour_mean: np.ndarray, own_prior: np.ndarray, flags: np.ndarray,
                  bucket: np.ndarray) -> np.ndarray:
    """``neighbour_mean`` turned in place into each value's mean: the neighbours' where its channel's
    flag is set and its row has neighbours (bucket >= 0), else the prior's (no second [N, M] array)."""
    prior = np.broadcast_to(own_prior, neighbour_mean.shape)
    for block in row_blocks(neighbour_mean.shape[0]):
        np.copyto(neighbour_mean[block], prior[block], where=~(flags[None, :] & (bucket[block] >= 0)))
    return neighbour_mean


class NeighbourCoding:
    """The neighbour prediction of one tile (or scene): its graph, the means and buckets, the
    fitted unit, prior and cross-channel prediction. ``adjust``: each row's step-adjustment
    index (clause 11.8), None without the tool. ``choose_mean_flags`` False: every channel's mean
    from its neighbours, for estimates that need no unit."""

    def __init__(self, q: np.ndarray, coords: np.ndarray, num_lods: int, num_neighbours: int, num_buckets: int,
                 channel_prediction: bool, layout, unit: NeighbourPredictionUnit | None = None,
                 graph: NeighbourGraph | None = None, adjust: np.ndarray | None = None,
                 choose_mean_flags: bool = True, degrees: np.ndarray | None = None, step_flags_allowed: bool = True):
        n, m = q.shape
        self.graph = graph if graph is not None else neighbour_graph(coords, num_lods, num_neighbours)
        self._set_degrees(degrees, layout, unit)
        if self.coded is not None:
            q = q * self.coded  # a value not coded is q = 0, also in its neighbours' sums (clause 11.9)
        self.q, self.layout, self.adjust = q, layout, adjust
        self._given_unit, self._step_flags_allowed = unit, step_flags_allowed
        self._counts: tuple[int, np.ndarray] | None = None  # (top, flag_counts of the indices up to top)
        lod0 = self.graph.rows[0]
        a0 = None if adjust is None else adjust[lod0]
        base = q[lod0] if adjust is None else q[lod0] * ADJUST_FIXED_POINT[a0][:, None] / ADJUST_FIXED_POINT[0]
        prior_mean = np.clip(np.rint(self._medians(base)), -PRIOR_MEAN_MAX, PRIOR_MEAN_MAX).astype(np.int64)
        neighbour_mean, bucket = _coding_params(q, self.graph, num_buckets, prior_mean, adjust)
        own_prior = prior_mean[None, :] if adjust is None else prior_mean_in_steps(prior_mean, adjust)
        fit_bucket = bucket if self.coded is None else np.where(self.coded, bucket, -2)  # fits: coded values only
        if unit is not None:
            flags, table = mean_flags(unit), level_table(unit)
        else:  # choose_mean_flags False: every channel from its neighbours (a quick estimate, no flags to fit)
            flags, table = _flags_and_table(q, neighbour_mean, own_prior, fit_bucket, num_buckets, choose_mean_flags)
        self._mean, self._bucket = _chosen_means(neighbour_mean, own_prior, flags, bucket), bucket
        del neighbour_mean  # (now the chosen means)
        self.prediction = attr.ChannelPrediction.none()
        if channel_prediction and layout.channel_prediction_allowed:
            self.prediction = self._fitted_prediction(q, self._mean, bucket, table, own_prior, a0)
        if unit is None:
            unit = self._fitted_unit(flags, table, fit_bucket, num_lods, num_neighbours)
        self.unit = unit
        self.prior_mean = prior_mean
        self.prior_level = self._prior_levels(self._residuals_of(lod0), a0)

    def _residuals_of(self, rows) -> np.ndarray:
        """int64: the residuals of ``rows`` (a slice or indices)."""
        if self._mean is None:  # dropped once the residuals were made
            return self.residuals[rows]
        coded = None if self.coded is None else self.coded[rows]
        return self.prediction.residuals(self.q[rows], self._mean[rows], coded)

    @functools.cached_property
    def residuals(self) -> np.ndarray:
        """int64 [N, M]: every value's residual, made when first asked for (RDOQ's fit of the unit and the
        whole-scene coding's ideal bits take none: they make a block of rows' at a time); the means are
        dropped then."""
        r = np.empty(self.q.shape, dtype=np.int64)
        for block in row_blocks(r.shape[0]):
            r[block] = self._residuals_of(block)
        self._mean = None
        return r

    @functools.cached_property
    def levels(self) -> np.ndarray:
        """uint8 [N, M]: every value's scale level, made when first asked for (RDOQ's fit needs none)."""
        return _levels(self._bucket, level_table(self.unit), self.prior_level, self.adjust)

    def _fitted_unit(self, flags: np.ndarray, table: np.ndarray, fit_bucket: np.ndarray, num_lods: int,
                     num_neighbours: int) -> NeighbourPredictionUnit:
        """The unit of ``flags`` and ``table``, the table refitted where the prediction changed the
        residuals (its targets), from their histograms per bucket gathered a block of rows at a time."""
        targets = np.unique(self.prediction.targets)
        m, b = table.shape
        if targets.size:
            hist = ResidualHistograms(targets.size * b)
            group = np.arange(targets.size)[None, :] * b
            for block in row_blocks(self.q.shape[0]):
                fb = fit_bucket[block][:, targets]
                ok = fb >= 0  # (-1: LoD 0, -2: not coded)
                hist.add((group + fb)[ok], self._residuals_of(block)[:, targets][ok])
            for i, c in enumerate(targets):
                table[c] = [hist.best_level(i * b + k) for k in range(b)]
        return NeighbourPredictionUnit(num_channels=m, num_lods_minus1=num_lods - 1,
                                       num_neighbours_minus1=num_neighbours - 1, num_buckets_minus1=b - 1,
                                       neighbour_mean_flag=flags.astype(int).tolist(),
                                       bucket_level=table.ravel().tolist())

    def _fitted_prediction(self, q: np.ndarray, mean: np.ndarray, bucket: np.ndarray, table: np.ndarray,
                           own_prior: np.ndarray, a0: np.ndarray | None) -> attr.ChannelPrediction:
        """The cross-channel prediction of the deviations from ``mean``, fitted on the rows
        prediction.fit_rows draws with the levels ``table`` and the prior give them: only those rows'
        levels and deviations are made (the prior's levels, refitted after it, are not needed)."""
        lod0 = self.graph.rows[0]
        prior0 = self._prior_levels(q[lod0] - np.broadcast_to(own_prior, q.shape)[lod0], a0)
        rows = fit_rows(q.shape[0])
        lv = _levels(bucket[rows], table, prior0, None if self.adjust is None else self.adjust[rows])
        live = np.broadcast_to(True, q.shape) if self.coded is None else self.coded
        return fit_sampled_prediction(q[rows] - mean[rows], lv.astype(np.int64), live[rows], self.layout, q.shape[0])

    def _set_degrees(self, degrees: np.ndarray | None, layout, unit: NeighbourPredictionUnit | None) -> None:
        """Each row's SH degree (clause 11.9) and with it the coded channels, the flags' counts and the
        sh_degree unit: the stream's (``unit``'s context, for a tile), else the one fitted here."""
        self.degrees, self.coded, self.degree_unit, self.degree_counts = None, None, None, None
        if degrees is None:
            return
        self.degrees = np.asarray(degrees, np.int64)
        self.coded = coded_channels(layout.sh_channels, layout.num_channels, self.degrees)
        self.degree_counts = flag_counts(self.graph, self.degrees, layout.sh_degree)
        given = None if unit is None else unit.sh_degree_unit
        self.degree_unit = given if given is not None else degree_unit_of(self.degree_counts)

    def _medians(self, base: np.ndarray) -> np.ndarray:
        """Each channel's median of LoD 0's values ``base`` [n_0, M] (coded values only; 0 where none)."""
        if self.coded is None:
            return np.median(base, axis=0)
        ok = self.coded[self.graph.rows[0]]
        return np.array([np.median(base[ok[:, c], c]) if ok[:, c].any() else 0.0 for c in range(base.shape[1])])

    def _prior_levels(self, r0: np.ndarray, a0: np.ndarray | None) -> np.ndarray:
        """The best prior level of each channel's residuals ``r0`` [n_0, M] of LoD 0's rows (coded values only)."""
        lod0 = self.graph.rows[0]
        out = np.zeros(r0.shape[1], dtype=np.int64)
        for c in range(r0.shape[1]):
            ok = slice(None) if self.coded is None else self.coded[lod0, c]
            out[c] = best_prior_level(r0[:, c][ok], None if a0 is None else a0[ok])
        return out

    def ideal_bits(self) -> float:
        """The ideal bits of the coded values."""
        lv = self.levels  # the residuals and code lengths of a few rows at a time (peak memory)
        return ideal_code_length_bits_by_rows(lambda a, b: self._residuals_of(slice(a, b)), lambda a, b: lv[a:b],
                                              self.q.shape, self.coded)

    def ideal_stream_bits(self) -> float:
        """The ideal bits of the values, their step-adjustment indices, their SH degrees and the
        units that carry the table and the flags' probabilities."""
        units = unit_bytes(self.unit) + sum(unit_bytes(u) for u in (self.degree_unit, self.step_flags) if u is not None)
        return self.ideal_bits() + self.adjust_bits() + self.degree_bits() + 8 * units

    def degree_bits(self) -> float:
        """The ideal bits of the SH-degree flags (0 without them)."""
        return 0.0 if self.degrees is None else flag_bits(self.degree_counts, self.degree_unit.degree_flag_prob)

    @functools.cached_property
    def step_flags(self) -> StepAdjustFlagsUnit | None:
        """Whether the step-adjustment indices are coded as flags (version 1.5, clause 11.8) and with
        which step_adjust_flags unit: the stream's (the given unit's context, for a tile), else the one
        fitted here when the indices cost fewer bits as flags, the unit included, than as symbols
        (computed when first asked for: the RDOQ's codings never ask)."""
        if self.adjust is None:
            return None
        if self._given_unit is not None:
            return self._given_unit.step_flags
        if not self._step_flags_allowed:
            return None
        top = int(self.adjust.max(initial=0))
        flags = StepAdjustFlagsUnit(max_step_adjust=top, step_flag_prob=flag_probabilities(self._flag_counts(top)))
        use = flag_bits(self._flag_counts(top), flags.step_flag_prob) + 8 * unit_bytes(flags) < self._adjust_symbol_bits()
        return flags if use else None

    def _flag_counts(self, top: int) -> np.ndarray:
        """flag_counts of the indices up to ``top`` (computed once per coding)."""
        if self._counts is None or self._counts[0] != top:
            self._counts = (top, flag_counts(self.graph, self.adjust, top))
        return self._counts[1]

    def _symbol_model(self) -> tuple[int, int]:
        """The mean and scale level that code the indices as symbols (clause 11.8)."""
        a = self.adjust
        mean = int(np.clip(np.rint(np.median(a)), 0, NUM_STEP_ADJUST - 1))
        return mean, best_level(a - mean)

    def _adjust_symbol_bits(self) -> float:
        mean, level = self._symbol_model()
        return ideal_code_length_bits(self.adjust - mean, np.full(self.adjust.shape, level, np.int64))

    def adjust_model(self) -> tuple[int, int]:
        """The step-adjustment indices' mean and scale level (the tile's attribute unit header; 0 and
        0 with the indices as flags, clause 7.3.5)."""
        return (0, 0) if self.step_flags is not None else self._symbol_model()

    def adjust_bits(self) -> float:
        """The ideal bits of the step-adjustment indices (0 without them)."""
        if self.adjust is None:
            return 0.0
        if self.step_flags is not None:
            return flag_bits(self._flag_counts(self.step_flags.max_step_adjust), self.step_flags.step_flag_prob)
        return self._adjust_symbol_bits()

    def write(self, header) -> bytes:
        header.prior_mean = self.prior_mean.tolist()
        header.prior_level = self.prior_level.tolist()
        if self.adjust is not None:
            header.step_adjust_present = 1
            header.adjust_mean, header.adjust_level = self.adjust_model()
        header.sh_degree_present = int(self.degrees is not None)
        return write_predicted_attribute_unit(header, self.layout, self.q, self.graph, self.unit, self.prediction,
                                              self.adjust, self.degrees, self.degree_unit, self.step_flags,
                                              None if self._mean is None else self._lod_params)

    def _lod_params(self, level: int) -> attr.CodingParams:
        """The means and scale levels of LoD ``level`` >= 1's rows, those the writer's lod_coding_params
        would make again (the chosen means: the neighbours' where the unit's flag is set, the prior's
        otherwise; the level of the value's bucket in the unit's table)."""
        rows = self.graph.rows[level]
        bucket = self._bucket[rows].astype(np.int64)
        return attr.CodingParams(self._mean[rows], np.take_along_axis(level_table(self.unit).T, bucket, axis=0))


def usable(coords: np.ndarray) -> bool:
    """Whether the points are within the neighbour prediction's extent limit."""
    return check_extent(coords, "scene") is None
