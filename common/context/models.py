"""The level-2 context models behind one interface (normative): read the context-model
unit into parameters, and turn decoded level-1 attributes into level-2 coding parameters.
A new context model plugs in here: an id, a parameter class with to_arrays/from_arrays,
and a function giving (mean, level, step_adjust)."""

from __future__ import annotations

import numpy as np

from lghcc.common.attributes import ChannelLayout, CodingParams
from lghcc.common.context.ggconv import GGConvParams, ggconv_coding_params
from lghcc.common.context.model_unit import read_context_model_unit
from lghcc.common.context.parent_mlp import ParentMlpParams, parent_mlp_coding_params
from lghcc.common.errors import BitstreamError
from lghcc.common.units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP

PARAMS_CLASS = {CONTEXT_PARENT_MLP: ParentMlpParams, CONTEXT_GGCONV: GGConvParams}
CONTEXT_MODEL_NAMES = {0: "per-channel prior", CONTEXT_PARENT_MLP: "parent MLP (vanilla EM)",
                       CONTEXT_GGCONV: "GG-Conv"}


def read_context_model(payload: bytes, layout: ChannelLayout, trace=None):
    """-> (model_id, params). Checks that the model fits the scene's channel layout."""
    model_id, arrays = read_context_model_unit(payload, trace)
    try:
        params = PARAMS_CLASS[model_id].from_arrays(arrays)
    except ValueError as e:
        raise BitstreamError(f"context model unit: {e}") from None
    if params.num_attrs != layout.num_channels or params.num_features != layout.feature_dim:
        raise BitstreamError(f"context model unit: the model codes {params.num_attrs} channels with "
                             f"{params.num_features} features; the scene has {layout.num_channels} with "
                             f"{layout.feature_dim}")
    return model_id, params


def level2_coding_params(model, coords2: np.ndarray, parent_attrs: np.ndarray, voxel_scale: int) -> CodingParams:
    model_id, params = model
    if model_id == CONTEXT_GGCONV:
        mean, level, adj = ggconv_coding_params(params, coords2, parent_attrs, voxel_scale)
    else:
        mean, level, adj = parent_mlp_coding_params(params, coords2, parent_attrs, voxel_scale)
    return CodingParams(mean, level, adj)
