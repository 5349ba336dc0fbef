"""Tiles (informative: how the reference encoder cuts a scene; the format is common/tiles.py).

The tile side is a power of two of coarse voxels (voxels without the hierarchy): the one whose
occupied tiles hold nearest ``tile_points`` points on average, so that the fixed cost of a
tile (its attribute unit headers with their priors, a hash unit, an index entry, a geometry
octree restarted at the tile's box) stays a small share of its bytes. A scene that fits one
tile is not tiled: the tool costs it no bits.

The context model is fitted once, over the whole scene (encode.py); each tile then codes its
level 2 with it, or with its own per-channel prior where that is smaller (a level-2 unit may
use context_model_id 0 in a stream with a context model unit, clause 8.3). The hierarchy of a
tile is the whole scene's restricted to it, as no coarse voxel straddles two tiles.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ...common.context.models import read_context_model
from ...common.container import DataUnit, UnitType
from ...common.errors import InputError
from ...common.geometry import encode_geometry, normative_order
from ...common.hashing import digest_of
from ...common.hierarchy import build_hierarchy
from ...common.tiles import tile_cells
from .level_coding import (AttributeInput, LevelCoder, code_with_model, code_with_neighbours, code_with_prior,
                           neighbour_coding_of, quantized_level, reconstruct_level)
from ...common.units import (LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_TILE_SCALE, SE_MAX, DecodedSceneHashUnit, TileIndex)
from .config import channel_prediction_on
from .voxel_keys import VoxelBox

MAX_TILE_LOG2 = 40


def tile_scale_of(coords: np.ndarray, unit: int, cfg) -> int:
    """The configured tile scale (cfg.tile_scale, checked to give codable cells), else the one
    chosen from cfg.tile_points."""
    if not cfg.tile_scale:
        return choose_tile_scale(coords, unit, cfg.tile_points)
    if coords.shape[0] and np.abs(tile_cells(coords, cfg.tile_scale * unit)).max() > SE_MAX:
        raise InputError(f"tile_scale {cfg.tile_scale}: tile cells beyond +-(2^31 - 1); use larger tiles")
    return int(cfg.tile_scale)


def cell_keys(cells: np.ndarray) -> np.ndarray:
    """One int64 per row of ``cells`` (int64 [N, 3]), equal for equal rows and ordered as the
    rows in lexicographic order (the rows' ranks when their box is too large for one int64). np.unique on rows sorts
    them as structured values: 1.2 s for 100k rows, and the tile size is chosen over up to 20 sizes (17 of 20 s of a
    100k encode)."""
    if cells.shape[0] == 0:
        return np.zeros(0, np.int64)
    box = VoxelBox(cells)
    if not box.packable:
        _, inverse = np.unique(cells, axis=0, return_inverse=True)
        return inverse.reshape(-1).astype(np.int64)
    return box.keys(cells)


def unique_cells(cells: np.ndarray) -> np.ndarray:
    """The distinct rows of ``cells`` (int64 [N, 3])."""
    if cells.shape[0] == 0:
        return cells
    _, first = np.unique(cell_keys(cells), return_index=True)
    return cells[first]


def choose_tile_scale(coords: np.ndarray, unit: int, tile_points: int) -> int:
    """tile_scale_minus1 + 1 (tile side in units of ``unit`` voxels; 0: no tiles): among the power-of-two
    sides that give two tiles or more, the one whose mean points per occupied tile is nearest
    ``tile_points`` (by ratio; the smaller of equals); none for a scene of fewer than 2 x tile_points points, or for
    tile_points 0. The occupied cells of each side come from those of the side below (floor(floor(c / s) / 2)
    = floor(c / 2s)): one pass over the points, then over ever fewer cells."""
    n = coords.shape[0]
    if tile_points <= 0 or n < 2 * tile_points:
        return 0
    best, best_err = 0, np.inf
    cells = unique_cells(tile_cells(coords, unit))
    for j in range(MAX_TILE_LOG2):
        scale = 1 << j
        if scale > MAX_TILE_SCALE:
            break
        if j:
            cells = unique_cells(cells >> 1)  # arithmetic shift: floor division by 2
        if np.abs(cells).max() > SE_MAX:
            continue
        occupied = int(cells.shape[0])
        if occupied == 1:
            break
        err = abs(np.log2(n / occupied / tile_points))
        if err < best_err:
            best, best_err = scale, err
    return best


@dataclass
class TileCoding:
    """One tile as coded: its cell, the stream rows it holds (indices into the whole scene's
    normative order, in the tile's normative order), and its units' payloads."""
    cell: tuple[int, int, int] | None
    rows: np.ndarray
    geometry: bytes
    attributes: list[bytes]
    scene_hash: bytes = b""
    # per attribute unit: level, context model id, value bits, channel predictions, step-adjustment index
    # bits, SH-degree flag bits
    unit_stats: list[tuple[int, int, int, int, int, int]] = field(default_factory=list)


def tile_rows(coords: np.ndarray, tile_size: int) -> list[tuple[tuple[int, int, int], np.ndarray]]:
    """[(cell, rows)] in stream order (cells in increasing lexicographic order), each tile's rows
    in its normative order."""
    cells = tile_cells(coords, tile_size)
    _, inverse = np.unique(cell_keys(cells), return_inverse=True)  # lexicographic order of cells
    inverse = inverse.reshape(-1)
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(int(inverse.max(initial=-1)) + 2))
    out = []
    for t in range(bounds.size - 1):
        rows = order[bounds[t]:bounds[t + 1]]
        cell = tuple(int(x) for x in cells[rows[0]])
        out.append((cell, rows[normative_order(coords[rows])]))
    return out


def tile_levels(coords: np.ndarray, ps) -> tuple[list[tuple[int, np.ndarray]], object]:
    """The attribute levels of a tile (rows within the tile) and its hierarchy: level 2 only when
    the tile has level-2 points (clause 13.2)."""
    if not ps.hierarchy_enabled_flag:
        return [(LEVEL_ALL, np.arange(coords.shape[0]))], None
    hier = build_hierarchy(coords, ps.coarse_voxel_scale)
    levels = [(LEVEL_1, hier.level1_idx)]
    if hier.num_level2:
        levels.append((LEVEL_2, hier.level2_idx))
    return levels, hier


def tile_input(inp, rows: np.ndarray):
    """The AttributeInput of the tile holding ``rows`` of ``inp`` (in the tile's order)."""
    def part(a):
        return None if a is None else a[rows]
    return AttributeInput(inp.parameter_set, inp.layout, inp.steps, inp.values[rows], inp.live[rows], part(inp.mask),
                          inp.coords[rows], part(inp.step_adjust), part(inp.sh_degrees), quantized=inp.quantized)


def code_tile(tinp, cfg, context_payload: bytes | None, unit_stats: list,
              neighbour_unit=None) -> tuple[list[bytes], np.ndarray]:
    """The attribute units of a tile (``tinp``: its AttributeInput) and its decoded values. Level 2
    with the stream's context model where it codes smaller than the tile's own prior; with the
    stream's neighbour_prediction unit, the tile's one unit is coded with it."""
    coords = tinp.coords
    levels, hier = tile_levels(coords, tinp.parameter_set)
    predict = bool(tinp.layout.channel_prediction_allowed) and channel_prediction_on(cfg)
    model = None if context_payload is None else read_context_model(context_payload, tinp.layout)
    trecon = np.zeros_like(tinp.values, dtype=np.float32)
    payloads, q_level1 = [], None
    for level, lrows in levels:
        coder = LevelCoder(tinp.layout, cfg, level, lrows, tinp.live[lrows],
                           None if tinp.mask is None else tinp.mask[lrows], predict)
        if neighbour_unit is not None:
            q = quantized_level(coder, tinp)
            chosen = code_with_neighbours(coder, q, neighbour_coding_of(q, coords, cfg, tinp.layout, predict,
                                                                       neighbour_unit, tinp.step_adjust,
                                                                       tinp.sh_degrees))
        else:
            chosen = code_with_prior(coder, quantized_level(coder, tinp))
        if level == LEVEL_2 and model is not None:
            with_model = code_with_model(coder, tinp, hier, q_level1, model)
            if len(with_model.payload) < len(chosen.payload):
                chosen = with_model
        if level == LEVEL_1:
            q_level1 = chosen.q
        payloads.append(chosen.payload)
        h = chosen.header
        unit_stats.append((level, h.context_model_id, 8 * sum(h.chunk_size), h.num_channel_predictions,
                           8 * sum(h.adjust_chunk_size), 8 * sum(h.degree_chunk_size)))
        reconstruct_level(trecon, lrows, chosen, tinp.steps, tinp.layout)
    return payloads, trecon


@dataclass
class TileJob:
    """What every tile of a scene is coded with: the configuration, the stream's context model
    and neighbour_prediction units, and ``make_scene(coords, values, mask)``, the decoded scene of
    some points (for the tile's hash). Small: a worker process or a Ray task gets it once."""
    cfg: object
    context_payload: bytes | None
    neighbour_unit: object
    make_scene: Callable


def code_one_tile(job: TileJob, cell, rows: np.ndarray, tinp) -> tuple[TileCoding, np.ndarray]:
    """One tile, from its own input alone -> (its coding with its hash, its decoded values): the
    same in this process, a worker process or a Ray task (encoder/stream/tile_workers.py)."""
    tile = TileCoding(cell, rows, encode_geometry(tinp.coords), [])
    tile.attributes, trecon = code_tile(tinp, job.cfg, job.context_payload, tile.unit_stats, job.neighbour_unit)
    tile.scene_hash = digest_of(job.make_scene(tinp.coords, trecon, tinp.mask))
    return tile, trecon


def tile_level_stats(tiles: list[TileCoding], stats) -> None:
    """The stats of a tiled stream's attribute units: per level, their bytes, the context used
    (the model of most of the level's tiles, and how many use it), channel predictions."""
    from ...common.context.models import CONTEXT_MODEL_NAMES
    from .stats import LevelStats

    stats.num_tiles = len(tiles)
    stats.attribute_coded_bits = sum(u[2] for t in tiles for u in t.unit_stats)
    if any(u[4] for t in tiles for u in t.unit_stats):
        stats.step_adjust_coded_bits = sum(u[4] for t in tiles for u in t.unit_stats)
    if any(u[5] for t in tiles for u in t.unit_stats):
        stats.sh_degree_coded_bits = sum(u[5] for t in tiles for u in t.unit_stats)
    for level in sorted({u[0] for t in tiles for u in t.unit_stats}):
        units = [(u, len(p)) for t in tiles for u, p in zip(t.unit_stats, t.attributes) if u[0] == level]
        (model_id, count), = Counter(u[1] for u, _ in units).most_common(1)
        name = CONTEXT_MODEL_NAMES[model_id] + ("" if count == len(units) else f" ({count} of {len(units)} tiles)")
        old = stats.levels.get(level)
        preds = None if old is None or old.channel_predictions is None else sum(u[3] for u, _ in units)
        stats.levels[level] = LevelStats(name, sum(b for _, b in units), preds, None if old is None else old.context_fit)


def tile_units(tiles: list[TileCoding], num_points: int) -> list[DataUnit]:
    """The tile_index unit (when the stream has tiles) and every tile's units."""
    body = []
    sizes = []
    for tile in tiles:
        units = [DataUnit(UnitType.GEOMETRY, tile.geometry)] + [DataUnit(UnitType.ATTRIBUTE, p)
                                                               for p in tile.attributes]
        units.append(DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=tile.scene_hash).to_bytes()))
        sizes.append(sum(u.size for u in units))
        body += units
    if len(tiles) == 1 and tiles[0].cell is None:
        return body
    cells = [t.cell for t in tiles]
    index = TileIndex(num_points=num_points, num_tiles_minus1=len(tiles) - 1, tile_x=[c[0] for c in cells],
                      tile_y=[c[1] for c in cells], tile_z=[c[2] for c in cells],
                      tile_num_points_minus1=[t.rows.size - 1 for t in tiles], tile_data_size=sizes)
    if max(sizes) > (1 << 32) - 2:
        raise InputError("a tile's units exceed 2^32 - 2 bytes; use smaller tiles (tile_points)")
    return [DataUnit(UnitType.TILE_INDEX, index.to_bytes())] + body
