"""Where the encoder codes a scene's tiles (informative; lghcc-enc --jobs, --ray): in this
process, in worker processes, or as Ray tasks. Each tile is coded from its own points alone
(tiling.code_one_tile) with what the whole scene shares (tiling.TileJob), so the stream is
byte for byte the same wherever its tiles ran.

Worker processes follow the decoder's (decoder/decode.py): forked after the scene is in memory
(the workers read it without a copy), one torch thread each (the workers are the parallelism),
the largest tiles first (no large tile left to one worker at the end), each tile's decoded
values written into a shared output array, the tiles put back in stream order. Without fork
(Windows) they are spawned and get their tile's input through the pipe.

On Ray every tile is one task: its own input travels with it (a tile of 16k Gaussians is a few
MB) and the shared part once through the object store, so the workers need no shared
filesystem, only lghcc installed.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

import numpy as np

from ...common.errors import LghccError
from ...app.workers import available_cpus, shared_array
from ...common.units import tile_size_of
from .tiling import TileCoding, TileJob, code_one_tile, tile_input, tile_rows


def auto_jobs(num_tiles: int, num_points: int, cpus: int | None = None) -> int:
    """--jobs auto: one worker per CPU, no more than there are tiles, and one process for a scene
    too small to repay starting workers (under 2 x 16,384 points a worker's start, about 0.1 s,
    is a fair share of the tiles' time)."""
    cpus = available_cpus() if cpus is None else cpus
    if num_tiles < 2 or num_points < 2 * 16384:
        return 1
    return max(1, min(cpus, num_tiles))


@dataclass
class TileWorkers:
    """Where the tiles are coded: ``jobs`` processes (1: this one; 0: auto_jobs), or Ray tasks
    (``ray``, on the cluster at ``address``, None: a local Ray; ``ray_cpus``: the local instance's
    CPUs, None: all)."""
    jobs: int = 1
    ray: bool = False
    address: str | None = None
    ray_cpus: int | None = None
    connect_timeout_s: float = 15.0

    def code(self, inp, job: TileJob, parts: list, progress: bool) -> tuple[list[TileCoding], np.ndarray]:
        """The tiles ``parts`` ([(cell, rows)] in stream order) -> (their codings in stream order,
        the decoded values of the whole scene)."""
        from ...app.progress import progress_bar

        bar = progress_bar(total=len(parts), desc="code tiles", unit="tile", disable=not progress, leave=False)
        try:
            if self.ray:
                return _on_ray(self, inp, job, parts, bar)
            jobs = self.jobs or auto_jobs(len(parts), inp.coords.shape[0])
            if jobs > 1 and len(parts) > 1:
                return _in_workers(inp, job, parts, jobs, bar)
            return _here(inp, job, parts, bar)
        finally:
            bar.close()


def _largest_first(parts: list) -> list[int]:
    return sorted(range(len(parts)), key=lambda i: -parts[i][1].size)


def _here(inp, job: TileJob, parts: list, bar) -> tuple[list[TileCoding], np.ndarray]:
    recon = np.zeros_like(inp.values, dtype=np.float32)
    tiles = []
    for cell, rows in parts:
        tile, trecon = code_one_tile(job, cell, rows, tile_input(inp, rows))
        recon[rows] = trecon
        tiles.append(tile)
        bar.update()
    return tiles, recon


# What the forked workers read (set by the parent before it forks): the scene's input, the shared
# job, and the output array the tiles' decoded values go into (shared anonymous memory).
_FORKED: dict = {}


def _worker_init() -> None:
    import torch

    torch.set_num_threads(1)  # the workers are the parallelism


def _forked_tile(args) -> TileCoding:
    """A forked worker's task: the tile of ``rows``, read from the scene the parent holds; its
    decoded values go into the shared output, its coding comes back."""
    cell, rows = args
    tile, trecon = code_one_tile(_FORKED["job"], cell, rows, tile_input(_FORKED["inp"], rows))
    _FORKED["recon"][rows] = trecon
    return tile


def _spawned_tile(args) -> tuple[TileCoding, np.ndarray]:
    """A spawned worker's task: the tile from its own input."""
    job, cell, rows, tinp = args
    return code_one_tile(job, cell, rows, tinp)


def _in_workers(inp, job: TileJob, parts: list, jobs: int, bar) -> tuple[list[TileCoding], np.ndarray]:
    fork = os.name == "posix"
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    tiles: list[TileCoding] = [None] * len(parts)  # type: ignore[list-item]
    if fork:
        recon = shared_array(inp.values.shape, np.float32)
        _FORKED.update(inp=inp, job=job, recon=recon)
    else:
        recon = np.zeros_like(inp.values, dtype=np.float32)
    try:
        with ProcessPoolExecutor(max_workers=min(jobs, len(parts)), mp_context=ctx,
                                 initializer=_worker_init) as pool:
            futures = {}
            for i in _largest_first(parts):
                cell, rows = parts[i]
                futures[pool.submit(_forked_tile, (cell, rows)) if fork else
                        pool.submit(_spawned_tile, (job, cell, rows, tile_input(inp, rows)))] = i
            for f in as_completed(futures):
                i = futures[f]
                try:
                    got = f.result()
                except BrokenProcessPool as e:  # killed (out of memory?) or crashed
                    raise LghccError(f"a tile worker process died ({e}); try --jobs 1") from None
                if fork:
                    tiles[i] = got
                else:
                    tiles[i], recon[parts[i][1]] = got
                bar.update()
    finally:
        _FORKED.clear()
    return tiles, recon


def _ray_tile(job: TileJob, cell, rows: np.ndarray, tinp) -> tuple[TileCoding, np.ndarray]:
    """A Ray task: one tile from its own input (one torch thread: the tasks are the parallelism)."""
    import torch

    torch.set_num_threads(1)
    return code_one_tile(job, cell, rows, tinp)


def _on_ray(w: TileWorkers, inp, job: TileJob, parts: list, bar) -> tuple[list[TileCoding], np.ndarray]:
    from ...app.cluster import ClusterError, init_ray, one_line

    ray = init_ray(w.address, w.ray_cpus, w.connect_timeout_s,
                   missing="pip install 'lghcc[batch]', or code the tiles in processes (--jobs)")
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(_ray_tile)
        job_ref = ray.put(job)
        pending = {}
        for i in _largest_first(parts):
            cell, rows = parts[i]
            pending[task.remote(job_ref, cell, rows, tile_input(inp, rows))] = i
        tiles: list[TileCoding] = [None] * len(parts)  # type: ignore[list-item]
        recon = np.zeros_like(inp.values, dtype=np.float32)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            i = pending.pop(ready[0])
            try:
                tiles[i], recon[parts[i][1]] = ray.get(ready[0])
            except Exception as e:  # noqa: BLE001 - RayTaskError, WorkerCrashedError, ...
                raise ClusterError(f"tile {i} failed on Ray: {one_line(e)}") from None
            bar.update()
        return tiles, recon
    finally:
        ray.shutdown()


def code_tiles(inp, job: TileJob, progress: bool = False, workers=None) -> tuple[list[TileCoding], np.ndarray]:
    """Every tile of the scene -> (the tiles in stream order with their hashes, the decoded values
    [N, M] in the whole scene's normative order). ``workers`` (TileWorkers; None: this
    process): where the tiles are coded; the stream is the same."""
    parts = tile_rows(inp.coords, tile_size_of(inp.parameter_set))
    return (workers or TileWorkers()).code(inp, job, parts, progress)
