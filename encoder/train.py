"""lghcc-train: train a Scaffold-GS anchor scene from posed images on the CPU (informative).

What it does (Scaffold-GS, Lu et al. 2024, with the differences listed here):

* Data: NeRF-synthetic (``transforms_train.json`` / ``transforms_test.json``), LLFF
  (``poses_bounds.npy`` + ``images/``) or COLMAP (``sparse/0`` + ``images/``), through the
  loaders of ``lghcc.render.camera``. LLFF/COLMAP hold out every 8th image for testing.
* Initialization without SfM points. NeRF-synthetic: random points, uniform inside the
  intersection of the training cameras' view frusta (the region every camera sees; for
  lego a ball of radius ~1.4 around the origin), voxelized on the anchor grid of voxel size
  eps (default: the extent of that region / 64). LLFF/COLMAP: random points on random
  training rays, uniform in inverse depth between the views' near and far bounds
  (``--init sfm`` uses COLMAP's points3D instead when the model has them).
  Anchors: feature 0, offsets 0, log scalings log(mean distance to the 3 nearest anchors)
  (x6), as Scaffold-GS; anchor positions are fixed (Scaffold-GS's position lr is 0).
* Render MLPs (Scaffold-GS): Linear(C+4, C), ReLU, Linear(C, out) with Tanh (opacity, K),
  none (covariance, 7K), Sigmoid (colour, 3K); input [feature, view direction, distance].
* Loss: 0.8 L1 + 0.2 (1 - SSIM) + 0.01 * mean volume of the neural Gaussians (Scaffold-GS's
  scaling regularizer). Adam (eps 1e-15) with Scaffold-GS's learning rates and exponential
  decays; the decays span the whole run (``--iterations``) instead of 30k steps.
* Anchor growing (every ``--densify-interval`` iterations from ``--densify-from`` to
  ``--densify-until``): per neural Gaussian, the mean screen-space gradient norm since the
  last update (Gaussians seen in > 40% of the interval's iterations). At level i = 0..2,
  Gaussians above threshold * 2^i (kept with probability 1 - 0.5^(i+1)) spawn new anchors at
  the centres of voxels of size eps * 16 / 4^i holding no anchor; new anchors take the
  element-wise max of their parents' features, zero offsets and log scalings log(voxel).
  Difference: Scaffold-GS skips the finer levels whenever the coarsest one adds nothing,
  which stops growing once every coarse voxel near the surface holds an anchor (measured on
  lego at 100x100: ~50 anchors grown in 4000 iterations); here every level runs
  (``--skip-finer-levels`` restores the original rule).
  Difference: our rasterizer does not expose the gradient of the 2D means, so the
  screen-space gradient is taken from the gradient of the 3D means: its camera-x/y
  components times z / f (-> pixels) times W/2 (-> NDC, the unit of Scaffold-GS's threshold).
* Anchor pruning (same schedule): anchors seen in > 80% of the interval's iterations whose
  mean summed neural opacity per view is below ``--min-opacity`` are removed (never all).
* Statistics saved with the scene: ``scene.extra["opacity_accum"]`` = mean over the views
  that saw the anchor (since its creation) and over its K offsets of max(0, neural opacity):
  the quantity NAAP (encoder/naap.py) uses; written as the PLY column ``opacity_accum``.
* Output: ``<out>/point_cloud/iteration_<N>/`` (the Scaffold-GS layout lghcc-enc reads),
  ``<out>/train_state.pth`` (everything needed to resume exactly: parameters, Adam state,
  statistics, RNG states), ``<out>/metrics.json`` / ``metrics.csv`` (test PSNR/SSIM curve),
  ``<out>/config.yaml``. Every file is written atomically, and every iteration folder too (written
  as a hidden sibling, then renamed into place: a killed run never leaves one without MLPs).
* Resume: ``--resume`` continues exactly; with a larger ``--iterations`` it extends the run
  (also a finished one), the learning-rate decays keeping their original span.
"""

from __future__ import annotations

import os

# Without this, OpenMP threads spin at barriers: on a shared machine (more runnable processes
# than cores) a 2-thread torch run went ~18x slower than 1 thread; passive waiting fixes it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import csv
import dataclasses
import io
import json
import math
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import yaml
from torch import nn

from ..common.errors import InputError, LghccError
from ..app.fileio import atomic_write_bytes
from ..formats.scaffold_io import write_scaffold
from ..common.scene import AnchorScene
from .config import DEFAULT_ATTRIBUTE_STEP

STATE_NAME = "train_state.pth"
STATE_VERSION = 1


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
    # hierarchy and context model (encoder/rate_model.py), and the scene renders with its
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


# ------------------------------------------------------------------------------------------
# Data
# ------------------------------------------------------------------------------------------

# Datasets: lghcc.render.datasets (layouts detected by their files; also used by lghcc-dec --render)
from ..render.datasets import Dataset, load_dataset  # noqa: E402,F401  (re-exported)


def camera_extent(cams: list) -> float:
    """3DGS's ``cameras_extent``: 1.1 x the largest distance of a camera centre from their mean."""
    c = np.stack([cam.center for cam in cams])
    return 1.1 * float(np.linalg.norm(c - c.mean(0), axis=1).max())


def _in_frusta_fraction(points: np.ndarray, cams: list) -> np.ndarray:
    seen = np.zeros(len(points))
    for cam in cams:
        uv, z = cam.project(points)
        seen += (z > cam.near) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return seen / len(cams)


def init_points(ds: Dataset, cfg: TrainConfig, rng: np.random.Generator) -> np.ndarray:
    """Initial points [P, 3] float64 (see the module doc)."""
    mode = cfg.init
    if mode == "auto":
        mode = "sfm" if ds.sfm_points is not None else "random"
    if mode == "sfm":
        if ds.sfm_points is None:
            raise InputError(f"{cfg.data}: --init sfm needs a COLMAP model with points3D (sparse/0/points3D.bin or "
                             ".txt); this dataset has none")
        return np.asarray(ds.sfm_points, np.float64)
    if mode != "random":
        raise InputError(f"unknown --init {cfg.init!r} (auto, random or sfm)")
    if ds.kind == "nerf_synthetic":
        # rejection sampling in the bounding box of the camera centres: keep points that every
        # training camera sees (the intersection of the view frusta)
        centres = np.stack([c.center for c in ds.train])
        lo, hi = centres.min(0), centres.max(0)
        got: list[np.ndarray] = []
        total, tries = 0, 0
        while total < cfg.init_points and tries < 200:
            cand = rng.uniform(lo, hi, size=(max(4 * cfg.init_points, 10000), 3))
            ok = cand[_in_frusta_fraction(cand, ds.train) >= 1.0]
            got.append(ok)
            total += len(ok)
            tries += 1
        pts = np.concatenate(got)[: cfg.init_points]
        if len(pts) == 0:
            raise InputError(f"{cfg.data}: the training cameras' view frusta have no common region; "
                             "use a dataset with SfM points (--init sfm)")
        return pts
    # forward-facing / general scenes: random points on random training rays, uniform in 1/depth
    out = []
    idx = rng.integers(0, len(ds.train), cfg.init_points)
    for i in np.unique(idx):
        cam = ds.train[i]
        n = int((idx == i).sum())
        u = rng.uniform(0, cam.width, n)
        v = rng.uniform(0, cam.height, n)
        far = min(cam.far, cam.near * 1e3)
        inv = rng.uniform(1.0 / far, 1.0 / cam.near, n)
        z = 1.0 / inv
        pc = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], 1)
        out.append((pc - cam.translation) @ cam.rotation)
    return np.concatenate(out)


def default_voxel_size(points: np.ndarray, voxels_per_extent: float) -> float:
    lo, hi = np.percentile(points, [1, 99], axis=0)
    ext = float((hi - lo).max())
    if not np.isfinite(ext) or ext <= 0:
        raise InputError("cannot derive a voxel size from the initial points (all at one place); give --voxel-size")
    return ext / voxels_per_extent


def _knn_mean_dist(points: np.ndarray, k: int = 3) -> np.ndarray:
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return np.ones(len(points))
    kk = min(k + 1, len(points))
    d, _ = cKDTree(points).query(points, k=kk)
    return np.maximum(np.sqrt((d[:, 1:] ** 2).mean(1)), 1e-7)


# ------------------------------------------------------------------------------------------
# The trainer
# ------------------------------------------------------------------------------------------

def _make_mlp(c: int, out: int, final: str):
    from ..render.neural_gaussians import TorchMLP

    return TorchMLP([nn.Linear(c + 4, c), nn.Linear(c, out)], ["relu", final])


def _expon_lr(step: int, init: float, final: float, max_steps: int) -> float:
    """3DGS's get_expon_lr_func without delay: log-linear from init to final."""
    if init == final:
        return init
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp(math.log(max(init, 1e-300)) * (1 - t) + math.log(max(final, 1e-300)) * t)


class Trainer:
    PARAMS = ("features", "scalings", "offsets")

    def __init__(self, cfg: TrainConfig, ds: Dataset, out: Path):
        from ..render.rasterizer import rasterize_with, select_device

        self.cfg, self.ds, self.out = cfg, ds, out
        self.rasterize = rasterize_with(select_device(cfg.device))
        self.bg = torch.as_tensor(_background(cfg.background), dtype=torch.float32)
        self.train_images = [torch.from_numpy(np.ascontiguousarray(c.image, np.float32)) for c in ds.train]
        self.spatial_lr_scale = camera_extent(ds.train)
        self.history: list[dict] = []
        self.elapsed = 0.0
        self.loss_ema = None
        self.grown = 0  # anchors added by growing / removed by pruning, since the start
        self.pruned = 0
        self.rate_model = None  # encoder/rate_model.AnchorRateModel, built when the rate phase starts
        self.rate_opt = None
        self.rate_bits = None  # last estimate of the attribute bits per anchor
        self.prune_report = None  # what prune_anchors did

    # --- construction ----------------------------------------------------------------
    def fresh(self) -> None:
        cfg = self.cfg
        torch.manual_seed(cfg.seed)
        self.np_rng = np.random.default_rng(cfg.seed)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        pts = init_points(self.ds, cfg, self.np_rng)
        vs = cfg.voxel_size if cfg.voxel_size is not None else default_voxel_size(pts, cfg.voxels_per_extent)
        if not (vs > 0 and math.isfinite(vs)):
            raise InputError(f"--voxel-size must be positive, got {vs}")
        self.voxel_size = float(vs)
        self.origin = np.zeros(3, np.float32)
        coords = np.unique(np.round(pts / self.voxel_size).astype(np.int64), axis=0)
        self.coords = torch.from_numpy(coords)
        n, c, k = len(coords), cfg.feature_dim, cfg.num_offsets
        dist = _knn_mean_dist(coords * self.voxel_size)
        self.mlps = {"opacity": _make_mlp(c, k, "tanh"), "cov": _make_mlp(c, 7 * k, "none"),
                     "color": _make_mlp(c, 3 * k, "sigmoid")}
        self.params = {
            "features": nn.Parameter(torch.zeros(n, c)),
            "scalings": nn.Parameter(torch.from_numpy(np.log(dist)).float()[:, None].repeat(1, 6)),
            "offsets": nn.Parameter(torch.zeros(n, k, 3)),
        }
        self._new_stats(n)
        self.iteration = 0
        self.order: list[int] = []
        self._build_optimizer()

    def _new_stats(self, n: int) -> None:
        k = self.cfg.num_offsets
        self.opacity_accum = torch.zeros(n, dtype=torch.float64)  # window (pruning)
        self.anchor_demon = torch.zeros(n, dtype=torch.float64)
        self.offset_grad_accum = torch.zeros(n * k, dtype=torch.float64)
        self.offset_denom = torch.zeros(n * k, dtype=torch.float64)
        self.life_opacity = torch.zeros(n, dtype=torch.float64)  # since creation (exported)
        self.life_views = torch.zeros(n, dtype=torch.float64)

    def _build_optimizer(self) -> None:
        groups = [{"params": [self.params[name]], "lr": 0.0, "name": name} for name in self.PARAMS]
        groups += [{"params": list(m.parameters()), "lr": 0.0, "name": f"mlp_{r}"} for r, m in self.mlps.items()]
        self.opt = torch.optim.Adam(groups, lr=0.0, eps=1e-15)
        self._set_lr(self.iteration)

    def _set_lr(self, step: int) -> None:
        cfg = self.cfg
        n = cfg.lr_schedule_iterations if cfg.lr_schedule_iterations is not None else cfg.iterations
        lrs = {
            "features": cfg.feature_lr, "scalings": cfg.scaling_lr,
            "offsets": _expon_lr(step, cfg.offset_lr_init * self.spatial_lr_scale,
                                 cfg.offset_lr_final * self.spatial_lr_scale, n),
            "mlp_opacity": _expon_lr(step, cfg.mlp_opacity_lr_init, cfg.mlp_opacity_lr_final, n),
            "mlp_cov": _expon_lr(step, cfg.mlp_cov_lr_init, cfg.mlp_cov_lr_final, n),
            "mlp_color": _expon_lr(step, cfg.mlp_color_lr_init, cfg.mlp_color_lr_final, n),
        }
        for g in self.opt.param_groups:
            g["lr"] = lrs[g["name"]]

    @property
    def num_anchors(self) -> int:
        return int(self.coords.shape[0])

    def positions(self) -> torch.Tensor:
        """float32 world positions exactly as AnchorScene.positions() defines them."""
        return (self.coords.float() * np.float32(self.voxel_size) + torch.from_numpy(self.origin))

    def scene_tensors(self):
        from ..render.neural_gaussians import SceneTensors

        f, sc, off = self.params["features"], self.params["scalings"], self.params["offsets"]
        if self.rate_model is not None:  # render what the decoder will output (straight-through rounding)
            from .rate_model import quantize_ste

            step = torch.tensor(self.cfg.rate_step, dtype=torch.float32)
            f, sc, off = quantize_ste(f, step), quantize_ste(sc, step), quantize_ste(off, step)
        return SceneTensors(self.positions(), f, sc, off, self.mlps)

    # --- pruning (NAAP or opacity) -----------------------------------------------------
    @torch.no_grad()
    def prune_anchors(self) -> None:
        """NAAP or opacity pruning of the current anchors (encoder/naap.py), importance from the
        opacity accumulated since each anchor's creation; NAAP merges offsets, scalings and the
        accumulated opacity of every pruned anchor into its nearest kept neighbour (eq. 11).
        The optimizer state of the kept anchors carries over."""
        from .naap import NaapConfig, naap_plan, opacity_plan

        cfg = self.cfg
        acc = (self.life_opacity / self.life_views.clamp_min(1)).numpy()
        if cfg.prune == "naap":
            plan = naap_plan(self.coords.numpy(), acc,
                             NaapConfig(keep_ratio=cfg.prune_keep, lam=cfg.naap_lambda, gamma=cfg.naap_gamma))
        else:
            plan = opacity_plan(acc, keep_ratio=cfg.prune_keep)
        merged = {name: torch.from_numpy(plan.merge(self.params[name].detach().numpy(), cfg.naap_gamma))
                  for name in ("scalings", "offsets")}
        merged_acc = plan.merge(acc, cfg.naap_gamma)
        keep = torch.from_numpy(plan.keep)
        self._keep(keep)
        for name, v in merged.items():
            self.params[name].copy_(v)
        self.life_opacity = torch.from_numpy(merged_acc) * self.life_views.clamp_min(1)
        self.pruned += int((~keep).sum())
        self.prune_report = str(plan.report())

    # --- rate-distortion phase ---------------------------------------------------------
    def attribute_values(self) -> torch.Tensor:
        """[N, M] attributes in the codec's channel layout (features, scalings, offsets k-major)."""
        n = self.num_anchors
        return torch.cat([self.params["features"], self.params["scalings"], self.params["offsets"].reshape(n, -1)], 1)

    def _build_rate_model(self, scales=None, twin_size: tuple[int, int, int] | None = None) -> None:
        """The rate model of the current anchors; twin_size (Ch, feature hidden, head hidden): the
        twin's size on resume (None: the encoder's size rule for this many level-2 anchors)."""
        from .ggconv_train import GGConvTrainConfig
        from .rate_model import AnchorRateModel

        from ..common.geometry import normative_order
        from ..common.hierarchy import build_hierarchy
        from .config import EncoderConfig, context_model_size

        cfg = self.cfg
        m = cfg.feature_dim + 6 + 3 * cfg.num_offsets
        coords = self.coords.numpy()
        # the model the encoder will fit for this many level-2 anchors (its size rule), so the scene is
        # trained for a rate that coder can reach
        n2 = build_hierarchy(coords[normative_order(coords)], cfg.rate_voxel_scale).num_level2
        ch, feat_hidden, head_hidden = twin_size or context_model_size(EncoderConfig(), n2)[:3]
        twin = GGConvTrainConfig(neighbour_level=cfg.rate_neighbour_level, ctx_channels=ch, feat_hidden=feat_hidden,
                                 head_hidden=head_hidden, seed=cfg.seed)
        self.rate_model = AnchorRateModel(coords, np.full(m, cfg.rate_step), cfg.feature_dim,
                                          cfg.rate_voxel_scale, self.attribute_values().detach().numpy(), twin)
        if scales is not None and self.rate_model.twin is not None:  # resume: the saved input scales
            self.rate_model.twin.feat_q, self.rate_model.twin.head_q_raw = scales
        self.rate_opt = torch.optim.Adam(self.rate_model.parameters(), lr=cfg.rate_lr)

    def _rate_scales(self):
        t = self.rate_model.twin
        return None if t is None else (t.feat_q, t.head_q_raw)

    # --- one iteration ---------------------------------------------------------------
    def _next_view(self) -> int:
        if not self.order:
            self.order = self.np_rng.permutation(len(self.ds.train)).tolist()
        return self.order.pop()

    def step(self) -> dict:
        from ..render.metrics import ssim_torch
        from ..render.neural_gaussians import (anchor_bounding_radii, generate_neural_gaussians,
                                                   visible_anchors)
        cfg = self.cfg
        it = self.iteration + 1
        self._set_lr(it)
        vi = self._next_view()
        cam, gt = self.ds.train[vi], self.train_images[vi]
        st = self.scene_tensors()
        ng = generate_neural_gaussians(st, cam)
        if ng.num_gaussians == 0:
            # nothing visible: the loss cannot reach any parameter; count the iteration
            self.iteration = it
            return {"loss": float("nan"), "gaussians": 0}
        ng.means.retain_grad()
        res = self.rasterize(ng.means, ng.quats, ng.scales, ng.opacities, ng.colors, cam, background=self.bg)
        img = res.image
        l1 = (img - gt).abs().mean()
        loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1 - ssim_torch(img, gt))
        if cfg.lambda_volume:
            loss = loss + cfg.lambda_volume * ng.scales.prod(dim=1).mean()
        if self.rate_model is not None:
            bits = self.rate_model(self.attribute_values(), generator=self.gen)["total"]
            self.rate_bits = float(bits.detach()) / self.num_anchors
            loss = loss + cfg.rate_lambda * bits.float() / (self.num_anchors * self.rate_model.num_attrs)
        loss.backward()
        with torch.no_grad():
            if it > cfg.stats_from and it <= cfg.densify_until:
                self._accumulate(st, ng, cam, anchor_bounding_radii, visible_anchors)
            self._accumulate_life(ng)
        self.opt.step()
        self.opt.zero_grad(set_to_none=True)
        if self.rate_opt is not None:
            self.rate_opt.step()
            self.rate_opt.zero_grad(set_to_none=True)
        self.iteration = it
        lv = float(loss.detach())
        self.loss_ema = lv if self.loss_ema is None else 0.6 * self.loss_ema + 0.4 * lv
        if (cfg.densify_from < it <= cfg.densify_until and it % cfg.densify_interval == 0):
            self.adjust_anchors()
        if cfg.prune != "none" and it == cfg.prune_iteration:
            self.prune_anchors()
        if cfg.rate_lambda > 0 and self.rate_model is None and it >= cfg.rate_iteration:
            self._build_rate_model()  # the anchor set is final: no growing or pruning after densify_until
        return {"loss": lv, "gaussians": ng.num_gaussians}

    def _accumulate(self, st, ng, cam, anchor_bounding_radii, visible_anchors) -> None:
        k = self.cfg.num_offsets
        radii = anchor_bounding_radii(st.scalings, st.offsets, None)
        vis = visible_anchors(st.positions, radii, cam)
        self.anchor_demon[vis] += 1
        op = ng.opacities.detach().double().clamp_min(0)
        self.opacity_accum.index_add_(0, ng.anchor_index, op)
        g = ng.means.grad
        if g is None:
            return
        r = torch.as_tensor(cam.rotation, dtype=torch.float64)
        t = torch.as_tensor(cam.translation, dtype=torch.float64)
        gc = g.double() @ r.T
        z = (ng.means.detach().double() @ r.T + t)[:, 2].clamp_min(cam.near)
        gx = gc[:, 0] * z / cam.fx * (cam.width / 2)
        gy = gc[:, 1] * z / cam.fy * (cam.height / 2)
        gn = torch.sqrt(gx * gx + gy * gy)
        drawn = torch.isfinite(gn) & (gn > 0)  # Gaussians that reached the image
        flat = (ng.anchor_index * k + ng.offset_index)[drawn]
        self.offset_grad_accum.index_add_(0, flat, gn[drawn])
        self.offset_denom.index_add_(0, flat, torch.ones_like(gn[drawn]))

    def _accumulate_life(self, ng) -> None:
        k = self.cfg.num_offsets
        op = ng.opacities.detach().double().clamp_min(0) / k
        self.life_opacity.index_add_(0, ng.anchor_index, op)
        seen = torch.unique(ng.anchor_index)
        self.life_views[seen] += 1

    # --- growing and pruning ---------------------------------------------------------
    @torch.no_grad()
    def adjust_anchors(self) -> None:
        cfg = self.cfg
        check = cfg.densify_interval
        grads = self.offset_grad_accum / self.offset_denom
        grads[~torch.isfinite(grads)] = 0.0
        offset_mask = self.offset_denom > check * cfg.success_threshold * 0.5
        n_before = self.num_anchors
        self._grow(grads, cfg.densify_grad_threshold, offset_mask)
        n_new = self.num_anchors - n_before
        k = cfg.num_offsets
        pad = torch.zeros(n_new * k, dtype=torch.float64)
        self.offset_denom[offset_mask] = 0
        self.offset_grad_accum[offset_mask] = 0
        self.offset_denom = torch.cat([self.offset_denom, pad])
        self.offset_grad_accum = torch.cat([self.offset_grad_accum, pad])
        pad_a = torch.zeros(n_new, dtype=torch.float64)
        self.opacity_accum = torch.cat([self.opacity_accum, pad_a])
        self.anchor_demon = torch.cat([self.anchor_demon, pad_a])
        self.life_opacity = torch.cat([self.life_opacity, pad_a])
        self.life_views = torch.cat([self.life_views, pad_a])
        prune = (self.opacity_accum < cfg.min_opacity * self.anchor_demon)
        seen_enough = self.anchor_demon > check * cfg.success_threshold
        prune &= seen_enough
        self.opacity_accum[seen_enough] = 0
        self.anchor_demon[seen_enough] = 0
        if bool(prune.all()):  # never remove every anchor
            prune[torch.argmax(self.life_opacity / self.life_views.clamp_min(1))] = False
        if bool(prune.any()):
            self.pruned += int(prune.sum())
            self._keep(~prune)

    def _grow(self, grads: torch.Tensor, threshold: float, offset_mask: torch.Tensor) -> None:
        cfg, k = self.cfg, self.cfg.num_offsets
        init_len = self.num_anchors * k
        vs = self.voxel_size
        for i in range(cfg.update_depth):
            cur_threshold = threshold * ((cfg.update_hierarchy_factor // 2) ** i)
            cand = (grads >= cur_threshold) & offset_mask
            cand &= torch.rand(cand.shape, generator=self.gen) > 0.5 ** (i + 1)
            inc = self.num_anchors * k - init_len
            if inc == 0 and i > 0 and cfg.skip_finer_levels:
                continue
            if inc:
                cand = torch.cat([cand, torch.zeros(inc, dtype=torch.bool)])
            if not bool(cand.any()):
                continue
            size_factor = max(cfg.update_init_factor // (cfg.update_hierarchy_factor ** i), 1)
            pos = self.positions().double()
            s = torch.exp(self.params["scalings"].detach().double())
            all_xyz = (pos[:, None, :] + self.params["offsets"].detach().double() * s[:, None, :3]).reshape(-1, 3)
            sel = all_xyz[cand]
            # grid of voxel size eps * size_factor, in units of eps (anchors stay on the eps grid)
            sel_grid = torch.round((sel - torch.from_numpy(self.origin).double()) / (vs * size_factor)).long()
            uniq, inverse = torch.unique(sel_grid, dim=0, return_inverse=True)
            existing = torch.round(self.coords.double() / size_factor).long()
            free = ~_rows_in(uniq, existing)
            if not bool(free.any()):
                continue
            new_coords = uniq[free] * size_factor
            feat = self.params["features"].detach()[:, None, :].expand(-1, k, -1).reshape(-1, cfg.feature_dim)[cand]
            nf = torch.full((uniq.shape[0], cfg.feature_dim), -torch.inf)
            nf = nf.scatter_reduce(0, inverse[:, None].expand(-1, cfg.feature_dim), feat, "amax")[free]
            m = new_coords.shape[0]
            self.grown += m
            new_scal = torch.full((m, 6), math.log(vs * size_factor), dtype=torch.float32)
            self._append(new_coords, nf, new_scal, torch.zeros(m, k, 3))

    def _replace(self, name: str, tensor: torch.Tensor, keep: torch.Tensor | None, n_add: int) -> None:
        old = self.params[name]
        p = nn.Parameter(tensor.contiguous())
        for g in self.opt.param_groups:
            if g["name"] == name:
                g["params"][0] = p
        stt = self.opt.state.pop(old, None)
        if stt:
            for key in ("exp_avg", "exp_avg_sq"):
                v = stt[key]
                if keep is not None:
                    v = v[keep]
                if n_add:
                    v = torch.cat([v, torch.zeros((n_add,) + tuple(v.shape[1:]), dtype=v.dtype)])
                stt[key] = v.contiguous()
            self.opt.state[p] = stt
        self.params[name] = p

    def _append(self, coords, feat, scal, off) -> None:
        m = coords.shape[0]
        self.coords = torch.cat([self.coords, coords])
        for name, new in (("features", feat), ("scalings", scal), ("offsets", off)):
            self._replace(name, torch.cat([self.params[name].detach(), new.float()]), None, m)

    def _keep(self, keep: torch.Tensor) -> None:
        k = self.cfg.num_offsets
        self.coords = self.coords[keep]
        for name in self.PARAMS:
            self._replace(name, self.params[name].detach()[keep], keep, 0)
        keep_o = keep[:, None].expand(-1, k).reshape(-1)
        self.offset_denom, self.offset_grad_accum = self.offset_denom[keep_o], self.offset_grad_accum[keep_o]
        for a in ("opacity_accum", "anchor_demon", "life_opacity", "life_views"):
            setattr(self, a, getattr(self, a)[keep])

    # --- evaluation ------------------------------------------------------------------
    @torch.no_grad()
    def evaluate(self, num_views: int = 0) -> dict:
        from ..render.metrics import psnr, ssim

        test = self.ds.test
        if num_views and num_views < len(test):
            test = [test[i] for i in np.linspace(0, len(test) - 1, num_views).round().astype(int)]
        scene = self.to_scene()
        ps, ss = [], []
        for cam in test:
            img = render_image(scene, cam, self.bg)
            ps.append(psnr(img, cam.image))
            ss.append(ssim(img, cam.image))
        return {"iteration": self.iteration, "time_s": round(self.elapsed, 2), "psnr": float(np.mean(ps)),
                "ssim": float(np.mean(ss)), "views": len(test), "anchors": self.num_anchors,
                "grown": self.grown, "pruned": self.pruned, "loss_ema": self.loss_ema,
                **({} if self.rate_model is None else {"rate_bits_per_anchor": self._rate_estimate()})}

    @torch.no_grad()
    def _rate_estimate(self) -> float:
        """Estimated attribute bits per anchor of the rounded attributes (no noise)."""
        return float(self.rate_model(self.attribute_values(), noise=False)["total"]) / self.num_anchors

    # --- export and checkpoints ------------------------------------------------------
    def to_scene(self) -> AnchorScene:
        mlps = {r: m.to_render_mlp() for r, m in self.mlps.items()}
        acc = (self.life_opacity / self.life_views.clamp_min(1)).float().numpy()
        return AnchorScene(coords=self.coords.numpy().copy(), voxel_size=self.voxel_size, origin=self.origin.copy(),
                           features=self.params["features"].detach().numpy().copy(),
                           scalings=self.params["scalings"].detach().numpy().copy(),
                           offsets=self.params["offsets"].detach().numpy().copy(), mlps=mlps,
                           extra={"opacity_accum": acc})

    def state_dict(self) -> dict:
        return {
            "version": STATE_VERSION, "config": dataclasses.asdict(self.cfg), "iteration": self.iteration,
            "voxel_size": self.voxel_size, "origin": self.origin, "coords": self.coords,
            "params": {k: v.detach() for k, v in self.params.items()},
            "mlps": {r: m.state_dict() for r, m in self.mlps.items()},
            "optimizer": self.opt.state_dict(),
            "stats": {a: getattr(self, a) for a in ("opacity_accum", "anchor_demon", "offset_grad_accum",
                                                    "offset_denom", "life_opacity", "life_views")},
            "np_rng": self.np_rng.bit_generator.state, "torch_gen": self.gen.get_state(),
            "order": list(self.order), "history": self.history, "elapsed": self.elapsed,
            "loss_ema": self.loss_ema, "grown": self.grown, "pruned": self.pruned,
            "rate": None if self.rate_model is None else {
                "model": self.rate_model.state_dict(), "optimizer": self.rate_opt.state_dict(),
                "scales": self._rate_scales()},
        }

    def load_state_dict(self, sd: dict) -> None:
        self.iteration = int(sd["iteration"])
        self.voxel_size = float(sd["voxel_size"])
        self.origin = np.asarray(sd["origin"], np.float32)
        self.coords = sd["coords"].clone()
        c, k = self.cfg.feature_dim, self.cfg.num_offsets
        self.mlps = {"opacity": _make_mlp(c, k, "tanh"), "cov": _make_mlp(c, 7 * k, "none"),
                     "color": _make_mlp(c, 3 * k, "sigmoid")}
        for r, m in self.mlps.items():
            m.load_state_dict(sd["mlps"][r])
        self.params = {k_: nn.Parameter(v.clone()) for k_, v in sd["params"].items()}
        for a, v in sd["stats"].items():
            setattr(self, a, v.clone())
        self.np_rng = np.random.default_rng()
        self.np_rng.bit_generator.state = sd["np_rng"]
        self.gen = torch.Generator()
        self.gen.set_state(sd["torch_gen"])
        self.order = list(sd["order"])
        self.history = list(sd["history"])
        self.elapsed = float(sd["elapsed"])
        self.loss_ema = sd["loss_ema"]
        self.grown, self.pruned = int(sd.get("grown", 0)), int(sd.get("pruned", 0))
        self._build_optimizer()
        self.opt.load_state_dict(sd["optimizer"])
        self._set_lr(self.iteration)
        if sd.get("rate") is not None:
            model_sd = dict(sd["rate"]["model"])
            # the twin's size as saved (the encoder's size rule may have changed since)
            twin_size = None if "twin.table" not in model_sd else (
                model_sd["twin.table"].shape[1], model_sd["twin.feat.0.lin.weight"].shape[0],
                model_sd["twin.head.0.lin.weight"].shape[0])
            self._build_rate_model(sd["rate"]["scales"], twin_size)
            twin = self.rate_model.twin
            if twin is not None and "twin.parent_base" not in model_sd:
                # a checkpoint from before parent_base existed: its twin's mean was parent + o
                model_sd["twin.parent_base"] = torch.ones_like(twin.parent_base)
            self.rate_model.load_state_dict(model_sd)
            self.rate_opt.load_state_dict(sd["rate"]["optimizer"])

    def save_checkpoint(self) -> Path:
        twin = None if self.rate_model is None else self.rate_model.context_twin()
        folder = write_checkpoint_folder(self.to_scene(), self.out, self.iteration, twin)
        buf = io.BytesIO()
        torch.save(self.state_dict(), buf)
        atomic_write_bytes(self.out / STATE_NAME, buf.getvalue())
        self._write_metrics()
        if self.cfg.keep_checkpoints > 0:
            its = sorted(int(d.name.split("_")[1]) for d in (self.out / "point_cloud").glob("iteration_*")
                         if d.name.split("_")[1].isdigit())
            for old in its[:-self.cfg.keep_checkpoints]:
                if old != self.iteration:
                    shutil.rmtree(self.out / "point_cloud" / f"iteration_{old}", ignore_errors=True)
        return folder

    def _write_metrics(self) -> None:
        atomic_write_bytes(self.out / "metrics.json", json.dumps(self.history, indent=1).encode())
        sio = io.StringIO()
        fields = ["iteration", "time_s", "psnr", "ssim", "views", "anchors", "grown", "pruned", "loss_ema",
                  "rate_bits_per_anchor"]
        w = csv.DictWriter(sio, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for h in self.history:
            w.writerow(h)
        atomic_write_bytes(self.out / "metrics.csv", sio.getvalue().encode())


TMP_PREFIX = ".tmp_"  # point_cloud/.tmp_iteration_<N>_<pid>: a checkpoint folder being written
OLD_PREFIX = ".old_"  # point_cloud/.old_iteration_<N>_<pid>: a replaced folder about to be removed


def write_checkpoint_folder(scene: AnchorScene, out: Path, iteration: int, twin=None) -> Path:
    """``write_scaffold`` into a temporary sibling of ``out/point_cloud/iteration_<N>``, renamed
    into place once complete (PLY and MLPs, and the rate phase's context twin, ``TWIN_FILE``,
    which lghcc-enc starts its GG-Conv fit from), so a run killed mid-write never leaves an
    iteration folder without its MLPs (readers take the newest ``iteration_<N>``; the hidden
    temporary names do not match). A folder already there for N (a repeated checkpoint) is
    moved aside first and removed after. Leftovers of killed writes are removed."""
    pc = Path(out) / "point_cloud"
    pc.mkdir(parents=True, exist_ok=True)
    for d in pc.iterdir():
        if d.is_dir() and d.name.startswith((TMP_PREFIX, OLD_PREFIX)):
            shutil.rmtree(d, ignore_errors=True)
    name = f"iteration_{iteration}"
    tmp_model = pc / f"{TMP_PREFIX}{name}_{os.getpid()}"
    written = write_scaffold(scene, tmp_model, iteration)  # tmp_model/point_cloud/iteration_<N>
    if twin is not None:
        from .ggconv_train import TWIN_FILE

        twin.save(Path(written) / TWIN_FILE)
    staged = pc / f"{TMP_PREFIX}{name}_{os.getpid()}.ready"
    os.replace(written, staged)
    shutil.rmtree(tmp_model)
    final = pc / name
    old = None
    if final.exists():
        old = pc / f"{OLD_PREFIX}{name}_{os.getpid()}"
        os.replace(final, old)
    os.replace(staged, final)
    _fsync_dir(pc)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _rows_in(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Bool [len(a)]: rows of a (int64 [n, 3]) present in b ([m, 3])."""
    if b.numel() == 0 or a.numel() == 0:
        return torch.zeros(a.shape[0], dtype=torch.bool)
    both = torch.cat([b, a])
    _, inv = torch.unique(both, dim=0, return_inverse=True)
    in_b = torch.zeros(int(inv.max()) + 1, dtype=torch.bool)
    in_b[inv[: b.shape[0]]] = True
    return in_b[inv[b.shape[0]:]]


def _background(spec) -> np.ndarray:
    from ..render.datasets import parse_background

    return parse_background(spec)


@torch.no_grad()
def render_image(scene, cam, background) -> np.ndarray:
    """Render ``scene`` (AnchorScene or SceneTensors) for ``cam``; [H, W, 3] float64 clipped to [0, 1]."""
    from ..render.rasterizer import render_scene

    bg = torch.as_tensor(np.asarray(background, np.float32).reshape(3))
    # the CPU reference renderer, as in training: reported metrics do not depend on the machine
    return render_scene(scene, cam, background=bg, backend="torch").image.clamp(0, 1).double().numpy()


def evaluate_model(model: str | Path, data: str | Path, background: str = "white", downscale: int = 1,
                   images: str | None = None, voxel_size: float | None = None) -> dict:
    """Test-view PSNR / SSIM of a Scaffold-GS model (e.g. a decoded .lghcc) on a dataset."""
    from ..formats.scaffold_io import read_scaffold

    scene = read_scaffold(model, voxel_size=voxel_size)
    ds = load_dataset(data, background, downscale, images)
    return {"model": str(model), **evaluate_scene(scene, ds.test, background)}


def evaluate_scene(scene, cams: list, background: str = "white") -> dict:
    """Mean PSNR / SSIM of ``scene`` (an AnchorScene) against the images of ``cams``
    (lghcc.render.scenes.evaluate: the CPU reference renderer)."""
    from ..render.scenes import evaluate

    ev = evaluate(scene, None, cams, background=_background(background), backend="torch")
    return {"psnr": ev.psnr, "ssim": ev.ssim, "views": ev.views, "anchors": scene.num_anchors}


# ------------------------------------------------------------------------------------------
# Driver
# ------------------------------------------------------------------------------------------

@dataclass
class TrainResult:
    out: Path
    iteration: int
    finished: bool
    history: list
    scene: AnchorScene


def _check_config(cfg: TrainConfig) -> None:
    from ..render.rasterizer import select_device

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


def read_train_state(out: str | Path) -> dict:
    """The training state of the run in ``out`` (``STATE_NAME``); InputError naming the file
    when it is missing, unreadable or of another version."""
    sp = Path(out) / STATE_NAME
    if not sp.is_file():
        raise InputError(f"{sp}: no training state to resume from")
    try:
        state = torch.load(sp, map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001
        raise InputError(f"{sp}: cannot load ({e})") from None
    if state.get("version") != STATE_VERSION:
        raise InputError(f"{sp}: training state version {state.get('version')} not supported")
    return state


def train(cfg: TrainConfig, out: str | Path, *, resume: bool = False, stop_after: int | None = None,
          time_limit_s: float | None = None, progress: bool = True, log=print,
          iterations: int | None = None) -> TrainResult:
    """Train (or resume) into ``out``. ``stop_after``: stop after that iteration with a
    checkpoint, as if interrupted (a later ``resume=True`` continues exactly). ``time_limit_s``:
    stop (with a checkpoint and a full evaluation) once this much training time has passed.
    ``iterations`` (with ``resume``): a new total for the run, also for a finished one, which
    then continues (the learning-rate decays keep their original span; the added iterations
    use the final rates); smaller than the iteration reached raises InputError."""
    out = Path(out)
    state = None
    if resume:
        state = read_train_state(out)
        saved = TrainConfig(**state["config"])
        saved.threads = cfg.threads  # a resumed run may change the threads and extend the iterations
        saved.device = cfg.device
        reached = int(state["iteration"])
        if iterations is not None and iterations != saved.iterations:
            if iterations < reached:
                raise InputError(f"{out}: the run is already at iteration {reached}; --iterations {iterations} "
                                 "cannot shorten it")
            if saved.lr_schedule_iterations is None:
                saved.lr_schedule_iterations = saved.iterations
            log(f"run extended from {saved.iterations} to {iterations} iterations (the learning-rate decays keep "
                f"their span of {saved.lr_schedule_iterations}; later iterations use the final rates)")
            saved.iterations = iterations
            atomic_write_bytes(out / "config.yaml",
                               yaml.safe_dump(dataclasses.asdict(saved), sort_keys=False).encode())
        elif reached >= saved.iterations:
            log(f"the run already finished at iteration {reached} of {saved.iterations}; "
                "give --iterations N (> the current count) to continue it")
        cfg = saved
    _check_config(cfg)
    torch.set_num_threads(cfg.threads)
    ds = load_dataset(cfg.data, cfg.background, cfg.downscale, cfg.images)
    out.mkdir(parents=True, exist_ok=True)
    tr = Trainer(cfg, ds, out)
    if state is not None:
        tr.load_state_dict(state)
        log(f"resumed at iteration {tr.iteration} ({tr.num_anchors:,} anchors)")
    else:
        tr.fresh()
        atomic_write_bytes(out / "config.yaml", yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False).encode())
        log(f"{ds.kind}: {len(ds.train)} training / {len(ds.test)} test views of "
            f"{ds.train[0].width}x{ds.train[0].height}; {tr.num_anchors:,} initial anchors, "
            f"voxel size {tr.voxel_size:.5g}, C={cfg.feature_dim}, K={cfg.num_offsets}")
    bar = None
    if progress:
        from ..app.progress import progress_bar

        bar = progress_bar(total=cfg.iterations, initial=tr.iteration, desc="train", dynamic_ncols=True, file=sys.stderr)
    finished = tr.iteration >= cfg.iterations
    t_start = time.perf_counter() - tr.elapsed
    while tr.iteration < cfg.iterations:
        info = tr.step()
        tr.elapsed = time.perf_counter() - t_start
        it = tr.iteration
        if cfg.prune != "none" and it == cfg.prune_iteration and tr.prune_report:
            (bar.write if bar is not None else log)(f"[it {it}] pruned after growing: {tr.prune_report}")
        if bar is not None:
            bar.update(1)
            if it % 10 == 0:
                bar.set_postfix(loss=f"{tr.loss_ema:.4f}" if tr.loss_ema is not None else "-",
                                anchors=tr.num_anchors, gs=info["gaussians"],
                                **({} if tr.rate_bits is None else {"bits_per_anchor": f"{tr.rate_bits:.0f}"}))
        last = it >= cfg.iterations
        timed_out = time_limit_s is not None and tr.elapsed >= time_limit_s
        if it % cfg.eval_interval == 0 or last or timed_out:
            t0 = time.perf_counter()
            rec = tr.evaluate(0 if (last or timed_out) else cfg.eval_views)
            t_start += time.perf_counter() - t0  # evaluation time is not training time
            tr.history.append(rec)
            if tr.prune_report and not any(h.get("pruning") for h in tr.history):
                rec["pruning"] = tr.prune_report
            msg = (f"[it {it}] test PSNR {rec['psnr']:.2f} dB, SSIM {rec['ssim']:.4f} ({rec['views']} views), "
                   f"{rec['anchors']:,} anchors (+{tr.grown:,} grown, -{tr.pruned:,} pruned so far), {tr.elapsed:.0f} s"
                   + (f", ~{rec['rate_bits_per_anchor']:.0f} attribute bits/anchor" if "rate_bits_per_anchor" in rec
                      else ""))
            (bar.write(msg) if bar is not None else log(msg))
        if it % cfg.checkpoint_interval == 0 or last or timed_out or (stop_after is not None and it >= stop_after):
            t0 = time.perf_counter()
            tr.save_checkpoint()
            t_start += time.perf_counter() - t0
        if last:
            finished = True
        if timed_out or (stop_after is not None and it >= stop_after):
            break
    if bar is not None:
        bar.close()
    if finished and tr.history and tr.history[-1]["iteration"] != tr.iteration:
        tr.history.append(tr.evaluate(0))
        tr.save_checkpoint()
    return TrainResult(out, tr.iteration, finished, tr.history, tr.to_scene())


DESCRIPTION = """\
Train an anchor-based 3D Gaussian Splatting scene (Scaffold-GS) from posed images, on the
CPU, with lghcc's own differentiable renderer, and write it in the Scaffold-GS checkpoint
layout that lghcc-enc compresses.

The data folder's layout is found by its files: NeRF-synthetic (transforms_train.json,
transforms_test.json and the images they name), COLMAP (sparse/0 or sparse/ as .bin or .txt,
and images/), Mip-NeRF 360 (COLMAP sparse/0 with images_2/4/8: --downscale 4 reads images_4),
LLFF (poses_bounds.npy and images/; its sparse/0, when kept, gives the cameras and the SfM
points). Anchors start from the COLMAP model's points3D when there are some (--init sfm),
else from random points in the region all training cameras see (NeRF-synthetic) or on random
camera rays; they then grow where the image gradients are large and are pruned where they
stay transparent.

Time: one iteration renders one view. On lego at 100x100 pixels an iteration took 0.19 s on
2 CPU threads (tools/results/training.md): 8,000 iterations in 25 minutes, the default 30,000
in about 1.5 hours; more pixels take proportionally longer. Try --iterations 2000 first;
--time-limit MIN bounds a run, --resume continues it.

The output folder gets point_cloud/iteration_<N>/ (the scene), train_state.pth (to resume
with --resume), metrics.json/metrics.csv (test PSNR/SSIM over training) and config.yaml.

examples:
  lghcc-train data/lego -o runs/lego --iterations 7000
  lghcc-train data/lego -o runs/lego --resume             continue an interrupted run
  lghcc-train data/lego -o runs/lego --config my.yaml     options from a YAML file
  lghcc-enc runs/lego -o lego.lghcc                       then compress the result
  lghcc-dec lego.lghcc -o dec/ && lghcc-train data/lego --evaluate dec/    quality after decoding
"""


def setup_args() -> argparse.ArgumentParser:
    from ..app.cliargs import add_overwrite_options, add_version_option

    d = TrainConfig()
    from ..app.cli_common import EXIT_ERROR, EXIT_INTERRUPTED, EXIT_OK, EXIT_RESOURCE_LIMIT, EXIT_USAGE, exit_status_epilog

    p = argparse.ArgumentParser(prog="lghcc-train", description=DESCRIPTION,
                                epilog=exit_status_epilog(
                                    {EXIT_RESOURCE_LIMIT: "the system ran out of memory",
                                     EXIT_INTERRUPTED: "interrupted (Ctrl-C); continue with --resume from the last "
                                                       "checkpoint (every file is written atomically)"},
                                    codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED)),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    p.add_argument("data", nargs="?", help="folder with the posed images (NeRF-synthetic, LLFF or COLMAP layout)")
    p.add_argument("-o", "--output", help="output folder (the trained model and logs)")
    p.add_argument("--evaluate", metavar="MODEL",
                   help="do not train: render the test views of the data with this Scaffold-GS model folder "
                        "(e.g. lghcc-dec's output) and print PSNR / SSIM")
    p.add_argument("--config", metavar="YAML",
                   help="YAML file of options (keys as the long options, with _ or -); the command line wins")
    add_overwrite_options(p, "run files in the output folder (a fresh run replaces them)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in the output folder from its last checkpoint (its saved settings are "
                        "used, except --threads; a larger --iterations extends the run, also a finished one)")
    g = p.add_argument_group("training")
    g.add_argument("--iterations", type=int, default=d.iterations, help=f"training steps, one view each (default {d.iterations})")
    g.add_argument("--seed", type=int, default=d.seed, help="random seed (default 0): same seed, same result")
    g.add_argument("--threads", type=int, default=d.threads, help=f"CPU threads for torch (default {d.threads})")
    g.add_argument("--device", choices=("cpu", "cuda"), default=d.device,
                   help="where the rasterizer runs: cpu (default), or cuda (gsplat's CUDA rasterizer: pip install "
                        "'lghcc[gsplat]'; the MLPs and the optimizer stay on the CPU)")
    g.add_argument("--time-limit", type=float, metavar="MIN",
                   help="stop after this many minutes of training (checkpoint + full evaluation); resume later")
    g.add_argument("--stop-after", type=int, metavar="N",
                   help="stop after iteration N with a checkpoint, as if interrupted (resume later)")
    g = p.add_argument_group("scene")
    g.add_argument("--feature-dim", type=int, default=d.feature_dim, help=f"anchor feature size C (default {d.feature_dim})")
    g.add_argument("--num-offsets", "-K", type=int, default=d.num_offsets,
                   help=f"neural Gaussians per anchor K (default {d.num_offsets})")
    g.add_argument("--voxel-size", type=float, help="anchor voxel size eps (default: the extent of the initial "
                   f"points / --voxels-per-extent, {d.voxels_per_extent:g})")
    g.add_argument("--voxels-per-extent", type=float, default=d.voxels_per_extent, metavar="N",
                   help=f"without --voxel-size: the voxel size is the extent of the initial points / N (default "
                        f"{d.voxels_per_extent:g}; larger: finer anchors, more of them)")
    g.add_argument("--init", choices=("auto", "random", "sfm"), default=d.init,
                   help="initial points: random (see above) or the COLMAP model's points; auto: sfm when present")
    g.add_argument("--init-points", type=int, default=d.init_points,
                   help=f"random initial points before voxelization (default {d.init_points})")
    g = p.add_argument_group("images")
    g.add_argument("--background", default=d.background,
                   help="colour behind transparent pixels and the scene: white, black or r,g,b in [0,1] (default white)")
    g.add_argument("--downscale", type=int, default=d.downscale,
                   help="train and test at 1/N of the image resolution: the dataset's images_N when it has them "
                        "(Mip-NeRF 360, LLFF), else area averaging (default 1)")
    g.add_argument("--images", default=d.images,
                   help="image folder of LLFF/COLMAP/Mip-NeRF 360 scenes (default: images_N for --downscale N when "
                        "the folder has it, else images)")
    g = p.add_argument_group("evaluation and checkpoints")
    g.add_argument("--eval-interval", type=int, default=d.eval_interval,
                   help=f"evaluate on the test views every N iterations (default {d.eval_interval})")
    g.add_argument("--eval-views", type=int, default=d.eval_views,
                   help="test views used at the intermediate evaluations (0 = all; the final one uses all)")
    g.add_argument("--checkpoint-interval", type=int, default=d.checkpoint_interval,
                   help=f"write a checkpoint every N iterations (default {d.checkpoint_interval}) and at the end")
    g.add_argument("--keep-checkpoints", type=int, default=d.keep_checkpoints,
                   help="keep the last N point_cloud/iteration_* folders (0 = all; default 2)")
    g = p.add_argument_group("anchor growing and pruning (Scaffold-GS defaults)")
    g.add_argument("--stats-from", type=int, default=d.stats_from, help="start gathering statistics (default 500)")
    g.add_argument("--densify-from", type=int, default=d.densify_from, help="first growing/pruning (default 1500)")
    g.add_argument("--densify-until", type=int, default=d.densify_until, help="last growing/pruning (default 15000)")
    g.add_argument("--densify-interval", type=int, default=d.densify_interval, help="every N iterations (default 100)")
    g.add_argument("--densify-grad-threshold", type=float, default=d.densify_grad_threshold,
                   help="screen-space gradient that spawns anchors (default 0.0002)")
    g.add_argument("--min-opacity", type=float, default=d.min_opacity,
                   help="prune anchors whose summed neural opacity per view stays below this (default 0.005)")
    g.add_argument("--skip-finer-levels", action="store_true",
                   help="Scaffold-GS's literal growing rule: no finer level when the coarsest adds no anchor")
    g = p.add_argument_group("anchor pruning after growing (then training goes on with the pruned set)")
    g.add_argument("--prune", choices=("none", "naap", "opacity"), default=d.prune,
                   help="naap: Neighborhood-Aware Anchor Pruning (importance from each anchor's accumulated opacity "
                        "and its k-NN neighbourhood; pruned anchors merged into their nearest kept neighbour); "
                        "opacity: drop the anchors of lowest accumulated opacity (Context-GS). Default none")
    g.add_argument("--prune-keep", type=float, default=d.prune_keep,
                   help=f"fraction of the anchors kept (default {d.prune_keep})")
    g.add_argument("--prune-at", type=int, help="iteration of the pruning (default: --densify-until)")
    g = p.add_argument_group("rate-distortion training (LG-HCC: L = L_render + lambda x estimated attribute bits)")
    g.add_argument("--rate-lambda", type=float, default=d.rate_lambda,
                   help="weight of the estimated bits per attribute value under the codec's hierarchy and GG-Conv "
                        "context (0: plain Scaffold-GS, the default; on lego 100x100, 0.004: -0.1 dB, "
                        "0.05: -2.3 dB and half the attribute bits; tools/results/training.md)")
    g.add_argument("--rate-from", type=int, help="first iteration with the rate term (default: --densify-until; "
                   "not earlier, the anchor set must be final)")
    g.add_argument("--rate-step", type=float, default=d.rate_step,
                   help=f"the quantization step the encoder will use (default {d.rate_step}, preset medium)")
    g.add_argument("--rate-voxel-scale", type=int, default=d.rate_voxel_scale,
                   help=f"the encoder's coarse voxel scale (default {d.rate_voxel_scale})")
    g.add_argument("--rate-neighbour-level", type=int, choices=(1, 2), default=d.rate_neighbour_level,
                   help="the encoder's GG-Conv neighbour level (default 1)")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def _config_from_yaml(path: str) -> dict:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: config file not found")
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as e:
        raise InputError(f"{p}: not valid YAML ({e})") from None
    if not isinstance(data, dict):
        raise InputError(f"{p}: expected a mapping of option: value")
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    out = {}
    for key, v in data.items():
        k = str(key).replace("-", "_")
        if k not in fields:
            raise InputError(f"{p}: unknown option {key!r} (known: {', '.join(sorted(fields))})")
        out[k] = v
    return out


def explicit_options(args: argparse.Namespace, argv: list[str] | None) -> set[str]:
    """TrainConfig fields the user set: on the command line or in the --config file."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    given = setup_args()
    for action in given._actions:
        action.default = argparse.SUPPRESS
        action.required = False
    out = {k for k in vars(given.parse_args(argv)) if k in fields}
    if args.config:
        out |= set(_config_from_yaml(args.config)) & fields
    return out


def config_from_args(args: argparse.Namespace, argv: list[str] | None) -> TrainConfig:
    """Defaults, then the YAML file, then the options given on the command line."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    values = {k: v for k, v in vars(args).items() if k in fields}
    if args.config:
        values.update(_config_from_yaml(args.config))
        given = setup_args()
        for action in given._actions:
            action.default = argparse.SUPPRESS
            action.required = False
        values.update({k: v for k, v in vars(given.parse_args(argv)).items() if k in fields})
    if args.data is not None:
        values["data"] = str(Path(args.data).absolute())
    try:
        return TrainConfig(**values)
    except TypeError as e:
        raise InputError(str(e)) from None


OUTPUT_NAMES = (STATE_NAME, "point_cloud", "metrics.json", "metrics.csv", "config.yaml")


def _check_fresh_output(out: Path, overwrite: bool) -> None:
    """A new run's output folder: one that holds a run's files (OUTPUT_NAMES) needs --resume,
    or -y, which removes those files first (nothing else in the folder is touched)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"cannot write {out} (it exists and is not a folder)")
    present = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if not present:
        return
    if not overwrite:
        what = "a training run" if STATE_NAME in present else ", ".join(present)
        raise InputError(f"{out} already holds {what}; use --resume to continue it, -y (--overwrite) to start "
                         "over (its run files are replaced), or choose another output folder")
    for n in present:
        p = out / n
        shutil.rmtree(p) if p.is_dir() else p.unlink()


def main(argv: list[str] | None = None) -> int:
    """Exit status: lghcc.app.cli_common (0, 1 input error, 2 usage, 4 out of memory, 130 interrupted), through
    run_cli: one line on stderr."""
    from ..app.cliargs import run_cli

    return run_cli("lghcc-train", _main, argv, "continue with --resume from the last checkpoint")


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = setup_args().parse_args(argv)
    # a failure is reported by run_cli: one line, the exit status of its kind (lghcc.app.cli_common)
    if args.evaluate:
        if not args.data:
            raise InputError("--evaluate needs the data folder")
        torch.set_num_threads(args.threads)
        r = evaluate_model(args.evaluate, args.data, args.background, args.downscale, args.images)
        print(f"{r['model']}: {r['anchors']:,} anchors, test PSNR {r['psnr']:.3f} dB, SSIM {r['ssim']:.4f} "
              f"({r['views']} views)")
        return 0
    if not args.output:
        raise InputError("give the output folder with -o")
    cfg = config_from_args(args, argv)
    if not args.resume and not cfg.data:
        raise InputError("give the data folder (or --resume an existing run)")
    if not args.resume:
        _check_fresh_output(Path(args.output), args.overwrite)
    iterations = None
    if args.resume:
        given = explicit_options(args, argv) - {"data"}
        iterations = cfg.iterations if "iterations" in given else None
        ignored = sorted(given - {"iterations", "threads", "device"})
        if ignored:
            print("lghcc-train: --resume uses the run's saved settings; ignored: "
                  + ", ".join("--" + k.replace("_", "-") for k in ignored), file=sys.stderr)
    res = train(cfg, args.output, resume=args.resume, stop_after=args.stop_after,
                time_limit_s=None if args.time_limit is None else 60.0 * args.time_limit,
                progress=not args.quiet, iterations=iterations)
    last = res.history[-1] if res.history else None
    state = "finished" if res.finished else "stopped (continue with --resume)"
    print(f"{state} at iteration {res.iteration}: {res.scene.num_anchors:,} anchors"
          + (f", test PSNR {last['psnr']:.2f} dB, SSIM {last['ssim']:.4f}" if last else "")
          + f" -> {res.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
