#!/usr/bin/env python3
"""lghcc-enc's peak memory and time per Gaussian on SH-3 scenes (issue 53), and the same scenes at SH 0.

The scenes: tools/scale_scenes.py's scene of each size (--sizes) given SH-3 content
(scale_scenes.with_sh3_content: playbot lod3's bands 1-2, band 3 from them), written as 3DGS PLYs
into --work, and the same cut to SH 0. Each is encoded by lghcc-enc (--preset, default fast;
--jobs 2 --no-verify, as tools/bench_scale.py) in its own process under GNU time: peak RSS (the
largest process), wall and CPU seconds, the stage times (--json) and the --max-memory estimate
(encoder/stream/memory.py) of the scene. One markdown row per run on stdout.

    python tools/bench_sh3_memory.py --sizes 100k,300k --work /tmp/sh3   # minutes

Results: tools/results/scale.md, section "SH 3 memory (issue 53)". Exit status: 0 done, 1 a scene
source missing.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real as br  # noqa: E402
import scale_scenes  # noqa: E402
from bench_scale import parse_size  # noqa: E402


def build(n: int, work: Path, data_root: Path) -> dict[int, Path]:
    """{SH degree: PLY} of the scene of ``n`` Gaussians at SH 3 and at SH 0 (written once)."""
    from lghcc.formats.ply3dgs import read_3dgs_ply, write_3dgs_ply

    paths = {d: work / f"sh3_{n}_sh{d}.ply" for d in (3, 0)}
    if not all(p.exists() for p in paths.values()):
        scene, _ = scale_scenes.build_scene(n, scale_scenes.load_sources(data_root))
        playbot = read_3dgs_ply(data_root / scale_scenes.SOURCES[1][1])
        sh3 = scale_scenes.with_sh3_content(scene, playbot)
        write_3dgs_ply(paths[3], sh3)
        write_3dgs_ply(paths[0], sh3.with_sh_degree(0))
    return paths


def estimate(ply: Path, preset: str) -> int:
    """The --max-memory estimate (bytes) of encoding ``ply`` with ``preset`` and 2 worker processes."""
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.memory import encode_memory
    from lghcc.encoder.stream.tile_workers import TileWorkers
    from lghcc.formats.ply3dgs import read_3dgs_ply

    return encode_memory(read_3dgs_ply(ply), load_config(preset, kind="gaussians"), TileWorkers(jobs=2)).total


def run(ply: Path, preset: str, work: Path) -> str:
    out, js, tm = (work / f"{ply.stem}_{preset}{ext}" for ext in (".lghcc", ".json", ".time"))
    cmd = ["/usr/bin/time", "-f", "%M %e %U %S", "-o", str(tm), sys.executable, "-m", "lghcc.encoder.cli", str(ply),
           "-o", str(out), "-y", "--preset", preset, "--jobs", "2", "--no-verify", "--json", str(js), "-q"]
    subprocess.run(cmd, check=True)
    rss_kb, wall, user, system = (float(x) for x in tm.read_text().split())
    stats = json.loads(js.read_text())
    n = stats["num_gaussians"]
    stages = ", ".join(f"{k} {v:.1f}" for k, v in stats["stats"]["stage_times_s"].items())
    est = estimate(ply, preset)
    load = Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() else "n/a"
    return (f"| {preset} | {ply.stem} | {n:,} | {rss_kb / 1024:,.0f} | {(rss_kb * 1024 - (320 << 20)) / n:,.0f} | "
            f"{est / 2 ** 20:,.0f} | {wall:.1f} | {1e6 * wall / n:.0f} | {1e6 * (user + system) / n:.0f} | {stages} | "
            f"{load} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="100k,300k")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--work", type=Path, default=Path("/tmp/lghcc_sh3"))
    ap.add_argument("--data-root", type=Path, default=None, help="the shared scenes (default ../shared/data)")
    args = ap.parse_args(argv)
    args.data = args.data_root or br.default_data_root()
    if not all((args.data / rel).exists() for _, rel in scale_scenes.SOURCES):
        print(f"bench_sh3_memory: scene sources missing under {args.data}", file=sys.stderr)
        return 1
    args.work.mkdir(parents=True, exist_ok=True)
    print("| preset | scene | Gaussians | peak RSS MiB | bytes / Gaussian above 320 MiB | --max-memory estimate MiB | "
          "wall s | us / Gaussian | CPU us / Gaussian | stages s | load |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for n in (parse_size(s) for s in args.sizes.split(",")):
        for degree, ply in build(n, args.work, args.data).items():
            print(run(ply, args.preset, args.work), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
