"""The estimated rate of anchor attributes, for rate-distortion training (informative, encoder side).

LG-HCC optimizes a scene under L = L_render + lambda L_anchor (paper eq. 12), L_anchor being
the entropy-coded size of the anchor attributes under the codec's own context model. Without
it, a trained scene's attributes are nearly independent from anchor to anchor: on the lego
scene trained without a rate term, the features of an anchor's 8 nearest level-1 anchors
explain 23% of its feature variance (tools/results/context.md) and GG-Conv codes level 2
at 0.88x the per-channel prior; trained with the rate term (lambda 0.05), at 0.75x
(tools/results/context.md).

``AnchorRateModel`` estimates, differentiably, the bits the encoder will spend on the
attributes of a fixed anchor set, with the structure the stream uses:

* the normative anchor order and the two-level hierarchy of the encoder's configuration
  (common/hierarchy.py), so level 1 and level 2 are the sets the codec will code;
* level 1: a per-channel discretized Gaussian (learned mean and log scale, in steps), the
  per-channel prior of the level-1 attribute unit;
* level 2: the GG-Conv float twin (encoder/context/ggconv_train.py) over the canonical Ball k-NN graph
  of the configured neighbour level, conditioned, as a decoder is, on the *rounded* level-1
  values; its mean and scale give the level-2 bits.

Symbols are the attributes in quantization steps plus uniform noise in [-1/2, 1/2) (the usual
relaxation of rounding, Balle et al. 2017); the bits are those of the discretized Gaussian of
``ggconv_train.gaussian_bits``. The twin's parameters are trained with the scene; the encoder
fits its own context model afterwards (the twin is not written).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ...common.context.ggconv import GRID_FRAC_BITS, grid_coordinate, neighbour_graph, trilinear_corners
from ...common.geometry import normative_order
from ...common.hierarchy import Hierarchy, build_hierarchy, local_position
from ...common.entropy.scale_levels import LOG_SIGMA_MIN, LOG_SIGMA_STEP
from ..context.ste import ste_round_half_even
from ..context.ggconv_train import (ContextTwin, GGConvFloat, GGConvTrainConfig, default_radius_sq, gaussian_bits,
                           init_mean_outputs, pow2_scale)


class AnchorRateModel(nn.Module):
    """Estimated bits of the attributes of a fixed anchor set (module docstring).

    coords: int [N, 3] voxel positions in the trainer's row order; steps: float [M], the
    quantization step of each attribute channel (features, 6 scalings, 3K offsets); values:
    float [N, M], the current attributes (for the initial means, scales and input scales);
    voxel_scale: the hierarchy's coarse voxel scale s, or None for a stream without the
    hierarchy (every anchor under the per-channel prior, "level 1"); cfg: the twin's
    architecture (k, neighbour_level, widths). With fewer than 2 anchors in a level, that
    level's term is 0.
    """

    def __init__(self, coords: np.ndarray, steps: np.ndarray, num_features: int, voxel_scale: int | None,
                 values: np.ndarray, cfg: GGConvTrainConfig | None = None):
        super().__init__()
        cfg = cfg or GGConvTrainConfig()
        coords = np.asarray(coords, dtype=np.int64)
        n, m = np.asarray(values).shape
        order = normative_order(coords)
        if voxel_scale is None:
            e = np.zeros(0, dtype=np.int64)
            hier = Hierarchy(np.arange(n, dtype=np.int64), e, e.copy())
        else:
            hier = build_hierarchy(coords[order], voxel_scale)
        self.register_buffer("steps", torch.as_tensor(np.asarray(steps, dtype=np.float64)))
        self.register_buffer("l1", torch.from_numpy(order[hier.level1_idx].astype(np.int64)))
        self.register_buffer("l2", torch.from_numpy(order[hier.level2_idx].astype(np.int64)))
        self.num_anchors, self.num_attrs, self.num_features = n, m, num_features
        y = torch.as_tensor(np.asarray(values, dtype=np.float64)) / self.steps
        y1 = y[self.l1]
        # level 1: per-channel prior, initialized at the channel's median and spread
        self.l1_mean = nn.Parameter(y1.median(0).values.clone() if len(self.l1) else torch.zeros(m, dtype=torch.float64))
        spread = (y1 - self.l1_mean.detach()).abs().mean(0) * 1.25 + 0.1 if len(self.l1) > 1 else torch.ones(m)
        self.l1_log_sigma = nn.Parameter(spread.to(torch.float64).log())
        self.twin = None
        if len(self.l2) == 0 or len(self.l1) == 0:
            return
        c1, c2 = coords[order[hier.level1_idx]], coords[order[hier.level2_idx]]
        lvl = cfg.neighbour_level
        radius_sq = cfg.radius_sq or default_radius_sq(c2, cfg.k, c1 if lvl == 1 else None)
        self.graph = (voxel_scale, cfg.k, lvl, radius_sq)  # what a ContextTwin records
        nbr, valid = neighbour_graph(cfg.k, radius_sq, lvl, c2, c1 if lvl == 1 else None)
        valid_t = torch.from_numpy(valid)
        r_loc, slot = torch.nonzero(valid_t, as_tuple=True)
        j = torch.from_numpy(nbr)[r_loc, slot]
        data_c = torch.from_numpy(c1 if lvl == 1 else c2)
        u = grid_coordinate(data_c[j] - torch.from_numpy(c2)[r_loc], math.isqrt(radius_sq), cfg.grid)
        ci, cw = trilinear_corners(u, cfg.grid)
        self.register_buffer("row", r_loc)
        # neighbour j as an index into level 1 (its own values, or its parent's for neighbour_level 2)
        parent = torch.from_numpy(hier.parent_of_level2.astype(np.int64))
        self.register_buffer("parent", parent)
        self.register_buffer("nbr_l1", j if lvl == 1 else parent[j])
        self.register_buffer("du", (u - ((cfg.grid - 1) << (GRID_FRAC_BITS - 1))).to(torch.float64))
        self.register_buffer("corner_idx", ci)
        self.register_buffer("corner_w", cw.to(torch.float64))
        n_valid = valid_t.sum(1).to(torch.float64)
        local = torch.from_numpy(local_position(c2, voxel_scale)).to(torch.float64)
        self.register_buffer("head_fixed", torch.cat([local, n_valid[:, None]], 1))
        # input column scales as the codec's fitting chooses them (powers of two near 1 / std)
        x1 = torch.round(y1)
        df = x1[self.nbr_l1, :num_features] - x1[parent][r_loc, :num_features]
        fstd = float(df.std()) if df.numel() > 1 else 1.0
        feat_q = torch.tensor([pow2_scale(fstd)] * num_features + [2.0 ** -GRID_FRAC_BITS] * 3, dtype=torch.float64)
        xstd = x1[parent].std(0) if len(parent) > 1 else torch.ones(m, dtype=torch.float64)
        head_q = torch.tensor([pow2_scale(float(voxel_scale) / 2)] * 3 + [2.0 ** -3]
                              + [pow2_scale(float(v)) for v in xstd], dtype=torch.float64)
        self.twin = GGConvFloat(num_features, m, cfg, feat_q, head_q)
        init_mean_outputs(self.twin, y[self.l2], x1[parent])  # parent_base by the codec's "choose" rule

    def context_twin(self) -> ContextTwin | None:
        """The trained twin with what the encoder needs to start its fit from it (None without a
        level 2, or with per-channel steps that differ)."""
        steps = self.steps.numpy()
        if self.twin is None or not np.all(steps == steps[0]):
            return None
        voxel_scale, k, level, radius_sq = self.graph
        return ContextTwin(dict(self.twin.state_dict()), self.twin.feat_q.clone(), self.twin.head_q_raw.clone(),
                           voxel_scale, k, level, radius_sq, float(steps[0]), self.num_features, self.num_attrs)

    @property
    def num_level1(self) -> int:
        return int(self.l1.shape[0])

    @property
    def num_level2(self) -> int:
        return int(self.l2.shape[0])

    def forward(self, values: torch.Tensor, noise: bool = True, generator: torch.Generator | None = None,
                live: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """values: float [N, M] attributes (trainer row order). Returns the estimated bits of
        level 1, of level 2 and in all ("level1", "level2", "total"), differentiable in values.
        noise: uniform noise in [-1/2, 1/2) steps (training); else the rounded values.
        live: bool [N, M], the values the stream codes (None: all); the channels of a dead
        offset (offset mask) are not coded and cost nothing."""
        y = values.to(torch.float64) / self.steps
        if noise:
            yn = y + (torch.rand(y.shape, generator=generator, dtype=y.dtype) - 0.5)
        else:
            yn = torch.round(y)
        w = None if live is None else live.to(torch.float64)
        y1 = yn[self.l1]
        bits1 = y.new_zeros(())
        if self.num_level1:
            b1 = gaussian_bits(y1, self.l1_mean, self.l1_log_sigma.exp())
            bits1 = (b1 if w is None else b1 * w[self.l1]).sum()
        bits2 = y.new_zeros(())
        if self.twin is not None:
            x1 = torch.round(y[self.l1]).detach()  # the decoder's context: decoded (rounded) level-1 values
            xpar = x1[self.parent]
            c = self.num_features
            feat_in = torch.cat([x1[self.nbr_l1, :c] - xpar[self.row, :c], self.du], 1)
            batch = {"n": self.num_level2, "feat_in": feat_in, "corner_idx": self.corner_idx,
                     "corner_w": self.corner_w, "row": self.row, "head_raw": torch.cat([self.head_fixed, xpar], 1)}
            mean, level, _ = self.twin(batch)
            b2 = gaussian_bits(yn[self.l2], mean, torch.exp(LOG_SIGMA_MIN + LOG_SIGMA_STEP * level))
            bits2 = (b2 if w is None else b2 * w[self.l2]).sum()
        return {"level1": bits1, "level2": bits2, "total": bits1 + bits2}


def quantize_ste(values: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
    """round(values / step) * step forward (what decoding gives), identity backward."""
    s = steps.to(values.dtype)
    return ste_round_half_even(values / s) * s
