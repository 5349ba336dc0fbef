"""Coding one level of attributes (informative): the values quantized at their steps, and one
attribute unit written with the per-channel prior, with neighbour prediction or with a context
model; the values the decoder will rebuild from it. Both the whole-scene coding (encode.py) and
each tile's (tiling.py) use these, so they sit below both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...common import attributes as attr
from ...common.context.models import level2_coding_params
from ...common.entropy.symbol_coder import best_level
from ...common.errors import InputError
from ...common.hierarchy import Hierarchy
from ...common.neighbour_prediction import NeighbourGraph
from ...common.sh_degree import coded_channels
from ...common.units import (CONTEXT_PER_CHANNEL_PRIOR, MASK_PROB_BITS, MAX_PREDICTED_MAGNITUDE, PRIOR_MEAN_MAX,
                            AttributeUnitHeader, GaussianParameterSet, NeighbourPredictionUnit, SceneParameterSet)
from .config import AttributeCodingConfig, GaussianEncoderConfig
from .neighbour_coding import NeighbourCoding
from .prediction import fit_channel_prediction

MAX_QUANTIZED_MAGNITUDE = 2 ** 52  # |x / step| beyond this cannot be rounded exactly in float64


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


@dataclass
class LevelCoding:
    """One way of coding the attributes of a hierarchy level."""
    q: np.ndarray
    params: attr.CodingParams
    payload: bytes
    header: AttributeUnitHeader
    prediction: attr.ChannelPrediction | None = None


@dataclass
class AttributeInput:
    """The attribute values of a scene in normative order, and the parameter set that says how
    they are coded."""
    parameter_set: SceneParameterSet | GaussianParameterSet  # exactly the values the decoder will see
    layout: attr.ChannelLayout | attr.GaussianLayout
    steps: np.ndarray
    values: np.ndarray  # [N, M]
    live: np.ndarray  # bool [N, M]: the values that are coded (dead offsets are not)
    mask: np.ndarray | None  # bool: the offset mask (anchor scenes; None: every offset live) or None
    coords: np.ndarray  # the points, in normative order
    # int64 [N]: each point's step-adjustment index (clause 11.8, with neighbour prediction), or None
    step_adjust: np.ndarray | None = None
    # int [N]: each Gaussian's SH degree in [0, sh_degree] (clause 11.9, with neighbour prediction;
    # the bands above it are not coded: ``live`` is narrowed to the coded channels), or None (the tool
    # off: every band coded, no sh_degree unit)
    sh_degrees: np.ndarray | None = None
    # the neighbour graph of ``coords`` (common/neighbour_prediction.py neighbour_graph at the
    # configuration's LoDs and neighbours) where RDOQ built it already, for the coding to reuse
    graph: NeighbourGraph | None = None
    # ``values`` are the quantized integers (in each row's own steps, the narrowest integer dtype
    # that holds them) the encoder chose (RDOQ): the coding takes them as they are, quantizing once
    quantized: bool = False

    def float_values(self, rows) -> np.ndarray:
        """float64: the values of ``rows`` (where ``quantized``: the integers times the channels' steps)."""
        if self.quantized:
            return self.values[rows] * self.steps.astype(np.float64)
        return self.values[rows]

    def __post_init__(self) -> None:
        if self.sh_degrees is None:
            return
        if not isinstance(self.layout, attr.GaussianLayout):
            raise ValueError("sh_degrees are for explicit-Gaussian scenes")
        d = np.asarray(self.sh_degrees)
        n = self.values.shape[0]
        if d.shape != (n,) or not np.issubdtype(d.dtype, np.integer):
            raise ValueError(f"sh_degrees must be an integer array of one degree per Gaussian ({n}), got "
                             f"{d.dtype} {d.shape}")
        if d.size and (int(d.min()) < 0 or int(d.max()) > self.layout.sh_degree):
            raise ValueError(f"sh_degrees must be in [0, {self.layout.sh_degree}] (the scene's SH degree)")
        self.sh_degrees = d.astype(np.int64)
        self.live = self.live & coded_channels(self.layout.sh_channels, self.layout.num_channels, self.sh_degrees)


@dataclass
class LevelCoder:
    """Writes the attribute units of one level: its rows, their live values and offset mask."""
    layout: attr.ChannelLayout | attr.GaussianLayout
    cfg: AttributeCodingConfig
    level: int
    rows: np.ndarray
    live: np.ndarray
    mask: np.ndarray | None
    predict: bool  # cross-channel prediction is fitted (Gaussian scenes that allow it)

    def new_header(self) -> AttributeUnitHeader:
        h = attr.new_attribute_header(self.layout, self.rows.size, self.level)
        h.rows_per_chunk_minus1 = min(self.cfg.rows_per_chunk, self.rows.size) - 1
        if self.mask is not None:
            p = np.clip(np.rint(self.mask.mean(axis=0) * (1 << MASK_PROB_BITS)), 1, (1 << MASK_PROB_BITS) - 1)
            h.mask_live_prob = [int(x) for x in p]
        return h

    def code(self, header: AttributeUnitHeader, q: np.ndarray, params: attr.CodingParams,
             write: bool = True) -> LevelCoding:
        """``write`` False: everything but the payload (b""), for a size estimate (ideal bits)."""
        prediction = None
        if self.predict:
            prediction, levels_after = fit_channel_prediction(q, params, self.layout, self.live)
            if header.context_model_id == CONTEXT_PER_CHANNEL_PRIOR:  # the prior's levels follow the residuals
                header.prior_level = levels_after.tolist()
                params = attr.prior_params(header)
        payload = attr.write_attribute_unit(header, self.layout, q, self.mask, params, prediction) if write else b""
        return LevelCoding(q, params, payload, header, prediction)


def quantized_level(coder: LevelCoder, inp: AttributeInput) -> np.ndarray:
    """The level's quantized values (0 where not coded)."""
    if inp.quantized:  # checked when chosen (rd_quantized_input)
        return np.where(coder.live, inp.values[coder.rows], 0).astype(np.int64, copy=False)
    steps = inp.steps if inp.step_adjust is None else \
        attr.effective_steps(inp.steps, inp.step_adjust[coder.rows][:, None])
    q = np.where(coder.live, quantize(inp.values[coder.rows], steps, "attributes"), 0)
    check_predicted_magnitude(q, inp.layout)
    return q


def narrowest_integers(q: np.ndarray) -> np.ndarray:
    """``q`` (integers) in the narrowest of int16, int32 and int64 that holds every value."""
    lo, hi = (int(q.min()), int(q.max())) if q.size else (0, 0)
    for dtype in (np.int16, np.int32):
        if np.iinfo(dtype).min <= lo and hi <= np.iinfo(dtype).max:
            return q.astype(dtype)
    return q.astype(np.int64, copy=False)


def check_predicted_magnitude(q: np.ndarray, layout) -> None:
    """InputError for a quantized value beyond the 2^40 steps of a layout with cross-channel
    prediction (an explicit-Gaussian scene; clause 11.6)."""
    if layout.channel_prediction_allowed and np.abs(q).max(initial=0) > MAX_PREDICTED_MAGNITUDE:
        raise InputError(f"a value is {float(np.abs(q).max()):.3g} quantization steps from zero, beyond the "
                         "2^40 steps a Gaussian scene allows; use a larger step")


def neighbour_coding_of(q: np.ndarray, coords: np.ndarray, cfg: GaussianEncoderConfig, layout, predict: bool,
                        unit: NeighbourPredictionUnit | None = None,
                        step_adjust: np.ndarray | None = None, sh_degrees: np.ndarray | None = None,
                        graph: NeighbourGraph | None = None) -> NeighbourCoding:
    return NeighbourCoding(q, coords, cfg.prediction_lods, cfg.prediction_neighbours, cfg.prediction_buckets, predict,
                           layout, unit, adjust=step_adjust, degrees=sh_degrees, graph=graph,
                           step_flags_allowed=cfg.step_adjust_flags)


def code_with_neighbours(coder: LevelCoder, q: np.ndarray, nc: NeighbourCoding) -> LevelCoding:
    """The level (every point of a tile) coded with neighbour prediction (and each point's step
    adjustment when the coding has one)."""
    header = coder.new_header()
    header.context_model_id = CONTEXT_PER_CHANNEL_PRIOR
    payload = nc.write(header)
    params = attr.prior_params(header)
    if nc.adjust is not None:  # what reconstruction needs: each row's step
        params = attr.CodingParams(params.mean, params.level, nc.adjust[:, None])
    return LevelCoding(q, params, payload, header, nc.prediction)


def code_with_prior(coder: LevelCoder, q: np.ndarray, write: bool = True) -> LevelCoding:
    """The level coded with the per-channel prior fitted to its quantized values ``q`` (quantized_level;
    ``write`` False: without its payload)."""
    header = coder.new_header()
    means, lv = fit_per_channel_prior(q, coder.live, coder.cfg.prior_fit_rows)
    header.context_model_id = CONTEXT_PER_CHANNEL_PRIOR
    header.prior_mean, header.prior_level = means.tolist(), lv.tolist()
    return coder.code(header, q, attr.prior_params(header), write)


def code_with_model(coder: LevelCoder, inp: AttributeInput, hier: Hierarchy, q_level1: np.ndarray,
                    model) -> LevelCoding:
    """Level 2 coded with a context model (as ``read_context_model`` returns it): its means,
    levels and step adjustment from the decoded level 1, the values quantized with those steps."""
    params = level2_coding_params(model, inp.coords[hier.level1_idx], q_level1, inp.coords[coder.rows],
                                  hier.parent_of_level2, inp.parameter_set.coarse_voxel_scale).materialize()
    q = np.where(coder.live, quantize(inp.float_values(coder.rows), attr.effective_steps(inp.steps, params.step_adjust),
                                      "attributes"), 0)
    header = coder.new_header()
    header.context_model_id = model[0]
    return coder.code(header, q, params)


def reconstruct_level(recon: np.ndarray, rows: np.ndarray, chosen: LevelCoding, steps: np.ndarray, layout) -> None:
    """The level's decoded values into ``recon`` (float32), bit for bit (with a rotation_length
    unit, the rotations' implied w: clause 11.10)."""
    values_q = attr.inverse_sh_transform(chosen.q, layout, "attributes")  # clause 11.11
    with np.errstate(over="ignore", invalid="ignore"):
        values = attr.reconstruct(values_q, steps, chosen.params.step_adjust)
    if not np.isfinite(values).all():
        raise InputError("an attribute value would decode beyond the binary32 range; use a smaller value or step")
    attr.reconstruct_rotations(chosen.q, values, layout, "attributes")
    recon[rows] = values
