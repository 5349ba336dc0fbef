"""Tiles (normative, version 1; spec clause 7.3.11 and clause 13.2).

With ``tiles_enabled_flag`` = 1 the voxel grid is cut into cubic cells of TileSize voxels per
side (the parameter set's ``tile_scale_minus1`` + 1 coarse voxels, so that no coarse voxel of the
hierarchy straddles two cells). A point with voxel coordinates c lies in the cell
floor(c / TileSize) (per axis, floor division). Every occupied cell is one tile: its own
geometry unit, attribute units and decoded_scene_hash unit, decodable without any other tile
(its hierarchy, its Ball k-NN graph and its context use its own points only). The tiles appear
in strictly increasing lexicographic order of their cells (x, then y, then z); the decoded
scene is the concatenation of the tiles' points in that order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import BitstreamError
from .units import TileIndex


def tile_cells(coords: np.ndarray, tile_size: int) -> np.ndarray:
    """int64 [N, 3]: the cell floor(c / TileSize) of every point."""
    return np.floor_divide(np.asarray(coords, dtype=np.int64), np.int64(tile_size))


INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1


def cell_bounds(cell, tile_size: int) -> tuple[np.ndarray, np.ndarray]:
    """The voxel coordinates the cell covers: lo .. hi inclusive, per axis, as int64 (bounds beyond
    the int64 range, which a cell of a stream's index can reach, are clamped to it: every
    coordinate is within it, so comparisons are unchanged)."""
    lo = [min(max(int(c) * int(tile_size), INT64_MIN), INT64_MAX) for c in cell]
    hi = [min(max(int(c) * int(tile_size) + int(tile_size) - 1, INT64_MIN), INT64_MAX) for c in cell]
    return np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)


def check_tile_index(index: TileIndex, num_points: int) -> None:
    """The tile index's own rules (clause 7.3.11): cells in strictly increasing lexicographic
    order (so no two tiles share a cell) and point counts adding up to N. BitstreamError."""
    cells = index.cells
    for t in range(1, len(cells)):
        if not cells[t - 1] < cells[t]:
            raise BitstreamError(f"tile_index_unit: tile {t} has cell {cells[t]}, not after tile {t - 1}'s cell "
                                 f"{cells[t - 1]} (tiles shall be in strictly increasing order of their cells, "
                                 "each cell once)", condition="E56")
    total = sum(x + 1 for x in index.tile_num_points_minus1)
    if total != num_points:
        raise BitstreamError(f"tile_index_unit: the tiles hold {total} points, the parameter set declares "
                             f"{num_points}", condition="E57")


def check_points_in_cell(coords: np.ndarray, cell, tile_size: int, t: int) -> None:
    """Every decoded point of tile t lies in the tile's cell (clause 13.2). BitstreamError."""
    lo, hi = cell_bounds(cell, tile_size)
    outside = ((coords < lo) | (coords > hi)).any(axis=1)
    if outside.any():
        i = int(np.argmax(outside))
        raise BitstreamError(f"tile {t}: decoded point {i} at voxel {coords[i].tolist()} lies outside the "
                             f"tile's cell {list(cell)} (voxels {lo.tolist()} .. {hi.tolist()})", condition="E58")


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in world coordinates (lghcc-dec --box): lo <= hi per axis."""
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]


def cell_intersects_box(cell, tile_size: int, voxel_size: float, origin, box: Box) -> bool:
    """Whether the world-space cube of a cell meets the box (clause 13.3): per axis the closed
    intervals [cell * TileSize * voxel_size + origin, (cell + 1) * TileSize * voxel_size + origin]
    (binary64, left to right) and [lo, hi] of the box intersect."""
    o = [float(x) for x in origin]
    wlo = [float(int(c) * int(tile_size)) * float(voxel_size) + oa for c, oa in zip(cell, o)]
    whi = [float((int(c) + 1) * int(tile_size)) * float(voxel_size) + oa for c, oa in zip(cell, o)]
    return all(a <= bh and b >= bl for a, b, bl, bh in zip(wlo, whi, box.lo, box.hi))
