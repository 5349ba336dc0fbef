"""Plain 3DGS baseline trainer on the CPU with lghcc's own renderer (informative).

A small plain-3DGS (Kerbl et al. 2023) trainer, to compare with lghcc-train's Scaffold-GS
scenes under the same renderer (render/rasterizer.py), data loading, initialization, loss and
test metrics, all imported from encoder/training/ (lghcc-train), render/datasets.py and render/metrics.py.

* Gaussians: position, log-scale (3), quaternion (w, x, y, z), opacity logit, SH degree 0
  colour (DC coefficient; colour = max(0, C0 dc + 0.5) as 3DGS).
* Initialization: ``init_points`` of lghcc-train (NeRF-synthetic: random points uniform in the
  region every training camera sees), log scale = log(mean distance to the 3 nearest points),
  identity rotation, opacity 0.1, colour 0.5 (DC 0).
* Loss: 0.8 L1 + 0.2 (1 - SSIM) (``ssim_torch``). Adam (eps 1e-15) with 3DGS's learning rates:
  position 1.6e-4 -> 1.6e-6 (x camera extent, exponential decay over ``--iterations``), DC 2.5e-3,
  opacity 0.05, scaling 5e-3, rotation 1e-3.
* Densification (3DGS's rule, schedule compressed for short runs): every
  ``--densify-interval`` iterations from ``--densify-from`` to ``--densify-until`` (default
  half the run), Gaussians whose mean screen-space position gradient (NDC units, over the views
  that drew them) exceeds ``--densify-grad-threshold`` are cloned (largest scale <= 1% of the
  extent) or split in two (sampled from the Gaussian, scales / 1.6); then Gaussians with
  opacity < ``--min-opacity`` or a world-space scale > 10% of the extent (after the first
  opacity reset) are pruned. Opacities are reset to <= 0.01 every ``--opacity-reset-interval``
  iterations (0 = never). Growth stops at ``--max-gaussians``.
  Difference: our rasterizer does not expose the gradient of the 2D means; as in lghcc-train,
  it is taken from the gradient of the 3D means (camera x/y components x z / f x W / 2).
* Output: ``<out>/point_cloud.ply`` (INRIA layout, ``write_3dgs_ply``, atomic),
  ``<out>/metrics.json`` (test PSNR/SSIM on all test views, time, Gaussian count, atomic).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see encoder/training/__init__.py

import argparse  # noqa: E402
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ...common.errors import InputError, LghccError
from ...app.fileio import atomic_write_bytes
from ...render.datasets import load_dataset, parse_background
from .config import TrainConfig
from .data import camera_extent, init_points, knn_mean_dist
from .parameters import expon_lr
from ...render.gaussians3dgs import write_3dgs_ply
from ...render.metrics import psnr, ssim, ssim_torch
from ...render.rasterizer import rasterize
from ...render.sh import sh_to_rgb

PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc")


@dataclass
class Config3DGS:
    data: str = ""
    iterations: int = 3000
    init_points: int = 10000
    background: str = "white"
    downscale: int = 1
    seed: int = 0
    threads: int = 2
    time_limit_s: float | None = None
    lambda_dssim: float = 0.2
    position_lr_init: float = 0.00016
    position_lr_final: float = 0.0000016
    feature_lr: float = 0.0025
    opacity_lr: float = 0.05
    scaling_lr: float = 0.005
    rotation_lr: float = 0.001
    densify_from: int = 500
    densify_until: int | None = None  # None: iterations // 2
    densify_interval: int = 100
    densify_grad_threshold: float = 0.0002
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    opacity_reset_interval: int = 3000
    max_gaussians: int = 100000
    log_interval: int = 100


class Trainer3DGS:
    def __init__(self, cfg: Config3DGS, ds):
        self.cfg, self.ds = cfg, ds
        self.rng = np.random.default_rng(cfg.seed)
        torch.manual_seed(cfg.seed)
        self.bg = torch.as_tensor(parse_background(cfg.background), dtype=torch.float32)
        self.extent = camera_extent(ds.train)
        self.train_images = [torch.as_tensor(np.asarray(c.image, np.float32)) for c in ds.train]
        pts = init_points(ds, TrainConfig(data=cfg.data, init="auto", init_points=cfg.init_points), self.rng)
        n = len(pts)
        d = knn_mean_dist(pts)
        q = np.zeros((n, 4)); q[:, 0] = 1
        init = {"means": pts, "log_scales": np.repeat(np.log(d)[:, None], 3, 1), "quats": q,
                "opacity_logits": np.full(n, math.log(0.1 / 0.9)), "sh_dc": np.zeros((n, 1, 3))}
        self.params = {k: torch.nn.Parameter(torch.as_tensor(v, dtype=torch.float32)) for k, v in init.items()}
        lrs = {"means": cfg.position_lr_init * self.extent, "log_scales": cfg.scaling_lr, "quats": cfg.rotation_lr,
               "opacity_logits": cfg.opacity_lr, "sh_dc": cfg.feature_lr}
        self.opt = torch.optim.Adam([{"params": [self.params[k]], "lr": lrs[k], "name": k} for k in PARAMS],
                                    lr=0.0, eps=1e-15)
        self.iteration = 0
        self.order: list[int] = []
        self._reset_stats()

    @property
    def num_gaussians(self) -> int:
        return int(self.params["means"].shape[0])

    def _reset_stats(self) -> None:
        n = self.num_gaussians
        self.grad_accum = torch.zeros(n, dtype=torch.float64)
        self.denom = torch.zeros(n, dtype=torch.float64)

    def activated(self):
        p = self.params
        return (p["means"], torch.nn.functional.normalize(p["quats"], dim=1), torch.exp(p["log_scales"]),
                torch.sigmoid(p["opacity_logits"]))

    def render(self, cam) -> torch.Tensor:
        means, quats, scales, op = self.activated()
        c = torch.as_tensor(np.asarray(cam.center, np.float32))
        dirs = torch.nn.functional.normalize(means.detach() - c, dim=1)
        cols = sh_to_rgb(0, self.params["sh_dc"], dirs)
        return rasterize(means, quats, scales, op, cols, cam, background=self.bg).image

    def _next_view(self) -> int:
        if not self.order:
            self.order = self.rng.permutation(len(self.ds.train)).tolist()
        return self.order.pop()

    def step(self) -> float:
        cfg = self.cfg
        it = self.iteration + 1
        for g in self.opt.param_groups:
            if g["name"] == "means":
                g["lr"] = expon_lr(it, cfg.position_lr_init * self.extent, cfg.position_lr_final * self.extent,
                                   cfg.iterations)
        vi = self._next_view()
        cam, gt = self.ds.train[vi], self.train_images[vi]
        img = self.render(cam)
        loss = (1 - cfg.lambda_dssim) * (img - gt).abs().mean() + cfg.lambda_dssim * (1 - ssim_torch(img, gt))
        loss.backward()
        until = cfg.densify_until if cfg.densify_until is not None else cfg.iterations // 2
        with torch.no_grad():
            if it <= until:
                self._accumulate(cam)
            self.opt.step()
            self.opt.zero_grad(set_to_none=True)
            self.iteration = it
            if cfg.densify_from < it <= until and it % cfg.densify_interval == 0:
                self.densify_and_prune(prune_big=cfg.opacity_reset_interval > 0 and it > cfg.opacity_reset_interval)
            if cfg.opacity_reset_interval and it % cfg.opacity_reset_interval == 0 and it <= until:
                self._reset_opacity()
        return float(loss.detach())

    def _accumulate(self, cam) -> None:
        g = self.params["means"].grad
        if g is None:
            return
        r = torch.as_tensor(cam.rotation, dtype=torch.float64)
        t = torch.as_tensor(cam.translation, dtype=torch.float64)
        gc = g.double() @ r.T
        z = (self.params["means"].detach().double() @ r.T + t)[:, 2].clamp_min(cam.near)
        gx = gc[:, 0] * z / cam.fx * (cam.width / 2)
        gy = gc[:, 1] * z / cam.fy * (cam.height / 2)
        gn = torch.sqrt(gx * gx + gy * gy)
        drawn = torch.isfinite(gn) & (gn > 0)
        self.grad_accum[drawn] += gn[drawn]
        self.denom[drawn] += 1

    # --- densification ------------------------------------------------------------------
    def _replace(self, new: dict, keep: torch.Tensor | None) -> None:
        """Set every parameter to ``new[name]``: the first rows are the old rows ``keep`` (their
        Adam state carried over), the rest are new (zero Adam state)."""
        for g in self.opt.param_groups:
            name = g["name"]
            old = g["params"][0]
            p = torch.nn.Parameter(new[name].contiguous())
            st = self.opt.state.pop(old, None)
            if st:
                n_old = int(keep.sum()) if keep is not None else old.shape[0]
                for key in ("exp_avg", "exp_avg_sq"):
                    prev = st[key][keep] if keep is not None else st[key]
                    pad = torch.zeros((p.shape[0] - n_old,) + tuple(p.shape[1:]), dtype=prev.dtype)
                    st[key] = torch.cat([prev, pad])
                self.opt.state[p] = st
            g["params"][0] = p
            self.params[name] = p

    @torch.no_grad()
    def densify_and_prune(self, prune_big: bool = False) -> None:
        cfg = self.cfg
        p = {k: v.detach() for k, v in self.params.items()}
        grads = self.grad_accum / self.denom.clamp_min(1)
        big = grads >= cfg.densify_grad_threshold
        room = cfg.max_gaussians - self.num_gaussians
        maxs = torch.exp(p["log_scales"]).max(1).values
        small = maxs <= cfg.percent_dense * self.extent
        clone = big & small
        split = big & ~small
        if room <= 0:
            clone[:] = False
            split[:] = False
        adds = []
        if clone.any():
            adds.append({k: v[clone] for k, v in p.items()})
        if split.any():
            s = torch.exp(p["log_scales"][split])
            rot = _quat_to_rotmat(torch.nn.functional.normalize(p["quats"][split], dim=1))
            for _ in range(2):
                off = torch.randn(s.shape, dtype=s.dtype) * s
                a = {k: v[split] for k, v in p.items()}
                a["means"] = a["means"] + (rot @ off[:, :, None])[:, :, 0]
                a["log_scales"] = torch.log(s / 1.6)
                adds.append(a)
        keep = ~split
        new = {k: torch.cat([v[keep]] + [a[k] for a in adds]) for k, v in p.items()}
        self._replace(new, keep)
        # prune
        op = torch.sigmoid(self.params["opacity_logits"].detach())
        drop = op < cfg.min_opacity
        if prune_big:
            drop |= torch.exp(self.params["log_scales"].detach()).max(1).values > 0.1 * self.extent
        if drop.all():
            drop[:] = False
        if drop.any():
            keep2 = ~drop
            self._replace({k: v.detach()[keep2] for k, v in self.params.items()}, keep2)
        self._reset_stats()

    @torch.no_grad()
    def _reset_opacity(self) -> None:
        lo = self.params["opacity_logits"].detach()
        new = dict((k, v.detach()) for k, v in self.params.items())
        new["opacity_logits"] = torch.minimum(lo, torch.full_like(lo, math.log(0.01 / 0.99)))
        self._replace(new, None)
        for g in self.opt.param_groups:  # 3DGS resets the optimizer state of the opacities
            if g["name"] == "opacity_logits":
                st = self.opt.state.get(g["params"][0])
                if st:
                    st["exp_avg"].zero_()
                    st["exp_avg_sq"].zero_()

    # --- evaluation and output ------------------------------------------------------------
    @torch.no_grad()
    def evaluate(self, cams=None) -> dict:
        cams = self.ds.test if cams is None else cams
        ps, ss = [], []
        for cam in cams:
            img = self.render(cam).clamp(0, 1).double().numpy()
            ps.append(psnr(img, cam.image))
            ss.append(ssim(img, cam.image))
        return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "views": len(ps)}

    def write_ply(self, path: str | os.PathLike) -> None:
        p = {k: v.detach().numpy() for k, v in self.params.items()}
        q = p["quats"] / np.maximum(np.linalg.norm(p["quats"], axis=1, keepdims=True), 1e-12)
        # atomic: write_3dgs_ply -> common.ply.write_ply -> common.fileio.atomic_output
        write_3dgs_ply(path, p["means"], p["sh_dc"], p["opacity_logits"], p["log_scales"], q)


def _quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    from ...render.rasterizer import quat_to_rotmat

    return quat_to_rotmat(q)


@dataclass
class Result3DGS:
    iteration: int
    train_s: float
    gaussians: int
    metrics: dict = field(default_factory=dict)


def train_3dgs(cfg: Config3DGS, out: str | os.PathLike | None = None, log=print) -> tuple[Trainer3DGS, Result3DGS]:
    torch.set_num_threads(cfg.threads)
    if cfg.iterations < 1:
        raise InputError(f"iterations must be a positive integer, got {cfg.iterations}")
    ds = load_dataset(cfg.data, cfg.background, cfg.downscale)
    tr = Trainer3DGS(cfg, ds)
    log(f"{len(ds.train)} training / {len(ds.test)} test views, {tr.num_gaussians:,} initial Gaussians, "
        f"extent {tr.extent:.3f}")
    t0 = time.perf_counter()
    ema = None
    while tr.iteration < cfg.iterations:
        lv = tr.step()
        ema = lv if ema is None else 0.9 * ema + 0.1 * lv
        el = time.perf_counter() - t0
        if tr.iteration % cfg.log_interval == 0:
            log(f"it {tr.iteration}: loss {ema:.4f}, {tr.num_gaussians:,} Gaussians, {el:.0f} s")
        if cfg.time_limit_s is not None and el >= cfg.time_limit_s:
            log(f"time limit reached at iteration {tr.iteration}")
            break
    train_s = time.perf_counter() - t0
    res = Result3DGS(tr.iteration, train_s, tr.num_gaussians)
    t1 = time.perf_counter()
    res.metrics = tr.evaluate()
    res.metrics["eval_s"] = round(time.perf_counter() - t1, 1)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        tr.write_ply(out / "point_cloud.ply")
        summary = {"data": cfg.data, "iterations": res.iteration, "train_s": round(train_s, 1),
                   "gaussians": res.gaussians, **res.metrics, "config": cfg.__dict__}
        atomic_write_bytes(out / "metrics.json", json.dumps(summary, indent=2).encode())
    return tr, res


def setup_args() -> argparse.ArgumentParser:
    d = Config3DGS()
    p = argparse.ArgumentParser(prog="python -m lghcc.encoder.training.train_3dgs",
                                description="Plain 3DGS baseline trained on the CPU with lghcc's renderer.")
    p.add_argument("data", help="folder with the posed images (as lghcc-train)")
    p.add_argument("-o", "--output", required=True, help="output folder (point_cloud.ply, metrics.json)")
    p.add_argument("--iterations", type=int, default=d.iterations)
    p.add_argument("--threads", type=int, default=d.threads)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--time-limit", type=float, metavar="MIN", help="stop training after this many minutes")
    p.add_argument("--init-points", type=int, default=d.init_points)
    p.add_argument("--background", default=d.background)
    p.add_argument("--downscale", type=int, default=d.downscale)
    p.add_argument("--densify-from", type=int, default=d.densify_from)
    p.add_argument("--densify-until", type=int, help="default: half the iterations")
    p.add_argument("--densify-interval", type=int, default=d.densify_interval)
    p.add_argument("--densify-grad-threshold", type=float, default=d.densify_grad_threshold)
    p.add_argument("--opacity-reset-interval", type=int, default=d.opacity_reset_interval, help="0: never")
    p.add_argument("--max-gaussians", type=int, default=d.max_gaussians)
    return p


def main(argv: list[str] | None = None) -> int:
    a = setup_args().parse_args(argv)
    cfg = Config3DGS(data=str(Path(a.data).absolute()), iterations=a.iterations, threads=a.threads, seed=a.seed,
                     time_limit_s=None if a.time_limit is None else 60.0 * a.time_limit,
                     init_points=a.init_points, background=a.background, downscale=a.downscale,
                     densify_from=a.densify_from, densify_until=a.densify_until,
                     densify_interval=a.densify_interval, densify_grad_threshold=a.densify_grad_threshold,
                     opacity_reset_interval=a.opacity_reset_interval, max_gaussians=a.max_gaussians)
    try:
        _, res = train_3dgs(cfg, a.output)
    except LghccError as e:
        print(f"train_3dgs: error: {e}", file=sys.stderr)
        return 1
    m = res.metrics
    print(f"iteration {res.iteration}, {res.train_s:.0f} s training, {res.gaussians:,} Gaussians: test PSNR "
          f"{m['psnr']:.3f} dB, SSIM {m['ssim']:.4f} ({m['views']} views) -> {a.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
