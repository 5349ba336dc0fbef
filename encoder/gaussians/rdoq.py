"""Rate-distortion optimized quantization of an explicit-Gaussian scene (informative).

Plain rounding gives every value the same treatment, while the pictures depend on the values
of different Gaussians very differently: a Gaussian that covers a hundred pixels against one
that covers a tenth of one, a rotation that turns an elongated Gaussian against one that turns
a round one, whose rotation the pictures do not show at all. With one quantization step per
attribute group (the format's), the encoder spends the same bits on both. RDOQ chooses, for
each value, between the rounded value, one step closer to the value its coding predicts (the
neighbours' mean with neighbour prediction, clause 11.7; the per-channel prior's otherwise),
and that predicted value itself, minimizing

    F_ic (x_ic - q)^2 + mu_g bits(q),

with x the value in steps, F_ic the sensitivity of the pictures to value c of Gaussian i (the
diagonal of J^T J, J the Jacobian of the rendered pixels with respect to the values, estimated
with random +-1 probes: E[(v^T J)^2] = diag(J^T J)), and bits(q) the code length under the
coding's scale level for that value. mu_g is the rate-distortion slope of a uniform quantizer
at the group's own step (mean F of the group x ln 2 / 6, in steps^2, times ``strength``): a
value as sensitive as its group's mean keeps the rounding's choice unless the bits saved are
worth the error by that slope, one the pictures barely show goes to the predicted value. So
the step of each group sets the precision of the values that matter, and each Gaussian's
sensitivity decides how much of it it gets: a per-Gaussian quantization without a per-Gaussian
step in the stream.

A Gaussian's orientation is the encoder's to choose as well. Its covariance R S^2 R^T is the
same for the quaternion q and -q, and for q g with the log scales permuted to follow the axes,
g any of the 24 turns that map the coordinate axes onto the axes (half-turns about an axis,
quarter-turns, turns about a diagonal): 48 ways to write one Gaussian, every one rendering the
same picture. Before the values are chosen, each Gaussian takes the way that codes cheapest
under its coding's means and scale levels: the 24 turns are ranked by the bits of their rounded
scales and rotation (the sign of each the one nearer the mean), and the TURN_CANDIDATES best
and the Gaussian's own are then costed in full, with the rotation's length (below). Each
Gaussian's own way is first the half-turn of largest |w| (q, q i, q j or q k, scales unchanged),
so that the coding's scale levels, fitted before the choice, are near those after it. On scenes
whose rotations the neighbours do not predict, this writes them the way the prior expects; on
scenes whose neighbours do predict them, the way the neighbours already took.

A rotation is read as a direction: the decoder keeps the quaternion as coded and renderers
normalize it (spec clause 11.1), so its length is the encoder's to choose. A shorter quaternion
rounds to fewer, smaller integers with a coarser direction: per-Gaussian precision for the
rotation. Each Gaussian's quaternion is given the length of ROTATION_NORMS (1 down to 1/8)
whose rounded multiple costs least in F (x - d)^2 + mu bits, d the rounded quaternion's
direction at the original length; its sensitivities scale by 1 / rho^2 (the pictures see the
direction). A zero quaternion, which has no direction, is never chosen.

With step adjustment (format 1.2, clause 11.8; ``step_adjust_choice``), each Gaussian's steps
are 2^(a/4) times its channels', a = 0..7 chosen per Gaussian before the values: the a whose plain
rounding costs least in sum_c F (x - q 2^(a/4))^2 + mu bits(q), with the means and levels fitted to
the rounding at a = 0 carried to the coarser step. RDOQ's one step is a per-value choice within
one precision; this is a per-Gaussian precision, which the pictures call for where a Gaussian is
barely seen (a uniform quantizer's best step goes as F^(-1/2)). The values are then chosen as
above in each Gaussian's own steps (x divided by its factor, F multiplied by its square).

Measured and left out (tools/results/sh_rotation_snaps.md; the code is at commit 91a5d73): a
Gaussian's SH rest set whole to its prediction, and a Gaussian symmetric about a body axis
turned about it towards its predicted rotation, each where RDOQ's cost falls. Neither changed
the bytes at equal PSNR on playbot lod4: a residual 0 still costs what its level says (12.3 of
24.4 SH-rest bits per Gaussian at low), few Gaussians are symmetric, and F, a derivative,
underrates long jumps on views it was not measured on.

The means of a finer LoD depend on the values chosen for the coarser ones, so the LoDs are
chosen in coding order. The scale levels are those fitted to the rounded values (the coder
fits its own to the values chosen). Cross-channel prediction is left out of the costs.

The decoder is unchanged by RDOQ: the stream holds the chosen values like any others (step
adjustment alone is a coding tool, signalled in the stream).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ...common.attributes import STEP_ADJUST_FACTORS, CodingParams, GaussianLayout
from ...common.entropy.symbol_coder import best_level, code_lengths_bits
from ...common.neighbour_prediction import (NeighbourGraph, adjusted_prior, neighbour_means_and_buckets,
                                           prior_level_in_steps)
from ...common.scene import GaussianScene
from ...common.sh_degree import FLAG_PROB_UNIT, coded_channels, flag_contexts, neighbour_degrees
from ...common.units import DEGREE_PROB_BITS
from ...render.camera import Camera
from ...render.rasterizer import quat_to_rotmat, rasterize
from ...render.sh import sh_to_rgb
from ...render.view_threads import map_views
from ..stream.level_coding import fit_per_channel_prior
from ..stream.memory import RDOQ_BLOCK_ROWS
from .gaussian_grid import OPACITY_LOGIT_LIMIT, canonical_rotations
from ..stream.neighbour_coding import NeighbourCoding, flag_counts, flag_probabilities


# Memory of one view's render forward and backward per Gaussian of the scene: 1,600 MiB over the
# scene's at 1M (4 views of 160 px; 3,139 MiB two at a time), so above about 600k Gaussians the views
# go one at a time (render/view_threads.py VIEW_MEMORY_BUDGET).
SENSITIVITY_VIEW_BYTES = 1700.0


def sensitivities(scene: GaussianScene, cams: list[Camera], probes: int = 1, seed: int = 0,
                  on_view=None) -> np.ndarray:
    """float64 [N, M]: per Gaussian and coded channel (GaussianLayout order: SH coefficient-major
    with RGB inner, opacity logit, 3 log scales, 4 rotation components), the sum over the views'
    pixels of the squared derivative of the rendered colour with respect to the value (module
    doc; ``probes`` random +-1 images per view)."""
    t = lambda a: torch.tensor(np.asarray(a, np.float64), dtype=torch.float32)  # noqa: E731
    n = scene.num_gaussians
    means = t(scene.means)
    sh = t(scene.sh).requires_grad_(True)
    op = t(np.clip(scene.opacity, -OPACITY_LOGIT_LIMIT, OPACITY_LOGIT_LIMIT)).requires_grad_(True)
    ls = t(scene.log_scales).requires_grad_(True)
    rot = t(canonical_rotations(scene.rotations)).requires_grad_(True)
    params = [sh, op, ls, rot]
    total = [torch.zeros_like(p, dtype=torch.float64) for p in params]
    gen = torch.Generator().manual_seed(seed)
    # each view's random images, drawn in the views' order before the views render two at a time
    signs = [[torch.randint(0, 2, (cam.height, cam.width, 3), generator=gen).float() * 2 - 1 for _ in range(probes)]
             for cam in cams]

    def view(k: int) -> list[list[torch.Tensor]]:
        """Per probe of view k, the squared gradients of the parameters."""
        cam = cams[k]
        d = means - torch.as_tensor(cam.center, dtype=torch.float32)
        d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-12)
        q = rot / rot.norm(dim=1, keepdim=True).clamp_min(1e-12)
        img = rasterize(means, q, torch.exp(ls), torch.sigmoid(op), sh_to_rgb(scene.sh_degree, sh, d), cam,
                        background=torch.zeros(3)).image
        return [[g.double() ** 2 for g in torch.autograd.grad(img, params, grad_outputs=v, retain_graph=j + 1 < probes)]
                for j, v in enumerate(signs[k])]

    for squares in map_views(view, range(len(cams)), view_bytes=SENSITIVITY_VIEW_BYTES * n):
        for probe in squares:  # added in the order one view after another adds them
            for acc, s in zip(total, probe):
                acc += s
        if on_view is not None:
            on_view()
    f = [a.numpy() / probes for a in total]
    return np.concatenate([f[0].reshape(n, -1), f[1].reshape(n, 1), f[2], f[3]], axis=1)


def group_slopes(f: np.ndarray, group_of_channel: np.ndarray, strength: float) -> np.ndarray:
    """float64 [M]: mu of each channel's group (module doc), from the sensitivities ``f``."""
    mu = np.zeros(f.shape[1], dtype=np.float64)
    for g in np.unique(group_of_channel):
        sel = group_of_channel == g
        mu[sel] = strength * float(take_rows(f, slice(0, 1) if uniform(f) else slice(None))[:, sel].mean()) \
            * math.log(2) / 6
    return mu


# Random +-1 images per view for the sensitivities: over 24 views one gives the same choices as
# two within 0.3% of the bytes and 0.04 dB (tools/results/rdoq.md), for half the backward renders.
SENSITIVITY_PROBES = 1
# The largest move, in steps, from the rounded value: the sensitivities are derivatives, good for
# small moves only (a colour clamped at 0 by the renderer has no derivative, yet moving it to a
# brighter mean shows). Measured on playbot lod4 (SH degree 2) at the low preset's steps: letting a
# value jump to its prediction from anywhere cost 3.9 dB for 15% of the bytes, while one step at
# most gives 2.6-4.8% fewer bytes at equal PSNR, and two steps the same (tools/results/rdoq.md).
MAX_JUMP = 1
# The lengths a rotation quaternion may be given (module doc): shorter ones round to fewer, smaller
# integers with a coarser direction. Longer ones (finer directions) were measured to give less:
# playbot lod4 at the low steps, 1.7% fewer bytes than unit length with 2 and sqrt 2 allowed, 2.0%
# without (tools/results/rdoq.md).
ROTATION_NORMS = (1.0, 2 ** -0.5, 0.5, 2 ** -1.5, 0.25, 2 ** -2.5, 0.125)


def _choose(x: np.ndarray, q0: np.ndarray, mean: np.ndarray, level: np.ndarray, f: np.ndarray,
            mu: np.ndarray) -> np.ndarray:
    """Per value, of the rounded value, one step towards the mean and the mean, the least cost."""
    toward = q0 - np.sign(q0 - mean)
    best, best_cost = q0, f * (x - q0) ** 2 + mu * code_lengths_bits(q0 - mean, level)
    for cand in (toward, np.where(np.abs(q0 - mean) <= MAX_JUMP, mean, toward)):
        cost = f * (x - cand) ** 2 + mu * code_lengths_bits(cand - mean, level)
        better = cost < best_cost
        best, best_cost = np.where(better, cand, best), np.where(better, cost, best_cost)
    return best


# How many of the 24 turns, ranked by the bits of their rounded scales and rotation at unit
# length, are costed in full with every rotation length (besides the Gaussian's own). Playbot lod4
# at the low preset's steps: 3 keep half of the 3.5% that all 24 save, 8 all of it.
TURN_CANDIDATES = 8


def _axis_turns() -> tuple[np.ndarray, np.ndarray]:
    """The 24 unit quaternions g, one of each +-g, whose rotations map the coordinate axes onto
    the axes: (float64 [24, 4, 4] the matrices of q -> q g (Hamilton product, (w, x, y, z)),
    int [24, 3] the permutation p that takes the scales along: axis a of q g is axis p[a] of q).
    The identity comes first."""
    gs = [np.eye(4)[i] for i in range(4)]  # the identity and the half-turns about the axes
    gs += [np.array([1.0, *(1 - 2 * b for b in s)]) / 2 for s in np.ndindex(2, 2, 2)]  # about the body diagonals
    gs += [(np.eye(4)[a] + sb * np.eye(4)[b]) * 2 ** -0.5  # quarter-turns; half-turns about face diagonals
           for a in range(4) for b in range(a + 1, 4) for sb in (1, -1)]
    mats = [np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]]) for w, x, y, z in gs]
    r = quat_to_rotmat(torch.from_numpy(np.stack(gs))).numpy()
    perms = np.argmax(np.abs(r), axis=1)  # column a of R(g) is +-axis p[a]
    return np.stack(mats), perms


AXIS_TURNS, AXIS_TURN_PERMS = _axis_turns()
_TURNS_SQUARED = AXIS_TURNS * AXIS_TURNS
_ONES4 = np.ones(4)


def _rotation_norms(x: np.ndarray, f: np.ndarray, mean: np.ndarray, level: np.ndarray, mu: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per row of unit quaternions ``x`` [n, 4] (in steps): the factor of ROTATION_NORMS whose
    rounded multiple costs least in F (x - direction)^2 + mu bits, the direction being the
    rounded quaternion normalized back to the length of x (module doc), and that cost
    (float64 [n] each)."""
    best, best_cost = np.ones(x.shape[0]), np.full(x.shape[0], np.inf)
    length = np.linalg.norm(x, axis=1, keepdims=True)
    for rho in ROTATION_NORMS:
        v = np.rint(rho * x)
        vlen = np.linalg.norm(v, axis=1, keepdims=True)
        err = x - v * (length / np.maximum(vlen, 1e-300))
        cost = (f * err * err) @ _ONES4 + mu * (code_lengths_bits((v - mean).astype(np.int64), level) @ _ONES4)
        better = (vlen[:, 0] > 0) & (cost < best_cost)
        best, best_cost = np.where(better, rho, best), np.where(better, cost, best_cost)
    return best, best_cost


def _length_indices(x: np.ndarray, f: np.ndarray, mean: np.ndarray, level: np.ndarray, mu: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """_rotation_norms for rotations coded as a length index and x, y, z (format 1.4, clause
    11.10; ``x`` with w >= 0): the length 2^(-k/2), k in LENGTH_INDICES, of least cost in F (x -
    direction)^2 + mu bits, the direction being (implied w, rounded x, y, z) at that length, the
    bits those of k and of x, y, z (float64 [n] each: the factor, the cost)."""
    best, best_cost = np.ones(x.shape[0]), np.full(x.shape[0], np.inf)
    length2 = (x * x) @ _ONES4
    for k in LENGTH_INDICES:
        rho = 2.0 ** (-k / 2)
        v = np.rint(rho * x[:, 1:])
        w = np.sqrt(np.maximum(rho * rho * length2 - (v * v).sum(axis=1), 0.0))
        err = x - np.concatenate([w[:, None], v], axis=1) / rho
        r = np.concatenate([np.full((x.shape[0], 1), float(k)), v], axis=1) - mean
        cost = (f * err * err) @ _ONES4 + mu * (code_lengths_bits(r.astype(np.int64), level) @ _ONES4)
        better = cost < best_cost
        best, best_cost = np.where(better, rho, best), np.where(better, cost, best_cost)
    return best, best_cost


# The length indices k (lengths 2^(-k/2)) RDOQ may give format-1.4 rotations. With w implied, the
# unit length alone codes best: through RDOQ at the low preset's fixed steps
# (tools/results/rotations.md section 3) playbot lod4 80,240 B with k = 0 only against 80,285-80,450 B
# with k = 0..6 (the index priced at levels 6-13), the donut 187,158 B against 187,287-188,992 B, at
# the same PSNR: the shorter lengths' coarser x, y, z no longer pay for their index. The format
# keeps the index (0 .. 15): it costs nothing where every Gaussian has k = 0.
LENGTH_INDICES = (0,)
# The scale level at which RDOQ prices a rotation length index before the coding is fitted to the
# indices chosen (rd_quantize): that of residuals 0 and 1 in equal shares
INDEX_LEVEL = best_level(np.array([0, 1]))
# The sensitivity given a length index (format 1.4) so that RDOQ's per-value choice never moves it:
# a move changes the quaternion's length, and with it the implied w, by far more than one step
FIXED = 1e30


def _as_length_index(x: np.ndarray, f: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations ``x`` [n, 4] (in steps, w >= 0, scaled to their lengths ``rho``) and their
    sensitivities as coded with a length index (clause 11.10): column w holds the index k of rho,
    fixed; a step of x, y or z also moves the implied w by v / w steps, which their
    sensitivities take in."""
    k = np.rint(-2 * np.log2(rho))
    w = np.maximum(x[:, :1], 0.5)  # (a w under half a step: the coupling bounded)
    x, f = x.copy(), f.copy()
    f[:, 1:] += f[:, :1] * (x[:, 1:] / w) ** 2
    x[:, 0], f[:, 0] = k, FIXED
    return x, f


def _turned(turn: np.ndarray, sign: np.ndarray, xr: np.ndarray, fr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions ``xr`` [n, 4] turned by the per-row AXIS_TURNS ``turn`` [n] times ``sign``
    [n] (+-1), and their sensitivities: the diagonal of M diag(f) M^T (exact for the signed
    permutations; the sign squares away). The sign multiplies the product, which is the product
    with the signed matrix exactly (rounding is symmetric about 0)."""
    return np.einsum("nij,nj->ni", AXIS_TURNS[turn], xr) * sign[:, None], np.einsum("nij,nj->ni", _TURNS_SQUARED[turn], fr)


_TURNS_T = np.concatenate([m.T for m in AXIS_TURNS], 1)  # [4, 96]: x @ _TURNS_T = every q g at once


def _turn_ranking(xr: np.ndarray, mean_r: np.ndarray, level_r: np.ndarray, mu_r: float, block: int = 16384,
                  length_index: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """For unit quaternions ``xr`` [n, 4] (in steps, contiguous) and their coding's means and
    levels: (float64 [n, 24] mu_r x the bits of each turn's rounded quaternion, float64 [n, 24] the
    sign each turn takes: the one nearer the mean). All 24 turns in one product, rows by blocks.
    ``length_index`` (format 1.4): the bits of x, y, z alone, the sign the one of w >= 0."""
    n, nt = xr.shape[0], len(AXIS_TURNS)
    bits, signs = np.empty((n, nt)), np.empty((n, nt))
    c0 = 1 if length_index else 0  # the first column counted
    for lo in range(0, n, block):
        hi = min(n, lo + block)
        xg = (xr[lo:hi] @ _TURNS_T).reshape(hi - lo, nt, 4)
        toward = xg[:, :, 0] if length_index else np.einsum("ntc,nc->nt", xg, mean_r[lo:hi])
        s = np.where(toward < 0, -1.0, 1.0)
        r = (np.rint(xg[:, :, c0:] * s[:, :, None]) - mean_r[lo:hi, None, c0:]).astype(np.int64)
        b = code_lengths_bits(r, np.broadcast_to(level_r[lo:hi, None, c0:], r.shape))
        bits[lo:hi] = mu_r * _quaternion_sum(b)
        signs[lo:hi] = s
    return bits, signs


def _quaternion_sum(b: np.ndarray) -> np.ndarray:
    """b [..., 4] summed over its last axis as the product with ones(4) summed it, (b0 + b2) + (b1 +
    b3) (the turns' ranking, and its ties, depend on the last bit); b [..., 3], the columns x, y, z
    (w not counted): that sum with b0 = 0."""
    if b.shape[-1] == 3:
        return b[..., 1] + (b[..., 0] + b[..., 2])
    return (b[..., 0] + b[..., 2]) + (b[..., 1] + b[..., 3])


def _orientation(x: np.ndarray, f: np.ndarray, mean: np.ndarray, level: np.ndarray, mu: np.ndarray,
                 scales: slice, rotation: slice, ways: np.ndarray | None = None, length_index: bool = False
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rows ``x`` [n, M] (in steps) with sensitivities ``f``, their coding's means and scale
    levels and the slopes ``mu`` [M], each Gaussian written the way that codes cheapest (module
    doc), or the way ``ways`` [n] gives where it is >= 0 (rd_quantize): (x, f) with the scale
    and rotation columns turned, the rotation scaled to its length, that length (float64 [n])
    and the ways (int64 [n]: turn + 24 where the quaternion is negated). ``length_index``: the
    rotations coded as a length index and x, y, z (format 1.4): w >= 0, and column w the index."""
    n = x.shape[0]
    mu_r = float(mu[rotation].max(initial=0.0))
    if not mu_r > 0:  # no rate term: plain rounding, as for every other value (no way chosen)
        if length_index:  # unit length (k = 0), w >= 0 already (the canonical rotations)
            x, f = x.copy(), f.copy()
            x[:, rotation], f[:, rotation] = _as_length_index(x[:, rotation], f[:, rotation], np.ones(n))
        return x, f, np.ones(n), np.full(n, -1, dtype=np.int64)
    xs, fs, xr, fr = x[:, scales], f[:, scales], x[:, rotation], f[:, rotation]
    mean_r, level_r = mean[:, rotation], level[:, rotation]
    perms, perm_of_turn = np.unique(AXIS_TURN_PERMS, axis=0, return_inverse=True)
    scale_bits = np.stack([code_lengths_bits((np.rint(xs[:, p]) - mean[:, scales]).astype(np.int64),
                                             level[:, scales]) @ mu[scales] for p in perms], 1)
    nt = len(AXIS_TURNS)
    fixed = np.zeros(n, dtype=bool) if ways is None else np.asarray(ways) >= 0
    # the first candidate of every row: the Gaussian as given, or the way given
    turn = np.where(fixed, np.maximum(ways, 0) % nt, 0) if ways is not None else np.zeros(n, dtype=np.int64)
    sign = np.where(fixed & (np.maximum(ways, 0) >= nt), -1.0, 1.0) if ways is not None else np.ones(n)
    candidates, free = [(slice(None), turn, sign)], np.flatnonzero(~fixed)
    if free.size and TURN_CANDIDATES > 0:  # then the best-ranked turns of the rows still to choose
        free = slice(None) if free.size == n else free  # (every row, the usual case: views, no gathers)
        ranking, signs = _turn_ranking(np.ascontiguousarray(xr[free]), np.ascontiguousarray(mean_r[free]),
                                       np.ascontiguousarray(level_r[free]), mu_r, length_index=length_index)
        ranking += scale_bits[free][:, perm_of_turn]
        best_turns = np.argsort(ranking, axis=1, kind="stable")[:, :TURN_CANDIDATES]
        best_signs = np.take_along_axis(signs, best_turns, 1)
        candidates += [(free, best_turns[:, k], best_signs[:, k]) for k in range(best_turns.shape[1])]
    best = best_cost = None
    for idx, t, sg in candidates:
        xt, ft = _turned(t, sg, xr[idx], fr[idx])
        if length_index:  # w is implied >= 0: the sign that makes it so
            neg = xt[:, 0] < 0
            xt[neg], sg = -xt[neg], np.where(neg, -sg, sg)
        rho, cost = (_length_indices if length_index else _rotation_norms)(xt, ft, mean_r[idx], level_r[idx], mu_r)
        cost += np.take_along_axis(scale_bits[idx], perm_of_turn[t][:, None], 1)[:, 0]
        cand = (xt, ft, rho, AXIS_TURN_PERMS[t], t + np.where(sg < 0, nt, 0))
        if best is None:
            best, best_cost = cand, cost
            continue
        better = cost < best_cost[idx]
        rows = better if isinstance(idx, slice) else idx[better]
        best_cost[rows] = cost[better]
        for b, c in zip(best, cand):
            b[rows] = c[better]
    xt, ft, rho, perm, way = best
    x, f = x.copy(), f.copy()
    x[:, scales], f[:, scales] = np.take_along_axis(xs, perm, 1), np.take_along_axis(fs, perm, 1)
    x[:, rotation] = xt * rho[:, None]
    f[:, rotation] = ft / (rho * rho)[:, None]  # the pictures see the direction: d/dx scales by 1 / rho
    if length_index:
        x[:, rotation], f[:, rotation] = _as_length_index(x[:, rotation], f[:, rotation], rho)
    return x, f, rho, way


def _half_turned(x: np.ndarray, f: np.ndarray, rotation: slice) -> tuple[np.ndarray, np.ndarray]:
    """x and f with each quaternion replaced by the one of largest |w| among q, q i, q j, q k
    (half-turns about the Gaussian's axes: the scales stay), w >= 0: the start nearest the
    identity, so that the coding's means and scale levels, fitted to the rounded values before
    the choice, are near those of the values chosen (playbot lod4: 118,243 B against 120,578 B
    from the rotations as given)."""
    xr = x[:, rotation]
    turn = np.argmax(np.abs(np.einsum("tij,nj->nti", AXIS_TURNS[:4], xr)[:, :, 0]), axis=1)
    xt, ft = _turned(turn, np.ones(turn.size), xr, f[:, rotation])
    x, f = x.copy(), f.copy()
    x[:, rotation] = np.where(xt[:, :1] < 0, -xt, xt)
    f[:, rotation] = ft
    return x, f


def _choose_rows(x: np.ndarray, mean: np.ndarray, level: np.ndarray, f: np.ndarray, mu: np.ndarray,
                 orientation: tuple[slice, slice] | None, ways: np.ndarray | None = None,
                 length_index: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The values chosen for rows ``x`` [n, M] given their coding's means and scale levels: the
    orientation and the rotation's length first (when ``orientation`` names the scale and
    rotation columns; ``ways`` and ``length_index`` as _orientation's), then each value. Returns
    them and the ways."""
    way = None
    if orientation is not None:
        scales, rotation = orientation
        x, f, rho, way = _orientation(x, f, mean, level, mu[0], scales, rotation, ways, length_index)
    q = _choose(x, np.rint(x).astype(np.int64), mean, level, f, mu)
    if orientation is not None and not length_index:  # never a zero quaternion (it has no direction): the rounded one instead
        zero = ~q[:, rotation].any(axis=1)
        if zero.any():
            r = np.rint(x[zero, rotation] / rho[zero, None]).astype(np.int64)
            r[~r.any(axis=1), 0] = 1
            q[zero, rotation] = r
    return q, way




def uniform(f: np.ndarray) -> bool:
    """Whether ``f`` [N, M] is one row broadcast to every Gaussian (``uniform_sensitivity``)."""
    return f.ndim == 2 and f.shape[0] > 1 and f.strides[0] == 0


def take_rows(f: np.ndarray, rows) -> np.ndarray:
    """f[rows] (``rows`` an index array or a slice); uniform sensitivities, one row broadcast to
    every Gaussian (``uniform_sensitivity``), stay one row broadcast, not copied per Gaussian."""
    if uniform(f):
        k = len(range(f.shape[0])[rows]) if isinstance(rows, slice) else len(rows)
        return np.broadcast_to(f[0], (k, f.shape[1]))
    return f[rows]


def uniform_sensitivity(n: int, m: int) -> np.ndarray:
    """float64 [n, m] of ones, every value equally sensitive (config.py sensitivity_model "uniform"):
    one row broadcast (read-only; no memory per Gaussian)."""
    return np.broadcast_to(np.ones(m), (n, m))


def _in_own_steps(x: np.ndarray, f: np.ndarray, rows, factor: np.ndarray | None,
                  rotation: slice | None) -> tuple[np.ndarray, np.ndarray]:
    """x[rows] and f[rows] as rd_quantize chooses them: in each row's own steps (``factor``
    [N, 1], the step adjustment's, None: the channels' steps) and, with ``rotation``, each
    quaternion half-turned (_half_turned)."""
    xb, fb = x[rows], take_rows(f, rows)
    if factor is not None:
        xb, fb = xb / factor[rows], fb * factor[rows] ** 2
    if rotation is not None:
        xb, fb = _half_turned(xb, fb, rotation)
    return xb, fb


# int32 holds the values chosen, and the sums of up to 32 neighbours' values the neighbour coding makes
# of them (clause 11.7, prediction_neighbours <= 32), where every |x| is below this
INT32_VALUE_LIMIT = float(1 << 26)


def chosen_values_dtype(x: np.ndarray) -> type[np.integer]:
    """int32 where the values chosen for ``x`` (in steps) fit it with their neighbours' sums: every
    value within INT32_VALUE_LIMIT (own steps, a quaternion turned and a length index within it too);
    int64 otherwise. Half the bytes of RDOQ's [N, M] values and of its coding fit's means."""
    if x.size == 0:
        return np.int64
    return np.int32 if max(float(x.max()), -float(x.min())) < INT32_VALUE_LIMIT else np.int64


def _rounded(x: np.ndarray, f: np.ndarray, factor: np.ndarray | None, rotation: slice | None) -> np.ndarray:
    """int [N, M] (chosen_values_dtype): the values x rounded in each row's own steps (_in_own_steps),
    block by block."""
    q0 = np.empty(x.shape, dtype=chosen_values_dtype(x))
    for lo in range(0, x.shape[0], RDOQ_BLOCK_ROWS):
        block = slice(lo, min(lo + RDOQ_BLOCK_ROWS, x.shape[0]))
        q0[block] = np.rint(_in_own_steps(x, f, block, factor, rotation)[0])
    return q0


@dataclass
class _LodCoding:
    """What the coding fitted to the rounded values gives each LoD's rows (rd_quantize): the
    per-channel prior (LoD 0), the channels whose mean is the neighbours', the scale level per
    channel and activity bucket, and the step adjustment (int [N] or None)."""
    prior: CodingParams
    flags: np.ndarray
    table: np.ndarray
    num_buckets: int
    adjust: np.ndarray | None

    def params(self, q: np.ndarray, lod: int, neighbours: np.ndarray | None, lo: int,
               rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean, level) [n, M] of ``rows``, LoD ``lod``'s rows lo .. lo + n - 1 (``neighbours``: the LoD's)."""
        m = self.flags.size
        if lod == 0 and self.adjust is not None:
            p = adjusted_prior(CodingParams(self.prior.mean[None, :], self.prior.level[None, :]), self.adjust[rows])
            return p.mean, p.level
        if lod == 0:
            return (np.broadcast_to(self.prior.mean, (rows.size, m)),
                    np.broadcast_to(self.prior.level, (rows.size, m)))
        mean, bucket = neighbour_means_and_buckets(q, neighbours[lo:lo + rows.size], self.num_buckets, self.flags,
                                                   self.prior.mean, self.adjust,
                                                   None if self.adjust is None else self.adjust[rows])
        return mean, np.take_along_axis(self.table.T, bucket, axis=0)


def rd_quantize(x: np.ndarray, f: np.ndarray, mu: np.ndarray, coords: np.ndarray, graph: NeighbourGraph | None,
                num_buckets: int, orientation: tuple[slice, slice] | None = None,
                ways: np.ndarray | None = None, adjust: np.ndarray | None = None,
                length_index: bool = False) -> np.ndarray:
    """int [N, M] (int32 where it holds them, chosen_values_dtype): the values chosen for ``x``
    (float [N, M], in steps, rows in coding order) with sensitivities ``f`` [N, M] and slopes ``mu``
    [M] (module doc). ``graph``: the neighbour graph of ``coords`` when neighbour prediction codes
    the rows (None: the per-channel prior).
    ``orientation``: the columns of the log scales and of the unit rotation quaternions
    (``orientation_columns``), whose orientation and rotation length are chosen per row.
    ``ways``: int [N], the way each Gaussian is to be written (0..47, from the half-turn start;
    what an earlier call chose), -1 where it is to be chosen; the ways chosen are written into
    it (None: every way chosen here, as the coding and the settings search choose them).
    ``adjust``: int [N], each row's step-adjustment index (clause 11.8; needs ``graph``): ``x`` is
    then in the channels' steps and the values chosen are in each row's own. ``length_index``: the
    rotations coded as a length index and x, y, z (format 1.4, clause 11.10; needs ``orientation``):
    the rotation's column w of the values chosen is then the index k of its length 2^(-k/2)."""
    factor = None if adjust is None else STEP_ADJUST_FACTORS[adjust].astype(np.float64)[:, None]
    turned = orientation is not None and x.shape[0] and float(np.max(mu[orientation[1]], initial=0.0)) > 0
    rotation = orientation[1] if turned else None
    q0 = _rounded(x, f, factor, rotation)
    if length_index and orientation is not None:
        q0[:, orientation[1].start] = 0  # the coding first fitted with unit lengths (index 0) in column w
    n, m = q0.shape
    if n == 0:
        return q0
    if graph is None:  # one LoD coded with the per-channel prior, fitted as the coder fits it
        graph = NeighbourGraph([np.arange(n)], [None])
        prior_mean, prior_level = fit_per_channel_prior(q0, np.broadcast_to(True, q0.shape), n)
        flags, table = np.zeros(m, dtype=bool), np.zeros((m, num_buckets), dtype=np.int64)
    else:  # the unit the coder would fit to the rounded values (the graph fixes L and k)
        nc = NeighbourCoding(q0, coords, len(graph.rows), 1, num_buckets, False, None, graph=graph, adjust=adjust)
        prior_mean, prior_level = nc.prior_mean, nc.prior_level
        flags = np.asarray(nc.unit.neighbour_mean_flag, dtype=bool)
        table = np.asarray(nc.unit.bucket_level, dtype=np.int64).reshape(m, num_buckets)
        del nc  # its [N, M] arrays (peak memory)
    if length_index and orientation is not None:  # the coding, fitted to unit lengths only, would price out
        w = orientation[1].start  # every other length: the index is priced as an even choice of two instead
        prior_level, table = prior_level.copy(), table.copy()
        prior_level[w] = table[w] = INDEX_LEVEL
    q = q0  # filled LoD by LoD: a row's means come from coarser LoDs' values chosen already
    coding = _LodCoding(CodingParams(prior_mean, prior_level), flags, table, num_buckets, adjust)
    for lod, rows in enumerate(graph.rows):
        for lo in range(0, rows.size, RDOQ_BLOCK_ROWS):
            block = rows[lo:lo + RDOQ_BLOCK_ROWS]
            mean, level = coding.params(q, lod, graph.neighbours[lod], lo, block)
            xb, fb = _in_own_steps(x, f, block, factor, rotation)
            q[block], way = _choose_rows(xb, mean, level, fb, mu[None, :], orientation,
                                         None if ways is None else ways[block], length_index)
            if ways is not None and way is not None:
                ways[block] = way
    return q


def step_adjust_choice(x: np.ndarray, f: np.ndarray, mu: np.ndarray, coords: np.ndarray, graph: NeighbourGraph,
                       num_buckets: int, max_index: int) -> np.ndarray:
    """int64 [N]: each row's step-adjustment index (clause 11.8), rows in coding order: the a in
    [0, max_index] whose rounding costs least in sum_c F (x - q 2^(a/4))^2 + mu bits(q - mean_a),
    x in the channels' steps. The means and scale levels are those the coder fits to the rounded
    values at a = 0, carried to the coarser steps as the coding carries them: the mean divided by
    the factor, the level lowered by ADJUST_LEVEL_SHIFT[a] (a coarser step narrows the
    distribution). A Gaussian the pictures barely see thus takes a coarse step for all of its
    values, one they see well keeps its channels' steps (module doc)."""
    n = x.shape[0]
    if max_index <= 0 or n == 0:
        return np.zeros(n, dtype=np.int64)
    q0 = np.rint(x).astype(np.int64)
    nc = NeighbourCoding(q0, coords, len(graph.rows), 1, num_buckets, False, None, graph=graph,
                         choose_mean_flags=False)
    mean0, level0 = q0 - nc.residuals, nc.levels
    del q0
    costs = np.empty((max_index + 1, n))
    # a block of rows at a time (each row's costs are its own: the same sums): the working arrays of
    # every index are [rows, M] float64, not the scene's
    for lo in range(0, n, RDOQ_BLOCK_ROWS):
        rows = slice(lo, min(lo + RDOQ_BLOCK_ROWS, n))
        xb, fb, mb, lb = x[rows], f[rows], mean0[rows].astype(np.float64), level0[rows]
        for a in range(max_index + 1):
            factor = float(STEP_ADJUST_FACTORS[a])
            q = np.rint(xb / factor)
            mean = np.rint(mb / factor)
            level = prior_level_in_steps(lb, a)  # every level, as a coarser step narrows any distribution
            costs[a, rows] = (fb * (xb - q * factor) ** 2).sum(axis=1) \
                + (mu[None, :] * code_lengths_bits((q - mean).astype(np.int64), level)).sum(axis=1)
    # (weighing the indices' own bits in, by their marginal over a first choice, changed the bytes by
    # -0.1 to +0.4% on playbot lod4: not done)
    return np.argmin(costs, axis=0).astype(np.int64)  # ties: the finer step


def orientation_columns(layout: GaussianLayout) -> tuple[slice, slice]:
    """The columns of the log scales and of the rotation quaternion (rd_quantize's ``orientation``)."""
    return slice(layout.scale_start, layout.rotation_start), slice(layout.rotation_start, layout.num_channels)


def channel_steps(cfg, sh_degree: int) -> np.ndarray:
    """float64 [M]: the quantization step of each coded channel (GaussianLayout order) in ``cfg``."""
    band_steps = np.array([cfg.sh_dc_step] + list(cfg.sh_band_steps), dtype=np.float64)
    return np.concatenate([band_steps[GaussianLayout(sh_degree).band_of_channel()], [cfg.opacity_step],
                           [cfg.scale_step] * 3, [cfg.rotation_step] * 4])


def channel_groups(sh_degree: int, transformed: bool = False) -> np.ndarray:
    """int [M]: each coded channel's step group (0-3: SH band, 4 opacity, 5 scales, 6 rotation). With
    the SH transform (format 1.6) the SH rest's channels hold coefficients of one step, every band's
    share mixed: one group (1)."""
    bands = GaussianLayout(sh_degree).band_of_channel()
    if transformed:
        bands = np.minimum(bands, 1)
    return np.concatenate([bands, [4], [5] * 3, [6] * 4])


def sh_degree_subset(f: np.ndarray, sh_degree: int) -> np.ndarray:
    """The columns of ``f`` [N, M] (any SH degree) that a scene of ``sh_degree`` codes."""
    sh = 3 * (sh_degree + 1) ** 2
    if uniform(f):
        return np.broadcast_to(np.concatenate([f[0, :sh], f[0, -8:]]), (f.shape[0], sh + 8))
    return np.concatenate([f[:, :sh], f[:, -8:]], axis=1)


def adjust_on_graph(x: np.ndarray, f: np.ndarray, degree: int, coords: np.ndarray, order: np.ndarray, graph,
                    cfg, transformed: bool = False) -> np.ndarray | None:
    """int64 [N] (scene order): the step-adjustment indices encoder/gaussians/rdoq.py step_adjust_choice
    gives values ``x`` [N, M] (in the channels' steps) with sensitivities ``f``, ``graph`` being
    the neighbour graph of ``coords[order]`` (the normative order); None where every index is 0
    (the stream then carries nothing of the tool). ``transformed``: the SH rest holds transform
    coefficients (format 1.6)."""
    mu = group_slopes(f, channel_groups(degree, transformed), cfg.rd_quantization)
    adjust = np.empty(x.shape[0], dtype=np.int64)
    adjust[order] = step_adjust_choice(x[order], take_rows(f, order), mu, coords[order], graph, cfg.prediction_buckets,
                                       cfg.step_adjust_max)
    return adjust if adjust.any() else None


# Rounds of the SH-degree choice (sh_degree_choice): the first prices the flags at one bit each,
# every later one at the flags' probabilities and contexts of the round before.
DEGREE_ROUNDS = 2
# The weight of the pictures' error of a dropped band against its bits (1: RDOQ's slopes). F, a
# derivative from the fit views, underrates what a whole band's loss shows on other views: on
# playbot lod4 (tools/results/sh_degree.md) weight 1 gave
# 2.3% fewer bytes at equal PSNR on the search views but 0.9% on the orbit at low; weights 2-4
# gave 1.5-2.6% on both at low, medium and high (within about 0.3% of each other).
DEGREE_DISTORTION_WEIGHT = 2.0


def _band_gains(x: np.ndarray, q: np.ndarray, f: np.ndarray, mu: np.ndarray, bits: np.ndarray,
                layout: GaussianLayout) -> np.ndarray:
    """float64 [N, d]: per row and band b = 1 .. d, in bits, what dropping the band costs: the
    pictures' error of its values decoded as 0 instead of q (F-weighted, over the band's slope mu)
    less the bits of its residuals. A band whose slope is 0 (the views see none of its values):
    no distortion where F is 0 too, else never dropped."""
    band = layout.band_of_channel()
    gains = np.empty((x.shape[0], layout.sh_degree))
    for b in range(1, layout.sh_degree + 1):
        c = np.flatnonzero(band == b)
        added = (f[:, c] * (x[:, c] ** 2 - (x[:, c] - q[:, c]) ** 2)).sum(axis=1)
        slope = float(mu[c].max())
        per_bit = DEGREE_DISTORTION_WEIGHT * added / slope if slope > 0 else np.where(added > 0, np.inf, 0.0)
        gains[:, b - 1] = per_bit - bits[:, c].sum(axis=1)
    return gains


def _flag_bits(degrees: np.ndarray | None, graph: NeighbourGraph, sh_degree: int) -> np.ndarray:
    """float64 [N, d, 2]: per row and band, the bits of a flag 0 and of a flag 1 (clause 11.9) under
    the probabilities the coder fits to ``degrees`` and the contexts their neighbours give; one
    bit each where ``degrees`` is None."""
    n = graph.rows[0].size + sum(r.size for r in graph.rows[1:])
    if degrees is None:
        return np.ones((n, sh_degree, 2))
    p = np.asarray(flag_probabilities(flag_counts(graph, degrees, sh_degree)), np.float64)
    p1 = ((FLAG_PROB_UNIT * p + FLAG_PROB_UNIT / 2) / (FLAG_PROB_UNIT << DEGREE_PROB_BITS)).reshape(sh_degree, -1)
    bits = np.empty((n, sh_degree, 2))
    for lod, rows in enumerate(graph.rows):
        nd = neighbour_degrees(graph.neighbours[lod], degrees) if lod else None
        for b in range(1, sh_degree + 1):
            one = p1[b - 1][flag_contexts(b, nd, np.arange(rows.size))]
            bits[rows, b - 1, 0], bits[rows, b - 1, 1] = -np.log2(1 - one), -np.log2(one)
    return bits


def _degree_costs(gains: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """float64 [N, d + 1]: the cost in bits of each degree D, relative to keeping every band: the
    gains of the bands above D plus the flags D codes (ones for bands 1 .. D, a zero for D + 1)."""
    n = gains.shape[0]
    dropped = np.concatenate([np.cumsum(gains[:, ::-1], axis=1)[:, ::-1], np.zeros((n, 1))], axis=1)
    ones = np.concatenate([np.zeros((n, 1)), np.cumsum(flags[:, :, 1], axis=1)], axis=1)
    zero = np.concatenate([flags[:, :, 0], np.zeros((n, 1))], axis=1)
    return dropped + ones + zero


def sh_degree_choice(x: np.ndarray, q: np.ndarray, f: np.ndarray, mu: np.ndarray, coords: np.ndarray,
                     graph: NeighbourGraph, num_buckets: int, layout: GaussianLayout,
                     adjust: np.ndarray | None = None, coding: NeighbourCoding | None = None) -> np.ndarray:
    """int64 [N]: each row's SH degree (format 1.3, clause 11.9), rows in coding order: the D in
    [0, d] of least cost in bits, the pictures' error of the bands above D decoded as 0 instead
    of the values ``q`` chosen (RDOQ's, in each row's own steps) over the bands' slopes ``mu``
    [M], less those bands' residual bits, plus the bits of the flags D codes. ``x`` (in the
    channels' steps) and ``f`` as rd_quantize's. The residuals' bits are those of the coding
    fitted to ``q``; the flags' bits those of the probabilities and contexts of the round before
    (DEGREE_ROUNDS); ``coding``: that coding when the caller has it. A Gaussian whose colour the
    views do not see change keeps no band."""
    n, d = x.shape[0], layout.sh_degree
    if d == 0 or n == 0:
        return np.full(n, d, dtype=np.int64)
    if adjust is not None:
        factor = STEP_ADJUST_FACTORS[adjust].astype(np.float64)[:, None]
        x, f = x / factor, f * factor ** 2
    nc = coding or NeighbourCoding(q, coords, len(graph.rows), 1, num_buckets, False, None, graph=graph, adjust=adjust)
    gains = _band_gains(x, q, f, mu, code_lengths_bits(nc.residuals, nc.levels), layout)
    degrees = None
    for _ in range(DEGREE_ROUNDS):
        costs = _degree_costs(gains, _flag_bits(degrees, graph, d))
        degrees = d - np.argmin(costs[:, ::-1], axis=1)  # ties: the higher degree
    return degrees.astype(np.int64)


def sh_degrees_wanted(cfg, sensitivity: np.ndarray | None, degree: int) -> bool:
    """The per-Gaussian SH degree needs an SH rest, the sensitivities and RDOQ (and, checked by the
    callers, neighbour prediction)."""
    return cfg.sh_degree_choice and degree > 0 and sensitivity is not None and cfg.rd_quantization > 0


def without_dropped_bands(q: np.ndarray, degrees: np.ndarray, layout: GaussianLayout) -> np.ndarray:
    """``q`` [N, M] with the values of every band above each row's degree set to 0 (clause 11.9)."""
    return q * coded_channels(layout.sh_channels, layout.num_channels, degrees)


def degrees_on_graph(x: np.ndarray, q: np.ndarray, f: np.ndarray, layout: GaussianLayout, coords: np.ndarray,
                     order: np.ndarray, graph, cfg, adjust: np.ndarray | None = None) -> np.ndarray | None:
    """int64 [N] (scene order): each Gaussian's SH degree by sh_degree_choice, for values ``x``
    [N, M] (channels' steps), their RDOQ'd values ``q`` (own steps) and sensitivities ``f``
    (``adjust`` in scene order), ``graph`` the neighbour graph of ``coords[order]``; None where
    every Gaussian keeps every band, or where the attributes' ideal bits with the degrees (their
    flags and unit included) are not fewer than without (a scene the tool does not help pays
    nothing for it)."""
    mu = group_slopes(f, channel_groups(layout.sh_degree, layout.sh_transform is not None), cfg.rd_quantization)
    a = None if adjust is None else adjust[order]
    xo, qo, co = x[order], q[order], coords[order]
    args = (co, len(graph.rows), 1, cfg.prediction_buckets, False, layout)
    without = NeighbourCoding(qo, *args, graph=graph, adjust=a)
    chosen = sh_degree_choice(xo, qo, take_rows(f, order), mu, co, graph, cfg.prediction_buckets, layout, a, without)
    if (chosen == layout.sh_degree).all():
        return None
    with_tool = NeighbourCoding(without_dropped_bands(qo, chosen, layout), *args, graph=graph, adjust=a,
                                degrees=chosen)
    if with_tool.ideal_stream_bits() >= without.ideal_stream_bits():
        return None
    degrees = np.empty(x.shape[0], dtype=np.int64)
    degrees[order] = chosen
    return degrees
