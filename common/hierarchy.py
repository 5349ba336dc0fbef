"""Two-level anchor hierarchy and the parent map Q (normative; spec/hierarchy_ggconv.md,
clause "Hierarchy").

Anchors are given in the normative order (index order). With the coarse voxel scale s >= 1,
anchor i lies in coarse voxel v_i = floor(p_i / s) (per axis, floor division, so -1 // 4 = -1).
Level 1 holds, for every occupied coarse voxel, the anchor of lowest index in it; level 2 holds
all other anchors. Both levels keep the normative order (ascending index). The parent of a
level-2 anchor is the level-1 anchor of its voxel (paper eq. 6 and the mapping Q).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Hierarchy:
    level1_idx: np.ndarray  # int64 [N1], ascending anchor indices of level 1
    level2_idx: np.ndarray  # int64 [N2], ascending anchor indices of level 2
    parent_of_level2: np.ndarray  # int64 [N2], index into level1_idx of each level-2 anchor's parent

    @property
    def num_level1(self) -> int:
        return int(self.level1_idx.shape[0])

    @property
    def num_level2(self) -> int:
        return int(self.level2_idx.shape[0])

    @property
    def parent_anchor_of_level2(self) -> np.ndarray:
        """int64 [N2]: the parent of each level-2 anchor as an index into the full anchor set."""
        return self.level1_idx[self.parent_of_level2]


def coarse_voxels(coords: np.ndarray, scale: int) -> np.ndarray:
    """floor(coords / scale) per axis (int64 floor division, rounds toward minus infinity)."""
    return np.floor_divide(coords, np.int64(scale))


def local_position(coords: np.ndarray, scale: int) -> np.ndarray:
    """Position of each anchor inside its coarse voxel: p - scale * floor(p / scale), in [0, scale)."""
    return np.mod(coords, np.int64(scale))


def _check(coords, scale) -> np.ndarray:
    c = np.asarray(coords)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"coords must have shape [N, 3], got {list(c.shape)}")
    if c.size and not np.issubdtype(c.dtype, np.integer):
        raise ValueError(f"coords must be integers, got {c.dtype}")
    if isinstance(scale, bool) or not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ValueError(f"the coarse voxel scale must be an integer >= 1, got {scale!r}")
    return c.astype(np.int64, copy=False)


def build_hierarchy(coords, scale: int) -> Hierarchy:
    """Split anchors (int64 [N, 3], normative order) into level 1 and level 2 with the parent map."""
    c = _check(coords, scale)
    n = c.shape[0]
    if n == 0:
        e = np.zeros(0, dtype=np.int64)
        return Hierarchy(e, e.copy(), e.copy())
    v = coarse_voxels(c, int(scale))
    # Stable lexsort: within one voxel, anchors stay in ascending index order.
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    vs = v[order]
    new_group = np.empty(n, dtype=bool)
    new_group[0] = True
    new_group[1:] = (vs[1:] != vs[:-1]).any(axis=1)
    group_sorted = np.cumsum(new_group) - 1  # voxel group id of each sorted position
    first_of_group = order[new_group]  # lowest anchor index of every voxel
    group = np.empty(n, dtype=np.int64)
    group[order] = group_sorted
    is_l1 = np.zeros(n, dtype=bool)
    is_l1[first_of_group] = True
    level1_idx = np.nonzero(is_l1)[0].astype(np.int64)
    level2_idx = np.nonzero(~is_l1)[0].astype(np.int64)
    # rank of each voxel's level-1 anchor within level1_idx
    rank_of_group = np.searchsorted(level1_idx, first_of_group)
    parent_of_level2 = rank_of_group[group[level2_idx]].astype(np.int64)
    return Hierarchy(level1_idx, level2_idx, parent_of_level2)
