"""The views the encoder measures an explicit-Gaussian scene on (informative): orbit cameras on a
sphere around it, finer or magnified views where the orbit does not resolve its typical
Gaussian, and the pruning by contribution to them. The settings search and the fit share them.
"""

from __future__ import annotations

import math

import numpy as np

from ...common.scene import GaussianScene
from ...render.camera import Camera
from ...render.views import fibonacci_sphere
from .gaussian_grid import typical_size


def _robust_bounds(scene: GaussianScene) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre, radius, positions) of the scene's robust bounds: 1%..99% quantiles of the
    positions of the Gaussians with opacity >= 0.05 (all when fewer than 10 are)."""
    m = scene.means.astype(np.float64)
    op = 1 / (1 + np.exp(-scene.opacity.astype(np.float64)))
    if (op >= 0.05).sum() >= 10:
        m = m[op >= 0.05]
    lo, hi = np.quantile(m, 0.01, axis=0), np.quantile(m, 0.99, axis=0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6), m


def _orbit_distance(radius: float, fov_deg: float) -> float:
    return radius / math.sin(math.radians(fov_deg) / 2) * 1.05


def _sphere_camera(centre: np.ndarray, dist: float, direction: np.ndarray, aim: np.ndarray, resolution: int,
                   fov_deg: float, name: str) -> Camera:
    """A camera at ``dist`` from ``centre`` along ``direction``, looking at ``aim``."""
    up = (0.0, 0.0, 1.0) if abs(direction[2]) < 0.99 else (0.0, 1.0, 0.0)
    return Camera.look_at(centre + dist * direction, aim, up=up, width=resolution, height=resolution,
                          fov_x_deg=fov_deg, near=dist * 1e-3, far=dist * 10, name=name)


def fit_cameras(scene: GaussianScene, n: int, resolution: int, fov_deg: float = 50.0) -> list[Camera]:
    """n cameras on a sphere around the scene's robust bounds, each seeing the whole bounding sphere."""
    centre, radius, _ = _robust_bounds(scene)
    dist = _orbit_distance(radius, fov_deg)
    return [_sphere_camera(centre, dist, d, centre, resolution, fov_deg, f"fit_{j:03d}")
            for j, d in enumerate(fibonacci_sphere(n))]


# The most the views are magnified (module doc, "views that resolve the Gaussians").
MAX_MAGNIFICATION = 8.0


def typical_size_px(scene: GaussianScene, resolution: int, fov_deg: float = 50.0) -> float:
    """The size in pixels of the scene's typical Gaussian (the median of exp(mean log scale)) in
    ``fit_cameras(scene, n, resolution)`` at the scene's centre."""
    _, radius, _ = _robust_bounds(scene)
    focal_px = 0.5 * resolution / math.tan(math.radians(fov_deg) / 2)
    return typical_size(scene) * focal_px / _orbit_distance(radius, fov_deg)


def magnification(scene: GaussianScene, resolution: int, resolve_px: float, fov_deg: float = 50.0) -> float:
    """How much finer than ``fit_cameras(scene, n, resolution)`` the views must sample the scene
    for its typical Gaussian to span ``resolve_px`` pixels: 1 when it already does, at most
    MAX_MAGNIFICATION."""
    size_px = typical_size_px(scene, resolution, fov_deg)
    if not (size_px > 0 and math.isfinite(size_px)) or resolve_px <= 0:
        return 1.0
    return float(min(max(resolve_px / size_px, 1.0), MAX_MAGNIFICATION))


def crop_cameras(scene: GaussianScene, n: int, resolution: int, magnification: float,
                 fov_deg: float = 50.0, seed: int = 0) -> list[Camera]:
    """n magnified views: cameras on the orbit sphere (directions between those of fit_cameras)
    whose field of view is ``magnification`` times narrower, each aimed at a Gaussian drawn
    uniformly (fixed seed) from the opaque ones, so the crops sample where the scene is."""
    centre, radius, opaque = _robust_bounds(scene)
    dist = _orbit_distance(radius, fov_deg)
    crop_fov = 2 * math.degrees(math.atan(math.tan(math.radians(fov_deg) / 2) / magnification))
    aims = opaque[np.random.default_rng(seed).integers(0, opaque.shape[0], n)]
    return [_sphere_camera(centre, dist, d, aim, resolution, crop_fov, f"crop_{j:03d}")
            for j, (d, aim) in enumerate(zip(fibonacci_sphere(n, offset=0.25), aims))]


def resolving_views(scene: GaussianScene, n: int, resolution: int, resolve_px: float) -> list[Camera]:
    """The n orbit views, plus n magnified crops when the orbit views at ``resolution`` do not
    resolve the scene's typical Gaussian (``magnification`` > 1): what the fit and the settings
    search render. A scene whose Gaussians the orbit views resolve renders only those."""
    cams = fit_cameras(scene, n, resolution)
    m = magnification(scene, resolution, resolve_px)
    return cams + crop_cameras(scene, n, resolution, m) if m > 1 else cams


def prune_by_contribution(contrib: np.ndarray, share: float) -> np.ndarray:
    """bool [N]: keep all but the least contributing Gaussians whose contributions add up to at
    most ``share`` of the total."""
    keep = np.ones(contrib.shape[0], dtype=bool)
    total = float(contrib.sum())
    if share <= 0 or total <= 0:
        return keep
    order = np.argsort(contrib, kind="stable")
    cum = np.cumsum(contrib[order])
    drop = int(np.searchsorted(cum, share * total, side="right"))
    drop = min(drop, contrib.shape[0] - 1)  # never drop the whole scene
    keep[order[:drop]] = False
    return keep


