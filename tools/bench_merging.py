#!/usr/bin/env python3
"""Merging against dropping the pruned Gaussians (``prune_mode``, encoder/gaussians/merging.py), at
the same count and the same steps.

For a 3DGS scene and a preset: for each pruning share of ``--shares``, the scene prepared as the
encoder prepares it (encoder/gaussians/gaussian_fit.py prepare_gaussians: contributions, the
pruning dropping or merging, the grid, ``--fit`` steps of the fit; no settings search, the
preset's steps) with ``prune_mode`` drop and merge, coded as lghcc-enc codes it (encode_gaussian_scene
with the contributions and sensitivities: RDOQ and the preset's per-Gaussian tools), decoded, and
rendered from bench_real's orbit (12 views of 320 px at 20 degrees, black background; up axis as
bench_real records it for the named scenes): PSNR against the source's renders, bytes, and the
CPU seconds of the preparation. Both modes keep the same Gaussians, so the rows differ only in
the kept Gaussians' values.

``--search``: the whole preparation as lghcc-enc runs it at the preset (its quality target, the
settings search walking the pruning ladder with ``prune_mode`` drop or merge, the trim), one row
per mode; ``share pruned`` is then the share the search chose. The rows reach different PSNRs:
compare them at equal PSNR by the scene's bytes per dB (the fixed-count rows give it).

    python tools/bench_merging.py playbot-lod4 donut --preset low --shares 0.008,0.03,0.1
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import datetime  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from benchutil import command_line, load_average, write_lines  # noqa: E402
from bench_real import SCENES, orbit  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lghcc.decoder.decode import decode_stream  # noqa: E402
from lghcc.encoder.gaussians.gaussian_fit import prepare_gaussians  # noqa: E402
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs  # noqa: E402

HEADER = ("| scene | preset | share pruned | fit steps | mode | Gaussians kept | bytes | orbit PSNR dB | "
          "prepare CPU s |")


def renders(scene, cams) -> list[torch.Tensor]:
    g = gaussians_from_scene(scene)
    with torch.no_grad():
        return [render_3dgs(g, cam, background=(0, 0, 0), backend="torch").image for cam in cams]


def psnr(images: list[torch.Tensor], targets: list[torch.Tensor]) -> float:
    mse = float(np.mean([((a - b) ** 2).double().mean().item() for a, b in zip(images, targets)]))
    return -10 * math.log10(max(mse, 1e-12))


def row(scene, targets, cams, cfg, mode: str) -> tuple[int, int, float, float, float]:
    """(kept, bytes, orbit PSNR, prepare CPU s, share pruned) of the scene prepared and coded with ``mode``."""
    t0 = time.process_time()
    prep = prepare_gaussians(scene, dataclasses.replace(cfg, prune_mode=mode))
    cpu = time.process_time() - t0
    res = encode_gaussian_scene(prep.scene, prep.cfg, weights=prep.weights, sensitivity=prep.sensitivity)
    dec = decode_stream(res.data).scene
    return prep.scene.num_gaussians, len(res.data), psnr(renders(dec, cams), targets), cpu, prep.cfg.prune_share


def scene_rows(name: str, args) -> list[str]:
    path, up, _ = SCENES[name]
    scene = read_3dgs_ply(args.data_root / path)
    cams = orbit(scene.means, 12, 320, up)
    targets = renders(scene, cams)
    base = load_config(args.preset, kind="gaussians")
    if not args.search:
        base = dataclasses.replace(base, target_psnr=0.0, rd_lambda=0.0)
    out = []
    for share in ["search"] if args.search else args.shares:
        cfg = base if args.search else dataclasses.replace(base, prune_share=share, fit_iterations=args.fit)
        for mode in ("drop", "merge"):
            kept, nbytes, p, cpu, chosen = row(scene, targets, cams, cfg, mode)
            label = f"{chosen:g} (search)" if args.search else f"{share:g}"
            print(f"{name} {label} {mode}: {kept} kept, {nbytes} B, {p:.3f} dB, {cpu:.1f} s", flush=True)
            out.append(f"| {name} | {args.preset} | {label} | {cfg.fit_iterations} | {mode} | {kept:,} | {nbytes:,} | "
                       f"{p:.3f} | {cpu:.1f} |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", choices=sorted(SCENES))
    ap.add_argument("--preset", default="low", help="the steps of this explicit-Gaussian preset (default low)")
    ap.add_argument("--shares", type=lambda s: [float(x) for x in s.split(",")], default=[0.008, 0.03, 0.1],
                    help="pruning shares of the contribution (comma-separated)")
    ap.add_argument("--fit", type=int, default=0, help="fit steps after the pruning (default 0)")
    ap.add_argument("--search", action="store_true",
                    help="the preset's whole preparation, its settings search choosing the share (module doc)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--out", type=Path, default=None, help="markdown file for the table (default: stdout only)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    lines = [HEADER, "|---|---|---:|---:|---|---:|---:|---:|---:|"]
    for name in args.scenes:
        lines += scene_rows(name, args)
    lines += ["", f"Command: `{command_line('bench_merging.py', argv)}`  ",
              f"Date: {datetime.date.today()}; torch {torch.__version__}, {args.threads} threads; "
              f"load {load_average()} at the end."]
    print("\n".join(lines))
    if args.out:
        write_lines(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
