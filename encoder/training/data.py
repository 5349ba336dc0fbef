"""The training data beyond the images: the camera extent, the initial points (random in the
region every training camera sees, on random training rays, or the SfM points), the default
voxel size and the anchors' initial scale (mean distance to the nearest anchors). The datasets
themselves (layouts, cameras, images) are lghcc.render.datasets."""

from __future__ import annotations

import numpy as np

from ...common.errors import InputError
from ...render.datasets import Dataset
from .config import TrainConfig


def camera_extent(cams: list) -> float:
    """3DGS's ``cameras_extent``: 1.1 x the largest distance of a camera centre from their mean."""
    c = np.stack([cam.center for cam in cams])
    return 1.1 * float(np.linalg.norm(c - c.mean(0), axis=1).max())


def _in_frusta_fraction(points: np.ndarray, cams: list) -> np.ndarray:
    seen = np.zeros(len(points))
    for cam in cams:
        uv, z = cam.project(points)
        seen += (z > cam.near) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return seen / len(cams)


def init_points(ds: Dataset, cfg: TrainConfig, rng: np.random.Generator) -> np.ndarray:
    """Initial points [P, 3] float64 (see the module doc)."""
    mode = cfg.init
    if mode == "auto":
        mode = "sfm" if ds.sfm_points is not None else "random"
    if mode == "sfm":
        if ds.sfm_points is None:
            raise InputError(f"{cfg.data}: --init sfm needs a COLMAP model with points3D (sparse/0/points3D.bin or "
                             ".txt); this dataset has none")
        return np.asarray(ds.sfm_points, np.float64)
    if mode != "random":
        raise InputError(f"unknown --init {cfg.init!r} (auto, random or sfm)")
    if ds.kind == "nerf_synthetic":
        # rejection sampling in the bounding box of the camera centres: keep points that every
        # training camera sees (the intersection of the view frusta)
        centres = np.stack([c.center for c in ds.train])
        lo, hi = centres.min(0), centres.max(0)
        got: list[np.ndarray] = []
        total, tries = 0, 0
        while total < cfg.init_points and tries < 200:
            cand = rng.uniform(lo, hi, size=(max(4 * cfg.init_points, 10000), 3))
            ok = cand[_in_frusta_fraction(cand, ds.train) >= 1.0]
            got.append(ok)
            total += len(ok)
            tries += 1
        pts = np.concatenate(got)[: cfg.init_points]
        if len(pts) == 0:
            raise InputError(f"{cfg.data}: the training cameras' view frusta have no common region; "
                             "use a dataset with SfM points (--init sfm)")
        return pts
    # forward-facing / general scenes: random points on random training rays, uniform in 1/depth
    out = []
    idx = rng.integers(0, len(ds.train), cfg.init_points)
    for i in np.unique(idx):
        cam = ds.train[i]
        n = int((idx == i).sum())
        u = rng.uniform(0, cam.width, n)
        v = rng.uniform(0, cam.height, n)
        far = min(cam.far, cam.near * 1e3)
        inv = rng.uniform(1.0 / far, 1.0 / cam.near, n)
        z = 1.0 / inv
        pc = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], 1)
        out.append((pc - cam.translation) @ cam.rotation)
    return np.concatenate(out)


def default_voxel_size(points: np.ndarray, voxels_per_extent: float) -> float:
    lo, hi = np.percentile(points, [1, 99], axis=0)
    ext = float((hi - lo).max())
    if not np.isfinite(ext) or ext <= 0:
        raise InputError("cannot derive a voxel size from the initial points (all at one place); give --voxel-size")
    return ext / voxels_per_extent


def knn_mean_dist(points: np.ndarray, k: int = 3) -> np.ndarray:
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return np.ones(len(points))
    kk = min(k + 1, len(points))
    d, _ = cKDTree(points).query(points, k=kk)
    return np.maximum(np.sqrt((d[:, 1:] ** 2).mean(1)), 1e-7)
