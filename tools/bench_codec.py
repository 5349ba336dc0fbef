#!/usr/bin/env python3
"""Codec throughput and decoder memory on procedural scenes.

For each size: encode time, decode time (anchors/s), stream size and breakdown,
attribute coding overhead over the model's ideal, and the decoder's peak memory
against the target 3 x decoded-scene size + 300 MB, measured twice in fresh child
processes limited to --threads threads (torch, OpenMP and BLAS):

  decode_stream   a child that only decodes the stream in memory;
  lghcc-dec -o    a child that runs the real command line (lghcc.decoder.cli.main, what
                  the lghcc-dec script calls) with -o, so its peak includes reading the
                  file and writing the Scaffold-GS folder; its wall time is reported too.

Writes a markdown table (default tools/results/codec.md).

    python tools/bench_codec.py --sizes 10000 100000 1000000

Long runs can be split: --rows FILE keeps the measured rows in a JSON file, merged by
size with those already there, and the table shows them all.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse
import datetime
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Peak memory is VmHWM of the child itself: ru_maxrss would carry over the parent's peak
# across fork/exec on Linux.
CHILD = r"""
import sys, time
def hwm():
    return next(int(l.split()[1]) * 1024 for l in open('/proc/self/status') if l.startswith('VmHWM'))
import torch
torch.set_num_threads(int(sys.argv[2]))
from lghcc.decoder.decode import decode_stream
data = open(sys.argv[1], 'rb').read()
base = hwm()
t = time.perf_counter(); r = decode_stream(data); dt = time.perf_counter() - t
s = r.scene
scene_bytes = s.coords.nbytes + s.features.nbytes + s.scalings.nbytes + s.offsets.nbytes
print(dt, hwm(), base, scene_bytes, torch.get_num_threads())
"""

# The command line itself, as the lghcc-dec script runs it; the peak is read after main() returns,
# so it covers decoding and writing the output folder.
CLI_CHILD = r"""
import sys, time
def hwm():
    return next(int(l.split()[1]) * 1024 for l in open('/proc/self/status') if l.startswith('VmHWM'))
from lghcc.decoder.cli import main
t = time.perf_counter()
rc = main(sys.argv[1:])
dt = time.perf_counter() - t
import torch
print(rc, dt, hwm(), torch.get_num_threads(), file=sys.stderr)
"""


def _child_env(threads: int) -> dict[str, str]:
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[var] = str(threads)
    return env


def _load_avg() -> str:
    try:
        return " / ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000, 1000000])
    ap.add_argument("--preset", default="medium")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "codec.md"))
    ap.add_argument("--rows", metavar="JSON", help="keep the rows in this JSON file, merged by size with earlier runs")
    args = ap.parse_args(argv)

    import torch

    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.encode import encode_scene

    torch.set_num_threads(args.threads)
    cfg = load_config(args.preset)
    env = _child_env(args.threads)
    rows = {}
    for n in args.sizes:
        load_before = _load_avg()
        t0 = time.perf_counter()
        scene = make_procedural_scene(n, seed=0)
        t_gen = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = encode_scene(scene, cfg)
        t_enc = time.perf_counter() - t0
        ideal = encode_scene(scene, cfg, measure_ideal=True).stats.attribute_ideal_bits
        with tempfile.TemporaryDirectory() as tmp:
            stream = Path(tmp) / "s.lghcc"
            stream.write_bytes(res.data)
            out = subprocess.run([sys.executable, "-c", CHILD, str(stream), str(args.threads)], capture_output=True,
                                 text=True, check=True, env=env)
            t_dec, peak, base, scene_bytes, child_threads = (float(x) for x in out.stdout.split())
            cli = subprocess.run([sys.executable, "-c", CLI_CHILD, str(stream), "-o", str(Path(tmp) / "dec"), "-q",
                                  "--threads", str(args.threads)], capture_output=True, text=True, env=env)
            rc, t_cli, cli_peak, cli_threads = (float(x) for x in cli.stderr.split()[-4:])
            if rc != 0:
                raise SystemExit(f"lghcc-dec failed: {cli.stderr}")
            assert child_threads == cli_threads == args.threads, (child_threads, cli_threads)
        b = res.breakdown.bytes_by_category
        na = scene.num_anchors
        target = 3 * scene_bytes + 300e6
        overhead = res.stats.attribute_coded_bits / ideal - 1
        rows[str(n)] = dict(
            anchors=na, bytes=len(res.data), geometry_bpa=8 * b["geometry"] / na,
            attribute_bpa=8 * b["attributes"] / na, model_bpa=8 * b["model"] / na, encode_aps=na / t_enc,
            decode_aps=na / t_dec, overhead_pct=100 * overhead, decode_peak_mb=peak / 1e6,
            decoding_mb=(peak - base) / 1e6, cli_peak_mb=cli_peak / 1e6, cli_s=t_cli, target_mb=target / 1e6,
            generate_s=t_gen, date=str(datetime.date.today()), load=f"{load_before} -> {_load_avg()}",
            threads=args.threads)
        r = rows[str(n)]
        print(f"{na:>9,} anchors: {len(res.data):,} B, enc {na / t_enc:,.0f}/s, dec {na / t_dec:,.0f}/s, "
              f"peak decode_stream {r['decode_peak_mb']:.0f} MB, lghcc-dec -o {r['cli_peak_mb']:.0f} MB in "
              f"{t_cli:.1f} s (target {target / 1e6:.0f} MB); generated in {t_gen:.0f} s", flush=True)

    if args.rows:
        old_rows = json.loads(Path(args.rows).read_text()) if Path(args.rows).exists() else {}
        old_rows.update(rows)
        rows = old_rows
        Path(args.rows).write_text(json.dumps(rows, indent=2))
    sizes = sorted(rows, key=int)
    over = [s for s in sizes if rows[s]["cli_peak_mb"] > rows[s]["target_mb"]]
    lines = [
        "# Codec throughput and decoder memory",
        "",
        f"Command: `python tools/bench_codec.py --sizes {' '.join(sizes)} --preset {args.preset} "
        f"--threads {args.threads}`" + (" (sizes run separately, merged with --rows)" if args.rows else "") + "  ",
        f"Date: {', '.join(sorted({rows[s]['date'] for s in sizes}))}; machine: {platform.machine()}, "
        f"{os.cpu_count()} CPUs shared with other work (timings are noisy), {args.threads} threads in every "
        "decoder child (torch, OpenMP, BLAS). Load average (1/5/15 min) before -> after each size: "
        + "; ".join(f"{int(s):,}: {rows[s]['load']}" for s in sizes) + ".  ",
        "Scene: procedural (`common/procedural.py`, seed 0), C=50, K=10, per-channel prior.",
        "",
        "| anchors | bytes | geometry bits/anchor | attribute bits/anchor | model bits/anchor | encode anchors/s "
        "| decode anchors/s | attribute overhead vs ideal | decode_stream peak RSS MB | of which decoding MB "
        "| lghcc-dec -o peak RSS MB | lghcc-dec -o wall s | target MB (3x scene + 300) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in sizes:
        r = rows[s]
        lines.append(f"| {r['anchors']:,} | {r['bytes']:,} | {r['geometry_bpa']:.2f} | {r['attribute_bpa']:.1f} "
                     f"| {r['model_bpa']:.2f} | {r['encode_aps']:,.0f} | {r['decode_aps']:,.0f} "
                     f"| {r['overhead_pct']:+.4f}% | {r['decode_peak_mb']:.0f} | {r['decoding_mb']:.0f} "
                     f"| {r['cli_peak_mb']:.0f} | {r['cli_s']:.1f} | {r['target_mb']:.0f} |")
    lines.append("")
    lines.append("Decode target: >= 200,000 anchors/s at 1M anchors on 2 cores; peak memory under the target column. "
                 "decode_stream: a child that only decodes in memory (its peak RSS, and the part of it above the "
                 "RSS before decoding). lghcc-dec -o: a child running the command line with -o, its peak RSS "
                 "covering reading the stream, decoding and writing the Scaffold-GS folder (PLY written in row "
                 "blocks), and its wall time including the write. "
                 + ("Every size is under the target." if not over else
                    f"Over the target: {', '.join(f'{int(s):,}' for s in over)}."))
    lines.append("")
    lines.append("Generating the procedural scene (not part of the codec) took "
                 + ", ".join(f"{rows[s]['generate_s']:.0f} s at {int(s):,}" for s in sizes) + ".")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
