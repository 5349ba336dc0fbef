#!/usr/bin/env python3
"""The SH rest's error of decoded streams against their source (informative; tools/results/sh_coding.md).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 .venv/bin/python tools/sh_rest_error.py SOURCE STREAM [STREAM ...]

SOURCE: what the streams were encoded from (a 3DGS PLY, SPZ, SOG or streamed SOG's lod-meta.json, as
lghcc-enc reads it); each STREAM is decoded and each decoded Gaussian matched to the source Gaussian
nearest its position (a k-d tree; the decoded scene is in normative order, and an encoder may drop or
move Gaussians). Prints a markdown table: bytes, bits per decoded Gaussian, and the mean squared error
of the SH rest (bands 1 .. d, in SH units) and of the DC term, so that two codings of one scene (e.g.
with and without the SH transform of format 1.6) compare at their distortion, without renders.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def errors(source, decoded) -> tuple[float, float, float]:
    """(SH-rest MSE, DC MSE, median match distance in voxels) of ``decoded`` against ``source``."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(source.means.astype(np.float64)).query(decoded.means.astype(np.float64))
    src = source.sh[idx].astype(np.float64)
    dec = decoded.sh.astype(np.float64)
    rest = float(np.square(dec[:, 1:] - src[:, 1:]).mean()) if decoded.sh_degree > 0 else 0.0
    return rest, float(np.square(dec[:, 0] - src[:, 0]).mean()), float(np.median(dist) / decoded.voxel_size)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", help="the scene the streams were encoded from")
    ap.add_argument("streams", nargs="+", help="lghcc streams of it")
    args = ap.parse_args(argv)
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.api import read_source

    source = read_source(args.source).scene
    print("| stream | bytes | Gaussians | bits / Gaussian | SH-rest MSE | DC MSE | median match distance (voxels) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for s in args.streams:
        data = Path(s).read_bytes()
        dec = decode_stream(data).scene
        rest, dc, dist = errors(source, dec)
        n = dec.num_gaussians
        print(f"| {Path(s).name} | {len(data):,} | {n:,} | {8 * len(data) / n:.2f} | {rest:.4e} | {dc:.4e} | {dist:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
