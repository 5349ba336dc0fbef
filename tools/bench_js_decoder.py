"""Speed of the JavaScript decoder (viewer/web/decoder) against the reference decoder, on real
scenes coded at a preset's steps (no search, no fit: the preset's quantization, neighbour
prediction where it pays, tiles of about 16k Gaussians as lghcc-enc writes them).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 .venv/bin/python tools/bench_js_decoder.py [--out DIR] [--repeat R]

Writes the streams to --out (kept between runs: a stream already there is reused), decodes each in
Node (viewer/web/decoder/bench.mjs: best of R, tables loaded, page and process start excluded) and
once with the reference decoder in this process, and prints a markdown table (Gaussians/s). The
results are in tools/results/js_decoder.md."""
from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
SCENES = {"donut": DATA / "donut" / "donut.ply", "playbot_lod3": DATA / "playbot" / "playbot_lod3_31k.ply",
          "playcanvas_logo": DATA / "playcanvas-logo" / "playcanvas_logo_307k.ply"}


def stream_for(name: str, ply: Path, out: Path, preset: str) -> Path:
    path = out / f"{name}_{preset}_steps.lghcc"
    if not path.is_file():
        from lghcc.encoder.config import load_config
        from lghcc.encoder.gaussians import encode_gaussian_scene
        from lghcc.formats.ply3dgs import read_3dgs_ply

        cfg = load_config(preset, kind="gaussians")
        t0 = time.perf_counter()
        res = encode_gaussian_scene(read_3dgs_ply(ply), cfg)
        path.write_bytes(res.data)
        print(f"{name}: encoded {len(res.data)} bytes in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/lghcc-bench-js", help="folder for the coded streams")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--preset", default="medium")
    ap.add_argument("scenes", nargs="*", default=list(SCENES))
    args = ap.parse_args()
    node = shutil.which("node")
    if node is None:
        print("node is not on the PATH", file=sys.stderr)
        return 1
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from lghcc.decoder.decode import decode_stream

    print("| scene | Gaussians | bytes | JS (Node) s | JS Gaussians/s | reference s | reference Gaussians/s |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes:
        if not SCENES[name].is_file():
            print(f"{name}: {SCENES[name]} is missing", file=sys.stderr)
            continue
        s = stream_for(name, SCENES[name], out, args.preset)
        res = subprocess.run([node, str(ROOT / "viewer/web/decoder/bench.mjs"), str(s), "--repeat", str(args.repeat)],
                             capture_output=True, text=True, check=True)
        js = json.loads(res.stdout.strip().splitlines()[-1])
        t0 = time.perf_counter()
        ref = decode_stream(s.read_bytes())
        tr = time.perf_counter() - t0
        n = ref.scene.num_gaussians
        assert js["count"] == n
        print(f"| {name} | {n} | {s.stat().st_size} | {js['seconds']:.3f} | {n / js['seconds'] / 1e6:.2f} M | "
              f"{tr:.2f} | {n / tr / 1e6:.3f} M |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
