"""Fitting the level-2 context model (informative, encoder side).

``fit_level2_context`` dispatches on the model: GG-Conv (encoder/context/ggconv_train.py: float
twin, then quantization-aware training that emulates the integer path) or the parent MLP
(the paper's "vanilla EM"; below: float training with the same rate-distortion loss, then
post-training quantization with per-layer power-of-two scales).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from ...app.progress import progress_bar

from ...common.context.models import check_ggconv_extent
from ...common.context.parent_mlp import ParentMlpParams
from ...common.errors import BitstreamError
from ...common.hierarchy import local_position
from ...common.intnn import ACT_MAX, ACT_MIN, IntMLP
from .int_quantization import frac_bits_for, quantize_linear
from ...common.units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP
from .ggconv_train import (GGConvTrainConfig, choose_parent_base, fit_ggconv, level_of_spread, one_cycle,
                                         rd_loss)

CONTEXT_MODEL_IDS = {"parent_mlp": CONTEXT_PARENT_MLP, "ggconv": CONTEXT_GGCONV}


class ContextFitError(Exception):
    """The context model could not be fitted (e.g. it diverged); the encoder keeps the prior."""


@dataclass
class FittedContext:
    model_id: int
    params: object  # GGConvParams | ParentMlpParams (to_syntax: the context model unit's content)


def fit_parent_mlp(coords2: np.ndarray, parent_attrs: np.ndarray, targets: np.ndarray, num_features: int,
                   voxel_scale: int, cfg: GGConvTrainConfig) -> ParentMlpParams:
    """Head MLP [local position (3), parent attributes (M)] -> 3M, fitted on the rate-distortion
    loss of GG-Conv's trainer, then quantized (16-bit activations, cfg.weight_bits weights)."""
    n, m = parent_attrs.shape
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    rows = np.sort(rng.permutation(n)[:cfg.max_train_points])
    local = local_position(coords2[rows], voxel_scale).clip(0, ACT_MAX).astype(np.float64)
    xpar = np.clip(parent_attrs[rows], ACT_MIN, ACT_MAX).astype(np.float64)
    x_int = torch.from_numpy(np.concatenate([local, xpar], 1))
    tgt = torch.from_numpy(np.clip(np.asarray(targets, dtype=np.float64)[rows], ACT_MIN, ACT_MAX))  # see fit_ggconv
    xp = torch.from_numpy(xpar)
    x_spread = x_int.std(0) if x_int.shape[0] > 1 else torch.ones(x_int.shape[1], dtype=torch.float64)
    scale = 1.0 / x_spread.clamp_min(1.0)  # input normalization, folded into layer 1 at export
    hidden = cfg.head_hidden
    net = nn.Sequential(nn.Linear(3 + m, hidden), nn.ReLU(), nn.Linear(hidden, 3 * m)).double()
    with torch.no_grad():  # start from the best constant prediction (parent or median), no step change
        base, center, spread = choose_parent_base(tgt, xp, cfg.parent_base)
        net[2].weight.mul_(0.1)
        net[2].bias.zero_()
        net[2].bias[:m] = center
        net[2].bias[m:2 * m] = level_of_spread(spread)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    steps = cfg.float_steps + cfg.qat_steps
    sched = one_cycle(opt, cfg.lr, steps)
    for _ in progress_bar(range(steps), desc="fit parent MLP", disable=not cfg.progress, unit="step"):
        sel = torch.from_numpy(rng.integers(0, rows.size, min(cfg.batch, rows.size)))
        o = net(x_int[sel] * scale)
        mean = xp[sel] * base + o[:, :m]
        level = o[:, m:2 * m].clamp(0, 63)
        adj = o[:, 2 * m:].clamp(0, 7)
        loss, _ = rd_loss(mean, level, adj, tgt[sel], cfg.lam)
        opt.zero_grad()
        (loss.mean() / m).backward()
        opt.step()
        sched.step()
    with torch.no_grad():
        w1 = (net[0].weight * scale[None, :]).numpy()
        b1 = net[0].bias.numpy()
        h = torch.relu(x_int @ torch.from_numpy(w1).T + torch.from_numpy(b1))
        f1 = frac_bits_for(float(h.abs().max()) if h.numel() else 0.0)
        l1, _ = quantize_linear(w1, b1, f1, relu=True, weight_bits=cfg.weight_bits)
        l2, _ = quantize_linear(net[2].weight.numpy() * 2.0 ** -f1, net[2].bias.numpy(), 0, relu=False,
                                weight_bits=cfg.weight_bits)
    return ParentMlpParams(num_features, IntMLP([l1, l2]), base.round().to(torch.int64).numpy())


def fit_level2_context(kind: str, coords1: np.ndarray, attrs1: np.ndarray, coords2: np.ndarray, parent: np.ndarray,
                       targets: np.ndarray, num_features: int, voxel_scale: int,
                       cfg: GGConvTrainConfig) -> FittedContext:
    """Fit the level-2 context model ``kind`` (parent_mlp or ggconv) on the decoded level 1
    (coords1 [N1, 3], attrs1 [N1, M] quantized) and the level-2 targets (float [N2, M], in base
    steps) of the level-2 anchors at coords2 [N2, 3] with parents ``parent`` [N2] (level-1 index)."""
    if kind == "ggconv":  # a scene beyond GG-Conv's extent limit (spec clause 8) keeps the per-channel prior
        try:
            check_ggconv_extent(coords1, coords2)
        except BitstreamError as e:
            raise ContextFitError(str(e)) from None
    try:
        return _fit(kind, coords1, attrs1, coords2, parent, targets, num_features, voxel_scale, cfg)
    except ValueError as e:  # a float network that diverged cannot be quantized ("NaN or Inf")
        if "NaN" in str(e) or "Inf" in str(e):
            raise ContextFitError(f"the {kind} context model diverged while fitting ({e})") from None
        raise


def _fit(kind, coords1, attrs1, coords2, parent, targets, num_features, voxel_scale, cfg) -> FittedContext:
    if kind == "ggconv":
        p = fit_ggconv(coords2, parent, coords1, attrs1, targets, num_features, voxel_scale, cfg)
        return FittedContext(CONTEXT_GGCONV, p)
    if kind == "parent_mlp":
        p = fit_parent_mlp(coords2, attrs1[parent], targets, num_features, voxel_scale, cfg)
        return FittedContext(CONTEXT_PARENT_MLP, p)
    raise ValueError(f"unknown context model {kind!r}")
