"""Kevin Kwok's / mkkellogg's ``.ksplat`` (GaussianSplats3D's format): read only.

Layout as @playcanvas/splat-transform 3.7.0 reads it (``readKsplat`` in ``dist/index.mjs``):
a 4096-byte main header (uint8 major 0, minor >= 1; uint32 at 4 the section count, at 16 the
Gaussian count; uint16 at 20 the compression mode 0, 1 or 2; float32 at 36 and 40 the SH range
of mode 2, 0 meaning -1.5 and 1.5), then a 1024-byte header per section (uint32 at 0 its
Gaussians, 4 its capacity, 8 the bucket capacity, 12 the bucket count; float32 at 16 the block
size; uint16 at 20 the bytes per bucket; uint32 at 24 the position range (0: the mode's), 32 the
full and 36 the partial buckets; uint16 at 40 the SH degree), then each section's data: uint32
sizes of its partial buckets, float32 bucket centres, and ``capacity`` records of

- mode 0: float32 position, float32 scale (linear), float32 quaternion (w, x, y, z as stored);
- modes 1 and 2: uint16 position u, read as (u - range) block / (2 range) + its bucket's centre
  (a bucket: ``bucket capacity`` records, then the partial buckets in turn), float16 scale and
  quaternion;

then uint8 r, g, b (c / 255 = 0.5 + SH_C0 f_dc), alpha (formats/opacity.py), and the SH of the
section's degree: float32 (mode 0), float16 (1) or uint8 within the header's range (2), band by
band, each band channel by channel. A scale of 0 or below reads as log scale -10.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..common.scene import GaussianScene, sh_coeffs_per_channel
from .opacity import alpha_logits

SH_C0 = 0.28209479177387814
MAIN_HEADER, SECTION_HEADER = 4096, 1024
# per mode: (position, scale/rotation, SH) element types and the position range when a section gives 0
MODES = {0: ("<f4", "<f4", "<f4", 1), 1: ("<u2", "<f2", "<f2", 32767), 2: ("<u2", "<f2", "u1", 32767)}
SMALLEST_LOG_SCALE = -10.0  # what a scale of 0 or below reads as (splat-transform's)
SECTION = struct.Struct("<4IfH2xI4x2IH")  # the section header's fields at offsets 0-20, 24, 32-40


def sh_slots(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """(coefficient - 1, channel) of the section's i-th stored SH value: band by band, and within
    a band channel by channel."""
    coeff, channel = [], []
    for band in range(1, degree + 1):
        first, width = band * band - 1, 2 * band + 1
        for c in range(3):
            coeff += range(first, first + width)
            channel += [c] * width
    return np.array(coeff, int), np.array(channel, int)


class _Ksplat:
    """The file's bytes and main header, read section by section (InputError naming the file)."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise InputError(f"{path}: cannot read ({e.strerror})") from None
        if len(self.data) < MAIN_HEADER:
            raise InputError(f"{path}: {len(self.data)} bytes, shorter than the .ksplat header ({MAIN_HEADER})")
        major, minor = self.data[0], self.data[1]
        if major != 0 or minor < 1:
            raise InputError(f"{path}: .ksplat version {major}.{minor}; version 0.1 and later 0.x are read")
        self.sections, self.count = struct.unpack_from("<I", self.data, 4)[0], struct.unpack_from("<I", self.data, 16)[0]
        self.mode = struct.unpack_from("<H", self.data, 20)[0]
        if self.mode not in MODES:
            raise InputError(f"{path}: compression mode {self.mode}; modes 0, 1 and 2 are read")
        if self.count == 0:
            raise InputError(f"{path}: the file holds no Gaussians")
        lo, hi = struct.unpack_from("<2f", self.data, 36)
        self.sh_range = (lo or -1.5, hi or 1.5)  # splat-transform's `|| -1.5`, `|| 1.5`
        if MAIN_HEADER + self.sections * SECTION_HEADER > len(self.data):
            raise InputError(f"{path}: {self.sections} section headers do not fit in {len(self.data)} bytes")
        self.headers = [SECTION.unpack_from(self.data, MAIN_HEADER + i * SECTION_HEADER) for i in range(self.sections)]

    def array(self, offset: int, dtype, count: int, what: str) -> np.ndarray:
        dtype = np.dtype(dtype)
        if offset + dtype.itemsize * count > len(self.data):
            raise InputError(f"{self.path}: truncated: {what} runs past the end of the file")
        return np.frombuffer(self.data, dtype, count, offset)

    def record(self, degree: int) -> np.dtype:
        pos, half, sh, _ = MODES[self.mode]
        fields = [("position", pos, 3), ("scale", half, 3), ("rotation", half, 4), ("rgba", "u1", 4)]
        k = 3 * (sh_coeffs_per_channel(degree) - 1)
        return np.dtype(fields + ([("sh", sh, k)] if k else []))

    def degree(self) -> int:
        degrees = [h[9] for h in self.headers if h[0] > 0]
        if any(d > 3 for d in degrees):
            raise InputError(f"{self.path}: a section of SH degree {max(degrees)}; degrees 0-3 are read")
        return max(degrees, default=0)


def _buckets(k: _Ksplat, header: tuple, offset: int) -> np.ndarray:
    """The bucket index of each of the section's Gaussians."""
    count, _, capacity, _, _, _, _, full, partial, _ = header
    sizes = k.array(offset, "<u4", partial, "the partial bucket sizes").astype(np.int64)
    full_splats = min(count, full * capacity)
    index = np.arange(full_splats) // max(capacity, 1)
    tail = np.repeat(np.arange(full, full + partial), sizes)[: count - full_splats]
    if len(tail) < count - full_splats:
        raise InputError(f"{k.path}: the buckets of a section hold fewer than its {count} Gaussians")
    return np.concatenate([index, tail])


def _read_section(k: _Ksplat, header: tuple, offset: int, out: dict, start: int) -> int:
    """Decode one section into ``out`` from Gaussian ``start``; the offset of the next section."""
    count, capacity, _, n_buckets, block, bucket_bytes, qrange, _, partial, degree = header
    storage = bucket_bytes * n_buckets + 4 * partial
    rec = k.array(offset + storage, k.record(degree), capacity, "a section's records")[:count]
    if count:
        end = slice(start, start + count)
        pos = rec["position"].astype(np.float64)
        if k.mode:
            qrange = qrange or MODES[k.mode][3]
            centres = k.array(offset + 4 * partial, "<f4", 3 * n_buckets, "the bucket centres").reshape(-1, 3)
            pos = (pos - qrange) * (block / 2.0 / qrange) + centres[_buckets(k, header, offset)]
        out["means"][end] = pos
        scale = rec["scale"].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            out["log_scales"][end] = np.where(scale > 0, np.log(scale), SMALLEST_LOG_SCALE)
        out["rotations"][end] = rec["rotation"]
        out["sh"][end, 0] = (rec["rgba"][:, :3] / 255.0 - 0.5) / SH_C0
        out["opacity"][end] = alpha_logits(rec["rgba"][:, 3])
        if degree:
            sh = rec["sh"].astype(np.float64)
            if k.mode == 2:
                sh = k.sh_range[0] + sh / 255.0 * (k.sh_range[1] - k.sh_range[0])
            coeff, channel = sh_slots(degree)
            out["sh"][start:start + count, 1 + coeff, channel] = sh
    return offset + storage + rec.dtype.itemsize * capacity


def read_ksplat(path: str | os.PathLike) -> GaussianScene:
    """Read a ``.ksplat`` file into a validated GaussianScene (InputError naming the file)."""
    p = Path(path)
    k = _Ksplat(p)
    n = k.count
    out = {"means": np.zeros((n, 3)), "log_scales": np.zeros((n, 3)), "rotations": np.zeros((n, 4)),
           "opacity": np.zeros(n), "sh": np.zeros((n, sh_coeffs_per_channel(k.degree()), 3))}
    offset, start = MAIN_HEADER + k.sections * SECTION_HEADER, 0
    for header in k.headers:
        if start + header[0] > n:
            raise InputError(f"{p}: the sections hold more Gaussians than the header's {n}")
        offset = _read_section(k, header, offset, out, start)
        start += header[0]
    if start != n:
        raise InputError(f"{p}: the sections hold {start} Gaussians, the header says {n}")
    f32 = np.float32
    return GaussianScene(out["means"].astype(f32), out["sh"].astype(f32), out["opacity"].astype(f32),
                         out["log_scales"].astype(f32), out["rotations"].astype(f32)).validate(str(p))
