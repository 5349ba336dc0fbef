"""Speed of the JavaScript decoder (viewer/web/decoder) against the reference decoder, on real
scenes coded at a preset's steps (no search, no fit: the preset's quantization, neighbour
prediction where it pays, tiles of about 16k Gaussians as lghcc-enc writes them).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 .venv/bin/python tools/bench_js_decoder.py [--out DIR] [--repeat R]

Writes the streams to --out (kept between runs: a stream already there is reused), decodes each in
Node (viewer/web/decoder/bench.mjs: best of R, tables loaded, page and process start excluded), in
headless Chromium (the page's Web Worker, lghcc-decoder-worker.js: best of R, the stream's bytes
already in the page; also when the first tile arrived) and once with the reference decoder in this
process, and prints a markdown table (Gaussians/s). The results are in tools/results/js_decoder.md."""
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
        from lghcc.encoder.stream.config import load_config
        from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
        from lghcc.formats.ply3dgs import read_3dgs_ply

        cfg = load_config(preset, kind="gaussians")
        t0 = time.perf_counter()
        res = encode_gaussian_scene(read_3dgs_ply(ply), cfg)
        path.write_bytes(res.data)
        print(f"{name}: encoded {len(res.data)} bytes in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return path


CHROMIUM_PAGE = """<!doctype html><html><body><script id="w" type="text/plain">%WORKER%</script><script>
const src = document.getElementById('w').textContent;
const b64 = '%STREAM%';
function once() {
    return new Promise((resolve) => {
        const w = new Worker(URL.createObjectURL(new Blob([src], {type: 'text/javascript'})));
        const bytes = Uint8Array.from(atob(b64), (ch) => ch.charCodeAt(0));
        let first = null;
        w.onmessage = (e) => {
            if (e.data.type === 'tile') { if (first === null) first = e.data.ms; return; }
            w.terminate();
            resolve({...e.data, first});
        };
        w.postMessage({bytes}, [bytes.buffer]);
    });
}
window.results = (async () => { const out = []; for (let i = 0; i < %REPEAT%; i++) out.push(await once()); return out; })();
</script></body></html>"""


def chromium_decode(stream: Path, repeat: int, tmp: Path) -> dict:
    """Best of ``repeat`` decodes in headless Chromium's worker: {seconds, first_tile_s, count}."""
    import base64

    from playwright.sync_api import sync_playwright

    from lghcc.viewer.browser import CHROMIUM_FLAGS, chromium_path
    from lghcc.viewer.page import worker_js

    page_file = tmp / "bench.html"
    page_file.write_text(CHROMIUM_PAGE.replace("%WORKER%", worker_js()).replace("%REPEAT%", str(repeat))
                         .replace("%STREAM%", base64.b64encode(stream.read_bytes()).decode("ascii")))
    pw = sync_playwright().start()
    try:
        ctx = pw.chromium.launch_persistent_context(str(tmp / "profile"), executable_path=chromium_path(),
                                                    args=list(CHROMIUM_FLAGS), headless=True)
        page = ctx.new_page()
        page.goto(page_file.as_uri())
        runs = page.evaluate("() => window.results")
        ctx.close()
    finally:
        pw.stop()
    if any(r["type"] != "done" for r in runs):
        raise RuntimeError(f"{stream}: {runs}")
    best = min(runs, key=lambda r: r["seconds"])
    return {"seconds": best["seconds"], "first_tile_s": best["first"] / 1000, "count": best["count"]}


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

    import tempfile

    from lghcc.viewer.browser import browser_status

    use_chromium, why = browser_status()
    if not use_chromium:
        print(f"no Chromium measurement: {why}", file=sys.stderr)
    print("| scene | Gaussians | bytes | Node s | Node Gaussians/s | Chromium s | Chromium Gaussians/s | "
          "Chromium first tile s | reference s | reference Gaussians/s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        if not SCENES[name].is_file():
            print(f"{name}: {SCENES[name]} is missing", file=sys.stderr)
            continue
        s = stream_for(name, SCENES[name], out, args.preset)
        res = subprocess.run([node, str(ROOT / "viewer/web/decoder/bench.mjs"), str(s), "--repeat", str(args.repeat)],
                             capture_output=True, text=True, check=True)
        js = json.loads(res.stdout.strip().splitlines()[-1])
        ch = None
        if use_chromium:
            with tempfile.TemporaryDirectory() as t:
                ch = chromium_decode(s, args.repeat, Path(t))
        t0 = time.perf_counter()
        ref = decode_stream(s.read_bytes())
        tr = time.perf_counter() - t0
        n = ref.scene.num_gaussians
        assert js["count"] == n and (ch is None or ch["count"] == n)
        chc = (f"{ch['seconds']:.3f} | {n / ch['seconds'] / 1e6:.3f} M | {ch['first_tile_s']:.3f}" if ch else "- | - | -")
        print(f"| {name} | {n} | {s.stat().st_size} | {js['seconds']:.3f} | {n / js['seconds'] / 1e6:.3f} M | {chc} | "
              f"{tr:.2f} | {n / tr / 1e6:.3f} M |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
