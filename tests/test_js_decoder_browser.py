"""The JavaScript decoder in headless Chromium (Debian's chromium driven by playwright, as
tests/test_viewer_browser.py): every conformance stream of the explicit-Gaussian profile decoded in
the browser's Web Worker to its hash (and its box decodes) or rejected; lghcc-view's page of an
explicit-Gaussian stream carries the stream itself, decodes it in the page, says the hash checked
and draws what lghcc.render draws of the reference decoder's scene; a damaged stream gives a clear
message and no scene. Skips with the reason where playwright, Chromium or the built bundle (`make
viewer-bundle`) is missing."""

import base64
import json
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml

from lghcc.conformance import runner
from lghcc.viewer import page as page_mod
from lghcc.viewer.browser import CHROMIUM_FLAGS, ViewerSession, browser_status, chromium_path

OK, WHY = browser_status()
pytestmark = [pytest.mark.integration,  # Chromium
              pytest.mark.skipif(not OK, reason=WHY),
              pytest.mark.skipif(not page_mod.WORKER.is_file(),
                                 reason=f"the decoder worker {page_mod.WORKER} is not built (make viewer-bundle)")]
STREAMS = runner.STREAMS_DIR
SIZE = (160, 160)
PSNR_MIN, SSIM_MIN = 30.0, 0.94  # tests/test_viewer_browser.py's thresholds (its module doc)

RUNNER_PAGE = """<!doctype html><html><body><script id="w" type="text/plain">%WORKER%</script><script>
const cases = %CASES%;
const src = document.getElementById('w').textContent;
function run(c) {
    return new Promise((resolve) => {
        const w = new Worker(URL.createObjectURL(new Blob([src], {type: 'text/javascript'})));
        const timer = setTimeout(() => { w.terminate(); resolve({timeout: true}); }, 60000);
        const bytes = Uint8Array.from(atob(c.b64), (ch) => ch.charCodeAt(0));
        w.onmessage = (e) => { if (e.data.type === 'tile') return; clearTimeout(timer); w.terminate(); resolve(e.data); };
        w.onerror = (e) => { clearTimeout(timer); w.terminate(); resolve({type: 'error', kind: 'crash', message: e.message}); };
        w.postMessage({bytes, box: c.box || null, digest: true, workers: c.workers || 0, source: src}, [bytes.buffer]);
    });
}
window.results = (async () => { const out = []; for (const c of cases) out.push(await run(c)); return out; })();
</script></body></html>"""


def _page_results(tmp_path, template: str, cases: list) -> list:
    """window.results of ``template`` run in headless Chromium with the worker bundle and ``cases``."""
    html = template.replace("%WORKER%", page_mod.worker_js()).replace("%CASES%", json.dumps(cases))
    pw, ctx, page = _browser_page(tmp_path, html)
    try:
        return page.evaluate("() => window.results")
    finally:
        ctx.close()
        pw.stop()


def _browser_page(tmp_path: Path, html: str):
    """(playwright, context, page) of a page written to tmp_path; the caller closes them."""
    from playwright.sync_api import sync_playwright

    f = tmp_path / "page.html"
    f.write_text(html)
    pw = sync_playwright().start()
    ctx = pw.chromium.launch_persistent_context(str(tmp_path / "profile"), executable_path=chromium_path(),
                                                args=list(CHROMIUM_FLAGS), headless=True)
    page = ctx.new_page()
    page.goto(f.as_uri())
    return pw, ctx, page


def test_profile_conformance_in_chromium(tmp_path):
    cases, want = [], []
    for c in runner.load_cases(STREAMS, runner.js_profile_ids(STREAMS)):
        b64 = base64.b64encode(c.stream.read_bytes()).decode("ascii")
        cases.append({"id": c.id, "b64": b64})
        want.append((c.id, c.expect, c.meta.get("decoded_sha256")))
        # the same stream with its tiles decoded by a pool of 3 helper workers started once its prelude is in (no {warm}; pool.mjs)
        cases.append({"id": c.id + " pool", "b64": b64, "workers": 3})
        want.append((c.id + " pool", c.expect, c.meta.get("decoded_sha256")))
        for p in c.meta.get("partial_decodes", []):
            if "box" in p:
                cases.append({"id": c.id + " box", "b64": b64, "box": p["box"]})
                want.append((c.id + " box", "decode", p["decoded_sha256"]))
    got = _page_results(tmp_path, RUNNER_PAGE, cases)
    failed = []
    for (cid, expect, digest), r in zip(want, got):
        ok = (r.get("type") == "error" and r.get("kind") in runner.ERROR_KINDS) \
            if expect == "error" else (r.get("type") == "done" and r.get("digest") == digest)
        if not ok:
            failed.append((cid, r))
    assert len(got) == len(want) >= 2 * 54 and not failed, failed
    pooled = {cid for (cid, _, _), r in zip(want, got) if r.get("helpers")}
    assert {"c078_neighbour_prediction_tiles pool", "c086_step_adjust_tiles pool"} <= pooled, pooled
    assert "c032_gaussians_sh0 pool" not in pooled  # one tile: decoded by the worker itself


KEPT_POOL_PAGE = """<!doctype html><html><body><script id="w" type="text/plain">%WORKER%</script><script>
const cases = %CASES%;
const src = document.getElementById('w').textContent;
const w = new Worker(URL.createObjectURL(new Blob([src], {type: 'text/javascript'})));
function post(msg, transfer) {
    return new Promise((resolve) => {
        let tiles = 0;
        const timer = setTimeout(() => resolve({timeout: true}), 60000);
        w.onmessage = (e) => { if (e.data.type === 'tile') { tiles++; return; } clearTimeout(timer); resolve({...e.data, tileMessages: tiles}); };
        w.postMessage(msg, transfer);
    });
}
window.results = (async () => {
    const out = [await post({warm: true, workers: 2, source: src}, [])];
    for (const c of cases) {
        const bytes = Uint8Array.from(atob(c.b64), (ch) => ch.charCodeAt(0));
        out.push(await post({bytes, digest: true, workers: 2, source: src}, [bytes.buffer]));
    }
    return out;
})();
</script></body></html>"""


def test_a_kept_pool_decodes_stream_after_stream_and_survives_a_bad_one(tmp_path):
    """One worker, warmed before any stream ({warm}: 2 helpers ready), decodes a tiled stream, then one
    whose tile unit fails its CRC-32 (E9: rejected before any of its tiles is shown, although its tiles
    were handed out before the check), then two good streams with the pool it made again: the same
    digests as test.yaml's, every tile by a helper."""
    good = [STREAMS / n / "stream.lghcc" for n in ("c078_neighbour_prediction_tiles", "c086_step_adjust_tiles")]
    data = bytearray(good[0].read_bytes())
    data[len(data) // 2] ^= 0x55  # a byte in the middle of the tiles, its unit's CRC left as it was
    streams = [good[0].read_bytes(), bytes(data), good[1].read_bytes(), good[0].read_bytes()]
    cases = [{"b64": base64.b64encode(b).decode("ascii")} for b in streams]
    got = _page_results(tmp_path, KEPT_POOL_PAGE, cases)
    want = [yaml.safe_load((p.parent / "test.yaml").read_text())["decoded_sha256"] for p in good]
    assert got[0] == {"type": "ready", "helpers": 2, "tileMessages": 0}, got[0]
    assert got[2]["type"] == "error" and got[2]["kind"] == "BitstreamError" and "E9" in got[2]["message"] and got[2]["tileMessages"] == 0, got[2]
    for r, digest in zip([got[1], got[3], got[4]], [want[0], want[1], want[0]]):
        assert r["type"] == "done" and r["digest"] == digest and r["helpers"] == 2, r
        assert r["tileMessages"] == r["tiles"] == 8 and {x["thread"] for x in r["timeline"]["tiles"]} == {"helper 1", "helper 2"}


def _gaussian_page(tmp_path: Path, stream: Path) -> Path:
    from lghcc.viewer import cli as view_cli

    out = tmp_path / "v.html"
    assert view_cli.main([str(stream), "-o", str(out), "--no-psnr", "-q"]) == 0
    return out


def test_page_decodes_its_stream_and_draws_it(tmp_path):
    from lghcc.decoder.decode import decode_stream
    from lghcc.render.camera import Camera
    from lghcc.render.metrics import psnr, ssim
    from lghcc.viewer.scenes import render_gaussians_fn

    stream = STREAMS / "c078_neighbour_prediction_tiles" / "stream.lghcc"
    html_path = _gaussian_page(tmp_path, stream)
    text = html_path.read_text()
    assert 'id="lghcc-stream-decoded"' in text and 'id="lghcc-ply-decoded"' not in text  # no decoded scene inside
    meta = json.loads(text.split('<script id="lghcc-meta" type="application/json">')[1].split("</script>")[0])
    scene = decode_stream(stream.read_bytes()).scene
    with ViewerSession(html_path, *SIZE) as s:
        decodes = s.page.evaluate("() => window.lghccViewer.decodes")
        check = s.page.inner_text("#lghcc-check")
        shot = s.images()["decoded"]
        requests = list(s.requests)
    assert decodes == [{"pane": "decoded", "tiles": 8, "count": scene.num_gaussians, "seconds": decodes[0]["seconds"],
                        "firstTileSeconds": decodes[0]["firstTileSeconds"], "hashChecked": True}]
    assert 0 < decodes[0]["firstTileSeconds"] <= decodes[0]["seconds"]
    assert "hash ✓" in check and f"{scene.num_gaussians:,}" in check
    assert all(r.startswith(("file:", "blob:", "data:")) for r in requests), requests
    c = meta["camera"]
    cam = Camera.look_at(c["eye"], c["target"], up=c["up"], width=SIZE[0], height=SIZE[1], fov_x_deg=c["fov_x_deg"],
                         near=c["near"], far=c["far"])
    ref = render_gaussians_fn(scene)(cam, np.asarray(meta["background"], np.float32))
    p, q = psnr(shot, ref), ssim(shot, ref)
    print(f"page drawn from its stream vs CPU render of the reference decoder's scene: {p:.2f} dB, SSIM {q:.4f}")
    assert p >= PSNR_MIN and q >= SSIM_MIN and shot.max() > 0.2


def test_damaged_stream_gives_a_clear_message_and_no_scene(tmp_path):
    html_path = _gaussian_page(tmp_path, STREAMS / "c078_neighbour_prediction_tiles" / "stream.lghcc")
    text = html_path.read_text()
    head, rest = text.split('<script id="lghcc-stream-decoded" type="application/octet-stream">')
    b64, tail = rest.split("</script>", 1)
    data = bytearray(base64.b64decode(b64))
    # the last unit (a tile's decoded_scene_hash): one hash byte changed, its CRC made right again
    start = len(data) - 4 - 33 - 5
    assert data[start] == 0x06
    data[start + 5 + 10] ^= 0xFF
    data[-4:] = zlib.crc32(bytes(data[start:-4])).to_bytes(4, "big")
    bad = head + '<script id="lghcc-stream-decoded" type="application/octet-stream">' + \
        base64.b64encode(bytes(data)).decode("ascii") + "</script>" + tail
    pw, ctx, page = _browser_page(tmp_path, bad)
    try:
        page.wait_for_function("() => window.lghccViewer && window.lghccViewer.error", timeout=90000)
        error = page.evaluate("() => window.lghccViewer.error")
        status = page.inner_text("#lghcc-status")
        check = page.inner_text("#lghcc-check")
        first = page.evaluate("() => window.lghccViewer.firstFrame")
    finally:
        ctx.close()
        pw.stop()
    assert "HashMismatchError" in error and "scene_hash" in error, error
    assert status.startswith("error:") and "stream rejected" in status
    assert "not a valid stream" in check and not first
