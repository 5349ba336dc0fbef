"""The parent-MLP context model for level-2 anchors (normative): the "vanilla EM" of the
paper's ablations, in the style of Context-GS. No graph: an integer MLP of the anchor's
position inside its coarse voxel and its parent's decoded attributes gives, per attribute
channel, the mean, the scale level and the step adjustment:

    o_i = head_mlp([clamp(p_i mod s, 0, 32767) (3), x_i])       x_i = clamp16(parent attributes)
    mean = clamp16(parent_base * x_i + o[0:M]);  level = clamp(o[M:2M], 0, 63);
    step_adjust = clamp(o[2M:3M], 0, 7)

with the integer network arithmetic of common/intnn.py and the output mapping shared with
GG-Conv (``split_outputs``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .ggconv import (arrays_by_name, check_level2_inputs, check_parent_base, clamp16, mlp_from_arrays,
                     split_outputs, take_array)
from .model_unit import Hyperparameters, NamedIntArray, mlp_arrays
from ..hierarchy import local_position
from ..intnn import ACT_MAX, IntMLP
from ..scene import NUM_SCALINGS

_BLOCK = 1 << 16


@dataclass
class ParentMlpParams:
    num_features: int
    head_mlp: IntMLP  # 3 + M -> ... -> 3 M
    parent_base: np.ndarray | None = None  # int [M] of 0/1 (None: all 1): the parent's value is the mean's base

    def __post_init__(self) -> None:
        m = self.head_mlp.out_dim // 3
        if self.head_mlp.out_dim != 3 * m or self.head_mlp.in_dim != 3 + m:
            raise ValueError(f"the head MLP must map 3 + M inputs to 3 M outputs, got "
                             f"{self.head_mlp.in_dim} -> {self.head_mlp.out_dim}")
        if not 1 <= self.num_features <= m - NUM_SCALINGS:
            raise ValueError(f"num_features {self.num_features} does not fit M = {m} channels")
        for l, layer in enumerate(self.head_mlp.layers):
            if layer.relu != (l < len(self.head_mlp.layers) - 1):
                raise ValueError("head MLP: ReLU follows every layer but the last")
        self.parent_base = check_parent_base(self.parent_base, m)

    @property
    def base(self) -> np.ndarray:
        """parent_base as __post_init__ made it: int [M] of 0/1."""
        assert self.parent_base is not None, "set by __post_init__"
        return self.parent_base

    @property
    def num_attrs(self) -> int:
        return self.head_mlp.out_dim // 3

    def num_parameters(self) -> int:
        return self.head_mlp.num_parameters()

    def to_syntax(self) -> tuple[Hyperparameters, list[NamedIntArray]]:
        """The context-model unit's content (spec clause 7.3.7, Annex H.6.3): the hyperparameters
        num_features and every head layer's shift (syntax elements), and the arrays parent_base
        (u1 [M]), then for each head layer l: head.{l}.weight (s8 or s16 [out, in]), head.{l}.bias (s32)."""
        hp = Hyperparameters(int(self.num_features), [layer.shift for layer in self.head_mlp.layers])
        return hp, [NamedIntArray("parent_base", self.base.copy(), 1, False)] + mlp_arrays("head", self.head_mlp)

    @classmethod
    def from_syntax(cls, hp: Hyperparameters, arrays: list[NamedIntArray]) -> "ParentMlpParams":
        """Inverse of ``to_syntax``; ValueError on a missing, unknown or malformed array, or a
        model whose parts do not fit together."""
        by = arrays_by_name(arrays)
        parent_base = take_array(by, "parent_base").values
        p = cls(int(hp.num_features), mlp_from_arrays(by, "head", hp.head_layer_shift), parent_base)
        if by:
            raise ValueError(f"unknown parameters: {sorted(by)}")
        return p


class ParentMlpEvaluator:
    """Parent-MLP coding parameters of any range of level-2 rows (decoders evaluate a chunk's
    rows when they decode that chunk: memory O(chunk))."""

    def __init__(self, params: ParentMlpParams, coords2, parent, attrs1, voxel_scale: int):
        attrs1 = np.asarray(attrs1)
        c, par, _, x1 = check_level2_inputs(params.num_attrs, coords2, parent,
                                            np.zeros((attrs1.shape[0] if attrs1.ndim else 0, 3), np.int64), attrs1,
                                            voxel_scale)
        self.params, self.coords, self.parent, self.voxel_scale = params, c, par, int(voxel_scale)
        self.num_rows = c.shape[0]
        self.x1c = clamp16(torch.from_numpy(np.ascontiguousarray(x1)))

    def rows(self, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean int32, level int8, step_adjust int8), each [hi - lo, M], for level-2 rows lo..hi-1."""
        if not 0 <= lo <= hi <= self.num_rows:
            raise ValueError(f"rows {lo}..{hi} outside the {self.num_rows} level-2 rows")
        m = self.params.num_attrs
        mean = np.empty((hi - lo, m), dtype=np.int32)
        level = np.empty((hi - lo, m), dtype=np.int8)
        adj = np.empty((hi - lo, m), dtype=np.int8)
        for b_lo in range(lo, hi, _BLOCK):
            b_hi = min(hi, b_lo + _BLOCK)
            xpar = self.x1c.index_select(0, torch.from_numpy(self.parent[b_lo:b_hi]))
            local = torch.from_numpy(local_position(self.coords[b_lo:b_hi], self.voxel_scale).clip(0, ACT_MAX))
            out = split_outputs(self.params.head_mlp(torch.cat([local, xpar], 1)), xpar, self.params.base, m)
            for dst, o in zip((mean, level, adj), out):
                dst[b_lo - lo:b_hi - lo] = o.numpy()
        return mean, level, adj
