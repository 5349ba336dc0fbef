"""Reading and writing images (informative), with Pillow.

Images are returned as float32 arrays [H, W, C] in [0, 1], C in {1, 2, 3, 4}.
"""

from __future__ import annotations

import os
import struct

import numpy as np
from PIL import Image as _PILImage

from ..app.fileio import atomic_output
from ..common.errors import InputError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of a PNG from its header, without decoding it."""
    p = str(path)
    with open(p, "rb") as f:
        head = f.read(33)
    if len(head) < 24 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        raise InputError(f"{p}: not a PNG file")
    w, h = struct.unpack(">II", head[16:24])
    return int(w), int(h)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """float32 [H, W, C] in [0, 1]. Raises InputError if the file is missing or unreadable."""
    p = str(path)
    if not os.path.isfile(p):
        raise InputError(f"image not found: {p}")
    try:
        with _PILImage.open(p) as im:
            if im.mode in ("I;16", "I;16B", "I"):
                arr = np.asarray(im, dtype=np.float32) / 65535.0
                return arr[..., None]
            if im.mode not in ("L", "LA", "RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in im.mode or "transparency" in im.info else "RGB")
            arr = np.asarray(im, dtype=np.float32) / 255.0
    except OSError as e:
        raise InputError(f"{p}: cannot read image ({e})") from None
    return arr[..., None] if arr.ndim == 2 else arr


def composite_background(img: np.ndarray, background: str | tuple | np.ndarray) -> np.ndarray:
    """RGB [H, W, 3] from an image with or without alpha, composited on the background
    ('white', 'black' or 3 values in [0, 1])."""
    bg = background_color(background)
    if img.shape[-1] in (2, 4):
        rgb, a = img[..., :-1], img[..., -1:]
        if rgb.shape[-1] == 1:
            rgb = np.repeat(rgb, 3, axis=-1)
        return (rgb * a + bg * (1.0 - a)).astype(np.float32)
    if img.shape[-1] == 1:
        return np.repeat(img, 3, axis=-1).astype(np.float32)
    return img.astype(np.float32)


def background_color(background: str | tuple | np.ndarray) -> np.ndarray:
    if isinstance(background, str):
        if background == "white":
            return np.ones(3, np.float32)
        if background == "black":
            return np.zeros(3, np.float32)
        raise InputError(f"background must be 'white', 'black' or 3 numbers, got {background!r}")
    bg = np.asarray(background, np.float32).reshape(-1)
    if bg.shape != (3,) or not np.isfinite(bg).all():
        raise InputError(f"background must be 3 finite numbers, got {background!r}")
    return bg


def write_png(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write float [H, W, C] in [0, 1] (or uint8) as an 8-bit PNG (C = 1, 2, 3 or 4), atomically
    (a reader never sees a partial file; an interrupted write leaves the old one)."""
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float64)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    picture = _PILImage.fromarray(a[..., 0] if a.shape[2] == 1 else a)
    with atomic_output(path) as f:
        picture.save(f, format="PNG")
