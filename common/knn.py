"""Canonical Ball k-NN on integer coordinates (normative; spec/hierarchy_ggconv.md, clause "Ball k-NN").

For a query point q and data points c_0 .. c_{N-1} (int64 [N, 3]):

* d2(q, c_j) = sum over the 3 axes of (q - c_j)^2, exact integer arithmetic;
* candidates are the data points with d2 <= radius_sq (the ball is closed), minus "self"
  (see ``ball_knn``);
* the candidates are ordered by the pair (d2, j), ascending: distance first, ties broken by
  the lower data index;
* the answer is the first k of that order; rows with fewer than k candidates are padded with
  idx = -1, valid = False.

The answer depends on nothing but the integers: no float, no tree layout, no thread count.

Overflow bound: every coordinate difference along one axis is at most the extent
E = max over axes of (max - min) of all data and query coordinates. We require
3 * E^2 <= 2^63 - 1, i.e. E <= MAX_EXTENT = 1_753_413_056 (about 2^30.7), so every d2 of every
pair fits int64. Inputs with a larger extent raise ValueError. (Coordinates themselves may
be anywhere in int64 as long as the extent bound holds; realistic scenes use <= 2^21.)

Implementation (informative, the result is what is normative): scipy's cKDTree on the
recentred float64 coordinates (exact: values <= 2^31) generates candidate sets; the exact
int64 d2 is recomputed, the candidates are lexsorted by (d2, index), and a row is accepted
only when its candidate set provably contains every point that can belong to the answer:

* the tree returned fewer candidates than asked for (it then returned every point within a
  float bound B slightly larger than sqrt(radius_sq), so every point of the ball), or
* the largest exact d2 among the candidates, d_last, exceeds the row's threshold T (the k-th
  accepted d2, or radius_sq when fewer than k lie in the ball) by more than d_last >> 40
  (the tree ranks by float64 d2, which is exact below 2^53 and otherwise within a relative
  2^-50 of the exact value; the margin covers that, so no point outside the candidate set
  can have d2 <= T).

Other rows are queried again with twice as many candidates, until the candidate count
reaches N (then the set is everything and trivially complete).
"""

from __future__ import annotations

import math

import numpy as np

MAX_EXTENT = math.isqrt((2**63 - 1) // 3)  # 1_753_413_056: 3 * E^2 fits int64
_MARGIN_SHIFT = 40
_BIG = np.iinfo(np.int64).max
_BLOCK = 1 << 17  # rows per candidate query (memory bound only)
# threads of the candidate generator when a caller names none (-1: one per CPU); a decoder's
# worker processes set 1, since they are the parallelism (set_candidate_threads)
_default_threads = -1


def set_candidate_threads(n: int) -> None:
    """Threads the candidate generator uses when ``ball_knn`` is given no ``workers`` (-1: one
    per CPU). Informative: the answer does not depend on it."""
    global _default_threads
    if isinstance(n, bool) or not isinstance(n, int) or (n < 1 and n != -1):
        raise ValueError(f"threads must be a positive integer or -1, got {n!r}")
    _default_threads = n


def candidate_generator():
    """The candidate generator's tree class (scipy's cKDTree), imported on first use: a decoder
    loads it before forking its workers, which then share it instead of each importing it."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (scipy's stubs omit it)

    return cKDTree


def _as_coords(a, what: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{what} must have shape [N, 3], got {list(a.shape)}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f"{what} must be integers, got {a.dtype}")
    if a.dtype == np.uint64 and a.size and int(a.max()) > np.iinfo(np.int64).max:
        raise ValueError(f"{what} exceed the int64 range")
    return a.astype(np.int64, copy=False)


def check_extent(*arrays: np.ndarray) -> int:
    """Return the extent E of the union of the given [*, 3] int64 arrays; ValueError when
    3 * E^2 would overflow int64 (E > MAX_EXTENT)."""
    lo = hi = None
    for a in arrays:
        if a.shape[0] == 0:
            continue
        amin = [int(v) for v in a.min(axis=0)]
        amax = [int(v) for v in a.max(axis=0)]
        lo = amin if lo is None else [min(x, y) for x, y in zip(lo, amin)]
        hi = amax if hi is None else [max(x, y) for x, y in zip(hi, amax)]
    if lo is None or hi is None:
        return 0
    extent = max(h - l for h, l in zip(hi, lo))  # Python ints: no overflow here
    if extent > MAX_EXTENT:
        raise ValueError(f"coordinate extent {extent} exceeds {MAX_EXTENT}: squared distances would "
                         "overflow int64")
    return extent


def _prepare(coords, query, k: int):
    """Checked int64 data and query points, their extent E, and empty outputs (idx -1, valid False)
    of [M, k]."""
    c = _as_coords(coords, "coords")
    self_mode = query is None
    q = c if self_mode else _as_coords(query, "query")
    extent = check_extent(c, q)
    m = q.shape[0]
    return c, q, self_mode, extent, np.full((m, k), -1, dtype=np.int64), np.zeros((m, k), dtype=bool)


def _check_k_radius(k, radius_sq) -> tuple[int, int]:
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0:
        raise ValueError(f"k must be a non-negative integer, got {k!r}")
    if isinstance(radius_sq, bool) or not isinstance(radius_sq, (int, np.integer)) or radius_sq < 0:
        raise ValueError(f"radius_sq must be a non-negative integer, got {radius_sq!r}")
    return int(k), int(radius_sq)


def ball_knn(coords, k: int, radius_sq: int, query=None, exclude_self: bool = True,
             workers: int | None = None, initial_extra: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Canonical Ball k-NN.

    coords: int [N, 3] data points; query: int [M, 3] or None (then query = coords, M = N).
    Returns idx int64 [M, k] (data indices, -1 where invalid) and valid bool [M, k]; valid
    entries come first in each row, ordered by (d2, index).

    exclude_self: with query None, row i never contains index i; with a query given, data
    points at the query's own position (d2 == 0) are excluded.
    workers, initial_extra: performance knobs of the candidate generator only (workers: its
    threads, None: set_candidate_threads's, by default one per CPU; initial_extra:
    candidates asked beyond k at first; None: 8 for a self query, whose dense neighbourhoods
    tie often, and 2 for a separate query set; tools/results/ggconv.md measures both).
    """
    k, radius_sq = _check_k_radius(k, radius_sq)
    c, q, self_mode, extent, idx_out, valid_out = _prepare(coords, query, k)
    n, m = c.shape[0], q.shape[0]
    if n == 0 or m == 0 or k == 0:
        return idx_out, valid_out
    # Clamp the radius to the largest d2 of these points, 3 E^2 (the same ball): float bounds stay
    # finite, and a ball that covers everything still orders by one int64 key (use_key)
    search = _CandidateSearch(c, q, self_mode, min(radius_sq, 3 * extent * extent), k, exclude_self,
                              _default_threads if workers is None else workers)
    if initial_extra is None:
        initial_extra = 8 if self_mode else 2
    ask = k + initial_extra + (1 if exclude_self else 0)
    pending = np.arange(m, dtype=np.int64)
    while pending.size:
        ask = min(ask, n)
        rest = [search.solve(pending[lo:lo + _BLOCK], ask, idx_out, valid_out)
                for lo in range(0, pending.size, _BLOCK)]
        pending = np.concatenate(rest)
        assert ask < n or pending.size == 0
        ask *= 2
    return idx_out, valid_out


class _CandidateSearch:
    """The candidate generator (informative: a cKDTree over the recentred float64 coordinates)
    and the exact answer of the rows whose candidate set provably holds it (module doc)."""

    def __init__(self, c: np.ndarray, q: np.ndarray, self_mode: bool, radius_sq: int, k: int,
                 exclude_self: bool, workers: int):
        self.n, self.self_mode, self.radius_sq, self.k = c.shape[0], self_mode, radius_sq, k
        self.exclude_self, self.workers = exclude_self, workers
        base = np.minimum(c.min(axis=0), q.min(axis=0))
        cf = (c - base).astype(np.float64)  # exact: 0 <= value <= MAX_EXTENT < 2^53
        self.qf = cf if self_mode else (q - base).astype(np.float64)
        self.tree = candidate_generator()(cf, balanced_tree=False, compact_nodes=False)
        self.bound = math.sqrt(radius_sq) * (1 + 2.0**-30) + 1e-3  # float bound strictly beyond the ball
        self.cols = [np.ascontiguousarray(c[:, a]) for a in range(3)]
        self.qcols = self.cols if self_mode else [np.ascontiguousarray(q[:, a]) for a in range(3)]
        self.use_key = radius_sq < _BIG // (self.n + 1) - 1  # then d2 * (n + 1) + index fits int64

    def solve(self, rows: np.ndarray, ask: int, idx_out: np.ndarray, valid_out: np.ndarray) -> np.ndarray:
        """Answer the given rows from `ask` candidates each; write the complete ones into the
        outputs and return the incomplete ones."""
        n, k = self.n, self.k
        _, cand = self.tree.query(self.qf[rows], k=ask, distance_upper_bound=self.bound, workers=self.workers)
        cand = np.asarray(cand, dtype=np.int64).reshape(rows.size, ask)
        missing = cand >= n  # the tree pads with index n beyond the bound
        complete = missing.any(axis=1) if ask < n else np.ones(rows.size, dtype=bool)
        cidx, d2, ok = self.candidates_in_ball(rows, cand, missing)
        d_last = d2.max(axis=1)  # largest exact d2 among the real candidates
        take = min(k, ask)
        sd, si, sok = _first_by_distance_then_index(d2, cidx, ok, n, take, self.use_key)
        # T: the k-th accepted d2 (needs take == k), else the ball's radius.
        full = sok[:, k - 1] if take == k else np.zeros(rows.size, dtype=bool)
        thresh = np.where(full, sd[:, take - 1], self.radius_sq)
        complete |= (d_last - thresh) > (d_last >> _MARGIN_SHIFT)
        r = rows[complete]
        sok = sok[complete]
        idx_out[r, :take] = np.where(sok, si[complete], -1)
        valid_out[r, :take] = sok
        return rows[~complete]

    def candidates_in_ball(self, rows: np.ndarray, cand: np.ndarray, missing: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The candidates' data indices, exact squared distances d2 (-1 for missing ones) and
        whether each is an answer candidate: in the closed ball, and not self."""
        anymiss = bool(missing.any())
        cidx = np.where(missing, 0, cand) if anymiss else cand
        d2 = None
        for a in range(3):
            d = self.cols[a][cidx] - self.qcols[a][rows][:, None]
            d2 = d * d if d2 is None else d2 + d * d
        assert d2 is not None  # three axes
        if anymiss:
            d2[missing] = -1
        ok = d2 <= self.radius_sq
        if anymiss:
            ok &= ~missing
        if self.exclude_self:
            ok &= (cidx != rows[:, None]) if self.self_mode else (d2 != 0)
        return cidx, d2, ok


def _first_by_distance_then_index(d2: np.ndarray, cidx: np.ndarray, ok: np.ndarray, n: int, take: int,
                                  use_key: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first ``take`` accepted candidates of each row in (d2, index) order: their d2, index
    and acceptance (rows with fewer accepted candidates end in rejected ones)."""
    if use_key:
        # one int64 key orders exactly as the pair (d2, index)
        key = np.where(ok, d2 * (n + 1) + cidx, _BIG)
        key.sort(axis=1)
        key = key[:, :take]
        sok = key != _BIG
        sd = key // (n + 1)
        si = key - sd * (n + 1)
    else:
        key_d = np.where(ok, d2, _BIG)
        key_i = np.where(ok, cidx, _BIG)
        order = np.lexsort((key_i, key_d), axis=-1)[:, :take]
        sd = np.take_along_axis(key_d, order, axis=1)
        si = np.take_along_axis(key_i, order, axis=1)
        sok = np.take_along_axis(ok, order, axis=1)
    return sd, si, sok
