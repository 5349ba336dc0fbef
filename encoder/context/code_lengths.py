"""The encoder's rate estimates (informative): what residuals cost under the scale tables.

The decoder never calls these; common/entropy/symbol_coder.py holds what a writer in common/ needs
too (code_lengths_bits, best_level). Here: the sum of code lengths (ideal_code_length_bits), made
a few rows at a time to the last bit (ideal_code_length_bits_by_rows), histograms of residuals
gathered a part at a time (ResidualHistograms), the level nearest a scale (level_for_sigma) and a
smooth estimate for gradient-based fitting (estimate_bits_float, scipy).
"""

from __future__ import annotations

import numpy as np

from ...common.entropy.symbol_coder import TABLE_RADIUS, bits_by_level, code_lengths_bits, level_and_bits
from ...common.entropy.tables import NUM_SCALE_LEVELS, PRECISION_BITS, SCALE_SIGMAS


def ideal_code_length_bits(residuals: np.ndarray, levels: np.ndarray) -> float:
    """-log2 of the probabilities the tables give these residuals, escape class and raw
    remainder bits included: what the coder spends, up to its termination (<= 2 words)."""
    return float(code_lengths_bits(residuals, levels).sum())


# informative: the most values whose code lengths row_blocked_total makes at a time (2 MiB of float64)
SUM_BLOCK_VALUES = 1 << 18


def pairwise_total(size: int, part) -> float:
    """np.sum of the float64 values 0 .. size - 1, ``part(lo, hi)`` giving values lo .. hi - 1, to the
    last bit with at most SUM_BLOCK_VALUES of them made at a time: numpy sums a contiguous array
    pairwise (halves cut at a multiple of 8), and this follows its cuts down to parts of at most
    SUM_BLOCK_VALUES, each summed by numpy (tests/test_bounded_memory.py checks the two agree)."""
    return _pairwise_part_total(part, 0, size)


def _pairwise_part_total(part, lo: int, n: int) -> float:
    """pairwise_total's sum of values lo .. lo + n - 1. (A module function, not a nested one that calls
    itself: such a closure is a reference cycle, which kept what ``part`` holds, a whole scene's
    neighbour coding, alive until the next garbage collection, through the tiles' stage.)"""
    if n <= SUM_BLOCK_VALUES:
        return float(np.sum(part(lo, lo + n)))
    half = n // 2
    half -= half % 8
    return _pairwise_part_total(part, lo, half) + _pairwise_part_total(part, lo + half, n - half)


def row_blocked_total(ends: np.ndarray, values) -> float:
    """pairwise_total of the values of every row, rows in order: ``values(a, b)`` gives those of rows
    a .. b - 1 (float64, flat), ``ends`` int [rows] where each row's end (cumulative counts)."""
    def part(lo: int, hi: int) -> np.ndarray:
        a = int(np.searchsorted(ends, lo, side="right"))  # the row holding value lo
        b = int(np.searchsorted(ends, hi - 1, side="right")) + 1  # .. and the one holding hi - 1
        start = int(ends[a - 1]) if a else 0
        return values(a, b)[lo - start:hi - start]
    size = int(ends[-1]) if len(ends) else 0
    return pairwise_total(size, part) if size else 0.0


def ideal_code_length_bits_by_rows(residuals, levels, shape: tuple[int, int], coded: np.ndarray | None = None) -> float:
    """ideal_code_length_bits of the values of ``shape`` [N, M] that ``residuals(a, b)`` and
    ``levels(a, b)`` give for rows a .. b - 1 (where ``coded`` [N, M], those values only, row-major),
    to the last bit, with the residuals, levels and code lengths of a few rows at a time."""
    n, m = shape
    if coded is None:
        return row_blocked_total(m * np.arange(1, n + 1, dtype=np.int64),
                                 lambda a, b: code_lengths_bits(residuals(a, b), levels(a, b)).ravel())
    return row_blocked_total(np.cumsum(coded.sum(axis=1), dtype=np.int64),
                             lambda a, b: code_lengths_bits(residuals(a, b)[coded[a:b]], levels(a, b)[coded[a:b]]))


_LOG_SIGMA0 = np.log(SCALE_SIGMAS[0])
_LOG_STEP = (np.log(SCALE_SIGMAS[-1]) - _LOG_SIGMA0) / (NUM_SCALE_LEVELS - 1)


def level_for_sigma(sigma: np.ndarray) -> np.ndarray:
    """Nearest level in the log domain, clipped to [0, 63] (informative)."""
    s = np.asarray(sigma, dtype=np.float64)
    if np.isnan(s).any():
        raise ValueError("sigma contains NaN")
    with np.errstate(divide="ignore"):
        x = (np.log(np.maximum(s, 0.0)) - _LOG_SIGMA0) / _LOG_STEP
    return np.clip(np.rint(np.nan_to_num(x, nan=0.0, posinf=63.0, neginf=0.0)), 0, 63).astype(np.int64)


def estimate_bits_float(residuals: np.ndarray, sigma: np.ndarray) -> float:
    """Bits of residuals under a discretized zero-mean Gaussian of scale sigma (clamped to the
    tables' range), each probability floored at 2^-24 (informative, smooth in sigma)."""
    from scipy.special import ndtr

    a = np.abs(np.asarray(residuals, dtype=np.float64))
    s = np.clip(np.asarray(sigma, dtype=np.float64), SCALE_SIGMAS[0], SCALE_SIGMAS[-1])
    p = ndtr((0.5 - a) / s) - ndtr((-0.5 - a) / s)
    return float(-np.log2(np.maximum(p, 2.0 ** -PRECISION_BITS)).sum())


class ResidualHistograms:
    """Per group (a channel, say): the histogram of its residuals, gathered a part at a time (counts:
    the same however the values are cut), and from it bits_by_level's sums, those best_level_and_bits
    gives all of the group's residuals to the last bit. Tabled residuals are counted, far ones kept."""

    def __init__(self, groups: int):
        self.near = np.zeros((groups, 2 * TABLE_RADIUS + 1), dtype=np.int64)
        self.far: list[tuple[np.ndarray, np.ndarray]] = []  # (groups, residuals) beyond the table

    def add(self, group: np.ndarray, r: np.ndarray) -> None:
        """Count residuals ``r`` (int) of groups ``group`` (int, the same shape)."""
        near = (r >= -TABLE_RADIUS) & (r <= TABLE_RADIUS)
        every = bool(near.all())  # (the rule: no masked copies)
        g, rn = (group, r) if every else (group[near], r[near])
        key = g.astype(np.int64) * (2 * TABLE_RADIUS + 1) + rn + TABLE_RADIUS
        self.near += np.bincount(key.ravel(), minlength=self.near.size).reshape(self.near.shape)
        if not every:
            self.far.append((group[~near], r[~near].astype(np.int64)))

    def bits(self, g: int) -> np.ndarray | None:
        """bits_by_level of group ``g``'s residuals (None where it has none)."""
        values = np.flatnonzero(self.near[g])
        counts = self.near[g, values]
        values = values - TABLE_RADIUS
        far = [r[group == g] for group, r in self.far]
        if far and sum(f.size for f in far):
            fv, fc = np.unique(np.concatenate(far), return_counts=True)
            values = np.concatenate([fv[fv < 0], values, fv[fv > 0]])
            counts = np.concatenate([fc[fv < 0], counts, fc[fv > 0]])
        return bits_by_level(values, counts) if values.size else None

    def best_level(self, g: int) -> int:
        """best_level of group ``g``'s residuals (0 where it has none)."""
        bits = self.bits(g)
        return 0 if bits is None else level_and_bits(bits)[0]
