#!/usr/bin/env python
"""Where is each scene watched from? The encoder's decision (encoder/gaussians/free_space.py) on the
shared scenes and on built ones whose answer is known, with the figures it decides by: the share of
the box that is roomy free space enclosed on all sides, the share of roomy free space, and the best
enclosure (share of directions that meet the scene) of a roomy place. The constants of
free_space.py were set from this table.

    python tools/bench_views.py                          # writes tools/results/views.md (section a; b and c stay)
    python tools/bench_views.py --out /tmp/views.md --scenes room,sphere
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import datetime  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SHARED = {"donut": ("donut/donut.ply", "orbit"), "playbot-lod4": ("playbot/playbot_lod4_8k.ply", "orbit"),
          "playbot-lod3": ("playbot/playbot_lod3_31k.ply", "orbit"),
          "playcanvas-logo": ("playcanvas-logo/playcanvas_logo_307k.ply", "orbit"),
          "garden-sfm": ("garden/test_garden.npz", "inside or both")}
BUILT = {"room": "inside", "empty-box": "inside or both (geometry cannot tell)",
         "sphere-shell": "inside or both (geometry cannot tell)", "solid-cube": "orbit"}


def points_scene(points: np.ndarray):
    """Opaque small Gaussians at ``points`` (what free_space.py reads of a scene is its opaque means)."""
    from lghcc.common.scene import GaussianScene

    n = points.shape[0]
    return GaussianScene(points.astype(np.float32), np.zeros((n, 1, 3), np.float32), np.full(n, 3.0, np.float32),
                         np.full((n, 3), -4.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)))


def built_scene(name: str):
    from lghcc.formats.procedural import make_room_scene

    rng = np.random.default_rng(0)
    if name == "room":
        return make_room_scene(60_000)
    if name == "empty-box":
        faces = []
        for axis in range(3):
            for side in (0.0, 1.0):
                p = rng.uniform(0, 1, (5000, 3)) * [6, 5, 3]
                p[:, axis] = side * [6, 5, 3][axis]
                faces.append(p)
        return points_scene(np.concatenate(faces))
    if name == "sphere-shell":
        d = rng.normal(size=(30_000, 3))
        return points_scene(d / np.linalg.norm(d, axis=1, keepdims=True))
    return points_scene(rng.uniform(-1, 1, (30_000, 3)))


def shared_scene(rel: str):
    from lghcc.formats import read_scene

    if rel.endswith(".npz"):  # SfM points: what a 360 capture's geometry looks like before training
        return points_scene(np.load(DATA / rel)["means3d"])
    return read_scene(DATA / rel)


def row(name: str, scene, expected: str) -> str:
    from lghcc.encoder.gaussians.free_space import watched_from

    t0 = time.perf_counter()
    found = watched_from(scene)
    seconds = time.perf_counter() - t0
    figures = found.reason[found.reason.index("(") + 1:found.reason.rindex(")")] if "(" in found.reason else \
        found.reason
    return (f"| {name} | {scene.num_gaussians:,} | {expected} | **{found.kind}** | {figures} | "
            f"{len(found.eyes)} | {seconds:.2f} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default=",".join([*SHARED, *BUILT]),
                    help=f"comma-separated, of {', '.join([*SHARED, *BUILT])} (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "views.md")
    args = ap.parse_args(argv)
    names = [s for s in args.scenes.split(",") if s]
    unknown = [s for s in names if s not in SHARED and s not in BUILT]
    if unknown:
        ap.error(f"unknown scenes: {', '.join(unknown)}")
    rows = []
    for name in names:
        if name in SHARED and not (DATA / SHARED[name][0]).exists():
            print(f"bench_views: {name}: {DATA / SHARED[name][0]} missing, skipped", file=sys.stderr)
            continue
        scene = shared_scene(SHARED[name][0]) if name in SHARED else built_scene(name)
        rows.append(row(name, scene, SHARED[name][1] if name in SHARED else BUILT[name]))
        print(rows[-1])
    lines = ["## (a) Where each scene is watched from: the decision and its figures", "",
             f"Command: `{command_line('bench_views.py', argv)}`; {datetime.date.today()}.", "",
             "| scene | Gaussians | watched | decided | figures (free_space.py) | viewpoints | s |",
             "|---|---|---|---|---|---|---|", *rows]
    if args.out.exists():  # the other sections of the results file (b, c: bench_real's) stay
        rest = args.out.read_text().split("\n## (")[1:]
        lines += [""] + ["## (" + sec.rstrip("\n") for sec in rest if not sec.startswith("a)")]
    write_lines(args.out, lines)
    print(f"bench_views: wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
