"""Streaming by tiles (js/lghcc-decoder's stream(), the loaders' LghccStream) against the whole-file
decode, over a local link throttled to a given rate (tools/range_server.py: one shared link, every
.lghcc byte through it).

Per stream, alternated for --repeat rounds, from the first byte of the first request (the server's
clock; the page's and Node's Date.now() are on the same machine):

- Node: `decode(url)` (the whole file, tiles decoded as they arrive in stream order) and
  `stream(url, {camera})` (Range requests, nearest the camera first): the first decoded tile and the
  last, with the share of the file's bytes sent by then.
- Chromium (--chromium): a page with the decoder alone (decode(url) and stream(url, {camera}): the
  first decoded tile and the last), and js/lghcc-three's example page (three.js with Spark): its
  first frame with Gaussians and its frame with every Gaussian sorted, streamed (?stream=1) and whole.
  Headless Chromium draws with a software renderer here: its frames cost CPU the transfer competes for.

The camera: two half-diagonals from the centre of the tiles' cells along +z (the example pages'
framing, in the stream's coordinates). Writes a markdown table (stdout, and appended to --out).

    OMP_WAIT_POLICY=PASSIVE nice -n 10 .venv/bin/python tools/bench_js_stream.py STREAM.lghcc [...] \\
        --rate 20 --repeat 3 [--chromium [--no-engine]] [--out tools/results/js_stream.md]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch is imported (lghcc's decoder imports it)

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import urllib.parse  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
import range_server  # noqa: E402

PKG = ROOT / "js" / "lghcc-decoder"
NODE_MODULES = ROOT / "tools" / "node" / "node_modules"

# a page with the decoder alone (no engine): ?mode=stream or decode; the first tile and the last as the example pages signal a draw
DECODER_PAGE = """<!doctype html><script type="module">
import { decode, stream } from './node_modules/lghcc-decoder/index.mjs';
const params = new URLSearchParams(location.search);
const onTile = () => { if (!window.lghccFirstDraw) window.lghccFirstDraw = { time: Date.now() }; };
const s = params.get('mode') === 'stream'
    ? await stream('scene.lghcc', { activated: true, camera: JSON.parse(params.get('camera')), onTile })
    : await decode('scene.lghcc', { activated: true, onProgress: onTile });
window.lghccDrew = { count: s.count, time: Date.now() };
</script>"""

NODE_SCRIPT = """
import { decode, stream } from %(index)s;
const [url, mode, camera] = process.argv.slice(2);
const times = [];
const onTile = () => times.push(Date.now());
const t0 = Date.now();
let s;
if (mode === 'stream') s = await stream(url, { camera: JSON.parse(camera), activated: true, onTile });
else s = await decode(url, { activated: true, onProgress: onTile });
console.log(JSON.stringify({ count: s.count, start: t0, first: times[0], last: times[times.length - 1], end: Date.now(),
    requests: s.requests ?? 1, bytesFetched: s.bytesFetched ?? null }));
"""


def camera_of(data: bytes) -> list[float]:
    """The example pages' camera in the stream's coordinates: two half-diagonals from the centre of
    the tiles' cells, along +z."""
    import numpy as np

    from lghcc.decoder.decode import parse_stream

    p = parse_stream(data)
    ps = p.ps
    cells = np.asarray([t.cell for t in p.tiles], dtype=np.float64)
    vs, origin = float(ps.voxel_size), np.asarray(ps.origin, dtype=np.float64)
    lo, hi = cells.min(0) * ps.tile_size * vs + origin, (cells.max(0) + 1) * ps.tile_size * vs + origin
    centre, half = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    return [float(centre[0]), float(centre[1]), float(centre[2] + 2 * half)]


def node_run(node: str, folder: Path, name: str, mode: str, camera: list[float], rate: float) -> dict:
    server, link = range_server.serve(folder, rate)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/{name}"
        res = subprocess.run([node, str(folder / "bench_stream.mjs"), url, mode, json.dumps(camera)],
                             capture_output=True, text=True, timeout=600)
        if res.returncode:
            raise RuntimeError(res.stderr[-2000:])
        time.sleep(0.05)
        got = json.loads(res.stdout.strip().splitlines()[-1])
    finally:
        server.shutdown()
    return summary(got["first"], got["last"], link, got["count"], got["requests"])


def summary(first_ms: float, last_ms: float, link, count: int, requests: int) -> dict:
    """Seconds from the first byte sent, and the share of the file's bytes sent by then."""
    t0 = min(row[4] for row in link.log)
    return {"count": count, "first_s": first_ms / 1000 - t0, "last_s": last_ms / 1000 - t0,
            "first_bytes": link.sent_by(first_ms / 1000), "transfer_s": link.last_byte_time - t0,
            "bytes": link.bytes_sent, "requests": requests}


def chromium_run(folder: Path, query: str, rate: float) -> dict:
    from playwright.sync_api import sync_playwright

    from lghcc.viewer.browser import CHROMIUM_FLAGS, chromium_path

    server, link = range_server.serve(folder, rate)
    origin = f"http://127.0.0.1:{server.server_address[1]}/"
    pw = sync_playwright().start()
    try:
        ctx = pw.chromium.launch_persistent_context(tempfile.mkdtemp(prefix="bench-js-stream-"), executable_path=chromium_path(),
                                                    args=list(CHROMIUM_FLAGS), headless=True, viewport={"width": 640, "height": 480})
        try:
            ctx.route("**/*", lambda r: r.continue_() if r.request.url.startswith(origin) else r.abort())
            page = ctx.new_page()
            page.goto(origin + query)
            page.wait_for_function("() => window.lghccDrew || window.lghccError", timeout=600_000)
            got = page.evaluate("() => ({drew: window.lghccDrew, first: window.lghccFirstDraw, error: window.lghccError, "
                                "now: Date.now()})")
        finally:
            ctx.close()
    finally:
        pw.stop()
        server.shutdown()
    if got.get("error"):
        raise RuntimeError(got["error"])
    first = got["first"]["time"] if got.get("first") else got["drew"]["time"]  # whole: the first frame is the full one
    return summary(first, got["drew"]["time"], link, got["drew"]["count"], len(link.log))


def site(tmp: Path, stream: Path) -> Path:
    folder = tmp / "site"
    folder.mkdir(exist_ok=True)
    shutil.copy(ROOT / "js" / "lghcc-three" / "example" / "index.html", folder / "index.html")
    shutil.copy(stream, folder / "scene.lghcc")
    for name, src in {"three": NODE_MODULES / "three", "@sparkjsdev/spark": NODE_MODULES / "@sparkjsdev" / "spark",
                      "lghcc-decoder": PKG, "lghcc-three": ROOT / "js" / "lghcc-three"}.items():
        link = folder / "node_modules" / name
        link.parent.mkdir(parents=True, exist_ok=True)
        if not link.exists():
            link.symlink_to(src, target_is_directory=True)
    (folder / "bench_stream.mjs").write_text(NODE_SCRIPT % {"index": json.dumps(str(PKG / "index_node.mjs"))})
    (folder / "decoder.html").write_text(DECODER_PAGE)
    return folder


def row(name: str, size: int, how: str, runs: list[dict]) -> str:
    best = min(runs, key=lambda r: r["first_s"])
    last = min(r["last_s"] for r in runs)
    rounds = ", ".join(f"{r['first_s']:.2f}/{r['last_s']:.2f}" for r in runs)
    transfer = min(r["transfer_s"] for r in runs)
    return (f"| {name} | {size:,} | {how} | {best['first_s']:.2f} ({100 * best['first_bytes'] / size:.0f}% of the bytes) | "
            f"{last:.2f} | {transfer:.2f} | {100 * (last - transfer) / transfer:+.0f}% | {runs[0]['requests']} | "
            f"{runs[0]['bytes']:,} | {rounds} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("streams", nargs="+", type=Path, help=".lghcc files (tiled, explicit-Gaussian)")
    ap.add_argument("--rate", type=float, default=20.0, help="the link in Mbit/s (default 20)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds, each mode once per round, alternated (default 3)")
    ap.add_argument("--chromium", action="store_true", help="also in headless Chromium: the decoder alone and the three.js example page")
    ap.add_argument("--no-engine", action="store_true", help="with --chromium: the decoder alone, not the three.js page "
                    "(its software-rendered frames take minutes for a 1M scene here)")
    ap.add_argument("--out", type=Path, help="append the table to this markdown file")
    args = ap.parse_args(argv)
    node = shutil.which("node")
    if node is None:
        ap.error("node (Node.js) is not on the PATH")
    for s in args.streams:
        if not s.is_file():
            ap.error(f"{s}: no such file")
    rate = args.rate * 1e6 / 8
    lines = ["| stream | bytes | run | first tile s (bytes sent by then) | all tiles s | transfer s | all vs transfer | "
             "requests | bytes fetched | each round first/all s |", "|---|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="bench-js-stream-") as tmp:
        for stream in args.streams:
            data = stream.read_bytes()
            folder, camera = site(Path(tmp), stream), camera_of(data)
            modes = {"Node decode(url), whole": lambda: node_run(node, folder, "scene.lghcc", "decode", camera, rate),
                     "Node stream(url, {camera})": lambda: node_run(node, folder, "scene.lghcc", "stream", camera, rate)}
            if args.chromium:
                cam = urllib.parse.quote(json.dumps(camera))
                modes["Chromium decode(url) alone, no engine"] = lambda: chromium_run(folder, "decoder.html?mode=decode", rate)
                modes["Chromium stream(url, {camera}) alone, no engine"] = lambda: chromium_run(folder, f"decoder.html?mode=stream&camera={cam}", rate)
            if args.chromium and not args.no_engine:
                modes["Chromium three.js page, whole (drawn)"] = lambda: chromium_run(folder, "index.html", rate)
                modes["Chromium three.js page, ?stream=1 (drawn)"] = lambda: chromium_run(folder, "index.html?stream=1", rate)
            runs: dict[str, list[dict]] = {m: [] for m in modes}
            for _ in range(args.repeat):
                for m, f in modes.items():
                    runs[m].append(f())
                    print(m, runs[m][-1], file=sys.stderr, flush=True)
            lines += [row(stream.name, len(data), m, r) for m, r in runs.items()]
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    head = (f"\n## {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, commit {commit}, load {os.getloadavg()[0]:.1f}, "
            f"link {args.rate:g} Mbit/s\n\n`{' '.join(['tools/bench_js_stream.py', *sys.argv[1:]])}`\n")
    text = head + "\n" + "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with args.out.open("a") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
