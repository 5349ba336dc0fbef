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

from .ggconv import check_level2_inputs, check_parent_base, clamp16, split_outputs
from .model_unit import NamedIntArray, mlp_arrays
from ..hierarchy import local_position
from ..intnn import ACT_MAX, WEIGHT_BITS_ALLOWED, IntLinear, IntMLP
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
    def num_attrs(self) -> int:
        return self.head_mlp.out_dim // 3

    def num_parameters(self) -> int:
        return self.head_mlp.num_parameters()

    def to_arrays(self) -> list[NamedIntArray]:
        return [NamedIntArray("num_features", np.array(self.num_features, dtype=np.int64), 16, False),
                NamedIntArray("parent_base", self.parent_base.copy(), 1, False)] + mlp_arrays("head", self.head_mlp)

    @classmethod
    def from_arrays(cls, arrays: list[NamedIntArray]) -> "ParentMlpParams":
        by = {a.name: a for a in arrays}
        if len(by) != len(arrays) or "num_features" not in by or "parent_base" not in by:
            raise ValueError("malformed parent-MLP parameters")
        n = (len(arrays) - 2) // 3
        # scalars (spec 7.3.8): array_ndim 0, or one dimension of 1, as GG-Conv's (ggconv.py from_arrays)
        for name in ["num_features"] + [f"head.{l}.shift" for l in range(n)]:
            if name in by and np.shape(by[name].values) not in ((), (1,)):
                raise ValueError(f"parameter {name!r} must be a scalar")
        layers = []
        for l in range(n):
            w, b, s = by[f"head.{l}.weight"], by[f"head.{l}.bias"], by[f"head.{l}.shift"]
            if w.bits not in WEIGHT_BITS_ALLOWED or np.asarray(s.values).size != 1:
                raise ValueError(f"head.{l}: weight bits must be one of {WEIGHT_BITS_ALLOWED} and the shift a scalar")
            layers.append(IntLinear(np.asarray(w.values), np.asarray(b.values), int(np.asarray(s.values).ravel()[0]),
                                    l < n - 1, w.bits))
        return cls(int(np.asarray(by["num_features"].values).ravel()[0]), IntMLP(layers),
                   np.asarray(by["parent_base"].values))


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
            out = split_outputs(self.params.head_mlp(torch.cat([local, xpar], 1)), xpar, self.params.parent_base, m)
            for dst, o in zip((mean, level, adj), out):
                dst[b_lo - lo:b_hi - lo] = o.numpy()
        return mean, level, adj
