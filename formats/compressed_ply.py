"""PlayCanvas compressed PLY (``.compressed.ply``, SuperSplat's compressed export): read only.

Layout and dequantization as @playcanvas/splat-transform 3.7.0 reads it (``readCompressedChunked``
in ``dist/index.mjs``; ``src/lib/readers/decompress-ply.ts`` in playcanvas/splat-transform):

- element ``chunk``, one row per 256 Gaussians (Gaussian i uses row i >> 8): float bounds
  ``min_x..max_z``, ``min_scale_x..max_scale_z`` and, optionally, ``min_r..max_b``;
- element ``vertex``: four uint32 per Gaussian. ``packed_position`` and ``packed_scale``: 11,
  10, 11 bits (x from bit 21, y from bit 11, z from bit 0), each lerp(min, max, q / (2^bits - 1))
  of its chunk (scales are log scales); ``packed_rotation``: bits 30-31 the index of the
  largest quaternion component (w, x, y, z order), then the other three in order, 10 bits each
  from bit 20, as (q / 1023 - 0.5) sqrt(2), the largest sqrt(1 - the others' squares);
  ``packed_color``: 8 bits each of r (bit 24), g, b and alpha (bit 0); colour c / 255 (lerped
  between the chunk's ``min_r..max_r`` when present) is 0.5 + SH_C0 f_dc;
- element ``sh`` (optional): uint8 ``f_rest_*`` in the INRIA PLY's order, byte b meaning
  ((b + 0.5) / 256 - 0.5) 8, with 0 and 255 meaning -4 and 4 exactly.

Alpha 0 and 255 read as the finite logits of the other 8-bit formats (formats/opacity.py), where
splat-transform gives -inf and +inf. Not kept: the header's antialiasing comment.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..common.scene import GaussianScene, sh_coeffs_per_channel
from .opacity import alpha_logits
from .ply import read_ply, read_ply_header_lines

SH_C0 = 0.28209479177387814
CHUNK_GAUSSIANS = 256
ROTATION_SCALE = 1.0 / (math.sqrt(2) * 0.5)
POSITION_FIELDS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z")
SCALE_FIELDS = ("min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z")
COLOR_FIELDS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
PACKED_FIELDS = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def _unorm(v: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((v >> shift) & ((1 << bits) - 1)) / ((1 << bits) - 1)


def _lerp_11_10_11(packed: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """[N, 3] from 11/10/11-bit fields and per-Gaussian [min x, y, z, max x, y, z] (float64)."""
    t = np.stack([_unorm(packed, 21, 11), _unorm(packed, 11, 10), _unorm(packed, 0, 11)], axis=1)
    return bounds[:, :3] * (1 - t) + bounds[:, 3:] * t


def _rotations(packed: np.ndarray) -> np.ndarray:
    small = np.stack([(_unorm(packed, s, 10) - 0.5) * ROTATION_SCALE for s in (20, 10, 0)], axis=1)
    largest = packed >> 30
    n = len(packed)
    rot = np.zeros((n, 4))
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    np.put_along_axis(rot, others, small, 1)
    rot[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1 - (small * small).sum(axis=1)))
    return rot


def _colours(packed: np.ndarray, chunks: dict[str, np.ndarray], index: np.ndarray) -> np.ndarray:
    c = np.stack([_unorm(packed, s, 8) for s in (24, 16, 8)], axis=1)
    if all(f in chunks for f in COLOR_FIELDS):
        b = _bounds(chunks, COLOR_FIELDS, index)
        c = b[:, :3] * (1 - c) + b[:, 3:] * c
    return (c - 0.5) / SH_C0


def _sh_rest(path: Path, n: int) -> np.ndarray | None:
    """[N, coefficients, 3] from the ``sh`` element, or None without one."""
    if "sh" not in [line.split()[1] for line in read_ply_header_lines(path) if line.startswith("element ")]:
        return None
    cols = read_ply(path, "sh")
    rest = [f"f_rest_{i}" for i in range(len(cols))]
    k = {3 * (sh_coeffs_per_channel(d) - 1): sh_coeffs_per_channel(d) for d in (1, 2, 3)}.get(len(cols))
    if k is None or any(name not in cols for name in rest) or len(cols["f_rest_0"]) != n:
        raise InputError(f"{path}: the sh element needs f_rest_0..f_rest_(9, 24 or 45 - 1) for the {n} Gaussians, "
                         f"got {len(cols)} properties")
    b = np.stack([cols[name] for name in rest], axis=1).astype(np.float64)
    v = np.where(b == 0, 0.0, np.where(b == 255, 1.0, (b + 0.5) / 256))
    return ((v - 0.5) * 8).reshape(n, 3, k - 1).transpose(0, 2, 1)


def _bounds(chunks: dict[str, np.ndarray], fields: tuple[str, ...], index: np.ndarray) -> np.ndarray:
    return np.stack([chunks[f].astype(np.float64) for f in fields], axis=1)[index]


def is_compressed_ply_header(names: list[str]) -> bool:
    """The vertex property names of a compressed PLY (``packed_position`` marks it, as for splat-transform)."""
    return "packed_position" in names


def read_compressed_ply(path: str | os.PathLike) -> GaussianScene:
    """Read a PlayCanvas compressed PLY into a validated GaussianScene (InputError naming the
    file and the first missing element or property)."""
    p = Path(path)
    verts, chunks = read_ply(p, "vertex"), read_ply(p, "chunk")
    for where, cols, fields in (("vertex", verts, PACKED_FIELDS), ("chunk", chunks, POSITION_FIELDS + SCALE_FIELDS)):
        missing = [f for f in fields if f not in cols]
        if missing:
            raise InputError(f"{p}: the {where} element has no {', '.join(missing)}: not a compressed PLY")
    n = len(verts["packed_position"])
    if n == 0:
        raise InputError(f"{p}: the file holds no Gaussians")
    if len(chunks["min_x"]) * CHUNK_GAUSSIANS < n:
        raise InputError(f"{p}: {len(chunks['min_x'])} chunk rows bound at most "
                         f"{len(chunks['min_x']) * CHUNK_GAUSSIANS} Gaussians, the file has {n}")
    packed = {f: verts[f].astype(np.int64) for f in PACKED_FIELDS}
    index = np.arange(n) >> 8
    rest = _sh_rest(p, n)
    sh = np.zeros((n, 1 + (0 if rest is None else rest.shape[1]), 3))
    sh[:, 0] = _colours(packed["packed_color"], chunks, index)
    if rest is not None:
        sh[:, 1:] = rest
    f32 = np.float32
    scene = GaussianScene(_lerp_11_10_11(packed["packed_position"], _bounds(chunks, POSITION_FIELDS, index)).astype(f32),
                          sh.astype(f32), alpha_logits(packed["packed_color"] & 255).astype(f32),
                          _lerp_11_10_11(packed["packed_scale"], _bounds(chunks, SCALE_FIELDS, index)).astype(f32),
                          _rotations(packed["packed_rotation"]).astype(f32))
    return scene.validate(str(p))
