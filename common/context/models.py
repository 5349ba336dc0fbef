"""The level-2 context models behind one interface (normative): read the context-model
unit into parameters, and turn the decoded level 1 into level-2 coding parameters.
A new context model plugs in here: an id, a parameter class with to_syntax/from_syntax
(its hyperparameters as syntax elements, its arrays), and a function giving (mean, level, step_adjust).

The models' inference uses torch; it is imported only when a stream carries a context model,
so decoding a stream without one never loads it (time and memory: only what the stream calls for).
"""

from __future__ import annotations

import numpy as np

from ..attributes import ChannelLayout, CodingParams, GaussianLayout
from .model_unit import read_context_model_unit
from ..errors import BitstreamError
from ..units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP

CONTEXT_MODEL_NAMES = {0: "per-channel prior", CONTEXT_PARENT_MLP: "parent MLP (vanilla EM)",
                       CONTEXT_GGCONV: "GG-Conv"}


def params_class(model_id: int):
    """The parameter class of a context model id (1 parent MLP, 2 GG-Conv)."""
    if model_id == CONTEXT_GGCONV:
        from .ggconv import GGConvParams
        return GGConvParams
    if model_id == CONTEXT_PARENT_MLP:
        from .parent_mlp import ParentMlpParams
        return ParentMlpParams
    raise BitstreamError(f"context model unit: unknown context model id {model_id}", condition="E19")


def read_context_model(payload: bytes, layout: ChannelLayout | GaussianLayout, trace=None):
    """-> (model_id, params). Checks that the model fits the scene's channel layout."""
    model_id, hp, arrays = read_context_model_unit(payload, trace)
    try:
        params = params_class(model_id).from_syntax(hp, arrays)
    except ValueError as e:
        raise BitstreamError(f"context model unit: {e}", condition="E42") from None
    if params.num_attrs != layout.num_channels or params.num_features != layout.feature_dim:
        raise BitstreamError(f"context model unit: the model codes {params.num_attrs} channels with "
                             f"{params.num_features} features; the scene has {layout.num_channels} with "
                             f"{layout.feature_dim}", condition="E43")
    return model_id, params


def describe_context_model(model) -> str:
    """A context model and its main settings in words (for reports)."""
    model_id, p = model
    mlps = [m for m in (getattr(p, "feat_mlp", None), p.head_mlp) if m is not None]
    width = {layer.weight_bits for mlp in mlps for layer in mlp.layers}
    bits = "/".join(str(b) for b in sorted(width))
    if model_id == CONTEXT_GGCONV:
        nb = "level-1 anchors" if p.neighbour_level == 1 else "level-2 anchors (parents' attributes)"
        return (f"GG-Conv over {nb}, k={p.k}, radius^2={p.radius_sq}, table {p.grid_size}^3 x {p.context_channels}, "
                f"{p.num_parameters():,} parameters of {bits} bits")
    return f"parent MLP, {p.num_parameters():,} parameters of {bits} bits"


def check_ggconv_extent(*coords: np.ndarray) -> None:
    """Level limit (spec clause 8, Annex H.3): a stream with a GG-Conv context model has anchors
    whose coordinate extent (the largest over the axes of max - min, over all anchors: level 1 and
    level 2 together, whichever level the model's neighbours are) is at most MAX_EXTENT, so every
    squared distance of the Ball k-NN fits a signed 64-bit integer. BitstreamError naming it."""
    from ..knn import MAX_EXTENT

    arrays = [np.asarray(c) for c in coords if np.asarray(c).size]
    if not arrays:
        return
    lo = np.min([a.min(axis=0) for a in arrays], axis=0)
    hi = np.max([a.max(axis=0) for a in arrays], axis=0)
    extent = max(int(h) - int(l) for h, l in zip(hi, lo))  # Python ints: exact
    if extent > MAX_EXTENT:
        raise BitstreamError(f"the anchors' coordinate extent {extent} exceeds the level limit of {MAX_EXTENT} "
                             "for a stream with a GG-Conv context model (spec clause 8)", condition="E44")


class Level2CodingParams:
    """The coding parameters of the level-2 attribute unit, computed for the rows a caller asks
    for (``rows``, the CodingParams interface the attribute decoder uses chunk by chunk): the
    context model's graph and level-1 terms are prepared once, the per-row outputs only for the
    chunk being decoded, so decoding memory grows with the chunk, not with N2."""

    def __init__(self, evaluator):
        self._evaluator = evaluator
        self.num_rows = evaluator.num_rows

    def rows(self, lo: int, hi: int, num_channels: int) -> CodingParams:
        mean, level, adj = self._evaluator.rows(lo, hi)
        return CodingParams(mean, level, adj)

    def materialize(self) -> CodingParams:
        """Every row at once (the encoder needs all step adjustments before coding)."""
        return self.rows(0, self.num_rows, 0)


def level2_coding_params(model, coords1: np.ndarray, attrs1: np.ndarray, coords2: np.ndarray,
                         parent: np.ndarray, voxel_scale: int) -> Level2CodingParams:
    """Coding parameters of the level-2 attributes from the decoded level 1.

    model: (model_id, params) from ``read_context_model``; coords1 int [N1, 3] and attrs1
    int [N1, M]: the level-1 positions and decoded quantized attributes (level-1 order);
    coords2 int [N2, 3]: the level-2 positions; parent int [N2]: each level-2 anchor's parent
    as an index into level 1 (Annex H, clause H.2); voxel_scale: the coarse voxel scale s.
    The model's inputs are checked here; rows are computed on demand (``Level2CodingParams``)."""
    model_id, params = model
    if model_id == CONTEXT_GGCONV:
        from .ggconv import GGConvEvaluator
        check_ggconv_extent(coords1, coords2)
        return Level2CodingParams(GGConvEvaluator(params, coords2, parent, coords1, attrs1, voxel_scale))
    from .parent_mlp import ParentMlpEvaluator
    return Level2CodingParams(ParentMlpEvaluator(params, coords2, parent, attrs1, voxel_scale))
