"""Anchor scene -> plain 3DGS PLY (INRIA layout) that standard viewers open (informative).

Neural Gaussians depend on the view; a 3DGS PLY does not (except colour through SH).
Per anchor, the MLPs are evaluated for ``num_directions`` view directions v_j spread on
the sphere (Fibonacci points), from cameras at distance ``distance`` (default: 2.5 x the
radius of the anchors' bounding sphere, i.e. half the diagonal of their bounding box)
placed at p - distance v_j, with the exact formulas of render/neural_gaussians.py
(``evaluate_anchors``, ``gaussian_geometry``). Per Gaussian (anchor, offset k):

- skipped when the offset is masked dead or its opacity is <= 0 from every direction;
- opacity = mean over directions of max(0, opacity_j) (a view where the Gaussian is
  not built counts as 0), written as a logit;
- covariance = mean of R_j S_j^2 R_j^T weighted by max(0, opacity_j), written as scales
  and a rotation from its eigen-decomposition;
- colour: SH coefficients of degree ``sh_degree`` (0..3) fitted by weighted least squares
  (weights max(0, opacity_j) + 1e-3, a ridge of 1e-4 on the non-DC terms) to the colour
  MLP's outputs, in 3DGS's convention colour = SH(u) + 0.5 with u the direction from the
  camera centre to the Gaussian's mean;
- mean = p + o_k exp(s[0:3]) (view independent).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
import torch

from ..common.errors import InputError
from ..common.scene import AnchorScene
from .gaussians3dgs import write_3dgs_ply
from .neural_gaussians import SceneTensors, evaluate_anchors, gaussian_geometry
from .rasterizer import quat_to_rotmat
from .sh import MAX_SH_DEGREE, num_sh_coeffs, sh_basis
from .views import fibonacci_sphere


@dataclass
class Exported3DGS:
    means: np.ndarray  # [M, 3]
    sh: np.ndarray  # [M, (d + 1)^2, 3]
    opacity_logits: np.ndarray  # [M]
    log_scales: np.ndarray  # [M, 3]
    quats: np.ndarray  # [M, 4] (w, x, y, z)
    stats: dict = field(default_factory=dict)

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])


def default_distance(scene: AnchorScene) -> float:
    """2.5 x half the diagonal of the anchors' bounding box (at least one voxel)."""
    p = scene.positions().astype(np.float64)
    return 2.5 * max(float(np.linalg.norm(p.max(0) - p.min(0))) / 2, scene.voxel_size)


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """[M, 3, 3] proper rotations -> [M, 4] unit quaternions (w, x, y, z), w >= 0."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(r).as_quat()  # (x, y, z, w)
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def _check_export(scene: AnchorScene, sh_degree: int, num_directions: int, distance: float | None) -> float:
    """The export distance; InputError for a setting or a scene that cannot be exported."""
    if not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise InputError(f"SH degree must be 0..{MAX_SH_DEGREE}, got {sh_degree}")
    nb = num_sh_coeffs(sh_degree)
    if num_directions < nb:
        raise InputError(f"SH degree {sh_degree} needs at least {nb} view directions, got {num_directions}")
    for role in ("opacity", "cov", "color"):
        if role not in scene.mlps:
            raise InputError(f"the scene has no {role} MLP; it cannot be exported")
    dist = float(distance) if distance is not None else default_distance(scene)
    if not (math.isfinite(dist) and dist > 0):
        raise InputError(f"the export distance must be positive, got {distance}")
    return dist


def _weighted_covariance(st: SceneTensors, anchor: torch.Tensor, ki: torch.Tensor, cov_g: torch.Tensor,
                         wg: torch.Tensor, nd: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(means [m, 3], eigenvalues [m, 3], right-handed eigenvectors [m, 3, 3]) of the covariance
    averaged over the directions by opacity, with the renderer's own formulas per direction."""
    m = anchor.numel()
    means, scales, quats = gaussian_geometry(st, anchor.repeat_interleave(nd), ki.repeat_interleave(nd), cov_g)
    rot = quat_to_rotmat(quats)  # [m nd, 3, 3]
    sig = (rot * scales[:, None, :] ** 2) @ rot.transpose(1, 2)
    wn = wg / wg.sum(1, keepdim=True)
    sig = (sig.reshape(m, nd, 3, 3) * wn[..., None, None]).sum(1)
    lam, vec = torch.linalg.eigh(0.5 * (sig + sig.transpose(1, 2)))
    vec = torch.where(torch.linalg.det(vec)[:, None, None] < 0, vec * torch.tensor([1.0, 1.0, -1.0]), vec)
    return means.reshape(m, nd, 3)[:, 0], lam, vec


def _fit_sh(u: torch.Tensor, colour: torch.Tensor, wg: torch.Tensor, sh_degree: int) -> torch.Tensor:
    """SH coefficients [m, nb, 3] with colour = B(u) c + 0.5 in the weighted least-squares sense
    (a small ridge on the bands above DC)."""
    nb = num_sh_coeffs(sh_degree)
    b = sh_basis(sh_degree, u)  # [m, nd, nb]
    ww = wg + 1e-3
    bw = b * ww[..., None]
    ata = bw.transpose(1, 2) @ b
    ridge = torch.full((nb,), 1e-4, dtype=torch.float64)
    ridge[0] = 1e-9
    ata = ata + torch.diag(ridge)[None] * ww.sum(1)[:, None, None]
    return torch.linalg.solve(ata, bw.transpose(1, 2) @ (colour - 0.5))


def _export_chunk(st: SceneTensors, idx: torch.Tensor, dirs: torch.Tensor, dist: float, live: torch.Tensor,
                  sh_degree: int) -> dict | None:
    """The Gaussians of anchors ``idx`` (live offsets with an opacity above 0 from some direction)."""
    na, nd, k = idx.numel(), dirs.shape[0], st.num_offsets
    op, cov, col = evaluate_anchors(st, idx.repeat_interleave(nd), dirs.repeat(na, 1),
                                    torch.full((na * nd, 1), dist, dtype=torch.float64))
    op, cov, col = op.reshape(na, nd, k), cov.reshape(na, nd, k, 7), col.reshape(na, nd, k, 3)
    w = op.clamp_min(0)  # [na, nd, k]
    mean_op = w.mean(1)  # [na, k]
    ai, ki = torch.nonzero(live[idx] & (mean_op > 0), as_tuple=True)
    if ai.numel() == 0:
        return None
    anchor, wg = idx[ai], w[ai, :, ki]  # wg: [m, nd]
    means, lam, vec = _weighted_covariance(st, anchor, ki, cov[ai, :, ki].reshape(-1, 7), wg, nd)
    # SH fit: u from the camera centre to the mean
    u = means[:, None, :] - (st.positions[anchor][:, None, :] - dist * dirs[None])
    u = u / torch.linalg.vector_norm(u, dim=-1, keepdim=True).clamp_min(1e-300)
    return {"means": means, "sh": _fit_sh(u, col[ai, :, ki], wg, sh_degree), "op": mean_op[ai, ki],
            "scales": torch.sqrt(lam.clamp_min(1e-30)), "rot": vec}


@torch.no_grad()
def export_3dgs(scene: AnchorScene, path: str | os.PathLike | None = None, *, sh_degree: int = 1,
                num_directions: int = 16, distance: float | None = None, chunk_anchors: int = 2048) -> Exported3DGS:
    """Convert an anchor scene to plain 3DGS Gaussians (module doc); write them to ``path``
    as an INRIA PLY when given."""
    dist = _check_export(scene, sh_degree, num_directions, distance)
    st = SceneTensors.from_scene(scene, torch.float64)
    n = st.num_anchors
    dirs = torch.as_tensor(fibonacci_sphere(num_directions))
    live_all = st.offset_mask if st.offset_mask is not None else torch.ones(n, st.num_offsets, dtype=torch.bool)
    chunks = [_export_chunk(st, torch.arange(a0, min(n, a0 + chunk_anchors)), dirs, dist, live_all, sh_degree)
              for a0 in range(0, n, chunk_anchors)]
    chunks = [c for c in chunks if c is not None]
    if not chunks:
        raise InputError("no Gaussian of the scene has a positive opacity from any direction: nothing to export")
    cat = {key: torch.cat([c[key] for c in chunks]).numpy() for key in chunks[0]}
    o = np.clip(cat["op"], 1e-6, 1 - 1e-6)
    res = Exported3DGS(
        means=cat["means"].astype(np.float32), sh=cat["sh"].astype(np.float32),
        opacity_logits=np.log(o / (1 - o)).astype(np.float32), log_scales=np.log(cat["scales"]).astype(np.float32),
        quats=rotmat_to_quat(cat["rot"]).astype(np.float32),
        stats={"anchors": n, "live_offsets": int(live_all.sum()), "gaussians": int(cat["means"].shape[0]),
               "sh_degree": sh_degree, "directions": num_directions, "distance": dist})
    if path is not None:
        write_3dgs_ply(path, res.means, res.sh, res.opacity_logits, res.log_scales, res.quats)
    return res
