"""One int64 per voxel of a bounding box: the key that sets and sorts of voxel rows use (np.unique
on rows sorts them as structured values, about 10x slower; a set of a million tuples takes seconds
to build). Keys follow the rows' lexicographic order."""

from __future__ import annotations

import numpy as np

PACKABLE_VOLUME = 2.0 ** 62  # boxes of fewer voxels than this have an int64 key per voxel


class VoxelBox:
    """The bounding box of int64 rows [N, 3] and the key of each voxel inside it."""

    def __init__(self, rows: np.ndarray):
        self.lo = rows.min(axis=0).tolist() if rows.size else [0, 0, 0]
        self.span = (rows.max(axis=0) - rows.min(axis=0) + 1).tolist() if rows.size else [0, 0, 0]
        self.packable = float(self.span[0]) * float(self.span[1]) * float(self.span[2]) < PACKABLE_VOLUME

    def keys(self, rows: np.ndarray) -> np.ndarray:
        """The key of every row (rows inside the box; the box packable)."""
        c = rows - np.asarray(self.lo, dtype=np.int64)
        return (c[:, 0] * self.span[1] + c[:, 1]) * self.span[2] + c[:, 2]

    def key(self, t: tuple) -> int | None:
        """The key of one voxel, None outside the box."""
        d = [t[k] - self.lo[k] for k in range(3)]
        if not all(0 <= d[k] < self.span[k] for k in range(3)):
            return None
        return (d[0] * self.span[1] + d[1]) * self.span[2] + d[2]
