"""Plain 3DGS scenes (the INRIA PLY layout): read, write, render (informative).

The PLY layout is read and written by lghcc.formats.ply3dgs (into a GaussianScene); this
module holds the activated torch tensors the renderer uses.

``render_3dgs`` evaluates the SH colour for the direction from the camera centre to each
mean (render/sh.py) and rasterizes with render/rasterizer.py.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from ..common.scene import GaussianScene
from ..formats.ply3dgs import is_3dgs_ply, read_3dgs_ply  # noqa: F401  (is_3dgs_ply: re-exported)
from ..formats.ply3dgs import write_3dgs_ply as write_ply_scene
from .camera import Camera
from .rasterizer import RenderResult, rasterize
from .sh import sh_to_rgb


@dataclass
class Gaussians3DGS:
    """Activated parameters as torch tensors: means [M, 3], quats [M, 4] unit (w, x, y, z),
    scales [M, 3] (exp of the stored log scales), opacities [M] (sigmoid of the stored
    logits), sh [M, (d + 1)^2, 3] (coefficient, channel)."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor
    sh_degree: int
    source: str = ""

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    def colors(self, camera_center) -> torch.Tensor:
        """Colours [M, 3] seen from a camera centre (world coordinates)."""
        c = torch.as_tensor(np.asarray(camera_center, np.float64), dtype=self.means.dtype)
        d = self.means - c
        d = d / torch.linalg.vector_norm(d, dim=1, keepdim=True).clamp_min(1e-12)
        return sh_to_rgb(self.sh_degree, self.sh, d)

    def bounds(self, quantile: float = 0.01) -> tuple[np.ndarray, float]:
        """(centre, radius) of the Gaussians with opacity >= 0.05, robust to floaters: the
        box between the ``quantile`` and 1 - ``quantile`` quantiles of the means."""
        m = self.means.detach().double().numpy()
        o = self.opacities.detach().numpy()
        if (o >= 0.05).sum() >= 10:
            m = m[o >= 0.05]
        lo, hi = np.quantile(m, quantile, axis=0), np.quantile(m, 1 - quantile, axis=0)
        return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo) / 2), 1e-6)


def gaussians_from_scene(scene: GaussianScene, dtype: torch.dtype = torch.float32, source: str = "") -> Gaussians3DGS:
    """The activated tensors of a GaussianScene: unit quaternions (a zero one becomes the
    identity), exp of the log scales, sigmoid of the opacity logits."""
    rot = scene.rotations.astype(np.float64)
    norm = np.linalg.norm(rot, axis=1, keepdims=True)
    rot = np.where(norm > 0, rot / np.maximum(norm, 1e-30), np.array([1.0, 0, 0, 0]))
    t = lambda a: torch.as_tensor(np.asarray(a, np.float64), dtype=dtype)  # noqa: E731
    log_s = np.clip(scene.log_scales.astype(np.float64), -80, 80)
    opac = scene.opacity.astype(np.float64)
    return Gaussians3DGS(t(scene.means), t(rot), t(np.exp(log_s)), t(1 / (1 + np.exp(-opac))),
                         t(scene.sh), scene.sh_degree, source)


def load_3dgs_ply(path: str | os.PathLike, dtype: torch.dtype = torch.float32) -> Gaussians3DGS:
    """Read an INRIA 3DGS PLY (lghcc.formats.ply3dgs) as activated tensors. Raises InputError
    naming the file and the first missing or malformed field."""
    return gaussians_from_scene(read_3dgs_ply(path), dtype, str(path))


def write_3dgs_ply(path: str | os.PathLike, means: np.ndarray, sh: np.ndarray, opacity_logits: np.ndarray,
                   log_scales: np.ndarray, quats: np.ndarray) -> None:
    """Write an INRIA 3DGS PLY from arrays: means [M, 3], sh [M, K, 3] (K = (d + 1)^2), opacity
    logits [M], log scales [M, 3], quats [M, 4] (w, x, y, z); lghcc.formats.ply3dgs lays it out."""
    n = means.shape[0]
    k = sh.shape[1]
    if sh.shape != (n, k, 3) or opacity_logits.shape != (n,) or log_scales.shape != (n, 3) or quats.shape != (n, 4):
        raise ValueError("write_3dgs_ply: inconsistent shapes")
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    write_ply_scene(path, GaussianScene(f(means), f(sh), f(opacity_logits), f(log_scales), f(quats)))


def render_3dgs(g: Gaussians3DGS, camera: Camera, *, background=None, backend: str = "auto", **kw) -> RenderResult:
    """Render a plain 3DGS scene into ``camera`` (SH colours for this camera centre);
    ``backend`` as ``render_scene`` (auto: gsplat when CUDA and gsplat are usable)."""
    from .rasterizer import rasterize_gsplat, select_backend

    cols = g.colors(camera.center)
    fn = rasterize if select_backend(backend) == "torch" else rasterize_gsplat
    return fn(g.means, g.quats, g.scales, g.opacities, cols, camera, background=background, **kw)
