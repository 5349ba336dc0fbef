"""The voxel size of anchors stored as float32: the spacing of the grid through the origin that
explains every coordinate within the error that float32 storage explains, and no more.

Scaffold-GS and HAC place anchors at k * voxel_size (integer k, computed and stored in float32),
so a coordinate x is within half a float32 spacing at |x| (at most |x| * 2^-24) of a whole multiple
of the spacing. The spacing is found in two stages, both narrowing an interval [lo, hi] that
holds every spacing consistent with the values seen so far:

1. the differences between neighbouring distinct coordinate values on each axis (and between
   neighbouring differences, small multiples where anchors are sparse): an approximate greatest
   common divisor, started from the smallest; a difference that is no multiple of the spacing
   found makes its remainder the next candidate (Euclid's step), the remainder joining the values;
2. the coordinates themselves (the grid passes through the origin).

Each stage takes in, round by round, the values whose multiple of the spacing the interval already
tells apart (that multiple times the interval's half width, plus the value's error, stays below half
a spacing), so that near coordinates (small float32 error) pin the spacing down for far ones (a
0.0005 grid is found to +-200 m). A value that no spacing in the interval explains (the first one,
taken most precise first) sends stage 1 to Euclid's step; in stage 2, or a value whose multiple
stays ambiguous, it means the positions are not on a regular grid. When a float32 number lies in
the final interval it is the answer: the voxel size Scaffold-GS multiplied by.
"""

from __future__ import annotations

import numpy as np

from ..common.errors import InputError

# The float64 arithmetic on the intervals adds a little to the float32 error (relative to it).
FLOAT64_MARGIN = 2.0 ** -20
MAX_ROUNDS = 200  # each round takes in more values or shrinks the candidate by half or more


def float32_error(x: np.ndarray) -> np.ndarray:
    """The most that storing x as float32 can have moved it: half the float32 spacing at |x|."""
    return np.spacing(np.abs(x).astype(np.float32)).astype(np.float64) / 2 * (1 + FLOAT64_MARGIN)


def axis_values(positions: np.ndarray, origin: np.ndarray | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per axis: the distinct coordinates (sorted, float64, relative to ``origin``; None: 0) and the
    error float32 storage allows in each (twice rounded when an origin was added)."""
    out = []
    for a in range(positions.shape[1]):
        stored = np.unique(positions[:, a]).astype(np.float64)
        o = 0.0 if origin is None else float(origin[a])
        x = stored - o
        out.append((x, float32_error(stored) + (float32_error(x) if o else 0.0)))
    return out


def all_values(axes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The distance of every distinct coordinate from the origin, and its error."""
    return np.abs(np.concatenate([x for x, _ in axes])), np.concatenate([e for _, e in axes])


def neighbour_gaps(axes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The differences between neighbouring distinct coordinates on each axis that are more than the
    errors of their two ends could make, with that error, all axes together."""
    return differences([x for x, _ in axes], [e for _, e in axes])


def differences(values: list[np.ndarray], errs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The neighbour differences of each sorted array in ``values`` above their errors, with them."""
    d = np.concatenate([np.diff(x) for x in values])
    e = np.concatenate([err[1:] + err[:-1] for err in errs])
    return d[d > e], e[d > e]


def multiple_bounds(g: np.ndarray, e: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spacings for which each value ``g`` is ``m`` times the spacing within its error ``e``
    (m = 0: any spacing when g is within its error of 0, else none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        low = np.where(m > 0, (g - e) / m, np.where(g <= e, 0.0, np.inf))
        high = np.where(m > 0, (g + e) / m, np.where(g <= e, np.inf, 0.0))
    return low, high


def first_miss(g: np.ndarray, e: np.ndarray, m: np.ndarray, safe: np.ndarray, lo: float,
               hi: float) -> tuple[float, float, int]:
    """Among the ``safe`` values taken most precise first, the first that no spacing agreeing with
    the ones before it explains -> (the spacings those explain, its index)."""
    precision = (m * (hi - lo) / 2 + e)[safe]
    order = safe[np.argsort(precision, kind="stable")]
    low, high = multiple_bounds(g[order], e[order], m[order])
    lows, highs = np.maximum.accumulate(np.append(lo, low)), np.minimum.accumulate(np.append(hi, high))
    j = int(np.argmax(lows > highs))
    return float(lows[j - 1]), float(highs[j - 1]), int(order[j - 1])


def narrow(g: np.ndarray, e: np.ndarray, lo: float, hi: float) -> tuple[float, float, int | None]:
    """Narrow [lo, hi] (0 < lo <= hi) by the values ``g`` >= 0, each a whole multiple of the spacing
    within its error ``e`` -> (lo, hi, None) when every value agrees, else (lo, hi, i) with i the
    value that is no multiple of any spacing in [lo, hi], narrowed by the values more precise than
    it (-1: values whose multiple stays ambiguous)."""
    taken = -1
    while True:
        v, dv = (lo + hi) / 2, (hi - lo) / 2
        m = np.round(g / v)
        safe = np.flatnonzero(m * dv + e < v / 2)  # the multiple is the same for every spacing in [lo, hi]
        low, high = multiple_bounds(g[safe], e[safe], m[safe])
        new_lo, new_hi = max(lo, low.max(initial=lo)), min(hi, high.min(initial=hi))
        if new_lo > new_hi:
            return first_miss(g, e, m, safe, lo, hi)
        lo, hi = float(new_lo), float(new_hi)
        if safe.size in (g.size, taken):
            return lo, hi, None if safe.size == g.size else -1
        taken = safe.size


def common_spacing(g: np.ndarray, e: np.ndarray) -> tuple[float, float] | None:
    """[lo, hi] holding the largest spacing of which every ``g`` is a whole multiple within its
    error ``e`` (stage 1 of the module doc), or None when there is none above the errors."""
    order = np.argsort(g)
    d, de = differences([g[order]], [e[order]])  # multiples too: small ones where gaps are sparse
    g, e = np.append(g, d), np.append(e, de)
    i = int(np.argmin(g))
    lo, hi = g[i] - e[i], g[i] + e[i]
    for _ in range(MAX_ROUNDS):
        if lo <= 0:
            return None
        lo, hi, off = narrow(g, e, lo, hi)
        if off is None:
            return lo, hi
        if off < 0:
            return None
        v, dv = (lo + hi) / 2, (hi - lo) / 2
        m = np.round(g[off] / v)
        rest, rest_err = abs(g[off] - m * v), e[off] + m * dv
        lo, hi = rest - rest_err, rest + rest_err  # Euclid's step: the remainder is a multiple too,
        g, e = np.append(g, rest), np.append(e, rest_err)  # and narrows the spacings after it
    return None


def grid_error(positions: np.ndarray, voxel_size: float) -> float:
    """The largest distance of a coordinate from the grid, in voxels."""
    q = positions / voxel_size
    return float(np.abs(q - np.round(q)).max(initial=0.0))


def spacing_bounds(axes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float, bool]:
    """(lo, hi, True): the spacings of a grid through the origin on which every coordinate of
    ``axes`` (``axis_values``) lies within its float32 error (both stages of the module doc);
    (v, v, False) when there is none, v the best spacing found."""
    x, err = all_values(axes)
    g, e = neighbour_gaps(axes)
    if not g.size:  # one anchor, or all at one place: only the coordinates tell
        g, e = x[x > err], err[x > err]
    if not g.size:  # every anchor at the origin: any spacing will do
        return 1.0, 1.0, True
    bounds = common_spacing(g, e)
    if bounds is None:
        return float(g.min()), float(g.min()), False
    lo, hi, off = narrow(x, err, *bounds)
    if off is not None:
        v = (bounds[0] + bounds[1]) / 2
        return v, v, False
    return lo, hi, True


def infer_voxel_size(positions: np.ndarray, origin: np.ndarray | None = None) -> float:
    """The voxel size of anchor positions [N, 3] on a grid through ``origin`` (default 0), stored as
    float32 (module doc). InputError when the positions are not on such a grid."""
    axes = axis_values(np.asarray(positions), origin)
    lo, hi, found = spacing_bounds(axes)
    if not found:
        error = max(grid_error(x, lo) for x, _ in axes)
        raise InputError(f"anchor positions are not on a regular grid (best spacing {lo:.6g} leaves an error of "
                         f"{error:.3g} voxels, more than float32 storage explains); pass the voxel size explicitly "
                         "(--voxel-size)")
    v32 = float(np.float32((lo + hi) / 2))
    return v32 if lo <= v32 <= hi else (lo + hi) / 2


def on_grid(positions: np.ndarray, voxel_size: float, origin: np.ndarray | None = None) -> bool:
    """Whether every position is within its float32 error of origin + k * voxel_size (k whole), the
    voxel size taken as given or as float32 (the scene's positions multiply by its float32)."""
    g, e = all_values(axis_values(np.asarray(positions), origin))
    return any(narrow(g, e, v, v)[2] is None for v in {float(voxel_size), float(np.float32(voxel_size))})
