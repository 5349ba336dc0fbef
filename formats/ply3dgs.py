"""The INRIA 3DGS PLY (3DGS's ``save_ply``; gsplat, nerfstudio, SuperSplat write the same):

per Gaussian ``x, y, z`` (``nx, ny, nz``, unused), ``f_dc_0..2``, ``f_rest_0..3(K-1)-1``
(channel-major: f_rest_{c (K-1) + i - 1} is coefficient i of channel c, K = (d + 1)^2 for SH
degree d; none for degree 0), ``opacity`` (logit), ``scale_0..2`` (log), ``rot_0..3``
(quaternion w, x, y, z, any norm). Opacity logits of +-inf (opacity 1 and 0, as splat-transform
writes the 8-bit opacities of a compressed PLY) are read as finite logits with a warning
(formats/opacity.py); NaN anywhere is an error.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from .opacity import finite_opacity_logits
from .ply import read_ply, read_ply_header_lines, write_ply
from ..common.scene import SH_DEGREE_MAX, GaussianScene, sh_coeffs_per_channel

REQUIRED_FIELDS = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                   "rot_0", "rot_1", "rot_2", "rot_3")


def ply_property_names(path: str | os.PathLike, element: str | None = None) -> list[str]:
    """Property names of the element ``element`` (None: the first) of a PLY file, from its
    header only ([] when it has no such element)."""
    names: list[str] = []
    current = None
    for line in read_ply_header_lines(path):
        parts = line.split()
        if parts[:1] == ["element"] and len(parts) >= 2:
            if current is not None and (element is None or current == element):
                break
            current = parts[1]
        elif parts[:1] == ["property"] and len(parts) >= 3 and (element is None or current == element):
            names.append(parts[-1])
    return names


def is_3dgs_ply(path: str | os.PathLike) -> bool:
    """True for a plain 3DGS PLY: a .ply file with f_dc_0 and no f_anchor_feat_0."""
    p = Path(path)
    if not p.is_file():
        return False
    try:
        names = ply_property_names(p)
    except InputError:
        return False
    return "f_dc_0" in names and "f_anchor_feat_0" not in names


def read_3dgs_ply(path: str | os.PathLike) -> GaussianScene:
    """Read an INRIA 3DGS PLY into a validated GaussianScene. Raises InputError naming the file
    and the first missing or malformed field."""
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
    counts = [sh_coeffs_per_channel(d) for d in range(SH_DEGREE_MAX + 1)]
    if nrest % 3 or nrest // 3 + 1 not in counts:
        raise InputError(f"{p}: {nrest} f_rest_* fields match no SH degree: expected 3((d+1)^2 - 1) = 0, 9, 24 or "
                         f"45 for d = 0..{SH_DEGREE_MAX}")
    k = nrest // 3 + 1
    n = len(cols["x"])
    if n == 0:
        raise InputError(f"{p}: the file holds no Gaussians")

    def stack(names):
        return np.stack([np.asarray(cols[c], np.float32) for c in names], axis=1)

    sh = np.zeros((n, k, 3), np.float32)
    sh[:, 0] = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    if nrest:
        sh[:, 1:] = stack(rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    opacity = finite_opacity_logits(np.asarray(cols["opacity"], np.float32), str(p))
    scene = GaussianScene(stack(["x", "y", "z"]), sh, opacity,
                          stack(["scale_0", "scale_1", "scale_2"]), stack(["rot_0", "rot_1", "rot_2", "rot_3"]))
    return scene.validate(str(p))


def write_3dgs_ply(path: str | os.PathLike, scene: GaussianScene, comments: list[str] = ()) -> None:
    """Write an INRIA 3DGS PLY (binary little-endian float32, normals zero, the field order of
    3DGS's ``save_ply``), atomically."""
    n, k = scene.num_gaussians, scene.sh.shape[1]
    z = np.zeros(n, np.float32)
    m = scene.means
    cols = {"x": m[:, 0], "y": m[:, 1], "z": m[:, 2], "nx": z, "ny": z, "nz": z}
    cols.update({f"f_dc_{c}": scene.sh[:, 0, c] for c in range(3)})
    # f_rest_{c (K-1) + i - 1} is coefficient i of channel c: views, no copy of the scene's SH
    cols.update({f"f_rest_{c * (k - 1) + i - 1}": scene.sh[:, i, c] for c in range(3) for i in range(1, k)})
    cols["opacity"] = scene.opacity
    cols.update({f"scale_{i}": scene.log_scales[:, i] for i in range(3)})
    cols.update({f"rot_{i}": scene.rotations[:, i] for i in range(4)})
    write_ply(path, {k_: np.asarray(v, np.float32) for k_, v in cols.items()}, comments)
