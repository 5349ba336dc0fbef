"""Where a scene is watched from (informative): an object is watched from around it; a scene that
surrounds free space (a room, a street, the background of a 360-degree capture) is watched from
inside that space, where it was captured. The encoder's views (gaussian_views.py) follow.

The scene's opaque Gaussians are binned into an occupancy grid over their robust box (1%..99%
quantiles, GRID_CELLS cells along its longest side). Free cells at least OPEN_CLEARANCE_CELLS from
every occupied one are places to look from, "roomy" ones at least ROOM_CLEARANCE_CELLS. From a
sample of them (those nearest the scene's dense middle, the median of the opaque Gaussians, and a
spread of the rest) RAY_DIRECTIONS rays are marched through the grid; a place's **enclosure** is
the share of rays that meet content before they leave the box. Inside a room every ray meets a
wall (1.0); beside an object, or in a hole through it, many escape (0.6-0.7 at best around the
shared objects). A hollow object (a closed shell) is enclosed inside too, but its inside is a thin
cavity: what decides is how much of the box is roomy free space enclosed on all sides (constants
below, with what they measured). Inside a closed box that holds nothing geometry cannot tell a room
from an object; the capture's cameras can (``--cameras``), and ``--views`` overrides.
The viewpoints (``eyes``) are VIEWPOINTS enclosed roomy places near the dense middle, spread apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...common.scene import GaussianScene
from ...render.views import fibonacci_sphere

GRID_CELLS = 32
RAY_DIRECTIONS = 64
# free cells at least this far (in cells) from content are places to look from; at least
# ROOM_CLEARANCE_CELLS (an eighth of the box's longest side), room for a viewer to stand
OPEN_CLEARANCE_CELLS = 3.0
ROOM_CLEARANCE_CELLS = 4.0
# a place whose rays meet the scene in at least this share of directions is enclosed
INSIDE_ENCLOSURE = 0.85
# The share of the box that is roomy enclosed free space: inside at INSIDE_SHARE or more, both at
# BOTH_SHARE or more, or where roomy free space is at least BOTH_ROOM of the box and its best place
# is enclosed in BOTH_ENCLOSURE of its directions (partly open: a street). Measured
# (tools/bench_views.py, tools/results/views.md): the procedural room 0.091, an empty box 0.26, a
# sphere shell 0.22; the shared objects 0 (donut, playbot) and 0.009 (the PlayCanvas logo, a hollow
# cushion, whose roomy inside is 1% of its box)
INSIDE_SHARE = 0.05
BOTH_SHARE = 0.02
BOTH_ROOM = 0.1
BOTH_ENCLOSURE = 0.75
# places nearest the middle whose enclosure is measured, and as many spread over the rest (the
# rays cost 2 x this x RAY_DIRECTIONS marches)
CANDIDATE_CELLS = 256
VIEWPOINTS = 3
# the most Gaussians the grid is built from (every k-th beyond)
MAX_GRID_POINTS = 400_000
# opacity (after the sigmoid) a Gaussian needs to count as content a viewer cannot see through
SOLID_OPACITY = 0.2


@dataclass(frozen=True)
class WatchedFrom:
    """How a scene is watched: ``kind`` orbit | inside | both, the viewpoints inside it (world
    coordinates, [P, 3]; empty for orbit), and why (for the log)."""
    kind: str
    eyes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    reason: str = ""


def solid_points(scene: GaussianScene) -> np.ndarray:
    """float64 [M, 3]: the means of the Gaussians of opacity >= SOLID_OPACITY (all when fewer than
    10 are), at most MAX_GRID_POINTS of them (every k-th)."""
    alpha = 1.0 / (1.0 + np.exp(-scene.opacity.astype(np.float64)))
    m = scene.means.astype(np.float64)
    if (alpha >= SOLID_OPACITY).sum() >= 10:
        m = m[alpha >= SOLID_OPACITY]
    stride = max(1, -(-m.shape[0] // MAX_GRID_POINTS))
    return m[::stride]


@dataclass(frozen=True)
class OccupancyGrid:
    lo: np.ndarray  # [3] world position of cell (0, 0, 0)'s corner
    cell: float  # cell size, world units
    occupied: np.ndarray  # bool [X, Y, Z]

    @classmethod
    def of(cls, points: np.ndarray, cells: int = GRID_CELLS) -> OccupancyGrid:
        """The occupancy of ``points``' robust box: a cell is occupied when it holds at least 2
        points and a twentieth of the median count of the non-empty cells (isolated floaters
        are not walls); points just outside the box count in its border cells."""
        lo, hi = np.quantile(points, 0.01, axis=0), np.quantile(points, 0.99, axis=0)
        cell = max(float((hi - lo).max()) / cells, 1e-9)
        dims = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
        ijk = np.floor((points - lo) / cell).astype(np.int64)
        near = np.all((ijk >= -1) & (ijk <= dims), axis=1)  # one cell of margin, clipped in
        ijk = np.clip(ijk[near], 0, dims - 1)
        counts = np.zeros(tuple(dims), np.int64)
        np.add.at(counts, tuple(ijk.T), 1)
        nonempty = counts[counts > 0]
        least = max(2.0, 0.05 * float(np.median(nonempty))) if nonempty.size else 2.0
        return cls(lo, cell, counts >= least)

    def centres(self, ijk: np.ndarray) -> np.ndarray:
        return self.lo + (ijk + 0.5) * self.cell

    def enclosure(self, starts: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """float64 [M]: for each start (world [M, 3]) the share of ``directions`` whose ray meets an
        occupied cell before it leaves the grid (marched in half-cell steps)."""
        dims = np.array(self.occupied.shape)
        hit = np.zeros((starts.shape[0], directions.shape[0]), bool)
        alive = np.ones_like(hit)
        s = (starts - self.lo) / self.cell  # in cells
        for t in np.arange(1, int(2 * np.linalg.norm(dims)) + 2) * 0.5:
            p = np.floor(s[:, None, :] + t * directions[None, :, :]).astype(np.int64)
            alive &= np.all((p >= 0) & (p < dims), axis=2)
            if not alive.any():
                break
            q = np.clip(p, 0, dims - 1)
            hit |= alive & self.occupied[q[..., 0], q[..., 1], q[..., 2]]
            alive &= ~hit
        return hit.mean(axis=1)


def spread(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of k of ``points`` spread apart (farthest-point order from the first)."""
    chosen = [0]
    d = np.linalg.norm(points - points[0], axis=1)
    while len(chosen) < min(k, points.shape[0]):
        j = int(np.argmax(d))
        if d[j] <= 0:
            break
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(points - points[j], axis=1))
    return np.array(chosen)


def _sampled(count: int, middle_first: np.ndarray) -> np.ndarray:
    """Indices into the free cells (``middle_first``: all of them, nearest the middle first): the
    CANDIDATE_CELLS nearest the middle and as many spread over the rest."""
    near = middle_first[:CANDIDATE_CELLS]
    rest = np.setdiff1d(np.arange(count), near)
    return np.concatenate([near, rest[::max(1, -(-rest.shape[0] // CANDIDATE_CELLS))]])


def _kind(share: float, room: float, best: float) -> str:
    partly = room >= BOTH_ROOM and best >= BOTH_ENCLOSURE  # a street, the open middle of a 360 capture
    return "inside" if share >= INSIDE_SHARE else "both" if share >= BOTH_SHARE or partly else "orbit"


def watched_from(scene: GaussianScene) -> WatchedFrom:
    """Whether ``scene`` is an object or surrounds free space, and where its viewers stand (module doc)."""
    from scipy.ndimage import distance_transform_edt

    points = solid_points(scene)
    grid = OccupancyGrid.of(points)
    clearance = distance_transform_edt(~grid.occupied) if grid.occupied.any() else np.zeros(grid.occupied.shape)
    free = np.argwhere(clearance >= OPEN_CLEARANCE_CELLS)
    if free.shape[0] == 0:
        return WatchedFrom("orbit", reason="no free space inside the scene's bounds: an object, views from around it")
    middle = np.median(points, axis=0)
    at = grid.centres(free)
    pick = _sampled(free.shape[0], np.argsort(np.linalg.norm(at - middle, axis=1), kind="stable"))
    at, roomy = at[pick], clearance[tuple(free[pick].T)] >= ROOM_CLEARANCE_CELLS
    enclosed = grid.enclosure(at, fibonacci_sphere(RAY_DIRECTIONS))
    # shares of the box, estimated on the sample's spread part (the part nearest the middle is denser)
    spread_part = np.arange(at.shape[0]) >= min(CANDIDATE_CELLS, free.shape[0])
    if not spread_part.any():
        spread_part[:] = True
    per_cell = free.shape[0] / clearance.size
    share = float(np.mean((roomy & (enclosed >= INSIDE_ENCLOSURE))[spread_part])) * per_cell
    room = float(np.mean(roomy[spread_part])) * per_cell
    best = float(enclosed[roomy].max(initial=0.0))
    kind = _kind(share, room, best)
    seen = (f"{100 * share:.1f}% of its box is roomy free space enclosed on all sides, {100 * room:.0f}% roomy free "
            f"space, at most {100 * best:.0f}% of directions from there meet the scene")
    if kind == "orbit":
        return WatchedFrom(kind, reason=f"an object ({seen}): views from around it")
    ok = roomy & (enclosed >= (INSIDE_ENCLOSURE if kind == "inside" else best - 0.05))
    good = np.flatnonzero(ok)
    good = good[np.argsort(np.linalg.norm(at[good] - middle, axis=1), kind="stable")]  # nearest the middle first
    eyes = at[good[spread(at[good][:4 * VIEWPOINTS], VIEWPOINTS)]]
    why, where = ("it surrounds free space", "from inside") if kind == "inside" else \
        ("unclear", "from around it and from inside")
    return WatchedFrom(kind, eyes, f"{why} ({seen}): views {where}")
