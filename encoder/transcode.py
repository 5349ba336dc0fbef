"""Plain 3DGS PLY -> anchor scene (Scaffold-GS), by fitting against renders of the source.

1. Views: ``views`` training and ``test_views`` held-out cameras on a sphere around the
   source (Fibonacci points, the held-out set on a shifted spiral so that no view is
   shared), looking at the centre of the robust bounding box of the Gaussians with
   opacity >= 0.05, at a distance where that box's sphere fills the field of view.
   The source is rendered into them with render/gaussians3dgs.py (SH colours for each
   view, black background).
2. Anchors: Gaussians with opacity >= ``min_opacity`` are voxelized; the voxel size is
   given or found by bisection so that about ``anchors`` voxels are occupied. One anchor
   per occupied voxel, at the voxel's grid point. Each anchor takes up to K of its
   Gaussians (largest opacity x area first) as offsets; unused slots are masked dead
   (``offset_mask``), Gaussians beyond K in a voxel are dropped (counted in the stats).
   Offset scaling = voxel size; base scaling = 1.25 x the largest scale of its Gaussians.
3. Initialization by distillation (no rendering): features and the three MLPs are fitted
   so that, for random view directions, each live offset reproduces its source Gaussian's
   opacity, scales, rotation and SH colour (Adam, ``distill_steps`` full-batch steps).
4. Render fitting: Adam on features, offsets, scalings and the MLP weights (anchor
   positions stay on the grid), loss (1 - l) L1 + l D-SSIM (l = 0.2, as 3DGS) between
   the anchor scene's render (render/neural_gaussians.py, differentiable) and the source
   render of a random training view, ``iterations`` steps.

PSNR against the source renders on the held-out views is reported after 3 and after 4.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from ..app.progress import progress_bar

from ..common.errors import InputError
from ..common.scene import AnchorScene
from ..render.camera import Camera
from ..render.gaussians3dgs import Gaussians3DGS, load_3dgs_ply, render_3dgs
from ..render.metrics import psnr, ssim_torch
from ..render.neural_gaussians import SceneTensors, TorchMLP, evaluate_anchors
from ..render.rasterizer import render_scene
from ..render.sh import sh_to_rgb


@dataclass
class TranscodeConfig:
    anchors: int | None = None  # target anchor count (default: kept Gaussians / 4)
    voxel_size: float | None = None  # overrides ``anchors``
    feature_dim: int = 32
    num_offsets: int = 10
    views: int = 32  # training views
    test_views: int = 6  # held-out views (PSNR report)
    resolution: int = 128  # square images
    fov_deg: float = 50.0
    min_opacity: float = 0.02  # source Gaussians below this are not anchorized
    distill_steps: int = 400
    iterations: int = 200  # render-fitting steps
    lr_features: float = 0.0075
    lr_offsets: float = 0.002
    lr_scalings: float = 0.005
    lr_mlp: float = 0.004
    lambda_dssim: float = 0.2
    seed: int = 0
    progress: bool = False
    threads: int | None = None
    # where the fitting's rasterizer runs: cpu or cuda (gsplat; lghcc.render.rasterizer.select_device).
    # The held-out evaluation always renders on the CPU (evaluate_views), so reported PSNRs compare.
    device: str = "cpu"


@dataclass
class TranscodeStats:
    gaussians: int  # of the source
    sh_degree: int
    anchors: int
    voxel_size: float
    live_offsets: int
    dropped_gaussians: int  # beyond K in their voxel
    below_min_opacity: int
    views: int
    test_views: int
    resolution: int
    camera_distance: float
    psnr_init: float  # held-out PSNR against the source renders after distillation (NaN: no held-out views)
    psnr_final: float  # and after render fitting
    psnr_init_train: float  # the same on the first 4 training views
    psnr_final_train: float
    distill_loss: float | None  # the last distillation step's (None: no steps)
    fit_loss: list[float]  # every render-fitting step's
    time_render_source_s: float
    time_distill_s: float
    time_fit_s: float
    time_total_s: float

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class TranscodeResult:
    scene: AnchorScene
    stats: TranscodeStats


# --- views --------------------------------------------------------------------------------

def fibonacci_sphere(n: int, offset: float = 0.5) -> np.ndarray:
    """n unit vectors spread evenly on the sphere (golden spiral; ``offset`` shifts the spiral)."""
    i = np.arange(n, dtype=np.float64) + offset
    z = 1 - 2 * i / n
    r = np.sqrt(np.clip(1 - z * z, 0, 1))
    phi = i * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sphere_cameras(center: np.ndarray, radius: float, n: int, *, resolution: int = 128, fov_deg: float = 50.0,
                   offset: float = 0.5, prefix: str = "view") -> list[Camera]:
    """n cameras on a sphere around ``center`` looking at it; the sphere of ``radius``
    around the centre fills the field of view (distance radius / sin(fov / 2) x 1.05)."""
    dist = radius / math.sin(math.radians(fov_deg) / 2) * 1.05
    cams = []
    for j, d in enumerate(fibonacci_sphere(n, offset)):
        cams.append(Camera.look_at(center + dist * d, center, up=(0.0, 0.0, 1.0), width=resolution,
                                   height=resolution, fov_x_deg=fov_deg, near=dist * 1e-3, far=dist * 10,
                                   name=f"{prefix}_{j:03d}"))
    return cams


# --- anchors --------------------------------------------------------------------------------

def _occupied(points: np.ndarray, origin: np.ndarray, voxel: float) -> np.ndarray:
    return np.round((points - origin) / voxel).astype(np.int64)


def voxel_size_for_count(points: np.ndarray, target: int) -> float:
    """Voxel size whose grid (through the world origin) has about ``target`` occupied voxels."""
    origin = np.zeros(3)
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    lo, hi = extent * 1e-5, extent * 2
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        n = np.unique(_occupied(points, origin, mid), axis=0).shape[0]
        if n > target:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1.01:
            break
    return hi


def anchorize(g: Gaussians3DGS, cfg: TranscodeConfig) -> dict:
    """Voxelize the source Gaussians and assign up to K of them to each anchor (see module doc)."""
    op = g.opacities.double().numpy()
    keep = np.nonzero(op >= cfg.min_opacity)[0]
    if keep.size == 0:
        raise InputError(f"{g.source}: no Gaussian has opacity >= {cfg.min_opacity}; nothing to transcode")
    pts = g.means.double().numpy()[keep]
    k = cfg.num_offsets
    if cfg.voxel_size is not None:
        if not cfg.voxel_size > 0:
            raise InputError(f"the voxel size must be positive, got {cfg.voxel_size}")
        voxel = float(cfg.voxel_size)
    else:
        target = cfg.anchors if cfg.anchors is not None else max(1, keep.size // 4)
        if target < 1:
            raise InputError(f"the anchor count must be positive, got {target}")
        voxel = voxel_size_for_count(pts, target)
    origin = np.zeros(3)  # the grid through the world origin: a written checkpoint's voxel size can be inferred
    coords_all = _occupied(pts, origin, voxel)
    coords, inv = np.unique(coords_all, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n = coords.shape[0]
    sc = g.scales.double().numpy()[keep]
    importance = op[keep] * np.sort(sc, axis=1)[:, 1:].prod(1)  # opacity x area of the two largest axes
    order = np.lexsort((-importance, inv))  # by voxel, then by decreasing importance
    inv_s = inv[order]
    start = np.searchsorted(inv_s, np.arange(n))
    rank = np.arange(order.size) - start[inv_s]
    take = rank < k
    slot_g = np.full((n, k), -1, np.int64)
    slot_g[inv_s[take], rank[take]] = keep[order[take]]
    return {"coords": coords, "origin": origin.astype(np.float32), "voxel": voxel, "slot_gaussian": slot_g,
            "kept": int(keep.size), "dropped": int((~take).sum()), "below_min_opacity": int(g.num_gaussians - keep.size)}


def _mlp(c_in: int, hidden: int, out: int, final: str, gen: torch.Generator) -> TorchMLP:
    l1, l2 = nn.Linear(c_in, hidden), nn.Linear(hidden, out)
    with torch.no_grad():  # PyTorch's default init, from our generator (reproducible)
        for lin in (l1, l2):
            bound = 1 / math.sqrt(lin.in_features)
            lin.weight.uniform_(-bound, bound, generator=gen)
            lin.bias.uniform_(-bound, bound, generator=gen)
    return TorchMLP([l1, l2], ["relu", final])


def initial_scene_tensors(g: Gaussians3DGS, a: dict, cfg: TranscodeConfig) -> SceneTensors:
    gen = torch.Generator().manual_seed(cfg.seed)
    n, k = a["slot_gaussian"].shape
    c = cfg.feature_dim
    slot = torch.as_tensor(a["slot_gaussian"])
    live = slot >= 0
    gi = slot.clamp_min(0)
    voxel = a["voxel"]
    pos32 = (torch.as_tensor(a["coords"], dtype=torch.float32) * np.float32(voxel)
             + torch.as_tensor(a["origin"], dtype=torch.float32))
    offsets = (g.means[gi].double() - pos32.double()[:, None, :]) / voxel
    offsets = torch.where(live[..., None], offsets, torch.zeros_like(offsets)).float()
    smax = torch.where(live, g.scales[gi].amax(-1), torch.zeros(n, k)).amax(1).clamp_min(voxel * 1e-4)
    scal = torch.cat([torch.full((n, 3), math.log(voxel)), torch.log(1.25 * smax)[:, None].repeat(1, 3)], 1)
    feats = 0.1 * torch.randn(n, c, generator=gen)
    mlps = {"opacity": _mlp(c + 4, c, k, "tanh", gen), "cov": _mlp(c + 4, c, 7 * k, "none", gen),
            "color": _mlp(c + 4, c, 3 * k, "sigmoid", gen)}
    p = lambda t: nn.Parameter(t.float().contiguous())  # noqa: E731
    return SceneTensors(pos32, p(feats), p(scal), p(offsets), mlps, live)


def distill(st: SceneTensors, g: Gaussians3DGS, a: dict, cfg: TranscodeConfig, cam_dist: float) -> list[float]:
    """Fit features and MLPs to the assigned source Gaussians' attributes (module doc, step 3)."""
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    slot = torch.as_tensor(a["slot_gaussian"])
    live = slot >= 0
    gi = slot.clamp_min(0)
    n, k = slot.shape
    t_op = g.opacities[gi].clamp(0, 0.999)
    base = torch.exp(st.scalings.detach()[:, 3:6])  # [n, 3]
    s_sorted = g.scales[gi]
    t_logsig = torch.log((s_sorted / base[:, None, :]).clamp(1e-6, 0.999))  # log sigmoid target
    t_quat = g.quats[gi]
    sh_t = g.sh[gi]  # [n, k, K, 3]
    means_t = g.means[gi]
    idx = torch.arange(n)
    params = [st.features] + [q for m in ("opacity", "cov", "color") for q in st.mlps[m].parameters()]
    opt = torch.optim.Adam(params, lr=0.01)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(cfg.distill_steps, 1), eta_min=1e-3)
    w = live.float()
    wsum = w.sum().clamp_min(1)
    losses = []
    bar = progress_bar(range(cfg.distill_steps), desc="transcode: distill", unit="step", disable=not cfg.progress,
               leave=False)
    for _ in bar:
        v = torch.randn(n, 3, generator=gen)
        v = v / torch.linalg.vector_norm(v, dim=1, keepdim=True)
        dist = torch.full((n, 1), cam_dist)
        op, cov, col = evaluate_anchors(st, idx, v, dist)
        l_op = ((op - t_op).abs() * w).sum() / wsum
        logsig = nn.functional.logsigmoid(cov[..., :3])
        l_sc = ((logsig - t_logsig).abs().mean(-1) * w).sum() / wsum
        q = nn.functional.normalize(cov[..., 3:7], dim=-1)
        l_rot = ((1 - (q * t_quat).sum(-1).abs()) * w).sum() / wsum
        cam = st.positions.detach()[:, None, :] - cam_dist * v[:, None, :]
        d = means_t - cam
        d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True).clamp_min(1e-12)
        t_col = sh_to_rgb(g.sh_degree, sh_t, d).clamp(0, 1)
        l_col = ((col - t_col).abs().mean(-1) * w).sum() / wsum
        loss = l_op + l_sc + l_rot + 2 * l_col
        _optimizer_step(opt, sched, loss, losses, bar)
    return losses


def _optimizer_step(opt, sched, loss: torch.Tensor, losses: list, bar) -> None:
    """One Adam step with its schedule; the loss is logged and shown on the progress bar."""
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    sched.step()
    losses.append(float(loss.detach()))
    bar.set_postfix(loss=f"{losses[-1]:.4f}")


def _to_scene(st: SceneTensors, a: dict) -> AnchorScene:
    return AnchorScene(
        coords=a["coords"].astype(np.int64), voxel_size=float(a["voxel"]), origin=a["origin"],
        features=st.features.detach().float().numpy().copy(), scalings=st.scalings.detach().float().numpy().copy(),
        offsets=st.offsets.detach().float().numpy().copy(),
        offset_mask=st.offset_mask.numpy().copy() if st.offset_mask is not None else None,
        mlps={r: st.mlps[r].to_render_mlp() for r in ("opacity", "cov", "color")}).validate()


@torch.no_grad()
def evaluate_views(scene, cams: list[Camera], targets: list[torch.Tensor]) -> float:
    """Mean PSNR of the anchor scene's renders against ``targets`` over ``cams``."""
    # the CPU reference renderer throughout the transcoder: results do not depend on the machine
    vals = [psnr(render_scene(scene, cam, backend="torch").image.clamp(0, 1).numpy(), t.numpy())
            for cam, t in zip(cams, targets)]
    return float(np.mean(vals))


def check_transcode_config(cfg: TranscodeConfig) -> None:
    if cfg.num_offsets < 1 or cfg.feature_dim < 1 or cfg.views < 1 or cfg.resolution < 8:
        raise InputError("transcode: need at least 1 offset, 1 feature, 1 view and 8x8 pixels")
    if cfg.iterations < 0 or cfg.distill_steps < 0 or cfg.test_views < 0:
        raise InputError("transcode: iteration, step and view counts cannot be negative")


@dataclass
class TranscodeViews:
    """The training and held-out cameras and the source rendered into them."""
    train: list[Camera]
    test: list[Camera]
    camera_distance: float
    train_targets: list[torch.Tensor]
    test_targets: list[torch.Tensor]


def render_source_views(g: Gaussians3DGS, cfg: TranscodeConfig, backend: str) -> TranscodeViews:
    center, radius = g.bounds()
    train = sphere_cameras(center, radius, cfg.views, resolution=cfg.resolution, fov_deg=cfg.fov_deg, prefix="train")
    test = sphere_cameras(center, radius, cfg.test_views, resolution=cfg.resolution, fov_deg=cfg.fov_deg,
                          offset=0.25, prefix="test") if cfg.test_views else []
    cam_dist = float(np.linalg.norm(train[0].center - center))
    with torch.no_grad():
        bar = progress_bar(train + test, desc="transcode: render source", unit="view", disable=not cfg.progress, leave=False)
        targets = [render_3dgs(g, cam, backend=backend).image.clamp(0, 1) for cam in bar]
    return TranscodeViews(train, test, cam_dist, targets[:len(train)], targets[len(train):])


def fit_to_source_renders(st: SceneTensors, views: TranscodeViews, cfg: TranscodeConfig, backend: str) -> list[float]:
    """Render fitting (module doc, 4) -> the loss of every step."""
    groups = [{"params": [st.features], "lr": cfg.lr_features}, {"params": [st.offsets], "lr": cfg.lr_offsets},
              {"params": [st.scalings], "lr": cfg.lr_scalings},
              {"params": [q for r in ("opacity", "cov", "color") for q in st.mlps[r].parameters()], "lr": cfg.lr_mlp}]
    opt = torch.optim.Adam(groups, eps=1e-15)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(cfg.iterations, 1), eta_min=0.0)
    rng = np.random.default_rng(cfg.seed)
    losses: list[float] = []
    bar = progress_bar(range(cfg.iterations), desc="transcode: fit", unit="it", disable=not cfg.progress, leave=False)
    for _ in bar:
        j = int(rng.integers(len(views.train)))
        img = render_scene(st, views.train[j], backend=backend).image
        target = views.train_targets[j]
        l1 = (img - target).abs().mean()
        loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1 - ssim_torch(img, target))
        _optimizer_step(opt, sched, loss, losses, bar)
    return losses


def held_out_psnr(scene, views: TranscodeViews) -> tuple[float, float]:
    """(PSNR on the held-out views (NaN: none), on the first 4 training views)."""
    held_out = evaluate_views(scene, views.test, views.test_targets) if views.test else float("nan")
    return held_out, evaluate_views(scene, views.train[:4], views.train_targets[:4])


def transcode_3dgs(source: str | Gaussians3DGS, cfg: TranscodeConfig | None = None, log=None) -> TranscodeResult:
    """A plain 3DGS scene (a PLY path or loaded Gaussians) -> an AnchorScene (module doc)."""
    from ..render.rasterizer import select_device

    cfg = cfg or TranscodeConfig()
    say = log or (lambda *a: None)
    backend = select_device(cfg.device)  # 'no CUDA device: ...' before any work
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    t0 = time.perf_counter()
    g = load_3dgs_ply(source) if not isinstance(source, Gaussians3DGS) else source
    check_transcode_config(cfg)
    views = render_source_views(g, cfg, backend)
    t_render = time.perf_counter() - t0
    a = anchorize(g, cfg)
    say(f"transcode: {g.num_gaussians:,} Gaussians (SH degree {g.sh_degree}) -> {len(a['coords']):,} anchors, "
        f"voxel {a['voxel']:.4g}, K={cfg.num_offsets}, {a['dropped']:,} Gaussians beyond K dropped, "
        f"{a['below_min_opacity']:,} below opacity {cfg.min_opacity}")
    st = initial_scene_tensors(g, a, cfg)
    t1 = time.perf_counter()
    distill_losses = distill(st, g, a, cfg, views.camera_distance)
    t_distill = time.perf_counter() - t1
    psnr_init, psnr_init_train = held_out_psnr(st, views)
    say(f"transcode: after distillation ({cfg.distill_steps} steps, {t_distill:.1f} s): held-out PSNR {psnr_init:.2f} dB")
    t2 = time.perf_counter()
    losses = fit_to_source_renders(st, views, cfg, backend)
    t_fit = time.perf_counter() - t2
    scene = _to_scene(st, a)
    psnr_final, psnr_final_train = held_out_psnr(scene, views)
    say(f"transcode: after render fitting ({cfg.iterations} iterations, {t_fit:.1f} s): "
        f"held-out PSNR {psnr_final:.2f} dB")
    stats = TranscodeStats(
        gaussians=g.num_gaussians, sh_degree=g.sh_degree, anchors=scene.num_anchors, voxel_size=scene.voxel_size,
        live_offsets=int(scene.offset_mask.sum()), dropped_gaussians=a["dropped"],
        below_min_opacity=a["below_min_opacity"], views=len(views.train), test_views=len(views.test),
        resolution=cfg.resolution, camera_distance=views.camera_distance, psnr_init=psnr_init, psnr_final=psnr_final,
        psnr_init_train=psnr_init_train, psnr_final_train=psnr_final_train,
        distill_loss=distill_losses[-1] if distill_losses else None, fit_loss=losses, time_render_source_s=t_render,
        time_distill_s=t_distill, time_fit_s=t_fit, time_total_s=time.perf_counter() - t0)
    return TranscodeResult(scene, stats)


def main(argv: list[str] | None = None) -> int:
    """``python -m lghcc.encoder.transcode SCENE.ply -o MODEL_DIR``: transcode and write the
    Scaffold-GS layout (and the statistics as JSON)."""
    import argparse
    import json
    import sys

    from ..common.errors import LghccError
    from ..formats.scaffold_io import write_scaffold

    d = TranscodeConfig()
    p = argparse.ArgumentParser(prog="python -m lghcc.encoder.transcode", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help="plain 3DGS PLY (INRIA layout)")
    p.add_argument("-o", "--output", help="Scaffold-GS model folder to write")
    p.add_argument("--json", help="write the statistics as JSON")
    for name in ("anchors", "voxel_size", "feature_dim", "num_offsets", "views", "test_views", "resolution",
                 "distill_steps", "iterations", "seed", "threads"):
        default = getattr(d, name)
        typ = float if name == "voxel_size" else int
        p.add_argument("--" + name.replace("_", "-"), type=typ, default=default, help=f"default {default}")
    args = p.parse_args(argv)
    cfg = TranscodeConfig(**{k: getattr(args, k) for k in ("anchors", "voxel_size", "feature_dim", "num_offsets",
                                                            "views", "test_views", "resolution", "distill_steps",
                                                            "iterations", "seed", "threads")},
                          progress=True)
    try:
        res = transcode_3dgs(args.input, cfg, log=lambda *a: print(*a, flush=True))
        if args.output:
            write_scaffold(res.scene, args.output)
    except LghccError as e:
        print(f"transcode: error: {e}", file=sys.stderr)
        return 1
    st = {k: v for k, v in res.stats.to_json().items() if k != "fit_loss"}
    print(json.dumps(st, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({**st, "config": {k: getattr(cfg, k) for k in vars(cfg)}, "fit_loss": res.stats.fit_loss},
                      f, indent=1)
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
