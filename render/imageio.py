"""Reading and writing images (informative).

Pillow is used when it is installed. Without it, PNG (8 and 16 bit; grey, grey+alpha,
RGB, RGBA, palette; not interlaced) is read and written by the small codec below,
which needs only zlib; other formats then raise an InputError that says to install
Pillow (``pip install "pillow>=10"``).

Images are returned as float32 arrays [H, W, C] in [0, 1], C in {1, 2, 3, 4}.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..common.errors import InputError

try:  # optional dependency
    from PIL import Image as _PILImage  # type: ignore

    HAVE_PIL = True
except ImportError:  # pragma: no cover - depends on the environment
    _PILImage = None
    HAVE_PIL = False

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}


def _png_chunks(data: bytes, path: str):
    if not data.startswith(_PNG_SIGNATURE):
        raise InputError(f"{path}: not a PNG file (bad signature)")
    pos = 8
    while pos + 8 <= len(data):
        length, ctype = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if len(body) != length:
            raise InputError(f"{path}: truncated PNG chunk {ctype!r}")
        yield ctype, body
        pos += 12 + length
        if ctype == b"IEND":
            return
    raise InputError(f"{path}: truncated PNG (no IEND chunk)")


def png_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of a PNG from its header, without decoding it."""
    p = str(path)
    with open(p, "rb") as f:
        head = f.read(33)
    if len(head) < 24 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        raise InputError(f"{p}: not a PNG file")
    w, h = struct.unpack(">II", head[16:24])
    return int(w), int(h)


def _unfilter(raw: np.ndarray, height: int, stride: int, bpp: int, path: str) -> np.ndarray:
    """Undo the PNG scanline filters. raw: uint8 [height * (stride + 1)]."""
    if raw.size != height * (stride + 1):
        raise InputError(f"{path}: PNG image data has {raw.size} bytes, expected {height * (stride + 1)}")
    rows = raw.reshape(height, stride + 1)
    ftypes, data = rows[:, 0], rows[:, 1:].astype(np.int64)
    out = np.zeros((height, stride), np.int64)
    prev = np.zeros(stride, np.int64)
    for y in range(height):
        f, line = int(ftypes[y]), data[y]
        if f == 0:
            cur = line
        elif f == 1:  # Sub: a running sum per byte lane, mod 256
            cur = np.cumsum(line.reshape(-1, bpp), axis=0).reshape(-1) & 255
        elif f == 2:  # Up
            cur = (line + prev) & 255
        elif f in (3, 4):  # Average, Paeth: sequential over pixels, vectorized over the bpp lanes
            cur = np.empty(stride, np.int64)
            left = np.zeros(bpp, np.int64)
            upleft = np.zeros(bpp, np.int64)
            for x in range(0, stride, bpp):
                up = prev[x:x + bpp]
                if f == 3:
                    pred = (left + up) >> 1
                else:
                    p = left + up - upleft
                    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
                    pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
                left = (line[x:x + bpp] + pred) & 255
                cur[x:x + bpp] = left
                upleft = up
        else:
            raise InputError(f"{path}: unknown PNG filter type {f} in row {y}")
        out[y] = cur
        prev = cur
    return out.astype(np.uint8)


def _read_png(path: str) -> np.ndarray:
    data = Path(path).read_bytes()
    ihdr, idat, plte, trns = None, [], None, None
    for ctype, body in _png_chunks(data, path):
        if ctype == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif ctype == b"IDAT":
            idat.append(body)
        elif ctype == b"PLTE":
            plte = np.frombuffer(body, np.uint8).reshape(-1, 3)
        elif ctype == b"tRNS":
            trns = np.frombuffer(body, np.uint8)
    if ihdr is None:
        raise InputError(f"{path}: PNG without IHDR")
    w, h, depth, ctype, _comp, _filt, interlace = ihdr
    if ctype not in _CHANNELS or depth not in (8, 16) or (ctype == 3 and depth != 8):
        raise InputError(f"{path}: PNG colour type {ctype} with bit depth {depth} needs Pillow "
                         "(pip install 'pillow>=10')")
    if interlace:
        raise InputError(f"{path}: interlaced PNG needs Pillow (pip install 'pillow>=10')")
    ch = _CHANNELS[ctype]
    bpp = ch * depth // 8
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8)
    except zlib.error as e:
        raise InputError(f"{path}: corrupt PNG image data ({e})") from None
    pix = _unfilter(raw, h, w * bpp, bpp, path)
    if depth == 16:
        img = pix.reshape(h, w * ch, 2).astype(np.uint16)
        img = ((img[..., 0] << 8) | img[..., 1]).reshape(h, w, ch).astype(np.float32) / 65535.0
    else:
        img = pix.reshape(h, w, ch)
        if ctype == 3:
            if plte is None:
                raise InputError(f"{path}: palette PNG without PLTE chunk")
            idx = img[..., 0]
            if idx.max(initial=0) >= len(plte):
                raise InputError(f"{path}: palette index out of range")
            rgb = plte[idx]
            if trns is not None:
                a = np.full(len(plte), 255, np.uint8)
                a[:len(trns)] = trns[:len(plte)]
                rgb = np.concatenate([rgb, a[idx][..., None]], axis=-1)
            img = rgb
        img = img.astype(np.float32) / 255.0
    return img


def read_image(path: str | os.PathLike) -> np.ndarray:
    """float32 [H, W, C] in [0, 1]. Raises InputError if the file is missing or unreadable."""
    p = str(path)
    if not os.path.isfile(p):
        raise InputError(f"image not found: {p}")
    if HAVE_PIL:
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
    if p.lower().endswith(".png"):
        return _read_png(p)
    raise InputError(f"{p}: reading this image format needs Pillow (pip install 'pillow>=10'); "
                     "without it only PNG is supported")


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
    """Write float [H, W, C] in [0, 1] (or uint8) as an 8-bit PNG (C = 1, 3 or 4)."""
    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.clip(np.nan_to_num(a.astype(np.float64)) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        a = a[..., None]
    h, w, c = a.shape
    ctype = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    if HAVE_PIL:
        _PILImage.fromarray(a[..., 0] if c == 1 else a).save(str(path))
        return
    raw = np.concatenate([np.zeros((h, 1), np.uint8), a.reshape(h, w * c)], axis=1).tobytes()

    def chunk(t: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + t + body + struct.pack(">I", zlib.crc32(t + body) & 0xFFFFFFFF)

    out = (_PNG_SIGNATURE + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    Path(path).write_bytes(out)
