"""The encoder's memory, estimated before it starts (informative; lghcc-enc --max-memory).

The encoder's peak resident memory grows linearly with the scene: the program itself (Python,
NumPy, torch), then per point its arrays (the scene read, the values in coding order in float64,
their quantized integers, the neighbour graph, each tile's working copy, the decoded values)
and, per value of a point, the arrays sized N x M; RDOQ adds the working arrays of one block of
rows (no whole-scene copy: it works block by block). The constants are the kernel's peak RSS of
lghcc-enc on the scenes tools/scale_scenes.py builds, fitted as a line in N (50k-300k Gaussians,
SH degree 0 and the same scenes padded to degree 3: tools/results/scale.md, "Memory"), rounded
up; they bound the measured peaks of those runs. Each worker process (--jobs) adds its own
runtime and its tile's arrays (fork shares the scene); Ray (--ray) adds a copy of every tile's
input in the object store and the local instance's processes. A bound on memory is a property
of this encoder, not of the format.
"""

from __future__ import annotations

from dataclasses import dataclass

from ...app.cli_common import format_bytes
from ...common.errors import ResourceLimitError
from ...common.scene import AnchorScene, GaussianScene

PROGRAM_BYTES = 320 << 20  # Python, NumPy, torch and the encoder's modules (300 MiB measured at N -> 0)
# Fitted on the peaks of 100k-300k Gaussians at SH 0 (11 channels: 1,376 B per Gaussian) and
# SH 3 (59 channels: 5,433 B): 446 B per point and 84.5 B per value, rounded up.
PER_POINT_BYTES = 480  # coordinates, orders, the neighbour graph, the tiles' indices, hash rows
PER_VALUE_BYTES = 90  # per point and channel: the scene read, float64 values, int64 q, float32 decoded, copies
# With the neighbour coding's fits by histogram and by block, `fast` peaks at about 49 B per value and no more
# per point (300k: 453 B per Gaussian above PROGRAM_BYTES at SH 0, 2,639 at SH 3; tools/results/scale.md "SH 3
# memory (issue 53)"): the constants above bound those and the anchor scenes' peaks they were fitted on.
# The render-based preparation (a PSNR or lambda asked for, fitting, pruning): the views' renders and
# projected Gaussians (two views at a time), contributions, sensitivities, the search's trial scenes
# (on a sample of at most 100k Gaussians) and the fit. Fitted on bench_scale's peaks of `medium` with
# --jobs 2 (tools/results/scale.md, 2026-11-29; SH 0): 1,194 MiB at 100k, 1,679 at 300k, 3,206 at 1M
# (409k pruned), 10,158 at 3M (none pruned): above the other parts, about 420 MiB plus 1.8 KB per
# Gaussian from 300k to 3M, more per Gaussian at 100k (the fixed part: renders, torch's buffers).
# 600 MiB plus 2,000 B per point (24 B per value then) bounds all four: with the other parts and two workers the whole
# estimate is 1.16x the peak at 3M, 1.18x at 100k (the tightest), 1.44x at 1M (where pruning lowered
# the peak). The per-value term: the sensitivities' two views in flight (each parameter's float32
# gradient and its float64 square, [N, M]), their float64 sums and result, the fit's parameters, gradients
# and moments. The settings search's peak is bounded by keeping the grid, values and neighbour graph
# (620 B per Gaussian at SH 3) of only two (pruning share, position step) pairs (gaussian_rd.py
# GRID_CACHE_KEYS). With that, the per-stage traces (in-process, --jobs 2) of `medium` on the room
# watched from inside and on a 100k SH-3 scene peak at the sensitivities and the trials: 1,003 MiB the
# room (SH 0), 1,373 the SH-3 scene, 86 B per value apart (tools/results/scale.md "SH 3 memory"): hence
# 96 B per value, with the per-point term 1,200 B so that a Gaussian at SH 0 (11 values) costs what the
# fit above gave it (2,000 B + 24 B per value; 3M: 1.15x its peak).
# At 1M SH 3 `low` (tools/results/scale_sh3.md, 2026-12-08) the peak was 18,072 MiB, where 96 B per value gave
# 12,584: the landing's whole-scene trials (a 300k SH-3 trace peaks there, at 2,982-3,128 MiB) grow faster than
# the 100k-300k traces showed; the 1M run's stage was not traced. 210 B per value bounds that row (18,672 MiB,
# 1.03x), at the cost of looser bounds elsewhere: by this arithmetic about 1.5x the 3M SH-0 peak above, 1.5x the
# room's and 2.1x the 100k SH-3 scene's.
PREPARE_BYTES = 600 << 20
PREPARE_PER_POINT_BYTES = 1200
PREPARE_PER_VALUE_BYTES = 210
# Rate-distortion optimized quantization without the preparation (sensitivity_model "uniform": the
# fast preset). The uniform sensitivities are one broadcast row (nothing per value), the values in steps
# are the coding's values divided in place, RDOQ chooses each LoD's rows in blocks of RDOQ_BLOCK_ROWS
# (below) and its integers go on to the coding (no q x steps): what RDOQ holds per value (the values in
# steps, the rounded integers, the fit of the coding to them) is within the coding's own arrays above,
# and its peak no higher than the coding's (300k SH 3, in-process with --jobs 1: 876 MiB at RDOQ's fit
# of the coding, 875 at the coding's own, 946 at a tile's writing; tools/results/scale.md "SH 3 memory
# (issue 53)"). Left: the working arrays of one block, about 24 float64 or int64 [rows, M] (values,
# sensitivities, means, levels, candidates, costs).
# Measured `fast` peaks (--jobs 2, same section): 370 and 450 MiB at 100k and 300k SH 0, 536 and
# 1,075 MiB at 100k and 300k SH 3; with the terms above the estimate is 1.68-2.13x these (621, 902, 1,142 and
# 2,195 MiB).
# Rows RDOQ (encoder/gaussians/rdoq.py rd_quantize) chooses at a time, within a LoD, whose rows' choices
# are independent of each other: the working arrays of a block bound its memory, not the scene's size
RDOQ_BLOCK_ROWS = 16384
# Rows the neighbour coding (encoder/stream/neighbour_coding.py) makes its working arrays for at a time
# (the neighbours' sums and spreads, levels, residuals; each row's are its own): beside its whole-scene
# arrays, one block's
CODING_BLOCK_ROWS = 16384
RDOQ_PER_POINT_BYTES = 0
RDOQ_PER_VALUE_BYTES = 0
RDOQ_BLOCK_VALUE_BYTES = 24 * 8  # per value of a block of RDOQ_BLOCK_ROWS rows
# A forked worker's own pages (torch's thread pools, its tile's arrays): a margin, as the peak is in
# the whole-scene stages before the tiles: 200k Gaussians at SH 0 peaked at 503 MB of PSS over the
# process tree with --jobs 1 and with --jobs 2 alike (tools/bench_scale.py's sampler)
WORKER_BYTES = 64 << 20
RAY_BYTES = 600 << 20  # a local Ray instance's processes (raylet, GCS, a worker per CPU)


@dataclass
class MemoryEstimate:
    """The encoder's estimated peak and its largest parts (name -> bytes)."""
    total: int
    parts: dict[str, int]

    def largest(self) -> str:
        name, size = max(self.parts.items(), key=lambda kv: kv[1])
        return f"{name} {format_bytes(size)}"


def _points_and_channels(scene: AnchorScene | GaussianScene, cfg) -> tuple[int, int]:
    if isinstance(scene, GaussianScene):
        from ...common.attributes import GaussianLayout

        degree = scene.sh_degree if cfg.sh_degree is None else min(cfg.sh_degree, scene.sh_degree)
        return scene.num_gaussians, GaussianLayout(degree).num_channels
    return scene.num_anchors, scene.feature_dim + 6 + 3 * scene.num_offsets


def prepares(scene, cfg) -> bool:
    """Whether the render-based preparation runs (api._encode_gaussians' rule)."""
    return isinstance(scene, GaussianScene) and (cfg.rd_lambda > 0 or cfg.target_psnr > 0 or cfg.fit_iterations > 0
                                                 or cfg.prune_share > 0)


def rdoq_without_preparation(scene, cfg) -> bool:
    """Whether RDOQ runs on modelled sensitivities, with no renders (encoder/gaussians/gaussians.py's rule)."""
    return isinstance(scene, GaussianScene) and cfg.rd_quantization > 0 and cfg.sensitivity_model != "none"


def encode_memory(scene: AnchorScene | GaussianScene, cfg, workers=None) -> MemoryEstimate:
    """The estimated peak resident memory of encoding ``scene`` with ``cfg`` where ``workers``
    (tile_workers.TileWorkers; None: this process) says."""
    from ...app.workers import available_cpus

    n, m = _points_and_channels(scene, cfg)
    parts = {"program": PROGRAM_BYTES, "scene and coding arrays": n * (PER_POINT_BYTES + PER_VALUE_BYTES * m)}
    if prepares(scene, cfg):
        parts["render-based preparation"] = PREPARE_BYTES + n * (PREPARE_PER_POINT_BYTES + PREPARE_PER_VALUE_BYTES * m)
    elif rdoq_without_preparation(scene, cfg):
        parts["rate-distortion optimized quantization"] = n * (RDOQ_PER_POINT_BYTES + RDOQ_PER_VALUE_BYTES * m) \
            + min(n, RDOQ_BLOCK_ROWS) * m * RDOQ_BLOCK_VALUE_BYTES
    if workers is not None and workers.ray:
        parts["Ray: tile inputs in the object store"] = n * (8 * m + 40)
        if not workers.address:
            parts["Ray: the local instance"] = RAY_BYTES
    elif workers is not None and workers.jobs != 1:
        jobs = workers.jobs or available_cpus()
        parts[f"{jobs} worker processes"] = jobs * WORKER_BYTES
    return MemoryEstimate(sum(parts.values()), parts)


def check_encode_memory(scene: AnchorScene | GaussianScene, cfg, workers, max_memory: int, name: str,
                        limit: str = "--max-memory") -> int:
    """The estimate (bytes) when within ``max_memory``; else ResourceLimitError naming the scene,
    what it needs (and its largest part) and the limit (``limit``: what the bound is)."""
    est = encode_memory(scene, cfg, workers)
    if est.total > max_memory:
        n, _ = _points_and_channels(scene, cfg)
        what = "Gaussians" if isinstance(scene, GaussianScene) else "anchors"
        raise ResourceLimitError(
            f"{name}: encoding {n:,} {what} needs about {format_bytes(est.total)} (largest part: {est.largest()}), "
            f"more than {limit} {format_bytes(max_memory)}; " +
            ("raise the limit, or encode on a machine with more memory" if limit == "--max-memory" else
             "free memory, encode on a machine with more, or pass --max-memory (none: no bound) to try anyway"))
    return est.total
