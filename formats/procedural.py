"""A deterministic procedural anchor scene (informative): anchors on surfaces (a torus,
a sphere and a ground plane, voxelized), spatially smooth features, scalings and
offsets, and render MLPs of the Scaffold-GS shapes. Used by the demo, tests,
conformance sources and benchmarks; the same seed gives the same scene.
"""

from __future__ import annotations

import sys

from typing import Callable

import numpy as np

from ..common.scene import DEFAULT_FEATURE_DIM, DEFAULT_NUM_OFFSETS, AnchorScene, GaussianScene, RenderMLP


def surface_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """n points on a torus (45%), a sphere (25%) and a ground plane (30%), in [-1, 1]^3."""
    nt, ns = int(0.45 * n), int(0.25 * n)
    npl = n - nt - ns
    u, v = rng.uniform(0, 2 * np.pi, (2, nt))
    torus = np.stack([(0.55 + 0.18 * np.cos(v)) * np.cos(u), (0.55 + 0.18 * np.cos(v)) * np.sin(u),
                      0.18 * np.sin(v) + 0.1], axis=1)
    d = rng.normal(size=(ns, 3))
    sphere = 0.25 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([0.0, 0.0, 0.2])
    plane = np.stack([rng.uniform(-1, 1, npl), rng.uniform(-1, 1, npl),
                      -0.35 + 0.03 * np.sin(3 * rng.uniform(-1, 1, npl))], axis=1)
    return np.concatenate([torus, sphere, plane])


def _smooth_field(rng: np.random.Generator, p: np.ndarray, channels: int, freq: float,
                  tick: Callable[[], None] = lambda: None) -> np.ndarray:
    """channels smooth functions of position: random Fourier features, unit variance.
    ``tick`` is called once per channel done (progress). The per-channel loop stays: computing
    several channels, or blocks of rows, at once is faster but not bit-identical (BLAS blocking),
    and the scenes of the conformance sources must not change."""
    nf = 8
    w = rng.normal(scale=freq, size=(channels, nf, 3))
    phase = rng.uniform(0, 2 * np.pi, (channels, nf))
    amp = rng.normal(size=(channels, nf)) / np.sqrt(nf / 2)
    out = np.empty((p.shape[0], channels))
    for c in range(channels):  # one channel at a time: memory O(N * nf), not O(N * C * nf)
        out[:, c] = np.sin(p @ w[c].T + phase[c]) @ amp[c]
        tick()
    return out


def _mlp(rng: np.random.Generator, dims: list[int], final: str) -> RenderMLP:
    ws = [(rng.normal(size=(o, i)) / np.sqrt(i)).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
    bs = [(0.05 * rng.normal(size=o)).astype(np.float32) for o in dims[1:]]
    return RenderMLP(ws, bs, ["relu"] * (len(ws) - 1) + [final])


def make_procedural_scene(num_anchors: int = 20000, seed: int = 0, feature_dim: int = DEFAULT_FEATURE_DIM,
                          num_offsets: int = DEFAULT_NUM_OFFSETS, with_mask: bool = False,
                          noise: float = 0.05, progress: bool = False) -> AnchorScene:
    """About ``num_anchors`` anchors (voxelization merges a few), voxel size chosen for the count.
    ``progress``: show a progress bar on stderr (one step per generated attribute channel); the
    scene is the same with or without it."""
    if num_anchors < 1:
        raise ValueError("num_anchors must be at least 1")
    from ..app.progress import progress_bar

    channels = 2 + feature_dim + 6 + 3 * num_offsets + (num_offsets if with_mask else 0)
    bar = progress_bar(total=channels, desc="procedural scene", unit="ch", disable=not progress, leave=False,
               file=sys.stderr)
    rng = np.random.default_rng(seed)
    # Surface area ~ 8.6 units^2: pick the voxel so that the surfaces hold ~num_anchors voxels.
    voxel = float(np.sqrt(8.6 / num_anchors))
    pts = surface_points(rng, 4 * num_anchors + 16)
    bar.update()
    coords = np.unique(np.floor(pts / voxel).astype(np.int64), axis=0)
    bar.update()
    if coords.shape[0] > num_anchors:
        coords = coords[np.sort(rng.choice(coords.shape[0], num_anchors, replace=False))]
    n = coords.shape[0]
    p = (coords + 0.5) * voxel
    feats = 0.8 * _smooth_field(rng, p, feature_dim, 3.0, bar.update) + noise * rng.normal(size=(n, feature_dim))
    scal = np.log(voxel) + 0.3 * _smooth_field(rng, p, 6, 2.0, bar.update) + noise * rng.normal(size=(n, 6))
    offs = (0.5 * _smooth_field(rng, p, 3 * num_offsets, 2.5, bar.update)
            + noise * rng.normal(size=(n, 3 * num_offsets)))
    mask = None
    if with_mask:
        mask = _smooth_field(rng, p, num_offsets, 2.0, bar.update) > -0.6
    bar.close()
    c = feature_dim
    mlps = {
        "opacity": _mlp(rng, [c + 4, c, num_offsets], "tanh"),
        "cov": _mlp(rng, [c + 4, c, 7 * num_offsets], "none"),
        "color": _mlp(rng, [c + 4, c, 3 * num_offsets], "sigmoid"),
    }
    return AnchorScene(
        coords=coords,
        voxel_size=voxel,
        origin=np.zeros(3, np.float32),
        features=feats.astype(np.float32),
        scalings=scal.astype(np.float32),
        offsets=offs.reshape(n, num_offsets, 3).astype(np.float32),
        offset_mask=mask,
        mlps=mlps,
    )


def smooth_gaussian_scene(n: int, degree: int, seed: int = 0) -> GaussianScene:
    """n Gaussians of SH degree ``degree`` on a surface whose attributes vary slowly (what
    neighbour prediction is for; used by the tests and tools/bench_sh_degree_decode.py)."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 1, n), rng.uniform(0, 1, n)
    means = np.stack([u, v, 0.2 * np.sin(6 * u)], 1).astype(np.float32)
    k = (degree + 1) ** 2
    sh = (np.sin(4 * u)[:, None, None] + 0.5 * np.cos(3 * v)[:, None, None] * np.ones((1, k, 3))
          + 0.05 * rng.normal(size=(n, k, 3))).astype(np.float32)
    sh[:, 1:] *= 0.1
    f = np.float32
    return GaussianScene(means, sh, (2 * np.cos(5 * v) + 0.1 * rng.normal(size=n)).astype(f),
                         (-4 + np.sin(3 * u)[:, None] + 0.1 * rng.normal(size=(n, 3))).astype(f),
                         np.column_stack([np.ones(n), 0.3 * np.sin(2 * u), 0.2 * v, 0.1 * rng.normal(size=n)]).astype(f))
