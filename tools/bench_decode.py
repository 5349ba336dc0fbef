#!/usr/bin/env python3
"""Decoding by stream kind: what lghcc-dec costs, split into start, parse, decode and write, with 1
and 2 worker processes, --jobs auto, a box and the level-1 preview (issue 38).

Streams (cached in ``--cache``, encoded once): procedural anchor scenes (32 features, 10 offsets)
at the anchor presets low and medium (per-channel prior, no hierarchy) and lghcc-low (the
hierarchy and GG-Conv, short context training as tools/results/tiles.md's: the decoder's speed does
not depend on it), and procedural explicit-Gaussian scenes (SH degree 1, smooth attributes) at
gaussians-medium's steps (neighbour prediction, step adjustment; no settings search, no fit), at
the sizes ``--sizes`` (default 100k; 1M for the medium presets: ``--large``).

Each case is one ``lghcc-dec STREAM -o DIR -y -q --json J`` in a fresh process (nice'd), wall
time; the JSON gives the seconds of parse (clause 13.1 steps 1-5), decode (the tiles) and write
(-o); start is the rest (interpreter, imports, reading the file, exit). "2 workers" forces two
workers (decode.worker_plan with exact_jobs), "auto" is the default. The box is a small cube at
the centre of the largest tile's cell: it reads 1 of n tiles. The cases alternate over
``--repeats`` rounds; medians.

``--calibrate`` measures decoder/jobs.py's constants in this process: a worker's start (a fork
pool of 2 workers with the decoder and torch loaded, two no-op tasks), a task's round trip, and
the tiles' decode time per point and per value, by coding tool (the tiles one after the other).

    python tools/bench_decode.py                        # writes tools/results/decode.md
    python tools/bench_decode.py --calibrate --large
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse  # noqa: E402
import datetime
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("medium", "low", "lghcc-low", "gaussians-medium")
# forces exactly --jobs N workers (the "2 workers" rows): the CLI otherwise takes at most N
FORCED = ("import sys; from lghcc.decoder import decode as d; p = d.worker_plan; "
          "d.worker_plan = lambda *a, **k: p(*a, **{**k, 'exact_jobs': True}); "
          "from lghcc.decoder.cli import main; sys.exit(main(sys.argv[1:]))")
PLAIN = "import sys; from lghcc.decoder.cli import main; sys.exit(main(sys.argv[1:]))"


def encode(kind: str, n: int):
    """-> stream bytes of a procedural scene of about n points for a preset kind."""
    if kind.startswith("gaussians"):
        from lghcc.conformance.generate import random_gaussian_scene
        from lghcc.encoder.stream.config import load_config
        from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene

        spread = int(round((n * 4) ** (1 / 3)))  # positions on a grid of (2 spread)^3 cells, n of them occupied
        scene = random_gaussian_scene({"num_gaussians": n, "sh_degree": 1, "seed": 5, "smooth": True,
                                       "spread": spread})
        return encode_gaussian_scene(scene, load_config(kind.removeprefix("gaussians-"), kind="gaussians")).data
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.formats.procedural import make_procedural_scene

    scene = make_procedural_scene(n, seed=0, feature_dim=32, num_offsets=10)
    over = {} if not kind.startswith("lghcc") else {
        "context_neighbour_level": 1, "context_parent_base": "choose", "context_float_steps": 150,
        "context_qat_steps": 30, "context_train_points": 50_000}
    return encode_scene(scene, load_config(kind, overrides=over)).data


def stream_path(cache: Path, kind: str, n: int) -> Path:
    path = cache / f"{kind}_{n}.lghcc"
    if not path.is_file():
        t = time.perf_counter()
        data = encode(kind, n)
        path.write_bytes(data)
        print(f"encoded {path.name}: {len(data):,} bytes in {time.perf_counter() - t:.1f} s", flush=True)
    return path


def one_tile_box(data: bytes):
    """A small cube at the centre of the largest tile's cell (world coordinates): it selects that
    tile alone. None for a stream without tiles."""
    from lghcc.decoder.decode import parse_stream

    s = parse_stream(data)
    if s.tiles[0].cell is None:
        return None
    big = max(s.tiles, key=lambda t: t.num_points)
    size, v = s.ps.tile_size, float(s.ps.voxel_size)
    centre = [(c + 0.5) * size * v + float(o) for c, o in zip(big.cell, s.ps.origin)]
    eps = 0.01 * size * v
    return ",".join(f"{x:.9g}" for x in [c - eps for c in centre] + [c + eps for c in centre])


def run_case(stream: Path, extra: list[str], forced: bool) -> dict:
    """One lghcc-dec run in a fresh nice'd process -> wall seconds, the JSON's, the exit status."""
    with tempfile.TemporaryDirectory() as tmp:
        j = Path(tmp) / "r.json"
        argv = [str(stream), "-o", str(Path(tmp) / "out"), "-y", "-q", "--json", str(j), *extra]
        t = time.perf_counter()
        p = subprocess.run(["nice", "-n", "10", sys.executable, "-c", FORCED if forced else PLAIN, *argv],
                           capture_output=True, text=True, cwd=ROOT)
        wall = time.perf_counter() - t
        info = json.loads(j.read_text()) if p.returncode == 0 else {"error": p.stderr.strip()[-200:]}
    return {"wall": wall, "rc": p.returncode, **info}


def cases_of(data: bytes) -> list[tuple[str, list[str], bool]]:
    box = one_tile_box(data)
    out = [("1 process (--jobs 1)", ["--jobs", "1"], False), ("2 workers (forced)", ["--jobs", "2"], True),
           ("--jobs auto", [], False)]
    if box is not None:
        out.append(("--box (1 tile)", [f"--box={box}"], False))
    return out + [("--level 1", ["--level", "1"], False)]


def bench_stream(kind: str, n: int, path: Path, repeats: int) -> list[dict]:
    cases = cases_of(path.read_bytes())
    runs: list[list[dict]] = [[] for _ in cases]
    for _ in range(repeats):  # alternated: the machine's drift falls on every case
        for i, (_, extra, forced) in enumerate(cases):
            runs[i].append(run_case(path, extra, forced))
    rows = []
    for (label, _, _), rs in zip(cases, runs):
        best = sorted(rs, key=lambda r: r["wall"])[len(rs) // 2]  # the median run, its split with it
        rows.append({"kind": kind, "n": n, "case": label, "bytes": path.stat().st_size, **best})
        print(_row(rows[-1]), flush=True)
    return rows


def _row(r: dict) -> str:
    if r["rc"] != 0:
        return (f"| {r['kind']} | {r['n']:,} | {r['case']} | - | - | - | {r['wall']:.2f} | - | - | - | "
                f"exit {r['rc']}: {r['error'][:90]} |")
    s = r["seconds"]
    start = r["wall"] - s["parse"] - s["decode"] - s["write"]
    return (f"| {r['kind']} | {r['n']:,} | {r['case']} | {r['tiles_decoded']} of {r['tiles']} | {r['workers']} | "
            f"{r.get('num_anchors', r.get('num_gaussians', 0)):,} | {r['wall']:.2f} | {start:.2f} | "
            f"{s['parse']:.2f} | {s['decode']:.2f} | {s['write']:.2f} |")


def verdicts(rows: list[dict]) -> list[str]:
    """The targets of issue 38, per stream."""
    out = []
    for key in sorted({(r["kind"], r["n"]) for r in rows}, key=lambda k: (k[1], k[0])):
        rs = {r["case"]: r for r in rows if (r["kind"], r["n"]) == key}
        one, two, auto = rs["1 process (--jobs 1)"], rs["2 workers (forced)"], rs["--jobs auto"]
        best = min(one["wall"], two["wall"])
        text = f"- {key[0]}, {key[1]:,}: auto {auto['wall']:.2f} s against the best of 1 and 2 {best:.2f} s " \
               f"({auto['wall'] / best - 1:+.1%}; target <= +5%: {'met' if auto['wall'] <= 1.05 * best else 'MISSED'})"
        box = rs.get("--box (1 tile)")
        if box is not None and box["rc"] == 0:
            full = one if one["wall"] <= auto["wall"] else auto
            start = full["wall"] - sum(full["seconds"].values())
            k, n = box["tiles_decoded"], box["tiles"]
            limit = start + (k / n + 0.1) * (full["wall"] - start)
            text += (f"; box {k} of {n} tiles {box['wall']:.2f} s, limit {limit:.2f} s (start {start:.2f} + "
                     f"{k / n + 0.1:.3f} x the rest): {'met' if box['wall'] <= limit else 'MISSED'}")
        prev = rs["--level 1"]
        text += (f"; --level 1: exit {prev['rc']}" + (" (no hierarchy: refused)" if prev["rc"] == 2 else
                                                      f", {prev.get('num_anchors', 0):,} of {one.get('num_anchors', 0):,} points"))
        out.append(text)
    return out


def calibrate(paths: list[tuple[str, Path]]) -> list[str]:
    """decoder/jobs.py's constants measured here (see the module docstring)."""
    import torch  # noqa: F401  (loaded as it is for context-model streams: a larger process to fork)

    from lghcc.decoder.core import decode_tile
    from lghcc.decoder.decode import attribute_tool, parse_stream

    lines = [_worker_start(), ""]
    print(lines[0], flush=True)
    lines += ["| stream | tool | tiles | points | channels | s | s per point | s per value |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, path in paths:
        s = parse_stream(path.read_bytes())
        t0 = time.perf_counter()
        for t, tile in enumerate(s.tiles):
            decode_tile(tile, t, s.ps, s.layout, s.context_model, s.mlps)
        secs, pts, ch = time.perf_counter() - t0, sum(t.num_points for t in s.tiles), s.layout.num_channels
        lines.append(f"| {name} | {attribute_tool(s.ps, s.context_model)} | {len(s.tiles)} | {pts:,} | {ch} | "
                     f"{secs:.2f} | {secs / pts:.3g} | {secs / pts / ch:.3g} |")
        print(lines[-1], flush=True)
    return lines


def _noop(x):
    return x


def _worker_start() -> str:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from lghcc.decoder.decode import init_tile_worker

    starts, tasks = [], []
    for _ in range(5):
        t = time.perf_counter()
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork"), initializer=init_tile_worker,
                                 initargs=(None,)) as pool:
            list(pool.map(_noop, range(2)))
            t1 = time.perf_counter()
            list(pool.map(_noop, range(200)))
            t2 = time.perf_counter()
        starts.append((t1 - t) / 2)
        tasks.append((t2 - t1) / 200 * 2)  # a task's round trip, on one of the two workers
    return (f"Worker start (fork, the decoder and torch loaded; a 2-worker pool and its first tasks, per worker): "
            f"median {statistics.median(starts) * 1e3:.1f} ms of 5 (max {max(starts) * 1e3:.1f}); a task's round "
            f"trip {statistics.median(tasks) * 1e3:.2f} ms.")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000])
    ap.add_argument("--large", type=int, default=0, metavar="N",
                    help="also streams of N points (e.g. 1000000) for the medium presets")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "lghcc_bench_decode"))
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "decode.md"))
    args = ap.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    load_before = load_average()
    todo = [(k, n) for n in args.sizes for k in args.kinds]
    todo += [(k, args.large) for k in ("medium", "gaussians-medium") if args.large and k in args.kinds]
    paths = [(k, n, stream_path(cache, k, n)) for k, n in todo]
    calib = calibrate([(f"{k}, {n:,}", p) for k, n, p in paths]) if args.calibrate else []
    rows = [r for k, n, p in paths for r in bench_stream(k, n, p, args.repeats)]
    lines = [
        "# Decoding by stream kind: start, parse, decode, write; workers, box, preview", "",
        f"Command: `{command_line('bench_decode.py', argv)}`  ",
        f"Date: {datetime.date.today()}; {platform.machine()}, {os.cpu_count()} CPUs (shared); load {load_before} "
        f"before, {load_average()} after.", "",
        f"Each case one `lghcc-dec STREAM -o DIR -y -q --json J` in a fresh nice'd process, the median of "
        f"{args.repeats} alternated runs. start: wall minus parse, decode and write (interpreter, imports, reading "
        "the file, exit).", "",
        "| stream kind | points | decode | tiles | workers | points out | wall s | start | parse | decode | write |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|", *[_row(r) for r in rows], "",
        "## Against the targets of issue 38", "", *verdicts(rows), ""]
    if calib:
        lines += ["## Calibration of decoder/jobs.py", "", *calib, ""]
    write_lines(Path(args.out), lines)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
