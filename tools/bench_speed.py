#!/usr/bin/env python3
"""Encoding time of an explicit-Gaussian scene per preset, by stage, against a baseline measured
in the same process (issue 12's target: a 150k-Gaussian scene at ``medium`` in <= 10 minutes
on 2 cores).

The scene: ``--gaussians`` Gaussians drawn at random (seed 0) from a 3DGS PLY (default the
PlayCanvas logo of shared/data, 307k Gaussians), so that the count is the one the target names.
For each preset: contributions, settings search, fit and coding times (the encoder's own
statistics), the wall time of the whole encode, and the stream's bytes and search PSNR. The
baseline: one forward render of the whole scene at 320x320 on the CPU rasterizer, timed before
and after the presets (the median of 3 each); "x baseline" divides by it, which stays
comparable when the shared machine is slower or faster.

    python tools/bench_speed.py                           # 150k of the logo, low, medium, high
    python tools/bench_speed.py --presets medium --gaussians 50000
    python tools/bench_speed.py --presets medium,fast --copies 4 --gaussians 1000000   # a 1M scene

``--copies K`` places K copies of the scene side by side along x (none overlap) before the draw,
for scenes larger than the source (issue 32: time per Gaussian as the scene grows).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse  # noqa: E402
import datetime
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENE = ROOT.parent / "shared" / "data" / "playcanvas-logo" / "playcanvas_logo_307k.ply"


def baseline_render_s(scene) -> float:
    """Median of 3 forward renders of the scene at 320x320 from a fit camera."""
    from lghcc.encoder.gaussians.gaussian_views import fit_cameras
    from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs

    g = gaussians_from_scene(scene)
    cam = fit_cameras(scene, 1, 320)[0]
    times = []
    with torch.no_grad():
        for _ in range(3):
            t = time.perf_counter()
            render_3dgs(g, cam, background=(0, 0, 0), backend="torch")
            times.append(time.perf_counter() - t)
    return float(np.median(times))


def encode_once(scene, preset: str) -> dict:
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.gaussians.gaussian_fit import needs_preparation, prepare_gaussians
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
    from lghcc.encoder.stream.stats import PrepareStats

    cfg = load_config(preset, kind="gaussians")
    t0, cpu0 = time.perf_counter(), time.process_time()
    if needs_preparation(cfg):
        prep = prepare_gaussians(scene, cfg, log=lambda m: print(f"bench_speed: {preset}: {m}", file=sys.stderr,
                                                                 flush=True))
        scene, cfg, weights, sensitivity, s = prep.scene, prep.cfg, prep.weights, prep.sensitivity, prep.stats
    else:  # the fast preset: coded as it comes, less what no rasterizer draws (encoder/api.py)
        from lghcc.encoder.gaussians.gaussians import without_invisible

        weights, sensitivity, s = None, None, PrepareStats(gaussians_in=scene.num_gaussians)
        scene, _ = without_invisible(scene, cfg)
    t1 = time.perf_counter()
    result = encode_gaussian_scene(scene, cfg, weights=weights, sensitivity=sensitivity)
    t2 = time.perf_counter()
    return {"preset": preset, "bytes": len(result.data), "kept": scene.num_gaussians,
            "contrib_s": s.time_contributions_s, "sens_s": s.time_sensitivities_s or 0.0,
            "search_s": s.time_search_s or 0.0, "fit_s": s.time_fit_s or 0.0,
            "check_s": (s.time_trim_s or 0.0) + (s.time_whole_check_s or 0.0), "sample": s.search_sample_gaussians,
            "prepare_s": t1 - t0, "code_s": t2 - t1, "total_s": t2 - t0, "trials": s.search_trials or 0,
            "cpu_s": time.process_time() - cpu0}


def side_by_side(src, copies: int):
    """``copies`` copies of the scene in a row along x, each shifted by 1.05 x the scene's width
    (none overlap)."""
    if copies <= 1:
        return src
    from lghcc.common.scene import GaussianScene

    width = float(src.means[:, 0].max() - src.means[:, 0].min()) * 1.05
    shift = np.repeat(np.arange(copies) * width, src.num_gaussians).astype(np.float32)
    means = np.tile(src.means, (copies, 1))
    means[:, 0] += shift
    rep = lambda a: np.concatenate([a] * copies)  # noqa: E731
    return GaussianScene(means, rep(src.sh), rep(src.opacity), rep(src.log_scales), rep(src.rotations))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=DEFAULT_SCENE, help="a 3DGS PLY, SPZ or SOG file")
    ap.add_argument("--gaussians", type=int, default=150_000, help="Gaussians drawn from it (default 150000)")
    ap.add_argument("--copies", type=int, default=1,
                    help="copies of the scene placed side by side along x before the draw (default 1; 4 copies of "
                         "the 307k logo for a 1M scene)")
    ap.add_argument("--presets", default="low,medium,high")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "speed.md")
    args = ap.parse_args(argv)
    if not args.scene.is_file():
        print(f"bench_speed: {args.scene} not found (shared/data missing? pass --scene)", file=sys.stderr)
        return 1
    torch.set_num_threads(args.threads)
    from lghcc.formats import read_scene

    one = read_scene(args.scene)
    src = side_by_side(one, args.copies)
    n = min(args.gaussians, src.num_gaussians)
    keep = np.zeros(src.num_gaussians, bool)
    keep[np.random.default_rng(0).choice(src.num_gaussians, n, replace=False)] = True
    scene = src.subset(keep)
    base0 = baseline_render_s(scene)
    rows = [encode_once(scene, p) for p in args.presets.split(",")]
    base = (base0 + baseline_render_s(scene)) / 2
    lines = [
        "# Encoding speed of explicit-Gaussian scenes",
        "",
        f"Command: `{command_line('bench_speed.py', argv)}`  ",
        f"Date: {datetime.date.today()}; torch {torch.__version__}, {args.threads} threads, "
        f"{platform.processor() or platform.machine()}; load {load_average()} at the end (shared machine).  ",
        f"Scene: {n:,} of the {src.num_gaussians:,} Gaussians of "
        + (f"{args.copies} copies side by side of " if args.copies > 1 else "")
        + f"`{args.scene.name}` (drawn at random, seed 0), SH degree "
        f"{scene.sh_degree}. Baseline: one 320x320 forward render of it, {base:.3f} s (mean of the medians "
        "before and after the presets). Stage times are the encoder's own; total = prepare + code "
        "(the verification decode of lghcc-enc and reading the file are not included). CPU s: the process's "
        "CPU time over the encode (both threads; on a loaded machine about twice the wall time a quiet one "
        "would take).",
        "",
        "| preset | bytes | Gaussians kept | search sample | search trials | contributions s | sensitivities s "
        "| search s | fit s | trim + whole check s | code s | total s | us / Gaussian | CPU s | total x baseline |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['bytes']:,} | {r['kept']:,} | {r['sample'] or 'whole'} | {r['trials']} | "
                     f"{r['contrib_s']:.1f} | {r['sens_s']:.1f} | {r['search_s']:.1f} | {r['fit_s']:.1f} | "
                     f"{r['check_s']:.1f} | {r['code_s']:.1f} | {r['total_s']:.1f} | {1e6 * r['total_s'] / n:,.0f} | "
                     f"{r['cpu_s']:.0f} | "
                     f"{r['total_s'] / base:,.0f} |")
    write_lines(args.out, lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
