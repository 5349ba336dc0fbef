"""An explicit-Gaussian scene on its coding grid (informative): the grid's voxel size and origin,
the Gaussians snapped to it (each on its own voxel), their canonical rotations and the values
as the stream codes them. The settings search, the fit, RDOQ and the stream writer all use it.
"""

from __future__ import annotations

import numpy as np

from ...common.attributes import GaussianLayout
from ...common.errors import InputError
from ...common.geometry import COORD_MAX
from ...common.scene import GaussianScene
from ..stream.config import GaussianEncoderConfig
from ..stream.voxel_keys import VoxelBox

_RING_CACHE: dict[int, np.ndarray] = {}


OPACITY_LOGIT_LIMIT = 8.0


MAX_GRID_EXTENT = 1 << 30  # voxels per axis; beyond, the grid is made coarser (far floaters)


def typical_size(scene: GaussianScene, weights: np.ndarray | None = None) -> float:
    """The (weighted) median of exp(mean log scale) over the Gaussians: their typical size."""
    size = np.exp(scene.log_scales.astype(np.float64).mean(axis=1))
    w = np.ones_like(size) if weights is None else np.asarray(weights, np.float64)
    if not (w > 0).any():
        w = np.ones_like(size)
    order = np.argsort(size)
    cw = np.cumsum(w[order])
    return float(size[order][np.searchsorted(cw, cw[-1] / 2)])


def choose_grid(scene: GaussianScene, cfg: GaussianEncoderConfig,
                weights: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """(voxel size, origin) of the position grid (module doc)."""
    m = scene.means.astype(np.float64)
    lo, hi = m.min(axis=0), m.max(axis=0)
    extent = float((hi - lo).max())
    voxel = cfg.position_step * typical_size(scene, weights)
    if not np.isfinite(voxel) or voxel <= 0:
        voxel = extent / 4096 if extent > 0 else 1.0
    voxel = max(voxel, extent / MAX_GRID_EXTENT, np.finfo(np.float32).tiny)
    voxel = float(np.float32(voxel))
    if not voxel > 0:
        raise InputError(f"no usable position grid for this scene (extent {extent:g})")
    return voxel, lo.astype(np.float32)


def _ring(r: int) -> np.ndarray:
    """Integer offsets at Chebyshev distance r, nearest (Euclidean) first."""
    if r not in _RING_CACHE:
        g = np.arange(-r, r + 1)
        d = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        d = d[np.abs(d).max(axis=1) == r]
        _RING_CACHE[r] = d[np.lexsort((d[:, 2], d[:, 1], d[:, 0], (d * d).sum(axis=1)))]
    return _RING_CACHE[r]


def separate_duplicates(coords: np.ndarray, priority: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Give every point its own voxel: of the points sharing a voxel the one of highest
    ``priority`` stays, the others move to the nearest free voxel. -> (coords, moved)."""
    c = np.asarray(coords, np.int64).copy()
    n = c.shape[0]
    pr = np.zeros(n) if priority is None else np.asarray(priority, np.float64)
    order = np.lexsort((-pr, c[:, 2], c[:, 1], c[:, 0]))  # voxel, then priority (highest first)
    cs = c[order]
    dup = np.zeros(n, dtype=bool)
    dup[1:] = (cs[1:] == cs[:-1]).all(axis=1)
    movers = order[dup]
    if movers.size == 0:
        return c, 0
    taken = OccupiedVoxels(cs[~dup])
    for i in movers[np.argsort(-pr[movers], kind="stable")]:
        base = c[i]
        r = 1
        while True:
            for off in _ring(r):
                t = (int(base[0] + off[0]), int(base[1] + off[1]), int(base[2] + off[2]))
                if t not in taken:
                    break
            else:
                r += 1
                continue
            break
        taken.add(t)
        c[i] = t
    return c, int(movers.size)


class OccupiedVoxels:
    """A set of voxels, given first as int64 rows [K, 3] (distinct): those held as one key per
    voxel within their box (few points move), the voxels added later as tuples."""

    def __init__(self, rows: np.ndarray):
        self.box = VoxelBox(rows)
        self.keys = set(self.box.keys(rows).tolist()) if self.box.packable else set()
        self.added = set() if self.box.packable else set(map(tuple, rows.tolist()))

    def __contains__(self, t: tuple) -> bool:
        if t in self.added:
            return True
        key = self.box.key(t) if self.box.packable else None
        return key is not None and key in self.keys

    def add(self, t: tuple) -> None:
        self.added.add(t)


def snap_to_grid(scene: GaussianScene, voxel: float, origin: np.ndarray,
                 priority: np.ndarray | None = None) -> tuple[GaussianScene, int]:
    """The scene on the grid (means = origin + coords x voxel); -> (scene, Gaussians moved off a
    shared voxel)."""
    q = np.rint((scene.means.astype(np.float64) - origin.astype(np.float64)) / voxel)
    if np.abs(q).max(initial=0) > COORD_MAX - 2:
        raise InputError(f"positions span more than 2^31 voxels of {voxel:g}; use a larger position_step")
    coords, moved = separate_duplicates(q.astype(np.int64), priority)
    return GaussianScene.on_grid(coords, voxel, origin, scene.sh, scene.opacity, scene.log_scales,
                                 scene.rotations), moved


def canonical_rotations(rot: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0 (a zero quaternion becomes the identity)."""
    r = rot.astype(np.float64)
    norm = np.linalg.norm(r, axis=1, keepdims=True)
    r = np.where(norm > 0, r / np.maximum(norm, 1e-300), np.array([1.0, 0, 0, 0]))
    return np.where(r[:, :1] < 0, -r, r)


def coded_values(scene: GaussianScene, order: np.ndarray | None = None) -> np.ndarray:
    """float64 [N, M] (GaussianLayout; rows in ``order``, None: the scene's): the values the
    encoder codes, opacity logits clamped and rotations canonical. Filled column by column: one
    [N, M] array, no copy of it."""
    rows = slice(None) if order is None else order
    layout = GaussianLayout(scene.sh_degree)
    out = np.empty((scene.num_gaussians if order is None else len(order), layout.num_channels))
    out[:, :layout.sh_channels] = scene.sh.reshape(scene.num_gaussians, layout.sh_channels)[rows]
    out[:, layout.opacity_channel] = np.clip(scene.opacity[rows].astype(np.float64), -OPACITY_LOGIT_LIMIT,
                                             OPACITY_LOGIT_LIMIT)
    out[:, layout.scale_start:layout.rotation_start] = scene.log_scales[rows]
    out[:, layout.rotation_start:] = canonical_rotations(scene.rotations[rows])
    return out


