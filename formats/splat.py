"""antimatter15's ``.splat`` (the WebGL viewer's format): read only.

No header; 32 bytes per Gaussian, as @playcanvas/splat-transform 3.7.0 reads it (``readSplat``
in ``dist/index.mjs``): float32 x, y, z; float32 linear scales (read as their logs); uint8 r, g, b
(c / 255 = 0.5 + SH_C0 f_dc) and alpha (formats/opacity.py); uint8 quaternion w, x, y, z as
q / 255 * 2 - 1, normalized (no byte decodes to 0, so no quaternion has length 0). SH degree 0.
A scale of 0 or below has no log: the scene's validation refuses it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..common.scene import GaussianScene
from .opacity import alpha_logits

SH_C0 = 0.28209479177387814
SPLAT_RECORD = np.dtype([("means", "<f4", 3), ("scales", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])


def read_splat(path: str | os.PathLike) -> GaussianScene:
    """Read a ``.splat`` file into a validated GaussianScene (InputError naming the file)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as e:
        raise InputError(f"{p}: cannot read ({e.strerror})") from None
    if size == 0 or size % SPLAT_RECORD.itemsize:
        raise InputError(f"{p}: {size} bytes: a .splat file is a positive multiple of {SPLAT_RECORD.itemsize} bytes "
                         "(one record per Gaussian)")
    try:
        rec = np.fromfile(p, SPLAT_RECORD)
    except OSError as e:
        raise InputError(f"{p}: cannot read ({e.strerror})") from None
    rot = rec["rotation"] / 255.0 * 2 - 1
    rot /= np.linalg.norm(rot, axis=1, keepdims=True)
    scales = rec["scales"].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):  # scale 0 or below: the validation names it
        log_scales = np.log(scales)
    f32 = np.float32
    return GaussianScene(rec["means"].astype(f32), ((rec["rgba"][:, None, :3] / 255.0 - 0.5) / SH_C0).astype(f32),
                         alpha_logits(rec["rgba"][:, 3]).astype(f32), log_scales.astype(f32),
                         rot.astype(f32)).validate(str(p))
