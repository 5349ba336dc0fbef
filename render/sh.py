"""Real spherical harmonics up to degree 3, as 3DGS evaluates them (informative).

3DGS (``utils/sh_utils.eval_sh``) stores per Gaussian and colour channel (d + 1)^2
coefficients and computes, for the unit direction v = (x, y, z) from the camera centre
to the Gaussian's mean,

    colour = max(0, sum_i coef_i Y_i(v) + 0.5)

with the real SH basis below (its sign convention: Y_1 = -C1 y, Y_2 = C1 z, Y_3 = -C1 x,
...). The basis is orthonormal over the sphere. The INRIA PLY stores coefficient 0 as
``f_dc_0..2`` and the others channel-major as ``f_rest_{c * (K - 1) + (i - 1)}``, K =
(d + 1)^2 (see ``render/gaussians3dgs.py``).
"""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
      1.445305721320277, -0.5900435899266435)
MAX_SH_DEGREE = 3


def num_sh_coeffs(degree: int) -> int:
    """(degree + 1)^2 coefficients per channel."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be 0..{MAX_SH_DEGREE}, got {degree}")
    return (degree + 1) ** 2


def sh_degree_from_count(k: int) -> int:
    """The degree whose coefficient count per channel is k (1, 4, 9 or 16)."""
    for d in range(MAX_SH_DEGREE + 1):
        if (d + 1) ** 2 == k:
            return d
    raise ValueError(f"{k} coefficients per channel is not (d + 1)^2 for a degree d <= {MAX_SH_DEGREE}")


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """Basis values [..., (degree + 1)^2] at unit directions ``dirs`` [..., 3] (not renormalized)."""
    k = num_sh_coeffs(degree)
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3 * xx - yy), C3[1] * xy * z, C3[2] * y * (4 * zz - xx - yy),
                C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)]
    b = torch.stack(out, -1)
    assert b.shape[-1] == k
    return b


def eval_sh(degree: int, coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """sum_i coeffs[..., i, c] Y_i(dirs): ``coeffs`` [..., K', 3] with K' >= (degree + 1)^2
    (extra coefficients are ignored, as in 3DGS when the active degree is lower), ``dirs``
    [..., 3] unit vectors. Returns [..., 3] (no +0.5 offset, no clamp)."""
    k = num_sh_coeffs(degree)
    if coeffs.shape[-2] < k:
        raise ValueError(f"degree {degree} needs {k} coefficients per channel, got {coeffs.shape[-2]}")
    b = sh_basis(degree, dirs).to(coeffs.dtype)
    return (b[..., :, None] * coeffs[..., :k, :]).sum(-2)


def sh_to_rgb(degree: int, coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """The colour 3DGS renders: max(0, eval_sh + 0.5)."""
    return (eval_sh(degree, coeffs, dirs) + 0.5).clamp_min(0.0)


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """The DC coefficient giving a constant colour: (rgb - 0.5) / C0."""
    return (rgb - 0.5) / C0


def sh0_to_rgb(dc: torch.Tensor) -> torch.Tensor:
    return dc * C0 + 0.5
