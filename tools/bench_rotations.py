"""The bits of a Gaussian's rotation channels, and what other codings of the rotation would cost.

For a 3DGS scene and a preset: the values the settings search's trial at the preset's own steps
codes (RDOQ with the preset's weight, step adjustment and SH degrees, as tools/bench_rdoq.py
measures them), their rotation channels' ideal code lengths under neighbour prediction, channel
by channel, and those of the same rotations coded otherwise, each refitted (its own neighbour
means, table and prior):

- ``4 channels``: the format's w, x, y, z (the values coded).
- ``length m``: channel w carrying m = rint(|q|), the quaternion's length in steps, and w
  implied as sqrt(max(0, m^2 - x^2 - y^2 - z^2)) (smallest three, RDOQ's lengths kept).
- ``length index``: channel w carrying the index of the nearest of RDOQ's ROTATION_NORMS.
- ``w implied, one length``: x, y, z alone (a fixed length; RDOQ's per-Gaussian length lost):
  a lower bound of any smallest-three coding.

plus the direction error the length m brings (the angle between the quaternion as coded and as
the length m gives it back, against the angle of half a step).

``--rdoq-factors``: then the whole trial (RDOQ choosing the values for the coding) with the format
1.4 tool (config rotation_length: the length index coded, w implied) against without, every step
times each factor: PSNR on the search views and bits (geometry + the attributes' ideal code
lengths), and the tool's bits at the PSNR of the trial without it at factor 1 (log bits
interpolated linearly in PSNR between the factors).

    python tools/bench_rotations.py ../shared/data/playbot/playbot_lod4_8k.ply --presets low,medium,high
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
from lghcc.common.entropy.symbol_coder import code_lengths_bits  # noqa: E402
from lghcc.encoder.stream.config import load_config  # noqa: E402
from lghcc.encoder.gaussians.gaussian_fit import measure_contributions  # noqa: E402
from lghcc.encoder.gaussians.gaussian_views import fit_cameras, resolving_views  # noqa: E402
from lghcc.encoder.gaussians.gaussian_rd import GROUPS, SettingsSearch, _scaled  # noqa: E402
from lghcc.encoder.gaussians.rdoq import ROTATION_NORMS, sensitivities  # noqa: E402
from lghcc.encoder.stream.neighbour_coding import NeighbourCoding  # noqa: E402
from lghcc.common.attributes import STEP_ADJUST_FACTORS  # noqa: E402
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene  # noqa: E402


def capture(search: SettingsSearch) -> dict:
    """Makes ``search`` keep what its next trial codes (the rows in coding order)."""
    got: dict = {}
    inner = search._attribute_bits

    def attribute_bits(key, grid, q, prior_bits, adjust=None, degrees=None, layout=None):
        order, graph = search._graph(key, grid)
        got.update(q=q[order], coords=grid.coords[order], graph=graph,
                   adjust=None if adjust is None else adjust[order],
                   degrees=None if degrees is None else degrees[order],
                   layout=layout or GaussianLayout(search.scene.sh_degree), total=None)
        bits = inner(key, grid, q, prior_bits, adjust, degrees, layout)
        got["attribute_bits"] = bits
        got["geometry_bits"] = search._grid(*key)[2]
        return bits

    search._attribute_bits = attribute_bits
    return got


def channel_bits(got: dict, q: np.ndarray, cfg) -> np.ndarray:
    """float64 [M]: the ideal bits of each channel of ``q`` (rows in coding order), refitted."""
    nc = NeighbourCoding(q, got["coords"], cfg.prediction_lods, cfg.prediction_neighbours, cfg.prediction_buckets,
                         False, got["layout"], graph=got["graph"], adjust=got["adjust"], degrees=got["degrees"])
    coded = np.ones(q.shape, dtype=bool) if nc.coded is None else nc.coded
    return np.where(coded, code_lengths_bits(nc.residuals, nc.levels), 0.0).sum(axis=0)


def variants(got: dict, cfg) -> tuple[dict, dict]:
    """The rotation bits (total per Gaussian, and per channel) of each coding, and the direction
    errors of the length m."""
    q, rot = got["q"], got["layout"].rotation_start
    n = q.shape[0]
    r = q[:, rot:].astype(np.float64)
    length = np.linalg.norm(r, axis=1)
    m = np.rint(length).astype(np.int64)
    factor = 1.0 if got["adjust"] is None else STEP_ADJUST_FACTORS[got["adjust"]].astype(np.float64)
    rho = length * cfg.rotation_step * factor
    index = np.argmin(np.abs(np.log(rho[:, None]) - np.log(np.asarray(ROTATION_NORMS))[None, :]), axis=1)
    out = {}
    base = channel_bits(got, q, cfg)
    out["4 channels"] = base[rot:] / n
    for name, w in (("length m", m), ("length index", index)):
        qv = q.copy()
        qv[:, rot] = w
        out[name] = channel_bits(got, qv, cfg)[rot:] / n
    out["w implied, one length"] = np.concatenate([[0.0], base[rot + 1:] / n])
    v2 = (r[:, 1:] ** 2).sum(axis=1)
    w_implied = np.sqrt(np.maximum(0.0, m.astype(np.float64) ** 2 - v2))
    d_coded = r / np.maximum(length, 1e-300)[:, None]
    d_m = np.concatenate([w_implied[:, None], r[:, 1:]], axis=1) / np.maximum(m, 1)[:, None]
    ang = 2 * np.degrees(np.arccos(np.clip(np.abs((d_coded * d_m).sum(axis=1)), 0, 1)))
    half_step = 2 * np.degrees(np.arcsin(np.minimum(1.0, 0.5 / np.maximum(length, 1e-300))))
    errs = {"angle m vs coded, deg, mean": float(ang.mean()), "half a step, deg, mean": float(half_step.mean()),
            "lengths: share of each index": "/".join(f"{c / n:.0%}" for c in np.bincount(index, minlength=len(ROTATION_NORMS))),
            "w < 0 share": float((r[:, 0] < 0).mean()), "|v| > m share": float((v2 > m ** 2).mean())}
    return out, errs


def rdoq_rows(s: SettingsSearch, got: dict, cfg, preset: str, factors: list[float]) -> list[str]:
    """The trials with and without the tool at each factor on every step, and the tool's bits at
    equal PSNR (module doc)."""
    groups = [g for g in GROUPS if g != "position" and (not g.startswith("sh_band") or int(g[-1]) <= s.scene.sh_degree)]
    points: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    lines = []
    for on in (False, True):
        for fac in factors:
            t = s.evaluate(dataclasses.replace(_scaled(cfg, groups, fac), rotation_length=on))
            psnr = -10 * math.log10(max(t.mse, 1e-12))
            points[on].append((psnr, t.bits))
            q, rot = got["q"], got["layout"].rotation_start
            bits = channel_bits(got, q, cfg)[rot:] / q.shape[0]
            shares = "/".join(f"{c / q.shape[0]:.0%}" for c in np.bincount(np.clip(q[:, rot], 0, 15))) if on else "-"
            lines.append(f"| {preset} | RDOQ, {'length index' if on else '4 channels'}, steps x {fac:g} | "
                         f"{', '.join(f'{b:.2f}' for b in bits)} | {bits.sum():.2f} | {t.bits / 8:,.0f} B | "
                         f"PSNR {psnr:.3f} dB; index shares {shares} |")
            print(lines[-1], flush=True)
    ref_psnr, ref_bits = points[False][factors.index(1.0)]
    on_pts = sorted(points[True])
    log_bits = float(np.interp(ref_psnr, [p for p, _ in on_pts], [math.log(b) for _, b in on_pts]))
    lines.append(f"| {preset} | RDOQ, length index at equal PSNR ({ref_psnr:.3f} dB) | - | - | "
                 f"{math.exp(log_bits) / ref_bits - 1:+.2%} | against 4 channels at steps x 1 |")
    print(lines[-1], flush=True)
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", help="a 3DGS PLY")
    p.add_argument("--presets", default="low,medium,high")
    p.add_argument("--rdoq-factors", default="",
                   help="factors on every step for the trials with and without the tool, comma-separated, 1 among them "
                        "(e.g. 0.9,1,1.1; default: none)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("out/rotations.md"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    scene = read_3dgs_ply(args.scene)
    lines = [f"Command: `{command_line('bench_rotations.py', argv)}`  ",
             f"Scene: {args.scene}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}.", "",
             "| preset | coding | rotation bits per Gaussian (w, x, y, z) | total | change of the stream | notes |",
             "|---|---|---|---:|---:|---|"]
    for preset in args.presets.split(","):
        cfg = dataclasses.replace(load_config(preset, kind="gaussians"), rotation_length=False)
        t0 = time.perf_counter()
        g = gaussians_from_scene(scene)
        contrib = measure_contributions(g, fit_cameras(scene, cfg.fit_views, cfg.fit_resolution), False)
        cams = resolving_views(scene, cfg.fit_views, cfg.fit_resolution, cfg.resolve_px)
        f = sensitivities(scene, cams)
        s = SettingsSearch(scene, contrib, cfg, 0.0, cfg.search_views, cfg.search_resolution, sensitivity=f)
        got = capture(s)
        s.evaluate(cfg)
        out, errs = variants(got, cfg)
        n = got["q"].shape[0]
        stream_bits = (got["attribute_bits"] + got["geometry_bits"]) / n
        ref = out["4 channels"].sum()
        for name, bits in out.items():
            note = "; ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in errs.items()) \
                if name == "length m" else ""
            lines.append(f"| {preset} | {name} | {', '.join(f'{b:.2f}' for b in bits)} | {bits.sum():.2f} | "
                         f"{(bits.sum() - ref) / stream_bits:+.2%} of {stream_bits:.1f} | {note} |")
            print(lines[-1], flush=True)
        if args.rdoq_factors:
            lines += rdoq_rows(s, got, cfg, preset, [float(x) for x in args.rdoq_factors.split(",")])
        print(f"{preset}: {time.perf_counter() - t0:.0f} s", flush=True)
    lines += ["", f"Load average at the end: {load_average()}."]
    write_lines(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
