"""Two-level hierarchy and parent map (common/hierarchy.py)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.hierarchy import build_hierarchy, coarse_voxels, local_position


def _reference(coords, s):
    first, l1, l2, par = {}, [], [], []
    for i, p in enumerate(coords):
        v = tuple(int(x) // s for x in p)  # Python // floors
        if v not in first:
            first[v] = len(l1)
            l1.append(i)
        else:
            l2.append(i)
            par.append(first[v])
    return l1, l2, par


@settings(max_examples=100)
@given(st.lists(st.tuples(*[st.integers(-50, 50)] * 3), max_size=120), st.integers(1, 12))
def test_matches_reference(pts, s):
    c = np.array(pts, dtype=np.int64).reshape(-1, 3)
    h = build_hierarchy(c, s)
    l1, l2, par = _reference(c, s)
    assert h.level1_idx.tolist() == l1 and h.level2_idx.tolist() == l2
    assert h.parent_of_level2.tolist() == par
    if l2:
        p = h.parent_anchor_of_level2
        assert (coarse_voxels(c[p], s) == coarse_voxels(c[h.level2_idx], s)).all()
        assert (p < h.level2_idx).all()  # the parent comes first in the normative order


def test_negative_coordinates_floor():
    c = np.array([[-1, -1, -1], [-4, -4, -4], [-5, 0, 0], [0, 0, 0], [3, 3, 3]])
    h = build_hierarchy(c, 4)
    # voxels: (-1,-1,-1), (-1,-1,-1), (-2,0,0), (0,0,0), (0,0,0)
    assert h.level1_idx.tolist() == [0, 2, 3] and h.level2_idx.tolist() == [1, 4]
    assert h.parent_of_level2.tolist() == [0, 2]
    assert local_position(c, 4).tolist() == [[3, 3, 3], [0, 0, 0], [3, 0, 0], [0, 0, 0], [3, 3, 3]]


def test_level2_empty_and_scale_one():
    c = np.random.default_rng(0).permutation(np.stack(np.meshgrid(*[np.arange(5)] * 3), -1).reshape(-1, 3))
    h = build_hierarchy(c, 1)
    assert h.num_level2 == 0 and h.level1_idx.tolist() == list(range(125))
    assert h.parent_of_level2.shape == (0,) and h.parent_anchor_of_level2.shape == (0,)
    h0 = build_hierarchy(np.zeros((0, 3), np.int64), 3)
    assert h0.num_level1 == h0.num_level2 == 0


def test_one_voxel_500_children():
    rng = np.random.default_rng(1)
    inside = np.unique(rng.integers(0, 16, (900, 3)), axis=0)[:501]
    assert len(inside) == 501
    others = np.array([[100, 0, 0], [0, 100, 0], [-100, 0, 0]])
    c = np.concatenate([others[:1], inside, others[1:]])
    c[[1, 200]] = c[[200, 1]]
    h = build_hierarchy(c, 16)
    assert h.level1_idx.tolist() == [0, 1, 502, 503]
    assert h.num_level2 == 500 and (h.parent_of_level2 == 1).all()
    assert (h.parent_anchor_of_level2 == 1).all()


def test_rejects_bad_input():
    with pytest.raises(ValueError):
        build_hierarchy(np.zeros((3, 3), np.int64), 0)
    with pytest.raises(ValueError):
        build_hierarchy(np.zeros((3, 2), np.int64), 2)
    with pytest.raises(ValueError):
        build_hierarchy(np.zeros((3, 3)), 2)
