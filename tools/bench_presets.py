#!/usr/bin/env python3
"""What accuracy costs in time: every encoder preset on one scene.

For each preset: stream bytes and bits per anchor, encode and decode time, and the
fidelity of the decoded scene: PSNR of its renders against renders of the input scene
(same orbit cameras, our CPU renderer) and the attributes' RMS error in steps.
Writes a markdown table (default tools/results/presets.md).

    python tools/bench_presets.py --procedural 20000
    python tools/bench_presets.py path/to/scaffold_model --views 8 --size 256
    python tools/bench_presets.py runs/lego --data ../shared/data/lego/lego_100 --append

With --data (the images the scene was trained on) the decoded scene's test-view PSNR/SSIM
against the real images is reported too; --append adds this scene's section to the table file.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

import numpy as np

from benchutil import command_line  # noqa: E402  (tools/ is on the path when run as a script)

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", nargs="?", help="Scaffold-GS model folder or PLY (default: procedural scene)")
    ap.add_argument("--procedural", type=int, default=20000, help="anchors of the procedural scene")
    ap.add_argument("--presets", nargs="+", help="presets to run (default: all)")
    ap.add_argument("--views", type=int, default=6, help="orbit cameras for the render PSNR")
    ap.add_argument("--size", type=int, default=192, help="render width and height")
    ap.add_argument("--data", help="dataset of the scene: also report test-view PSNR/SSIM against its images")
    ap.add_argument("--background", default="white", help="background of --data (default white)")
    ap.add_argument("--append", action="store_true", help="append this scene's section to --out")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "presets.md"))
    args = ap.parse_args(argv)

    import torch

    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.formats.scaffold_io import read_scaffold
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.config import load_config, preset_names
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.render.metrics import psnr
    from lghcc.render.rasterizer import render_scene
    from lghcc.render.views import orbit_cameras

    torch.set_num_threads(args.threads)
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    scene = read_scaffold(args.input) if args.input else make_procedural_scene(args.procedural, seed=0)
    from lghcc.encoder.context.ggconv_train import find_context_twin
    twin = find_context_twin(args.input) if args.input else None  # as lghcc-enc: the training's GG-Conv twin
    test = None
    if args.data:
        from lghcc.encoder.training.evaluation import evaluate_scene
        from lghcc.render.datasets import load_dataset

        test = load_dataset(args.data, args.background).test
    source = args.input or f"procedural scene, {scene.num_anchors:,} anchors (seed 0)"
    cams = orbit_cameras(scene.positions(), args.views, width=args.size, height=args.size)
    with torch.no_grad():
        refs = [render_scene(scene, c).image.numpy() for c in cams]
    rows = []
    for name in args.presets or preset_names():
        cfg = load_config(name)
        t0 = time.perf_counter()
        res = encode_scene(scene, cfg, context_twin=twin)
        t_enc = time.perf_counter() - t0
        t0 = time.perf_counter()
        dec = decode_stream(res.data)
        t_dec = time.perf_counter() - t0
        with torch.no_grad():
            p = np.mean([psnr(render_scene(dec.scene, c).image.numpy(), r) for c, r in zip(cams, refs)])
        n = scene.num_anchors
        ev = evaluate_scene(dec.scene, test, args.background) if test is not None else None
        rows.append((name, len(res.data), 8 * len(res.data) / n, t_enc, t_dec, float(p),
                     res.stats.levels[2].context_model if 2 in res.stats.levels else "-", ev))
        print(f"{name}: {len(res.data):,} B, enc {t_enc:.1f} s, dec {t_dec:.2f} s, render PSNR {p:.2f} dB"
              + (f", test PSNR {ev['psnr']:.3f} dB" if ev else ""), flush=True)
    ref_ev = evaluate_scene(scene, test, args.background) if test is not None else None
    lines = [] if args.append else ["# Presets: size, time and fidelity", ""]
    lines += [f"## {source}", "",
             f"Command: `{command_line('bench_presets.py', argv)}`  ",
             f"Date: {datetime.date.today()}; {args.threads} torch threads; shared 2-core VM, load "
             f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} at the end (timings are noisy).  ",
             f"Scene: {source}. Fidelity: mean PSNR of {args.views} orbit renders ({args.size} px) of the decoded "
             "scene against the same renders of the input scene."
             + (f" Test PSNR/SSIM: the decoded scene on the {len(test)} test views of `{args.data}` (the input "
                f"scene itself: {ref_ev['psnr']:.3f} dB / {ref_ev['ssim']:.4f})." if test is not None else ""), "",
             "| preset | bytes | bits/anchor | encode s | decode s | render PSNR dB | level-2 model |"
             + (" test PSNR dB | test SSIM |" if test is not None else ""),
             "|---|---:|---:|---:|---:|---:|---|" + ("---:|---:|" if test is not None else "")]
    lines += [f"| {r[0]} | {r[1]:,} | {r[2]:.1f} | {r[3]:.1f} | {r[4]:.2f} | {r[5]:.2f} | {r[6]} |"
              + (f" {r[7]['psnr']:.3f} | {r[7]['ssim']:.4f} |" if r[7] else "") for r in rows]
    out = Path(args.out)
    prev = out.read_text() + "\n" if args.append and out.exists() else ""
    out.write_text(prev + "\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
