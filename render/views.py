"""Camera sets for looking at results (informative): ``orbit:N``, or the cameras of a
dataset of any layout (used by ``lghcc-dec --render``, ``lghcc.render_views`` and
tools/compare.py)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from .camera import Camera, load_capture_cameras, load_colmap, load_llff, load_nerf_synthetic, sparse_folder


def fibonacci_sphere(n: int, offset: float = 0.5) -> np.ndarray:
    """n unit vectors spread evenly on the sphere (golden spiral; ``offset`` shifts the spiral)."""
    i = np.arange(n, dtype=np.float64) + offset
    z = 1 - 2 * i / n
    r = np.sqrt(np.clip(1 - z * z, 0, 1))
    phi = i * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def orbit_cameras(positions: np.ndarray, n: int, *, width: int = 256, height: int = 256, fov_deg: float = 50.0,
                  elevation_deg: float = 20.0, up: tuple = (0.0, 0.0, 1.0)) -> list[Camera]:
    """n cameras on a circle around points (robust box: 1%..99% quantiles), ``elevation_deg``
    above the plane normal to ``up``, at a distance where the box's sphere fills the view."""
    if n < 1:
        raise InputError(f"orbit needs at least one camera, got {n}")
    p = np.asarray(positions, np.float64)
    lo, hi = np.quantile(p, 0.01, axis=0), np.quantile(p, 0.99, axis=0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    fov = min(fov_deg, fov_deg * height / width)
    dist = radius / math.sin(math.radians(fov) / 2) * 1.05
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    a = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    el = math.radians(elevation_deg)
    cams = []
    for i in range(n):
        t = 2 * math.pi * i / n
        d = math.cos(el) * (math.cos(t) * a + math.sin(t) * b) + math.sin(el) * u
        cams.append(Camera.look_at(centre + dist * d, centre, up=u, width=width, height=height, fov_x_deg=fov_deg,
                                   near=dist * 1e-3, far=dist * 10, name=f"orbit_{i:03d}"))
    return cams


def cameras_from_spec(spec: str, positions: np.ndarray, *, width: int = 256, height: int = 256,
                      scale: float = 1.0, split: str = "test") -> list[Camera]:
    """Cameras from a spec: ``orbit:N`` (around ``positions``, width x height); a dataset
    folder of any layout lghcc.render.datasets detects (NeRF-synthetic, COLMAP, Mip-NeRF 360,
    LLFF), its ``split`` (test, train or all); a NeRF-synthetic ``transforms_<split>.json``; a
    COLMAP sparse folder (cameras/images .bin or .txt: all its views); an LLFF
    ``poses_bounds.npy`` (all its views); the cameras a 3DGS capture comes with (all their
    views): an INRIA ``cameras.json``, a nerfstudio / instant-ngp ``transforms.json``, or a
    folder holding one (a trained INRIA model folder). File cameras are scaled by ``scale``."""
    from .datasets import dataset_cameras

    m = re.fullmatch(r"orbit:(\d+)", spec.strip())
    if m:
        return orbit_cameras(positions, int(m.group(1)), width=width, height=height)
    p = Path(spec)
    mm = re.fullmatch(r"transforms_(\w+)\.json", p.name)
    if p.is_file() and mm:
        cams = load_nerf_synthetic(p.parent, mm.group(1), load_images=False)
    elif p.is_file() and p.suffix == ".json":
        cams = load_capture_cameras(p)
    elif p.is_file() and p.name == "poses_bounds.npy":
        cams = load_llff(p.parent, load_images=False)
    elif p.is_dir() and (p / "transforms_train.json").is_file():
        cams = dataset_cameras(p, split)
    elif p.is_dir() and any((p / f"transforms_{s}.json").is_file() for s in ("test", "val")):
        split_ = next(s for s in ("test", "val") if (p / f"transforms_{s}.json").is_file())
        cams = load_nerf_synthetic(p, split_, load_images=False)
    elif p.is_dir() and sparse_folder(p) is not None and sparse_folder(p) == p:
        cams, _ = load_colmap(p)  # a bare sparse model folder: all its views
    elif p.is_dir() and (sparse_folder(p) is not None or (p / "poses_bounds.npy").is_file()):
        cams = dataset_cameras(p, split)
    elif p.is_dir() and any((p / f).is_file() for f in ("cameras.json", "transforms.json")):
        cams = load_capture_cameras(p)
    else:
        raise InputError(f"{spec}: not 'orbit:N', a dataset folder (transforms_train.json, sparse/0, "
                         "poses_bounds.npy), a transforms JSON, a COLMAP sparse folder, a poses_bounds.npy, or "
                         "a 3DGS capture's cameras.json (INRIA) or transforms.json (nerfstudio), or a folder "
                         "holding one")
    if not cams:
        raise InputError(f"{spec}: no cameras")
    return [c.scaled(scale) for c in cams] if scale != 1.0 else cams
