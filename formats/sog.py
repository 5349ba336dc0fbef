"""PlayCanvas SOG (``.sog``): read versions 1 and 2, write version 2.

Layout as @playcanvas/splat-transform 3.7.0 writes and reads it (``writeSogSource`` and
``readSogSourceV2``/``readSogV1`` in ``dist/index.mjs`` of the npm package; the same code is
``src/lib/writers/write-sog.ts`` and ``src/lib/readers/read-sog.ts`` in playcanvas/splat-transform)
and as the PlayCanvas engine decodes it (``src/scene/gsplat/gsplat-sog-data.js``,
``src/framework/parsers/sog-bundle.js``).

A ``.sog`` file is a zip archive (stored or deflated entries, no zip64) of ``meta.json`` and
lossless WebP images; an unbundled scene is a ``meta.json`` with the images beside it. Every
image but the SH palette is W x H pixels, W = ceil(sqrt(N) / 4) * 4 and H = ceil(N / W / 4) * 4,
pixel i (row-major) holding Gaussian i. Version 2 (``"version": 2`` and ``"count": N``):

- ``means_l.webp``, ``means_u.webp``: RGB = low and high bytes of 16-bit x, y, z, each the
  position mapped by l(v) = sign(v) ln(|v| + 1) and then linearly from ``means.mins`` ..
  ``means.maxs`` (the bounds of l over the scene) onto 0 .. 65535;
- ``quats.webp``: the unit quaternion (w, x, y, z) with its largest |component| made
  positive; RGB = the other three, in (w, x, y, z) order, as 255 (q sqrt(2) / 2 + 1/2); A =
  252 + the index of the largest;
- ``scales.webp``: RGB = indices into ``scales.codebook`` (256 log scales);
- ``sh0.webp``: RGB = indices into ``sh0.codebook`` (256 f_dc values); A = sigmoid(opacity) 255;
- ``shN_centroids.webp``, ``shN_labels.webp`` (SH degree ``shN.bands`` > 0): a palette of
  ``shN.count`` SH vectors, 64 per row, each 15, 8 or 3 pixels wide (one per coefficient,
  RGB = channels, as indices into ``shN.codebook``), and per Gaussian a 16-bit palette index
  (R low byte, G high byte).

Version 1 (no ``version``; ``means.shape[0]`` = N) stores scales, f_dc and the logit of the
opacity linearly between per-channel ``mins`` and ``maxs``, and the SH palette between scalar
bounds; it is read only.

The writer follows splat-transform: Gaussians in Morton order of their positions (so the
images compress; the file's order is not the scene's: ``morton_order`` gives it), 256-entry
codebooks by the same density-weighted optimal 1-D quantizer over a histogram (``quantize_1d``,
the same codebooks), the same WebP encoder settings, and an SH palette of
min(64, 2^floor(log2(N / 1024))) x 1024 entries by k-means, 10 Lloyd iterations. It differs
where that buys accuracy or speed: means, quaternions and opacity round to nearest where
splat-transform truncates (half the error, same layout); the k-means starts from k-means++
seeds (seeded: the same scene gives the same bytes) and, past 256 entries, clusters a tree of
groups (seconds in numpy for 300k Gaussians, where splat-transform runs flat k-means on a GPU or
a kd-tree on the CPU); and WebP keeps the colour of pixels whose alpha (opacity) is 0, which
libwebp's default replaces. Not kept: meta.json's ``model`` entry (e.g. antialiased).
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
import zlib
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image, UnidentifiedImageError

from .. import __version__
from ..common.errors import InputError
from ..app.fileio import atomic_write_bytes
from ..common.scene import GaussianScene
from .opacity import alpha_logits

SOG_VERSION = 2
CODEBOOK_SIZE = 256
SH_COEFFS = (0, 3, 8, 15)  # coefficients per channel beyond the DC term, by SH degree
PALETTE_ROW = 64  # SH palette entries per row of shN_centroids.webp
QUAT_TAG = 252  # quats.webp alpha = QUAT_TAG + index of the dropped (largest) component
KMEANS_ITERATIONS = 10  # splat-transform's default --iterations
KMEANS_LEAF = 256  # most centroids one flat k-means fits; larger palettes are built as a tree
MAX_TEXTURE_SIDE = 16383  # WebP's limit
WEBP_EFFORT, WEBP_METHOD = 70, 4  # libwebp's WebPEncodeLosslessRGBA settings, which splat-transform uses


def log_transform(v: np.ndarray) -> np.ndarray:
    """l(v) = sign(v) ln(|v| + 1), SOG's mapping of positions before quantization."""
    return np.sign(v) * np.log(np.abs(v) + 1)


def inverse_log_transform(v: np.ndarray) -> np.ndarray:
    return np.sign(v) * (np.exp(np.abs(v)) - 1)


def texture_size(n: int) -> tuple[int, int]:
    """(width, height) of the per-Gaussian images for n Gaussians."""
    w = math.ceil(math.sqrt(n) / 4) * 4
    return w, math.ceil(n / w / 4) * 4


def palette_size(n: int) -> int:
    """splat-transform's SH palette size for n Gaussians: min(64, 2^floor(log2(n / 1024))) x 1024."""
    return int(min(64.0, 2.0 ** math.floor(math.log2(n / 1024))) * 1024)


# --- Morton order -------------------------------------------------------------------------

def _part1by2(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.uint32) & 0x3FF
    v = (v ^ (v << 16)) & 0xFF0000FF
    v = (v ^ (v << 8)) & 0x0300F00F
    v = (v ^ (v << 4)) & 0x030C30C3
    return (v ^ (v << 2)) & 0x09249249


def morton_order(means: np.ndarray) -> np.ndarray:
    """The order a SOG writer stores Gaussians in: ``order[i]`` is the scene index of file
    position i. Morton (Z-order) codes of 10 bits per axis over the bounding box, stably sorted;
    a run of more than 256 equal codes is ordered again over its own box (splat-transform's
    ``sortMortonInterleaved``)."""
    means = np.asarray(means, np.float32)
    order = np.arange(len(means))
    stack = [(0, len(order))]
    while stack:
        start, end = stack.pop()
        idx = order[start:end]
        p = means[idx].astype(np.float64)
        lo, hi = p.min(axis=0), p.max(axis=0)
        span = hi - lo
        if not np.isfinite(span).all() or not span.any():
            continue
        mul = np.divide(1024.0, span, out=np.zeros(3), where=span > 0)
        q = np.minimum(1023.0, (p - lo) * mul).astype(np.uint32)
        code = (_part1by2(q[:, 2]) << 2) + (_part1by2(q[:, 1]) << 1) + _part1by2(q[:, 0])
        sort = np.argsort(code, kind="stable")
        order[start:end] = idx[sort]
        code = code[sort]
        bounds = np.flatnonzero(np.diff(code)) + 1
        runs = zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [len(code)]]))
        stack += [(start + int(a), start + int(b)) for a, b in runs if b - a > 256]
    return order


# --- codebooks ----------------------------------------------------------------------------

class _BinCosts:
    """Prefix sums of the weighted bins: the weighted squared error and the mean of one centroid
    over a run of bins, in O(1) each."""

    def __init__(self, centers: np.ndarray, weights: np.ndarray):
        self.centers = centers
        self.pw = np.concatenate([[0.0], np.cumsum(weights)])
        self.pwx = np.concatenate([[0.0], np.cumsum(weights * centers)])
        self.pwxx = np.concatenate([[0.0], np.cumsum(weights * centers * centers)])

    def cost(self, s: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Weighted squared error of one centroid over bins s + 1 .. j (s < j)."""
        pw, pwx, pwxx = self.pw, self.pwx, self.pwxx
        w, wx, wxx = pw[j + 1] - pw[s + 1], pwx[j + 1] - pwx[s + 1], pwxx[j + 1] - pwxx[s + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(w > 0, wxx - wx * wx / w, 0.0)

    def mean(self, a: int, b: int) -> float:
        ww = self.pw[b + 1] - self.pw[a]
        return (self.centers[a] + self.centers[b]) * 0.5 if ww <= 0 else (self.pwx[b + 1] - self.pwx[a]) / ww


def _weighted_bins(v: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(counts, centers, weights) of the min(1024, N) bins of the sorted values ``v``, placed by a
    blend of rank and value (more rank the heavier the tails), each weighted count^alpha."""
    n = len(v)
    vmin, vmax = v[0], v[-1]
    h = min(1024, n)
    vrange = vmax - vmin
    iqr = v[int(n * 0.75)] - v[int(n * 0.25)]
    beta = max(0.5, min(0.999, 1 - iqr / vrange))
    pos = beta * (np.arange(n) / n) + (1 - beta) * ((v - vmin) / vrange)
    bins = np.minimum(h - 1, np.floor(h * pos)).astype(np.int64)
    counts = np.bincount(bins, minlength=h).astype(np.float64)
    sums = np.bincount(bins, weights=v, minlength=h)
    centers = np.where(counts > 0, sums / np.maximum(counts, 1), vmin + (np.arange(h) + 0.5) / h * vrange)
    return counts, centers, np.where(counts > 0, counts ** alpha, 0.0)


def _next_centroid(dp: np.ndarray, costs: _BinCosts, m: int) -> tuple[np.ndarray, np.ndarray]:
    """dp'[j] = min over s in [m - 2, j) of dp[s] + cost(s, j), for j >= m - 1, and its first best
    s. That s never decreases with j (the cost is a Monge array), so solve by divide and conquer,
    all segments of a level at once: O(h log h) per m instead of O(h^2)."""
    h = len(dp)
    new_dp, split = np.full(h, 1e30), np.zeros(h, np.int64)
    jl, jr, sl, sr = (np.array([v]) for v in (m - 1, h - 1, m - 2, h - 2))
    while len(jl):
        mid = (jl + jr) // 2
        hi = np.minimum(sr, mid - 1)
        n_cand = hi - sl + 1
        seg = np.repeat(np.arange(len(mid)), n_cand)
        first = np.concatenate([[0], np.cumsum(n_cand)[:-1]])
        cand = sl[seg] + np.arange(len(seg)) - first[seg]
        val = dp[cand] + costs.cost(cand, mid[seg])
        best = np.minimum.reduceat(val, first)
        hit = np.flatnonzero(val == best[seg])
        _, at = np.unique(seg[hit], return_index=True)
        opt = cand[hit[at]]
        new_dp[mid], split[mid] = best, opt
        left, right = jl <= mid - 1, mid + 1 <= jr
        jl, jr, sl, sr = (np.concatenate([a[left], b[right]]) for a, b in
                          ((jl, mid + 1), (mid - 1, jr), (sl, opt), (opt, sr)))
    return new_dp, split


def _optimal_centroids(values: np.ndarray, k: int, alpha: float) -> np.ndarray:
    """splat-transform's ``quantizeFinite``: bin the sorted values (``_weighted_bins``) and choose
    the k centroids of least weighted squared error by dynamic programming over the bins. The
    same arithmetic and the same first-best splits as its O(k h^2) loop, so the same codebook,
    found in O(k h log h)."""
    counts, centers, weights = _weighted_bins(values.astype(np.float64), alpha)
    h = len(counts)
    costs = _BinCosts(centers, weights)
    k = min(k, int((counts > 0).sum()))
    dp = costs.cost(np.full(h, -1), np.arange(h))  # dp[j]: least error of m centroids over bins 0 .. j
    splits = [None, None]
    for m in range(2, k + 1):
        dp, split = _next_centroid(dp, costs, m)
        splits.append(split)
    out, j = np.empty(k), h - 1
    for m in range(k, 0, -1):
        s = int(splits[m][j]) if m > 1 else -1
        out[m - 1] = costs.mean(s + 1, j)
        j = s
    return np.sort(out.astype(np.float32))


def quantize_1d(columns: list[np.ndarray], k: int = CODEBOOK_SIZE, alpha: float = 0.5
                ) -> tuple[np.ndarray, list[np.ndarray]]:
    """(codebook [k] float32 ascending, [uint8 labels per column]): one codebook for all the
    columns' (finite) values, each value labelled with its nearest entry (splat-transform's
    ``quantize1dColumns``; short codebooks are padded with their last entry)."""
    data = np.concatenate([np.asarray(c, np.float32).reshape(-1) for c in columns])
    values = np.sort(data)
    if float(values[-1]) - float(values[0]) < 1e-20:
        book = np.full(k, values[0], np.float32)
        return book, [np.zeros(len(c), np.uint8) for c in columns]
    cents = _optimal_centroids(values, k, alpha)
    book = np.concatenate([cents, np.full(k - len(cents), cents[-1], np.float32)])
    mids = (book[:-1].astype(np.float64) + book[1:]) * 0.5
    labels = np.searchsorted(mids, data.astype(np.float64), side="right").astype(np.uint8)
    out, pos = [], 0
    for c in columns:
        out.append(labels[pos:pos + len(c)])
        pos += len(c)
    return book, out


# --- SH palette: k-means ------------------------------------------------------------------

def _nearest(points: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Index of the nearest centroid of each point (squared distance; chunked products)."""
    c2 = (centroids * centroids).sum(axis=1)
    out = np.empty(len(points), np.int64)
    step = max(1, (1 << 22) // max(1, len(centroids)))
    for s in range(0, len(points), step):
        d = points[s:s + step] @ centroids.T
        d *= -2
        d += c2
        out[s:s + step] = d.argmin(axis=1)
    return out


def _seeds(points: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding: each next centroid a point drawn with probability proportional to its
    squared distance from the nearest centroid so far (a cluster is seldom left without one,
    which Lloyd's iterations would not repair)."""
    n = len(points)
    idx = [int(rng.integers(n))]
    d2 = ((points - points[idx[0]]) ** 2).sum(axis=1, dtype=np.float64)
    for _ in range(k - 1):
        cum = np.cumsum(d2)
        i = int(np.searchsorted(cum, rng.random() * cum[-1], side="right")) if cum[-1] > 0 else int(rng.integers(n))
        idx.append(min(i, n - 1))
        np.minimum(d2, ((points - points[idx[-1]]) ** 2).sum(axis=1, dtype=np.float64), out=d2)
    return points[idx].copy()


def _kmeans(points: np.ndarray, k: int, iterations: int, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means from k-means++ seeds; an emptied cluster moves to a random point. Stops
    early once no label changes (the iterations left would change nothing)."""
    n = len(points)
    centroids = _seeds(points, k, rng)
    labels = None
    for _ in range(iterations):
        previous, labels = labels, _nearest(points, centroids)
        if previous is not None and np.array_equal(previous, labels):
            return centroids, labels
        order = np.argsort(labels, kind="stable")
        starts = np.searchsorted(labels[order], np.arange(k))
        counts = np.diff(np.append(starts, n))
        full = counts > 0
        sums = np.add.reduceat(points[order].astype(np.float64), starts[full])
        centroids[full] = (sums / counts[full, None]).astype(np.float32)
        centroids[~full] = points[rng.integers(0, n, int((~full).sum()))]
    return centroids, _nearest(points, centroids)


def sh_palette(points: np.ndarray, k: int, iterations: int = KMEANS_ITERATIONS, seed: int = 0
               ) -> tuple[np.ndarray, np.ndarray]:
    """(centroids [M, D], labels [N]) with M <= k: every point its own entry when N <= k, else
    k-means, as a tree once k > KMEANS_LEAF: ceil(sqrt(k)) groups by k-means, then each group
    clustered on its own with a share of the other k - sqrt(k) entries proportional to its size
    (at least one). A flat k-means costs N k D per iteration; the tree about 2 N sqrt(k) D."""
    rng = np.random.default_rng(seed)
    points = np.ascontiguousarray(points, np.float32)

    def build(p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        if len(p) <= k:
            return p.copy(), np.arange(len(p))
        if k <= KMEANS_LEAF:
            return _kmeans(p, k, iterations, rng)
        groups = math.isqrt(k - 1) + 1
        _, group = _kmeans(p, groups, iterations, rng)
        sizes = np.bincount(group, minlength=groups)
        share = np.maximum(1, sizes * (k - groups) // len(p))  # sums to at most k
        cents, labels, base = [], np.empty(len(p), np.int64), 0
        for g in np.flatnonzero(sizes):
            idx = np.flatnonzero(group == g)
            c, lab = build(p[idx], int(share[g]))
            labels[idx] = lab + base
            cents.append(c)
            base += len(c)
        return np.concatenate(cents), labels

    return build(points, k)


# --- images -------------------------------------------------------------------------------

def _webp(pixels: np.ndarray, width: int, height: int) -> bytes:
    """Lossless WebP of ``pixels`` ([<= W H, 4] uint8, row-major; the rest of the image zero),
    with the settings of splat-transform's encoder (libwebp's WebPEncodeLosslessRGBA) but
    ``exact``: RGB under alpha 0 is kept (a Gaussian of opacity 0 keeps its colour)."""
    img = np.zeros((height * width, 4), np.uint8)
    img[:len(pixels)] = pixels
    buf = io.BytesIO()
    Image.fromarray(img.reshape(height, width, 4), "RGBA").save(buf, "WEBP", lossless=True, exact=True,
                                                                quality=WEBP_EFFORT, method=WEBP_METHOD)
    return buf.getvalue()


def _decode_webp(data: bytes, name: str, what: str) -> np.ndarray:
    """[H, W, 4] uint8 pixels of a WebP image; InputError naming the entry when it is not one."""
    try:
        with Image.open(io.BytesIO(data)) as img:
            if img.format != "WEBP":
                raise InputError(f"{what}: {name} is {img.format}, SOG images are WebP")
            return np.asarray(img.convert("RGBA"))
    except (UnidentifiedImageError, OSError, ValueError) as e:
        raise InputError(f"{what}: {name} is not a readable WebP image ({e})") from None


# --- writing ------------------------------------------------------------------------------

def _means_images(s: GaussianScene, width: int, height: int, opaque: np.ndarray) -> tuple[dict, dict]:
    """(images, meta section) of the positions: log-transformed, 16 bits over two images."""
    lm = log_transform(s.means.astype(np.float64))
    mins, maxs = lm.min(axis=0), lm.max(axis=0)
    span = maxs - mins
    q = np.round(65535 * np.divide(lm - mins, span, out=np.zeros_like(lm), where=span > 0)).astype(np.uint16)
    files = {"means_l.webp": _webp(np.hstack([(q & 0xFF).astype(np.uint8), opaque]), width, height),
             "means_u.webp": _webp(np.hstack([(q >> 8).astype(np.uint8), opaque]), width, height)}
    return files, {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]}


def _quats_image(s: GaussianScene, width: int, height: int) -> bytes:
    """Smallest three components at 8 bits, the largest one's index in alpha."""
    rot = s.rotations.astype(np.float64)
    rot /= np.linalg.norm(rot, axis=1, keepdims=True)
    largest = np.argmax(np.abs(rot), axis=1)
    rot *= np.where(np.take_along_axis(rot, largest[:, None], 1) < 0, -1.0, 1.0)
    others = np.array([[j for j in range(4) if j != i] for i in range(4)])[largest]
    small = np.take_along_axis(rot, others, 1)
    quats = np.clip(np.round(255 * (small * math.sqrt(2) * 0.5 + 0.5)), 0, 255).astype(np.uint8)
    return _webp(np.hstack([quats, (QUAT_TAG + largest).astype(np.uint8)[:, None]]), width, height)


def _sh_rest_images(s: GaussianScene, width: int, height: int, palette: int | None, iterations: int,
                    seed: int) -> tuple[dict, dict]:
    """(images, meta section 'shN') of the higher SH bands: a k-means palette of the
    channel-major (f_rest order) vectors, its entries' values through a 1D codebook."""
    n, degree = s.num_gaussians, s.sh_degree
    coeffs = SH_COEFFS[degree]
    rest = s.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * coeffs)
    centroids, labels = sh_palette(rest, palette or palette_size(n), iterations, seed)
    book, cols = quantize_1d([centroids[:, i] for i in range(3 * coeffs)])
    m = len(centroids)
    texel = np.stack([np.stack(cols[c * coeffs:(c + 1) * coeffs], axis=1) for c in range(3)], axis=2)
    cent_px = np.concatenate([texel, np.full((m, coeffs, 1), 255, np.uint8)], axis=2).reshape(m * coeffs, 4)
    lab = np.stack([labels & 0xFF, labels >> 8, np.zeros(n, np.int64), np.full(n, 255)], axis=1)
    files = {"shN_centroids.webp": _webp(cent_px, PALETTE_ROW * coeffs, math.ceil(m / PALETTE_ROW)),
             "shN_labels.webp": _webp(lab.astype(np.uint8), width, height)}
    return files, {"count": m, "bands": degree, "codebook": book.tolist(),
                   "files": ["shN_centroids.webp", "shN_labels.webp"]}


def encode_sog(scene: GaussianScene, iterations: int = KMEANS_ITERATIONS, palette: int | None = None,
               seed: int = 0) -> bytes:
    """The ``.sog`` bundle (zip of meta.json and WebP images, version 2) of ``scene``, its
    Gaussians in ``morton_order``. ``palette``: SH palette entries (default splat-transform's
    ``palette_size``, at most 65536); ``iterations`` and ``seed``: its k-means."""
    scene.validate("SOG writer")
    if palette is not None and not 1 <= palette <= 1 << 16:
        raise InputError(f"SOG writer: the SH palette must have 1 to 65536 entries (16-bit labels), got {palette}")
    n = scene.num_gaussians
    width, height = texture_size(n)
    if max(width, height) > MAX_TEXTURE_SIDE:
        raise InputError(f"SOG writer: {n} Gaussians need {width} x {height} images, beyond WebP's "
                         f"{MAX_TEXTURE_SIDE} pixels a side")
    s = scene.subset(morton_order(scene.means))
    opaque = np.full((n, 1), 255, np.uint8)
    files, means = _means_images(s, width, height, opaque)
    files["quats.webp"] = _quats_image(s, width, height)
    scale_book, scale_labels = quantize_1d([s.log_scales[:, i] for i in range(3)])
    files["scales.webp"] = _webp(np.stack(scale_labels + [opaque[:, 0]], axis=1), width, height)
    with np.errstate(over="ignore"):
        alpha = 1 / (1 + np.exp(-s.opacity.astype(np.float64)))
    alpha_u8 = np.clip(np.round(alpha * 255), 0, 255).astype(np.uint8)
    dc_book, dc_labels = quantize_1d([s.sh[:, 0, c] for c in range(3)])
    files["sh0.webp"] = _webp(np.stack(dc_labels + [alpha_u8], axis=1), width, height)
    meta = {"version": SOG_VERSION, "asset": {"generator": f"lghcc v{__version__}"}, "count": n, "means": means,
            "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"codebook": dc_book.tolist(), "files": ["sh0.webp"]}}
    if s.sh_degree > 0:
        sh_files, meta["shN"] = _sh_rest_images(s, width, height, palette, iterations, seed)
        files.update(sh_files)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for name, data in [*files.items(), ("meta.json", json.dumps(meta).encode())]:
            z.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), data)
    return buf.getvalue()


def write_sog(path: str | os.PathLike, scene: GaussianScene, iterations: int = KMEANS_ITERATIONS,
              palette: int | None = None, seed: int = 0) -> None:
    """Write ``scene`` as a ``.sog`` bundle, atomically (see ``encode_sog``)."""
    atomic_write_bytes(path, encode_sog(scene, iterations, palette, seed))


# --- reading ------------------------------------------------------------------------------

def _numbers(value, count: int | None, what: str, field: str) -> np.ndarray:
    """A JSON list (or number, count None) of finite numbers as float64; InputError otherwise."""
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        arr = None
    shape_ok = arr is not None and (arr.shape == () if count is None else
                                    arr.ndim == 1 and (arr.shape[0] == count if count > 0 else arr.shape[0] > 0))
    if not shape_ok:
        want = "a number" if count is None else f"{count} numbers" if count > 0 else "a list of numbers"
        raise InputError(f"{what}: meta.json field '{field}' must be {want}")
    if not np.isfinite(arr).all():
        raise InputError(f"{what}: meta.json field '{field}' contains NaN or Inf")
    return arr


def _lookup(book: np.ndarray, index: np.ndarray, what: str, field: str) -> np.ndarray:
    if index.max(initial=0) >= len(book):
        raise InputError(f"{what}: an index {int(index.max())} past the {len(book)} entries of '{field}'")
    return book[index]


class _SogMeta:
    """A parsed ``meta.json`` with the images it names: each part of the scene read and checked
    on its own (InputError naming ``what`` and the field)."""

    def __init__(self, meta: dict, load: Callable[[str], bytes], what: str):
        if not isinstance(meta, dict):
            raise InputError(f"{what}: meta.json is not a JSON object")
        self.version = meta.get("version")
        if self.version not in (None, SOG_VERSION):
            raise InputError(f"{what}: unsupported SOG version {self.version!r}; versions 1 (no 'version') and 2 "
                             "are read")
        self.meta, self.load, self.what = meta, load, what
        self.v2 = self.version == SOG_VERSION

    def section(self, key: str, nfiles: int) -> dict:
        sec = self.meta.get(key)
        files = sec.get("files") if isinstance(sec, dict) else None
        if not (isinstance(files, list) and len(files) >= nfiles and all(isinstance(f, str) for f in files)):
            raise InputError(f"{self.what}: meta.json needs '{key}' with {nfiles} image file name(s) in 'files'")
        return sec

    def image(self, name: str, count: int) -> np.ndarray:
        px = _decode_webp(self.load(name), name, self.what)
        if px.shape[0] * px.shape[1] < count:
            raise InputError(f"{self.what}: {name} has {px.shape[1]} x {px.shape[0]} pixels, fewer than the {count} "
                             "Gaussians")
        return px.reshape(-1, 4)[:count].astype(np.int64)

    def numbers(self, sec: dict, key: str, field: str, count: int | None) -> np.ndarray:
        return _numbers(sec.get(key), count, self.what, field)

    def count(self, means: dict) -> int:
        if self.v2:
            n = self.meta.get("count")
        else:
            shape = means.get("shape")
            n = shape[0] if isinstance(shape, list) and shape else None
        if not isinstance(n, int) or isinstance(n, bool) or n <= 0:
            where = "'count'" if self.v2 else "'means.shape[0]'"
            raise InputError(f"{self.what}: meta.json {where} must be a positive Gaussian count, got {n!r}")
        return n

    def positions(self, means: dict, n: int) -> np.ndarray:
        lo, hi = self.image(means["files"][0], n), self.image(means["files"][1], n)
        mins = self.numbers(means, "mins", "means.mins", 3)
        span = self.numbers(means, "maxs", "means.maxs", 3) - mins
        span[span == 0] = 1  # splat-transform's `|| 1`
        return inverse_log_transform(mins + span * (((hi[:, :3] << 8) | lo[:, :3]) / 65535))

    def rotations(self, quats: dict, n: int) -> np.ndarray:
        qp = self.image(quats["files"][0], n)
        tag = qp[:, 3] - QUAT_TAG
        if ((tag < 0) | (tag > 3)).any():
            bad = int(((tag < 0) | (tag > 3)).sum())
            raise InputError(f"{self.what}: {quats['files'][0]}: {bad} Gaussians have no valid largest-component "
                             f"tag (alpha {QUAT_TAG}-{QUAT_TAG + 3})")
        small = (qp[:, :3] / 255 * 2 - 1) / math.sqrt(2)
        rot = np.zeros((n, 4))
        others = np.array([[j for j in range(4) if j != i] for i in range(4)])[tag]
        np.put_along_axis(rot, others, small, 1)
        rot[np.arange(n), tag] = np.sqrt(np.maximum(0.0, 1 - (small * small).sum(axis=1)))
        return rot

    def scales_colour_opacity(self, scales: dict, sh0: dict, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(log scales, DC colour, opacity logit): codebooks in version 2, linear ranges in 1."""
        sp, cp = self.image(scales["files"][0], n), self.image(sh0["files"][0], n)
        if self.v2:
            log_scales = _lookup(self.numbers(scales, "codebook", "scales.codebook", 0), sp[:, :3], self.what,
                                 "scales.codebook")
            dc = _lookup(self.numbers(sh0, "codebook", "sh0.codebook", 0), cp[:, :3], self.what, "sh0.codebook")
            return log_scales, dc, alpha_logits(cp[:, 3])  # splat-transform's sigmoidInv clamp
        smin = self.numbers(scales, "mins", "scales.mins", 3)
        log_scales = smin + (self.numbers(scales, "maxs", "scales.maxs", 3) - smin) * (sp[:, :3] / 255)
        cmin = self.numbers(sh0, "mins", "sh0.mins", 4)
        lin = cmin + (self.numbers(sh0, "maxs", "sh0.maxs", 4) - cmin) * (cp / 255)
        return log_scales, lin[:, :3], lin[:, 3]

    def palette_degree(self, shn: dict, cent: np.ndarray) -> int:
        """The SH degree of the palette: 'bands' in version 2, the palette image's width in 1."""
        if self.v2:
            degree = shn.get("bands")
            if degree not in (1, 2, 3):
                raise InputError(f"{self.what}: meta.json 'shN.bands' must be 1, 2 or 3, got {degree!r}")
        else:
            degree = {PALETTE_ROW * c: d for d, c in enumerate(SH_COEFFS) if c}.get(cent.shape[1], 0)
        if degree == 0 or cent.shape[1] != PALETTE_ROW * SH_COEFFS[degree]:
            raise InputError(f"{self.what}: {shn['files'][0]} is {cent.shape[1]} pixels wide, SH palettes are 192, "
                             "512 or 960 (64 entries of 3, 8 or 15 coefficients)")
        return degree

    def sh_rest(self, n: int) -> tuple[int, np.ndarray | None]:
        """(SH degree, the higher coefficients [N, coeffs, 3] or None) from the palette 'shN'."""
        if not isinstance(self.meta.get("shN"), dict):
            return 0, None
        shn = self.section("shN", 2)
        cent = _decode_webp(self.load(shn["files"][0]), shn["files"][0], self.what)
        degree = self.palette_degree(shn, cent)
        coeffs = SH_COEFFS[degree]
        slots = cent.shape[0] * PALETTE_ROW
        count = shn.get("count") if self.v2 else slots
        if not isinstance(count, int) or isinstance(count, bool) or count <= 0:
            raise InputError(f"{self.what}: meta.json 'shN.count' must be a positive palette size, got {count!r}")
        lab = self.image(shn["files"][1], n)
        label = lab[:, 0] | (lab[:, 1] << 8)
        if label.max() >= min(count, slots):
            raise InputError(f"{self.what}: {shn['files'][1]}: palette index {int(label.max())} past the "
                             f"{min(count, slots)} palette entries")
        entries = cent.reshape(slots, coeffs, 4)[label, :, :3].astype(np.int64)  # [N, coeffs, channel]
        if self.v2:
            return degree, _lookup(self.numbers(shn, "codebook", "shN.codebook", 0), entries, self.what,
                                   "shN.codebook")
        lo = self.numbers(shn, "mins", "shN.mins", None)
        return degree, lo + (self.numbers(shn, "maxs", "shN.maxs", None) - lo) * (entries / 255)


def decode_sog(meta: dict, load: Callable[[str], bytes], what: str) -> GaussianScene:
    """The validated scene described by a parsed ``meta.json``; ``load(name)`` returns the bytes
    of an image it names (or raises InputError)."""
    m = _SogMeta(meta, load, what)
    means, quats = m.section("means", 2), m.section("quats", 1)
    scales, sh0 = m.section("scales", 1), m.section("sh0", 1)
    n = m.count(means)
    xyz = m.positions(means, n)
    rot = m.rotations(quats, n)
    log_scales, dc, opacity = m.scales_colour_opacity(scales, sh0, n)
    degree, rest = m.sh_rest(n)
    sh = np.zeros((n, (degree + 1) ** 2, 3))
    sh[:, 0] = dc
    if rest is not None:
        sh[:, 1:] = rest
    f32 = np.float32
    return GaussianScene(xyz.astype(f32), sh.astype(f32), np.asarray(opacity).astype(f32),
                         np.asarray(log_scales).astype(f32), rot.astype(f32)).validate(what)


def _parse_meta(data: bytes, what: str) -> dict:
    try:
        return json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{what}: meta.json is not valid JSON ({e})") from None


def read_sog(path: str | os.PathLike) -> GaussianScene:
    """Read a ``.sog`` bundle, or an unbundled ``meta.json`` with its images beside it."""
    p = Path(path)
    what = str(p)
    if not p.is_file():
        raise InputError(f"{what}: no such file")
    if not zipfile.is_zipfile(p):
        if p.suffix.lower() == ".sog":
            raise InputError(f"{what}: not a SOG bundle (not a zip archive)")
        folder = p.parent

        def load_file(name: str) -> bytes:
            f = folder / name
            try:
                return f.read_bytes()
            except OSError as e:
                raise InputError(f"{what}: cannot read the image {f} it names ({e.strerror})") from None

        try:
            text = p.read_bytes()
        except OSError as e:
            raise InputError(f"{what}: cannot read ({e.strerror})") from None
        return decode_sog(_parse_meta(text, what), load_file, what)
    try:
        with zipfile.ZipFile(p) as z:
            names = set(z.namelist())
            if "meta.json" not in names:
                raise InputError(f"{what}: the zip archive has no meta.json: not a SOG bundle")

            def load_entry(name: str) -> bytes:
                if name not in names:
                    raise InputError(f"{what}: the bundle has no {name}, which meta.json names")
                return z.read(name)

            return decode_sog(_parse_meta(z.read("meta.json"), what), load_entry, what)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, zlib.error) as e:
        raise InputError(f"{what}: corrupt zip archive ({e})") from None
