"""The encoder (informative): it chooses quantization, priors and chunking, and writes
a stream that the normative decoding process turns back into exactly the scene whose
hash it carries. Everything the decoder must reproduce is computed by common/ code.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from lghcc.common import attributes as attr
from lghcc.common.container import (UNIT_CRC_BYTES, UNIT_HEADER_BYTES, DataUnit, UnitType, read_container,
                                    write_container)
from lghcc.common.entropy.symbol_coder import best_level, ideal_code_length_bits
from lghcc.common.errors import InputError
from lghcc.common.context.model_unit import write_context_model_unit
from lghcc.common.context.models import CONTEXT_MODEL_NAMES, level2_coding_params, read_context_model
from lghcc.common.geometry import encode_geometry, normative_order
from lghcc.common.hashing import scene_digest
from lghcc.common.render_model import dequantize, write_render_model_unit
from lghcc.common.report import SizeBreakdown, breakdown_of
from lghcc.common.scene import ACTIVATIONS, MLP_ROLES, AnchorScene, GaussianScene, RenderMLP
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.units import (CONTEXT_PER_CHANNEL_PRIOR, LEVEL_1, LEVEL_2, LEVEL_ALL, MASK_PROB_BITS, MAX_ANCHORS,
                                MAX_ATTRIBUTE_VALUES, MAX_EXPONENT, MAX_PREDICTED_MAGNITUDE, PRIOR_MEAN_MAX,
                                AttributeUnitHeader, DecodedSceneHashUnit, RenderMlpHeader, SceneParameterSet)
from lghcc.encoder.config import EncoderConfig, context_model_size
from lghcc.encoder.context_fit import ContextFitError, fit_level2_context
from lghcc.encoder.ggconv_train import ContextTwin, GGConvTrainConfig
from lghcc.encoder.prediction import fit_channel_prediction

UNIT_FRAMING_BYTES = UNIT_HEADER_BYTES + UNIT_CRC_BYTES
MAX_QUANTIZED_MAGNITUDE = 2 ** 52  # |x / step| beyond this cannot be rounded exactly in float64


@dataclass
class LevelCoding:
    """One way of coding the attributes of a hierarchy level."""
    q: np.ndarray
    params: attr.CodingParams
    payload: bytes
    header: AttributeUnitHeader
    prediction: attr.ChannelPrediction | None = None


@dataclass
class EncodeResult:
    data: bytes
    breakdown: SizeBreakdown
    decoded: AnchorScene | GaussianScene  # the scene the decoder will output, bit for bit
    scene_hash: bytes
    stats: dict = field(default_factory=dict)


def context_train_config(cfg: EncoderConfig, num_level2: int, neighbour_level: int, parent_base: str,
                         progress: bool) -> GGConvTrainConfig:
    """The fit of one candidate context model: its neighbour level and parent_base mode (the
    encoder tries each the configuration's "auto" calls for), the rest from the configuration."""
    ch, feat_hidden, head_hidden, weight_bits = context_model_size(cfg, num_level2)
    return GGConvTrainConfig(k=cfg.context_k, neighbour_level=neighbour_level, parent_base=parent_base,
                             ctx_channels=ch, feat_hidden=feat_hidden, head_hidden=head_hidden, lam=cfg.context_lambda,
                             float_steps=cfg.context_float_steps, qat_steps=cfg.context_qat_steps,
                             weight_bits=weight_bits, max_train_anchors=cfg.context_train_anchors,
                             progress=progress)


def twin_train_config(cfg: EncoderConfig, twin: ContextTwin, num_level2: int, progress: bool) -> GGConvTrainConfig:
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
    from lghcc.encoder.naap import NaapConfig, naap_prune, opacity_prune

    if cfg.pruning == "naap":
        return naap_prune(scene, NaapConfig(k=cfg.naap_k, lam=cfg.naap_lambda, gamma=cfg.naap_gamma,
                                            tau=cfg.prune_tau, keep_ratio=cfg.prune_keep_ratio))
    return opacity_prune(scene, tau=cfg.prune_tau, keep_ratio=cfg.prune_keep_ratio)


def quantize(values: np.ndarray, steps: np.ndarray, what: str) -> np.ndarray:
    scaled = values.astype(np.float64) / steps.astype(np.float64)
    worst = float(np.abs(scaled).max(initial=0))
    if not worst < MAX_QUANTIZED_MAGNITUDE:
        raise InputError(f"{what}: a value is {worst:.3g} quantization steps from zero, beyond the coding "
                         f"range of 2^52 steps; use a larger step")
    return np.rint(scaled).astype(np.int64)


def fit_per_channel_prior(q: np.ndarray, live: np.ndarray, sample_rows: int, seed: int = 0):
    """Per channel: integer mean (median) and the scale level that codes it best."""
    n, m = q.shape
    rows = np.arange(n) if n <= sample_rows else np.sort(
        np.random.default_rng(seed).choice(n, sample_rows, replace=False))
    qs, ls = q[rows], live[rows]
    means = np.zeros(m, dtype=np.int64)
    levels = np.zeros(m, dtype=np.int64)
    for c in range(m):
        vals = qs[ls[:, c], c]
        if vals.size:  # the prior mean is a prediction: clamped to its syntax range, escapes code the rest
            means[c] = int(np.clip(np.median(vals).round(), -PRIOR_MEAN_MAX, PRIOR_MEAN_MAX))
            levels[c] = best_level(vals - means[c])
    return means, levels


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


@dataclass
class CodedAttributes:
    """The attribute units of a scene and what they decode to."""
    payloads: list[bytes]  # one per level
    context_payload: bytes | None
    recon: np.ndarray  # float32 [N, M]: the decoded values, bit for bit


def level_layout(num_points: int, cfg, coords: np.ndarray, stats: dict):
    """-> (levels [(attribute_level, rows)], hierarchy or None): one level of every point, or
    level 1 and level 2 when the configuration asks for the hierarchy and level 2 is not empty
    (an empty level 2 switches the hierarchy off: it costs no bits)."""
    levels = [(LEVEL_ALL, np.arange(num_points))]
    hier = None
    if cfg.hierarchy:
        hier = build_hierarchy(coords, cfg.coarse_voxel_scale)
        if hier.num_level2:
            levels = [(LEVEL_1, hier.level1_idx), (LEVEL_2, hier.level2_idx)]
            stats["num_level1"], stats["num_level2"] = hier.num_level1, hier.num_level2
        else:
            hier = None
    return levels, hier


def code_attributes(values: np.ndarray, live: np.ndarray, mask: np.ndarray | None, coords: np.ndarray, levels,
                    hier, layout, steps: np.ndarray, cfg, stats: dict, *, progress: bool = False,
                    measure_ideal: bool = False, context_twin: ContextTwin | None = None) -> CodedAttributes:
    """Quantize and code the attribute values [N, M] (normative order) level by level: the
    per-channel prior, and for level 2 the configured context model when it codes smaller
    (fits of each candidate; the smallest stream is kept). ``live`` bool [N, M]: the values
    that are coded (dead offsets are not); ``mask``: the offset mask (anchor scenes) or None.
    Cross-channel prediction is fitted where the layout allows it (Gaussian scenes)."""
    n = values.shape[0]
    recon = np.zeros_like(values, dtype=np.float32)
    payloads = []
    if measure_ideal:
        stats["attribute_ideal_bits"] = 0.0
    stats["attribute_coded_bits"] = 0
    q_level1 = None
    context_payload = None
    predict = bool(layout.channel_prediction_allowed) and getattr(cfg, "channel_prediction", False)
    for level, rows in levels:
        level_live = live[rows]
        level_mask = None if mask is None else mask[rows]

        def new_header() -> AttributeUnitHeader:
            h = attr.new_attribute_header(layout, rows.size, level)
            h.rows_per_chunk_minus1 = min(cfg.rows_per_chunk, rows.size) - 1
            if mask is not None:
                p = np.clip(np.rint(level_mask.mean(axis=0) * (1 << MASK_PROB_BITS)), 1, (1 << MASK_PROB_BITS) - 1)
                h.mask_live_prob = [int(x) for x in p]
            return h

        def code(header: AttributeUnitHeader, q: np.ndarray, params: attr.CodingParams) -> LevelCoding:
            prediction = None
            if predict:
                prediction, levels_after = fit_channel_prediction(q, params, layout, level_live)
                if header.context_model_id == CONTEXT_PER_CHANNEL_PRIOR:  # the prior's levels follow the residuals
                    header.prior_level = levels_after.tolist()
                    params = attr.prior_params(header)
            payload = attr.write_attribute_unit(header, layout, q, level_mask, params, prediction)
            return LevelCoding(q, params, payload, header, prediction)

        q = np.where(level_live, quantize(values[rows], steps, "attributes"), 0)
        if layout.channel_prediction_allowed and np.abs(q).max(initial=0) > MAX_PREDICTED_MAGNITUDE:
            raise InputError(f"a value is {float(np.abs(q).max()):.3g} quantization steps from zero, beyond the "
                             "2^40 steps a Gaussian scene allows; use a larger step")
        header = new_header()
        means, lv = fit_per_channel_prior(q, level_live, cfg.prior_fit_rows)
        header.context_model_id = CONTEXT_PER_CHANNEL_PRIOR
        header.prior_mean, header.prior_level = means.tolist(), lv.tolist()
        chosen = code(header, q, attr.prior_params(header))
        if level == LEVEL_2 and cfg.context_model != "per_channel":
            t2 = time.perf_counter()
            # dead offsets are not coded: NaN tells the fit to leave them out of the rate
            targets = np.where(level_live, values[rows] / steps.astype(np.float64), np.nan)
            # GG-Conv with context_neighbour_level "auto": both neighbour levels are fitted, the
            # smaller stream is kept (neither wins on every scene: tools/results/context.md).
            # (the parent MLP has no neighbours: one level, ignored)
            levels_to_try = [1] if cfg.context_model != "ggconv" else \
                [1, 2] if cfg.context_neighbour_level == "auto" else [cfg.context_neighbour_level]
            # and parent_base: "auto" fits the per-channel choice and the parent on every channel
            bases_to_try = ["choose", "parent"] if cfg.context_parent_base == "auto" else [cfg.context_parent_base]
            candidates = [(nb_level, base_mode, context_train_config(cfg, rows.size, nb_level, base_mode, progress))
                          for nb_level, base_mode in itertools.product(levels_to_try, bases_to_try)]
            if context_twin is not None:
                candidates.append((context_twin.neighbour_level, "twin",
                                   twin_train_config(cfg, context_twin, rows.size, progress)))
            with_context = unit = None
            for nb_level, base_mode, train_cfg in candidates:
                try:
                    fitted = fit_level2_context(cfg.context_model, coords[hier.level1_idx], q_level1, coords[rows],
                                                hier.parent_of_level2, targets, layout.feature_dim,
                                                cfg.coarse_voxel_scale, train_cfg)
                except ContextFitError as e:  # informative: the stream then uses the per-channel prior
                    stats["context_fit_error"] = str(e)
                    continue
                cand_unit = write_context_model_unit(fitted.model_id, fitted.params.to_arrays(), fitted.feat_layers,
                                                     fitted.head_layers)
                model = read_context_model(cand_unit, layout)  # exactly what the decoder will use
                params = level2_coding_params(model, coords[hier.level1_idx], q_level1, coords[rows],
                                              hier.parent_of_level2, cfg.coarse_voxel_scale).materialize()
                q_ctx = np.where(level_live, quantize(values[rows], attr.effective_steps(steps, params.step_adjust),
                                                      "attributes"), 0)
                header = new_header()
                header.context_model_id = fitted.model_id
                cand = code(header, q_ctx, params)
                cand_bytes = len(cand.payload) + len(cand_unit)
                if len(levels_to_try) > 1 and base_mode != "twin":
                    key = f"level2_bytes_with_ggconv_neighbour_level_{nb_level}"
                    stats[key] = min(stats.get(key, cand_bytes), cand_bytes)
                if len(bases_to_try) > 1 or base_mode == "twin":
                    key = f"level2_bytes_with_parent_base_{base_mode}"
                    stats[key] = min(stats.get(key, cand_bytes), cand_bytes)
                if with_context is None or cand_bytes < stats["level2_bytes_with_context"]:
                    with_context, unit = cand, cand_unit
                    stats["level2_bytes_with_context"] = cand_bytes
                    stats["context_parent_base"] = base_mode
            stats["time_context_fit_s"] = time.perf_counter() - t2
            stats["level2_bytes_per_channel_prior"] = len(chosen.payload)
            # A context model the scene does not benefit from is not used and costs nothing.
            if with_context is not None and (not cfg.context_fallback or stats["level2_bytes_with_context"]
                                             + UNIT_FRAMING_BYTES < len(chosen.payload)):
                chosen, context_payload = with_context, unit
        stats[f"level{level}_context_model"] = CONTEXT_MODEL_NAMES[chosen.header.context_model_id]
        if predict:
            stats[f"level{level}_channel_predictions"] = chosen.header.num_channel_predictions
        if level == LEVEL_1:
            q_level1 = chosen.q
        payloads.append(chosen.payload)
        lq, lp = chosen.q, chosen.params
        if measure_ideal:
            res = (chosen.prediction or attr.ChannelPrediction.none()).residuals(lq, lp.mean)
            stats["attribute_ideal_bits"] += ideal_code_length_bits(
                res[level_live], np.broadcast_to(lp.level, lq.shape)[level_live])
        stats["attribute_coded_bits"] += 8 * sum(chosen.header.chunk_size)
        stats[f"attribute_bytes_level{level}"] = len(chosen.payload)
        with np.errstate(over="ignore", invalid="ignore"):
            recon[rows] = attr.reconstruct(lq, steps, lp.step_adjust)
        if not np.isfinite(recon[rows]).all():
            raise InputError("an attribute value would decode beyond the binary32 range; use a smaller value or step")
    return CodedAttributes(payloads, context_payload, recon)


def encode_scene(scene: AnchorScene, cfg: EncoderConfig | None = None, progress: bool = False,
                 measure_ideal: bool = False, context_twin: ContextTwin | None = None,
                 ancillary: list[DataUnit] | None = None) -> EncodeResult:
    """Encode a scene. ``measure_ideal`` also computes the attribute model's ideal code length
    (stats["attribute_ideal_bits"]), a full extra pass over the symbols. ``context_twin``: the
    GG-Conv twin trained with the scene (lghcc-train --rate-lambda writes it beside the scene):
    with a GG-Conv context model, a fit started from it is one more candidate (the smallest
    stream is kept); a twin that does not fit the configuration is reported in stats and unused.
    ``ancillary``: ancillary data units (type >= 0x80, e.g. source_info) written right after
    the scene parameter set; the decoded scene and its hash do not depend on them."""
    for u in ancillary or []:
        if not u.is_ancillary:
            raise ValueError(f"unit type 0x{u.unit_type:02x} is not an ancillary unit type")
    cfg = (cfg or EncoderConfig()).validate()
    scene.validate()
    stats: dict = {}
    if cfg.pruning != "none":
        scene, report = prune_scene(scene, cfg)
        stats["pruning"] = str(report)
        stats["anchors_before_pruning"] = report.num_before
    n = scene.num_anchors
    if n > MAX_ANCHORS:
        raise InputError(f"{n} anchors exceed the profile's limit of {MAX_ANCHORS}")
    t0 = time.perf_counter()
    bar = tqdm(total=5, desc="encode", unit="step", disable=not progress, leave=False)

    bar.set_postfix_str("geometry")
    order = normative_order(scene.coords)
    coords = scene.coords[order]
    geometry_payload = encode_geometry(coords)
    stats["time_geometry_s"] = time.perf_counter() - t0
    bar.update()

    bar.set_postfix_str("quantization")
    mask = None if scene.offset_mask is None else scene.offset_mask[order].astype(bool)
    if mask is not None and mask.all():
        mask = None  # every offset is live: the mask tool is switched off and costs nothing
    levels, hier = level_layout(n, cfg, coords, stats)
    sps = SceneParameterSet(
        num_anchors_minus1=n - 1, feature_dim_minus1=scene.feature_dim - 1,
        num_offsets_minus1=scene.num_offsets - 1, voxel_size=float(scene.voxel_size),
        origin=[float(x) for x in scene.origin], offset_mask_present_flag=int(mask is not None),
        feature_step=cfg.feature_step, scaling_step=cfg.scaling_step, offset_step=cfg.offset_step,
        hierarchy_enabled_flag=int(len(levels) == 2), coarse_voxel_scale_minus1=cfg.coarse_voxel_scale - 1)
    sps = SceneParameterSet.from_bytes(sps.to_bytes())  # exactly the values the decoder will see
    layout = attr.layout_of(sps)
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise InputError(f"{n} anchors x {layout.num_channels} channels exceed the profile's limit")
    steps = layout.steps(sps)
    values = layout.join(scene.features[order], scene.scalings[order], scene.offsets[order])
    live = layout.live_channels(mask, n)
    if live is None:
        live = np.ones((n, layout.num_channels), dtype=bool)
    bar.update()

    bar.set_postfix_str("attributes")
    t1 = time.perf_counter()
    twin = None
    if context_twin is not None and cfg.context_model == "ggconv" and hier is not None:
        why = context_twin.mismatch(scene.feature_dim, layout.num_channels, cfg.coarse_voxel_scale, cfg.context_k,
                                    steps)
        if why:
            stats["context_twin_unused"] = why
        else:
            twin = context_twin
    coded = code_attributes(values, live, mask, coords, levels, hier, layout, steps, cfg, stats, progress=progress,
                            measure_ideal=measure_ideal, context_twin=twin)
    stats["time_attributes_s"] = time.perf_counter() - t1
    bar.update()

    bar.set_postfix_str("render model")
    units = [DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())] + list(ancillary or [])
    decoded_mlps = {}
    if scene.mlps:
        model_payload, decoded_mlps = quantize_render_model(scene.mlps, cfg.mlp_weight_bits)
        units.append(DataUnit(UnitType.RENDER_MODEL, model_payload))
    bar.update()

    bar.set_postfix_str("hash")
    features, scalings, offsets = layout.split(coded.recon)
    decoded = AnchorScene(coords=coords, voxel_size=float(sps.voxel_size),
                          origin=np.asarray(sps.origin, dtype=np.float32), features=features, scalings=scalings,
                          offsets=offsets, offset_mask=mask, mlps=decoded_mlps)
    digest = scene_digest(decoded)
    units.append(DataUnit(UnitType.GEOMETRY, geometry_payload))
    if coded.context_payload is not None:
        units.append(DataUnit(UnitType.CONTEXT_MODEL, coded.context_payload))
    units += [DataUnit(UnitType.ATTRIBUTE, p) for p in coded.payloads]
    units.append(DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=digest).to_bytes()))
    data = write_container(units)
    bar.update()
    bar.close()
    stats["time_total_s"] = time.perf_counter() - t0
    return EncodeResult(data, breakdown_of(read_container(data), n), decoded, digest, stats)
