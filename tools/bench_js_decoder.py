"""Speed of the JavaScript decoder (js/lghcc-decoder) against the reference decoder, on real
scenes coded at a preset's steps (no search, no fit: the preset's quantization, neighbour
prediction where it pays, tiles of about 16k Gaussians as lghcc-enc writes them).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 .venv/bin/python tools/bench_js_decoder.py [--out DIR] [--repeat R]
        [--workers W] [--stream FILE.lghcc ...] [--no-reference] [--tree DIR]

Writes the streams to --out (kept between runs: a stream already there is reused), decodes each in
Node (js/lghcc-decoder/bench.mjs: best of R, tables loaded, page and process start excluded), in
headless Chromium (the page's Web Worker, lghcc-decoder-worker.js: best of R, the stream's bytes
already in the page, a fresh worker per decode; also when the first tile arrived), once more in
Chromium with the tiles decoded by a pool of W threads (the page's default:
navigator.hardwareConcurrency; W helper workers, the worker handing the tiles out, pool.mjs; made and
warmed with the page, before the first stream, and kept for every decode, as lghcc-view's page does:
"pool helpers" says "warmed"; a tree without {warm} gets a fresh worker per decode; each thread's
tiles and busy time to stderr), and once with the reference decoder in this process, and prints a markdown table
(Gaussians/s). --stream adds coded streams (e.g. a 1M-Gaussian scene of tools/scale_scenes.py),
--no-reference skips the reference decoder. --tree DIR measures the decoder of another tree (e.g. an
older commit's `git archive` with its worker bundle built by its tools/node/build-viewer.mjs), for
old-against-new ratios in the same window. The results are in tools/results/js_decoder.md."""
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
const workers = %WORKERS% < 0 ? navigator.hardwareConcurrency : %WORKERS%;
const make = () => new Worker(URL.createObjectURL(new Blob([src], {type: 'text/javascript'})));
// a pool is made and warmed as a page does when it is created ({warm}: helpers started, module compiled), then kept
// for every decode; a tree whose worker does not know {warm} (it answers an error) gets a fresh worker per decode
function warmed() {
    if (!workers) return Promise.resolve(null);
    const w = make();
    return new Promise((resolve) => {
        w.onmessage = (e) => { if (e.data.type === 'ready') resolve(w); else { w.terminate(); resolve(null); } };
        w.postMessage({warm: true, workers, source: src});
    });
}
function once(kept) {
    return new Promise((resolve) => {
        const w = kept || make();
        const bytes = Uint8Array.from(atob(b64), (ch) => ch.charCodeAt(0));
        let first = null;
        w.onmessage = (e) => {
            if (e.data.type === 'tile') { if (first === null) first = e.data.ms; return; }
            if (!kept) w.terminate();
            resolve({...e.data, first, workers, warm: !!kept});
        };
        w.postMessage({bytes, workers, source: src}, [bytes.buffer]);
    });
}
window.results = (async () => { const kept = await warmed(); const out = []; for (let i = 0; i < %REPEAT%; i++) out.push(await once(kept)); return out; })();
</script></body></html>"""


def chromium_decode(stream: Path, repeat: int, tmp: Path, workers: int = 0, tree: Path = ROOT) -> dict:
    """Best of ``repeat`` decodes in headless Chromium's worker, its tiles decoded by ``workers`` helper
    workers (0: by the worker itself; -1: navigator.hardwareConcurrency): {seconds, first_tile_s, first_s,
    count, helpers}; first_s: the first decode's seconds (a page decodes once). tree: whose worker bundle."""
    import base64

    from playwright.sync_api import sync_playwright

    from lghcc.viewer.browser import CHROMIUM_FLAGS, chromium_path
    from lghcc.viewer.page import worker_js

    page_file = tmp / "bench.html"
    worker = worker_js() if tree == ROOT else (tree / "viewer/assets/lghcc-decoder-worker.js").read_text(encoding="utf-8")
    page_file.write_text(CHROMIUM_PAGE.replace("%WORKER%", worker.replace("</script", "<\\/script")).replace("%REPEAT%", str(repeat)).replace("%WORKERS%", str(workers))
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
    if workers and best.get("timeline"):
        print(f"{stream.name}: pool of the best decode: {pool_balance(best['timeline'])}", file=sys.stderr)
    return {"seconds": best["seconds"], "first_tile_s": best["first"] / 1000, "first_s": runs[0]["seconds"],
            "count": best["count"], "helpers": best["helpers"], "warm": best["warm"]}


def pool_balance(timeline: dict) -> str:
    """Per decoding thread of a pool decode's timeline (worker.mjs's 'done'): tiles, points and busy ms."""
    threads: dict[str, list] = {}
    for x in timeline["tiles"]:
        threads.setdefault(x["thread"], []).append(x)
    # busy: decoding and making the arrays (the hash is computed off the helper's thread meanwhile: "decoded")
    return "; ".join(f"{th} {len(xs)} tiles, {sum(x['points'] for x in xs)} points, busy "
                     f"{sum(x.get('decoded', x['end']) - x['start'] for x in xs):.0f} ms" for th, xs in sorted(threads.items())) + \
        f" (decode {timeline['end'] - timeline['start']:.0f} ms)"


def chromium_cells(ch: dict | None, n: int) -> str:
    """Table cells of one Chromium measurement: seconds (best), Gaussians/s, first tile, first decode."""
    if ch is None:
        return "- | - | - | -"
    assert ch["count"] == n, (ch, n)
    return f"{ch['seconds']:.3f} | {n / ch['seconds'] / 1e6:.3f} M | {ch['first_tile_s']:.3f} | {ch['first_s']:.3f}"


def measure(label: str, s: Path, args, node: str, use_chromium: bool) -> str:
    """One table row: the stream decoded by Node, Chromium's worker, Chromium's pool, the reference."""
    import tempfile

    # a tree from before issue 54 has the decoder in viewer/web/decoder
    bench = args.tree / "js/lghcc-decoder/bench.mjs"
    if not bench.exists():
        bench = args.tree / "viewer/web/decoder/bench.mjs"
    res = subprocess.run([node, str(bench), str(s), "--repeat", str(args.repeat)],
                         capture_output=True, text=True, check=True)
    js = json.loads(res.stdout.strip().splitlines()[-1])
    n = js["count"]
    one = pool = None
    if use_chromium:
        with tempfile.TemporaryDirectory() as t:
            one = chromium_decode(s, args.repeat, Path(t), tree=args.tree)
        with tempfile.TemporaryDirectory() as t:
            pool = chromium_decode(s, args.repeat, Path(t), workers=args.workers, tree=args.tree)
    ref = "- | -"
    if not args.no_reference:
        from lghcc.decoder.decode import decode_stream

        t0 = time.perf_counter()
        scene = decode_stream(s.read_bytes()).scene
        tr = time.perf_counter() - t0
        assert scene.num_gaussians == n
        ref = f"{tr:.2f} | {n / tr / 1e6:.3f} M"
    helpers = (f"{pool['helpers']}" + (" warmed" if pool["warm"] else "")) if pool else "-"
    return (f"| {label} | {n} | {s.stat().st_size} | {js['seconds']:.3f} | {n / js['seconds'] / 1e6:.3f} M | "
            f"{js['first']:.3f} | {chromium_cells(one, n)} | {helpers} | {chromium_cells(pool, n)} | {ref} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="/tmp/lghcc-bench-js", help="folder for the coded streams")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--preset", default="medium")
    ap.add_argument("--workers", type=int, default=-1,
                    help="decoding threads of the pool measurement (helper workers; default -1: "
                    "navigator.hardwareConcurrency)")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the tree whose decoder is measured (default: this one)")
    ap.add_argument("--stream", action="append", default=[], help="also measure this coded stream (repeatable)")
    ap.add_argument("--no-reference", action="store_true", help="skip the reference decoder (slow on big streams)")
    ap.add_argument("scenes", nargs="*", default=None, help=f"scenes to code and measure (default: {', '.join(SCENES)};"
                    " none when --stream is given)")
    args = ap.parse_args()
    node = shutil.which("node")
    if node is None:
        print("node is not on the PATH", file=sys.stderr)
        return 1
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from lghcc.viewer.browser import browser_status

    use_chromium, why = browser_status()
    if not use_chromium:
        print(f"no Chromium measurement: {why}", file=sys.stderr)
    print("| scene | Gaussians | bytes | Node s | Node Gaussians/s | Node first decode s | Chromium s | "
          "Chromium Gaussians/s | Chromium first tile s | Chromium first decode s | pool helpers | pool s | "
          "pool Gaussians/s | pool first tile s | pool first decode s | reference s | reference Gaussians/s |")
    print("|" + "---|" * 17)
    scenes = args.scenes or ([] if args.stream else list(SCENES))
    for name in scenes:
        if not SCENES[name].is_file():
            print(f"{name}: {SCENES[name]} is missing", file=sys.stderr)
            continue
        print(measure(name, stream_for(name, SCENES[name], out, args.preset), args, node, use_chromium), flush=True)
    for path in map(Path, args.stream):
        print(measure(path.name, path, args, node, use_chromium), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
