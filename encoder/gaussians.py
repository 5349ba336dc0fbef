"""Encoding explicit-Gaussian scenes (informative): every Gaussian of a 3DGS scene is coded
as a point of the geometry unit with its SH colour, opacity, scales and rotation, through the
same attribute units (per-channel prior, hierarchy, context models) as anchors, plus the
cross-channel prediction of Gaussian scenes (spec clauses 7.3.7, 11.6).

The encoder's choices, none of which the decoder needs to know:
- the position grid: voxel size = ``position_step`` x a typical Gaussian size (the median,
  weighted by contribution when it is known, of exp(mean log scale)), so the rule works the
  same on scenes in millimetres and in metres; origin = the minimum corner of the positions;
- Gaussians that round to one voxel: all but the most contributing one move to the nearest
  free voxel (one voxel away as a rule: the error grows from half a voxel to about one and a
  half), so none is lost for lack of room;
- rotations are normalized with w >= 0 (q and -q are one rotation), opacity logits clamped to
  [-OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT] (beyond, alpha differs from 0 or 1 by < 3.4e-4);
- quantization steps from the preset; cross-channel prediction where it saves bits.
"""

from __future__ import annotations

import time

import numpy as np
from ..app.progress import progress_bar

from ..common import attributes as attr
from ..common.container import DataUnit, UnitType, read_container, write_container
from ..common.errors import InputError
from ..common.geometry import COORD_MAX, encode_geometry, normative_order
from ..common.hashing import gaussian_scene_digest
from ..app.report import breakdown_of
from ..common.scene import GaussianScene
from ..common.units import MAX_ANCHORS, MAX_ATTRIBUTE_VALUES, DecodedSceneHashUnit, GaussianParameterSet
from .config import GaussianEncoderConfig
from .encode import EncodeResult, code_attributes, level_layout

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


_RING_CACHE: dict[int, np.ndarray] = {}


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
    taken = set(map(tuple, np.unique(c, axis=0).tolist()))
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


def gaussian_parameter_set(n: int, sh_degree: int, voxel: float, origin, cfg: GaussianEncoderConfig,
                           hierarchy: bool) -> GaussianParameterSet:
    gps = GaussianParameterSet(
        num_gaussians_minus1=n - 1, sh_degree=sh_degree, voxel_size=voxel, origin=[float(x) for x in origin],
        sh_dc_step=cfg.sh_dc_step, sh_band_step=[float(s) for s in cfg.sh_band_steps[:sh_degree]],
        opacity_step=cfg.opacity_step, scale_step=cfg.scale_step, rotation_step=cfg.rotation_step,
        hierarchy_enabled_flag=int(hierarchy), coarse_voxel_scale_minus1=cfg.coarse_voxel_scale - 1)
    return GaussianParameterSet.from_bytes(gps.to_bytes())  # exactly the values the decoder will see


def encode_gaussian_scene(scene: GaussianScene, cfg: GaussianEncoderConfig | None = None, *,
                          weights: np.ndarray | None = None, progress: bool = False,
                          measure_ideal: bool = False) -> EncodeResult:
    """Encode an explicit-Gaussian scene. A scene already on a grid (``coords`` set, e.g. from
    encoder/gaussian_fit.py) keeps it; otherwise the grid is chosen here. ``weights``: each
    Gaussian's contribution to the pictures, when known (grid size, who keeps a shared voxel)."""
    cfg = (cfg or GaussianEncoderConfig()).validate()
    scene.validate()
    stats: dict = {}
    t0 = time.perf_counter()
    if cfg.sh_degree is not None and cfg.sh_degree < scene.sh_degree:
        stats["sh_degree_dropped_from"] = scene.sh_degree
        scene = scene.with_sh_degree(cfg.sh_degree)
    n = scene.num_gaussians
    if n > MAX_ANCHORS:
        raise InputError(f"{n} Gaussians exceed the profile's limit of {MAX_ANCHORS}")
    bar = progress_bar(total=4, desc="encode", unit="step", disable=not progress, leave=False)
    bar.set_postfix_str("geometry")
    if scene.coords is None:
        voxel, origin = choose_grid(scene, cfg, weights)
        scene, moved = snap_to_grid(scene, voxel, origin, weights)
        stats["gaussians_moved_off_shared_voxels"] = moved
    elif np.unique(scene.coords, axis=0).shape[0] != n:
        scene, moved = snap_to_grid(scene, scene.voxel_size, scene.origin, weights)
        stats["gaussians_moved_off_shared_voxels"] = moved
    order = normative_order(scene.coords)
    coords = scene.coords[order]
    geometry_payload = encode_geometry(coords)
    stats["time_geometry_s"] = time.perf_counter() - t0
    bar.update()

    bar.set_postfix_str("quantization")
    levels, hier = level_layout(n, cfg, coords, stats)
    gps = gaussian_parameter_set(n, scene.sh_degree, scene.voxel_size, scene.origin, cfg, hier is not None)
    layout = attr.gaussian_layout_of(gps)
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise InputError(f"{n} Gaussians x {layout.num_channels} channels exceed the profile's limit")
    steps = layout.steps(gps)
    opacity = np.clip(scene.opacity.astype(np.float64), -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT)
    values = layout.join(GaussianScene(scene.means, scene.sh, opacity, scene.log_scales,
                                       canonical_rotations(scene.rotations)))[order]
    live = np.ones(values.shape, dtype=bool)
    bar.update()

    bar.set_postfix_str("attributes")
    t1 = time.perf_counter()
    coded = code_attributes(values, live, None, coords, levels, hier, layout, steps, cfg, stats, progress=progress,
                            measure_ideal=measure_ideal)
    stats["time_attributes_s"] = time.perf_counter() - t1
    bar.update()

    bar.set_postfix_str("hash")
    sh, op, log_scales, rotations = layout.split(coded.recon)
    decoded = GaussianScene.on_grid(coords, gps.voxel_size, gps.origin, sh, op, log_scales, rotations)
    digest = gaussian_scene_digest(decoded)
    units = [DataUnit(UnitType.GAUSSIAN_PARAMETER_SET, gps.to_bytes()), DataUnit(UnitType.GEOMETRY, geometry_payload)]
    if coded.context_payload is not None:
        units.append(DataUnit(UnitType.CONTEXT_MODEL, coded.context_payload))
    units += [DataUnit(UnitType.ATTRIBUTE, p) for p in coded.payloads]
    units.append(DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=digest).to_bytes()))
    data = write_container(units)
    bar.update()
    bar.close()
    stats["time_total_s"] = time.perf_counter() - t0
    return EncodeResult(data, breakdown_of(read_container(data), n, "Gaussian"), decoded, digest, stats)
