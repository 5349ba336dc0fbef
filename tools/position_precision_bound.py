"""An upper bound on what a per-Gaussian position precision could save (issue 34, tool 3: positions
coded coarser where a Gaussian's size allows), from an existing explicit-Gaussian stream, no format
change (research; tools/results/geometry_research.md, "Per-Gaussian position precision").

    python tools/position_precision_bound.py STREAM [--axis min|mean|max] [--alpha 0.1 0.25 0.5]

In the octree a Gaussian costs about 3 bits per level below the depth where it becomes alone in
its node (its 'tail', incompressible by any octree coder: geometry_research.md). A Gaussian whose
size s allows a position error of alpha * s could drop r levels of precision (2^(r-1) voxels <=
alpha * s), saving at most 3 * min(r, its levels alone) bits; s is the smallest, the geometric
mean or the largest of its three scales (--axis: the smallest is what a flat Gaussian's thin axis
tolerates). The bound ignores the cost of signalling r and the pictures' error, both of which a
real tool pays.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

from lghcc.common.container import UnitType, read_container  # noqa: E402
from lghcc.decoder.decode import decode_stream  # noqa: E402


def levels_alone(coords: np.ndarray) -> tuple[np.ndarray, int]:
    """Per point (int64 [N, 3] >= 0), the octree levels below the depth at which it is alone in its
    node; and the depth D."""
    depth = max(1, int(np.ceil(np.log2(int(coords.max()) + 1))))
    if 3 * depth > 63:
        raise SystemExit(f"a grid of depth {depth}: Morton codes beyond 63 bits are not handled here")
    code = np.zeros(coords.shape[0], np.uint64)
    for b in range(depth - 1, -1, -1):
        for a in range(3):
            code = (code << np.uint64(1)) | ((coords[:, a] >> b) & 1).astype(np.uint64)
    order = np.argsort(code)
    sorted_codes = code[order]
    diff = sorted_codes[1:] ^ sorted_codes[:-1]  # distinct points: never 0
    shared = (3 * depth - 1 - np.floor(np.log2(diff.astype(np.float64))).astype(np.int64)) // 3  # common levels
    common = np.zeros(code.size, np.int64)
    common[1:] = shared
    common[:-1] = np.maximum(common[:-1], shared)
    alone = np.empty(code.size, np.int64)
    alone[order] = depth - (common + 1)
    return alone, depth


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stream", type=Path)
    ap.add_argument("--axis", choices=("min", "mean", "max"), default="min")
    ap.add_argument("--alpha", type=float, nargs="+", default=[0.1, 0.25, 0.5])
    args = ap.parse_args(argv)
    data = args.stream.read_bytes()
    scene = decode_stream(data, jobs=2).scene
    voxel = float(scene.voxel_size)
    coords = np.rint((scene.means - scene.origin) / voxel).astype(np.int64)
    coords -= coords.min(axis=0)
    alone, depth = levels_alone(coords)
    size = np.exp(getattr(scene.log_scales.astype(np.float64), args.axis)(axis=1))
    n = coords.shape[0]
    geometry = sum(u.size for u in read_container(data).units if u.unit_type == UnitType.GEOMETRY)
    print(f"{args.stream.name}: {n:,} Gaussians, octree depth {depth}, geometry {8 * geometry / n:.2f} bits per "
          f"Gaussian of {8 * len(data) / n:.2f}; levels alone {alone.mean():.2f} on average "
          f"(about {3 * alone.mean():.2f} bits per Gaussian); size = the {args.axis} of the scales")
    for alpha in args.alpha:
        r = np.floor(np.log2(np.maximum(2 * alpha * size / voxel, 1))).astype(np.int64)
        saved = 3 * np.minimum(r, alone)
        print(f"  alpha {alpha:g}: {np.mean(r >= 1):.0%} of the Gaussians may drop a level or more (mean {r.mean():.2f}); "
              f"saved at most {saved.mean():.2f} bits per Gaussian, {100 * saved.sum() / (8 * len(data)):.1f}% of the stream")
    return 0


if __name__ == "__main__":
    sys.exit(main())
