"""Scenes of any size from real content, for tools/bench_scale.py (deterministic; no randomness).

The sources, in this order (files under ../shared/data): donut (45,624 Gaussians, SH 0),
playbot lod3 (31,000, SH 2) and the PlayCanvas logo (307,128, SH 0); one cycle is 383,752.
Each source is first scaled uniformly so that the largest side of its bounding box is 1
(means x s, log scales + log s: the same picture, in common units; the three differ 15x in
size) and cut to SH degree 0 (the lowest of the three: playbot's bands are dropped). The copies
go in that order, cycling, onto a square grid of cells in the x-z plane, row by row: cell side
``CELL`` (1.25) and each copy's bounding box centred in its cell, so that any two copies are at
least ``CELL - 1`` = 0.25 apart and none overlap. A scene of N Gaussians holds the whole copies
whose running total stays within N and, of the next copy, its N - total Gaussians of lowest x (a
slab of it: a spatial subset, ties broken by the Gaussian's index). So

    100k = donut + playbot + a 23,376-Gaussian slab of the logo
    300k = donut + playbot + a 223,376-Gaussian slab of the logo
    1M   = 2 cycles + donut + playbot + a 155,872-Gaussian slab of the logo
    3M   = 7 cycles + donut + playbot + a 237,112-Gaussian slab of the logo

Nothing is rotated (the donut lies in its own x-y plane, the others stand along -y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SOURCES = (("donut", "donut/donut.ply"), ("playbot-lod3", "playbot/playbot_lod3_31k.ply"),
           ("playcanvas-logo", "playcanvas-logo/playcanvas_logo_307k.ply"))
CELL = 1.25  # each copy fits a unit box; 0.25 between neighbours


@dataclass
class Piece:
    """One copy in a built scene: its source, the Gaussians kept, its grid cell and its box."""
    source: str
    count: int
    whole: bool
    cell: tuple[int, int]
    lo: np.ndarray
    hi: np.ndarray


def normalized(scene):
    """The scene scaled to a unit bounding box (largest side 1), centred at the origin, SH 0."""
    from lghcc.common.scene import GaussianScene

    m = scene.means.astype(np.float64)
    lo, hi = m.min(axis=0), m.max(axis=0)
    s = 1.0 / max(float((hi - lo).max()), 1e-30)
    means = ((m - (lo + hi) / 2) * s).astype(np.float32)
    g = GaussianScene(means, scene.sh, scene.opacity, (scene.log_scales + np.float32(math.log(s))).astype(np.float32),
                      scene.rotations)
    return g.with_sh_degree(0) if g.sh_degree > 0 else g


def load_sources(data_root: Path) -> list:
    return [(name, normalized(read_source(data_root, name))) for name, _ in SOURCES]


def read_source(data_root: Path, name: str):
    """The source ``name`` of SOURCES as read, at its own SH degree (with_sh3_content takes playbot so)."""
    from lghcc.formats.ply3dgs import read_3dgs_ply

    return read_3dgs_ply(Path(data_root) / dict(SOURCES)[name])


def plan(n: int, sizes: list[int]) -> list[tuple[int, int]]:
    """[(source index, Gaussians taken)] of a scene of ``n`` from sources of ``sizes`` (module doc)."""
    if n < 1:
        raise ValueError(f"a scene needs at least one Gaussian, got {n}")
    out, total, i = [], 0, 0
    while total < n:
        k = i % len(sizes)
        take = min(sizes[k], n - total)
        out.append((k, take))
        total += take
        i += 1
    return out


def slab(means: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` Gaussians of lowest x (ties by index), in index order."""
    order = np.lexsort((np.arange(means.shape[0]), means[:, 0]))
    return np.sort(order[:k])


def build_scene(n: int, sources: list) -> tuple:
    """(GaussianScene of ``n`` Gaussians, [Piece]) from ``load_sources``' scenes (module doc)."""
    from lghcc.common.scene import GaussianScene

    steps = plan(n, [s.num_gaussians for _, s in sources])
    cols = max(1, math.ceil(math.sqrt(len(steps))))
    parts, pieces = [], []
    for i, (k, take) in enumerate(steps):
        name, src = sources[k]
        part = src if take == src.num_gaussians else src.subset(slab(src.means, take))
        cell = (i % cols, i // cols)
        shift = np.array([cell[0] * CELL, 0.0, cell[1] * CELL], np.float32)
        means = part.means + shift
        parts.append(GaussianScene(means, part.sh, part.opacity, part.log_scales, part.rotations))
        pieces.append(Piece(name, take, take == src.num_gaussians, cell, means.min(axis=0), means.max(axis=0)))
    scene = GaussianScene(*(np.concatenate([getattr(p, a) for p in parts])
                            for a in ("means", "sh", "opacity", "log_scales", "rotations")))
    return scene, pieces


def describe(pieces: list[Piece]) -> str:
    """How a scene was built, in words (whole copies counted by source, the slab named)."""
    whole: dict[str, int] = {}
    for p in pieces:
        if p.whole:
            whole[p.source] = whole.get(p.source, 0) + 1
    text = ", ".join(f"{c} x {s}" for s, c in whole.items())
    last = pieces[-1]
    if not last.whole:
        text += (", " if text else "") + f"a {last.count:,}-Gaussian slab (lowest x) of {last.source}"
    return text


def with_sh3_content(scene, playbot, block: int = 1 << 20):
    """``scene`` (a built scene, any SH degree) at SH degree 3 with real SH content laid out in
    space as in a capture (issue 53's scenes): the DC kept; each Gaussian takes, at its position in
    its grid cell, bands 1 and 2 of the nearest Gaussian of ``playbot`` (playbot lod3, SH 2, scaled
    to a unit box as the copies are: a playbot copy gets its own bands back) and band 3 as half of
    coefficients 2-8 of the second nearest (values of the size of real higher bands, not zeros,
    which code in almost nothing, and not a function of the Gaussian's own bands, which a
    transform would code for free). Neighbours thus share colour as in real scenes; SH assigned
    by index would be noise in space, which no capture is. Deterministic; by blocks of ``block``."""
    from scipy.spatial import cKDTree

    from lghcc.common.scene import GaussianScene

    m = playbot.means.astype(np.float64)
    lo, hi = m.min(axis=0), m.max(axis=0)
    tree = cKDTree((m - (lo + hi) / 2) / max(float((hi - lo).max()), 1e-30))
    rest = playbot.with_sh_degree(2).sh[:, 1:9]  # bands 1-2: [k, 8, 3]
    n = scene.num_gaussians
    sh = np.zeros((n, 16, 3), np.float32)
    sh[:, :1] = scene.sh[:, :1]
    for a in range(0, n, block):
        local = scene.means[a:a + block].astype(np.float64)
        local[:, [0, 2]] -= np.round(local[:, [0, 2]] / CELL) * CELL  # the position in its cell
        _, near = tree.query(local, k=2)
        sh[a:a + block, 1:9] = rest[near[:, 0]]
        sh[a:a + block, 9:16] = np.float32(0.5) * rest[near[:, 1]][:, 1:8]
    return GaussianScene(scene.means, sh, scene.opacity, scene.log_scales, scene.rotations)
