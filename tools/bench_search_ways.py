"""The settings search's trials with RDOQ's ways kept from the first trial against chosen afresh.

RDOQ (encoder/gaussians/rdoq.py) writes each Gaussian in one of 48 equivalent ways (axis turns,
the quaternion's sign). The coding chooses them at its steps; the settings search once chose them
at its first trial and kept them for every later one. This measures what that did to the moves
onto the quality target: a scene prepared as lghcc-enc prepares it (contributions, search, pruning,
grid, fit, and the trim or whole-scene check onto the target: ``prepare_gaussians``), then trials
at the chosen steps times each factor of ``--factors``, the first at factor 1 choosing the ways:

- ``kept``: the ways chosen at factor 1 kept (``SettingsSearch.ways``, as before);
- ``fresh``: chosen afresh in the trial (the search's trials now, and the coding).

PSNR on the encoder's search views (the trim's and the check's), bytes as the search counts them
(geometry coded + the attributes' ideal code lengths). Results: tools/results/search_ways.md.

    python tools/bench_search_ways.py ../shared/data/donut/donut.ply --preset medium
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lghcc.encoder.gaussians.gaussian_fit import prepare_gaussians  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import SettingsSearch, _attribute_groups, _scaled  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402


def psnr(t) -> float:
    return -10 * math.log10(max(t.mse, 1e-12))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scene", help="a 3DGS PLY")
    p.add_argument("--preset", default="medium", help="the encoder preset (default medium)")
    p.add_argument("--factors", default="0.9,0.95,0.98,1.02,1.05,1.1,1.2,1.3",
                   help="factors on the chosen attribute steps, besides 1 (comma-separated)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("out/search_ways.md"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    scene = read_3dgs_ply(args.scene)
    cfg = load_config(args.preset, kind="gaussians")
    t0 = time.perf_counter()
    prep = prepare_gaussians(scene, cfg, log=lambda m: print(m, flush=True))
    t_prep = time.perf_counter() - t0
    chosen = dataclasses.replace(prep.cfg, prune_share=0.0)  # the prepared scene is already pruned
    s = SettingsSearch(prep.scene, prep.weights, chosen, 0.0, chosen.search_views, chosen.search_resolution,
                       prep.sensitivity)
    groups = _attribute_groups(prep.scene)
    s.ways = np.full(prep.scene.num_gaussians, -1, dtype=np.int64)
    first = s.evaluate(chosen)  # chooses the ways
    kept_ways = s.ways.copy()
    lines = [f"Command: `{command_line('bench_search_ways.py', argv)}`  ",
             f"Scene: {args.scene}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}; preset "
             f"{args.preset}: prepared in {t_prep:.0f} s, {prep.scene.num_gaussians:,} Gaussians kept, target "
             f"{cfg.target_psnr:g} dB; {len(s.cams)} search views. Factor 1: {psnr(first):.2f} dB, "
             f"{first.bits / 8:,.0f} B.",
             "", "| factor on the chosen steps | ways kept: PSNR dB | bytes | ways afresh: PSNR dB | bytes | "
             "afresh - kept: dB | bytes | CPU s per trial: kept | afresh |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for f in sorted(float(x) for x in args.factors.split(",")):
        trial_cfg = _scaled(chosen, groups, f)
        s.ways = kept_ways.copy()
        c0 = time.process_time()
        kept = s.evaluate(trial_cfg)
        c1 = time.process_time()
        s.ways = None
        fresh = s.evaluate(trial_cfg)
        c2 = time.process_time()
        lines.append(f"| {f:g} | {psnr(kept):.2f} | {kept.bits / 8:,.0f} | {psnr(fresh):.2f} | {fresh.bits / 8:,.0f} | "
                     f"{psnr(fresh) - psnr(kept):+.2f} | {100 * (fresh.bits / kept.bits - 1):+.1f}% | "
                     f"{c1 - c0:.1f} | {c2 - c1:.1f} |")
        print(lines[-1], flush=True)
    lines += ["", f"Load average at the end: {load_average()}."]
    write_lines(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
