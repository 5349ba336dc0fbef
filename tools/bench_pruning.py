#!/usr/bin/env python3
"""NAAP against opacity-threshold pruning at the same anchor count: bytes and rendered fidelity.

For a trained anchor scene (a Scaffold-GS folder with its training statistics, e.g. lghcc-train's
output, whose PLY holds the accumulated opacity NAAP uses) and the dataset it was trained on,
for each keep ratio: prune with NAAP (paper section 3.3: neighbourhood-aware importance,
pruned anchors merged into their nearest kept neighbour) and with Context-GS's plain opacity
threshold, encode with the chosen preset (lghcc-enc's code path: encode_scene with the
pruning fields of EncoderConfig), decode, and render the test views: stream bytes by part and
test PSNR / SSIM of the decoded scene. The unpruned scene is the first row.

--ablation adds two NAAP variants per keep ratio: gamma 0 (neighbourhood importance, no merge)
and lambda 0 (the anchor's own opacity as importance, merged), which tell what the importance
and what the merge contribute.

Pruning here is post-hoc (at encode time, no fine-tuning after it); the paper prunes during
training and trains on. Both methods get exactly the same number of anchors.

    python tools/bench_pruning.py /work/scenes/lego100 /work/shared/data/lego/lego_100 --keep 0.9 0.75 0.6

--trained LABEL=DIR (repeatable) adds rows for scenes pruned inside training (lghcc-train --prune,
the paper's way: prune once growing ends, then train on), encoded without further pruning.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from benchutil import command_line, load_average, write_lines  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="trained Scaffold-GS folder (with opacity_accum in its PLY)")
    ap.add_argument("data", help="the dataset it was trained on (test views are rendered)")
    ap.add_argument("--keep", type=float, nargs="*", default=[0.9, 0.75, 0.6],
                    help="keep ratios of the post-hoc rows (none: only the unpruned and --trained rows)")
    ap.add_argument("--preset", default="medium")
    ap.add_argument("--trained", action="append", default=[], metavar="LABEL=DIR",
                    help="a scene pruned during training, encoded as is (repeatable)")
    ap.add_argument("--ablation", action="store_true",
                    help="also NAAP without the merge (gamma 0) and NAAP with the anchor's own opacity as "
                         "importance (lambda 0), to tell the importance from the merge")
    ap.add_argument("--background", default="white")
    ap.add_argument("--views", type=int, default=0, help="test views to render (0: all)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "pruning.md")
    args = ap.parse_args(argv)

    import numpy as np
    import torch

    from lghcc.formats.scaffold_io import read_scaffold
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.encoder.training.evaluation import evaluate_scene
    from lghcc.render.datasets import load_dataset

    torch.set_num_threads(args.threads)
    scene = read_scaffold(args.scene)
    if "opacity_accum" not in scene.extra:
        print(f"note: {args.scene} has no training statistics; opacities come from the opacity MLP", file=sys.stderr)
    ds = load_dataset(args.data, args.background)
    cams = ds.test
    if args.views and args.views < len(cams):
        cams = [cams[i] for i in np.linspace(0, len(cams) - 1, args.views).round().astype(int)]
    base_cfg = load_config(args.preset)
    cmd = command_line("bench_pruning.py", argv)
    lines = ["# NAAP vs opacity pruning: bytes and fidelity at the same anchor count", "",
             f"Command: `{cmd}`  ",
             f"Date: {datetime.date.today().isoformat()}; {args.threads} torch threads, shared 2-core VM.  ",
             f"Scene: `{args.scene}` ({scene.num_anchors:,} anchors), preset `{args.preset}`; PSNR/SSIM of the "
             f"decoded stream on {len(cams)} test views of `{args.data}` (CPU reference renderer). NAAP: K=8, "
             f"lambda={base_cfg.naap_lambda}, gamma={base_cfg.naap_gamma}, radius 4x the median nearest-neighbour "
             "distance; importance from the training's accumulated opacity.", "",
             "| pruning | keep | anchors | bytes | attribute bytes | geometry bytes | test PSNR dB | SSIM | "
             "encode+decode s | load |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]

    def row(method: str, keep: float | None, source=None, label: str | None = None, **naap) -> None:
        over = {} if keep is None else dict(pruning=method, prune_keep_ratio=keep, **naap)
        cfg = dataclasses.replace(base_cfg, **over).validate()
        t0 = time.perf_counter()
        res = encode_scene(scene if source is None else source, cfg)
        dec = decode_stream(res.data)
        dt = time.perf_counter() - t0
        assert dec.stream_hash == res.scene_hash
        ev = evaluate_scene(dec.scene, cams, args.background)
        bd = res.breakdown.bytes_by_category
        lines.append(f"| {label or method} | {'-' if keep is None else keep} | {dec.scene.num_anchors:,} | {len(res.data):,} | "
                     f"{bd.get('attributes', 0):,} | {bd.get('geometry', 0):,} | {ev['psnr']:.3f} | {ev['ssim']:.4f} | "
                     f"{dt:.1f} | {load_average()} |")
        print(lines[-1], flush=True)
        write_lines(args.out, lines)

    row("none", None)
    for keep in args.keep:
        for method in ("opacity", "naap"):
            row(method, keep)
        if args.ablation:
            row("naap", keep, label="naap, gamma 0 (no merge)", naap_gamma=0.0)
            row("naap", keep, label="naap, lambda 0 (own opacity, merged)", naap_lambda=0.0)
    if args.trained:
        lines += ["", "Pruned during training (lghcc-train --prune, then trained on), encoded as is:", "",
                  lines[6], lines[7]]
        for spec in args.trained:
            label, _, folder = spec.partition("=")
            row(label, None, read_scaffold(folder))
    write_lines(args.out, lines)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
