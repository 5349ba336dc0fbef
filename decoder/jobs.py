"""How many worker processes a decode uses (lghcc-dec --jobs; informative: the decoded scene never
depends on it, each tile being decoded by the same function from the same units).

Workers pay only where the tiles' work saved outweighs what the workers cost to start. Before
any tile is decoded, each selected tile's decoding time is estimated from its point count, the
channels per point and the coding tool of its attribute units (``tile_seconds``); the tiles are
then dealt to W workers largest first (``makespan``, as the decoder hands them out), and the
decode takes W workers where

    WORKER_START_S * W + TASK_S * tiles + makespan(W)  <  sum of the tiles' times (one process)

by the largest margin, W from 1 to the bound (the CPUs for --jobs auto, N for --jobs N). The
constants are measured (``python tools/bench_decode.py --calibrate``, tools/results/decode.md)
on the 2-core machine of the project: an estimate, not a promise; a wrong one costs time, never
bits.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

# Seconds on a quiet 2-core machine. tools/results/decode.md measured them under a load of 10 to
# 13 on 2 cores, where everything took about 9 times as long as quiet (a 100k-anchor low-preset
# decode 8.3 s, about 0.9 s quiet); the decision compares start against work, so what counts is
# their ratio, which that run measured alike. Forking one worker (the decoder and torch loaded)
# and its first round trip: 150 ms there, about 17 ms quiet; taken as 60 ms so that a close call
# stays in one process (a wrong "1" costs a little time, a wrong "2" can cost more).
WORKER_START_S = 0.060
# One tile handed to a worker and its verdict back: 0.9 ms there, 0.1 ms quiet; taken high.
TASK_S = 0.001
# A tile's fixed work: its units' headers, tables, the hash of its points (tiles.md: 13 ms per
# tile of a 1M-anchor GG-Conv stream, quiet).
TILE_S = 0.004
# Per point: the geometry (octree) decode and the hash, whatever the attribute coding (a profile
# of a 107,759-anchor medium stream: geometry 0.33 s of 0.98 s).
POINT_S = 2.0e-6
# Per attribute value (a point's channel), by the coding tool of the tile's attribute units, as
# their ratios in decode.md (1 process, per point: low 8.3e-5, lghcc-low 1.2e-4, gaussians-medium
# 7.2e-5 s of 20 channels, under the load above): range decoding with the per-channel prior (also
# a hierarchy's levels without a context model); GG-Conv (its level-2 network, spread over all the
# tile's values: 1.45 times the prior's per point); neighbour prediction (its k-NN and means per
# row: 3 times the prior's per value). The parent MLP is not measured: taken as GG-Conv.
VALUE_S = {"per-channel prior": 1.0e-7, "neighbour prediction": 3.0e-7, "parent MLP": 1.6e-7,
           "GG-Conv": 1.6e-7}
# The level-1 preview decodes the values of one point per coarse voxel with the per-channel prior:
# about a fifth of the points (13% of the 100k and 21% of the 1M procedural scenes of
# tools/results/tiles.md at coarse voxels of 4), taken high.
PREVIEW_VALUE_SHARE = 0.25


def tile_seconds(num_points: int, channels: int, tool: str, value_share: float = 1.0) -> float:
    """The estimated time of one tile's decode, in one process; ``value_share``: the share of its
    points whose values are decoded (the preview's)."""
    return TILE_S + num_points * (POINT_S + value_share * channels * VALUE_S[tool])


def makespan(costs: list[float], workers: int) -> float:
    """The time until the last of ``workers`` is done, the tiles given out largest first, each to
    the worker that is free first (as a process pool does)."""
    free = [0.0] * max(1, workers)
    for c in sorted(costs, reverse=True):
        heapq.heapreplace(free, free[0] + c)
    return max(free)


@dataclass(frozen=True)
class WorkerPlan:
    """The workers a decode uses (1: the tiles in this process) and why, in words."""
    workers: int
    reason: str


def plan_workers(costs: list[float], bound: int, asked: str) -> WorkerPlan:
    """The number of workers, 1 to ``bound``, with the shortest estimated decode of tiles of
    ``costs`` seconds; ``asked``: the bound in words (the log's reason names it)."""
    serial = sum(costs)
    if bound < 2 or len(costs) < 2:
        why = "one tile" if len(costs) < 2 else asked
        return WorkerPlan(1, f"1 process ({why})")
    best, best_s = 1, serial
    for w in range(2, min(bound, len(costs)) + 1):
        t = WORKER_START_S * w + TASK_S * len(costs) + makespan(costs, w)
        if t < best_s:
            best, best_s = w, t
    if best == 1:
        w = min(bound, len(costs))
        t = WORKER_START_S * w + TASK_S * len(costs) + makespan(costs, w)
        return WorkerPlan(1, f"1 process: {len(costs)} tiles of about {serial:.2f} s of decoding, {w} workers "
                             f"would take about {t:.2f} s with their start ({asked})")
    return WorkerPlan(best, f"{best} worker processes: {len(costs)} tiles of about {serial:.2f} s of decoding in "
                            f"about {best_s:.2f} s with their start ({asked})")
