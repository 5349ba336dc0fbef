"""Vector quantization of the SH rest (issue 34, tool 1), estimated at fixed steps without a format change.

For a 3DGS scene with an SH rest and a preset, at the preset's steps (as tools/bench_rdoq.py measures
its rows: the settings search's trial, PSNR on the search views and on tools/bench_real.py's orbit):

- ``base``: today's coding (the preset's RDOQ, step adjustment and SH-degree choice), at the step
  factors of ``--factors`` (the first two give the slope that converts PSNR into bytes);
- ``base, no degrees``: the same without the per-Gaussian SH degree (what the VQ rows build on);
- ``(a) K``: palette + index only (SOG-like): each Gaussian's SH rest is its palette entry;
- ``(b) K``: the palette entry is the prediction of the SH-rest vector; the residual is coded by
  today's scalar path (step adjustment, RDOQ, neighbour prediction) at today's steps.

The palette: deterministic k-means (float64, seeded k-means++-like start from a fixed generator) of
the kept Gaussians' SH-rest vectors in value units, each value weighted by its sensitivity (the
squared render derivative RDOQ weighs errors with, so the clustering minimizes the same distortion),
entries quantized at the band steps. Bits: the palette entries coded as the per-channel prior codes
values (each column about its median, at its best level), the indices' ideal code lengths (entropy
of the index histogram plus (K-1)/2 log2 N for an adaptive model), and the other values as the
search counts them (neighbour prediction's ideal stream bits, geometry as coded).

    python tools/bench_sh_vq.py ../shared/data/playbot/playbot_lod4_8k.ply --preset low --orbit-up -y
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse
import dataclasses
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lghcc.common.attributes import STEP_ADJUST_FACTORS, GaussianLayout, implied_w  # noqa: E402
from lghcc.common.entropy.symbol_coder import best_level_and_bits  # noqa: E402
from lghcc.common.scene import GaussianScene  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.encoder.gaussians.gaussian_fit import measure_contributions  # noqa: E402
from lghcc.encoder.gaussians.gaussian_views import fit_cameras, resolving_views  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import GROUPS, SettingsSearch, _scaled  # noqa: E402
from lghcc.encoder.gaussians.rdoq import channel_steps, sensitivities, sh_degree_subset  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs  # noqa: E402


def kmeans(v: np.ndarray, w: np.ndarray, k: int, iters: int = 25, seed: int = 0) -> np.ndarray:
    """Palette [k, D] (float64) of the rows of ``v`` [N, D] under the distance sum_c w_c (v_c - p_c)^2
    (per-row, per-value weights ``w``): a seeded greedy start (k-means++ on the weighted distance),
    then Lloyd iterations with weighted means; entries that lose every member keep their place."""
    rng = np.random.default_rng(seed)
    n = v.shape[0]
    k = min(k, n)
    start = [int(rng.integers(n))]
    best = assign_cost(v, w, v[start])[1]
    for _ in range(1, k):
        p = best / best.sum() if best.sum() > 0 else np.full(n, 1.0 / n)
        j = int(rng.choice(n, p=p))
        start.append(j)
        best = np.minimum(best, assign_cost(v, w, v[j:j + 1])[1])
    pal = v[start].copy()
    for _ in range(iters):
        idx, _ = assign_cost(v, w, pal)
        num = np.zeros_like(pal)
        den = np.zeros_like(pal)
        np.add.at(num, idx, w * v)
        np.add.at(den, idx, w)
        moved = den > 0
        new = np.where(moved, num / np.where(moved, den, 1.0), pal)
        if np.allclose(new, pal, atol=1e-9):
            break
        pal = new
    return pal


def assign_cost(v: np.ndarray, w: np.ndarray, pal: np.ndarray, chunk: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Each row's nearest palette entry under the weighted distance, and that distance."""
    idx = np.empty(v.shape[0], dtype=np.int64)
    cost = np.empty(v.shape[0], dtype=np.float64)
    wv2 = (w * v * v).sum(axis=1)
    for a in range(0, v.shape[0], chunk):
        sl = slice(a, a + chunk)
        d = wv2[sl, None] - 2.0 * (w[sl] * v[sl]) @ pal.T + w[sl] @ (pal * pal).T
        idx[sl] = np.argmin(d, axis=1)
        cost[sl] = np.maximum(d[np.arange(d.shape[0]), idx[sl]], 0.0)
    return idx, cost


def palette_bits(pq: np.ndarray) -> float:
    """The quantized entries coded as the per-channel prior codes values."""
    return float(sum(best_level_and_bits(pq[:, c] - int(np.median(pq[:, c])))[1] for c in range(pq.shape[1])))


def index_bits(idx: np.ndarray, k: int) -> float:
    """Ideal code lengths of the indices under their histogram, plus an adaptive model's learning cost."""
    counts = np.bincount(idx, minlength=k)
    counts = counts[counts > 0]
    n = idx.size
    return float(-(counts * np.log2(counts / n)).sum() + 0.5 * (counts.size - 1) * math.log2(max(n, 2)))


def rate_assignment(x: np.ndarray, pq: np.ndarray, idx: np.ndarray, rounds: int = 3, chunk: int = 128,
                    candidates: int = 0) -> np.ndarray:
    """Design br: each Gaussian's entry re-chosen for the fewest bits, not the nearest: the ideal code
    lengths of its rounded residuals rint(x - pq[k]) (step units; each column at the best level of the
    residuals of the previous assignment) plus -log2 of the entry's share; the rounding error is about
    the same whatever the entry (the same steps), so the rate decides. ``rounds`` times, shares and
    levels updated."""
    from lghcc.common.entropy.symbol_coder import best_level, code_lengths_bits

    k = pq.shape[0]
    near = None
    if 0 < candidates < k:  # only each row's nearest entries (step units) are costed
        near = np.empty((x.shape[0], candidates), dtype=np.int64)
        for a in range(0, x.shape[0], 1024):
            d = (x[a:a + 1024] ** 2).sum(1)[:, None] - 2 * x[a:a + 1024] @ pq.T + (pq * pq).sum(1)[None, :]
            near[a:a + 1024] = np.argpartition(d, candidates - 1, axis=1)[:, :candidates]
    for _ in range(rounds):
        r = np.rint(x - pq[idx]).astype(np.int64)
        levels = np.array([best_level(r[:, c]) for c in range(x.shape[1])], dtype=np.int64)
        counts = np.bincount(idx, minlength=k).astype(np.float64)
        length = np.where(counts > 0, -np.log2(np.maximum(counts, 1) / idx.size), np.inf)
        new = np.empty_like(idx)
        for a in range(0, x.shape[0], chunk):
            cand = np.broadcast_to(np.arange(k), (min(chunk, x.shape[0] - a), k)) if near is None else near[a:a + chunk]
            rr = np.rint(x[a:a + chunk, None, :] - pq[cand]).astype(np.int64)
            bits = code_lengths_bits(rr, np.broadcast_to(levels, rr.shape)).sum(axis=2) + length[cand]
            new[a:a + chunk] = cand[np.arange(cand.shape[0]), np.argmin(bits, axis=1)]
        if np.array_equal(new, idx):
            break
        idx = new
    return idx


class VQSearch(SettingsSearch):
    """The settings search's trial with the SH rest vector-quantized (design a or b, see the module doc)."""

    palettes: dict
    rate_rounds = 3
    candidates = 0  # 0: every entry costed

    def trial(self, cfg, design: str | None = None, k: int = 0, alpha: float = 1.0):
        """(decoded scene, bits, parts): ``design`` None is today's trial (SettingsSearch.evaluate)."""
        key = (cfg.prune_share, cfg.position_step)
        keep, grid, geometry_bits, values = self._grid(*key)
        degree = self.scene.sh_degree
        layout = GaussianLayout(degree)
        sh = layout.opacity_channel
        steps = channel_steps(cfg, degree)
        x = values / steps
        extra, pq, idx = 0.0, None, None
        if design is not None:
            if design not in ("bd", "brd"):  # "bd": b with the preset's SH-degree choice on the residual (bands above D: 0)
                cfg = dataclasses.replace(cfg, sh_degree_choice=False)
            pkey = (key[0], k, alpha)  # the kept rows depend on the pruning share only
            if pkey not in self.palettes:
                f = sh_degree_subset(self.sensitivity[keep], degree)[:, 3:sh]
                w = (f + 1e-12 * f.mean()) ** alpha
                pal = kmeans(values[:, 3:sh], w, k)
                self.palettes[pkey] = (pal, assign_cost(values[:, 3:sh], w, pal)[0])
            pal, idx = self.palettes[pkey]
            pq = np.rint(pal / steps[3:sh]).astype(np.int64)
            if design in ("br", "brd"):
                idx = rate_assignment(x[:, 3:sh], pq, idx, rounds=self.rate_rounds, candidates=self.candidates)
            used = np.unique(idx)
            extra = palette_bits(pq[used]) + index_bits(np.searchsorted(used, idx), used.size)
            if design in ("b", "bd", "br", "brd"):
                x = x.copy()
                x[:, 3:sh] -= pq[idx]
        adjust = self._adjust(key, grid, keep, x, layout, cfg, steps)
        factor = 1.0 if adjust is None else STEP_ADJUST_FACTORS[adjust].astype(np.float64)[:, None]
        q, degrees = np.rint(x / factor).astype(np.int64), None
        if cfg.rotation_length:
            q[:, layout.rotation_start] = 0
        if self.sensitivity is not None and cfg.rd_quantization > 0:
            q, degrees = self._rd_quantized(key, grid, keep, x, layout, cfg, adjust, steps)
        if design == "a":
            q[:, 3:sh] = 0
        dq = (q * factor).astype(np.float64)
        if design is not None:
            dq[:, 3:sh] += pq[idx]
        vals = (dq * steps).astype(np.float32)
        if cfg.rotation_length:
            wcol = layout.rotation_start
            vals[:, wcol] = implied_w(q[:, wcol], vals[:, wcol + 1:wcol + 4])
        dec = GaussianScene(grid.means, *layout.split(vals))
        if design == "a":  # the other channels as a scene without SH rest codes them
            l0 = GaussianLayout(0)
            q0 = np.concatenate([q[:, :3], q[:, sh:]], axis=1)
            attr = self._values_bits(key, grid, q0, adjust, None, l0)
        else:
            attr = self._values_bits(key, grid, q, adjust, degrees, layout)
        return dec, geometry_bits + attr + extra, extra


def psnr(mse: float) -> float:
    return -10 * math.log10(max(mse, 1e-12))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a 3DGS PLY with an SH rest")
    p.add_argument("--preset", default="low")
    p.add_argument("--factors", default="1,1.19", help="step factors of the base rows (the first two: the slope)")
    p.add_argument("--sizes", default="64,256,1024,4096", help="palette sizes")
    p.add_argument("--designs", default="a,b")
    p.add_argument("--sh-factors", default="", help="also rows with only the SH-rest band steps scaled by these")
    p.add_argument("--alphas", default="1", help="k-means weights: the sensitivities to these powers (0: unweighted)")
    p.add_argument("--orbit-up", default="-y")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--cache", type=Path, default=Path("/tmp/sh_vq_cache"), help="sensitivities kept here")
    p.add_argument("--out", type=Path, default=Path("out/sh_vq.md"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    scene = read_3dgs_ply(args.scene)
    cfg = load_config(args.preset, kind="gaussians")
    g = gaussians_from_scene(scene)
    args.cache.mkdir(parents=True, exist_ok=True)
    tag = args.cache / f"{Path(args.scene).stem}_{args.preset}.npz"
    if tag.exists():
        z = np.load(tag)
        contrib, f = z["contrib"], z["f"]
    else:
        contrib = measure_contributions(g, fit_cameras(scene, cfg.fit_views, cfg.fit_resolution), False)
        f = sensitivities(scene, resolving_views(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px))
        np.savez(tag, contrib=contrib, f=f)
    s = VQSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    s.palettes = {}
    from bench_real import orbit

    o = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    o.cams = orbit(scene.means, 12, 320, args.orbit_up)
    with torch.no_grad():
        o.targets = [render_3dgs(g, c, background=(0, 0, 0), backend="torch").image for c in o.cams]
    groups = [grp for grp in GROUPS if grp != "position" and (not grp.startswith("sh_band")
                                                               or int(grp[-1]) <= scene.sh_degree)]
    rows = []

    def run(label, trial_cfg, design=None, k=0, alpha=1.0):
        dec, bits, extra = s.trial(trial_cfg, design, k, alpha)
        share = trial_cfg.prune_share
        row = (label, bits / 8, psnr(s._mse(dec, share)), psnr(o._mse(dec, share)), extra / 8)
        rows.append(row)
        print(row, flush=True)
        return row

    factors = [float(x) for x in args.factors.split(",")]
    base = [run(f"base x{fac:g}", _scaled(cfg, groups, fac)) for fac in factors]
    nodeg = run("base, no degrees", dataclasses.replace(cfg, sh_degree_choice=False)) if cfg.sh_degree_choice else base[0]
    sh_groups = [grp for grp in groups if grp.startswith("sh_band")]
    for fac in (float(x) for x in args.sh_factors.split(",") if x):  # the SH rest's steps alone scaled
        run(f"SH-rest steps x{fac:g}", _scaled(cfg, sh_groups, fac))
    for alpha in (float(a) for a in args.alphas.split(",") if a):
        for d in (x for x in args.designs.split(",") if x):
            for k in (int(x) for x in args.sizes.split(",")):
                run(f"({d}) {k}, weights f^{alpha:g}", cfg, d, k, alpha)
    b0, b1 = base[0], base[1]
    slope_s = (b0[2] - b1[2]) / math.log(b0[1] / b1[1])
    slope_o = (b0[3] - b1[3]) / math.log(b0[1] / b1[1])
    lines = [f"Command: `{command_line('bench_sh_vq.py', argv)}`  ",
             f"Scene: {args.scene}, {scene.num_gaussians:,} Gaussians; preset {args.preset}; slope between factors "
             f"{factors[0]:g} and {factors[1]:g}: {slope_s:.2f} dB (search) / {slope_o:.2f} dB (orbit) per e-fold of bytes.",
             "", "| row | bytes | palette + index bytes | PSNR search / orbit dB | bytes vs base | at equal PSNR, search / orbit |",
             "|---|---:|---:|---|---:|---|"]
    for label, by, ps, po, ex in rows:
        eq_s = by / (b0[1] * math.exp((ps - b0[2]) / slope_s)) - 1
        eq_o = by / (b0[1] * math.exp((po - b0[3]) / slope_o)) - 1
        lines.append(f"| {label} | {by:,.0f} | {ex:,.0f} | {ps:.2f} / {po:.2f} | {by / b0[1] - 1:+.1%} | "
                     f"{eq_s:+.1%} / {eq_o:+.1%} |")
    lines += ["", f"Load average at the end: {load_average()}."]
    del nodeg
    write_lines(args.out, lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
