"""Neighbour prediction (format 1.1) against the per-channel prior, at the same quantized values.

For each explicit-Gaussian stream given (e.g. what ``lghcc-enc`` wrote for a real scene at a
preset), the decoded scene is coded again with the same steps and grid twice: neighbour
prediction never, and always (with the encoder's default parameters, and any ``--sweep``
variants). The decoded values are identical (the tool is lossless), so the table compares bytes
only, with encode and decode times measured in this process (ratios against the prior's run
beside them: the machine is shared).

    python tools/bench_neighbour.py donut=out/donut_low.lghcc lod3=out/lod3_med.lghcc
    python tools/bench_neighbour.py out/scene.lghcc --sweep 6,6,5 8,8,5 4,6,3 --out tools/results/neighbour.md

Results: tools/results/neighbour_prediction.md (``--out``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

from lghcc.common.container import UnitType, read_container  # noqa: E402
from lghcc.common.units import GaussianParameterSet  # noqa: E402
from lghcc.decoder.decode import decode_stream  # noqa: E402
from lghcc.encoder.stream.config import GaussianEncoderConfig  # noqa: E402
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene  # noqa: E402


def same_settings(data: bytes, tile_points: int) -> GaussianEncoderConfig:
    """The configuration that codes the stream's decoded scene with its own steps."""
    units = read_container(data).units
    gps = GaussianParameterSet.from_bytes(next(u.payload for u in units
                                               if u.unit_type == UnitType.GAUSSIAN_PARAMETER_SET))
    bands = list(gps.sh_band_step) + [1.0] * (3 - len(gps.sh_band_step))
    return GaussianEncoderConfig(sh_dc_step=gps.sh_dc_step, sh_band_steps=tuple(bands), opacity_step=gps.opacity_step,
                                 scale_step=gps.scale_step, rotation_step=gps.rotation_step, tile_points=tile_points)


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def run(label: str, path: Path, sweep: list[tuple[int, int, int]], tile_points: int) -> list[str]:
    data = path.read_bytes()
    scene = decode_stream(data).scene
    base = same_settings(data, tile_points)
    rows = []
    ref = None
    variants = [("per-channel prior", dataclasses.replace(base, neighbour_prediction=False))]
    for lods, k, buckets in sweep:
        variants.append((f"neighbour prediction L={lods} k={k} B={buckets}",
                         dataclasses.replace(base, neighbour_prediction="always", prediction_lods=lods,
                                             prediction_neighbours=k, prediction_buckets=buckets)))
    for name, cfg in variants:
        res, t_enc = timed(lambda: encode_gaussian_scene(scene, cfg))
        dec, t_dec = timed(lambda: decode_stream(res.data))
        assert dec.hash_checked and np.array_equal(dec.scene.sh, scene.sh), "the tool must be lossless"
        parts = res.breakdown.bytes_by_category
        if ref is None:
            ref = (len(res.data), parts["attributes"], t_enc, t_dec)
        rows.append(f"| {label} | {name} | {len(res.data):,} | {parts['attributes']:,} | "
                    f"{len(res.data) / ref[0]:.3f} | {parts['attributes'] / ref[1]:.3f} | {t_enc:.2f} | "
                    f"{t_dec:.2f} ({t_dec / ref[3]:.2f}x) |")
        print(rows[-1], flush=True)
    return [f"| {label} | {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}, {res.stats.num_tiles} "
            f"tile(s) | | | | | | |"] + rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("streams", nargs="+", help="explicit-Gaussian .lghcc streams, LABEL=PATH to name one")
    ap.add_argument("--sweep", nargs="*", default=["6,6,5"], help="LoDs,neighbours,buckets variants (default 6,6,5)")
    ap.add_argument("--tile-points", type=int, default=16384, help="tile size as the encoder's default (0: none)")
    ap.add_argument("--out", type=Path, help="write the markdown table here")
    args = ap.parse_args(argv)
    sweep = [tuple(int(x) for x in v.split(",")) for v in args.sweep]
    lines = ["| scene | coding | bytes | attribute bytes | bytes / prior | attributes / prior | encode s | decode s |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for item in args.streams:
        label, _, path = item.rpartition("=")
        lines += run(label or Path(path).stem, Path(path), sweep, args.tile_points)
    if args.out:
        head = [f"Command: `{command_line('bench_neighbour.py', argv)}`  ",
                f"Load at the end: {load_average()} (shared 2-core VM; times in this process).", ""]
        write_lines(args.out, head + lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
