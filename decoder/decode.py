"""The decoding process (spec clause 13): bitstream in, scene out, nothing else needed.

Critical data units come in the order (clause 6.3, version 1)
    scene_parameter_set, [render_model], [context_model], [tile_index], tile+
for an anchor scene, or
    gaussian_parameter_set, [context_model], [tile_index], tile+
for an explicit-Gaussian scene, where a tile is
    geometry, attribute x (1 or 2), decoded_scene_hash
with two attribute units (level 1, then level 2) when the hierarchy is enabled and the tile's
level 2 is not empty. Without tiles (tiles_enabled_flag = 0) the stream has one tile, which
holds every point, and no tile_index unit. Each tile decodes on its own (common/tiles.py), so
tiles can be decoded in worker processes (``jobs``), a box can select some of them, and the
level-1 preview can stop after each tile's level-1 unit. Ancillary units (type >= 0x80) may appear anywhere after the parameter
set. This decoder knows one, source_info (0x80, clause 7.3.10), and returns what it says
(``DecodeResult.source_info``: the source scene's SH degree, which lghcc-dec --export uses);
it skips the others. The decoded scene and its hash never depend on an ancillary unit: a
source_info this decoder cannot parse, or a second one, is reported (``notes``) and ignored.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import re
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from ..app.progress import progress_bar

from ..common import attributes as attr
from ..common.container import AncillaryUnitType, Container, DataUnit, UnitType, read_container
from ..common.errors import (BitstreamError, HashMismatchError, ResourceLimitError, UnsupportedStreamError,
                             UsageError)
from ..common.context.models import describe_context_model, level2_coding_params, read_context_model
from ..common.geometry import decode_geometry
from ..common.hashing import digest_of
from ..common.hierarchy import Hierarchy, build_hierarchy
from ..common.knn import candidate_generator, set_candidate_threads
from ..common.render_model import read_render_model_unit
from ..app.report import SizeBreakdown, breakdown_of
from ..common.scene import AnchorScene, GaussianScene
from ..common.syntax import TraceEntry
from ..common.tiles import Box, check_points_in_cell, check_tile_index, cell_intersects_box
from ..common.neighbour_prediction import read_predicted_attribute_unit
from ..common.units import (CONTEXT_GGCONV, LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_ATTRIBUTE_VALUES, DecodedSceneHashUnit,
                            GaussianParameterSet, NeighbourPredictionUnit, RotationLengthUnit, SceneParameterSet,
                            ShDegreeUnit, ShTransformUnit, SourceInfo, StepAdjustFlagsUnit, StepAdjustUnit,
                            TileIndex)
from ..app.workers import available_cpus, shared_array
from .jobs import PREVIEW_VALUE_SHARE, WorkerPlan, plan_workers, tile_seconds
from .limits import DEFAULT_MAX_MEMORY, MemoryPlan

_LETTER = {UnitType.SCENE_PARAMETER_SET: "S", UnitType.GAUSSIAN_PARAMETER_SET: "P", UnitType.RENDER_MODEL: "R",
           UnitType.GEOMETRY: "G", UnitType.CONTEXT_MODEL: "C", UnitType.ATTRIBUTE: "A",
           UnitType.DECODED_SCENE_HASH: "H", UnitType.TILE_INDEX: "I", UnitType.NEIGHBOUR_PREDICTION: "N",
           UnitType.STEP_ADJUST: "Q", UnitType.STEP_ADJUST_FLAGS: "F", UnitType.SH_DEGREE: "B",
           UnitType.ROTATION_LENGTH: "W", UnitType.SH_TRANSFORM: "T"}
# an anchor scene, or an explicit-Gaussian scene, which has no render model but may have neighbour
# prediction (and with it step adjustment and the SH degrees), rotation lengths and the SH transform;
# then the tiles
_UNIT_ORDER = re.compile(r"(SR?|P(N(QF?)?B?)?W?T?)C?I?(GA{1,2}H)+")


@dataclass
class DecodeResult:
    scene: AnchorScene | GaussianScene
    breakdown: SizeBreakdown
    hash_checked: bool
    # the scene hash the stream carries for the whole decoded scene (a stream of one tile, decoded
    # whole); None: computed from the decoded scene when asked for (``stream_hash``)
    scene_hash_in_stream: bytes | None
    skipped_units: list[str] = field(default_factory=list)
    trace: list[TraceEntry] | None = None
    tools: list[str] = field(default_factory=list)  # the coding tools the stream uses, in words
    # the source_info unit (clause 7.3.10), when the stream has one this decoder could parse
    source_info: SourceInfo | None = None
    notes: list[str] = field(default_factory=list)  # ancillary units reported and ignored, in words
    num_tiles: int = 1  # tiles in the stream (1: a stream without tiles)
    tiles_decoded: int = 1  # of them decoded (fewer with a box)
    preview: bool = False  # only the level-1 points were decoded (max_level 1)
    # the worker processes that decoded the tiles and why (decoder/jobs.py)
    workers: WorkerPlan = field(default_factory=lambda: WorkerPlan(1, "1 process"))
    timings: dict[str, float] = field(default_factory=dict)  # seconds: parse (clause 13.1 steps 1-5), decode

    @property
    def stream_hash(self) -> bytes:
        """The SHA-256 of the decoded scene (clause 12): the stream's own for a stream of one tile;
        for a tiled stream (each tile checked against its own hash) or a partial decode, computed
        from the output, once."""
        if self.scene_hash_in_stream is None:
            self.scene_hash_in_stream = digest_of(self.scene)
        return self.scene_hash_in_stream


_KNOWN_ANCILLARY = set(AncillaryUnitType._value2member_map_)


def _order_condition(letters: str) -> str:
    """The row of clause 8.2 a unit order that ``_UNIT_ORDER`` refuses breaks: E61 (a case of E14 with
    a row of its own) when the neighbour_prediction units alone are wrong (in an anchor stream,
    repeated, or not right after the gaussian_parameter_set), else E14."""
    if "N" in letters:
        rest = letters.replace("N", "")
        if _UNIT_ORDER.fullmatch(rest.replace("P", "PN", 1) if rest.startswith("P") else rest):
            return "E61"
    return "E14"


def organize_units(container: Container, known: list[DataUnit] | None = None) -> tuple[list[DataUnit], list[str]]:
    """Check unit types and their order; return the critical units and the skipped ones (the
    ancillary units this decoder does not know). The ancillary units it knows (clause 6.3)
    are appended to ``known`` when given, else skipped too."""
    critical: list[DataUnit] = []
    skipped: list[str] = []
    for idx, u in enumerate(container.units):
        if u.is_ancillary:
            if not critical:
                raise BitstreamError(f"data unit {idx}: an ancillary unit precedes the scene parameter set (or gaussian parameter set)", condition="E11")
            if known is not None and u.unit_type in _KNOWN_ANCILLARY:
                known.append(u)
            else:
                skipped.append(f"{u.type_name} ({len(u.payload)} bytes at byte {u.offset})")
        elif u.unit_type in _LETTER:
            critical.append(u)
        else:
            raise UnsupportedStreamError(f"data unit {idx} has unit type 0x{u.unit_type:02x}, which this "
                                         "decoder does not know and which is not marked ancillary", condition="E10")
    letters = "".join(_LETTER[UnitType(u.unit_type)] for u in critical)
    if "S" not in letters and "P" not in letters:
        raise BitstreamError("the stream has no scene_parameter_set or gaussian_parameter_set unit", condition="E12")
    for t in (UnitType.GEOMETRY, UnitType.ATTRIBUTE, UnitType.DECODED_SCENE_HASH):
        if _LETTER[t] not in letters:
            raise BitstreamError(f"the stream has no {t.name.lower()} unit", condition="E13")
    if not _UNIT_ORDER.fullmatch(letters):
        names = ", ".join(u.type_name for u in critical)
        raise BitstreamError(f"data units are out of order or repeated: {names} (expected scene_parameter_set, "
                             "[render_model], [context_model], [tile_index], then per tile geometry, attribute "
                             "(1 or 2), decoded_scene_hash; or gaussian_parameter_set, [neighbour_prediction [step_adjust "
                             "[step_adjust_flags]] [sh_degree]], "
                             "[rotation_length], [sh_transform], "
                             "[context_model], "
                             "[tile_index], then the tiles)", condition=_order_condition(letters))
    if "I" not in letters and letters.count("G") > 1:
        raise BitstreamError(f"the stream has {letters.count('G')} tiles (geometry units) but no tile_index unit", condition="E54")
    return critical, skipped


@dataclass
class TileUnits:
    """The units of one tile (clause 7.3.11): its cell (None: the one tile of a stream without
    tiles), its point count, geometry, attribute units and decoded_scene_hash unit."""
    cell: tuple[int, int, int] | None
    num_points: int
    geometry: DataUnit
    attributes: list[DataUnit]
    scene_hash: DataUnit


def _tile_groups(units: list[DataUnit]) -> list[list[DataUnit]]:
    """The critical units from the first geometry unit on, cut after each decoded_scene_hash."""
    start = next(i for i, u in enumerate(units) if u.unit_type == UnitType.GEOMETRY)
    groups, cur = [], []
    for u in units[start:]:
        cur.append(u)
        if u.unit_type == UnitType.DECODED_SCENE_HASH:
            groups.append(cur)
            cur = []
    return groups


def tiles_of(units: list[DataUnit], by_type: dict[int, list[DataUnit]], n: int, entries) -> tuple[list[TileUnits],
                                                                                                   TileIndex | None]:
    """The tiles of the stream, checked against its tile index (clause 7.3.11): each tile's units
    start at the byte the index gives and take tile_data_size bytes, so the index can be used to
    seek. Raises BitstreamError."""
    groups = _tile_groups(units)
    if UnitType.TILE_INDEX not in by_type:
        g = groups[0]
        return [TileUnits(None, n, g[0], g[1:-1], g[-1])], None
    iu = by_type[UnitType.TILE_INDEX][0]
    index = TileIndex.from_bytes(iu.payload, entries, what="tile index unit", num_points=n)
    check_tile_index(index, n)
    if index.num_tiles != len(groups):
        raise BitstreamError(f"tile_index_unit lists {index.num_tiles} tiles, the stream holds {len(groups)}", condition="E55")
    pos = iu.offset + iu.size
    tiles = []
    for t, g in enumerate(groups):
        end = g[-1].offset + g[-1].size
        at = g[0].offset
        for u in g:  # the tile's units one after the other: no ancillary unit among them
            if u.offset != at:
                raise BitstreamError(f"tile {t}: an ancillary unit stands among its units (at byte {at}); the tiles "
                                     "hold only their critical units", condition="E55")
            at += u.size
        if g[0].offset != pos or end - pos != index.tile_data_size[t]:
            raise BitstreamError(f"tile_index_unit: tile {t} is said to take {index.tile_data_size[t]} bytes at byte "
                                 f"{pos}, its units take {end - g[0].offset} bytes at byte {g[0].offset}", condition="E55")
        tiles.append(TileUnits(index.cells[t], index.tile_num_points_minus1[t] + 1, g[0], g[1:-1], g[-1]))
        pos = end
    return tiles, index


@dataclass
class _Levels:
    """What the attribute units of a scene decode into."""
    values: np.ndarray  # float32 [N, M]
    mask: np.ndarray | None  # bool [N, K] (anchor scenes with offset masks)
    hierarchy: Hierarchy | None


def read_context_model_unit(context_unit: DataUnit | None, ps, layout, entries):
    """The stream's context model (None without a context_model unit). Raises BitstreamError."""
    if context_unit is None:
        return None
    if not ps.hierarchy_enabled_flag:
        raise BitstreamError("a context model unit in a stream without the hierarchy", condition="E16")
    return read_context_model(context_unit.payload, layout, entries)


def read_neighbour_prediction_unit(unit: DataUnit | None, ps, layout, entries,
                                   step_adjust_unit: DataUnit | None = None,
                                   sh_degree_unit: DataUnit | None = None,
                                   step_flags_unit: DataUnit | None = None) -> NeighbourPredictionUnit | None:
    """The stream's neighbour_prediction unit (None without one), with the stream's step_adjust,
    step_adjust_flags and sh_degree units as its context (the unit order puts them only after a
    neighbour_prediction unit, the step_adjust_flags unit only after the step_adjust unit). Raises
    BitstreamError."""
    if unit is None:
        return None
    if ps.hierarchy_enabled_flag:
        raise BitstreamError("a neighbour_prediction unit in a stream with the hierarchy (hierarchy_enabled_flag 1)", condition="E60")
    neighbour = NeighbourPredictionUnit.from_bytes(unit.payload, entries, what="neighbour prediction unit",
                                                   num_channels=layout.num_channels)
    if step_adjust_unit is not None:
        neighbour.step_adjust = StepAdjustUnit.from_bytes(step_adjust_unit.payload, entries, what="step_adjust unit")
    if step_flags_unit is not None:
        neighbour.step_flags = StepAdjustFlagsUnit.from_bytes(step_flags_unit.payload, entries,
                                                              what="step_adjust_flags unit",
                                                              max_step_adjust=neighbour.step_adjust.max_step_adjust)
    if sh_degree_unit is not None:
        neighbour.sh_degree_unit = ShDegreeUnit.from_bytes(sh_degree_unit.payload, entries, what="sh_degree unit",
                                                           sh_degree=ps.sh_degree)
    return neighbour


def decode_predicted_attribute_units(attribute_units: list[DataUnit], layout, steps: np.ndarray, coords: np.ndarray,
                                    unit: NeighbourPredictionUnit, entries, progress: bool,
                                    memory: MemoryPlan | None = None) -> _Levels:
    """The attribute unit of a tile of a stream with a neighbour_prediction unit (clause 11.7):
    exactly one per tile."""
    n = coords.shape[0]
    if len(attribute_units) != 1:
        raise BitstreamError(f"a tile of {n} points without the hierarchy has {len(attribute_units)} attribute "
                             "units, not 1", condition="E63")
    values = np.empty((n, layout.num_channels), dtype=np.float32)
    if memory is not None:
        memory.check_predicted_attribute_unit(n, unit)
    bar = progress_bar(total=n, desc="decode attributes", unit="point", disable=not progress, leave=False)
    read_predicted_attribute_unit(attribute_units[0].payload, layout, steps, coords, unit, values, entries,
                                  on_chunk=bar.update, step_adjust=unit.step_adjust, sh_degree=unit.sh_degree_unit,
                                  step_flags=unit.step_flags)
    bar.close()
    return _Levels(values, None, None)


def decode_attribute_units(attribute_units: list[DataUnit], layout, steps: np.ndarray, coords: np.ndarray,
                           ps, context_model, entries, progress: bool,
                           memory: MemoryPlan | None = None, max_level: int = LEVEL_2) -> _Levels:
    """Decode the attribute units of a tile (clause 13 steps 5-7): level 1 (or every point) with
    its per-channel prior, then level 2 with the context model when there is one; a tile whose
    level 2 is empty has one unit. ``ps``: the parameter set (hierarchy flag and coarse voxel
    scale). ``memory``: the memory plan each unit is checked against before it is decoded.
    ``max_level`` 1: stop after level 1 (the preview; level-2 rows are left undefined).
    ``context_model``: the stream's context model as decoded, or its neighbour_prediction unit (a
    stream has at most one of them: one needs the hierarchy, the other its absence)."""
    n = coords.shape[0]
    if isinstance(context_model, NeighbourPredictionUnit):
        return decode_predicted_attribute_units(attribute_units, layout, steps, coords, context_model, entries,
                                                progress, memory)
    hier = None
    if ps.hierarchy_enabled_flag:
        hier = build_hierarchy(coords, ps.coarse_voxel_scale)
        levels = [(LEVEL_1, hier.level1_idx)] + ([(LEVEL_2, hier.level2_idx)] if hier.num_level2 else [])
    else:
        levels = [(LEVEL_ALL, None)]
    if len(attribute_units) != len(levels):
        raise BitstreamError(f"a tile of {n} points with hierarchy_enabled_flag = {ps.hierarchy_enabled_flag} "
                             + (f"and {hier.num_level2} level-2 points " if hier is not None else "")
                             + f"has {len(attribute_units)} attribute units, not {len(levels)}", condition="E15")
    if max_level == LEVEL_1:
        levels = levels[:1]
    values = np.empty((n, layout.num_channels), dtype=np.float32)
    mask = np.ones((n, layout.num_offsets), dtype=bool) if layout.offset_mask_present else None
    q_level1 = None

    def level2_context(model_id: int) -> attr.CodingParams:
        if context_model is None or model_id != context_model[0]:
            raise BitstreamError(f"the level-2 attribute unit uses context model {model_id}, but the stream's "
                                 "context model unit " + ("is missing" if context_model is None else
                                                          f"holds model {context_model[0]}"), condition="E47")
        return level2_coding_params(context_model, coords[hier.level1_idx], q_level1, coords[hier.level2_idx],
                                    hier.parent_of_level2, ps.coarse_voxel_scale)

    bar = progress_bar(total=n, desc="decode attributes", unit="point", disable=not progress, leave=False)
    for unit, (level, rows) in zip(attribute_units, levels):
        num_rows = n if rows is None else rows.size
        if memory is not None:
            memory.check_attribute_unit(unit.payload, num_rows, level, context_model,
                                        hier.num_level1 if rows is not None else None)
        _, m, q = attr.read_attribute_unit(unit.payload, layout, steps, num_rows, level, values, rows,
                                           level2_context if level == LEVEL_2 else None, entries,
                                           keep_q=level == LEVEL_1 and context_model is not None,
                                           on_chunk=bar.update)
        if level == LEVEL_1:
            q_level1 = q
        if mask is not None:
            mask[slice(None) if rows is None else rows] = m
    bar.close()
    return _Levels(values, mask, hier)


@dataclass
class DecodedTile:
    """What one tile decodes to: its points in normative order, their attribute values and
    offset mask, and whether its decoded_scene_hash was checked."""
    coords: np.ndarray | None  # None: written into the shared output (worker processes)
    values: np.ndarray | None
    mask: np.ndarray | None
    hash_checked: bool
    level_counts: tuple[int, int] | None = None  # N1, N2 of the tile's hierarchy

    @property
    def num_points(self) -> int:
        return 0 if self.coords is None else int(self.coords.shape[0])


def decode_tile(tile: TileUnits, t: int, ps, layout, context_model, mlps: dict, tile_size: int, *,
                verify_hash: bool = True, entries=None, progress: bool = False, memory: MemoryPlan | None = None,
                max_level: int = LEVEL_2) -> DecodedTile:
    """Decode one tile on its own (clause 13.2): geometry, attribute units, and its hash (the
    hash of the tile's points as a scene). ``max_level`` 1: only the level-1 points (the
    preview; no hash can be checked)."""
    coords = decode_geometry(tile.geometry.payload, tile.num_points, entries)
    if tile.cell is not None:
        check_points_in_cell(coords, tile.cell, tile_size, t)
    dec = decode_attribute_units(tile.attributes, layout, layout.steps(ps), coords, ps, context_model, entries,
                                 progress, memory, max_level)
    hash_unit = DecodedSceneHashUnit.from_bytes(tile.scene_hash.payload, entries, what="decoded scene hash unit")
    h = dec.hierarchy
    counts = None if h is None else (h.num_level1, h.num_level2)
    if max_level == LEVEL_1 and h is not None:
        keep = h.level1_idx
        return DecodedTile(coords[keep], dec.values[keep], None if dec.mask is None else dec.mask[keep], False, counts)
    if verify_hash:
        scene = _scene_of(ps, layout, coords, dec, mlps)
        _check_scene_hash(scene, hash_unit.scene_hash, "" if tile.cell is None else f"tile {t}: ")
    return DecodedTile(coords, dec.values, dec.mask, verify_hash, counts)


# The output arrays the worker processes write their tiles into: created by the parent before the
# workers are forked, in shared anonymous memory, so a tile's values are not sent back through a
# pipe (at 1M anchors of 86 channels they are 344 MB).
_SHARED_OUTPUT: dict[str, np.ndarray] = {}


def _decode_tile_job(job: tuple[int, int | None]) -> DecodedTile:
    """A worker process's task (lghcc-dec --jobs): one tile, from the tile's own units (the stream's
    state came with the worker, ``init_tile_worker``); with an output row, its points are written into
    the shared output and only the verdict comes back."""
    t, row = job
    tiles, ps, layout, context_model, mlps, verify_hash, max_level = _WORKER_STATE
    d = decode_tile(tiles[t], t, ps, layout, context_model, mlps, ps.tile_size, verify_hash=verify_hash,
                    max_level=max_level)
    if row is None:
        return d
    n = d.num_points
    _SHARED_OUTPUT["coords"][row:row + n] = d.coords
    _SHARED_OUTPUT["values"][row:row + n] = d.values
    if d.mask is not None:
        _SHARED_OUTPUT["mask"][row:row + n] = d.mask
    return DecodedTile(None, None, None, d.hash_checked, d.level_counts)


def _decode_in_workers(tiles: list[TileUnits], selected: list[int], ps, layout, context_model, mlps: dict, *,
                       verify_hash: bool, max_level: int, workers: int) -> tuple[list[DecodedTile], dict | None]:
    """The selected tiles decoded by ``workers`` forked worker processes, written into shared output
    arrays (whole tiles: their point counts are known; the preview's are not, and come back
    through the pipe) -> (the tiles' verdicts, the output arrays or None)."""
    fork = os.name == "posix"
    shared = fork and max_level != LEVEL_1
    rows: list[int | None] = [None] * len(selected)
    if shared:
        counts = [tiles[t].num_points for t in selected]
        rows = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
        total = sum(counts)
        _SHARED_OUTPUT.update(coords=shared_array((total, 3), np.int64),
                              values=shared_array((total, layout.num_channels), np.float32))
        if layout.offset_mask_present:
            _SHARED_OUTPUT["mask"] = shared_array((total, layout.num_offsets), np.bool_)
    jobs = list(zip(selected, rows))
    # the largest tiles first, so that no large tile is left to one worker at the end
    order = sorted(range(len(jobs)), key=lambda i: -tiles[selected[i]].num_points)
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    if fork and context_model is not None:
        candidate_generator()  # loaded once here, shared by the forked workers
    # the stream's state goes to each worker once (forked: not even copied), a task is a tile number
    state = (tiles, ps, layout, context_model, mlps, verify_hash, max_level)
    try:
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_tile_worker,
                                 initargs=(state,)) as pool:
            done = list(pool.map(_decode_tile_job, [jobs[i] for i in order]))
        parts: list[DecodedTile] = [None] * len(jobs)  # type: ignore[list-item]
        for i, part in zip(order, done):
            parts[i] = part
        return parts, (dict(_SHARED_OUTPUT) if shared else None)
    finally:
        _SHARED_OUTPUT.clear()


# The k-NN candidate generator's threads in each worker: the workers are the parallelism, and one
# thread per CPU in each oversubscribes the cores (tools/results/tiles.md times both, alternated).
WORKER_CANDIDATE_THREADS = 1
# A worker's stream: the tiles, parameter set, layout, context model, render MLPs, verify_hash and
# max_level (set by init_tile_worker).
_WORKER_STATE: tuple = ()


def init_tile_worker(state: tuple) -> None:
    global _WORKER_STATE
    _WORKER_STATE = state
    torch = sys.modules.get("torch")  # loaded by the parent where the stream's tools need it, else not at all
    if torch is not None:
        torch.set_num_threads(1)  # the workers are the parallelism
    set_candidate_threads(WORKER_CANDIDATE_THREADS)


@dataclass
class DecodedTiles:
    """The decoded tiles joined in stream order: their points, whether every tile's hash was
    checked, and each tile's level counts (N1, N2)."""
    coords: np.ndarray
    levels: _Levels
    hash_checked: bool
    level_counts: list[tuple[int, int]]


def decode_tiles(tiles: list[TileUnits], selected: list[int], ps, layout, context_model, mlps: dict, *,
                 verify_hash: bool, entries, progress: bool, memory: MemoryPlan | None, max_level: int,
                 workers: int = 1) -> DecodedTiles:
    """The selected tiles, in stream order: here, or in ``workers`` worker processes (the result is
    the same: each tile is decoded by the same function from the same units)."""
    size = ps.tile_size
    if workers > 1 and len(selected) > 1 and entries is None:
        parts, shared = _decode_in_workers(tiles, selected, ps, layout, context_model, mlps,
                                           verify_hash=verify_hash, max_level=max_level, workers=workers)
        return _joined(parts, layout, shared)
    one = len(tiles) == 1
    bar = progress_bar(total=len(selected), desc="decode tiles", unit="tile", disable=not progress or one, leave=False)
    out = []
    for t in selected:
        out.append(decode_tile(tiles[t], t, ps, layout, context_model, mlps, size, verify_hash=verify_hash,
                               entries=entries, progress=progress and one, memory=memory, max_level=max_level))
        bar.update()
    bar.close()
    return _joined(out, layout)


def attribute_tool(ps, context_model) -> str:
    """The coding tool of the tiles' attribute units, in the words of decoder/jobs.py's costs."""
    if isinstance(context_model, NeighbourPredictionUnit):
        return "neighbour prediction"
    if context_model is None:
        return "per-channel prior"
    return "GG-Conv" if context_model[0] == CONTEXT_GGCONV else "parent MLP"


def worker_plan(tiles: list[TileUnits], selected: list[int], ps, layout, context_model, *, jobs: int | None,
                exact_jobs: bool = False, max_level: int = LEVEL_2, tracing: bool = False) -> WorkerPlan:
    """How many worker processes decode the selected tiles (decoder/jobs.py): ``jobs`` None: as many
    as pay, up to the CPUs; N: as many as pay, up to N; with ``exact_jobs``, N (or one per tile)."""
    if tracing:
        return WorkerPlan(1, "1 process (the bit trace follows the stream's order)")
    if exact_jobs and jobs is not None:
        n = max(1, min(jobs, len(selected)))
        return WorkerPlan(n, f"{n} worker process{'es' if n > 1 else ''} as asked" if n > 1 else "1 process as asked")
    bound = available_cpus() if jobs is None else jobs
    asked = f"--jobs auto, {bound} CPUs" if jobs is None else f"--jobs {jobs}: at most {jobs}"
    preview = max_level == LEVEL_1
    tool = "per-channel prior" if preview else attribute_tool(ps, context_model)
    share = PREVIEW_VALUE_SHARE if preview else 1.0
    costs = [tile_seconds(tiles[t].num_points, layout.num_channels, tool, share) for t in selected]
    return plan_workers(costs, bound, asked)


def selected_tiles(tiles: list[TileUnits], ps, box: Box | None) -> list[int]:
    """Every tile, or those whose cell meets the box (a stream without tiles: its one tile)."""
    if box is None or tiles[0].cell is None:
        return list(range(len(tiles)))
    return [t for t, tile in enumerate(tiles)
            if cell_intersects_box(tile.cell, ps.tile_size, float(ps.voxel_size), ps.origin, box)]


def _joined(parts: list[DecodedTile], layout, shared: dict | None = None) -> DecodedTiles:
    """The tiles' points in stream order (``shared``: already written there by the workers)."""
    counts = [p.level_counts for p in parts if p.level_counts is not None]
    checked = all(p.hash_checked for p in parts)
    if shared is not None:
        return DecodedTiles(shared["coords"], _Levels(shared["values"], shared.get("mask"), None), checked, counts)
    if len(parts) == 1:
        p = parts[0]
        return DecodedTiles(p.coords, _Levels(p.values, p.mask, None), checked, counts)
    coords = np.concatenate([p.coords for p in parts]) if parts else np.empty((0, 3), np.int64)
    values = np.concatenate([p.values for p in parts]) if parts else np.empty((0, layout.num_channels), np.float32)
    mask = None
    if layout.offset_mask_present:
        mask = np.concatenate([p.mask for p in parts]) if parts else np.empty((0, layout.num_offsets), bool)
    return DecodedTiles(coords, _Levels(values, mask, None), checked, counts)


@dataclass
class ParsedStream:
    """What clause 13.1 steps 1 to 5 give before any tile is decoded: the container, the critical
    units (and the skipped ones), the parameter set and channel layout, the render MLPs, the
    attribute units' context (context model or neighbour_prediction unit) and the tiles."""
    container: Container
    skipped: list[str]
    ps: SceneParameterSet | GaussianParameterSet
    layout: object
    mlps: dict
    context_model: object
    tiles: list[TileUnits]
    memory: MemoryPlan
    source_info: SourceInfo | None
    notes: list[str]

    @property
    def point(self) -> str:
        return "Gaussian" if isinstance(self.ps, GaussianParameterSet) else "anchor"


def parse_stream(data: bytes, entries: list[TraceEntry] | None = None, *, max_anchors: int | None = None,
                 max_memory: int | None = DEFAULT_MAX_MEMORY, max_level: int = LEVEL_2) -> ParsedStream:
    """Clause 13.1 steps 1 to 5, made alike for a full and a partial decode: the container, the
    unit order, the parameter set and its limits, the models and the tile index. ``max_level`` 1
    on a stream without the hierarchy raises UsageError (clause 13.3: such a stream has no
    preview) once its parameter set is read."""
    container = read_container(data)
    ancillary: list[DataUnit] = []
    units, skipped = organize_units(container, ancillary)
    by_type: dict[int, list[DataUnit]] = {}
    for u in units:
        by_type.setdefault(u.unit_type, []).append(u)
    ps, layout = _read_parameter_set(by_type, entries)
    if max_level == LEVEL_1 and not ps.hierarchy_enabled_flag:
        raise UsageError(NO_PREVIEW)
    source_info, notes = read_source_info(ancillary, entries)
    _check_limits(ps, layout, max_anchors)
    memory = MemoryPlan(max_memory, ps, by_type, len(data), layout)  # refuses before anything sized by the stream exists
    if (UnitType.TILE_INDEX in by_type) != bool(ps.tiles_enabled_flag):
        raise BitstreamError(f"tiles_enabled_flag is {ps.tiles_enabled_flag} but the stream "
                             + ("has a tile_index unit" if ps.tiles_enabled_flag == 0 else "has no tile_index unit"), condition="E54")
    mlps = {}
    if UnitType.RENDER_MODEL in by_type:
        mlps = read_render_model_unit(by_type[UnitType.RENDER_MODEL][0].payload, entries)
    context_model = read_context_model_unit(by_type.get(UnitType.CONTEXT_MODEL, [None])[0], ps, layout, entries)
    neighbour = read_neighbour_prediction_unit(by_type.get(UnitType.NEIGHBOUR_PREDICTION, [None])[0], ps, layout,
                                               entries, by_type.get(UnitType.STEP_ADJUST, [None])[0],
                                               by_type.get(UnitType.SH_DEGREE, [None])[0],
                                               by_type.get(UnitType.STEP_ADJUST_FLAGS, [None])[0])
    if neighbour is not None:
        context_model = neighbour  # the attribute units' context (the stream has no context model)
    layout = with_rotation_length(layout, by_type.get(UnitType.ROTATION_LENGTH, [None])[0], entries)
    layout = with_sh_transform(layout, by_type.get(UnitType.SH_TRANSFORM, [None])[0], ps, entries)
    tiles, _ = tiles_of(units, by_type, ps.num_anchors, entries)
    return ParsedStream(container, skipped, ps, layout, mlps, context_model, tiles, memory, source_info, notes)


# lghcc-dec --level 1 on a stream without the hierarchy (clause 13.3)
NO_PREVIEW = ("the stream has no level-1 preview: it was coded without the hierarchy (hierarchy_enabled_flag 0; "
              "the lghcc-* presets code one), so --level 1 would decode the whole scene; decode it whole "
              "(--level 2, the default) or a part of it with --box")


def _check_limits(ps, layout, max_anchors: int | None) -> None:
    """The level limit on attribute values (clause 8) and the caller's bound on points."""
    point = "Gaussian" if isinstance(ps, GaussianParameterSet) else "anchor"
    n = ps.num_anchors
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise BitstreamError(f"{n} {point}s x {layout.num_channels} channels exceeds the level limit of "
                             f"{MAX_ATTRIBUTE_VALUES} attribute values", condition="E22")
    if max_anchors is not None and n > max_anchors:
        raise ResourceLimitError(f"the stream declares {n} {point}s, more than the allowed maximum {max_anchors}")


def decode_stream(data: bytes, *, verify_hash: bool = True, trace: bool = False,
                  max_anchors: int | None = None, max_memory: int | None = DEFAULT_MAX_MEMORY,
                  progress: bool = False, jobs: int | None = 1, exact_jobs: bool = False, box: Box | None = None,
                  max_level: int = LEVEL_2) -> DecodeResult:
    """Decode a stream. Raises a BitstreamError subclass naming the problem, or
    ResourceLimitError for a stream beyond ``max_anchors`` points (anchors or Gaussians) or one
    whose decoding needs more than ``max_memory`` bytes (None: no bound), computed from its
    headers before anything sized by the stream is allocated (decoder/limits.py). ``progress``
    shows a bar on stderr. ``jobs``: at most this many worker processes for the tiles, as many as
    pay by decoder/jobs.py's estimate (None: up to the CPUs; ``exact_jobs``: this many); the
    output does not depend on it. ``box``: decode only the tiles whose cell meets it (every point
    of such a tile is output). ``max_level`` 1: the level-1 preview (each tile's level-1 points;
    not hash-checked); UsageError for a stream without the hierarchy, which has none."""
    if jobs is not None and jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    t0 = time.perf_counter()
    entries: list[TraceEntry] | None = [] if trace else None
    s = parse_stream(data, entries, max_anchors=max_anchors, max_memory=max_memory, max_level=max_level)
    tiles, ps, layout = s.tiles, s.ps, s.layout
    selected = selected_tiles(tiles, ps, box)
    plan = worker_plan(tiles, selected, ps, layout, s.context_model, jobs=jobs, exact_jobs=exact_jobs,
                       max_level=max_level, tracing=entries is not None)
    t1 = time.perf_counter()
    decoded = decode_tiles(tiles, selected, ps, layout, s.context_model, s.mlps, verify_hash=verify_hash,
                           entries=entries, progress=progress, memory=s.memory, max_level=max_level,
                           workers=plan.workers)
    scene = _scene_of(ps, layout, decoded.coords, decoded.levels, s.mlps)
    whole = len(selected) == len(tiles) and max_level != LEVEL_1
    stream_hash = None  # a tiled stream carries no hash of the whole scene: computed when asked for
    if whole and len(tiles) == 1:
        stream_hash = DecodedSceneHashUnit.from_bytes(tiles[0].scene_hash.payload).scene_hash
    n = ps.num_anchors
    return DecodeResult(scene, breakdown_of(s.container, n, s.point), verify_hash and decoded.hash_checked,
                        stream_hash, s.skipped, entries, _stream_tools(ps, decoded, s.context_model, s.point,
                                                                      len(tiles), s.layout),
                        s.source_info, s.notes, len(tiles), len(selected), max_level == LEVEL_1, plan,
                        {"parse": t1 - t0, "decode": time.perf_counter() - t1})


def with_rotation_length(layout, unit: DataUnit | None, entries):
    """The layout of a stream with a rotation_length unit (clause 7.3.15): its channel w carries
    the length index (clause 11.10); ``layout`` itself without one."""
    if unit is None:
        return layout
    rl = RotationLengthUnit.from_bytes(unit.payload, entries, what="rotation_length unit")
    return dataclasses.replace(layout, max_rotation_length_index=rl.max_rotation_length_index)


def with_sh_transform(layout, unit: DataUnit | None, ps, entries):
    """The layout of a stream with an sh_transform unit (clause 7.3.17): its SH-rest channels carry
    transform coefficients (clause 11.11); ``layout`` itself without one."""
    if unit is None:
        return layout
    st = ShTransformUnit.from_bytes(unit.payload, entries, what="sh_transform unit", sh_degree=ps.sh_degree)
    return dataclasses.replace(layout, sh_transform=attr.ShTransform.from_unit(st))


def _read_parameter_set(by_type: dict[int, list[DataUnit]], entries) -> tuple[SceneParameterSet | GaussianParameterSet,
                                                                              object]:
    """The stream's parameter set (an explicit-Gaussian stream's, else the anchor scene's) and
    its channel layout."""
    if UnitType.GAUSSIAN_PARAMETER_SET in by_type:
        ps = GaussianParameterSet.from_bytes(by_type[UnitType.GAUSSIAN_PARAMETER_SET][0].payload, entries,
                                             what="gaussian parameter set")
        return ps, attr.gaussian_layout_of(ps)
    ps = SceneParameterSet.from_bytes(by_type[UnitType.SCENE_PARAMETER_SET][0].payload, entries,
                                      what="scene parameter set")
    return ps, attr.layout_of(ps)


def _scene_of(ps, layout, coords: np.ndarray, dec: _Levels, mlps: dict) -> AnchorScene | GaussianScene:
    """The decoded scene: positions on the grid of the parameter set, attributes split by the layout."""
    if isinstance(ps, GaussianParameterSet):
        sh, opacity, log_scales, rotations = layout.split(dec.values)
        return GaussianScene.on_grid(coords, float(ps.voxel_size), ps.origin, sh, opacity, log_scales, rotations)
    features, scalings, offsets = layout.split(dec.values)
    return AnchorScene(coords=coords, voxel_size=float(ps.voxel_size), origin=np.asarray(ps.origin, dtype=np.float32),
                       features=features, scalings=scalings, offsets=offsets, offset_mask=dec.mask, mlps=mlps)


def _check_scene_hash(scene: AnchorScene | GaussianScene, scene_hash: bytes, where: str = "") -> None:
    """Clause 12: the SHA-256 of the decoded scene (of a tile's points, in a tiled stream) must
    equal the decoded_scene_hash of the stream (of the tile)."""
    digest = digest_of(scene)
    if digest != scene_hash:
        raise HashMismatchError(f"{where}the decoded scene does not match the hash in the stream "
                                f"(decoded SHA-256 {digest.hex()}, stream {scene_hash.hex()})", condition="E53")


def _stream_tools(ps, decoded: DecodedTiles, context_model, point: str, num_tiles: int = 1,
                  layout=None) -> list[str]:
    """The coding tools the stream uses, in words (lghcc-dec prints them)."""
    if isinstance(ps, GaussianParameterSet):
        tools = [f"explicit Gaussians (SH degree {ps.sh_degree})"]
        if layout is not None and layout.max_rotation_length_index >= 0:
            tools.append(f"rotations as a length index (0 to {layout.max_rotation_length_index}) and x, y, z")
        if layout is not None and layout.sh_transform is not None:
            tools.append(f"the SH rest as coefficients of a {layout.sh_transform.size} x {layout.sh_transform.size} "
                         "integer transform")
    else:
        tools = ["offset masks"] if ps.offset_mask_present_flag else []
    if ps.tiles_enabled_flag:
        tools.append(f"{num_tiles} tile{'s' if num_tiles > 1 else ''} of {ps.tile_size} voxels per side")
    if isinstance(context_model, NeighbourPredictionUnit):
        tools.append(f"neighbour prediction ({context_model.num_lods} levels of detail, "
                     f"{context_model.num_neighbours} neighbours, {context_model.num_buckets} activity buckets)")
        if context_model.step_adjust is not None:
            tools.append(f"step adjustment (a step per Gaussian, up to 2^({context_model.step_adjust.max_step_adjust}"
                         "/4) times its channel's" + (", its indices as flags" if context_model.step_flags else "") + ")")
        if context_model.sh_degree_unit is not None:
            tools.append(f"per-Gaussian SH degree (0 to {context_model.sh_degree_unit.sh_degree})")
    if not ps.hierarchy_enabled_flag:
        return tools
    n1, n2 = sum(c[0] for c in decoded.level_counts), sum(c[1] for c in decoded.level_counts)
    return tools + [f"two-level hierarchy (coarse voxels of {ps.coarse_voxel_scale}; {n1:,} level-1 and {n2:,} "
                    f"level-2 {point}s)",
                    "level-2 context: " + ("per-channel prior" if context_model is None
                                           else describe_context_model(context_model))]


def read_source_info(units: list[DataUnit], trace: list[TraceEntry] | None = None
                     ) -> tuple[SourceInfo | None, list[str]]:
    """The source_info unit among the known ancillary ``units`` (clause 7.3.10), and notes on
    what was ignored (clause 6.3): the first source_info when its elements do not fit its
    payload (or its alignment bits are not zero), and every source_info after the first, well
    formed or not (a stream has at most one). Never raises: nothing the decoded scene depends
    on is in it. Its trace entries follow the parameter set's."""
    info, notes, seen = None, [], 0
    for u in units:
        if u.unit_type != AncillaryUnitType.SOURCE_INFO:
            continue
        where = f"source_info ({len(u.payload)} bytes at byte {u.offset})"
        seen += 1
        if seen > 1:
            notes.append(f"{where}: a second source_info unit, ignored (a stream has at most one)")
            continue
        mark = None if trace is None else len(trace)
        try:
            info = SourceInfo.from_payload(u.payload, trace)
        except BitstreamError as e:
            if trace is not None:
                del trace[mark:]
            notes.append(f"{where}: cannot be parsed ({e}); ignored")
    return info, notes
