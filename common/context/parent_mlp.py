"""The parent-MLP context model for level-2 anchors (normative): the "vanilla EM" of the
paper's ablations, in the style of Context-GS. No graph: an integer MLP of the anchor's
position inside its coarse voxel and its parent's decoded attributes gives, per attribute
channel, the mean, the scale level and the step adjustment:

    o_i = head_mlp([clamp(p_i mod s, 0, 32767) (3), x_i])       x_i = clamp16(parent attributes)
    mean = clamp16(x_i + o[0:M]);  level = clamp(o[M:2M], 0, 63);  step_adjust = clamp(o[2M:3M], 0, 7)

with the integer network arithmetic of common/intnn.py and the output mapping shared with
GG-Conv (``split_outputs``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lghcc.common.context.ggconv import clamp16, split_outputs
from lghcc.common.context.model_unit import NamedIntArray
from lghcc.common.intnn import ACT_MAX, WEIGHT_BITS_ALLOWED, IntLinear, IntMLP

NUM_SCALINGS = 6
_BLOCK = 1 << 16


@dataclass
class ParentMlpParams:
    num_features: int
    head_mlp: IntMLP  # 3 + M -> ... -> 3 M

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

    @property
    def num_attrs(self) -> int:
        return self.head_mlp.out_dim // 3

    def num_parameters(self) -> int:
        return self.head_mlp.num_parameters()

    def to_arrays(self) -> list[NamedIntArray]:
        out = [NamedIntArray("num_features", np.array(self.num_features, dtype=np.int64), 16, False)]
        for l, layer in enumerate(self.head_mlp.layers):
            out += [NamedIntArray(f"head.{l}.weight", layer.weight.copy(), layer.weight_bits, True),
                    NamedIntArray(f"head.{l}.bias", layer.bias.copy(), 32, True),
                    NamedIntArray(f"head.{l}.shift", np.array(layer.shift, dtype=np.int64), 8, False)]
        return out

    @classmethod
    def from_arrays(cls, arrays: list[NamedIntArray]) -> "ParentMlpParams":
        by = {a.name: a for a in arrays}
        if len(by) != len(arrays) or "num_features" not in by:
            raise ValueError("malformed parent-MLP parameters")
        layers = []
        n = (len(arrays) - 1) // 3
        for l in range(n):
            w, b, s = by[f"head.{l}.weight"], by[f"head.{l}.bias"], by[f"head.{l}.shift"]
            if w.bits not in WEIGHT_BITS_ALLOWED or np.asarray(s.values).size != 1:
                raise ValueError(f"head.{l}: weight bits must be one of {WEIGHT_BITS_ALLOWED} and the shift a scalar")
            layers.append(IntLinear(np.asarray(w.values), np.asarray(b.values), int(np.asarray(s.values).ravel()[0]),
                                    l < n - 1, w.bits))
        return cls(int(np.asarray(by["num_features"].values).ravel()[0]), IntMLP(layers))


def parent_mlp_coding_params(params: ParentMlpParams, coords2: np.ndarray, parent_attrs: np.ndarray,
                             voxel_scale: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """coords2 int [N2, 3] level-2 positions; parent_attrs int [N2, M] decoded parent attributes
    in quantization units. Returns mean, level, step_adjust, each int64 [N2, M]."""
    c = np.asarray(coords2, dtype=np.int64)
    x = np.asarray(parent_attrs, dtype=np.int64)
    m = params.num_attrs
    if x.shape != (c.shape[0], m):
        raise ValueError(f"parent_attrs must be [N2, {m}], got {list(x.shape)}")
    local = torch.from_numpy(np.mod(c, np.int64(voxel_scale)).clip(0, ACT_MAX))
    xpar = clamp16(torch.from_numpy(np.ascontiguousarray(x)))
    outs = [params.head_mlp(torch.cat([local[lo:lo + _BLOCK], xpar[lo:lo + _BLOCK]], 1))
            for lo in range(0, c.shape[0], _BLOCK)]
    if not outs:
        z = np.zeros((0, m), dtype=np.int64)
        return z, z.copy(), z.copy()
    mean, level, adj = split_outputs(torch.cat(outs), xpar, m)
    return mean.numpy().copy(), level.numpy().copy(), adj.numpy().copy()
