"""lghcc-train's settings: ``TrainConfig`` (defaults as Scaffold-GS) and ``check_config``."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ...common.errors import InputError
from ..stream.config import DEFAULT_ATTRIBUTE_STEP


@dataclass
class TrainConfig:
    data: str = ""
    iterations: int = 30000
    feature_dim: int = 32
    num_offsets: int = 10
    voxel_size: float | None = None  # None: extent of the scene bounds / voxels_per_extent
    voxels_per_extent: float = 64.0
    init: str = "auto"  # auto | random | sfm
    init_points: int = 20000
    background: str = "white"  # white | black | r,g,b
    downscale: int = 1
    images: str | None = None  # LLFF/COLMAP image folder; None: images_N for --downscale N when present, else images
    seed: int = 0
    threads: int = 2
    # where the rasterizer runs: cpu, or cuda (gsplat; lghcc.render.rasterizer.select_device, the
    # one seam); the MLPs and the optimizer stay on the CPU. Like threads, a resumed run may change it.
    device: str = "cpu"
    eval_interval: int = 1000
    eval_views: int = 0  # test views used at intermediate evaluations (0: all); the final one uses all
    checkpoint_interval: int = 1000
    keep_checkpoints: int = 2
    # span of the learning-rate decays; None: ``iterations``. A resumed run extended with a larger
    # --iterations keeps its original span (the added iterations train at the final rates).
    lr_schedule_iterations: int | None = None
    # Scaffold-GS schedule (defaults as Scaffold-GS: stats from 500, grow/prune 1500..15000 every 100)
    stats_from: int = 500
    densify_from: int = 1500
    densify_until: int = 15000
    densify_interval: int = 100
    densify_grad_threshold: float = 0.0002
    min_opacity: float = 0.005
    success_threshold: float = 0.8
    update_depth: int = 3
    update_init_factor: int = 16
    update_hierarchy_factor: int = 4
    # Scaffold-GS's literal rule: when the coarsest level adds no anchor, skip the finer levels
    # (once every coarse voxel near the surface is occupied, growing then stops). Off: every level runs.
    skip_finer_levels: bool = False
    lambda_dssim: float = 0.2
    lambda_volume: float = 0.01
    # learning rates (Scaffold-GS), exponential decay init -> final over the run
    offset_lr_init: float = 0.01  # times the camera extent (spatial_lr_scale)
    offset_lr_final: float = 0.0001
    feature_lr: float = 0.0075
    scaling_lr: float = 0.007
    mlp_opacity_lr_init: float = 0.002
    mlp_opacity_lr_final: float = 0.00002
    mlp_cov_lr_init: float = 0.004
    mlp_cov_lr_final: float = 0.004
    mlp_color_lr_init: float = 0.008
    mlp_color_lr_final: float = 0.00005
    # Anchor pruning once the anchor set is grown (after the growing/pruning at prune_at), then
    # training goes on with the pruned set, as the paper applies NAAP (section 3.3): naap merges
    # low-importance anchors into their nearest kept neighbour; opacity drops the anchors of
    # lowest accumulated opacity (Context-GS). none: no extra pruning.
    prune: str = "none"
    prune_keep: float = 0.8  # fraction of the anchors kept
    prune_at: int | None = None  # None: densify_until
    naap_lambda: float = 0.5
    naap_gamma: float = 0.2
    # Rate-distortion training (LG-HCC eq. 12: L = L_render + lambda L_anchor): from rate_from
    # on (after the last growing/pruning, so the anchor set is fixed), the loss adds
    # rate_lambda x the estimated bits per attribute value of the anchors under the codec's
    # hierarchy and context model (encoder/anchors/rate_model.py), and the scene renders with its
    # attributes quantized as the encoder will (steps rate_step). 0: plain Scaffold-GS.
    rate_lambda: float = 0.0
    rate_from: int | None = None  # None: densify_until
    rate_step: float = DEFAULT_ATTRIBUTE_STEP  # the encoder's feature/scaling/offset step (preset medium)
    rate_voxel_scale: int = 4  # the encoder's coarse voxel scale
    rate_neighbour_level: int = 1  # the encoder's GG-Conv neighbour level
    rate_lr: float = 0.002  # learning rate of the rate model's parameters

    @property
    def prune_iteration(self) -> int:
        return self.prune_at if self.prune_at is not None else self.densify_until

    @property
    def rate_iteration(self) -> int:
        """The first iteration with the rate term."""
        return self.rate_from if self.rate_from is not None else self.densify_until


def check_config(cfg: TrainConfig) -> None:
    from ...render.rasterizer import select_device

    select_device(cfg.device)  # 'no CUDA device: ...' before the data is loaded
    for name in ("iterations", "feature_dim", "num_offsets", "init_points", "threads", "eval_interval",
                 "checkpoint_interval", "densify_interval", "downscale"):
        v = getattr(cfg, name)
        if not isinstance(v, int) or v < 1:
            raise InputError(f"{name.replace('_', '-')} must be a positive integer, got {v!r}")
    if cfg.voxel_size is not None and not (cfg.voxel_size > 0 and math.isfinite(cfg.voxel_size)):
        raise InputError(f"voxel-size must be a positive number, got {cfg.voxel_size}")
    if cfg.prune not in ("none", "naap", "opacity"):
        raise InputError(f"prune must be none, naap or opacity, got {cfg.prune!r}")
    if cfg.prune != "none":
        if not 0 < cfg.prune_keep <= 1:
            raise InputError(f"prune-keep must be in (0, 1], got {cfg.prune_keep}")
        at = cfg.prune_iteration
        if at < cfg.densify_until or at > cfg.iterations:
            raise InputError(f"prune-at ({at}) must lie between densify-until ({cfg.densify_until}) and the last "
                             f"iteration ({cfg.iterations})")
        if cfg.rate_lambda > 0 and cfg.rate_iteration < at:
            raise InputError(f"rate-from ({cfg.rate_iteration}) must not come before prune-at ({at})")
    if not (cfg.rate_lambda >= 0 and math.isfinite(cfg.rate_lambda)):
        raise InputError(f"rate-lambda must be a non-negative number, got {cfg.rate_lambda}")
    if cfg.rate_lambda > 0:
        if not (cfg.rate_step > 0 and math.isfinite(cfg.rate_step)):
            raise InputError(f"rate-step must be a positive number, got {cfg.rate_step}")
        if cfg.rate_iteration < cfg.densify_until:
            raise InputError(f"rate-from ({cfg.rate_iteration}) must not come before the last growing/pruning "
                             f"(densify-until {cfg.densify_until}): the rate model needs a fixed anchor set")
        if cfg.rate_voxel_scale < 2 or cfg.rate_neighbour_level not in (1, 2):
            raise InputError("rate-voxel-scale must be >= 2 and rate-neighbour-level 1 or 2")
