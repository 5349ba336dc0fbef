#!/usr/bin/env python3
"""Decoding time of streams with per-Gaussian SH degrees (format 1.3) against the same scene coded
without the tool, in one process (CPU time of the decode, best of --repeat): a smooth synthetic scene
of SH degree 3 with neighbour prediction and cross-channel prediction, the degrees none, mixed
(a quarter of the Gaussians at each degree, ranked by SH-rest energy), all 3 and all 0.

    python tools/bench_sh_degree_decode.py 50000      # results: tools/results/sh_degree.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lghcc.decoder.decode import decode_stream  # noqa: E402
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene  # noqa: E402
from lghcc.encoder.stream.config import GaussianEncoderConfig  # noqa: E402
from lghcc.formats.procedural import smooth_gaussian_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    n = args.n
    scene = smooth_gaussian_scene(n, 3, 1)
    energy = (scene.sh[:, 1:].astype(np.float64) ** 2).sum(axis=(1, 2))
    rank = np.empty(n, np.int64)
    rank[np.argsort(energy, kind="stable")] = np.arange(n)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", channel_prediction=True)
    degrees = {"none (1.1)": None, "mixed 0..3": 4 * rank // n, "all 3": np.full(n, 3), "all 0": np.zeros(n, np.int64)}
    streams = {k: encode_gaussian_scene(scene, cfg, sh_degrees=d).data for k, d in degrees.items()}
    best = dict.fromkeys(streams, float("inf"))
    for _ in range(args.repeat):
        for k, data in streams.items():
            t = time.process_time()
            decode_stream(data)
            best[k] = min(best[k], time.process_time() - t)
    base = best["none (1.1)"]
    print(f"{n:,} Gaussians, load average {os.getloadavg()[0]:.1f}")
    print("| degrees | stream bytes | decode CPU s | vs none |\n|---|---|---|---|")
    for k in streams:
        print(f"| {k} | {len(streams[k]):,} | {best[k]:.2f} | {best[k] / base:.2f}x |")


if __name__ == "__main__":
    main()
