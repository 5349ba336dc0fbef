#!/usr/bin/env python3
"""Candidate codings of the SH rest against today's, as ideal code lengths at equal distortion
(issue 55, item 1: the design measurement; no format change, nothing here is used by the codec).

For each scene and distortion level (a preset's SH band steps, or the steps a real encode chose:
``--levels low=0.12,0.16,0.2;...``) the SH rest x (bands 1..D, RGB) is taken in units of its band's
step, u = x / step(band), on the Gaussians' position grid in the normative (Morton) order, as the
encoder codes it. Distortion is the squared error in those units summed over a Gaussian's SH-rest
values (per Gaussian, every Gaussian alike): the presets' band steps are the codec's weighting of the
bands (a finer step where the renders are more sensitive), so today's uniform rounding in step units
is the allocation that metric favours, and a candidate cannot win by moving error between bands.
The per-Gaussian render weight (opacity x footprint) and RDOQ / step adjustment / SH degrees are left
out for every row alike (plain rounding); today's real streams (tools/stream_bits.py) are beside them.

Rows (bits per Gaussian of the SH rest, side information included):

- ``today``: q = rint(u) coded as the encoder codes it: neighbour prediction (6 LoDs, 6 neighbours,
  5 activity buckets, encoder/stream/neighbour_coding.py) with cross-channel prediction, ideal bits;
  ``prior only``: the per-channel prior alone (no neighbours), for scale.
- ``KLT``: a per-scene orthonormal transform (eigenvectors of the covariance of u, M x M at 16 bits
  each, plus the mean) of the whole SH-rest vector (``KLT 3x3``: only across the colour channels,
  one 3 x 3 for every coefficient); transform coefficients rounded at step s, coded by today's
  neighbour prediction (no cross-channel prediction: they are decorrelated).
- ``RAHT``: region-adaptive Haar transform (G-PCC's, weights = points) over the octree of the grid
  positions, Morton order, per value; high-pass coefficients rounded at step s, each coded with the
  best scale level of its context (log2 of the merged node's weight x channel; 6 bits per context);
  ``KLT+RAHT``: RAHT of the KLT coefficients.
- ``DC-linear + today``: a per-scene linear prediction of q from the decoded DC (M x 4 at 16 bits),
  rint of it subtracted, the residual coded by today's path.
- ``MLP ctx``: a context model trained per scene at encode time (as the anchor route's GG-Conv, but
  smaller): from the k coarser neighbours' decoded values (their mean and spread), the own and the
  neighbours' mean decoded DC, a mean and a scale per value (one hidden layer of ``--hidden``,
  ``--hidden 0``: linear), trained on up to ``--train-rows`` rows with the discretized-Gaussian code
  length; coded as the symbol coder codes (rint of the mean, the scale level nearest the scale), LoD 0
  by the per-channel prior; its weights and the features' normalization at 16 bits each are counted.
  ``KLT + MLP ctx``, ``KLT 3x3 + MLP ctx``: the same on the rounded KLT coefficients.

Transforms change the distortion at a given step, so they run at step factors ``--factors`` and their
bits are read at today's distortion (log-log interpolation); predictions code today's integers, so
their distortion is today's by construction.

    python tools/bench_sh_coding.py playbot-lod4=../shared/data/playbot/playbot_lod4_8k.ply \\
        --levels "low=0.06,0.12,0.16,0.2;medium=0.04,0.08,0.1,0.12" --out tools/results/sh_coding.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

from lghcc.common.attributes import GaussianLayout  # noqa: E402
from lghcc.common.entropy.symbol_coder import best_level_and_bits, code_lengths_bits  # noqa: E402
from lghcc.encoder.context.code_lengths import level_for_sigma  # noqa: E402
from lghcc.common.geometry import normative_order  # noqa: E402
from lghcc.common.knn import MAX_EXTENT  # noqa: E402
from lghcc.common.neighbour_prediction import NeighbourGraph, neighbour_graph  # noqa: E402
from lghcc.encoder.gaussians.gaussian_grid import choose_grid, snap_to_grid  # noqa: E402
from lghcc.encoder.stream.config import GaussianEncoderConfig  # noqa: E402
from lghcc.encoder.stream.neighbour_coding import NeighbourCoding  # noqa: E402

LODS, NEIGHBOURS, BUCKETS = 6, 6, 5  # today's neighbour prediction (encoder/stream/config.py defaults)
PARAM_BITS = 16  # a transform entry or a model weight, as half floats
LEVEL_BITS = 6  # a scale level (u(6))
# DC step and band steps of the gaussians sections of encoder/presets/{low,medium,high}.yaml
DEFAULT_LEVELS = "low=0.06,0.12,0.16,0.2;medium=0.04,0.08,0.1,0.12;high=0.03,0.06,0.08,0.1"


@dataclass
class ShScene:
    """A scene's SH rest on its position grid, rows in the normative order."""
    name: str
    coords: np.ndarray  # int64 [N, 3], unique
    rest: np.ndarray  # float64 [N, M] SH-rest values (coefficient-major, RGB inner)
    dc: np.ndarray  # float64 [N, 3]
    degree: int
    graph: NeighbourGraph

    @property
    def n(self) -> int:
        return self.rest.shape[0]


def load_sh_scene(name: str, path: str, position_step: float = 0.25) -> ShScene:
    """Reads a scene (any format lghcc reads; streamed SOG: its finest level) and puts it on the grid
    the encoder would (``position_step`` x the typical Gaussian size, duplicates separated)."""
    from lghcc.formats import read_scene

    scene = read_scene(path)
    if scene.sh_degree < 1:
        raise SystemExit(f"{path}: SH degree 0, no SH rest to code")
    voxel, origin = choose_grid(scene, GaussianEncoderConfig(position_step=position_step))
    grid, _ = snap_to_grid(scene, voxel, origin)
    return sh_scene_on_grid(name, grid.coords, scene.sh)


def sh_scene_on_grid(name: str, coords: np.ndarray, sh: np.ndarray) -> ShScene:
    """``coords`` int [N, 3] unique, ``sh`` [N, S, 3]: the scene in the normative order with its graph."""
    coords = np.asarray(coords, np.int64)
    coords = coords - coords.min(axis=0)
    if coords.max(initial=0) > MAX_EXTENT:
        raise SystemExit(f"{name}: extent beyond the neighbour graph's limit")
    order = normative_order(coords)
    n = coords.shape[0]
    sh = np.asarray(sh, np.float64)[order]
    degree = int(round(math.sqrt(sh.shape[1]))) - 1
    coords = coords[order]
    return ShScene(name, coords, sh[:, 1:].reshape(n, -1), sh[:, 0], degree,
                   neighbour_graph(coords, LODS, NEIGHBOURS))


def rest_steps(degree: int, band_steps: list[float]) -> np.ndarray:
    """float64 [M]: each SH-rest value's step (its band's)."""
    band = GaussianLayout(degree).band_of_channel()[3:]
    return np.asarray(band_steps, np.float64)[band - 1]


# --- today's coding -------------------------------------------------------------------------------

def today_bits(q: np.ndarray, dc_q: np.ndarray, sc: ShScene, channel_prediction: bool = True) -> float:
    """Ideal bits of the SH-rest integers ``q`` [N, M] as today's neighbour prediction codes them (the
    whole Gaussian's layout, DC included, as the stream has it; the other channels 0), with the SH
    rest's share of the table and prior (6 bits per bucket level, prior mean and level)."""
    layout = GaussianLayout(sc.degree)
    full = np.zeros((sc.n, layout.num_channels), np.int64)
    full[:, :3] = dc_q
    full[:, 3:layout.sh_channels] = q
    nc = NeighbourCoding(full, sc.coords, LODS, NEIGHBOURS, BUCKETS, channel_prediction, layout, graph=sc.graph)
    rest = slice(3, layout.sh_channels)
    bits = code_lengths_bits(nc.residuals[:, rest], nc.levels[:, rest]).sum()
    return float(bits) + q.shape[1] * (LEVEL_BITS * BUCKETS + LEVEL_BITS + 16)


def plain_bits(q: np.ndarray) -> float:
    """Ideal bits of ``q`` [N, M] under the per-channel prior (median mean, best level; no context)."""
    total = 0.0
    for c in range(q.shape[1]):
        total += best_level_and_bits(q[:, c] - int(np.median(q[:, c])))[1] + LEVEL_BITS + 16
    return total


def neighbour_bits(q: np.ndarray, sc: ShScene) -> float:
    """Ideal bits of arbitrary integer channels ``q`` [N, M] by today's neighbour prediction (no
    cross-channel prediction), the table and priors included."""
    nc = NeighbourCoding(q, sc.coords, LODS, NEIGHBOURS, BUCKETS, False, None, graph=sc.graph)
    return nc.ideal_bits() + q.shape[1] * (LEVEL_BITS * BUCKETS + LEVEL_BITS + 16)


# --- transforms -----------------------------------------------------------------------------------

def klt_basis(u: np.ndarray, colour_only: bool = False) -> np.ndarray:
    """float64 [M, M] orthonormal: the eigenvectors of the covariance of ``u`` [N, M], strongest
    first; ``colour_only``: one 3 x 3 (of the pooled RGB covariance) on every coefficient."""
    d = u - u.mean(axis=0)
    if not colour_only:
        w, v = np.linalg.eigh(d.T @ d / max(1, d.shape[0]))
        return v[:, np.argsort(w)[::-1]]
    rgb = d.reshape(d.shape[0], -1, 3).reshape(-1, 3)
    w, v3 = np.linalg.eigh(rgb.T @ rgb / max(1, rgb.shape[0]))
    return np.kron(np.eye(u.shape[1] // 3), v3[:, np.argsort(w)[::-1]])


def morton_codes(coords: np.ndarray) -> tuple[np.ndarray, int]:
    """uint64 [N] Morton codes (x most significant) of non-negative ``coords`` and their bit depth."""
    depth = max(1, int(coords.max(initial=0)).bit_length())
    code = np.zeros(coords.shape[0], np.uint64)
    for b in range(depth - 1, -1, -1):
        for axis in range(3):
            code = (code << np.uint64(1)) | ((coords[:, axis] >> b) & 1).astype(np.uint64)
    return code, 3 * depth


def raht(values: np.ndarray, coords: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Region-adaptive Haar transform (weights = points) of ``values`` [N, C] over the octree of the
    unique ``coords``, one binary merge per Morton bit: -> (high-pass coefficients [H, C], the merged
    node's weight of each [H], the root's low-pass [C]). Orthonormal: the coefficients' squared sum is
    the values' (so rounding errors in them are errors in the values)."""
    code, bits = morton_codes(coords)
    order = np.argsort(code, kind="stable")
    key, a, w = code[order], values[order].astype(np.float64), np.ones(len(order))
    highs, weights = [], []
    for _ in range(bits):
        parent = key >> np.uint64(1)
        first = np.zeros(len(key), bool)
        first[:-1] = parent[:-1] == parent[1:]  # sorted and unique: a pair's two nodes are adjacent
        second = np.roll(first, 1)
        i = np.flatnonzero(first)
        w1, w2 = w[i], w[i + 1]
        s1, s2, t = np.sqrt(w1)[:, None], np.sqrt(w2)[:, None], np.sqrt(w1 + w2)[:, None]
        low = (s1 * a[i] + s2 * a[i + 1]) / t
        highs.append((s1 * a[i + 1] - s2 * a[i]) / t)
        weights.append(w1 + w2)
        a[i], w[i] = low, w1 + w2
        keep = ~second
        key, a, w = parent[keep], a[keep], w[keep]
    h = np.concatenate(highs) if highs else np.zeros((0, values.shape[1]))
    return h, np.concatenate(weights) if weights else np.zeros(0), a[0]


def context_bits(q: np.ndarray, context: np.ndarray) -> float:
    """Ideal bits of the integers ``q`` [H, C], each column and context value at its best scale level
    (zero mean), 6 bits per (context, column) used."""
    total = 0.0
    for ctx in np.unique(context):
        sel = context == ctx
        for c in range(q.shape[1]):
            total += best_level_and_bits(q[sel, c])[1] + LEVEL_BITS
    return total


def raht_rate_distortion(z: np.ndarray, sc: ShScene, s: float) -> tuple[float, float]:
    """(bits, squared error) of RAHT coefficients of ``z`` rounded at step ``s`` (contexts: the merged
    node's weight class); the root's low-pass at 16 bits a value."""
    h, w, root = raht(z, sc.coords)
    q = np.rint(h / s)
    err = float(((q * s - h) ** 2).sum())
    ctx = np.minimum(np.floor(np.log2(w)).astype(np.int64), 16)
    return context_bits(q.astype(np.int64), ctx) + 16 * root.size, err


def transform_rate_distortion(u: np.ndarray, sc: ShScene, basis: np.ndarray | None, s: float,
                              coder: str) -> tuple[float, float]:
    """(bits, squared error) of ``u`` in the orthonormal ``basis`` (None: u itself) rounded at step ``s``
    and coded by ``coder`` (``neighbour``: today's neighbour prediction; ``raht``); the basis and the
    mean are counted at 16 bits an entry."""
    mean = u.mean(axis=0)
    z = u - mean if basis is None else (u - mean) @ basis
    side = PARAM_BITS * mean.size + (0 if basis is None else PARAM_BITS * basis.size)
    if coder == "raht":
        bits, err = raht_rate_distortion(z, sc, s)
        return bits + side, err
    q = np.rint(z / s)
    return neighbour_bits(q.astype(np.int64), sc) + side, float(((q * s - z) ** 2).sum())




# --- predictions ----------------------------------------------------------------------------------

def dc_linear_prediction(q: np.ndarray, dc_q: np.ndarray) -> tuple[np.ndarray, float]:
    """(int64 [N, M] rint of the least-squares prediction of ``q`` from [decoded DC, 1], its side bits)."""
    a = np.concatenate([dc_q.astype(np.float64), np.ones((dc_q.shape[0], 1))], axis=1)
    coef, *_ = np.linalg.lstsq(a, q.astype(np.float64), rcond=None)
    return np.rint(a @ coef).astype(np.int64), float(PARAM_BITS * coef.size)


def context_features(q: np.ndarray, dc_q: np.ndarray, sc: ShScene) -> tuple[np.ndarray, np.ndarray]:
    """(rows of LoD >= 1 [R], float32 features [R, 2M + 7]): per row its coarser neighbours' mean and
    spread (max - min) of every SH-rest integer, its own decoded DC, the neighbours' mean DC and the
    share of neighbours found: what the decoder knows before the row's SH rest."""
    rows, feats = [], []
    for level in range(1, len(sc.graph.rows)):
        r, nb = sc.graph.rows[level], sc.graph.neighbours[level]
        if r.size == 0:
            continue
        valid = nb >= 0
        safe = np.where(valid, nb, 0)
        cnt = valid.sum(axis=1, keepdims=True)
        vq = np.where(valid[:, :, None], q[safe], 0).astype(np.float64)
        mean = vq.sum(axis=1) / cnt
        lo = np.where(valid[:, :, None], q[safe], np.iinfo(np.int64).max).min(axis=1)
        hi = np.where(valid[:, :, None], q[safe], np.iinfo(np.int64).min).max(axis=1)
        dcn = np.where(valid[:, :, None], dc_q[safe], 0).sum(axis=1) / cnt
        feats.append(np.concatenate([mean, hi - lo, dc_q[r], dcn, cnt / nb.shape[1]], axis=1))
        rows.append(r)
    return np.concatenate(rows), np.concatenate(feats).astype(np.float32)


def _code_length_bits_torch(q, mu, log_sigma):
    """Bits of integers ``q`` under discretized Gaussians (mean ``mu``, scale exp(log_sigma))."""
    import torch

    sigma = torch.exp(log_sigma).clamp(0.11, 512.0)  # the scale tables' range (in steps)
    normal = torch.distributions.Normal(0.0, 1.0)
    p = normal.cdf((q - mu + 0.5) / sigma) - normal.cdf((q - mu - 0.5) / sigma)
    return -torch.log2(p.clamp_min(2.0 ** -24))


def train_context_model(feats: np.ndarray, target: np.ndarray, hidden: int, train_rows: int, steps: int,
                        seed: int = 0):
    """A per-scene context model (features -> mean and log scale of each value), fitted with the code
    length as loss on at most ``train_rows`` rows (full batch, Adam); -> (model, its parameter count)."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    rows = rng.choice(feats.shape[0], min(train_rows, feats.shape[0]), replace=False)
    x, y = torch.from_numpy(feats[rows]), torch.from_numpy(target[rows].astype(np.float32))
    m = target.shape[1]
    layers = [torch.nn.Linear(x.shape[1], 2 * m)] if hidden == 0 else \
        [torch.nn.Linear(x.shape[1], hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 2 * m)]
    model = torch.nn.Sequential(*layers)
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(steps):
        out = model(x)
        loss = _code_length_bits_torch(y, out[:, :m], out[:, m:]).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model, sum(p.numel() for p in model.parameters())


def context_model_bits(q: np.ndarray, dc_q: np.ndarray, sc: ShScene, hidden: int, train_rows: int,
                       steps: int) -> float:
    """Ideal bits of ``q`` with a per-scene context model (``hidden`` 0: linear), coded as the symbol
    coder codes (rint of the mean, the scale level nearest the scale); LoD 0 by the per-channel prior;
    the weights and the features' normalization at 16 bits each."""
    import torch

    rows, feats = context_features(q, dc_q, sc)
    centre, spread = feats.mean(axis=0), feats.std(axis=0) + 1e-6
    x = (feats - centre) / spread
    model, params = train_context_model(x, q[rows], hidden, train_rows, steps)
    m = q.shape[1]
    with torch.no_grad():
        out = model(torch.from_numpy(x)).double().numpy()
    r = q[rows] - np.rint(out[:, :m]).astype(np.int64)
    level = level_for_sigma(np.exp(out[:, m:]))
    bits = code_lengths_bits(r, level).sum()
    side = PARAM_BITS * (params + 2 * feats.shape[1])
    return float(bits) + plain_bits(q[sc.graph.rows[0]]) + side


# --- one scene at one distortion level -------------------------------------------------------------

@dataclass
class LevelResult:
    scene: str
    level: str
    steps: list[float]
    error: float  # today's squared error per Gaussian (step units)
    bits: dict  # row -> bits per Gaussian at today's error
    errors: dict  # transform row -> its squared error per Gaussian where it was coded


TRANSFORMS = (("KLT", "klt", "neighbour"), ("KLT 3x3", "colour", "neighbour"), ("RAHT", None, "raht"),
              ("KLT+RAHT", "klt", "raht"))


def step_at_distortion(factors: list[float], errors: list[float], target: float) -> float:
    """The step factor whose squared error is ``target``, interpolated in log-log over the sweep."""
    le, ls = np.log(errors), np.log(factors)
    order = np.argsort(le)
    le, ls = le[order], ls[order]
    t = math.log(target)
    j = int(np.clip(np.searchsorted(le, t), 1, len(le) - 1))
    f = (t - le[j - 1]) / (le[j] - le[j - 1]) if le[j] != le[j - 1] else 0.0
    return float(math.exp(ls[j - 1] + f * (ls[j] - ls[j - 1])))


def transform_rows(u: np.ndarray, dc_q: np.ndarray, sc: ShScene, factors: list[float], target: float,
                   ctx: dict) -> tuple[dict, dict]:
    """Each transform's bits at squared error ``target``: swept over ``factors``, then coded at the
    step factor the sweep gives for the target (its error beside it); the KLTs also with the context
    model (``ctx``: context_model_bits' options) on their rounded coefficients. -> (bits, errors)."""
    bits, errors = {}, {}
    for label, basis_kind, coder in TRANSFORMS:
        basis = None if basis_kind is None else klt_basis(u, colour_only=basis_kind == "colour")
        points = [transform_rate_distortion(u, sc, basis, s, coder) for s in factors]
        s_eq = step_at_distortion(factors, [e for _, e in points], target)
        bits[label], errors[label] = transform_rate_distortion(u, sc, basis, s_eq, coder)
        print(f"  {label}: " + ", ".join(f"s={s:g} {b / sc.n:.2f} b/G err {e / sc.n:.3f}"
                                        for s, (b, e) in zip(factors, points)) +
              f"; at s={s_eq:.3f}: {bits[label] / sc.n:.2f} b/G err {errors[label] / sc.n:.3f}", flush=True)
        if coder == "neighbour":
            z = (u - u.mean(axis=0)) @ basis
            qz = np.rint(z / s_eq).astype(np.int64)
            side = PARAM_BITS * (basis.size + u.shape[1])
            bits[label + " + MLP ctx"] = context_model_bits(qz, dc_q, sc, **ctx) + side
            errors[label + " + MLP ctx"] = errors[label]
    return bits, errors


def measure_level(sc: ShScene, level: str, dc_step: float, band_steps: list[float], factors: list[float],
                  hidden: int, train_rows: int, train_steps: int) -> LevelResult:
    """Every row at one distortion level (see the module doc)."""
    u = sc.rest / rest_steps(sc.degree, band_steps)
    q = np.rint(u).astype(np.int64)
    dc_q = np.rint(sc.dc / dc_step).astype(np.int64)
    err = float(((q - u) ** 2).sum())
    t0 = time.time()
    bits = {"today": today_bits(q, dc_q, sc), "prior only": plain_bits(q)}
    pred, side = dc_linear_prediction(q, dc_q)
    bits["DC-linear + today"] = today_bits(q - pred, dc_q, sc) + side
    ctx = {"hidden": hidden, "train_rows": train_rows, "steps": train_steps}
    bits["MLP ctx"] = context_model_bits(q, dc_q, sc, **ctx)
    print(f"{sc.name} {level}: today {bits['today'] / sc.n:.2f} b/G, err {err / sc.n:.3f} "
          f"({time.time() - t0:.0f} s)", flush=True)
    tbits, terrors = transform_rows(u, dc_q, sc, factors, err, ctx)
    bits.update(tbits)
    return LevelResult(sc.name, level, [dc_step, *band_steps], err / sc.n, {k: v / sc.n for k, v in bits.items()},
                       {k: v / sc.n for k, v in terrors.items()})


# --- report ---------------------------------------------------------------------------------------

ROWS = ("today", "prior only", "DC-linear + today", "MLP ctx", "KLT", "KLT + MLP ctx", "KLT 3x3", "KLT 3x3 + MLP ctx",
        "RAHT", "KLT+RAHT")


def table_lines(results: list[LevelResult]) -> list[str]:
    """The markdown table: bits per Gaussian of the SH rest at today's distortion, and each row's
    saving against today."""
    head = "| scene | level (DC; band steps) | error / G | " + " | ".join(ROWS) + " | best saving | transforms' error / today's |"
    lines = [head, "|" + "---|" * 3 + "---:|" * len(ROWS) + "---|---|"]
    for r in results:
        today = r.bits["today"]
        cells = [f"{r.bits[k]:.2f}" + ("" if k == "today" else f" ({r.bits[k] / today - 1:+.0%})") for k in ROWS]
        best = min((k for k in ROWS if k != "today"), key=lambda k: r.bits[k])
        steps = f"{r.steps[0]:g}; " + ", ".join(f"{s:g}" for s in r.steps[1:])
        lines.append(f"| {r.scene} | {r.level} ({steps}) | {r.error:.3f} | " + " | ".join(cells) +
                     f" | {best}: {1 - r.bits[best] / today:.1%} | {min(r.errors.values()) / r.error:.3f}-"
                     f"{max(r.errors.values()) / r.error:.3f} |")
    return lines


def parse_levels(text: str) -> list[tuple[str, float, list[float]]]:
    """``name=dc,b1[,b2[,b3]];...`` -> [(name, DC step, band steps)] (a scene uses its degree's)."""
    out = []
    for part in (p for p in text.split(";") if p.strip()):
        name, steps = part.split("=")
        v = [float(x) for x in steps.split(",")]
        if not 2 <= len(v) <= 4:
            raise SystemExit(f"--levels: {part!r} needs a DC step and one to three band steps")
        out.append((name.strip(), v[0], v[1:]))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scenes", nargs="+", help="NAME=PATH of scenes with an SH rest (.ply, .spz, .sog, lod-meta.json...)")
    p.add_argument("--levels", default=DEFAULT_LEVELS, help="distortion levels: NAME=DC,BAND1,BAND2,BAND3;... (default: the presets' steps)")
    p.add_argument("--factors", default="0.8,1,1.25,1.6", help="step factors the transforms sweep")
    p.add_argument("--position-step", type=float, default=0.25, help="grid voxel / typical size (medium's)")
    p.add_argument("--hidden", type=int, default=32, help="the MLP context model's hidden width")
    p.add_argument("--train-rows", type=int, default=20000)
    p.add_argument("--train-steps", type=int, default=300)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--note", default="", help="a line for the results file (e.g. today's real streams)")
    p.add_argument("--out", type=Path, default=Path("out/sh_coding.md"))
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    factors = [float(x) for x in args.factors.split(",")]
    results = []
    for spec in args.scenes:
        name, path = spec.split("=", 1)
        sc = load_sh_scene(name, path, args.position_step)
        print(f"{name}: {sc.n:,} Gaussians, SH degree {sc.degree}", flush=True)
        for level, dc_step, bands in parse_levels(args.levels):
            if len(bands) < sc.degree:
                raise SystemExit(f"--levels {level}: {len(bands)} band steps for {name} of SH degree {sc.degree}")
            results.append(measure_level(sc, level, dc_step, bands[:sc.degree], factors, args.hidden,
                                         args.train_rows, args.train_steps))
    lines = [f"Command: `{command_line('bench_sh_coding.py', argv)}`  ",
             f"Load average at the end: {load_average()}.", "", *table_lines(results)]
    if args.note:
        lines += ["", args.note]
    write_lines(args.out, lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
