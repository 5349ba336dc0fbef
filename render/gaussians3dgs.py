"""Plain 3DGS scenes (the INRIA PLY layout): read, write, render (informative).

INRIA 3DGS ``point_cloud.ply`` per Gaussian: ``x, y, z`` (``nx, ny, nz``, unused),
``f_dc_0..2`` (SH coefficient 0 per channel), ``f_rest_0..3(K-1)-1`` (the other
coefficients, channel-major: f_rest_{c (K-1) + i - 1} is coefficient i of channel c,
K = (d + 1)^2 for SH degree d; none for degree 0), ``opacity`` (logit),
``scale_0..2`` (log), ``rot_0..3`` (quaternion w, x, y, z, any norm).

``render_3dgs`` evaluates the SH colour for the direction from the camera centre to each
mean (render/sh.py) and rasterizes with render/rasterizer.py.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lghcc.common.errors import InputError
from lghcc.common.ply import read_ply, read_ply_header_lines, write_ply
from lghcc.render.camera import Camera
from lghcc.render.rasterizer import RenderResult, rasterize
from lghcc.render.sh import MAX_SH_DEGREE, num_sh_coeffs, sh_to_rgb

REQUIRED_FIELDS = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                   "rot_0", "rot_1", "rot_2", "rot_3")


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


def read_ply_header(path: str | os.PathLike) -> list[str]:
    """Property names of the first element of a PLY file, from its header only."""
    names, seen_element = [], False
    for line in read_ply_header_lines(path):
        parts = line.split()
        if parts[:1] == ["element"]:
            if seen_element:
                break
            seen_element = True
        elif parts[:1] == ["property"] and len(parts) >= 3:
            names.append(parts[-1])
    return names


def is_3dgs_ply(path: str | os.PathLike) -> bool:
    """True for a plain 3DGS PLY: a .ply file with f_dc_0 and no f_anchor_feat_0."""
    p = Path(path)
    if not p.is_file():
        return False
    try:
        names = read_ply_header(p)
    except InputError:
        return False
    return "f_dc_0" in names and "f_anchor_feat_0" not in names


def load_3dgs_ply(path: str | os.PathLike, dtype: torch.dtype = torch.float32) -> Gaussians3DGS:
    """Read an INRIA 3DGS PLY. Raises InputError naming the file and the first missing
    or malformed field."""
    p = Path(path)
    cols = read_ply(p)
    if "f_anchor_feat_0" in cols:
        raise InputError(f"{p}: this is a Scaffold-GS anchor file (f_anchor_feat_*), not a plain 3DGS PLY")
    for f in REQUIRED_FIELDS:
        if f not in cols:
            raise InputError(f"{p}: field '{f}' is missing: not a 3DGS PLY (needs {', '.join(REQUIRED_FIELDS)}, "
                             "f_rest_* optional)")
    rest = sorted((k for k in cols if k.startswith("f_rest_")), key=lambda k: int(k[7:]) if k[7:].isdigit() else -1)
    for i, k in enumerate(rest):
        if k != f"f_rest_{i}":
            raise InputError(f"{p}: field 'f_rest_{i}' is missing (f_rest_* must be numbered 0..{len(rest) - 1})")
    nrest = len(rest)
    if nrest % 3 or nrest // 3 + 1 not in [num_sh_coeffs(d) for d in range(MAX_SH_DEGREE + 1)]:
        raise InputError(f"{p}: {nrest} f_rest_* fields: expected 3((d+1)^2 - 1) = 0, 9, 24 or 45 for SH degree "
                         f"d = 0..{MAX_SH_DEGREE}")
    k = nrest // 3 + 1
    degree = int(round(np.sqrt(k))) - 1
    n = len(cols["x"])
    if n == 0:
        raise InputError(f"{p}: the file holds no Gaussians")

    def stack(names):
        return np.stack([np.asarray(cols[c], np.float64) for c in names], axis=1)

    means = stack(["x", "y", "z"])
    dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    sh = np.zeros((n, k, 3))
    sh[:, 0] = dc
    if nrest:
        sh[:, 1:] = stack(rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    opac = np.asarray(cols["opacity"], np.float64)
    log_s = stack(["scale_0", "scale_1", "scale_2"])
    rot = stack(["rot_0", "rot_1", "rot_2", "rot_3"])
    for name, a in (("x/y/z", means), ("f_dc/f_rest", sh), ("opacity", opac), ("scale", log_s), ("rot", rot)):
        if not np.isfinite(a).all():
            raise InputError(f"{p}: field '{name}' contains NaN or Inf "
                             f"(in {int((~np.isfinite(a.reshape(n, -1))).any(1).sum())} Gaussians)")
    norm = np.linalg.norm(rot, axis=1, keepdims=True)
    rot = np.where(norm > 0, rot / np.maximum(norm, 1e-30), np.array([1.0, 0, 0, 0]))
    t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
    return Gaussians3DGS(t(means), t(rot), t(np.exp(np.clip(log_s, -80, 80))), t(1 / (1 + np.exp(-opac))),
                         t(sh), degree, str(p))


def write_3dgs_ply(path: str | os.PathLike, means: np.ndarray, sh: np.ndarray, opacity_logits: np.ndarray,
                   log_scales: np.ndarray, quats: np.ndarray) -> None:
    """Write an INRIA 3DGS PLY (binary little-endian float32, normals zero, the field order
    of 3DGS's ``save_ply``): means [M, 3], sh [M, K, 3] (K = (d + 1)^2), opacity logits [M],
    log scales [M, 3], quats [M, 4] (w, x, y, z)."""
    n = means.shape[0]
    k = sh.shape[1]
    if sh.shape != (n, k, 3) or opacity_logits.shape != (n,) or log_scales.shape != (n, 3) or quats.shape != (n, 4):
        raise ValueError("write_3dgs_ply: inconsistent shapes")
    z = np.zeros(n, np.float32)
    cols = {"x": means[:, 0], "y": means[:, 1], "z": means[:, 2], "nx": z, "ny": z, "nz": z}
    cols.update({f"f_dc_{c}": sh[:, 0, c] for c in range(3)})
    rest = np.asarray(sh[:, 1:, :]).transpose(0, 2, 1).reshape(n, 3 * (k - 1))
    cols.update({f"f_rest_{i}": rest[:, i] for i in range(rest.shape[1])})
    cols["opacity"] = opacity_logits
    cols.update({f"scale_{i}": log_scales[:, i] for i in range(3)})
    cols.update({f"rot_{i}": quats[:, i] for i in range(4)})
    write_ply(path, {k_: np.asarray(v, np.float32) for k_, v in cols.items()})


def render_3dgs(g: Gaussians3DGS, camera: Camera, *, background=None, backend: str = "auto", **kw) -> RenderResult:
    """Render a plain 3DGS scene into ``camera`` (SH colours for this camera centre);
    ``backend`` as ``render_scene`` (auto: gsplat when CUDA and gsplat are usable)."""
    from lghcc.render.rasterizer import rasterize_gsplat, select_backend

    cols = g.colors(camera.center)
    fn = rasterize if select_backend(backend) == "torch" else rasterize_gsplat
    return fn(g.means, g.quats, g.scales, g.opacities, cols, camera, background=background, **kw)
