"""The npm package lghcc-decoder (js/lghcc-decoder): `npm pack` makes a tarball that installs into an
empty npm project with no registry (no runtime dependency), its README's example runs there as
written, and its public API decode() gives, for every input form, the reference decoder's arrays
bit for bit (tiled and one-tile streams, SH degree 3, a box), in helper threads or on the calling
thread; onProgress comes once per tile, an AbortSignal stops a decode, errors come as the exported
classes, and index.d.ts declares exactly what the module exports and returns. Skips with the reason
where node or npm is absent."""

import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from lghcc.common.tiles import Box
from lghcc.conformance import runner
from lghcc.decoder.decode import decode_stream

NODE, NPM = shutil.which("node"), shutil.which("npm")
pytestmark = [pytest.mark.integration,  # npm and Node
              pytest.mark.skipif(NODE is None or NPM is None,
                                 reason="node and npm (Node.js) are not both on the PATH: the package is packed and run with them")]
PKG = runner.JS_DECODER_DIR
STREAMS = runner.STREAMS_DIR
TILED = STREAMS / "c086_step_adjust_tiles" / "stream.lghcc"  # 8 tiles, 1,500 Gaussians
SH3 = STREAMS / "c033_gaussians_sh3_prediction" / "stream.lghcc"  # one tile, SH degree 3
SH_DEGREES = STREAMS / "c092_sh_degree_tiles" / "stream.lghcc"  # tiles, per-Gaussian SH degrees


def _run(cmd: list[str], cwd, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    res = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, **kw)
    assert res.returncode == 0, f"{cmd}: {res.stdout[-2000:]}{res.stderr[-3000:]}"
    return res


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """An empty npm project with the packed tarball installed (offline: nothing comes from a registry)."""
    tmp = tmp_path_factory.mktemp("npm")
    cache = str(tmp / "npm-cache")
    packed = json.loads(_run([NPM, "pack", "--json", "--pack-destination", str(tmp), "--cache", cache], PKG).stdout)
    (tgz,) = tmp.glob("lghcc-decoder-*.tgz")
    proj = tmp / "app"
    proj.mkdir()
    (proj / "package.json").write_text(json.dumps({"name": "app", "private": True, "type": "module"}))
    _run([NPM, "install", "--offline", "--no-audit", "--no-fund", "--cache", cache, str(tgz)], proj)
    return {"dir": proj, "files": sorted(f["path"] for f in packed[0]["files"])}


def node_in(project, script: str, *args: str, timeout: float = 120) -> dict:
    """JSON printed by an ES module script run in the project (it imports 'lghcc-decoder' as a user would)."""
    f = project["dir"] / "script.mjs"
    f.write_text(script)
    return json.loads(_run([NODE, str(f), *args], project["dir"], timeout=timeout).stdout.strip().splitlines()[-1])


def test_tarball_holds_what_its_modules_import(project):
    """Every relative import of a packed module names a packed file; no test or tool is packed; the
    licence is the repository's."""
    files = set(project["files"])
    assert {"package.json", "README.md", "LICENSE", "index.mjs", "index_node.mjs", "index.d.ts", "wasm_module.mjs",
            "helper.mjs", "helper_node.mjs", "worker.mjs"} <= files
    assert not files & {"cli.mjs", "conformance.mjs", "bench.mjs", "IMPLEMENTATION.md", "wasm/decoder.ts"}
    for name in files:
        if name.endswith(".mjs"):
            text = (PKG / name).read_text()
            for ref in re.findall(r"""(?:from\s+|import\(\s*|new URL\(\s*)['"](\.\/[^'"]+)['"]""", text):
                assert ref[2:] in files, f"{name} imports {ref}, which is not in the tarball"
    assert (project["dir"] / "node_modules/lghcc-decoder/LICENSE").read_bytes() == (PKG.parents[1] / "LICENSE").read_bytes()


def test_readme_example_runs_as_written(project):
    """The README's Node example, copied from the README, run beside a scene.lghcc: a line per tile,
    then the count and SH degree the reference decoder gives."""
    text = (PKG / "README.md").read_text()
    example = re.search(r"## Example \(Node\).*?```js\n(.*?)```", text, re.S).group(1)
    (project["dir"] / "example.mjs").write_text(example)
    shutil.copy(SH_DEGREES, project["dir"] / "scene.lghcc")
    out = _run([NODE, "example.mjs"], project["dir"], timeout=120).stdout.splitlines()
    scene = decode_stream(SH_DEGREES.read_bytes()).scene
    tiles = [ln for ln in out if ln.startswith("tile ")]
    assert len(tiles) >= 2 and tiles[-1] == f"tile {len(tiles)} of {len(tiles)}", out
    degree = round(np.sqrt(scene.sh.shape[1])) - 1  # sh: [N, (d + 1)^2, 3]
    assert f"{scene.num_gaussians} Gaussians, SH degree {degree}" in out


ARRAYS = """
import { readFileSync } from 'node:fs';
import { decode } from 'lghcc-decoder';
const [path, workers, box, activated] = process.argv.slice(2);
const hex = (f) => Buffer.from(f.buffer, f.byteOffset, f.byteLength).toString('hex');
const progress = [];
const s = await decode(readFileSync(path), { workers: Number(workers), box: JSON.parse(box), activated: activated === '1',
    onProgress: (p) => progress.push(p) });
const out = { count: s.count, shDegree: s.shDegree, tiles: s.tiles, bounds: s.bounds, progress };
for (const k of ['positions', 'scales', 'rotations', 'opacities', 'colors', 'sh']) out[k] = hex(s[k]);
console.log(JSON.stringify(out));
"""


def _f32(hexed: str) -> bytes:
    return bytes.fromhex(hexed)


def _reference(path, box=None):
    """The reference decoder's scene as the package's fields (float32 arrays, [N, width])."""
    scene = decode_stream(path.read_bytes(), box=Box(tuple(box[:3]), tuple(box[3:])) if box else None).scene
    n = scene.num_gaussians
    f32 = lambda a: np.ascontiguousarray(a, dtype="<f4").reshape(n, -1)  # noqa: E731
    return n, {"positions": f32(scene.means), "scales": f32(scene.log_scales), "rotations": f32(scene.rotations),
               "opacities": f32(scene.opacity), "colors": f32(scene.sh[:, 0, :]), "sh": f32(scene.sh[:, 1:, :])}


@pytest.mark.parametrize("path,workers,box", [(TILED, 3, None), (TILED, 0, None), (SH3, 2, None), (SH_DEGREES, 2, None),
                                              (TILED, 2, [-100.0, -100.0, -100.0, -0.05, 0.05, -0.05])])
def test_arrays_are_the_reference_decoders(project, path, workers, box):
    """Bit for bit the reference decoder's scene (the default, stored values), the DC split off into
    colors; onProgress once per decoded tile; bounds the centres' box."""
    got = node_in(project, ARRAYS, str(path), str(workers), json.dumps(box), "0")
    n, want = _reference(path, box)
    assert got["count"] == n and got["shDegree"] == int(np.sqrt(want["sh"].shape[1] // 3 + 1)) - 1
    for name, arr in want.items():
        assert _f32(got[name]) == arr.tobytes(), name
    progress = got["progress"]
    assert len(progress) == got["tiles"] >= 1
    assert sorted(p["tile"] for p in progress) == sorted({p["tile"] for p in progress})
    assert [p["tilesDecoded"] for p in progress] == list(range(1, len(progress) + 1))
    assert progress[-1]["pointsDecoded"] == progress[-1]["pointsTotal"] == n
    pos = want["positions"]
    assert got["bounds"] == {"min": pos.min(0).astype(float).tolist(), "max": pos.max(0).astype(float).tolist()}


def test_a_box_that_selects_no_tile_is_the_empty_scene(project):
    got = node_in(project, ARRAYS, str(TILED), "2", json.dumps([0.2, 0.2, 0.2, 0.3, 0.3, 0.3]), "0")
    assert got["count"] == got["tiles"] == 0 and got["bounds"] is None and got["progress"] == []


def test_activated_values(project):
    """activated: sigmoid opacities, exp scales, RGB = 0.5 + SH_C0 * DC, unit quaternions (binary64
    arithmetic rounded to binary32 once); positions and higher SH unchanged."""
    got = node_in(project, ARRAYS, str(SH3), "2", "null", "1")
    n, want = _reference(SH3)
    f = lambda k: np.frombuffer(_f32(got[k]), "<f4").reshape(n, -1)  # noqa: E731
    w = {k: v.astype(np.float64) for k, v in want.items()}
    q = w["rotations"] / np.linalg.norm(w["rotations"], axis=1, keepdims=True)
    for name, value in (("opacities", 1 / (1 + np.exp(-w["opacities"]))), ("scales", np.exp(w["scales"])),
                        ("colors", 0.5 + 0.28209479177387814 * w["colors"]), ("rotations", q)):
        np.testing.assert_allclose(f(name), value.astype(np.float32), rtol=2e-7, atol=1e-12, err_msg=name)
    assert _f32(got["positions"]) == want["positions"].tobytes() and _f32(got["sh"]) == want["sh"].tobytes()


INPUTS = """
import { readFileSync } from 'node:fs';
import { createServer } from 'node:http';
import { decode } from 'lghcc-decoder';
const bytes = readFileSync(process.argv[2]);
const server = createServer((req, res) => {
    if (req.url !== '/scene.lghcc') { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'content-type': 'application/octet-stream' });
    // in 3 chunks, so that tiles are decoded as the bytes arrive
    const third = Math.ceil(bytes.length / 3);
    res.write(bytes.subarray(0, third));
    setTimeout(() => { res.write(bytes.subarray(third, 2 * third)); setTimeout(() => res.end(bytes.subarray(2 * third)), 20); }, 20);
});
await new Promise((r) => server.listen(0, '127.0.0.1', r));
const url = `http://127.0.0.1:${server.address().port}/scene.lghcc`;
const digest = async (s) => Buffer.from(await crypto.subtle.digest('SHA-256', new Uint8Array([
    ...new Uint8Array(s.positions.buffer), ...new Uint8Array(s.rotations.buffer), ...new Uint8Array(s.sh.buffer),
    ...new Uint8Array(s.colors.buffer), ...new Uint8Array(s.scales.buffer), ...new Uint8Array(s.opacities.buffer)]))).toString('hex');
const chunked = () => new ReadableStream({ start(c) { for (let p = 0; p < bytes.length; p += 1000) c.enqueue(new Uint8Array(bytes.subarray(p, p + 1000))); c.close(); } });
const inputs = {
    buffer: bytes, uint8array: new Uint8Array(bytes), arraybuffer: bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.length),
    dataview: new DataView(bytes.buffer, bytes.byteOffset, bytes.length), blob: new Blob([bytes]), stream: chunked(),
    response: new Response(chunked()), url, urlObject: new URL(url),
};
const out = {};
for (const [k, v] of Object.entries(inputs)) out[k] = await digest(await decode(v, { workers: 2 }));
try { await decode(url.replace('scene', 'missing'), { workers: 1 }); out.missing = 'decoded'; } catch (e) { out.missing = e.message; }
try { await decode({ not: 'bytes' }); out.wrong = 'decoded'; } catch (e) { out.wrong = e.name; }
server.close();
console.log(JSON.stringify(out));
"""


def test_every_input_form_gives_the_same_scene(project):
    """Buffer, Uint8Array, ArrayBuffer, DataView, Blob, ReadableStream, Response, URL string and URL
    object (served in three chunks); a 404 says its status, a wrong input is a TypeError."""
    got = node_in(project, INPUTS, str(TILED))
    digests = {k: v for k, v in got.items() if k not in ("missing", "wrong")}
    assert len(digests) == 9 and len(set(digests.values())) == 1, got
    assert "HTTP 404" in got["missing"] and got["wrong"] == "TypeError"


ABORT = """
import { readFileSync } from 'node:fs';
import { decode } from 'lghcc-decoder';
const bytes = readFileSync(process.argv[2]);
const out = {};
// aborted at the first tile's progress: rejects with the signal's reason; no later progress
for (const workers of [0, 2]) {
    const ac = new AbortController();
    let calls = 0;
    try {
        await decode(bytes, { workers, signal: ac.signal, onProgress: () => { calls++; ac.abort(); } });
        out[`progress${workers}`] = 'decoded';
    } catch (e) { out[`progress${workers}`] = [e.name]; }
    await new Promise((r) => setTimeout(r, 300)); // a decode that went on would call onProgress again
    out[`progress${workers}`].push(calls);
}
// aborted before: rejects at once
try { await decode(bytes, { signal: AbortSignal.abort() }); out.before = 'decoded'; } catch (e) { out.before = e.name; }
// a stream whose bytes stop coming: the abort cancels the read under way
const ac = new AbortController();
let cancelled = null;
const stalled = new ReadableStream({ start(c) { c.enqueue(new Uint8Array(bytes.subarray(0, 4000))); }, cancel(reason) { cancelled = reason && reason.name; } });
setTimeout(() => ac.abort(), 200);
try { await decode(stalled, { signal: ac.signal }); out.stalled = 'decoded'; } catch (e) { out.stalled = [e.name, cancelled]; }
// a custom reason is the rejection
try { await decode(bytes, { signal: AbortSignal.abort(new RangeError('mine')) }); } catch (e) { out.reason = e.message; }
console.log(JSON.stringify(out));
"""


def test_abort_signal_stops_a_decode(project):
    """Aborted from the first onProgress (helper threads or not: no tile is reported after it), before
    the call, or while the input stalls: rejected with signal.reason, the read cancelled, and the
    process exits (no helper thread left running: the script would not end within the timeout)."""
    got = node_in(project, ABORT, str(TILED), timeout=60)
    assert got["progress0"] == got["progress2"] == ["AbortError", 1], got
    assert got["before"] == "AbortError" and got["stalled"] == ["AbortError", "AbortError"] and got["reason"] == "mine"


ERRORS = """
import { readFileSync } from 'node:fs';
import * as lghcc from 'lghcc-decoder';
const out = [];
for (const [path, flip] of JSON.parse(process.argv[2])) {
    const bytes = new Uint8Array(readFileSync(path));
    if (flip) bytes[flip] ^= 0x10;
    try { await lghcc.decode(bytes, { workers: 2 }); out.push('decoded'); }
    catch (e) {
        const cls = ['HashMismatchError', 'UnsupportedStreamError', 'BitstreamError', 'ResourceLimitError'].find((c) => e instanceof lghcc[c]);
        out.push([e.name, cls, e instanceof lghcc.LghccError]);
    }
}
try { await lghcc.decode(readFileSync(JSON.parse(process.argv[2])[0][0]), { maxMemory: 1000 }); } catch (e) { out.push([e.name, e instanceof lghcc.ResourceLimitError]); }
try { await lghcc.decode(new Uint8Array(0), { workers: -1 }); } catch (e) { out.push(e.name); }
console.log(JSON.stringify(out));
"""


def test_errors_are_the_exported_classes(project):
    """An anchor stream (outside the profile), a damaged stream, a tiny maxMemory and a wrong option:
    rejected with the exported classes (instanceof and name)."""
    cases = [[str(TILED), 0], [str(STREAMS / "c001_one_anchor" / "stream.lghcc"), 0], [str(TILED), 3000]]
    got = node_in(project, ERRORS, json.dumps(cases))
    assert got[0] == "decoded"
    assert got[1] == ["UnsupportedStreamError", "UnsupportedStreamError", True]
    assert got[2][1] in ("BitstreamError", "HashMismatchError") and got[2][2] is True
    assert got[3] == ["ResourceLimitError", True] and got[4] == "TypeError"


TYPES = """
import * as lghcc from 'lghcc-decoder';
import { readFileSync } from 'node:fs';
const s = await lghcc.decode(readFileSync(process.argv[2]), { workers: 1, onProgress: (p) => { progress = Object.keys(p); } });
var progress;
const exported = Object.fromEntries(Object.entries(lghcc).map(([k, v]) => [k, typeof v === 'function' && /^class /.test(String(v)) ? 'class' : typeof v]));
console.log(JSON.stringify({ exported, scene: Object.fromEntries(Object.entries(s).map(([k, v]) => [k, v && v.constructor ? v.constructor.name : String(v)])),
    bounds: Object.keys(s.bounds), progress }));
"""


def _interface(dts: str, name: str) -> list[str]:
    body = re.search(r"export interface " + name + r" \{(.*?)\n\}", dts, re.S).group(1)
    return re.findall(r"^\s+(\w+)\??:", body, re.M)


def test_types_declare_what_the_module_has(project):
    """index.d.ts (hand-written): its exported functions, constants and classes are the module's
    exports, no more and no fewer; LghccScene, LghccBounds and LghccProgress list exactly the fields
    decode() gives, with the declared array types; every option it declares is one decode() reads."""
    dts = (project["dir"] / "node_modules/lghcc-decoder/index.d.ts").read_text()
    got = node_in(project, TYPES, str(TILED))
    declared = {m.group(2): m.group(1) for m in re.finditer(r"^export (function|const|class) (\w+)", dts, re.M)}
    kinds = {"function": "function", "const": "number", "class": "class"}
    assert {k: kinds[v] for k, v in declared.items()} == got["exported"]
    assert sorted(_interface(dts, "LghccScene")) == sorted(got["scene"])
    for field in ("positions", "scales", "rotations", "opacities", "colors", "sh"):
        assert re.search(rf"^\s+{field}: Float32Array;", dts, re.M) and got["scene"][field] == "Float32Array"
    assert sorted(_interface(dts, "LghccBounds")) == sorted(got["bounds"])
    assert sorted(_interface(dts, "LghccProgress")) == sorted(got["progress"])
    options = _interface(dts, "LghccDecodeOptions")
    source = (PKG / "decode.mjs").read_text()
    read = re.search(r"const \{ (.*?) \} = options;", source).group(1)
    assert sorted(options) == sorted(re.findall(r"(\w+) =", read))
    pkg = json.loads((project["dir"] / "node_modules/lghcc-decoder/package.json").read_text())
    assert pkg["exports"]["."]["types"] == "./index.d.ts" and not pkg.get("dependencies")


BROWSER_PAGE = """<!doctype html><html><body><script type="module">
import { decode, BitstreamError } from './node_modules/lghcc-decoder/index.mjs';
const hex = (f) => Array.from(new Uint8Array(f.buffer, f.byteOffset, f.byteLength), (b) => b.toString(16).padStart(2, '0')).join('');
window.results = (async () => {
    const out = {};
    for (const workers of [3, 0]) {
        const progress = [];
        const s = await decode('scene.lghcc', { workers, onProgress: (p) => progress.push(p.tile) });
        const r = { count: s.count, progress };
        for (const k of ['positions', 'scales', 'rotations', 'opacities', 'colors', 'sh']) r[k] = hex(s[k]);
        out[`workers${workers}`] = r;
    }
    const ac = new AbortController();
    try { await decode('scene.lghcc', { workers: 2, signal: ac.signal, onProgress: () => ac.abort() }); out.abort = 'decoded'; }
    catch (e) { out.abort = e.name; }
    const bytes = new Uint8Array(await (await fetch('scene.lghcc')).arrayBuffer());
    bytes[bytes.length - 100] ^= 1;
    try { await decode(bytes, { workers: 2 }); out.damaged = 'decoded'; } catch (e) { out.damaged = e instanceof BitstreamError; }
    return out;
})().catch((e) => ({ error: String(e && e.stack || e) }));
</script></body></html>"""


def test_unbundled_in_chromium(project, tmp_path):
    """The installed package imported by a page as it lies in node_modules (no bundler), served over
    http: decode() of a URL with 3 module-worker helpers and on the page's thread gives the reference
    decoder's arrays bit for bit, one onProgress per tile; abort and a damaged tile reject."""
    import functools
    import http.server
    import threading

    from lghcc.viewer.browser import CHROMIUM_FLAGS, browser_status, chromium_path

    ok, why = browser_status()
    if not ok:
        pytest.skip(why)
    from playwright.sync_api import sync_playwright

    (project["dir"] / "page.html").write_text(BROWSER_PAGE)
    shutil.copy(TILED, project["dir"] / "scene.lghcc")
    class Quiet(http.server.SimpleHTTPRequestHandler):
        extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map, ".mjs": "text/javascript"}

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(project["dir"])))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    pw = sync_playwright().start()
    try:
        ctx = pw.chromium.launch_persistent_context(str(tmp_path / "profile"), executable_path=chromium_path(),
                                                    args=list(CHROMIUM_FLAGS), headless=True)
        page = ctx.new_page()
        page.goto(f"http://127.0.0.1:{server.server_address[1]}/page.html")
        got = page.evaluate("() => window.results")
        ctx.close()
    finally:
        pw.stop()
        server.shutdown()
    assert "error" not in got, got.get("error")
    n, want = _reference(TILED)
    for run in ("workers3", "workers0"):
        assert got[run]["count"] == n and sorted(got[run]["progress"]) == list(range(8)), run
        for name, arr in want.items():
            assert bytes.fromhex(got[run][name]) == arr.tobytes(), (run, name)
    assert got["abort"] == "AbortError" and got["damaged"] is True, got
