"""The engine loaders beside the JavaScript decoder, each through its own example page in headless
Chromium (Debian's chromium driven by playwright, as tests/test_js_decoder_browser.py):
js/lghcc-playcanvas (a .lghcc loaded as a PlayCanvas gsplat asset) and js/lghcc-three (three.js with
Spark). A real scene, playbot lod4 (8,406 Gaussians, SH degree 2, CC-BY-4.0 Stephane Agullo), is
encoded here with lghcc's fast preset into a tiled stream; each page loads it by URL from a local
HTTP server laid out as an application that installed the packages (node_modules: the engines from
tools/node, the decoder and the loader from js/), every other request refused, and must say it
drew the reference decoder's number of Gaussians on a canvas that is not blank. An anchor stream
must fail through the engine's error path with the decoder's UnsupportedStreamError. Skips with
the reason where playwright, Chromium, the pinned engines (npm ci --prefix tools/node) or the scene
is missing."""

import functools
import http.server
import io
import shutil
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from lghcc.conformance import runner
from lghcc.viewer.browser import CHROMIUM_FLAGS, browser_status, chromium_path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import range_server  # noqa: E402  (tools/ is not a package: the throttled Range server of tests/test_js_stream.py)

ROOT = Path(__file__).resolve().parents[1]
JS = ROOT / "js"
NODE_MODULES = ROOT / "tools" / "node" / "node_modules"
PLAYBOT = ROOT.parent / "shared" / "data" / "playbot" / "playbot_lod4_8k.ply"  # conftest.SHARED_DATA's
ANCHOR = runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc"
SIZE = (320, 240)

# what each example page imports, as npm installs it: package name -> folder served at node_modules/<name>
ENGINES = {
    "playcanvas": {"playcanvas": NODE_MODULES / "playcanvas", "lghcc-decoder": JS / "lghcc-decoder",
                   "lghcc-playcanvas": JS / "lghcc-playcanvas"},
    "three": {"three": NODE_MODULES / "three", "@sparkjsdev/spark": NODE_MODULES / "@sparkjsdev" / "spark",
              "lghcc-decoder": JS / "lghcc-decoder", "lghcc-three": JS / "lghcc-three"},
}

OK, WHY = browser_status()
pytestmark = [pytest.mark.integration,  # Chromium
              pytest.mark.skipif(not OK, reason=WHY)]  # ~35 s in all, the encode (~6 s) included


@pytest.fixture(scope="module")
def scene_stream() -> tuple[bytes, int]:
    """(playbot lod4 as a tiled .lghcc stream, its Gaussian count by the reference decoder)."""
    if not PLAYBOT.is_file():
        pytest.skip(f"the playbot scene {PLAYBOT} is not here")
    import lghcc

    data = lghcc.encode(PLAYBOT, preset="fast", tile_points=2048)  # 4 tiles: decoded by helper workers
    return data, lghcc.decode(data).num_gaussians


def _site(tmp_path: Path, engine: str, scenes: dict[str, bytes]) -> Path:
    """A folder laid out as the example's README asks: index.html, the scenes, node_modules/<package>."""
    missing = [str(p) for p in ENGINES[engine].values() if not (p / "package.json").is_file()]
    if missing:
        pytest.skip(f"not installed: {', '.join(missing)} (npm ci --prefix tools/node)")
    site = tmp_path / f"site-{engine}"
    site.mkdir()
    shutil.copy(JS / f"lghcc-{engine}" / "example" / "index.html", site / "index.html")
    for name, data in scenes.items():
        (site / name).write_bytes(data)
    for name, folder in ENGINES[engine].items():
        link = site / "node_modules" / name
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(folder, target_is_directory=True)
    return site


class Quiet(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript",
                      ".js": "text/javascript"}

    def log_message(self, *args):
        pass


def _plain_server(site: Path) -> http.server.ThreadingHTTPServer:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(site)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _open_example(site: Path, query: str, server: http.server.ThreadingHTTPServer | None = None) -> dict:
    """The example page at site/index.html?query in headless Chromium, served over local HTTP (server:
    one serving site, shut down here; default a plain file server) with every other request refused:
    {drew, firstDraw, error, refused, console, image} once it drew or failed."""
    from PIL import Image
    from playwright.sync_api import sync_playwright

    server = server or _plain_server(site)
    origin = f"http://127.0.0.1:{server.server_address[1]}/"
    refused: list[str] = []
    console: list[str] = []

    def route(r):
        if r.request.url.startswith(origin):
            r.continue_()
        else:
            refused.append(r.request.url)
            r.abort()

    pw = sync_playwright().start()
    profile = site.parent / f"profile-{site.name}"
    try:
        ctx = pw.chromium.launch_persistent_context(str(profile), executable_path=chromium_path(), args=list(CHROMIUM_FLAGS),
                                                    headless=True, viewport={"width": SIZE[0], "height": SIZE[1]},
                                                    device_scale_factor=1)
        try:
            ctx.route("**/*", route)
            page = ctx.new_page()
            page.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
            page.on("pageerror", lambda e: console.append(f"pageerror: {e}"))
            page.goto(origin + "index.html" + query)
            try:
                page.wait_for_function("() => window.lghccDrew || window.lghccError", timeout=120_000)
            except Exception as e:  # noqa: BLE001 - playwright's timeout; re-raised with the page's console
                raise AssertionError(f"the page neither drew nor failed: {e}; console: {console[-12:]}") from None
            out = page.evaluate("() => ({drew: window.lghccDrew || null, error: window.lghccError || null, "
                                "firstDraw: window.lghccFirstDraw || null, dataset: {...document.body.dataset}})")
            page.evaluate("() => document.getElementById('status').remove()")  # the canvas alone, no text over it
            png = page.locator("canvas").screenshot()
        finally:
            ctx.close()
    finally:
        pw.stop()
        server.shutdown()
    out.update(refused=refused, console=console,
               image=np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32) / 255.0)
    return out


def _assert_drew(got: dict, count: int) -> None:
    assert got["error"] is None, (got["error"], got["console"][-12:])
    assert got["drew"] and got["drew"]["count"] == count and got["dataset"].get("drew") == str(count), (got["drew"], got["console"][-12:])
    assert got["refused"] == [], got["refused"]
    img = got["image"]
    lit = (img.max(axis=2) > 0.05).mean()  # the pages clear to black
    print(f"{lit:.1%} of the canvas drawn, brightest {img.max():.2f}")
    assert lit > 0.01 and img.max() > 0.3, (lit, img.max())


@pytest.mark.data
@pytest.mark.parametrize("engine", ["playcanvas", "three"])
def test_example_draws_a_real_scene(tmp_path, scene_stream, engine):
    data, count = scene_stream
    _assert_drew(_open_example(_site(tmp_path, engine, {"scene.lghcc": data}), ""), count)


@pytest.mark.parametrize("engine", ["playcanvas", "three"])
def test_an_anchor_stream_fails_with_the_decoders_error(tmp_path, engine):
    """The anchor representation is outside the decoder's profile: the load fails (PlayCanvas: the
    asset's 'error' event; three.js: loadAsync rejects) with UnsupportedStreamError, nothing drawn."""
    got = _open_example(_site(tmp_path, engine, {"anchor.lghcc": ANCHOR.read_bytes()}), "?scene=anchor.lghcc")
    assert got["drew"] is None and got["error"].startswith("UnsupportedStreamError: "), (got["error"], got["console"][-8:])
    assert got["dataset"].get("error") == got["error"] and got["refused"] == []


@pytest.fixture(scope="module")
def tiled_stream() -> tuple[bytes, object]:
    """(playbot lod4 in 12 tiles (105 kB), the reference decoder's parse of it)."""
    if not PLAYBOT.is_file():
        pytest.skip(f"the playbot scene {PLAYBOT} is not here")
    import lghcc
    from lghcc.decoder.decode import parse_stream

    data = lghcc.encode(PLAYBOT, preset="fast", tile_points=1024)
    return data, parse_stream(data)


@pytest.mark.data
@pytest.mark.parametrize("engine", ["playcanvas", "three"])
def test_a_streamed_scene_draws_before_its_last_byte(tmp_path, tiled_stream, engine):
    """?stream=1: the loader streams the file by Range requests over a link throttled so that the
    file takes about 1.6 s; the page's first frame with Gaussians comes before the server sent the
    file's last byte, and the whole scene is drawn in the end, from ranged requests only."""
    data, _ = tiled_stream
    site = _site(tmp_path, engine, {"scene.lghcc": data})
    server, link = range_server.serve(site, 64_000, chunk=2048)
    got = _open_example(site, "?stream=1", server)
    _assert_drew(got, lghcc_count(data))
    assert got["firstDraw"] is not None and link.last_byte_time is not None, got
    print(f"first drawn {got['firstDraw']['count']} Gaussians {link.last_byte_time * 1000 - got['firstDraw']['time']:.0f} ms "
          f"before the last byte; requests {[(s, e, st) for _, s, e, st, _, _ in link.log]}")
    assert got["firstDraw"]["time"] < link.last_byte_time * 1000, (got["firstDraw"], link.last_byte_time)
    assert got["firstDraw"]["count"] < lghcc_count(data)
    assert link.log and {st for *_, st, _, _ in link.log} == {206}


@pytest.mark.data
@pytest.mark.parametrize("engine", ["three"])
def test_a_streamed_box_fetches_fewer_bytes_than_the_file(tmp_path, tiled_stream, engine):
    """&box=...: only the tiles whose cells meet the box are fetched and drawn (the reference
    decoder's partial decode count), fewer bytes than the file."""
    from lghcc.common.tiles import Box
    from lghcc.decoder.decode import decode_stream

    data, parsed = tiled_stream
    ps = parsed.ps
    top = (parsed.tiles[0].cell[2] + 1) * ps.tile_size * float(ps.voxel_size) + ps.origin[2]
    box = (-100.0, -100.0, -100.0, 100.0, 100.0, top - 1e-3)  # the cells of the lowest z
    want = decode_stream(data, box=Box(box[:3], box[3:])).scene.num_gaussians
    site = _site(tmp_path, engine, {"scene.lghcc": data})
    server, link = range_server.serve(site, 200_000, chunk=2048)
    got = _open_example(site, "?stream=1&box=" + ",".join(map(repr, box)), server)
    _assert_drew(got, want)
    assert 0 < want < lghcc_count(data) and link.bytes_sent < len(data), (want, link.bytes_sent, len(data))


def lghcc_count(data: bytes) -> int:
    import lghcc

    return lghcc.decode(data).num_gaussians
