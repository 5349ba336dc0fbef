#!/usr/bin/env python3
"""Where an explicit-Gaussian stream's decode spends its CPU, stage by stage (issue 53 item 5).

One in-process decode of each STREAM in one process (``decode_stream(jobs=1)``, the k-NN
candidate search on one thread, so that the process's CPU clock is the work's), then the 3DGS PLY
write of the decoded scene (``write_3dgs_ply``, as ``lghcc-dec --export-ply`` writes it). Each
stage's own CPU seconds (``time.process_time``, the time of the stages it calls taken out), its
share and microseconds per Gaussian:

- geometry: the octree (clause 9), ``decode_geometry``;
- k-NN graph: the LoDs' neighbours (clause 11.7), ``neighbour_graph``;
- neighbour means and buckets: each LoD's coding parameters from its neighbours' values;
- entropy decoding and cross-channel prediction: the chunks' symbols, ``decode_chunk_values``;
- inverse SH transform and reconstruction: ``reconstruct_chunk`` (clauses 11.5, 11.10, 11.11);
- tile hashes (clause 12), the scene's positions, the PLY write;
- the rest: parsing, the attribute unit's own work (scattering rows, the LoDs' rows).

Nothing is written but the report (and a scratch PLY in --work). The lghcc imported is the
environment's: put another tree first on PYTHONPATH to time it (before/after on one machine); the
load average is printed with each stream (a shared machine's CPU seconds vary with it too).

    python tools/decode_stages.py STREAM.lghcc [STREAM ...] [--work DIR]

Exit status: 0, 2 usage (a stream that cannot be read or is not an explicit-Gaussian stream).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads on a shared machine

import argparse  # noqa: E402
import collections  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lghcc.common import neighbour_prediction as npd  # noqa: E402
from lghcc.common.knn import candidate_generator, set_candidate_threads  # noqa: E402
from lghcc.common.scene import GaussianScene  # noqa: E402
from lghcc.decoder import core  # noqa: E402
from lghcc.decoder.decode import decode_stream  # noqa: E402
from lghcc.formats import ply3dgs  # noqa: E402

STAGES = ((core, "decode_geometry", "geometry"), (npd, "neighbour_graph", "k-NN graph"),
          (npd, "_lod_params", "neighbour means and buckets"),
          (npd, "_adjusted_chunk_params", "neighbour means and buckets"),
          (npd, "decode_chunk_values", "entropy decoding and cross-channel prediction"),
          (npd, "reconstruct_chunk", "inverse SH transform and reconstruction"),
          (core, "check_tile_hash", "tile hashes"), (core, "scene_of", "scene (positions)"),
          (ply3dgs, "write_ply", "PLY write"))


def timed_stages() -> collections.Counter:
    """Wrap each stage's function (in the module that calls it) to add its own CPU seconds to the
    returned counter."""
    own: collections.Counter = collections.Counter()
    inner: list[float] = []

    def wrap(mod, name: str, label: str) -> None:
        f = getattr(mod, name)

        def timed(*a, **k):
            t = time.process_time()
            inner.append(0.0)
            try:
                return f(*a, **k)
            finally:
                nested, dt = inner.pop(), time.process_time() - t
                own[label] += dt - nested
                if inner:
                    inner[-1] += dt
        setattr(mod, name, timed)

    for mod, name, label in STAGES:
        wrap(mod, name, label)
    return own


def report(path: Path, own: collections.Counter, work: Path) -> list[str]:
    data = path.read_bytes()
    own.clear()
    t0 = time.process_time()
    result = decode_stream(data, jobs=1)
    if not isinstance(result.scene, GaussianScene):
        raise SystemExit(f"decode_stages.py: {path}: an anchor stream; this tool times explicit-Gaussian streams")
    ply3dgs.write_3dgs_ply(work / "decode_stages.ply", result.scene)
    total = time.process_time() - t0
    n = max(result.scene.num_gaussians, 1)
    lines = [f"{path}: {result.scene.num_gaussians:,} Gaussians, SH degree {result.scene.sh_degree}, "
             f"{len(data):,} bytes, {result.num_tiles} tiles; decode + PLY write {total:.2f} s CPU = "
             f"{total / n * 1e6:.2f} us per Gaussian; load {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
             "", "| stage | CPU s | share | us / Gaussian |", "|---|---:|---:|---:|"]
    rest = total - sum(own.values())
    for label, s in [*sorted(own.items(), key=lambda x: -x[1]), ("the rest (parse, the attribute unit's own)", rest)]:
        lines.append(f"| {label} | {s:.2f} | {s / max(total, 1e-9) * 100:.1f}% | {s / n * 1e6:.2f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("streams", nargs="+", type=Path, help="explicit-Gaussian .lghcc streams")
    ap.add_argument("--work", type=Path, default=None, help="where the scratch PLY goes (default: a temporary folder)")
    args = ap.parse_args(argv)
    for p in args.streams:
        if not p.is_file():
            ap.error(f"{p}: no such stream")
    t = time.process_time()
    candidate_generator()  # its import (scipy) is start-up, not a stage
    set_candidate_threads(1)
    print(f"imports: {time.process_time() - t:.2f} s CPU (not counted below)")
    own = timed_stages()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        for p in args.streams:
            print("\n".join(["", *report(p, own, work)]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
