"""The encoder (informative): it chooses quantization, priors and chunking, and writes
a stream that the normative decoding process turns back into exactly the scene whose
hash it carries. Everything the decoder must reproduce is computed by common/ code.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from collections.abc import Iterator

import numpy as np
from ...app.progress import progress_bar

from ...common import attributes as attr
from ...common.container import (UNIT_CRC_BYTES, UNIT_HEADER_BYTES, AncillaryUnitType, DataUnit, UnitType,
                                read_container, write_container)
from ...common.entropy.symbol_coder import best_level
from ..context.code_lengths import ideal_code_length_bits_by_rows
from ...common.errors import InputError
from ...common.context.model_unit import write_context_model_unit
from ...common.context.models import CONTEXT_MODEL_NAMES, read_context_model
from ...common.geometry import encode_geometry, normative_order
from ...common.hashing import digest_of
from ...common.render_model import dequantize, write_render_model_unit
from ...app.report import SizeBreakdown, breakdown_of
from ...common.scene import ACTIVATIONS, MLP_ROLES, AnchorScene, GaussianScene, RenderMLP
from ...common.hierarchy import Hierarchy, build_hierarchy
from ...common.units import (LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_POINTS,
                                MAX_ATTRIBUTE_VALUES, MAX_EXPONENT, NeighbourPredictionUnit, RenderMlpHeader,
                                SceneParameterSet, SourceInfo)
from .config import (AttributeCodingConfig, EncoderConfig, channel_prediction_on, context_model_size,
                     neighbour_prediction_on)
from ..context.context_fit import ContextFitError, fit_level2_context
from ..context.ggconv_train import ContextTwin, GGConvTrainConfig
from .neighbour_coding import usable as neighbour_usable
from .level_coding import (AttributeInput, LevelCoder, LevelCoding, code_with_model,
                           code_with_neighbours, code_with_prior, neighbour_coding_of, quantized_level, reconstruct_level)
from .stats import ContextFitStats, EncodeStats, LevelStats

UNIT_FRAMING_BYTES = UNIT_HEADER_BYTES + UNIT_CRC_BYTES


@dataclass
class EncodeResult:
    data: bytes
    breakdown: SizeBreakdown
    decoded: AnchorScene | GaussianScene  # the scene the decoder will output, bit for bit
    scene_hash: bytes
    stats: EncodeStats = field(default_factory=EncodeStats)


def context_train_config(cfg: AttributeCodingConfig, num_level2: int, neighbour_level: int, parent_base: str,
                         progress: bool) -> GGConvTrainConfig:
    """The fit of one candidate context model: its neighbour level and parent_base mode (the
    encoder tries each the configuration's "auto" calls for), the rest from the configuration."""
    ch, feat_hidden, head_hidden, weight_bits = context_model_size(cfg, num_level2)
    return GGConvTrainConfig(k=cfg.context_k, neighbour_level=neighbour_level, parent_base=parent_base,
                             ctx_channels=ch, feat_hidden=feat_hidden, head_hidden=head_hidden, lam=cfg.context_lambda,
                             float_steps=cfg.context_float_steps, qat_steps=cfg.context_qat_steps,
                             weight_bits=weight_bits, max_train_points=cfg.context_train_points,
                             progress=progress)


def twin_train_config(cfg: AttributeCodingConfig, twin: ContextTwin, num_level2: int, progress: bool) -> GGConvTrainConfig:
    """The fit started from a twin trained with the scene: its sizes, graph and parent_base,
    16-bit weights (a twin trained in float for thousands of steps lost 2x its bits at 8: on the
    rate-trained lego, 413 against 198 bits per level-2 anchor), a shorter float phase at a
    tenth of the rate (it starts near a solution: 198 -> 189), then the same QAT."""
    ch, feat_hidden, head_hidden = twin.sizes
    base = context_train_config(cfg, num_level2, twin.neighbour_level, "choose", progress)
    return dataclasses.replace(base, ctx_channels=ch, feat_hidden=feat_hidden, head_hidden=head_hidden,
                               radius_sq=twin.radius_sq, weight_bits=16, float_steps=cfg.context_float_steps // 2,
                               lr=base.lr * 0.1, init=twin)


def prune_scene(scene: AnchorScene, cfg: EncoderConfig):
    """The configured pruning (NAAP or opacity threshold) -> (pruned scene, PruneReport)."""
    from ..anchors.naap import NaapConfig, naap_prune, opacity_prune

    if cfg.pruning == "naap":
        return naap_prune(scene, NaapConfig(k=cfg.naap_k, lam=cfg.naap_lambda, gamma=cfg.naap_gamma,
                                            tau=cfg.prune_tau, keep_ratio=cfg.prune_keep_ratio))
    return opacity_prune(scene, tau=cfg.prune_tau, keep_ratio=cfg.prune_keep_ratio)


def quantize_mlp_tensor(t: np.ndarray, bits: int) -> tuple[np.ndarray, int]:
    """Power-of-two scale so that |q| <= 2^(bits-1) - 1 (informative choice)."""
    peak = float(np.abs(t).max(initial=0))
    if peak == 0.0:
        return np.zeros(t.shape, np.int64), 0
    exp = int(np.ceil(np.log2(peak / ((1 << (bits - 1)) - 1))))
    exp = min(max(exp, -MAX_EXPONENT), MAX_EXPONENT)
    q = np.rint(np.ldexp(t.astype(np.float64), -exp))
    if np.abs(q).max() > (1 << (bits - 1)) - 1:  # rounding at the top of the range
        exp += 1
        q = np.rint(np.ldexp(t.astype(np.float64), -exp))
    if np.abs(q).max() >= 2 ** 24:
        raise InputError(f"an MLP weight of magnitude {peak:.3g} cannot be represented")
    return q.astype(np.int64), exp


def quantize_render_model(mlps: dict[str, RenderMLP], bits: int):
    """-> (unit payload, decoded MLPs)."""
    headers, tensors, decoded = [], [], {}
    for role in MLP_ROLES:
        mlp = mlps.get(role)
        if mlp is None:
            continue
        h = RenderMlpHeader(mlp_role=MLP_ROLES.index(role), num_layers_minus1=len(mlp.weights) - 1,
                            input_dim_minus1=mlp.in_dim - 1)
        ts, ws, bs = [], [], []
        for w, b, a in zip(mlp.weights, mlp.biases, mlp.activations):
            qw, ew = quantize_mlp_tensor(w, bits)
            qb, eb = quantize_mlp_tensor(b, bits)
            h.output_dim_minus1.append(w.shape[0] - 1)
            h.activation.append(ACTIVATIONS.index(a))
            h.weight_exponent.append(ew)
            h.bias_exponent.append(eb)
            h.weight_level.append(best_level(qw.ravel()))
            h.bias_level.append(best_level(qb.ravel()))
            ts += [qw, qb]
            ws.append(dequantize(qw, ew))
            bs.append(dequantize(qb, eb))
        headers.append(h)
        tensors.append(ts)
        decoded[role] = RenderMLP(ws, bs, list(mlp.activations))
    return write_render_model_unit(headers, tensors), decoded


@contextmanager
def stage(bar, name: str, stats: EncodeStats | None = None, weight: float = 1) -> Iterator[None]:
    """One step of the encoder's progress bar: named while it runs, counted (``weight``: its
    share of the bar) when it ends; its time goes to ``stats.stage_times_s`` (lghcc-enc --json,
    tools/bench_scale.py's shares)."""
    bar.set_postfix_str(name)
    t0 = time.perf_counter()
    yield
    if stats is not None:
        stats.stage_times_s[name] = stats.stage_times_s.get(name, 0.0) + time.perf_counter() - t0
    bar.set_postfix_str(f"{name} done")
    bar.update(weight)


def prune(scene: AnchorScene, cfg: EncoderConfig, stats: EncodeStats) -> AnchorScene:
    """The configured pruning, reported in ``stats`` (none: the scene as it is)."""
    if cfg.pruning == "none":
        return scene
    scene, report = prune_scene(scene, cfg)
    stats.pruning = str(report)
    stats.anchors_before_pruning = report.num_before
    return scene


def check_point_count(n: int, what: str) -> None:
    if n > MAX_POINTS:
        raise InputError(f"{n} {what} exceed the profile's limit of {MAX_POINTS}")


@dataclass
class GeometryCoding:
    """The points in normative order and their geometry unit (coded when first asked for: a tiled
    stream codes each tile's geometry instead, and never needs the whole scene's)."""
    order: np.ndarray  # indices into the scene, in normative order
    coords: np.ndarray  # the coordinates in that order
    _payload: bytes | None = None

    @property
    def payload(self) -> bytes:
        if self._payload is None:
            self._payload = encode_geometry(self.coords)
        return self._payload


def code_geometry(coords: np.ndarray) -> GeometryCoding:
    order = normative_order(coords)
    return GeometryCoding(order, coords[order])


@dataclass
class LevelLayout:
    """The attribute levels [(attribute_level, rows)] and the hierarchy that defines them (None:
    one level of every point), and the tiles: tile_scale_minus1 + 1 (0: no tiles)."""
    levels: list[tuple[int, np.ndarray]]
    hier: Hierarchy | None
    tile_scale: int = 0


def level_layout(num_points: int, cfg: AttributeCodingConfig, coords: np.ndarray,
                 stats: EncodeStats) -> LevelLayout:
    """One level of every point, or level 1 and level 2 when the configuration asks for the
    hierarchy and level 2 is not empty (an empty level 2 switches the hierarchy off: it costs
    no bits); and the tile size (encoder/stream/tiling.py)."""
    from .tiling import tile_scale_of

    if cfg.hierarchy:
        hier = build_hierarchy(coords, cfg.coarse_voxel_scale)
        if hier.num_level2:
            stats.num_level1, stats.num_level2 = hier.num_level1, hier.num_level2
            scale = tile_scale_of(coords, cfg.coarse_voxel_scale, cfg)
            return LevelLayout([(LEVEL_1, hier.level1_idx), (LEVEL_2, hier.level2_idx)], hier, scale)
    return LevelLayout([(LEVEL_ALL, np.arange(num_points))], None, tile_scale_of(coords, 1, cfg))


def ordered_offset_mask(scene: AnchorScene, order: np.ndarray) -> np.ndarray | None:
    mask = None if scene.offset_mask is None else scene.offset_mask[order].astype(bool)
    if mask is not None and mask.all():
        mask = None  # every offset is live: the mask tool is switched off and costs nothing
    return mask


def scene_parameter_set(scene: AnchorScene, cfg: EncoderConfig, mask_present: bool,
                        hierarchy: bool, tile_scale: int = 0) -> SceneParameterSet:
    sps = SceneParameterSet(
        num_anchors_minus1=scene.num_anchors - 1, feature_dim_minus1=scene.feature_dim - 1,
        num_offsets_minus1=scene.num_offsets - 1, voxel_size=float(scene.voxel_size),
        origin=[float(x) for x in scene.origin], offset_mask_present_flag=int(mask_present),
        feature_step=cfg.feature_step, scaling_step=cfg.scaling_step, offset_step=cfg.offset_step,
        hierarchy_enabled_flag=int(hierarchy), coarse_voxel_scale_minus1=cfg.coarse_voxel_scale - 1,
        tiles_enabled_flag=int(tile_scale > 0), tile_scale_minus1=max(tile_scale - 1, 0))
    return SceneParameterSet.from_bytes(sps.to_bytes())  # exactly the values the decoder will see


def anchor_attribute_input(scene: AnchorScene, geometry: GeometryCoding, levels: LevelLayout,
                           cfg: EncoderConfig) -> AttributeInput:
    """The parameter set, and the features, scalings and offsets as attribute values."""
    n, order = scene.num_anchors, geometry.order
    mask = ordered_offset_mask(scene, order)
    sps = scene_parameter_set(scene, cfg, mask is not None, len(levels.levels) == 2, levels.tile_scale)
    layout = attr.layout_of(sps)
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise InputError(f"{n} anchors x {layout.num_channels} channels exceed the profile's limit")
    steps = layout.steps(sps)
    values = layout.join(scene.features[order], scene.scalings[order], scene.offsets[order])
    live = layout.live_channels(mask, n)
    if live is None:
        live = np.ones((n, layout.num_channels), dtype=bool)
    return AttributeInput(sps, layout, steps, values, live, mask, geometry.coords)


def usable_context_twin(context_twin: ContextTwin | None, scene: AnchorScene, inp: AttributeInput,
                        levels: LevelLayout, cfg: EncoderConfig, stats: EncodeStats) -> ContextTwin | None:
    """The context twin when it is one more candidate of the level-2 fit (a GG-Conv context
    model, a hierarchy, a twin that fits the configuration; why not is reported in ``stats``)."""
    if context_twin is None or cfg.context_model != "ggconv" or levels.hier is None:
        return None
    why = context_twin.mismatch(scene.feature_dim, inp.layout.num_channels, cfg.coarse_voxel_scale, cfg.context_k,
                                inp.steps)
    if why:
        stats.context_twin_unused = why
        return None
    return context_twin


@dataclass
class CodedAttributes:
    """The attribute units of a scene and what they decode to."""
    payloads: list[bytes]  # one per level (none: a tiled scene without a context model, coded by tile)
    context_payload: bytes | None
    recon: np.ndarray | None  # float32 [N, M]: the decoded values, bit for bit
    neighbour_unit: NeighbourPredictionUnit | None = None  # the stream's neighbour_prediction unit, if any


def neighbour_prediction_wanted(cfg: AttributeCodingConfig, levels: "LevelLayout", inp: AttributeInput) -> bool:
    """Whether the configuration asks for neighbour prediction and the scene admits it (a Gaussian
    scene without the hierarchy, within the extent limit)."""
    return (neighbour_prediction_on(cfg) and levels.hier is None
            and isinstance(inp.layout, attr.GaussianLayout) and neighbour_usable(inp.coords))


@dataclass
class ContextCandidate:
    """One fit of the level-2 context model."""
    neighbour_level: int
    parent_base: str  # "choose", "parent", or "twin": started from the context twin
    train_cfg: GGConvTrainConfig


@dataclass
class ContextCandidates:
    candidates: list[ContextCandidate]
    several_neighbour_levels: bool  # their sizes are compared in the stats
    several_parent_bases: bool


def context_candidates(cfg: AttributeCodingConfig, num_level2: int, progress: bool,
                       twin: ContextTwin | None) -> ContextCandidates:
    """The fits the configuration calls for. GG-Conv with context_neighbour_level "auto": both
    neighbour levels (neither wins on every scene: tools/results/context.md; the parent MLP
    has no neighbours: one level, ignored); parent_base "auto": the per-channel choice and the
    parent on every channel; and a fit started from the context twin when there is one."""
    levels_to_try = [1] if cfg.context_model != "ggconv" else \
        [1, 2] if cfg.context_neighbour_level == "auto" else [cfg.context_neighbour_level]
    bases_to_try = ["choose", "parent"] if cfg.context_parent_base == "auto" else [cfg.context_parent_base]
    candidates = [ContextCandidate(nb_level, base_mode, context_train_config(cfg, num_level2, nb_level, base_mode,
                                                                             progress))
                  for nb_level, base_mode in itertools.product(levels_to_try, bases_to_try)]
    if twin is not None:
        candidates.append(ContextCandidate(twin.neighbour_level, "twin",
                                           twin_train_config(cfg, twin, num_level2, progress)))
    return ContextCandidates(candidates, len(levels_to_try) > 1, len(bases_to_try) > 1)


def code_with_context_candidate(coder: LevelCoder, inp: AttributeInput, hier: Hierarchy, q_level1: np.ndarray,
                                targets: np.ndarray, candidate: ContextCandidate) -> tuple[LevelCoding, bytes]:
    """Fit one candidate context model -> (the level coded with it, its context model unit);
    ContextFitError when the fit fails."""
    cfg = coder.cfg
    coords1, coords2 = inp.coords[hier.level1_idx], inp.coords[coder.rows]
    fitted = fit_level2_context(cfg.context_model, coords1, q_level1, coords2, hier.parent_of_level2, targets,
                                inp.layout.feature_dim, cfg.coarse_voxel_scale, candidate.train_cfg)
    unit = write_context_model_unit(fitted.model_id, *fitted.params.to_syntax())
    model = read_context_model(unit, inp.layout)  # exactly what the decoder will use
    return code_with_model(coder, inp, hier, q_level1, model), unit


def record_candidate(ctx: ContextFitStats, candidates: ContextCandidates, candidate: ContextCandidate,
                     size: int) -> None:
    if candidates.several_neighbour_levels and candidate.parent_base != "twin":
        by_level = ctx.bytes_by_neighbour_level
        by_level[candidate.neighbour_level] = min(by_level.get(candidate.neighbour_level, size), size)
    if candidates.several_parent_bases or candidate.parent_base == "twin":
        by_base = ctx.bytes_by_parent_base
        by_base[candidate.parent_base] = min(by_base.get(candidate.parent_base, size), size)


def code_level2_with_context(coder: LevelCoder, inp: AttributeInput, hier: Hierarchy, q_level1: np.ndarray,
                             with_prior: LevelCoding, twin: ContextTwin | None,
                             progress: bool) -> tuple[LevelCoding, bytes | None, ContextFitStats]:
    """Level 2 with the smallest of the context-model fits when it codes smaller than with the
    per-channel prior -> (the coding kept, its context model unit or None, the fits' stats)."""
    cfg = coder.cfg
    t0 = time.perf_counter()
    ctx = ContextFitStats()
    # dead offsets are not coded: NaN tells the fit to leave them out of the rate
    targets = np.where(coder.live, inp.float_values(coder.rows) / inp.steps.astype(np.float64), np.nan)
    candidates = context_candidates(cfg, coder.rows.size, progress, twin)
    best, best_unit = None, None
    for candidate in candidates.candidates:
        try:
            coding, unit = code_with_context_candidate(coder, inp, hier, q_level1, targets, candidate)
        except ContextFitError as e:  # informative: the stream then uses the per-channel prior
            ctx.error = str(e)
            continue
        size = len(coding.payload) + len(unit)
        record_candidate(ctx, candidates, candidate, size)
        if best is None or size < ctx.bytes_with_context:
            best, best_unit = coding, unit
            ctx.bytes_with_context, ctx.parent_base = size, candidate.parent_base
    ctx.time_s = time.perf_counter() - t0
    ctx.bytes_per_channel_prior = len(with_prior.payload)
    # A context model the scene does not benefit from is not used and costs nothing.
    if best is not None and (not cfg.context_fallback or ctx.bytes_with_context + UNIT_FRAMING_BYTES
                             < len(with_prior.payload)):
        return best, best_unit, ctx
    return with_prior, None, ctx


def ideal_bits(coder: LevelCoder, chosen: LevelCoding) -> float:
    """The attribute model's ideal code length of the level as coded."""
    prediction, q, m = chosen.prediction or attr.ChannelPrediction.none(), chosen.q, chosen.q.shape[1]

    def residuals(a: int, b: int) -> np.ndarray:
        return prediction.residuals(q[a:b], chosen.params.rows(a, b, m).mean)
    # the residuals and code lengths of a few rows at a time (peak memory); every value coded: no mask
    return ideal_code_length_bits_by_rows(residuals, lambda a, b: chosen.params.rows(a, b, m).level, q.shape,
                                          None if coder.live.all() else coder.live)


def code_attributes(inp: AttributeInput, levels: LevelLayout, cfg: AttributeCodingConfig,
                    stats: EncodeStats, *, progress: bool = False, measure_ideal: bool = False,
                    context_twin: ContextTwin | None = None) -> CodedAttributes:
    """Quantize and code the attribute values level by level: the per-channel prior, and for
    level 2 the configured context model when it codes smaller (fits of each candidate; the
    smallest stream is kept). Cross-channel prediction is fitted where the layout allows it
    (Gaussian scenes)."""
    predict = bool(inp.layout.channel_prediction_allowed) and channel_prediction_on(cfg)
    if neighbour_prediction_wanted(cfg, levels, inp):
        return code_neighbours_or_prior(inp, levels, cfg, stats, predict, measure_ideal)
    if inp.sh_degrees is not None:
        raise ValueError("per-Gaussian SH degrees need neighbour prediction (a Gaussian scene without the "
                         "hierarchy, within its extent limit, with neighbour_prediction on)")
    if levels.tile_scale and cfg.context_model == "per_channel":
        return CodedAttributes([], None, None)  # nothing to fit: each tile codes its own units (tiling.py)
    recon = np.zeros_like(inp.values, dtype=np.float32)
    payloads = []
    ideal = 0.0
    stats.attribute_coded_bits = 0
    q_level1 = None  # level 1's, the context of level 2
    context_payload = None
    for level, rows in levels.levels:
        coder = LevelCoder(inp.layout, cfg, level, rows, inp.live[rows], None if inp.mask is None else inp.mask[rows],
                           predict)
        chosen, context_fit = code_with_prior(coder, quantized_level(coder, inp)), None
        if level == LEVEL_2 and cfg.context_model != "per_channel":
            assert levels.hier is not None and q_level1 is not None
            chosen, context_payload, context_fit = code_level2_with_context(coder, inp, levels.hier, q_level1, chosen,
                                                                            context_twin, progress)
        if level == LEVEL_1:
            q_level1 = chosen.q
        payloads.append(chosen.payload)
        if measure_ideal:
            ideal += ideal_bits(coder, chosen)
        stats.attribute_coded_bits += 8 * sum(chosen.header.chunk_size)
        stats.levels[level] = LevelStats(CONTEXT_MODEL_NAMES[chosen.header.context_model_id], len(chosen.payload),
                                         chosen.header.num_channel_predictions if predict else None, context_fit)
        reconstruct_level(recon, rows, chosen, inp.steps, inp.layout)
    if measure_ideal:
        stats.attribute_ideal_bits = ideal
    return CodedAttributes(payloads, context_payload, recon)


def code_neighbours_or_prior(inp: AttributeInput, levels: LevelLayout, cfg: AttributeCodingConfig, stats: EncodeStats,
                             predict: bool, measure_ideal: bool) -> CodedAttributes:
    """A Gaussian scene without the hierarchy: every point coded with neighbour prediction or with
    the per-channel prior, whichever is smaller (with tiles: by the whole scene's ideal code
    lengths, the unit being shared by every tile; each tile then codes its own units)."""
    level, rows = levels.levels[0]
    coder = LevelCoder(inp.layout, cfg, level, rows, inp.live[rows], None, predict)
    q = quantized_level(coder, inp)
    nc = neighbour_coding_of(q, inp.coords, cfg, inp.layout, predict, step_adjust=inp.step_adjust,
                             sh_degrees=inp.sh_degrees, graph=inp.graph)
    nc.unit.sh_degree_unit = nc.degree_unit  # the stream's sh_degree unit (None without the tool), for its tiles
    nc.unit.step_flags = nc.step_flags  # the stream's step_adjust_flags unit (None: the indices as symbols)
    unit_bytes = UNIT_FRAMING_BYTES + len(nc.unit.to_bytes())
    # step adjustment and SH degrees need neighbour prediction (the values were chosen with them)
    needed = inp.step_adjust is not None or inp.sh_degrees is not None
    always = cfg.neighbour_prediction == "always" or needed
    # with tiles only its ideal bits are compared: the whole scene's unit is never written
    with_prior = code_with_prior(coder, q, write=not levels.tile_scale) if not needed else None
    if levels.tile_scale:
        use = always or nc.ideal_stream_bits() / 8 < ideal_bits(coder, with_prior) / 8
        stats.neighbour_prediction = bool(use)
        return CodedAttributes([], None, None, nc.unit if use else None)
    with_neighbours = code_with_neighbours(coder, q, nc)
    use = always or len(with_neighbours.payload) + unit_bytes < len(with_prior.payload)
    chosen = with_neighbours if use else with_prior
    stats.neighbour_prediction = bool(use)
    stats.attribute_coded_bits = 8 * sum(chosen.header.chunk_size)
    if inp.step_adjust is not None:
        stats.step_adjust_coded_bits = 8 * sum(chosen.header.adjust_chunk_size)
    if inp.sh_degrees is not None:
        stats.sh_degree_coded_bits = 8 * sum(chosen.header.degree_chunk_size)
    if measure_ideal:
        stats.attribute_ideal_bits = nc.ideal_bits() if use else ideal_bits(coder, with_prior)
    stats.levels[level] = LevelStats("neighbour prediction" if use else CONTEXT_MODEL_NAMES[0], len(chosen.payload),
                                     chosen.header.num_channel_predictions if predict else None, None)
    recon = np.zeros_like(inp.values, dtype=np.float32)
    reconstruct_level(recon, rows, chosen, inp.steps, inp.layout)
    return CodedAttributes([chosen.payload], None, recon, nc.unit if use else None)


@dataclass
class RenderModelCoding:
    payload: bytes | None  # the render model unit (None: the scene has no MLPs)
    decoded: dict[str, RenderMLP]  # the MLPs the decoder will output


def code_render_model(mlps: dict[str, RenderMLP], cfg: EncoderConfig) -> RenderModelCoding:
    if not mlps:
        return RenderModelCoding(None, {})
    return RenderModelCoding(*quantize_render_model(mlps, cfg.mlp_weight_bits))


def write_stream(parameter_units: list[DataUnit], context_payload: bytes | None, tiles: list, num_points: int) -> bytes:
    """The container: the parameter set (and render model), the context model, then the tiles
    (with the tile index when there are several; clause 6.3)."""
    from .tiling import tile_units

    units = list(parameter_units)
    if context_payload is not None:
        units.append(DataUnit(UnitType.CONTEXT_MODEL, context_payload))
    return write_container(units + tile_units(tiles, num_points))


def stream_tiles(inp: AttributeInput, levels: LevelLayout, cfg: AttributeCodingConfig, geometry: GeometryCoding,
                 coded: CodedAttributes, make_scene, stats: EncodeStats, progress: bool = False, workers=None):
    """The tiles of the stream with their hashes, and the whole decoded scene (stream order).
    Without tiles: one tile of the units already coded. With tiles: every tile coded on its own
    (encoder/stream/tiling.py; ``stats`` then counts the tiles' units), where ``workers`` says
    (encoder/stream/tile_workers.py; None: this process). ``make_scene(coords, values, mask)``: the
    decoded scene of those points."""
    from .tile_workers import code_tiles
    from .tiling import TileCoding, TileJob, tile_level_stats

    stats.num_tiles = 1
    if levels.tile_scale == 0:
        decoded = make_scene(inp.coords, coded.recon, inp.mask)
        tile = TileCoding(None, np.arange(inp.coords.shape[0]), geometry.payload, coded.payloads, digest_of(decoded))
        return [tile], decoded
    job = TileJob(cfg, coded.context_payload, coded.neighbour_unit, make_scene)
    tiles, recon = code_tiles(inp, job, progress, workers)
    tile_level_stats(tiles, stats)
    order = np.concatenate([t.rows for t in tiles])
    return tiles, make_scene(inp.coords[order], recon[order], None if inp.mask is None else inp.mask[order])


def anchor_scene_maker(inp: AttributeInput, model: RenderModelCoding):
    """make_scene for stream_tiles: the anchor scene the decoder outputs for some points (it holds
    the layout, the parameter set and the MLPs, not the scene: it travels to worker processes)."""
    layout, voxel_size, origin, mlps = inp.layout, float(inp.parameter_set.voxel_size), inp.parameter_set.origin, \
        model.decoded

    def make(coords: np.ndarray, values: np.ndarray, mask: np.ndarray | None) -> AnchorScene:
        features, scalings, offsets = layout.split(values)
        return AnchorScene(coords=coords, voxel_size=voxel_size, origin=np.asarray(origin, dtype=np.float32),
                           features=features, scalings=scalings, offsets=offsets, offset_mask=mask, mlps=mlps)
    return make


def assemble_anchor_stream(inp: AttributeInput, levels: LevelLayout, cfg: EncoderConfig, geometry: GeometryCoding,
                           coded: CodedAttributes, model: RenderModelCoding, stats: EncodeStats,
                           ancillary: list[DataUnit] | None = None, progress: bool = False,
                           workers=None) -> EncodeResult:
    """The stream: the scene parameter set, the ancillary units (right after it), the render
    model, the context model, the tiles."""
    tiles, decoded = stream_tiles(inp, levels, cfg, geometry, coded, anchor_scene_maker(inp, model), stats, progress,
                                  workers)
    parameter_units = [DataUnit(UnitType.SCENE_PARAMETER_SET, inp.parameter_set.to_bytes())] + list(ancillary or [])
    if model.payload is not None:
        parameter_units.append(DataUnit(UnitType.RENDER_MODEL, model.payload))
    data = write_stream(parameter_units, coded.context_payload, tiles, decoded.num_anchors)
    digest = tiles[0].scene_hash if len(tiles) == 1 else digest_of(decoded)
    return EncodeResult(data, breakdown_of(read_container(data), decoded.num_anchors), decoded, digest, stats)


def source_info_unit(source_sh_degree: int) -> DataUnit:
    """The ancillary source_info unit (0x80, spec clause 7.3.10) of a scene transcoded from a
    plain 3DGS scene of SH degree ``source_sh_degree``."""
    info = SourceInfo(source_sh_degree=int(source_sh_degree))
    return DataUnit(AncillaryUnitType.SOURCE_INFO, info.to_bytes())


def check_ancillary(units: list[DataUnit] | None) -> list[DataUnit]:
    """The ancillary units given to the encoder (types >= 0x80, clause 6.3); ValueError for any
    other type."""
    for u in units or []:
        if not u.is_ancillary:
            raise ValueError(f"unit type 0x{u.unit_type:02x} is not an ancillary unit type")
    return list(units or [])


def encode_scene(scene: AnchorScene, cfg: EncoderConfig | None = None, progress: bool = False,
                 measure_ideal: bool = False, context_twin: ContextTwin | None = None,
                 ancillary: list[DataUnit] | None = None, workers=None) -> EncodeResult:
    """Encode a scene. ``measure_ideal`` also computes the attribute model's ideal code length
    (stats.attribute_ideal_bits), a full extra pass over the symbols. ``context_twin``: the
    GG-Conv twin trained with the scene (lghcc-train --rate-lambda writes it beside the scene):
    with a GG-Conv context model, a fit started from it is one more candidate (the smallest
    stream is kept); a twin that does not fit the configuration is reported in stats and unused.
    ``ancillary``: ancillary data units (type >= 0x80, e.g. source_info) written right after
    the scene parameter set; the decoded scene and its hash do not depend on them. ``workers``
    (encoder/stream/tile_workers.py TileWorkers; None: this process): where a tiled scene's tiles are
    coded; the stream does not depend on it."""
    ancillary = check_ancillary(ancillary)
    cfg = (cfg or EncoderConfig()).validate()
    scene.validate()
    stats = EncodeStats()
    scene = prune(scene, cfg, stats)
    check_point_count(scene.num_anchors, "anchors")
    t0 = time.perf_counter()
    bar = progress_bar(total=5, desc="encode", unit="step", disable=not progress, leave=False)
    with stage(bar, "geometry", stats):
        geometry = code_geometry(scene.coords)
        stats.time_geometry_s = time.perf_counter() - t0
    with stage(bar, "quantization", stats):
        levels = level_layout(scene.num_anchors, cfg, geometry.coords, stats)
        inp = anchor_attribute_input(scene, geometry, levels, cfg)
    with stage(bar, "attributes", stats):
        t1 = time.perf_counter()
        twin = usable_context_twin(context_twin, scene, inp, levels, cfg, stats)
        coded = code_attributes(inp, levels, cfg, stats, progress=progress, measure_ideal=measure_ideal,
                                context_twin=twin)
        stats.time_attributes_s = time.perf_counter() - t1
    with stage(bar, "render model", stats):
        model = code_render_model(scene.mlps, cfg)
    with stage(bar, "tiles and hash", stats):
        result = assemble_anchor_stream(inp, levels, cfg, geometry, coded, model, stats, ancillary, progress,
                                        workers)
    bar.close()
    stats.time_total_s = time.perf_counter() - t0
    return result
