"""The views the encoder measures an explicit-Gaussian scene on (informative), and the pruning by
contribution to them. The settings search, the sensitivities, the pruning and the fit share them.

Where they look from (``SceneViews``, fixed once on the source scene):
- ``orbit``: cameras on a sphere around an object, looking at its centre;
- ``inside``: cameras at viewpoints in the free space a scene surrounds (a room, a street, a
  360-degree capture; free_space.py finds them), looking all round within MAX_PITCH_DEG of the
  horizon with a 90-degree field of view, as a viewer standing there sees it;
- ``both``: half of each, where it is unclear which;
- ``capture``: the capture's own cameras (``--cameras``), a spread subset at the views' pixel count,
  half of them as taken and half turned a little (``turned``).
Finer or magnified views are added where the views do not resolve the scene's typical Gaussian
(``magnification``): crops of the same views, as many as there are views.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ...common.errors import InputError
from ...common.scene import GaussianScene
from ...render.camera import Camera
from ...render.views import fibonacci_sphere
from ..stream.config import VIEW_KINDS
from .free_space import solid_points, spread, watched_from
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


def fit_cameras(scene: GaussianScene, n: int, resolution: int, fov_deg: float = 50.0,
                offset: float = 0.5) -> list[Camera]:
    """n cameras on a sphere around the scene's robust bounds, each seeing the whole bounding sphere
    (``offset``: of the spiral, fibonacci_sphere)."""
    centre, radius, _ = _robust_bounds(scene)
    dist = _orbit_distance(radius, fov_deg)
    return [_sphere_camera(centre, dist, d, centre, resolution, fov_deg, f"fit_{j:03d}")
            for j, d in enumerate(fibonacci_sphere(n, offset))]


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


def resolving_views(scene: GaussianScene, n: int, resolution: int, resolve_px: float,
                    offset: float = 0.5) -> list[Camera]:
    """The n orbit views, plus n magnified crops when the orbit views at ``resolution`` do not
    resolve the scene's typical Gaussian (``magnification`` > 1): what the fit and the settings
    search render. A scene whose Gaussians the orbit views resolve renders only those."""
    cams = fit_cameras(scene, n, resolution, offset=offset)
    m = magnification(scene, resolution, resolve_px)
    return cams + crop_cameras(scene, n, resolution, m) if m > 1 else cams


def _drop_least(key: np.ndarray, budget: float) -> np.ndarray:
    """bool [N]: keep all but the Gaussians of least ``key`` whose keys add up to at most ``budget``
    (never all of them)."""
    keep = np.ones(key.shape[0], dtype=bool)
    if budget <= 0:
        return keep
    order = np.argsort(key, kind="stable")
    drop = int(np.searchsorted(np.cumsum(key[order]), budget, side="right"))
    keep[order[:min(drop, key.shape[0] - 1)]] = False  # never drop the whole scene
    return keep


def prune_by_contribution(contrib: np.ndarray, share: float) -> np.ndarray:
    """bool [N]: keep all but the least contributing Gaussians whose contributions add up to at
    most ``share`` of the total."""
    total = float(contrib.sum())
    return _drop_least(contrib, share * total) if share > 0 and total > 0 else np.ones(contrib.shape[0], bool)


def prune_by_view_share(view_share: np.ndarray, share: float) -> np.ndarray:
    """bool [N]: keep all but the Gaussians of least largest share of one view (render/importance.py
    ``Contributions.view_share``) whose largest shares add up to at most ``share``. The pruned
    Gaussians' shares of any view add up to at most the sum of their largest shares, so no view
    loses more than ``share`` of what it shows (its compositing weight), however few views see
    them; ranked by their share of all the views together, the Gaussians that one viewpoint alone
    sees (a room's inside from its middle) would go first."""
    return _drop_least(view_share, share)


# The field of view of the views from inside, degrees: a viewer's, wide enough that the views
# around one viewpoint cover every direction.
INSIDE_FOV_DEG = 90.0
# A viewer standing in a room or a street looks within about this many degrees of the horizon (the
# views then still take in floor and ceiling at their edges); looking straight up or down at them
# counted as much as looking at the walls, and the room's landing views measured 3.5 dB above what
# a standing viewer's views did at the same steps.
MAX_PITCH_DEG = 35.0


def viewer_directions(n: int, up: np.ndarray, offset: float = 0.5) -> np.ndarray:
    """[n, 3] unit directions a standing viewer looks in: yaws by the golden angle, pitches evenly
    spread within MAX_PITCH_DEG of the plane normal to ``up`` (``offset`` shifts both, as
    fibonacci_sphere's does)."""
    up = up / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    i = np.arange(n, dtype=np.float64) + offset
    z = math.sin(math.radians(MAX_PITCH_DEG)) * (1 - 2 * i / n)
    yaw = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    return (r * np.cos(yaw))[:, None] * a + (r * np.sin(yaw))[:, None] * b + z[:, None] * up


def _inside_camera(eye: np.ndarray, direction: np.ndarray, up: np.ndarray, resolution: int, near: float,
                   name: str) -> Camera:
    """A viewer's view from ``eye`` along ``direction`` (within MAX_PITCH_DEG of the horizon of ``up``,
    so never along it), upright."""
    return Camera.look_at(eye, eye + direction, up=up, width=resolution, height=resolution, fov_x_deg=INSIDE_FOV_DEG,
                          near=near, far=near * 1e6, name=name)


# How far a capture camera is turned to stand for a viewer beside it (``turned``), degrees: a viewer
# where the capture stood looks around; with the capture's 18 views of the procedural room, its
# other views lost 9-13 dB where only the capture's own measured (the rest was pruned unseen).
TURN_YAW_DEG, TURN_PITCH_DEG = 30.0, 15.0


def turned(cam: Camera, j: int, name: str) -> Camera:
    """``cam`` turned about its own axes, yaw and pitch from the j-th point of a low-discrepancy
    sequence within +-TURN_YAW_DEG and +-TURN_PITCH_DEG (its centre and intrinsics kept)."""
    u, v = ((j + 0.5) * 0.6180339887498949) % 1.0, ((j + 0.5) * 0.7548776662466927) % 1.0
    yaw, pitch = math.radians(TURN_YAW_DEG * (2 * u - 1)), math.radians(TURN_PITCH_DEG * (2 * v - 1))
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    about_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])  # camera axes: x right, y down, z forward
    about_x = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    w2c = cam.world_to_camera.copy()
    w2c[:3, :] = (about_x @ about_y) @ w2c[:3, :]  # turns about the centre: -R^T t is unchanged
    return dataclasses.replace(cam, world_to_camera=w2c, name=name, image=None)


def cropped(cam: Camera, m: float, centre: tuple[float, float], name: str) -> Camera:
    """The window of ``cam``'s picture m times narrower around pixel ``centre``, at ``cam``'s pixel
    count: the same pose, focal lengths times m."""
    u, v = centre
    return dataclasses.replace(cam, fx=cam.fx * m, fy=cam.fy * m, cx=m * (cam.cx - u) + cam.width / 2,
                               cy=m * (cam.cy - v) + cam.height / 2, name=name, image=None)


def _crops(cams: list[Camera], m: float, seed: int = 0) -> list[Camera]:
    """One crop of each view, m times magnified around a pixel drawn at random (fixed seed) far
    enough inside that the window stays in the picture."""
    rng = np.random.default_rng(seed)
    out = []
    for j, cam in enumerate(cams):
        half_w, half_h = cam.width / (2 * m), cam.height / (2 * m)
        u, v = rng.uniform(half_w, cam.width - half_w), rng.uniform(half_h, cam.height - half_h)
        out.append(cropped(cam, m, (u, v), f"crop_{j:03d}"))
    return out


# The views' sets (SceneViews.view_set): the encoder's own (the fit, the sensitivities, the search),
# the landing's (the steps moved onto the target on larger views, gaussian_fit.py land_on_target) and
# the check's (the decoded scene's PSNR reported): none sees through another's cameras.
ENCODER_VIEWS, LANDING_VIEWS, CHECK_VIEWS = 0, 1, 2
# the offset of each set's spiral of directions (fibonacci_sphere), and how far its viewpoints inside
# move towards their middle
_SPIRAL = (0.5, 0.8, 0.2)
_TOWARDS_MIDDLE = (0.0, 1 / 3, 2 / 3)


@dataclass(frozen=True)
class SceneViews:
    """Where the encoder looks at a scene from (module doc), fixed once on the source scene so that
    the search, the sensitivities, the pruning, the fit and the trim measure from the same places.
    The orbit is placed around whichever scene it is asked for (the source, a sample, the fitted
    grid); the viewpoints inside and the capture's cameras stay where they are.
    ``view_set``: which of the sets of views of the same kind (ENCODER_VIEWS, LANDING_VIEWS,
    CHECK_VIEWS; ``held``)."""
    kind: str  # orbit | inside | both | capture
    eyes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [P, 3] viewpoints inside
    capture: tuple[Camera, ...] = ()  # the capture's cameras, in spread order (the first n spread best)
    depth: float = 1.0  # median distance from the viewpoints to the scene (inside, capture)
    size: float = 0.0  # the scene's typical Gaussian size (inside, capture; for the magnification)
    reason: str = ""
    view_set: int = ENCODER_VIEWS
    # up for the viewers inside: the axis along which the scene's robust box is thinnest (a room is
    # wider than high, a street longer); its sign does not matter to them
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def held(self, view_set: int) -> SceneViews:
        """The same kind of views, another set: other directions, other viewpoints inside (moved
        towards their middle), the capture's cameras turned (from the end of its spread order)."""
        return dataclasses.replace(self, view_set=view_set)

    def _inside(self, n: int, resolution: int) -> list[Camera]:
        eyes = self.eyes + _TOWARDS_MIDDLE[self.view_set] * (self.eyes.mean(axis=0) - self.eyes)
        near = max(self.depth * 1e-3, 1e-9)
        return [_inside_camera(eyes[j % eyes.shape[0]], d, self.up, resolution, near, f"inside{self.view_set}_{j:03d}")
                for j, d in enumerate(viewer_directions(n, self.up, _SPIRAL[self.view_set]))]

    def _capture(self, n: int, resolution: int) -> list[Camera]:
        """The encoder's set: the first half of n from the capture's cameras as they are (spread
        order), the rest turned from the cameras after them (``turned``); a held set: n cameras turned,
        from the end of the spread order, never the encoder's views even where the capture is small."""
        k, count = self.view_set, len(self.capture)
        as_taken = (n + 1) // 2 if k == ENCODER_VIEWS else 0
        start = as_taken if k == ENCODER_VIEWS else max(count - k * n, 0)
        cams = list(self.capture[:as_taken]) + [
            turned(self.capture[(start + j) % count], k * n + j, f"turned{k}_{j:03d}") for j in range(n - as_taken)]
        return [c.scaled(resolution / math.sqrt(c.width * c.height)) for c in cams]

    def _other(self, n: int, resolution: int) -> list[Camera]:
        """n whole views of the kind that is not the orbit (inside, or the capture's)."""
        return self._capture(n, resolution) if self.kind == "capture" else self._inside(n, resolution)

    def _split(self, n: int) -> tuple[int, int]:
        """(orbit views, views of the other kind) of n."""
        if self.kind == "both":
            return (n + 1) // 2, n // 2
        return (n, 0) if self.kind == "orbit" else (0, n)

    def magnification(self, scene: GaussianScene, resolution: int, resolve_px: float) -> float:
        """How much finer than the whole views at ``resolution`` the views must sample the scene for
        its typical Gaussian to span ``resolve_px`` pixels (1 to MAX_MAGNIFICATION)."""
        if self.kind == "orbit":
            return magnification(scene, resolution, resolve_px)
        focal = 0.5 * resolution / math.tan(math.radians(INSIDE_FOV_DEG) / 2)
        if self.kind == "capture":
            c = self.capture[0]
            focal = c.fx * resolution / math.sqrt(c.width * c.height)
        size_px = self.size * focal / max(self.depth, 1e-12)
        if not (size_px > 0 and math.isfinite(size_px)) or resolve_px <= 0:
            return 1.0
        return float(min(max(resolve_px / size_px, 1.0), MAX_MAGNIFICATION))

    def whole_views(self, scene: GaussianScene, n: int, resolution: int) -> list[Camera]:
        """n whole views at ``resolution``."""
        around, other = self._split(n)
        cams = fit_cameras(scene, around, resolution, offset=_SPIRAL[self.view_set]) if around else []
        return cams + (self._other(other, resolution) if other else [])

    def cameras(self, scene: GaussianScene, n: int, resolution: int, resolve_px: float) -> list[Camera]:
        """The views the fit, the sensitivities and the search render: n whole views, plus a
        magnified crop of each where they do not resolve the scene's typical Gaussian."""
        around, other = self._split(n)
        cams = resolving_views(scene, around, resolution, resolve_px, _SPIRAL[self.view_set]) if around else []
        if not other:
            return cams
        whole = self._other(other, resolution)
        m = self.magnification(scene, resolution, resolve_px)
        return cams + whole + (_crops(whole, m) if m > 1 else [])

    def contribution_cameras(self, scene: GaussianScene, n: int, resolution: int,
                             resolve_px: float) -> list[Camera]:
        """The whole views the contributions are measured on, magnified to resolve the Gaussians
        (crops would favour the Gaussians they happen to show)."""
        around, other = self._split(n)
        cams = []
        if around:
            cams = fit_cameras(scene, around, round(resolution * magnification(scene, resolution, resolve_px)),
                               offset=_SPIRAL[self.view_set])
        if other:
            cams += self._other(other, round(resolution * self.magnification(scene, resolution, resolve_px)))
        return cams


ORBIT = SceneViews("orbit", reason="views from around it")


# The capture cameras whose distances to the scene give its depth (a capture may hold thousands)
DEPTH_VIEWPOINTS = 16


def _median_depth(points: np.ndarray, eyes: np.ndarray) -> float:
    d = np.linalg.norm(points[:, None, :] - eyes[None, :, :], axis=2)
    return float(np.median(d)) if d.size else 1.0


def scene_views(scene: GaussianScene, kind: str = "auto", capture: list[Camera] | None = None) -> SceneViews:
    """Where to look at ``scene`` from: the capture's cameras when given (a spread subset of them
    first), else ``kind``: orbit, inside, both, or auto (free_space.py decides)."""
    if kind not in VIEW_KINDS:
        raise InputError(f"views must be one of {', '.join(VIEW_KINDS)}, got {kind!r}")
    points = solid_points(scene)[::16]
    if capture:
        centres = np.array([c.center for c in capture])
        order = spread(centres, len(capture))
        order = np.concatenate([order, np.setdiff1d(np.arange(len(capture)), order)])  # coincident cameras last
        cams = tuple(capture[i] for i in order)
        depth = _median_depth(points, centres[order[:DEPTH_VIEWPOINTS]])
        return SceneViews("capture", capture=cams, depth=depth, size=typical_size(scene),
                          reason=f"the capture's {len(capture)} cameras")
    found = watched_from(scene)
    if kind == "auto":
        kind, reason = found.kind, found.reason
    else:
        reason = f"views {kind} as asked (by itself: {found.kind}, {found.reason})"
    if kind == "orbit":
        return dataclasses.replace(ORBIT, reason=reason)
    eyes = found.eyes if found.eyes.shape[0] else np.median(points, axis=0)[None, :]
    extent = np.quantile(points, 0.99, axis=0) - np.quantile(points, 0.01, axis=0)
    return SceneViews(kind, eyes=eyes, depth=_median_depth(points, eyes), size=typical_size(scene), reason=reason,
                      up=np.eye(3)[int(np.argmin(extent))])
