"""Fitting the GG-Conv context model (informative, encoder side).

A float twin of common/context/ggconv.py with the same structure is trained in two phases:

1. float phase: real-valued weights and activations; the integer-valued inputs (feature
   differences, grid offsets, local positions, parent attributes) enter through fixed
   power-of-two column scales that are folded into the first layers' weights at export;
2. quantized phase (straight-through rounding): the forward pass *emulates the integer path
   exactly* (float64 arithmetic on integers below 2^53, round half up, the same clamps),
   weights are rounded with one power-of-two scale per layer, gradients pass through every
   rounding and clamp unchanged.

The export takes the very integers the quantized phase used, so the integer path
(``ggconv_coding_params``) reproduces the twin's quantized outputs.

Loss per level-2 anchor, summed over its M attribute channels: the estimated rate (bits of
the symbol round(x / 2^(a/4)) under a discretized Gaussian of mean mu and of the sigma of the
scale level, both in adjusted steps; x is the attribute in base quantization steps) plus
lambda * 2^(a/2) / 12 (the quantization MSE in squared base steps).
"""

from __future__ import annotations

import copy
import io
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from ...app.progress import progress_bar

from ...common.context.ggconv import (
    GRID_FRAC_BITS,
    MAX_H_SHIFT,
    NUM_LEVELS,
    NUM_STEP_ADJUST,
    STEP_ADJUST_FACTORS,
    TRI_SHIFT,
    GGConvParams,
    check_level2_inputs,
    edge_inputs,
    ggconv_coding_params,
    head_inputs,
    neighbour_graph,
)
from ...common.entropy.scale_levels import LOG_SIGMA_MIN, LOG_SIGMA_STEP
from ...common.hierarchy import local_position
from ...common.intnn import ACT_MAX, ACT_MIN, BIAS_BITS, MAX_SHIFT, IntLinear, IntMLP, int_range
from .int_quantization import frac_bits_for
from .ste import ste_round_half_up


@dataclass
class GGConvTrainConfig:
    k: int = 8
    neighbour_level: int = 1  # 1: neighbours are level-1 anchors; 2: level-2 anchors (the paper's graph)
    radius_sq: int | None = None  # None: twice the median squared distance to the k-th neighbour
    grid: int = 5
    ctx_channels: int = 32
    feat_hidden: int = 64
    head_hidden: int = 64
    weight_bits: int = 16
    float_steps: int = 1200
    qat_steps: int = 300
    batch: int = 2048
    lr: float = 1e-2  # peak of the one-cycle schedule of the float phase
    qat_lr_scale: float = 0.05  # the quantization-aware phase peaks at lr * qat_lr_scale
    lam: float = 16.0  # distortion weight, bits per squared base step
    parent_base: str = "choose"  # "choose": per channel, parent or median (choose_parent_base); "parent": all 1
    max_train_points: int = 200_000
    seed: int = 0
    progress: bool = True
    # warm start: a twin trained with the scene (lghcc-train --rate-lambda; ``ContextTwin``): its
    # weights, input scales and parent_base start the fit instead of a random initialization
    init: "ContextTwin | None" = None


@dataclass
class ContextTwin:
    """A GG-Conv float twin trained together with a scene (lghcc-train --rate-lambda, the paper's
    joint rate-distortion training), saved beside the scene as ``TWIN_FILE`` so that the encoder
    can start its context-model fit from it: the twin learned on the attributes as they were
    shaped for it, over thousands of steps, where a fresh fit has a few hundred.

    state: the GGConvFloat state dict (table, feature and head MLPs, parent_base); feat_q and
    head_q_raw: its input column scales; the hierarchy and graph it was trained on (coarse voxel
    scale, k, neighbour level, radius^2), the quantization step of every attribute, and the
    channel counts (C features of M attributes)."""

    state: dict
    feat_q: torch.Tensor
    head_q_raw: torch.Tensor
    voxel_scale: int
    k: int
    neighbour_level: int
    radius_sq: int
    step: float
    num_features: int
    num_attrs: int

    @property
    def sizes(self) -> tuple[int, int, int]:
        """(context channels Ch, feature-MLP hidden, head hidden)."""
        return (int(self.state["table"].shape[1]), int(self.state["feat.0.lin.weight"].shape[0]),
                int(self.state["head.0.lin.weight"].shape[0]))

    def save(self, path) -> None:
        from ...app.fileio import atomic_write_bytes

        buf = io.BytesIO()
        torch.save({"version": 1, "state": {k: v.detach().clone() for k, v in self.state.items()},
                    "feat_q": self.feat_q, "head_q_raw": self.head_q_raw,
                    **{f: getattr(self, f) for f in ("voxel_scale", "k", "neighbour_level", "radius_sq", "step",
                                                     "num_features", "num_attrs")}}, buf)
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path) -> "ContextTwin":
        """ValueError naming the file when it is not a twin this version reads (tensors and
        numbers only: never unpickles code)."""
        try:
            d = torch.load(path, map_location="cpu", weights_only=True)
            if d.get("version") != 1:
                raise ValueError(f"version {d.get('version')!r} not supported")
            twin = cls(d["state"], d["feat_q"], d["head_q_raw"], int(d["voxel_scale"]), int(d["k"]),
                       int(d["neighbour_level"]), int(d["radius_sq"]), float(d["step"]), int(d["num_features"]),
                       int(d["num_attrs"]))
            twin.check()
        except Exception as e:  # noqa: BLE001
            raise ValueError(f"{path}: not a context twin ({e})") from None
        return twin

    def check(self) -> None:
        """ValueError unless the settings are in range and the state is exactly a twin of these
        sizes (so a fit can always start from it)."""
        if self.neighbour_level not in (1, 2) or not 1 <= self.k <= 64 or self.radius_sq < 1 or self.voxel_scale < 1:
            raise ValueError("neighbour level, k, radius^2 or voxel scale out of range")
        if not (math.isfinite(self.step) and self.step > 0):
            raise ValueError(f"quantization step {self.step!r}")
        if self.feat_q.shape != (self.num_features + 3,) or self.head_q_raw.shape != (self.num_attrs + 4,):
            raise ValueError("input scales do not match the channel counts")
        ch, fh, hh = self.sizes
        cfg = GGConvTrainConfig(k=self.k, neighbour_level=self.neighbour_level, ctx_channels=ch, feat_hidden=fh,
                                head_hidden=hh)
        GGConvFloat(self.num_features, self.num_attrs, cfg, self.feat_q, self.head_q_raw).load_state_dict(self.state)

    def mismatch(self, num_features: int, num_attrs: int, voxel_scale: int, k: int, steps: np.ndarray) -> str | None:
        """Why this twin cannot start a fit of this configuration (None: it can)."""
        if (num_features, num_attrs) != (self.num_features, self.num_attrs):
            return f"it codes {self.num_attrs} channels with {self.num_features} features"
        if voxel_scale != self.voxel_scale:
            return f"it was trained for coarse voxel scale {self.voxel_scale}, not {voxel_scale}"
        if k != self.k:
            return f"it was trained with k = {self.k}, not {k}"
        if not np.allclose(np.asarray(steps, dtype=np.float64), self.step, rtol=1e-6, atol=0):
            return f"it was trained for the quantization step {self.step:g}"
        return None


TWIN_FILE = "context_twin.pt"


def find_context_twin(scene_path) -> ContextTwin | None:
    """The twin saved beside a Scaffold-GS scene (a model folder, an iteration folder or its
    PLY: ``TWIN_FILE`` in the PLY's folder), None when there is none; InputError naming the
    file when it is there but unreadable."""
    from ...common.errors import InputError
    from ...formats.scaffold_io import locate_ply

    path = locate_ply(scene_path).parent / TWIN_FILE
    if not path.is_file():
        return None
    try:
        return ContextTwin.load(path)
    except ValueError as e:
        raise InputError(str(e)) from None


def _ste_clamp(x: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    return x + (x.clamp(lo, hi) - x).detach()


class _InwardClamp(torch.autograd.Function):
    """clamp(x, lo, hi) forward; backward passes the gradient inside the range and, outside
    it, only when a descent step would move x back toward the range (no drift, no dead unit)."""

    @staticmethod
    def forward(ctx, x, lo, hi):
        ctx.save_for_backward(x)
        ctx.lo, ctx.hi = lo, hi
        return x.clamp(lo, hi)

    @staticmethod
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        keep = ((x >= ctx.lo) & (x <= ctx.hi)) | ((x < ctx.lo) & (g < 0)) | ((x > ctx.hi) & (g > 0))
        return g * keep, None, None


def _inward_clamp(x: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    return _InwardClamp.apply(x, lo, hi)


def pow2_scale(std: float) -> float:
    """A power of two near 1/std (column scale of an integer input)."""
    return 2.0 ** -round(math.log2(max(std, 1e-3)))


def default_radius_sq(coords2: np.ndarray, k: int, coords1: np.ndarray | None = None) -> int:
    """Twice the median squared distance from a level-2 anchor to its k-th nearest neighbour
    (among the other level-2 anchors, or among coords1, the level-1 anchors, when given), at least 1."""
    from scipy.spatial import cKDTree
    data = coords2 if coords1 is None else coords1
    self_hit = 1 if coords1 is None else 0
    if coords2.shape[0] < 1 or data.shape[0] < 1 + self_hit:
        return 1
    kk = min(k, data.shape[0] - self_hit)
    sub = coords2[:: max(1, coords2.shape[0] // 20000)].astype(np.float64)
    d, _ = cKDTree(data.astype(np.float64)).query(sub, k=kk + self_hit)
    d = d.reshape(sub.shape[0], -1)[:, -1]
    return max(1, int(math.ceil(2 * float(np.median(d ** 2)))))


class _QLayer(nn.Module):
    """A float Linear acting on real inputs; the input integers' column scales (real = int * q)
    are given at call time. In quantized mode it emulates IntLinear exactly."""

    def __init__(self, fan_in: int, fan_out: int, relu: bool, weight_bits: int):
        super().__init__()
        self.lin = nn.Linear(fan_in, fan_out, dtype=torch.float64)
        self.relu = relu
        self.weight_bits = weight_bits
        self.acc_frac: int | None = None  # set when quantization starts
        self.out_frac: int = 0

    def w_eff(self, q: torch.Tensor) -> torch.Tensor:
        return self.lin.weight * q[None, :]

    def int_params(self, q: torch.Tensor, ste: bool) -> tuple[torch.Tensor, torch.Tensor]:
        rnd = ste_round_half_up if ste else (lambda t: torch.floor(t + 0.5))
        lo, hi = int_range(self.weight_bits)
        blo, bhi = int_range(BIAS_BITS)
        w = _ste_clamp(rnd(self.w_eff(q) * 2.0 ** self.acc_frac), lo, hi)
        b = _ste_clamp(rnd(self.lin.bias * 2.0 ** self.acc_frac), blo, bhi)
        return w, b

    def start_quantization(self, q: torch.Tensor, out_frac: int) -> None:
        with torch.no_grad():
            m = float(self.w_eff(q).abs().max()) * 1.25
            mb = float(self.lin.bias.abs().max()) * 1.25
        self.out_frac = out_frac
        # one power-of-two scale that fits both the weights (weight_bits) and the biases (32 bits)
        self.acc_frac = min(frac_bits_for(m, self.weight_bits, lo=out_frac, hi=out_frac + MAX_SHIFT),
                            max(out_frac, frac_bits_for(mb, BIAS_BITS, lo=out_frac, hi=out_frac + MAX_SHIFT)))

    def forward(self, x: torch.Tensor, q: torch.Tensor, quant: bool) -> torch.Tensor:
        """float mode: x real, returns real. quant mode: x integer-valued (real = x * q),
        returns integer-valued activations (real = y * 2^-out_frac)."""
        if not quant:
            y = self.lin(x)
            return torch.relu(y) if self.relu else y
        w, b = self.int_params(q, ste=True)
        acc = x @ w.T + b
        y = ste_round_half_up(acc * 2.0 ** -(self.acc_frac - self.out_frac))
        return _ste_clamp(y, 0 if self.relu else ACT_MIN, ACT_MAX)

    def export(self, q: torch.Tensor) -> IntLinear:
        with torch.no_grad():
            w, b = self.int_params(q, ste=False)
        return IntLinear(w.numpy().astype(np.int64), b.numpy().astype(np.int64),
                         self.acc_frac - self.out_frac, self.relu, self.weight_bits)


class GGConvFloat(nn.Module):
    """The float twin of GG-Conv (same structure as the integer model)."""

    def __init__(self, num_features: int, num_attrs: int, cfg: GGConvTrainConfig,
                 feat_q: torch.Tensor, head_q_raw: torch.Tensor):
        super().__init__()
        c, m, ch, d = num_features, num_attrs, cfg.ctx_channels, cfg.grid
        self.c, self.m, self.ch, self.d = c, m, ch, d
        g = torch.Generator().manual_seed(cfg.seed)
        self.table = nn.Parameter(1.0 / cfg.k + 0.1 * torch.randn(d ** 3, ch, generator=g, dtype=torch.float64))
        self.feat = nn.ModuleList([_QLayer(c + 3, cfg.feat_hidden, True, cfg.weight_bits),
                                   _QLayer(cfg.feat_hidden, ch, False, cfg.weight_bits)])
        self.head = nn.ModuleList([_QLayer(ch + 4 + m, cfg.head_hidden, True, cfg.weight_bits),
                                   _QLayer(cfg.head_hidden, 3 * m, False, cfg.weight_bits)])
        self.feat_q = feat_q  # column scales of the feature-MLP input integers
        self.head_q_raw = head_q_raw  # column scales of the head's integer inputs after h
        self.quant = False
        self.frac: dict[str, int] = {}
        self.k = cfg.k
        self.radius_sq = 0  # set by train_ggconv_twin
        self.neighbour_level = 2
        self.register_buffer("parent_base", torch.ones(m, dtype=torch.float64))  # see init_mean_outputs

    # -- pieces ---------------------------------------------------------------------------
    def _qs(self, frac: int, n: int) -> torch.Tensor:
        return torch.full((n,), 2.0 ** -frac, dtype=torch.float64)

    def _mlp(self, layers, x, q0):
        q = q0
        for l, layer in enumerate(layers):
            x = layer(x, q, True)
            q = self._qs(layer.out_frac, layer.lin.out_features)
        return x

    def table_int(self, ste: bool) -> torch.Tensor:
        rnd = ste_round_half_up if ste else (lambda t: torch.floor(t + 0.5))
        return _ste_clamp(rnd(self.table * 2.0 ** self.frac["table"]), ACT_MIN, ACT_MAX)

    def forward(self, batch: dict, collect: dict | None = None):
        """Returns (mean, level, adj), real-valued in float mode, integer-valued when quantized."""
        fin = batch["feat_in"]
        if self.quant:
            e = self._mlp(self.feat, fin, self.feat_q)
            t = self.table_int(ste=True)
            cw = batch["corner_w"]
            w = ste_round_half_up((cw[:, :, None] * t[batch["corner_idx"]]).sum(1) * 2.0 ** -TRI_SHIFT)
            hsum = torch.zeros((batch["n"], self.ch), dtype=torch.float64).index_add(0, batch["row"], w * e)
            h = _ste_clamp(ste_round_half_up(hsum * 2.0 ** -self.frac["h_shift"]), ACT_MIN, ACT_MAX)
            z = torch.cat([h, batch["head_raw"]], 1)
            o = self._mlp(self.head, z, torch.cat([self._qs(self.frac["h"], self.ch), self.head_q_raw]))
            lv = _inward_clamp(o[:, self.m:2 * self.m], 0, NUM_LEVELS - 1)
            adj = _inward_clamp(o[:, 2 * self.m:], 0, NUM_STEP_ADJUST - 1)
            return _ste_clamp(batch["head_raw"][:, 4:] * self.parent_base + o[:, :self.m], ACT_MIN, ACT_MAX), lv, adj
        x = fin * self.feat_q
        h1 = self.feat[0](x, None, False)
        e = self.feat[1](h1, None, False)
        w = (batch["corner_w"][:, :, None] * self.table[batch["corner_idx"]]).sum(1) * 2.0 ** -TRI_SHIFT
        h = torch.zeros((batch["n"], self.ch), dtype=torch.float64).index_add(0, batch["row"], w * e)
        z = torch.cat([h, batch["head_raw"] * self.head_q_raw], 1)
        h2 = self.head[0](z, None, False)
        o = self.head[1](h2, None, False)
        if collect is not None:
            for key, v in (("feat0", h1), ("e", e), ("h", h), ("head0", h2), ("w", w)):
                collect[key] = max(collect.get(key, 0.0), float(v.abs().max()) if v.numel() else 0.0)
        lv = _inward_clamp(o[:, self.m:2 * self.m], 0, NUM_LEVELS - 1)
        adj = _inward_clamp(o[:, 2 * self.m:], 0, NUM_STEP_ADJUST - 1)
        return batch["head_raw"][:, 4:] * self.parent_base + o[:, :self.m], lv, adj

    def start_quantization(self, stats: dict) -> None:
        """Choose every power-of-two scale from calibration maxima; switch to integer emulation."""
        f_feat0 = frac_bits_for(2 * stats["feat0"], lo=-8, hi=14)
        f_e = frac_bits_for(2 * stats["e"], lo=-8, hi=14)
        f_t = frac_bits_for(1.25 * float(self.table.detach().abs().max()), lo=-8, hi=14)
        f_h = frac_bits_for(2 * stats["h"], lo=-8, hi=14)
        f_h = max(f_t + f_e - MAX_H_SHIFT, min(f_h, f_t + f_e))  # 0 <= h_shift <= MAX_H_SHIFT
        f_head0 = frac_bits_for(2 * stats["head0"], lo=-8, hi=14)
        self.frac = {"table": f_t, "e": f_e, "h": f_h, "h_shift": f_t + f_e - f_h}
        self.feat[0].start_quantization(self.feat_q, f_feat0)
        self.feat[1].start_quantization(self._qs(f_feat0, self.feat[0].lin.out_features), f_e)
        self.head[0].start_quantization(torch.cat([self._qs(f_h, self.ch), self.head_q_raw]), f_head0)
        self.head[1].start_quantization(self._qs(f_head0, self.head[0].lin.out_features), 0)
        self.quant = True

    def export(self, num_features: int, k: int, radius_sq: int, neighbour_level: int = 2) -> GGConvParams:
        with torch.no_grad():
            table = self.table_int(ste=False).numpy().astype(np.int64).reshape(self.d, self.d, self.d, self.ch)
        feat = IntMLP([self.feat[0].export(self.feat_q),
                       self.feat[1].export(self._qs(self.feat[0].out_frac, self.feat[0].lin.out_features))])
        head = IntMLP([self.head[0].export(torch.cat([self._qs(self.frac["h"], self.ch), self.head_q_raw])),
                       self.head[1].export(self._qs(self.head[0].out_frac, self.head[0].lin.out_features))])
        return GGConvParams(num_features, k, radius_sq, table, self.frac["h_shift"], feat, head, neighbour_level,
                            self.parent_base.round().to(torch.int64).numpy())


# -- data -----------------------------------------------------------------------------------

@dataclass
class _Data:
    feat_in: torch.Tensor  # float64 [E, C+3]
    corner_idx: torch.Tensor
    corner_w: torch.Tensor  # float64
    row: torch.Tensor  # int64 [E], anchor row within the training set
    edge_start: torch.Tensor  # int64 [T]
    n_edges: torch.Tensor  # int64 [T]
    head_raw: torch.Tensor  # float64 [T, 4 + M]: local position, n_valid, parent attributes
    targets: torch.Tensor  # float64 [T, M], base steps


def _int_tensor(a, clamp: bool = False) -> torch.Tensor:
    t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.int64))
    return t.clamp(ACT_MIN, ACT_MAX) if clamp else t


def _prepare(coords2, parent_attrs, targets, voxel_scale, num_features, k, radius_sq, grid, rows,
             neighbours, neighbour_level: int = 2, level1=None) -> _Data:
    c = _int_tensor(coords2)
    x = _int_tensor(parent_attrs, clamp=True)
    if neighbour_level == 2:
        dc, dx = c, x
    else:
        dc, dx = _int_tensor(level1[0]), _int_tensor(level1[1], clamp=True)
    nbr, valid = neighbours if neighbours is not None else neighbour_graph(
        k, radius_sq, neighbour_level, coords2, None if level1 is None else level1[0])
    nbr_t = _int_tensor(nbr)
    valid_t = torch.from_numpy(np.ascontiguousarray(valid, dtype=bool))
    rows_t = torch.from_numpy(rows)
    ed = edge_inputs(c, x, dc, dx, nbr_t, valid_t, rows_t, num_features, math.isqrt(radius_sq), grid)
    n_valid = valid_t[rows_t].sum(1).to(torch.int64)
    start = torch.cumsum(n_valid, 0) - n_valid
    local = torch.from_numpy(local_position(np.asarray(coords2, dtype=np.int64)[rows], voxel_scale))
    head_raw = head_inputs(torch.zeros((rows.size, 0), dtype=torch.int64), local, n_valid, x[rows_t])
    return _Data(ed.feat_in.double(), ed.corner_idx, ed.corner_w.double(), ed.row, start, n_valid,
                 head_raw.double(), torch.from_numpy(np.asarray(targets, dtype=np.float64)[rows]))


def one_cycle(opt, lr: float, steps: int):
    """The one-cycle schedule (10% warm-up, cosine decay) of every context-model fit."""
    return torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=max(steps, 1) + 1, pct_start=0.1)


def _batch(d: _Data, sel: torch.Tensor) -> dict:
    cnt = d.n_edges[sel]
    total = int(cnt.sum())
    first = torch.repeat_interleave(d.edge_start[sel], cnt)
    offs = torch.arange(total) - torch.repeat_interleave(torch.cumsum(cnt, 0) - cnt, cnt)
    e = first + offs
    return {"n": int(sel.numel()), "feat_in": d.feat_in[e], "corner_idx": d.corner_idx[e],
            "corner_w": d.corner_w[e], "row": torch.repeat_interleave(torch.arange(sel.numel()), cnt),
            "head_raw": d.head_raw[sel], "targets": d.targets[sel]}


# -- loss -----------------------------------------------------------------------------------

def gaussian_bits(y: torch.Tensor, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Bits of integer symbols y under a discretized Gaussian (mu, sigma); floor 2^-24."""
    a = (y - mu).abs()
    p = torch.special.ndtr((0.5 - a) / sigma) - torch.special.ndtr((-0.5 - a) / sigma)
    return -torch.log2(p.clamp_min(2.0 ** -24))


def rd_loss(mean, level, adj, targets, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, bits) per anchor, summed over the coded channels (a NaN target is an entry that is
    not coded, a dead offset: it costs nothing)."""
    live = torch.isfinite(targets)
    sigma = torch.exp(LOG_SIGMA_MIN + LOG_SIGMA_STEP * level)
    y = ste_round_half_up(torch.where(live, targets, 0.0) * torch.exp2(-adj / 4))
    bits = (gaussian_bits(y, mean, sigma) * live).sum(1)
    dist = (torch.exp2(adj / 2) / 12 * live).sum(1)
    return bits + lam * dist, bits


# -- fitting --------------------------------------------------------------------------------

def fit_ggconv(coords2, parent, coords1, attrs1, targets, num_features: int, voxel_scale: int,
               config: GGConvTrainConfig | None = None,
               neighbours: tuple[np.ndarray, np.ndarray] | None = None) -> GGConvParams:
    """Fit GG-Conv on the level-2 anchors.

    coords2: int [N2, 3] level-2 positions (level-2 order); parent: int [N2] their level-1
    parents; coords1 int [N1, 3] and attrs1 int [N1, M]: the level-1 positions and decoded
    attributes in quantization units (features first) (the inputs of ``ggconv_coding_params``);
    targets: float [N2, M] the level-2 attributes in base quantization steps (NaN: an entry that
    is not coded, a dead offset; the fit ignores it); voxel_scale: the
    hierarchy's s; neighbours: the Ball k-NN graph when already computed with the config's k,
    radius_sq and neighbour_level. Returns the quantized parameters.
    """
    return train_ggconv_twin(coords2, parent, coords1, attrs1, targets, num_features, voxel_scale, config,
                             neighbours)[0]


def train_ggconv_twin(coords2, parent, coords1, attrs1, targets, num_features: int, voxel_scale: int,
                      config: GGConvTrainConfig | None = None,
                      neighbours: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[GGConvParams, GGConvFloat]:
    """``fit_ggconv`` that also returns the trained float twin (in quantized mode)."""
    cfg = config or GGConvTrainConfig()
    coords2, parent, coords1, attrs1, targets = _checked_fit_inputs(coords2, parent, coords1, attrs1, targets,
                                                                    num_features, voxel_scale, cfg)
    n = targets.shape[0]
    parent_attrs = attrs1[parent]  # encoder side: the training set's inputs, gathered once
    level1 = (coords1, attrs1)
    radius_sq = cfg.radius_sq if cfg.radius_sq is not None else \
        default_radius_sq(coords2, cfg.k, coords1 if cfg.neighbour_level == 1 else None)
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    rows = np.sort(rng.permutation(n)[:cfg.max_train_points]).astype(np.int64)
    data = _prepare(coords2, parent_attrs, targets, voxel_scale, num_features, cfg.k, radius_sq, cfg.grid,
                    rows, neighbours, cfg.neighbour_level, level1)
    model = _initial_twin(data, num_features, voxel_scale, cfg)
    model.radius_sq = radius_sq
    model.neighbour_level = cfg.neighbour_level
    # One-cycle learning rate (warm-up, then cosine decay): measured on a 20k-anchor procedural
    # scene, it converges in a quarter of the steps of a constant rate.
    bar = progress_bar(total=cfg.float_steps + cfg.qat_steps, desc="fit GG-Conv", disable=not cfg.progress, unit="step")
    _train_phase(model, data, cfg, rng, cfg.lr, cfg.float_steps, bar)
    _start_quantization(model, data)
    export = lambda mdl: mdl.export(num_features, cfg.k, radius_sq, cfg.neighbour_level)  # noqa: E731
    best, best_model = export(model), model
    if cfg.qat_steps:
        # Quantization-aware fine-tuning at a small rate (at 0.3 lr it undid the float phase: 349 ->
        # 367 bits/anchor); the encoder keeps whichever integer model codes the anchors better.
        ptq_model = copy.deepcopy(model)
        _train_phase(model, data, cfg, rng, cfg.lr * cfg.qat_lr_scale, cfg.qat_steps, bar)
        qat = export(model)
        # on the training rows (level-1 neighbours: any subset of queries; the level-2 graph: all anchors)
        sub = rows if cfg.neighbour_level == 1 else np.arange(n)
        costs = [rd_cost(p_, coords2[sub], parent[sub], coords1, attrs1, targets[sub], voxel_scale, cfg.lam)
                 for p_ in (best, qat)]
        if costs[1] <= costs[0]:
            best, best_model = qat, model
        else:
            best_model = ptq_model
        bar.set_postfix(kept="QAT" if best_model is model else "PTQ")
    bar.close()
    return best, best_model


def _checked_fit_inputs(coords2, parent, coords1, attrs1, targets, num_features: int, voxel_scale: int,
                        cfg: GGConvTrainConfig) -> tuple:
    """The inputs of ``fit_ggconv`` as arrays (attrs1 int64, targets float64 [N2, M] clipped to
    the 16-bit activation range); ValueError when they disagree or there is nothing to fit."""
    attrs1 = np.asarray(attrs1, dtype=np.int64)
    m = attrs1.shape[1] if attrs1.ndim == 2 else 0
    coords2, parent, coords1, attrs1 = check_level2_inputs(m, coords2, parent, coords1, attrs1, voxel_scale)
    # the model's mean is a 16-bit activation: targets beyond it are escapes whatever the model says,
    # and clipping them keeps the loss finite (values 1e8 steps away made the fit diverge)
    targets = np.clip(np.asarray(targets, dtype=np.float64), ACT_MIN, ACT_MAX)
    n = coords2.shape[0]
    if targets.shape != (n, m) or not 1 <= num_features <= m:
        raise ValueError("coords2 [N2, 3], parent [N2] and targets [N2, M] must agree")
    if n == 0:
        raise ValueError("no level-2 anchors to fit on")
    if cfg.neighbour_level not in (1, 2):
        raise ValueError(f"neighbour_level must be 1 or 2, got {cfg.neighbour_level}")
    return coords2, parent, coords1, attrs1, targets


def _initial_twin(data: _Data, num_features: int, voxel_scale: int, cfg: GGConvTrainConfig) -> GGConvFloat:
    """The float twin before training: column scales from the training rows' spread and output
    biases from the targets, or, with ``cfg.init``, the given twin's scales and weights."""
    t, m = data.targets.shape
    # column scales (powers of two, folded into the first layers at export)
    fi = data.feat_in
    fstd = float(fi[:, :num_features].std()) if fi.shape[0] > 1 else 1.0
    feat_q = torch.tensor([pow2_scale(fstd)] * num_features + [2.0 ** -GRID_FRAC_BITS] * 3, dtype=torch.float64)
    hr = data.head_raw
    xstd = hr[:, 4:].std(0) if t > 1 else torch.ones(m, dtype=torch.float64)
    head_q_raw = torch.tensor([pow2_scale(float(voxel_scale) / 2)] * 3 + [2.0 ** -3]
                              + [pow2_scale(float(s)) for s in xstd], dtype=torch.float64)

    if cfg.init is not None:
        feat_q, head_q_raw = cfg.init.feat_q.clone(), cfg.init.head_q_raw.clone()
    model = GGConvFloat(num_features, m, cfg, feat_q, head_q_raw)
    if cfg.init is not None:
        model.load_state_dict(cfg.init.state)  # the sizes come from the twin (encode.twin_train_config)
        with torch.no_grad():  # the twin learned the rate alone: its step adjustments start at 0, as in a fresh fit
            last = model.head[1].lin
            last.weight[2 * m:] = 0.0
            last.bias[2 * m:] = 0.25
    else:
        init_mean_outputs(model, data.targets, hr[:, 4:], cfg.parent_base)
    return model


def _start_quantization(model: GGConvFloat, data: _Data) -> None:
    """Switch the twin to its quantized mode, with activation ranges from one pass over the training rows."""
    t = data.targets.shape[0]
    stats: dict = {}
    with torch.no_grad():
        for lo in range(0, t, 8192):
            model(_batch(data, torch.arange(lo, min(t, lo + 8192))), collect=stats)
    model.start_quantization(stats)


def choose_parent_base(targets: torch.Tensor, xpar: torch.Tensor, mode: str = "choose"
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per channel (float [M] each): parent_base (1: the parent's value is the base of the mean,
    chosen when it predicts the channel better, by mean absolute residual, than the channel's
    median; on real scenes the median wins on most channels, tools/results/context.md), the
    initial output bias of the mean (0, or the median) and the spread of the residual about
    that prediction (the initial scale). mode "parent": the parent's value on every channel
    (scenes trained under the rate of that model, e.g. lghcc-train --rate-lambda, follow it)."""
    m = targets.shape[1]
    one = torch.ones(m, dtype=torch.float64)
    if not targets.shape[0]:
        return one, torch.zeros(m, dtype=torch.float64), one
    med = targets.nanmedian(0).values.nan_to_num(0.0)  # NaN: not coded; a channel never coded gets 0
    r_par, r_med = (targets - xpar).abs().nanmean(0), (targets - med).abs().nanmean(0)
    base = torch.where(r_med.isnan(), one, (r_par < r_med).to(torch.float64))
    if mode == "parent":
        base = one
    elif mode != "choose":
        raise ValueError(f"parent_base mode must be choose or parent, got {mode!r}")
    spread = torch.where(base > 0, r_par, r_med).nan_to_num(1.0) * 1.25 + 0.05
    return base, med * (1 - base), spread


def level_of_spread(spread: torch.Tensor) -> torch.Tensor:
    """The (real-valued) scale level whose nominal sigma is ``spread`` steps."""
    return ((spread.log() - LOG_SIGMA_MIN) / LOG_SIGMA_STEP).clamp(0, NUM_LEVELS - 1)


def init_mean_outputs(model: GGConvFloat, targets: torch.Tensor, xpar: torch.Tensor, mode: str = "choose") -> None:
    """Set the model's parent_base (``choose_parent_base``) and start its head's last layer from
    that constant prediction and its spread, with no step adjustment."""
    m = targets.shape[1]
    with torch.no_grad():
        base, center, spread = choose_parent_base(targets, xpar, mode)
        model.parent_base.copy_(base)
        last = model.head[1].lin
        last.weight.mul_(0.1)
        last.bias.zero_()
        last.bias[:m] = center
        last.bias[m:2 * m] = level_of_spread(spread)
        last.bias[2 * m:] = 0.25


def _train_phase(model: GGConvFloat, data: _Data, cfg: GGConvTrainConfig, rng, lr: float, steps: int, bar) -> None:
    """``steps`` Adam steps on random batches with a one-cycle learning rate peaking at ``lr``."""
    if steps <= 0:
        return
    t, m = data.targets.shape
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = one_cycle(opt, lr, steps)
    for step in range(steps):
        sel = torch.from_numpy(rng.integers(0, t, min(cfg.batch, t)))
        b = _batch(data, sel)
        mean, level, adj = model(b)
        loss, bits = rd_loss(mean, level, adj, b["targets"], cfg.lam)
        opt.zero_grad()
        (loss.mean() / m).backward()
        opt.step()
        sched.step()
        bar.update()
        if step % 10 == 0:
            bar.set_postfix(bits_per_anchor=f"{float(bits.detach().mean()):.1f}", quant=model.quant)


def rd_cost(params: GGConvParams, coords2, parent, coords1, attrs1, targets, voxel_scale: int, lam: float) -> float:
    """Exact integer-path rate (bits under the frozen tables) + lam * quantization MSE (squared
    base steps, 2^(a/2) / 12 per value), the quantity the fitting minimizes."""
    bits, adj = estimated_rate_bits(params, coords2, parent, coords1, attrs1, targets, voxel_scale)
    return bits + lam * float((np.exp2(adj / 2.0) / 12.0).sum())


def twin_outputs(model: GGConvFloat, coords2, parent, coords1, attrs1, voxel_scale: int, neighbours=None):
    """The twin's (quantized) outputs for every level-2 anchor, as float64 numpy arrays."""
    attrs1 = np.asarray(attrs1, dtype=np.int64)
    n, m = len(coords2), attrs1.shape[1]
    data = _prepare(coords2, attrs1[np.asarray(parent)], np.zeros((n, m)), voxel_scale, model.c, model.k,
                    model.radius_sq, model.d, np.arange(n, dtype=np.int64), neighbours, model.neighbour_level,
                    (np.asarray(coords1, dtype=np.int64), attrs1))
    with torch.no_grad():
        outs = [model(_batch(data, torch.arange(lo, min(n, lo + 8192)))) for lo in range(0, n, 8192)]
    return tuple(torch.cat([o[i] for o in outs]).numpy() for i in range(3))


def estimated_rate_bits(params: GGConvParams, coords2, parent, coords1, attrs1, targets, voxel_scale: int,
                        neighbours=None) -> tuple[float, np.ndarray]:
    """Bits of the level-2 attributes coded with the integer path's parameters and the frozen
    scale tables (symbols round(x / STEP_ADJUST_FACTORS[a])); also returns the step adjustments
    of the coded entries (flat; NaN targets are not coded)."""
    from .code_lengths import ideal_code_length_bits

    mean, level, adj = ggconv_coding_params(params, coords2, parent, coords1, attrs1, voxel_scale, neighbours)
    f = STEP_ADJUST_FACTORS[adj].astype(np.float64)
    t = np.asarray(targets, dtype=np.float64)
    live = np.isfinite(t)  # NaN: not coded
    sym = np.floor(np.where(live, t, 0.0) / f + 0.5).astype(np.int64)
    return ideal_code_length_bits((sym - mean)[live], level[live]), adj[live]


def zero_mean_prior_bits(targets) -> float:
    """Reference: each channel coded with one zero-mean Gaussian level fitted to its RMS."""
    from .code_lengths import ideal_code_length_bits, level_for_sigma

    x = np.asarray(targets, dtype=np.float64)
    sym = np.floor(x + 0.5).astype(np.int64)
    lv = level_for_sigma(np.sqrt((sym.astype(np.float64) ** 2).mean(0)))
    return ideal_code_length_bits(sym, np.broadcast_to(lv, sym.shape))
