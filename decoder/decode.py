"""The reference decoder's driver: clause 13's decoding process (decoder/core.py) run for a caller.

The core decodes; this module decides how, and reports: the caller's bound on points
(``max_points``) and on memory (decoder/limits.py, checked before anything sized by the stream
is allocated), the tiles a box selects, how many worker processes decode them (decoder/jobs.py;
forked, each writing its tiles' points into shared output arrays), progress bars, the size
breakdown by unit, the coding tools in words and the timings. Nothing here changes a decoded
value: each tile is decoded by the core's ``decode_tile`` from its own units, here or in a worker.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..app.progress import progress_bar
from ..app.report import SizeBreakdown, breakdown_of
from ..app.workers import available_cpus, shared_array
from ..common.attributes import GaussianLayout
from ..common.container import DataUnit
from ..common.context.models import describe_context_model
from ..common.errors import ResourceLimitError
from ..common.hashing import digest_of
from ..common.knn import candidate_generator, set_candidate_threads
from ..common.render_model import RenderMLP
from ..common.scene import AnchorScene, GaussianScene
from ..common.syntax import TraceEntry
from ..common.tiles import Box
from ..common.units import LEVEL_1, LEVEL_2, DecodedSceneHashUnit, GaussianParameterSet, NeighbourPredictionUnit, SourceInfo
from . import core
from .core import (NO_PREVIEW, AttributeContext, DecodedAttributes, DecodedTile, GgconvContext, Layout,
                   ParameterSet, ParsedStream, TileUnits, organize_units, read_source_info, selected_tiles, tiles_of)
from .jobs import PREVIEW_VALUE_SHARE, WorkerPlan, plan_workers, tile_seconds
from .limits import DEFAULT_MAX_MEMORY, MemoryPlan

# what the tests, tools and the library import from here (the core's names included)
__all__ = ["DecodeResult", "DecodedTiles", "NO_PREVIEW", "ParsedStream", "TileUnits", "attribute_tool",
           "decode_stream", "decode_tiles", "organize_units", "parse_stream", "read_source_info", "selected_tiles",
           "tiles_of", "worker_plan"]


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


# --- parsing with the caller's bounds ----------------------------------------------------------

def check_max_points(ps: ParameterSet, max_points: int | None) -> None:
    """The caller's bound on points (anchors or Gaussians): ResourceLimitError beyond it."""
    n = ps.num_points
    if max_points is not None and n > max_points:
        raise ResourceLimitError(f"the stream declares {n} {core.point_word(ps)}s, more than the allowed maximum "
                                 f"{max_points}")


def parse_with_bounds(data: bytes, entries: list[TraceEntry] | None, *, max_points: int | None,
                      max_memory: int | None, max_level: int) -> tuple[ParsedStream, MemoryPlan]:
    """Clause 13.1 steps 1 to 5 (``core.parse_stream``), refusing a stream beyond ``max_points``
    points or ``max_memory`` bytes once its parameter set is read; -> (the stream, its memory plan)."""
    plans: list[MemoryPlan] = []

    def admit(ps: ParameterSet, layout: Layout, by_type: dict[int, list[DataUnit]]) -> None:
        check_max_points(ps, max_points)
        # refuses before anything sized by the stream exists
        plans.append(MemoryPlan(max_memory, ps, by_type, len(data), layout))

    parsed = core.parse_stream(data, entries, max_level=max_level, admit=admit)
    return parsed, plans[0]


def parse_stream(data: bytes, entries: list[TraceEntry] | None = None, *, max_points: int | None = None,
                 max_memory: int | None = DEFAULT_MAX_MEMORY, max_level: int = LEVEL_2) -> ParsedStream:
    """Clause 13.1 steps 1 to 5, made alike for a full and a partial decode: the container, the
    unit order, the parameter set and its limits (and the caller's: ``max_points``,
    ``max_memory``), the models and the tile index. ``max_level`` 1 on a stream without the
    hierarchy raises UsageError (clause 13.3: such a stream has no preview)."""
    return parse_with_bounds(data, entries, max_points=max_points, max_memory=max_memory, max_level=max_level)[0]


# --- the tiles: here or in worker processes ----------------------------------------------------

@dataclass
class TileVerdict:
    """What a worker process sends back for a tile whose points it wrote into the shared output."""
    hash_checked: bool
    level_counts: tuple[int, int] | None


@dataclass
class DecodedTiles:
    """The decoded tiles joined in stream order: their points, whether every tile's hash was
    checked, and each tile's level counts (N1, N2)."""
    coords: np.ndarray
    levels: DecodedAttributes
    hash_checked: bool
    level_counts: list[tuple[int, int]]


# The output arrays the worker processes write their tiles into: created by the parent before the
# workers are forked, in shared anonymous memory, so a tile's values are not sent back through a
# pipe (at 1M anchors of 86 channels they are 344 MB).
_SHARED_OUTPUT: dict[str, np.ndarray] = {}
# The k-NN candidate generator's threads in each worker: the workers are the parallelism, and one
# thread per CPU in each oversubscribes the cores (tools/results/tiles.md times both, alternated).
WORKER_CANDIDATE_THREADS = 1


@dataclass(frozen=True)
class WorkerStream:
    """The stream as a worker process needs it (sent once, when the worker starts; forked: not
    even copied): the tiles, parameter set, layout, attribute context, render MLPs, verify_hash
    and max_level."""
    tiles: list[TileUnits]
    ps: ParameterSet
    layout: Layout
    context_model: AttributeContext
    mlps: dict[str, RenderMLP]
    verify_hash: bool
    max_level: int


# A worker's stream (set by init_tile_worker).
_WORKER_STATE: WorkerStream | None = None


def init_tile_worker(state: WorkerStream | None) -> None:
    global _WORKER_STATE
    _WORKER_STATE = state
    torch = sys.modules.get("torch")  # loaded by the parent where the stream's tools need it, else not at all
    if torch is not None:
        torch.set_num_threads(1)  # the workers are the parallelism
    set_candidate_threads(WORKER_CANDIDATE_THREADS)


def _decode_tile_job(job: tuple[int, int | None]) -> DecodedTile | TileVerdict:
    """A worker process's task (lghcc-dec --jobs): one tile, from the tile's own units (the stream's
    state came with the worker, ``init_tile_worker``); with an output row, its points are written into
    the shared output and only the verdict comes back."""
    t, row = job
    s = _WORKER_STATE
    assert s is not None, "init_tile_worker runs before any task"
    d = core.decode_tile(s.tiles[t], t, s.ps, s.layout, s.context_model, s.mlps, verify_hash=s.verify_hash,
                         max_level=s.max_level)
    if row is None:
        return d
    return _write_rows(_SHARED_OUTPUT, row, d)


def _write_rows(out: dict[str, np.ndarray], row: int, d: DecodedTile) -> TileVerdict:
    """A decoded tile's points written into the output arrays from ``row`` on -> its verdict."""
    n = d.num_points
    out["coords"][row:row + n] = d.coords
    out["values"][row:row + n] = d.values
    if d.mask is not None:
        out["mask"][row:row + n] = d.mask
    return TileVerdict(d.hash_checked, d.level_counts)


def _output_arrays(tiles: list[TileUnits], selected: list[int], layout: Layout,
                   alloc: Callable[..., np.ndarray]) -> tuple[list[int], dict[str, np.ndarray]]:
    """The output arrays of the selected tiles' points (made by ``alloc(shape, dtype)``) and each
    tile's first row in them."""
    counts = [tiles[t].num_points for t in selected]
    rows = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
    total = sum(counts)
    out = {"coords": alloc((total, 3), np.int64), "values": alloc((total, layout.num_channels), np.float32)}
    if layout.offset_mask_present:
        out["mask"] = alloc((total, layout.num_offsets), np.bool_)
    return rows, out


def _shared_rows(tiles: list[TileUnits], selected: list[int], layout: Layout) -> list[int | None]:
    """Each selected tile's first row in the shared output arrays, which are made here."""
    rows, out = _output_arrays(tiles, selected, layout, shared_array)
    _SHARED_OUTPUT.update(out)
    return list(rows)


def _decode_in_workers(stream: WorkerStream, selected: list[int],
                       workers: int) -> tuple[list[DecodedTile | TileVerdict], dict[str, np.ndarray] | None]:
    """The selected tiles decoded by ``workers`` forked worker processes, written into shared output
    arrays (whole tiles: their point counts are known; the preview's are not, and come back
    through the pipe) -> (the tiles' verdicts, the output arrays or None)."""
    fork = os.name == "posix"
    shared = fork and stream.max_level != LEVEL_1
    rows: list[int | None] = _shared_rows(stream.tiles, selected, stream.layout) if shared else [None] * len(selected)
    jobs = list(zip(selected, rows))
    # the largest tiles first, so that no large tile is left to one worker at the end
    order = sorted(range(len(jobs)), key=lambda i: -stream.tiles[selected[i]].num_points)
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    if fork and stream.context_model is not None:
        candidate_generator()  # loaded once here, shared by the forked workers
    try:
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_tile_worker,
                                 initargs=(stream,)) as pool:
            done = list(pool.map(_decode_tile_job, [jobs[i] for i in order]))
        parts: list[DecodedTile | TileVerdict] = list(done)
        for i, part in zip(order, done):
            parts[i] = part
        return parts, (dict(_SHARED_OUTPUT) if shared else None)
    finally:
        _SHARED_OUTPUT.clear()


def _joined(parts: list[DecodedTile | TileVerdict], layout: Layout,
            shared: dict[str, np.ndarray] | None = None) -> DecodedTiles:
    """The tiles' points in stream order (``shared``: already written there by the workers)."""
    counts = [p.level_counts for p in parts if p.level_counts is not None]
    checked = all(p.hash_checked for p in parts)
    if shared is not None:
        return DecodedTiles(shared["coords"], DecodedAttributes(shared["values"], shared.get("mask"), None), checked,
                            counts)
    tiles = [p for p in parts if isinstance(p, DecodedTile)]
    coords, levels = core.join_tiles(tiles, layout)
    return DecodedTiles(coords, levels, checked, counts)


def decode_tiles(tiles: list[TileUnits], selected: list[int], ps: ParameterSet, layout: Layout,
                 context_model: AttributeContext, mlps: dict[str, RenderMLP], *, verify_hash: bool,
                 entries: list[TraceEntry] | None, progress: bool, memory: MemoryPlan | None, max_level: int,
                 workers: int = 1) -> DecodedTiles:
    """The selected tiles, in stream order: here, or in ``workers`` worker processes (the result is
    the same: each tile is decoded by the same function from the same units)."""
    if workers > 1 and len(selected) > 1 and entries is None:
        stream = WorkerStream(tiles, ps, layout, context_model, mlps, verify_hash, max_level)
        parts, shared = _decode_in_workers(stream, selected, workers)
        return _joined(parts, layout, shared)
    one = len(tiles) == 1
    # whole tiles go straight into the output arrays as they are decoded: no second copy of the scene
    # to join them (the level-1 preview's point counts are not known before)
    rows, output = _output_arrays(tiles, selected, layout, np.empty) if not one and max_level != LEVEL_1 \
        else (None, None)
    bar = progress_bar(total=len(selected), desc="decode tiles", unit="tile", disable=not progress or one, leave=False)
    out: list[DecodedTile | TileVerdict] = []
    for i, t in enumerate(selected):
        rows_bar = progress_bar(total=tiles[t].num_points, desc="decode attributes", unit="point",
                                disable=not (progress and one), leave=False)
        on_rows: Callable[[int], object] = rows_bar.update
        d = core.decode_tile(tiles[t], t, ps, layout, context_model, mlps, verify_hash=verify_hash, entries=entries,
                             checks=memory, max_level=max_level, on_rows=on_rows)
        out.append(d if output is None or rows is None else _write_rows(output, rows[i], d))
        rows_bar.close()
        bar.update()
    bar.close()
    return _joined(out, layout, output)


def attribute_tool(ps: ParameterSet, context_model: AttributeContext) -> str:
    """The coding tool of the tiles' attribute units, in the words of decoder/jobs.py's costs."""
    if isinstance(context_model, NeighbourPredictionUnit):
        return "neighbour prediction"
    if context_model is None:
        return "per-channel prior"
    return "GG-Conv" if isinstance(context_model, GgconvContext) else "parent MLP"


def worker_plan(tiles: list[TileUnits], selected: list[int], ps: ParameterSet, layout: Layout,
                context_model: AttributeContext, *, jobs: int | None, exact_jobs: bool = False,
                max_level: int = LEVEL_2, tracing: bool = False) -> WorkerPlan:
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


# --- the whole decode ----------------------------------------------------------------------------

def decode_stream(data: bytes, *, verify_hash: bool = True, trace: bool = False,
                  max_points: int | None = None, max_memory: int | None = DEFAULT_MAX_MEMORY,
                  progress: bool = False, jobs: int | None = 1, exact_jobs: bool = False, box: Box | None = None,
                  max_level: int = LEVEL_2) -> DecodeResult:
    """Decode a stream. Raises a BitstreamError subclass naming the problem, or
    ResourceLimitError for a stream beyond ``max_points`` points (anchors or Gaussians) or one
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
    s, memory = parse_with_bounds(data, entries, max_points=max_points, max_memory=max_memory, max_level=max_level)
    tiles, ps, layout = s.tiles, s.ps, s.layout
    selected = selected_tiles(tiles, ps, box)
    plan = worker_plan(tiles, selected, ps, layout, s.context_model, jobs=jobs, exact_jobs=exact_jobs,
                       max_level=max_level, tracing=entries is not None)
    t1 = time.perf_counter()
    decoded = decode_tiles(tiles, selected, ps, layout, s.context_model, s.mlps, verify_hash=verify_hash,
                           entries=entries, progress=progress, memory=memory, max_level=max_level,
                           workers=plan.workers)
    scene = core.scene_of(ps, layout, decoded.coords, decoded.levels, s.mlps)
    whole = len(selected) == len(tiles) and max_level != LEVEL_1
    stream_hash = None  # a tiled stream carries no hash of the whole scene: computed when asked for
    if whole and len(tiles) == 1:
        stream_hash = DecodedSceneHashUnit.from_bytes(tiles[0].scene_hash.payload).scene_hash
    n = ps.num_points
    return DecodeResult(scene, breakdown_of(s.container, n, s.point), verify_hash and decoded.hash_checked,
                        stream_hash, s.skipped, entries, _stream_tools(ps, decoded, s.context_model, s.point,
                                                                      len(tiles), s.layout),
                        s.source_info, s.notes, len(tiles), len(selected), max_level == LEVEL_1, plan,
                        {"parse": t1 - t0, "decode": time.perf_counter() - t1})


def _layout_tools(layout: Layout) -> list[str]:
    """An explicit-Gaussian layout's coding tools, in words."""
    if not isinstance(layout, GaussianLayout):
        return []
    tools = []
    if layout.max_rotation_length_index >= 0:
        tools.append(f"rotations as a length index (0 to {layout.max_rotation_length_index}) and x, y, z")
    if layout.sh_transform is not None:
        tools.append(f"the SH rest as coefficients of a {layout.sh_transform.size} x {layout.sh_transform.size} "
                     "integer transform")
    return tools


def _neighbour_tools(unit: NeighbourPredictionUnit) -> list[str]:
    """The neighbour_prediction unit's tools and those of its context units, in words."""
    tools = [f"neighbour prediction ({unit.num_lods} levels of detail, "
             f"{unit.num_neighbours} neighbours, {unit.num_buckets} activity buckets)"]
    if unit.step_adjust is not None:
        tools.append(f"step adjustment (a step per Gaussian, up to 2^({unit.step_adjust.max_step_adjust}"
                     "/4) times its channel's" + (", its indices as flags" if unit.step_flags else "") + ")")
    if unit.sh_degree_unit is not None:
        tools.append(f"per-Gaussian SH degree (0 to {unit.sh_degree_unit.sh_degree})")
    return tools


def _stream_tools(ps: ParameterSet, decoded: DecodedTiles, context_model: AttributeContext, point: str,
                  num_tiles: int = 1, layout: Layout | None = None) -> list[str]:
    """The coding tools the stream uses, in words (lghcc-dec prints them)."""
    if isinstance(ps, GaussianParameterSet):
        tools = [f"explicit Gaussians (SH degree {ps.sh_degree})"] + ([] if layout is None else _layout_tools(layout))
    else:
        tools = ["offset masks"] if ps.offset_mask_present_flag else []
    if ps.tiles_enabled_flag:
        tools.append(f"{num_tiles} tile{'s' if num_tiles > 1 else ''} of {ps.tile_size} voxels per side")
    if isinstance(context_model, NeighbourPredictionUnit):
        tools += _neighbour_tools(context_model)
    if not ps.hierarchy_enabled_flag:
        return tools
    n1, n2 = sum(c[0] for c in decoded.level_counts), sum(c[1] for c in decoded.level_counts)
    return tools + [f"two-level hierarchy (coarse voxels of {ps.coarse_voxel_scale}; {n1:,} level-1 and {n2:,} "
                    f"level-2 {point}s)",
                    "level-2 context: " + ("per-channel prior" if context_model is None
                                           or isinstance(context_model, NeighbourPredictionUnit)
                                           else describe_context_model(context_model.pair))]
