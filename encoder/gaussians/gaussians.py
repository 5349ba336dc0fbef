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
- rotations are normalized with w >= 0 (q and -q are one rotation; RDOQ may write a Gaussian
  in another of its equivalent ways, encoder/gaussians/rdoq.py), opacity logits clamped to
  [-OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT] (beyond, alpha differs from 0 or 1 by < 3.4e-4);
- quantization steps from the preset; cross-channel prediction where it saves bits.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from ...app.progress import progress_bar

from ...common import attributes as attr
from ...common.container import DataUnit, UnitType, read_container
from ...common.errors import InputError
from ...common.hashing import gaussian_scene_digest
from ...app.report import breakdown_of
from ...common.neighbour_prediction import neighbour_graph
from ...common.scene import GaussianScene
from ...common.units import MAX_ATTRIBUTE_VALUES, GaussianParameterSet, RotationLengthUnit, StepAdjustUnit
from ..stream.config import GaussianEncoderConfig
from ..stream.level_coding import check_predicted_magnitude, narrowest_integers
from ..stream.encode import (AttributeInput, CodedAttributes, EncodeResult, GeometryCoding, LevelLayout, check_point_count,
                     code_attributes, code_geometry, level_layout, neighbour_prediction_wanted, stage, stream_tiles,
                     write_stream)
from .gaussian_grid import choose_grid, coded_values, snap_to_grid
from ..stream.stats import EncodeStats

# Each stage's share (percent) of the coding's time, so that the encoder's bar, and its estimate
# of the time left, advance as the time goes: a tiled scene at low's steps without the render-based
# preparation, 100k and 300k Gaussians, 2 worker processes (tools/results/scale.md: 8/8/48/35 and
# 7/14/43/36 percent of the stages' time)
STAGE_SHARES = {"geometry": 8, "quantization": 11, "attributes": 45, "tiles and hash": 36}




def gaussian_parameter_set(n: int, sh_degree: int, voxel: float, origin, cfg: GaussianEncoderConfig,
                           hierarchy: bool, tile_scale: int = 0) -> GaussianParameterSet:
    gps = GaussianParameterSet(
        num_gaussians_minus1=n - 1, sh_degree=sh_degree, voxel_size=voxel, origin=[float(x) for x in origin],
        sh_dc_step=cfg.sh_dc_step, sh_band_step=[float(s) for s in cfg.sh_band_steps[:sh_degree]],
        opacity_step=cfg.opacity_step, scale_step=cfg.scale_step, rotation_step=cfg.rotation_step,
        hierarchy_enabled_flag=int(hierarchy), coarse_voxel_scale_minus1=cfg.coarse_voxel_scale - 1,
        tiles_enabled_flag=int(tile_scale > 0), tile_scale_minus1=max(tile_scale - 1, 0))
    return GaussianParameterSet.from_bytes(gps.to_bytes())  # exactly the values the decoder will see


def with_coded_sh_degree(scene: GaussianScene, cfg: GaussianEncoderConfig, stats: EncodeStats) -> GaussianScene:
    """The scene at the configured SH degree when that is lower than its own."""
    if cfg.sh_degree is not None and cfg.sh_degree < scene.sh_degree:
        stats.sh_degree_dropped_from = scene.sh_degree
        return scene.with_sh_degree(cfg.sh_degree)
    return scene


def without_invisible(scene: GaussianScene, cfg: GaussianEncoderConfig) -> tuple[GaussianScene, int]:
    """The scene less its Gaussians of opacity below ``cfg.min_opacity`` (after the sigmoid; the
    most opaque one stays if none reaches it: a stream holds at least one) -> (scene, dropped)."""
    if cfg.min_opacity <= 0:
        return scene, 0
    alpha = 1.0 / (1.0 + np.exp(-scene.opacity.astype(np.float64)))
    keep = alpha >= cfg.min_opacity
    if not keep.any():
        keep[int(np.argmax(alpha))] = True
    return (scene, 0) if keep.all() else (scene.subset(keep), int((~keep).sum()))


def on_own_voxels(scene: GaussianScene, cfg: GaussianEncoderConfig, weights: np.ndarray | None,
                  stats: EncodeStats) -> GaussianScene:
    """The scene on a position grid, every Gaussian in its own voxel: a scene already on a grid
    keeps it (Gaussians sharing a voxel are moved apart), otherwise the grid is chosen here."""
    if scene.coords is None:
        voxel, origin = choose_grid(scene, cfg, weights)
        scene, stats.gaussians_moved_off_shared_voxels = snap_to_grid(scene, voxel, origin, weights)
    elif np.unique(scene.coords, axis=0).shape[0] != scene.num_gaussians:
        scene, stats.gaussians_moved_off_shared_voxels = snap_to_grid(scene, scene.voxel_size, scene.origin, weights)
    return scene


def gaussian_attribute_input(scene: GaussianScene, geometry: GeometryCoding, levels: LevelLayout,
                             cfg: GaussianEncoderConfig) -> AttributeInput:
    """The parameter set, and the SH, opacity (clamped), scales and rotations (canonical) as
    attribute values."""
    n = scene.num_gaussians
    gps = gaussian_parameter_set(n, scene.sh_degree, scene.voxel_size, scene.origin, cfg, levels.hier is not None,
                                 levels.tile_scale)
    layout = attr.gaussian_layout_of(gps, 0 if cfg.rotation_length else -1)
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise InputError(f"{n} Gaussians x {layout.num_channels} channels exceed the profile's limit")
    steps = layout.steps(gps)
    values = coded_values(scene, geometry.order)
    if cfg.sh_transform and layout.sh_degree > 0:
        gps, layout, steps = sh_transformed(values, gps, layout, steps, cfg, levels)
    # every value live (Gaussians have no dead channels): one broadcast True, no byte per value
    return AttributeInput(gps, layout, steps, values, np.broadcast_to(True, values.shape), None, geometry.coords)


def sh_transformed(values: np.ndarray, gps: GaussianParameterSet, layout, steps: np.ndarray, cfg: GaussianEncoderConfig,
                   levels: LevelLayout):
    """With the SH transform (format 1.6, encoder/gaussians/sh_transform.py) where it pays: the parameter
    set whose band steps are the value grid of the transform's inverse, the layout that carries the
    transform, its steps; ``values``' SH rest becomes, in place, the coefficients times those steps (so
    that the coding's values / steps are the coefficients). Otherwise the arguments as they are."""
    from . import sh_transform as sht

    rest = sht.sh_rest_columns(layout.sh_channels)
    # the SH rest in band steps: values[:, rest] / steps[rest] (not made whole: peak memory)
    transform, coefficients = sht.chosen_transform_of_values(values, rest, steps[rest].astype(np.float64),
                                                             cfg.sh_transform, layout.sh_degree)
    if transform is None:
        return gps, layout, steps
    fine = dataclasses.replace(cfg, sh_band_steps=tuple(float(s) / sht.guard_factor() for s in cfg.sh_band_steps))
    gps = gaussian_parameter_set(gps.num_points, gps.sh_degree, gps.voxel_size, gps.origin, fine, levels.hier is not None,
                                 levels.tile_scale)
    layout = dataclasses.replace(layout, sh_transform=transform)
    steps = layout.steps(gps)
    values[:, rest] = np.multiply(coefficients, steps[rest].astype(np.float64), out=coefficients)
    return gps, layout, steps


def transformed_sensitivity(f: np.ndarray, inp: AttributeInput) -> np.ndarray:
    """The sensitivities ``f`` [N, M] with the SH rest's replaced by the coefficients' (diag(B^T F B),
    encoder/gaussians/sh_transform.py) when the input carries the SH transform; ``f`` otherwise."""
    from . import sh_transform as sht
    from .rdoq import uniform

    transform = inp.layout.sh_transform
    if transform is None:
        return f
    rest = sht.sh_rest_columns(inp.layout.sh_channels)
    band_steps = inp.steps[rest].astype(np.float64) * sht.guard_factor()
    one = uniform(f)
    g = np.array(f[:1] if one else f, dtype=np.float64)
    g[:, rest] = sht.coefficient_sensitivity(g[:, rest], band_steps, transform)
    return np.broadcast_to(g[0], f.shape) if one else g


def rd_quantized_input(inp: AttributeInput, sensitivity: np.ndarray, levels: LevelLayout,
                       cfg: GaussianEncoderConfig) -> AttributeInput:
    """The attribute values moved onto the quantized values rate-distortion optimized
    quantization chooses (encoder/gaussians/rdoq.py; ``sensitivity`` rows in coding order), which the
    coder's rounding then reproduces exactly. The choice uses the whole scene's neighbour
    graph, also where tiles code their own. ``inp``'s values (float64) are consumed: divided by
    their steps in place (no copy of the scene's values), the input returned holds the integers."""
    from .rdoq import (adjust_on_graph, channel_groups, degrees_on_graph, group_slopes, orientation_columns, rd_quantize,
                       sh_degree_subset, sh_degrees_wanted, without_dropped_bands)

    degree = inp.layout.sh_degree
    transformed = inp.layout.sh_transform is not None
    f = transformed_sensitivity(sh_degree_subset(sensitivity, degree), inp)
    graph = neighbour_graph(inp.coords, cfg.prediction_lods, cfg.prediction_neighbours) \
        if neighbour_prediction_wanted(cfg, levels, inp) else None
    x = np.divide(inp.values, inp.steps.astype(np.float64), out=inp.values)  # the values in steps
    check_predicted_magnitude(np.rint([x.min(initial=0), x.max(initial=0)]), inp.layout)  # before RDOQ's int64
    adjust = None  # the rows are in coding order already
    if graph is not None and cfg.step_adjust_max > 0:
        adjust = adjust_on_graph(x, f, degree, inp.coords, np.arange(x.shape[0]), graph, cfg, transformed)
    q = rd_quantize(x, f, group_slopes(f, channel_groups(degree, transformed), cfg.rd_quantization), inp.coords, graph,
                    cfg.prediction_buckets, orientation_columns(inp.layout), adjust=adjust,
                    length_index=cfg.rotation_length)
    layout = inp.layout
    if cfg.rotation_length:  # the largest index used is the unit's (clause 7.3.15)
        layout = dataclasses.replace(layout, max_rotation_length_index=int(q[:, layout.rotation_start].max(initial=0)))
    degrees = None
    if graph is not None and inp.sh_degrees is None and sh_degrees_wanted(cfg, sensitivity, degree):
        degrees = degrees_on_graph(x, q, f, inp.layout, inp.coords, np.arange(x.shape[0]), graph, cfg, adjust)
        q = q if degrees is None else without_dropped_bands(q, degrees, inp.layout)
    check_predicted_magnitude(q, inp.layout)  # as the coding checked the values it quantized
    return dataclasses.replace(inp, layout=layout, values=narrowest_integers(q), step_adjust=adjust,
                               sh_degrees=inp.sh_degrees if degrees is None else degrees, graph=graph, quantized=True)


def assemble_gaussian_stream(inp: AttributeInput, levels: LevelLayout, cfg: GaussianEncoderConfig, coded: CodedAttributes,
                             geometry: GeometryCoding, stats: EncodeStats, progress: bool = False,
                             workers=None) -> EncodeResult:
    gps, layout = inp.parameter_set, inp.layout

    def make(coords: np.ndarray, values: np.ndarray, mask) -> GaussianScene:  # holds no scene: sent to workers
        sh, op, log_scales, rotations = layout.split(values)
        return GaussianScene.on_grid(coords, gps.voxel_size, gps.origin, sh, op, log_scales, rotations)

    tiles, decoded = stream_tiles(inp, levels, cfg, geometry, coded, make, stats, progress, workers)
    parameter_units = [DataUnit(UnitType.GAUSSIAN_PARAMETER_SET, gps.to_bytes())]
    if coded.neighbour_unit is not None:
        parameter_units.append(DataUnit(UnitType.NEIGHBOUR_PREDICTION, coded.neighbour_unit.to_bytes()))
        if inp.step_adjust is not None:
            unit = StepAdjustUnit(max_step_adjust=int(inp.step_adjust.max()))
            stats.step_adjust_counts = np.bincount(inp.step_adjust, minlength=unit.max_step_adjust + 1).tolist()
            parameter_units.append(DataUnit(UnitType.STEP_ADJUST, unit.to_bytes()))
            flags = coded.neighbour_unit.step_flags  # chosen by the neighbour coding (clause 7.3.16)
            stats.step_adjust_flags = flags is not None
            if flags is not None:
                parameter_units.append(DataUnit(UnitType.STEP_ADJUST_FLAGS, flags.to_bytes()))
        if inp.sh_degrees is not None:  # the unit fitted by the neighbour coding (clause 7.3.14)
            stats.sh_degree_counts = np.bincount(inp.sh_degrees, minlength=layout.sh_degree + 1).tolist()
            parameter_units.append(DataUnit(UnitType.SH_DEGREE, coded.neighbour_unit.sh_degree_unit.to_bytes()))
    if layout.max_rotation_length_index >= 0:
        unit = RotationLengthUnit(max_rotation_length_index=layout.max_rotation_length_index)
        parameter_units.append(DataUnit(UnitType.ROTATION_LENGTH, unit.to_bytes()))
    if layout.sh_transform is not None:  # clause 7.3.17
        parameter_units.append(DataUnit(UnitType.SH_TRANSFORM, layout.sh_transform.to_unit(layout.sh_degree).to_bytes()))
        stats.sh_transform = True
    data = write_stream(parameter_units, coded.context_payload, tiles, decoded.num_gaussians)
    digest = tiles[0].scene_hash if len(tiles) == 1 else gaussian_scene_digest(decoded)
    return EncodeResult(data, breakdown_of(read_container(data), decoded.num_gaussians, "Gaussian"), decoded, digest,
                        stats)


def encode_gaussian_scene(scene: GaussianScene, cfg: GaussianEncoderConfig | None = None, *,
                          weights: np.ndarray | None = None, sensitivity: np.ndarray | None = None,
                          progress: bool = False, measure_ideal: bool = False, workers=None,
                          sh_degrees: np.ndarray | None = None) -> EncodeResult:
    """Encode an explicit-Gaussian scene. A scene already on a grid (``coords`` set, e.g. from
    encoder/gaussians/gaussian_fit.py) keeps it; otherwise the grid is chosen here. ``weights``: each
    Gaussian's contribution to the pictures, when known (grid size, who keeps a shared voxel).
    ``sensitivity``: the pictures' sensitivity to each value (encoder/gaussians/rdoq.py, [N, M] at the
    scene's SH degree or above), when known: the values are then chosen by rate-distortion
    optimized quantization (``cfg.rd_quantization``) instead of rounded; without it,
    ``cfg.sensitivity_model`` "uniform" gives every value the same one. ``workers``
    (encoder/stream/tile_workers.py TileWorkers; None: this process): where a tiled scene's tiles are
    coded; the stream does not depend on it. ``sh_degrees``: each Gaussian's SH degree in [0, the
    coded SH degree] (format 1.3, clause 11.9; None: every band of every Gaussian coded, no
    sh_degree unit); the bands above it are not coded and decode to 0."""
    from .rdoq import take_rows, uniform_sensitivity

    cfg = (cfg or GaussianEncoderConfig()).validate()
    scene.validate()
    for name, a in (("sensitivity", sensitivity), ("sh_degrees", sh_degrees)):
        if a is not None and a.shape[0] != scene.num_gaussians:
            raise ValueError(f"{name} has {a.shape[0]} rows for {scene.num_gaussians} Gaussians")
    if sensitivity is None and cfg.sensitivity_model == "uniform":  # RDOQ without renders (config.py)
        sensitivity = uniform_sensitivity(scene.num_gaussians, attr.GaussianLayout(scene.sh_degree).num_channels)
    stats = EncodeStats()
    t0 = time.perf_counter()
    scene = with_coded_sh_degree(scene, cfg, stats)
    check_point_count(scene.num_gaussians, "Gaussians")
    bar = progress_bar(total=sum(STAGE_SHARES.values()), desc="encode", unit="%", disable=not progress, leave=False)
    with stage(bar, "geometry", stats, STAGE_SHARES["geometry"]):
        scene = on_own_voxels(scene, cfg, weights, stats)
        geometry = code_geometry(scene.coords)
        stats.time_geometry_s = time.perf_counter() - t0
    with stage(bar, "quantization", stats, STAGE_SHARES["quantization"]):
        levels = level_layout(scene.num_gaussians, cfg, geometry.coords, stats)
        inp = gaussian_attribute_input(scene, geometry, levels, cfg)
        if sh_degrees is not None:
            inp = dataclasses.replace(inp, sh_degrees=np.asarray(sh_degrees)[geometry.order])
        del scene  # the grid's copy of the scene: its values are in ``inp`` now (peak memory)
        if sensitivity is not None and cfg.rd_quantization > 0:
            inp = rd_quantized_input(inp, take_rows(sensitivity, geometry.order), levels, cfg)
        elif cfg.rotation_length:  # index 0, unit length (the rotations are normalized, w >= 0)
            inp.values[:, inp.layout.rotation_start] = 0
    with stage(bar, "attributes", stats, STAGE_SHARES["attributes"]):
        t1 = time.perf_counter()
        coded = code_attributes(inp, levels, cfg, stats, progress=progress, measure_ideal=measure_ideal)
        stats.time_attributes_s = time.perf_counter() - t1
    with stage(bar, "tiles and hash", stats, STAGE_SHARES["tiles and hash"]):
        result = assemble_gaussian_stream(inp, levels, cfg, coded, geometry, stats, progress, workers)
    bar.close()
    stats.time_total_s = time.perf_counter() - t0
    return result
