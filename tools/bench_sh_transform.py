"""The SH transform (format 1.6) at fixed steps, with and without it, through the settings search's trials.

For a 3DGS scene and each preset: the trial at the preset's own steps times each factor (every group's
step; RDOQ with the render-based sensitivities, step adjustment and SH degrees as the preset has them,
tools/bench_rdoq.py's way), once without the SH transform and once with it (config sh_transform: the
coefficients' RDOQ with their sensitivities diag(B^T F B), encoder/gaussians/sh_transform.py): PSNR on the
search views and bits (geometry + the attributes' ideal code lengths + the unit), and the tool's bits at
the PSNR of the trial without it at factor 1 (log bits interpolated linearly in PSNR between the factors).
So the coding's own saving at equal distortion, apart from where the settings search lands.

    python tools/bench_sh_transform.py ../shared/data/playbot/playbot_lod4_8k.ply --presets low,medium,high \\
        --factors 0.85,1,1.15
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lghcc.encoder.gaussians.gaussian_fit import measure_contributions  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import GROUPS, SettingsSearch, _scaled  # noqa: E402
from lghcc.encoder.gaussians.gaussian_views import fit_cameras, resolving_views  # noqa: E402
from lghcc.encoder.gaussians.rdoq import sensitivities  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene  # noqa: E402


def preset_rows(scene, preset: str, factors: list[float]) -> list[str]:
    """The trials without and with the tool at each factor, and the tool's bits at equal PSNR."""
    cfg = load_config(preset, kind="gaussians")
    contrib = measure_contributions(gaussians_from_scene(scene), fit_cameras(scene, cfg.fit_views, cfg.fit_resolution),
                                    False).total
    f = sensitivities(scene, resolving_views(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px))
    s = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    groups = [g for g in GROUPS if g != "position" and (not g.startswith("sh_band") or int(g[-1]) <= scene.sh_degree)]
    points: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    lines = []
    for on in (False, True):
        for fac in factors:
            t = s.evaluate(dataclasses.replace(_scaled(cfg, groups, fac), sh_transform="always" if on else False))
            psnr = -10 * math.log10(max(t.mse, 1e-12))
            points[on].append((psnr, t.bits))
            lines.append(f"| {preset} | {'with' if on else 'without'} | x {fac:g} | {psnr:.3f} | "
                         f"{t.bits / scene.num_gaussians:.2f} | {t.bits / 8:,.0f} |")
            print(lines[-1], flush=True)
    ref_psnr, ref_bits = points[False][factors.index(1.0)]
    on_pts = sorted(points[True])
    log_bits = float(np.interp(ref_psnr, [p for p, _ in on_pts], [math.log(b) for _, b in on_pts]))
    lines.append(f"| {preset} | with, at equal PSNR ({ref_psnr:.3f} dB) | - | - | - | "
                 f"{math.exp(log_bits) / ref_bits - 1:+.2%} against without at x 1 |")
    print(lines[-1], flush=True)
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a 3DGS PLY")
    p.add_argument("--presets", default="low,medium,high")
    p.add_argument("--factors", default="0.85,1,1.15", help="factors on every step, comma-separated, 1 among them")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("out/sh_transform.md"))
    args = p.parse_args(argv)
    factors = [float(x) for x in args.factors.split(",")]
    if 1.0 not in factors:
        p.error("--factors must hold 1")
    torch.set_num_threads(args.threads)
    scene = read_3dgs_ply(args.scene)
    lines = [f"Command: `{command_line('bench_sh_transform.py', argv)}`  ",
             f"Scene: {args.scene}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}.", "",
             "| preset | SH transform | steps | PSNR dB (search views) | bits / Gaussian | bytes |",
             "|---|---|---|---:|---:|---:|"]
    for preset in args.presets.split(","):
        t0 = time.perf_counter()
        lines += preset_rows(scene, preset, factors)
        print(f"{preset}: {time.perf_counter() - t0:.0f} s", flush=True)
    lines += ["", f"Load average at the end: {load_average()}."]
    write_lines(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
