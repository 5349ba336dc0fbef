#!/usr/bin/env python3
"""What accuracy costs in time: every encoder preset on one scene.

For each preset: stream bytes and bits per anchor, encode and decode time, and the
fidelity of the decoded scene: PSNR of its renders against renders of the input scene
(same orbit cameras, our CPU renderer) and the attributes' RMS error in steps.
Writes a markdown table (default tools/results/presets.md).

    python tools/bench_presets.py --procedural 20000
    python tools/bench_presets.py path/to/scaffold_model --views 8 --size 256
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", nargs="?", help="Scaffold-GS model folder or PLY (default: procedural scene)")
    ap.add_argument("--procedural", type=int, default=20000, help="anchors of the procedural scene")
    ap.add_argument("--presets", nargs="+", help="presets to run (default: all)")
    ap.add_argument("--views", type=int, default=6, help="orbit cameras for the render PSNR")
    ap.add_argument("--size", type=int, default=192, help="render width and height")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "presets.md"))
    args = ap.parse_args(argv)

    import torch

    from lghcc.common.procedural import make_procedural_scene
    from lghcc.common.scaffold_io import read_scaffold
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.config import load_config, preset_names
    from lghcc.encoder.encode import encode_scene
    from lghcc.render.metrics import psnr
    from lghcc.render.rasterizer import render_scene
    from lghcc.render.views import orbit_cameras

    torch.set_num_threads(args.threads)
    scene = read_scaffold(args.input) if args.input else make_procedural_scene(args.procedural, seed=0)
    source = args.input or f"procedural scene, {scene.num_anchors:,} anchors (seed 0)"
    cams = orbit_cameras(scene.positions(), args.views, width=args.size, height=args.size)
    with torch.no_grad():
        refs = [render_scene(scene, c).image.numpy() for c in cams]
    rows = []
    for name in args.presets or preset_names():
        cfg = load_config(name)
        t0 = time.perf_counter()
        res = encode_scene(scene, cfg)
        t_enc = time.perf_counter() - t0
        t0 = time.perf_counter()
        dec = decode_stream(res.data)
        t_dec = time.perf_counter() - t0
        with torch.no_grad():
            p = np.mean([psnr(render_scene(dec.scene, c).image.numpy(), r) for c, r in zip(cams, refs)])
        n = scene.num_anchors
        rows.append((name, len(res.data), 8 * len(res.data) / n, t_enc, t_dec, float(p),
                     res.stats.get("level2_context_model", "-")))
        print(f"{name}: {len(res.data):,} B, enc {t_enc:.1f} s, dec {t_dec:.2f} s, render PSNR {p:.2f} dB", flush=True)
    lines = ["# Presets: size, time and fidelity", "",
             f"Command: `python tools/bench_presets.py {' '.join(argv or sys.argv[1:])}`  ",
             f"Date: {datetime.date.today()}; {args.threads} torch threads; shared 2-core VM, load "
             f"{' '.join(f'{x:.1f}' for x in os.getloadavg())} at the end (timings are noisy).  ",
             f"Scene: {source}. Fidelity: mean PSNR of {args.views} orbit renders ({args.size} px) of the decoded "
             "scene against the same renders of the input scene.", "",
             "| preset | bytes | bits/anchor | encode s | decode s | render PSNR dB | level-2 model |",
             "|---|---:|---:|---:|---:|---:|---|"]
    lines += [f"| {r[0]} | {r[1]:,} | {r[2]:.1f} | {r[3]:.1f} | {r[4]:.2f} | {r[5]:.2f} | {r[6]} |" for r in rows]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
