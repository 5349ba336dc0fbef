"""Rate-distortion optimized quantization (encoder/gaussians/rdoq.py) against plain rounding, at fixed steps.

For a 3DGS scene and a preset: the preset's steps times each factor of ``--factors``, coded with
each RDOQ weight of ``--weights`` (0: plain rounding), measured as the settings search measures
its trials (encoder/gaussians/gaussian_rd.py SettingsSearch: PSNR of the quantized scene's renders against
the source's on the preset's search views, ``search_views`` x ``search_resolution``, 8 of 128 px:
not the encoder's ``search_view_plan``, which gives scenes under 150,000 Gaussians more, so
that the tables of tools/results/rdoq.md stay comparable; bits = geometry coded + attributes as
ideal code lengths under neighbour prediction or the prior). Equal-PSNR comparisons read
across rows: RDOQ wins where its row reaches a PSNR with fewer bits than plain rounding's curve
(the factor rows at weight 0).
The whole encoder's numbers against orbit renders are tools/bench_real.py's.

    python tools/bench_rdoq.py ../shared/data/playbot/playbot_lod4_8k.ply --preset low --out out/rdoq.md
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

from lghcc.common.attributes import GaussianLayout  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.encoder.gaussians.gaussian_fit import measure_contributions  # noqa: E402
from lghcc.encoder.gaussians.gaussian_views import fit_cameras, resolving_views  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import GROUPS, SettingsSearch, _scaled  # noqa: E402
from lghcc.encoder.gaussians import rdoq  # noqa: E402
from lghcc.encoder.gaussians.rdoq import SENSITIVITY_PROBES, sensitivities  # noqa: E402
from lghcc.encoder.stream.neighbour_coding import NeighbourCoding  # noqa: E402
from lghcc.common.entropy.symbol_coder import code_lengths_bits  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs  # noqa: E402


def record_parts(search: SettingsSearch) -> dict:
    """Makes ``search`` record the ideal bits per Gaussian of each part of its next trial (neighbour
    prediction's residuals at their levels, as the search estimates the attributes; cross-channel
    prediction and the units' headers left out; geometry as coded), and what the SH rest would
    cost were every residual of it 0 at the same levels, into the dict returned."""
    parts: dict = {}
    inner = search._attribute_bits

    def attribute_bits(key, grid, q, prior_bits, adjust=None, degrees=None, layout=None):
        order, graph = search._graph(key, grid)
        n, layout = q.shape[0], layout or GaussianLayout(search.scene.sh_degree)
        sh, rot = layout.opacity_channel, layout.rotation_start
        if graph is not None:
            nc = NeighbourCoding(q[order], grid.coords[order], search.cfg.prediction_lods,
                                 search.cfg.prediction_neighbours, search.cfg.prediction_buckets, False, layout,
                                 graph=graph, adjust=None if adjust is None else adjust[order],
                                 degrees=None if degrees is None else degrees[order])
            coded = np.ones(q.shape, dtype=bool) if nc.coded is None else nc.coded
            per_value = np.where(coded, code_lengths_bits(nc.residuals, nc.levels), 0.0)
            bits = per_value.sum(axis=0) / n
            zeros = np.where(coded[:, 3:sh], code_lengths_bits(np.zeros_like(nc.residuals[:, 3:sh]),
                                                               nc.levels[:, 3:sh]), 0.0).sum() / n
            shares = "-" if degrees is None else "/".join(
                f"{c / n:.0%}" for c in np.bincount(degrees, minlength=layout.sh_degree + 1))
            parts.update({"SH rest": bits[3:sh].sum(), "DC": bits[:3].sum(), "opacity": bits[sh],
                          "scales": bits[layout.scale_start:rot].sum(), "rotation": bits[rot:].sum(),
                          "geometry": search._grid(*key)[2] / n, "SH rest if every residual were 0": zeros,
                          "SH-degree flags": nc.degree_bits() / n, "share of each SH degree": shares})
        return inner(key, grid, q, prior_bits, adjust, degrees, layout)

    search._attribute_bits = attribute_bits
    return parts


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a 3DGS PLY")
    p.add_argument("--preset", default="low", help="the steps, pruning share and views of this preset (default low)")
    p.add_argument("--factors", default="0.84,1,1.19,1.41", help="factors on every attribute step")
    p.add_argument("--weights", default="0,0.25,0.5,1", help="RDOQ weights (0: plain rounding)")
    p.add_argument("--probes", type=int, default=SENSITIVITY_PROBES,
                   help=f"random images per view for the sensitivities (default {SENSITIVITY_PROBES}, the encoder's)")
    p.add_argument("--max-jump", type=int, default=rdoq.MAX_JUMP,
                   help=f"the largest move from the rounded value, in steps (default {rdoq.MAX_JUMP}, the encoder's)")
    p.add_argument("--turn-candidates", type=int, default=rdoq.TURN_CANDIDATES,
                   help=f"how many of the 24 ways of turning a Gaussian's axes are costed in full besides its own "
                        f"(default {rdoq.TURN_CANDIDATES}, the encoder's; 0: every Gaussian kept as it is)")
    p.add_argument("--keep-ways", action="store_true",
                   help="keep the way each Gaussian is written from the first row on, as the settings search "
                        "once did (default: chosen afresh at every row, as the search and the coding choose it)")
    p.add_argument("--rotation-lengths", default=",".join(f"{r:.4g}" for r in rdoq.ROTATION_NORMS),
                   help="the lengths a rotation quaternion may be given, comma-separated (default the "
                        "encoder's; 1 alone keeps every quaternion at unit length)")
    p.add_argument("--step-adjust", default="0",
                   help="largest step-adjustment indices to measure, comma-separated (format 1.2; default 0: "
                        "every Gaussian at its channels' steps; the presets use 7)")
    p.add_argument("--sh-degrees", default="off",
                   help="per-Gaussian SH degree (format 1.3, config sh_degree_choice) to measure, comma-separated: "
                        "off, on (default off)")
    p.add_argument("--degree-weight", type=float, default=rdoq.DEGREE_DISTORTION_WEIGHT,
                   help="the weight of a dropped SH band's error against its bits in the SH-degree choice "
                        f"(default {rdoq.DEGREE_DISTORTION_WEIGHT:g}, the encoder's)")
    p.add_argument("--orbit-up", default=None,
                   help="also measure each row on tools/bench_real.py's 12 orbit views at 320 px around this up "
                        "axis (x, y, z, -x, -y, -z): views the sensitivities and the search never saw")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("out/rdoq.md"))
    args = p.parse_args(argv)
    rdoq.MAX_JUMP = args.max_jump
    rdoq.ROTATION_NORMS = tuple(float(r) for r in args.rotation_lengths.split(","))
    rdoq.TURN_CANDIDATES = args.turn_candidates
    rdoq.DEGREE_DISTORTION_WEIGHT = args.degree_weight
    torch.set_num_threads(args.threads)
    scene = read_3dgs_ply(args.scene)
    cfg = load_config(args.preset, kind="gaussians")
    t0 = time.perf_counter()
    g = gaussians_from_scene(scene)
    contrib = measure_contributions(g, fit_cameras(scene, cfg.fit_views, cfg.fit_resolution), False)
    cams = resolving_views(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px)
    f = sensitivities(scene, cams, probes=args.probes)
    t_sens = time.perf_counter() - t0
    s = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
    if args.keep_ways:  # chosen at the first row and kept (the search's trials did so before search_ways.md)
        s.ways = np.full(scene.num_gaussians, -1, dtype=np.int64)
    parts = record_parts(s)
    groups = [grp for grp in GROUPS if grp != "position" and (not grp.startswith("sh_band")
                                                               or int(grp[-1]) <= scene.sh_degree)]
    orbit_search = None
    if args.orbit_up:  # the same trials rendered from the orbit of tools/bench_real.py
        from bench_real import orbit

        orbit_search = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution,
                                      sensitivity=f)
        orbit_search.cams = orbit(scene.means, 12, 320, args.orbit_up)
        with torch.no_grad():
            orbit_search.targets = [render_3dgs(g, c, background=(0, 0, 0), backend="torch").image
                                    for c in orbit_search.cams]
    lines = [f"Command: `{command_line('bench_rdoq.py', argv)}`  ",
             f"Scene: {args.scene}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}; preset "
             f"{args.preset} (pruning share {cfg.prune_share:g}); contributions and sensitivities "
             f"({len(cams)} views, {args.probes} probes each) in {t_sens:.1f} s; values moved at most "
             f"{args.max_jump} step(s); rotation lengths {args.rotation_lengths}; {args.turn_candidates} turn "
             "candidates.",
             "", "| step factor | RDOQ weight | step adjustment up to | SH degree per Gaussian | PSNR dB (search views) | "
             + ("PSNR dB (orbit, 320 px) | " if orbit_search else "") + "bytes | bytes / rounding at this factor | bits per Gaussian: SH rest, DC, opacity, scales, rotation, "
             "geometry; SH rest if every residual were 0; SH-degree flags; share of each SH degree |",
             "|---:|---:|---:|---:|---:|" + ("---:|" if orbit_search else "") + "---:|---:|---|"]
    for fac in (float(x) for x in args.factors.split(",")):
        ref = None
        for w in (float(x) for x in args.weights.split(",")):
            for top, degrees in ((int(a), b == "on") for a in args.step_adjust.split(",")
                                 for b in args.sh_degrees.split(",")):
                if w == 0 and (top or degrees):
                    continue  # step adjustment and the SH degrees are chosen with RDOQ's costs
                trial_cfg = dataclasses.replace(_scaled(cfg, groups, fac), rd_quantization=w, step_adjust_max=top,
                                                sh_degree_choice=degrees)
                t = s.evaluate(trial_cfg)
                ref = ref or t.bits
                seen = ""
                if orbit_search is not None:
                    orbit_search.ways = None if s.ways is None else s.ways.copy()  # the same values
                    seen = f"{-10 * math.log10(max(orbit_search.evaluate(trial_cfg).mse, 1e-12)):.2f} | "
                lines.append(f"| {fac:g} | {w:g} | {top} | {'on' if degrees else 'off'} | {-10 * math.log10(max(t.mse, 1e-12)):.2f} | {seen}"
                             f"{t.bits / 8:,.0f} | {t.bits / ref:.3f} | "
                             f"{', '.join(v if isinstance(v, str) else f'{v:.1f}' for v in parts.values()) if parts else '-'} |")
                print(lines[-1], flush=True)
    lines += ["", f"Load average at the end: {load_average()}."]
    write_lines(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
