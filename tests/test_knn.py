"""Canonical Ball k-NN (common/knn.py) against brute force, with the hard cases."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common import knn
from lghcc.common.knn import MAX_EXTENT, ball_knn, set_candidate_threads
from reference_impl import ball_knn_bruteforce


def _same(a, b):
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


coords_st = st.integers(1, 40).flatmap(
    lambda n: st.lists(st.tuples(*[st.integers(-3, 3)] * 3), min_size=n, max_size=n))


@settings(max_examples=150)
@given(coords_st, st.integers(0, 10), st.integers(0, 30), st.integers(0, 3), st.booleans())
def test_matches_bruteforce_small_grid(pts, k, r2, extra, exclude_self):
    c = np.array(pts, dtype=np.int64)  # duplicates allowed: self is excluded by index
    _same(ball_knn(c, k, r2, exclude_self=exclude_self, initial_extra=extra),
          ball_knn_bruteforce(c, k, r2, exclude_self=exclude_self))


@settings(max_examples=60)
@given(coords_st, st.lists(st.tuples(*[st.integers(-4, 4)] * 3), min_size=1, max_size=8),
       st.integers(1, 9), st.integers(0, 40))
def test_matches_bruteforce_with_query(pts, qpts, k, r2):
    c, q = np.array(pts), np.array(qpts)
    _same(ball_knn(c, k, r2, query=q, initial_extra=0), ball_knn_bruteforce(c, k, r2, query=q))


def test_full_grid_massive_ties():
    g = np.stack(np.meshgrid(*[np.arange(-6, 6)] * 3, indexing="ij"), -1).reshape(-1, 3)
    g = g[np.random.default_rng(0).permutation(len(g))]
    for k, r2 in ((8, 2), (8, 3), (6, 1), (26, 3), (27, 4)):
        got = ball_knn(g, k, r2, initial_extra=0)
        _same(got, ball_knn_bruteforce(g, k, r2))
    # interior point, k = 8, r2 = 3: the 6 face neighbours (d2 = 1) then the 2 lowest-index of the 12 at d2 = 2
    idx, valid = ball_knn(g, 8, 3)
    i = int(np.nonzero((g == 0).all(1))[0][0])
    d2 = (g[idx[i]] ** 2).sum(1)
    assert valid[i].all() and list(d2) == [1] * 6 + [2] * 2
    at2 = np.nonzero((g ** 2).sum(1) == 2)[0]
    assert list(idx[i, 6:]) == sorted(at2)[:2]


def test_all_equidistant_neighbours():
    # the 6 axis points and 8 cube corners at d2 = 12 around the origin... only distinct points:
    # points on a sphere of squared radius 9 (all lattice points with x^2+y^2+z^2 = 9)
    r = np.arange(-3, 4)
    g = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    shell = g[(g ** 2).sum(1) == 9]
    rng = np.random.default_rng(1)
    pts = np.concatenate([[[0, 0, 0]], shell[rng.permutation(len(shell))]])
    idx, valid = ball_knn(pts, 8, 9, initial_extra=0)
    assert valid[0].all()
    assert list(idx[0]) == list(range(1, 9))  # all at d2 = 9: ties broken by index
    _same((idx, valid), ball_knn_bruteforce(pts, 8, 9))


def test_fewer_than_k_within_radius_and_tiny_inputs():
    c = np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0], [0, 2, 0]])
    idx, valid = ball_knn(c, 4, 4)
    assert idx[0].tolist() == [1, 3, -1, -1] and valid[0].tolist() == [True, True, False, False]
    assert idx[2].tolist() == [-1] * 4 and not valid[2].any()
    # N = 1
    idx, valid = ball_knn(np.array([[7, -7, 7]]), 8, 100)
    assert idx.shape == (1, 8) and not valid.any() and (idx == -1).all()
    # N < k, everything inside
    c = np.random.default_rng(2).integers(-5, 5, (5, 3))
    _same(ball_knn(c, 8, 10 ** 6), ball_knn_bruteforce(c, 8, 10 ** 6))
    # N = 0, k = 0
    assert ball_knn(np.zeros((0, 3), int), 3, 5)[0].shape == (0, 3)
    assert ball_knn(c, 0, 5)[0].shape == (5, 0)


def test_radius_zero_and_self_modes():
    c = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0]])  # a duplicate position
    idx, valid = ball_knn(c, 2, 0)
    assert idx[0].tolist() == [1, -1] and idx[1].tolist() == [0, -1] and not valid[2].any()
    idx, valid = ball_knn(c, 3, 1, exclude_self=False)
    assert idx[0].tolist() == [0, 1, 2]
    # with a query, "self" = data at the query's own position
    idx, _ = ball_knn(c, 3, 1, query=np.array([[0, 0, 0]]))
    assert idx[0].tolist() == [2, -1, -1]


def test_large_coordinates_and_overflow_bound():
    rng = np.random.default_rng(3)
    base = np.array([-(2 ** 31), 2 ** 31 - MAX_EXTENT, 0])
    c = base + rng.integers(0, MAX_EXTENT + 1, (300, 3))
    c[:3] = base + np.array([[0, 0, 0], [MAX_EXTENT, MAX_EXTENT, MAX_EXTENT], [MAX_EXTENT, 0, 0]])
    r2 = 3 * MAX_EXTENT ** 2
    _same(ball_knn(c, 5, r2), ball_knn_bruteforce(c, 5, r2))
    # clustered far-apart points with near-tie distances around 2^60
    c2 = np.array([[0, 0, 0], [2 ** 29, 0, 0], [2 ** 29 - 1, 1, 0], [2 ** 29 - 1, 0, 1], [-(2 ** 29), 0, 0]])
    _same(ball_knn(c2, 2, 2 ** 58, initial_extra=0), ball_knn_bruteforce(c2, 2, 2 ** 58))
    with pytest.raises(ValueError, match="extent"):
        ball_knn(np.array([[0, 0, 0], [MAX_EXTENT + 1, 0, 0]]), 1, 1)
    with pytest.raises(ValueError, match="extent"):
        ball_knn(np.array([[0, 0, 0]]), 1, 1, query=np.array([[-(2 ** 31), 0, 2 ** 31]]))
    with pytest.raises(ValueError):
        ball_knn(np.zeros((2, 3)), 1, 1)  # float coordinates
    with pytest.raises(ValueError):
        ball_knn(np.zeros((2, 3), int), 1, -1)


def test_random_cloud_matches_bruteforce():
    rng = np.random.default_rng(4)
    c = np.unique(rng.integers(0, 30, (1500, 3)), axis=0)
    c = c[rng.permutation(len(c))]
    _same(ball_knn(c, 8, 20, initial_extra=1), ball_knn_bruteforce(c, 8, 20))


def test_candidate_threads_do_not_change_the_answer():
    rng = np.random.default_rng(5)
    c = rng.integers(0, 25, (3000, 3))
    expected = ball_knn_bruteforce(c, 6, 12)
    try:
        for n in (1, 2, -1):
            set_candidate_threads(n)
            _same(ball_knn(c, 6, 12), expected)
        _same(ball_knn(c, 6, 12, workers=3), expected)  # an explicit count overrides the default
    finally:
        set_candidate_threads(-1)
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match="threads"):
            set_candidate_threads(bad)
    assert knn._default_threads == -1


@pytest.mark.slow
def test_benchmark_1e6():
    import time
    c = np.random.default_rng(5).integers(0, 1 << 16, (10 ** 6, 3))
    t = time.perf_counter()
    idx, valid = ball_knn(c, 8, 3000 ** 2)
    print(f"ball_knn 1e6 anchors k=8: {time.perf_counter() - t:.1f} s")
    sub = np.random.default_rng(6).integers(0, 10 ** 6, 30)
    for i in sub:
        d2 = ((c - c[i]) ** 2).sum(1)
        d2[i] = np.iinfo(np.int64).max
        ok = d2 <= 3000 ** 2
        j = np.nonzero(ok)[0]
        j = j[np.lexsort((j, d2[j]))][:8]
        assert idx[i, :j.size].tolist() == j.tolist() and valid[i].sum() == j.size
