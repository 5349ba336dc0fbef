"""The trainable scene of lghcc-train: anchors (fixed positions on the voxel grid; features,
scalings, offsets), the render MLPs, Adam and its learning-rate schedules (Scaffold-GS's rates,
3DGS's exponential decay), and the statistics kept per anchor and per neural Gaussian."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ...common.errors import InputError
from ...common.scene import AnchorScene
from .config import TrainConfig
from .data import default_voxel_size, init_points, knn_mean_dist


def make_mlp(c: int, out: int, final: str):
    """Scaffold-GS's render MLP: Linear(C+4, C), ReLU, Linear(C, out), then ``final``."""
    from ...render.neural_gaussians import TorchMLP

    return TorchMLP([nn.Linear(c + 4, c), nn.Linear(c, out)], ["relu", final])


def expon_lr(step: int, init: float, final: float, max_steps: int) -> float:
    """3DGS's get_expon_lr_func without delay: log-linear from init to final."""
    if init == final:
        return init
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp(math.log(max(init, 1e-300)) * (1 - t) + math.log(max(final, 1e-300)) * t)


class AnchorParameters:
    """The anchors, MLPs, optimizer and statistics of a ``Trainer`` (training/loop.py), which
    sets ``cfg``, ``ds`` and ``spatial_lr_scale``; ``fresh`` starts them, ``load_state_dict``
    (training/checkpoints.py) restores them. Growing and pruning change the anchor set through
    ``append_anchors`` and ``keep_anchors``, which keep Adam's state in step."""

    PARAMS = ("features", "scalings", "offsets")
    cfg: TrainConfig

    def fresh(self) -> None:
        """A new run: seeded RNGs, the initial anchors (one per voxel of the initial points), new
        MLPs, zero statistics and Adam at iteration 0."""
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
        dist = knn_mean_dist(coords * self.voxel_size)
        self.mlps = {"opacity": make_mlp(c, k, "tanh"), "cov": make_mlp(c, 7 * k, "none"),
                     "color": make_mlp(c, 3 * k, "sigmoid")}
        self.params = {
            "features": nn.Parameter(torch.zeros(n, c)),
            "scalings": nn.Parameter(torch.from_numpy(np.log(dist)).float()[:, None].repeat(1, 6)),
            "offsets": nn.Parameter(torch.zeros(n, k, 3)),
        }
        self._new_stats(n)
        self.iteration = 0
        self.order: list[int] = []
        self.build_optimizer()

    def _new_stats(self, n: int) -> None:
        k = self.cfg.num_offsets
        self.opacity_accum = torch.zeros(n, dtype=torch.float64)  # window (pruning)
        self.anchor_demon = torch.zeros(n, dtype=torch.float64)
        self.offset_grad_accum = torch.zeros(n * k, dtype=torch.float64)
        self.offset_denom = torch.zeros(n * k, dtype=torch.float64)
        self.life_opacity = torch.zeros(n, dtype=torch.float64)  # since creation (exported)
        self.life_views = torch.zeros(n, dtype=torch.float64)

    def build_optimizer(self) -> None:
        groups = [{"params": [self.params[name]], "lr": 0.0, "name": name} for name in self.PARAMS]
        groups += [{"params": list(m.parameters()), "lr": 0.0, "name": f"mlp_{r}"} for r, m in self.mlps.items()]
        self.opt = torch.optim.Adam(groups, lr=0.0, eps=1e-15)
        self.set_lr(self.iteration)

    def set_lr(self, step: int) -> None:
        cfg = self.cfg
        n = cfg.lr_schedule_iterations if cfg.lr_schedule_iterations is not None else cfg.iterations
        lrs = {
            "features": cfg.feature_lr, "scalings": cfg.scaling_lr,
            "offsets": expon_lr(step, cfg.offset_lr_init * self.spatial_lr_scale,
                                 cfg.offset_lr_final * self.spatial_lr_scale, n),
            "mlp_opacity": expon_lr(step, cfg.mlp_opacity_lr_init, cfg.mlp_opacity_lr_final, n),
            "mlp_cov": expon_lr(step, cfg.mlp_cov_lr_init, cfg.mlp_cov_lr_final, n),
            "mlp_color": expon_lr(step, cfg.mlp_color_lr_init, cfg.mlp_color_lr_final, n),
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
        from ...render.neural_gaussians import SceneTensors

        f, sc, off = self.params["features"], self.params["scalings"], self.params["offsets"]
        if self.rate_model is not None:  # render what the decoder will output (straight-through rounding)
            from ..anchors.rate_model import quantize_ste

            step = torch.tensor(self.cfg.rate_step, dtype=torch.float32)
            f, sc, off = quantize_ste(f, step), quantize_ste(sc, step), quantize_ste(off, step)
        return SceneTensors(self.positions(), f, sc, off, self.mlps)

    def attribute_values(self) -> torch.Tensor:
        """[N, M] attributes in the codec's channel layout (features, scalings, offsets k-major)."""
        n = self.num_anchors
        return torch.cat([self.params["features"], self.params["scalings"], self.params["offsets"].reshape(n, -1)], 1)

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

    def append_anchors(self, coords, feat, scal, off) -> None:
        m = coords.shape[0]
        self.coords = torch.cat([self.coords, coords])
        for name, new in (("features", feat), ("scalings", scal), ("offsets", off)):
            self._replace(name, torch.cat([self.params[name].detach(), new.float()]), None, m)

    def keep_anchors(self, keep: torch.Tensor) -> None:
        k = self.cfg.num_offsets
        self.coords = self.coords[keep]
        for name in self.PARAMS:
            self._replace(name, self.params[name].detach()[keep], keep, 0)
        keep_o = keep[:, None].expand(-1, k).reshape(-1)
        self.offset_denom, self.offset_grad_accum = self.offset_denom[keep_o], self.offset_grad_accum[keep_o]
        for a in ("opacity_accum", "anchor_demon", "life_opacity", "life_views"):
            setattr(self, a, getattr(self, a)[keep])

    def to_scene(self) -> AnchorScene:
        mlps = {r: m.to_render_mlp() for r, m in self.mlps.items()}
        acc = (self.life_opacity / self.life_views.clamp_min(1)).float().numpy()
        return AnchorScene(coords=self.coords.numpy().copy(), voxel_size=self.voxel_size, origin=self.origin.copy(),
                           features=self.params["features"].detach().numpy().copy(),
                           scalings=self.params["scalings"].detach().numpy().copy(),
                           offsets=self.params["offsets"].detach().numpy().copy(), mlps=mlps,
                           extra={"opacity_accum": acc})
