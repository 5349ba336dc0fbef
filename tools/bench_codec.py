#!/usr/bin/env python3
"""Codec throughput and decoder memory on procedural scenes.

For each size: encode time, decode time (anchors/s), stream size and breakdown,
attribute coding overhead over the model's ideal, and the decoder's peak memory
(max RSS of a fresh child process that only decodes) against the target
3 x decoded-scene size + 300 MB. Writes a markdown table (default
tools/results/codec.md).

    python tools/bench_codec.py --sizes 10000 100000 1000000
"""

from __future__ import annotations

import argparse
import datetime
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
from lghcc.decoder.decode import decode_stream
data = open(sys.argv[1], 'rb').read()
base = hwm()
t = time.perf_counter(); r = decode_stream(data); dt = time.perf_counter() - t
s = r.scene
scene_bytes = s.coords.nbytes + s.features.nbytes + s.scalings.nbytes + s.offsets.nbytes
print(dt, hwm(), base, scene_bytes)
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000, 1000000])
    ap.add_argument("--preset", default="medium")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "codec.md"))
    args = ap.parse_args(argv)

    import torch

    from lghcc.common.procedural import make_procedural_scene
    from lghcc.encoder.config import load_config
    from lghcc.encoder.encode import encode_scene

    torch.set_num_threads(args.threads)
    cfg = load_config(args.preset)
    rows = []
    for n in args.sizes:
        scene = make_procedural_scene(n, seed=0)
        t0 = time.perf_counter()
        res = encode_scene(scene, cfg)
        t_enc = time.perf_counter() - t0
        ideal = encode_scene(scene, cfg, measure_ideal=True).stats["attribute_ideal_bits"]
        with tempfile.NamedTemporaryFile(suffix=".lghcc") as f:
            f.write(res.data)
            f.flush()
            out = subprocess.run([sys.executable, "-c", CHILD, f.name], capture_output=True, text=True, check=True)
        t_dec, peak, base, scene_bytes = (float(x) for x in out.stdout.split())
        b = res.breakdown.bytes_by_category
        na = scene.num_anchors
        target = 3 * scene_bytes + 300e6
        overhead = res.stats["attribute_coded_bits"] / ideal - 1
        rows.append((na, len(res.data), 8 * b["geometry"] / na, 8 * b["attributes"] / na, 8 * b["model"] / na,
                     na / t_enc, na / t_dec, 100 * overhead, peak / 1e6, (peak - base) / 1e6, target / 1e6))
        print(f"{na:>9,} anchors: {len(res.data):,} B, enc {na / t_enc:,.0f}/s, dec {na / t_dec:,.0f}/s, "
              f"peak {peak / 1e6:.0f} MB (target {target / 1e6:.0f} MB)", flush=True)

    lines = [
        "# Codec throughput and decoder memory",
        "",
        f"Command: `python tools/bench_codec.py --sizes {' '.join(map(str, args.sizes))} --preset {args.preset} "
        f"--threads {args.threads}`  ",
        f"Date: {datetime.date.today()}; machine: {platform.machine()}, {args.threads} torch threads, "
        "shared 2-core VM (timings are noisy). Scene: procedural (`common/procedural.py`, seed 0), "
        "C=50, K=10, per-channel prior.",
        "",
        "| anchors | bytes | geometry bits/anchor | attribute bits/anchor | model bits/anchor | encode anchors/s "
        "| decode anchors/s | attribute overhead vs ideal | decoder peak RSS MB | of which decoding MB "
        "| target MB (3x scene + 300) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r[0]:,} | {r[1]:,} | {r[2]:.2f} | {r[3]:.1f} | {r[4]:.2f} | {r[5]:,.0f} | {r[6]:,.0f} "
                     f"| {r[7]:+.4f}% | {r[8]:.0f} | {r[9]:.0f} | {r[10]:.0f} |")
    lines.append("")
    lines.append("Decode target: >= 200,000 anchors/s at 1M anchors on 2 cores; peak memory under the target column.")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
