"""The streamed reader of the JavaScript decoder (js/lghcc-decoder's stream(url)), in Node, against a
local HTTP server (tools/range_server.py) that answers Range requests over a throttled link (the
whole file takes over a second; nothing but that server is asked). A real scene, playbot lod4 (8,406
Gaussians, SH degree 2, CC-BY-4.0 Stephane Agullo), is encoded here with lghcc's fast preset into 12
tiles. The streamed scene, assembled in stream order, and each tile handed to onTile are bit for bit
the reference decoder's partial decode (clause 13.3) of the same tiles; the tiles come nearest the
camera first; a box or a frustum fetches fewer bytes than the file, byte-adjacent tiles in one
request; a server without Range support gives the same scene, whole, with a note; an abort stops
the transfer; a damaged tile is rejected when fetched. Skips where node or the scene is missing."""

import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from lghcc.common.tiles import Box
from lghcc.conformance import runner
from lghcc.decoder.decode import decode_stream, parse_stream

NODE = shutil.which("node")
pytestmark = [pytest.mark.integration,  # Node and Chromium
              pytest.mark.skipif(NODE is None, reason="node (Node.js) is not on the PATH")]
ROOT = Path(__file__).resolve().parents[1]
PKG = runner.JS_DECODER_DIR
PLAYBOT = ROOT.parent / "shared" / "data" / "playbot" / "playbot_lod4_8k.ply"  # conftest.SHARED_DATA's
ANCHOR = runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc"
UNTILED = runner.STREAMS_DIR / "c033_gaussians_sh3_prediction" / "stream.lghcc"  # one tile, SH degree 3
RATE = 64_000  # bytes/s: the 105 kB stream takes about 1.6 s
FIELDS = ("positions", "scales", "rotations", "opacities", "colors", "sh")

sys.path.insert(0, str(ROOT / "tools"))
import range_server  # noqa: E402  (tools/ is not a package)

STREAM_JS = """
import { stream } from %(index)s;
const [url, opts] = process.argv.slice(2);
const options = JSON.parse(opts);
const hex = (f) => Buffer.from(f.buffer, f.byteOffset, f.byteLength).toString('hex');
const tiles = [], notes = [], progress = [];
const controller = new AbortController();
let out;
try {
    const s = await stream(url, { ...options, signal: controller.signal, onNote: (m) => notes.push(m),
        onProgress: (p) => progress.push(p),
        onTile: (v) => {
            const t = { tile: v.tile, offset: v.offset, count: v.count, bounds: v.bounds, time: Date.now() };
            for (const k of %(fields)s) t[k] = hex(v[k]);
            tiles.push(t);
            if (options.abortAfterFirst) controller.abort(new Error('stopped by the test'));
        } });
    out = { count: s.count, shDegree: s.shDegree, tiles: s.tiles, ranged: s.ranged, requests: s.requests,
            bytesFetched: s.bytesFetched, bytesTotal: s.bytesTotal, bounds: s.bounds };
    for (const k of %(fields)s) out[k] = hex(s[k]);
} catch (err) {
    out = { error: `${err.name}: ${err.message}` };
}
console.log(JSON.stringify({ ...out, onTile: tiles, notes, progress, end: Date.now() }));
""" % {"index": json.dumps(str(PKG / "index_node.mjs")), "fields": json.dumps(list(FIELDS))}


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    """playbot lod4 as a 12-tile stream in a served folder: {dir, data, parsed}."""
    if not PLAYBOT.is_file():
        pytest.skip(f"the playbot scene {PLAYBOT} is not here")
    import lghcc

    folder = tmp_path_factory.mktemp("served")
    data = lghcc.encode(PLAYBOT, preset="fast", tile_points=1024)
    (folder / "scene.lghcc").write_bytes(data)
    (folder / "anchor.lghcc").write_bytes(ANCHOR.read_bytes())
    (folder / "untiled.lghcc").write_bytes(UNTILED.read_bytes())
    damaged = bytearray(data)
    parsed = parse_stream(data)
    last = parsed.tiles[-1].attributes[0]
    damaged[last.offset + 20] ^= 0x10  # a payload byte of the last tile's attribute unit: its CRC-32 fails
    (folder / "damaged.lghcc").write_bytes(bytes(damaged))
    assert len(parsed.tiles) >= 8
    return {"dir": folder, "data": data, "parsed": parsed}


def _stream(scene, name: str, options: dict, *, ranges: bool = True, rate: float | None = RATE) -> tuple[dict, object]:
    """stream() of the served file in Node: (its JSON, the server's link with its log)."""
    server, link = range_server.serve(scene["dir"], rate, ranges=ranges, chunk=1024)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/{name}"
        script = scene["dir"] / "stream.mjs"
        script.write_text(STREAM_JS)
        res = subprocess.run([NODE, str(script), url, json.dumps(options)], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr[-3000:]
        time.sleep(0.05)  # the server's last writes logged
        return json.loads(res.stdout.strip().splitlines()[-1]), link
    finally:
        server.shutdown()


def _reference(data: bytes, box=None) -> tuple[int, dict]:
    """The reference decoder's (partial) decode as the package's fields, float32 [N, width]."""
    s = decode_stream(data, box=Box(tuple(box[:3]), tuple(box[3:])) if box else None).scene
    n = s.num_gaussians
    f32 = lambda a: np.ascontiguousarray(a, dtype="<f4").reshape(n, int(np.prod(np.shape(a)[1:])))  # noqa: E731 (n may be 0)
    return n, {"positions": f32(s.means), "scales": f32(s.log_scales), "rotations": f32(s.rotations),
               "opacities": f32(s.opacity), "colors": f32(s.sh[:, 0, :]), "sh": f32(s.sh[:, 1:, :])}


def _cell_box(parsed, t: int) -> np.ndarray:
    """Tile t's cell in world coordinates (clause 13.3): [x0, y0, z0, x1, y1, z1]."""
    ps = parsed.ps
    c = np.asarray(parsed.tiles[t].cell, dtype=np.float64)
    vs, origin = float(ps.voxel_size), np.asarray(ps.origin, dtype=np.float64)
    return np.concatenate([c * ps.tile_size * vs + origin, (c + 1) * ps.tile_size * vs + origin])


def _tile_bytes(parsed, t: int) -> tuple[int, int]:
    tile = parsed.tiles[t]
    return tile.geometry.offset, tile.scene_hash.offset + tile.scene_hash.size


def _assert_reference(got: dict, data: bytes, box=None) -> None:
    """The streamed scene and every onTile tile are the reference decoder's, bit for bit."""
    assert "error" not in got, got
    n, want = _reference(data, box)
    assert got["count"] == n
    for k in FIELDS:
        assert bytes.fromhex(got[k]) == want[k].tobytes(), k
    assert sum(t["count"] for t in got["onTile"]) == n and len(got["onTile"]) == got["tiles"]
    for t in got["onTile"]:
        o, c = t["offset"], t["count"]
        for k in FIELDS:
            assert bytes.fromhex(t[k]) == want[k][o:o + c].tobytes(), (t["tile"], k)
        pos = want["positions"][o:o + c]
        assert t["bounds"] == {"min": pos.min(0).astype(float).tolist(), "max": pos.max(0).astype(float).tolist()}
    assert [p["tilesDecoded"] for p in got["progress"]] == list(range(1, got["tiles"] + 1))


@pytest.mark.data
@pytest.mark.parametrize("workers", [2, 0])
def test_streamed_scene_is_the_reference_decode_nearest_tiles_first(scene, workers):
    """No box: every tile, fetched by Range requests after the prelude, nearest the camera first,
    the scene the reference decoder's full decode; the first tile decoded before the last byte went out."""
    parsed = scene["parsed"]
    camera = _cell_box(parsed, len(parsed.tiles) - 1)[3:] + 0.01  # beyond the far corner of the last tile's cell
    got, link = _stream(scene, "scene.lghcc", {"workers": workers, "camera": camera.tolist(), "headBytes": 512,
                                               "connections": 1})
    _assert_reference(got, scene["data"])
    assert got["ranged"] is True and got["bytesTotal"] == len(scene["data"])
    assert got["bytesFetched"] == link.bytes_sent == len(scene["data"])  # no byte twice (the stream ends with its last tile)

    def distance(t):
        b = _cell_box(parsed, t)
        return float(np.sum(np.maximum(0, np.maximum(b[:3] - camera, camera - b[3:])) ** 2))

    ranks = {t: r for r, t in enumerate(sorted(range(len(parsed.tiles)), key=lambda t: (distance(t), t)))}
    # the requests (one connection: one after the other) each start at the best-ranked tile not yet asked for
    def first_tile(byte):  # the tile a request starts in (it may start inside the first request's bytes)
        return next(t for t in range(len(parsed.tiles)) if _tile_bytes(parsed, t)[0] <= byte < _tile_bytes(parsed, t)[1])

    # the prelude's requests (the first, and more while the prelude is longer: an sh_transform unit's matrix)
    # end before the first tile's bytes
    starts = [s for _, s, _, _, first, _ in sorted(link.log, key=lambda r: r[4]) if s >= _tile_bytes(parsed, 0)[0]]
    assert [ranks[first_tile(s)] for s in starts] == sorted(ranks[first_tile(s)] for s in starts), starts
    assert ranks[first_tile(starts[0])] == 0
    order = [t["tile"] for t in got["onTile"]]
    if workers == 0:  # decoded one after the other as they arrive (a pool may finish a small tile first)
        assert ranks[order[0]] == 0, (order, ranks)
    half = len(order) // 2
    assert np.mean([ranks[t] for t in order[:half]]) < np.mean([ranks[t] for t in order[half:]]), order
    # the first tile was handed over while the link still had bytes to send; every request a range
    assert got["onTile"][0]["time"] < link.last_byte_time * 1000 - 200, (got["onTile"][0]["time"], link.last_byte_time)
    assert link.log and all(status == 206 for *_, status, _, _ in [(p, s, e, st, a, b) for p, s, e, st, a, b in link.log])
    # byte-adjacent tiles share a request: fewer requests than tiles
    assert got["requests"] == len(link.log) < len(parsed.tiles), got["requests"]


@pytest.mark.data
def test_a_box_fetches_only_its_tiles(scene):
    """A box that meets some tiles: the reference decoder's partial decode of that box, bit for bit,
    with fewer bytes fetched than the file: the prelude and the selected tiles' bytes only."""
    parsed = scene["parsed"]
    box = [-100.0, -100.0, -100.0, 100.0, 100.0, float(_cell_box(parsed, 0)[2]) + 1e-3]  # the cells of the lowest z
    selected = [t for t in range(len(parsed.tiles)) if _cell_box(parsed, t)[2] <= box[5]]
    assert 0 < len(selected) < len(parsed.tiles)
    got, link = _stream(scene, "scene.lghcc", {"workers": 2, "box": box, "headBytes": 512})
    _assert_reference(got, scene["data"], box)
    assert sorted(t["tile"] for t in got["onTile"]) == selected
    wanted = sum(e - s for s, e in (_tile_bytes(parsed, t) for t in selected))
    prelude = _tile_bytes(parsed, 0)[0]  # the header and the units before the first tile
    # the prelude is read by requests of 512 bytes, then doubling: at most about twice it, past the tiles' start
    assert wanted + prelude <= got["bytesFetched"] <= wanted + 2 * prelude + 512 < len(scene["data"]), \
        (got["bytesFetched"], wanted, prelude)
    sent = sorted((s, e) for _, s, e, *_ in link.log)
    assert all(a[1] <= b[0] for a, b in zip(sent, sent[1:])), sent  # no byte twice
    assert link.bytes_sent == got["bytesFetched"]


@pytest.mark.data
def test_a_frustum_selects_the_tiles_it_meets(scene):
    """A frustum of one plane x >= c keeps the cells whose x range reaches c: the tiles of the box
    [c, +inf) on x, bit for bit the reference decoder's partial decode of that box."""
    parsed = scene["parsed"]
    c = float(_cell_box(parsed, len(parsed.tiles) - 1)[0]) + 1e-3  # inside the last column of cells
    got, _ = _stream(scene, "scene.lghcc", {"workers": 0, "frustum": [[1, 0, 0, -c]], "headBytes": 512}, rate=None)
    box = [c, -1e30, -1e30, 1e30, 1e30, 1e30]
    _assert_reference(got, scene["data"], box)
    assert 0 < got["tiles"] < len(parsed.tiles) and got["bytesFetched"] < len(scene["data"])


@pytest.mark.data
def test_a_server_without_range_support_gives_the_whole_file_with_a_note(scene):
    """A 200 to the first request: the file is read whole, its tiles decoded as they arrive; the
    box's tiles the same scene as the reference's; a note says why."""
    parsed = scene["parsed"]
    box = [-100.0, -100.0, -100.0, 100.0, 100.0, float(_cell_box(parsed, 0)[2]) + 1e-3]
    got, link = _stream(scene, "scene.lghcc", {"workers": 2, "box": box}, ranges=False)
    _assert_reference(got, scene["data"], box)
    assert got["ranged"] is False and got["requests"] == 1 and got["bytesFetched"] == len(scene["data"])
    assert len(got["notes"]) == 1 and "does not answer Range requests" in got["notes"][0], got["notes"]
    assert [st for *_, st, _, _ in link.log] == [200]


def test_an_untiled_stream_is_fetched_whole_after_its_prelude(scene):
    """One tile (no tile index): the prelude, then the rest of the file, the reference's scene."""
    got, link = _stream(scene, "untiled.lghcc", {"workers": 2, "camera": [0, 0, 0], "headBytes": 256}, rate=None)
    _assert_reference(got, UNTILED.read_bytes())
    assert got["ranged"] is True and got["bytesFetched"] == len(UNTILED.read_bytes()) and got["tiles"] == 1
    assert [(s, st) for _, s, _, st, _, _ in sorted(link.log, key=lambda r: r[4])] == [(0, 206), (256, 206)]


@pytest.mark.data
def test_an_abort_stops_the_transfer(scene):
    """Aborted at the first tile: stream() rejects with the reason and the rest is not sent."""
    got, link = _stream(scene, "scene.lghcc", {"workers": 0, "abortAfterFirst": True, "headBytes": 512, "connections": 1})
    assert got.get("error") == "Error: stopped by the test", got
    assert len(got["onTile"]) == 1
    time.sleep(0.3)
    assert link.bytes_sent < 0.7 * len(scene["data"]), link.bytes_sent


@pytest.mark.data
def test_a_damaged_tile_is_rejected_when_fetched(scene):
    """The last tile's attribute unit fails its CRC-32: a stream that fetches it rejects with
    BitstreamError (E9); a box without it decodes (a tile that is not fetched is not checked)."""
    parsed = scene["parsed"]
    got, _ = _stream(scene, "damaged.lghcc", {"workers": 2, "headBytes": 512}, rate=None)
    assert got["error"].startswith("BitstreamError: ") and "CRC-32" in got["error"] and "E9" in got["error"], got
    box = [-100.0, -100.0, -100.0, float(_cell_box(parsed, 0)[3]) - 1e-3, 100.0, 100.0]  # the first column of cells
    got, _ = _stream(scene, "damaged.lghcc", {"workers": 2, "box": box, "headBytes": 512}, rate=None)
    _assert_reference(got, scene["data"], box)


def test_an_anchor_stream_is_refused_from_its_prelude(scene):
    got, link = _stream(scene, "anchor.lghcc", {"workers": 0, "headBytes": 64}, rate=None)
    assert got["error"].startswith("UnsupportedStreamError: "), got
    assert len(link.log) == 1  # refused from the first request's bytes


def test_wrong_options_are_named():
    script = f"""import {{ stream }} from {json.dumps(str(PKG / 'index_node.mjs'))};
const out = [];
for (const o of [{{ camera: [0, 0] }}, {{ frustum: [[1, 0, 0]] }}, {{ connections: 0 }}, {{ box: [0, 0, 0] }}, {{ onTile: 3 }}]) {{
    try {{ await stream('http://127.0.0.1:9/x.lghcc', o); out.push('no error'); }} catch (e) {{ out.push(`${{e.name}}: ${{e.message}}`); }}
}}
try {{ await stream(new Uint8Array(8)); }} catch (e) {{ out.push(`${{e.name}}: ${{e.message}}`); }}
console.log(JSON.stringify(out));"""
    res = subprocess.run([NODE, "--input-type=module", "-e", script], capture_output=True, text=True, timeout=60)
    out = json.loads(res.stdout.strip().splitlines()[-1])
    for msg, name in zip(out, ["camera", "frustum", "connections", "box", "onTile", "url"]):
        assert msg.startswith("TypeError: ") and name in msg, out


def _interface(dts: str, name: str) -> list[str]:
    body = re.search(r"export interface " + name + r" [^{]*\{(.*?)\n\}", dts, re.S).group(1)
    return re.findall(r"^\s+(\w+)\??:", body, re.M)


@pytest.mark.data
def test_types_declare_what_stream_gives(scene):
    """index.d.ts: LghccStreamOptions lists exactly the options stream() reads; LghccTile, LghccStreamIndex
    and LghccStreamResult (with LghccScene's fields) exactly what it hands out."""
    dts = (PKG / "index.d.ts").read_text()
    read = re.search(r"const \{(.*?)\} = options;", (PKG / "stream.mjs").read_text(), re.S).group(1)
    assert sorted(_interface(dts, "LghccStreamOptions")) == sorted(re.findall(r"(\w+) =", read))
    server, _ = range_server.serve(scene["dir"], None)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/scene.lghcc"
        script = f"""import {{ stream }} from {json.dumps(str(PKG / 'index_node.mjs'))};
let tile, index;
const s = await stream({json.dumps(url)}, {{ workers: 1, onTile: (t) => {{ tile = Object.keys(t); }},
    camera: (i) => {{ index = Object.keys(i); return null; }} }});
console.log(JSON.stringify({{ tile, index, result: Object.keys(s) }}));"""
        (scene["dir"] / "types.mjs").write_text(script)  # a file: helper threads inherit --input-type and fail
        res = subprocess.run([NODE, str(scene["dir"] / "types.mjs")], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr[-2000:]
        got = json.loads(res.stdout.strip().splitlines()[-1])
    finally:
        server.shutdown()
    assert sorted(_interface(dts, "LghccTile")) == sorted(got["tile"])
    assert sorted(_interface(dts, "LghccStreamIndex")) == sorted(got["index"])
    assert sorted(_interface(dts, "LghccStreamResult") + _interface(dts, "LghccScene")) == sorted(got["result"])


PLAN_JS = """
import { planRequests, fetchOrder, selectTiles } from %(stream)s;
import { readFileSync } from 'node:fs';
const cases = JSON.parse(readFileSync(process.argv[2], 'utf8'));
const out = cases.map(({ sizes, order, maxBytes, cells, camera, box, planes }) => {
    let pos = 100;
    const tiles = sizes.map((n, t) => { const r = { start: pos, end: pos + n, points: 1, cell: cells[t] }; pos += n; return r; });
    const ctx = { tiles, ps: { tileSize: 4, voxelSize: 0.5, origin: [0.25, -1, 2], numGaussians: tiles.length, shDegree: 0 } };
    return { plan: planRequests(ctx, order, maxBytes), fetch: fetchOrder(ctx, tiles.map((_, t) => t), camera),
             chosen: selectTiles(ctx, { box, frustum: planes }) };
});
console.log(JSON.stringify(out));
""" % {"stream": json.dumps(str(PKG / "stream.mjs"))}


@pytest.mark.skipif(NODE is None, reason="node is not on the PATH")
def test_request_plans_cover_the_chosen_tiles_once_in_rank_order(tmp_path):
    """planRequests (property test: random tile sizes, random chosen subsets in random rank orders,
    limits from below one tile to above the file): every chosen tile in exactly one request, a
    request a run of consecutive tiles whose bytes are contiguous, started by the best-ranked tile
    not yet requested and running on only after it, no longer than the limit unless one tile; and
    fetchOrder sorts by distance to the cell, selectTiles keeps exactly the cells meeting the box and
    the half-spaces (checked against a direct evaluation here)."""
    hypothesis = pytest.importorskip("hypothesis")
    st = hypothesis.strategies
    cases = []

    @hypothesis.settings(max_examples=150, deadline=None, database=None)
    @hypothesis.given(st.data())
    def collect(data):
        n = data.draw(st.integers(0, 12))
        sizes = data.draw(st.lists(st.integers(9, 500), min_size=n, max_size=n))
        chosen = data.draw(st.lists(st.sampled_from(range(n)), unique=True) if n else st.just([]))
        order = data.draw(st.permutations(chosen))
        cells = sorted({tuple(c) for c in data.draw(st.lists(st.tuples(*[st.integers(-3, 3)] * 3), min_size=n, max_size=n, unique=True))})
        camera = data.draw(st.tuples(*[st.floats(-20, 20)] * 3))
        box = data.draw(st.none() | st.tuples(*[st.floats(-20, 20)] * 6).map(lambda b: [min(b[0], b[3]), min(b[1], b[4]), min(b[2], b[5]),
                                                                                     max(b[0], b[3]), max(b[1], b[4]), max(b[2], b[5])]))
        planes = data.draw(st.none() | st.lists(st.tuples(*[st.floats(-1, 1)] * 3, st.floats(-10, 10)).map(list), max_size=3))
        cases.append({"sizes": sizes, "order": list(order), "maxBytes": data.draw(st.integers(1, 3000)), "cells": [list(c) for c in cells],
                      "camera": list(camera), "box": box, "planes": planes})

    collect()
    (tmp_path / "cases.json").write_text(json.dumps(cases))
    (tmp_path / "plan.mjs").write_text(PLAN_JS)
    res = subprocess.run([NODE, str(tmp_path / "plan.mjs"), str(tmp_path / "cases.json")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr[-2000:]
    for case, got in zip(cases, json.loads(res.stdout)):
        sizes, order, limit = case["sizes"], case["order"], case["maxBytes"]
        starts = [100 + sum(sizes[:t]) for t in range(len(sizes))]
        plan = got["plan"]
        assert sorted(t for r in plan for t in r["tiles"]) == sorted(order), (case, plan)
        done: set[int] = set()
        for r in plan:
            tiles = r["tiles"]
            assert tiles == list(range(tiles[0], tiles[-1] + 1)) and r["start"] == starts[tiles[0]]
            assert r["end"] == starts[tiles[-1]] + sizes[tiles[-1]]
            assert len(tiles) == 1 or r["end"] - r["start"] <= limit, (r, limit)
            assert tiles[0] == next(t for t in order if t not in done), (order, plan)
            done.update(tiles)
        cells = np.asarray(case["cells"], dtype=np.float64).reshape(-1, 3)
        lo, hi = cells * 4 * 0.5 + [0.25, -1, 2], (cells + 1) * 4 * 0.5 + [0.25, -1, 2]
        cam = np.asarray(case["camera"])
        dist = (np.maximum(0, np.maximum(lo - cam, cam - hi)) ** 2).sum(axis=1)
        assert [float(dist[t]) for t in got["fetch"]] == sorted(float(d) for d in dist), case
        keep = np.ones(len(cells), bool)
        if case["box"]:
            b = case["box"]
            keep &= (lo <= b[3:]).all(axis=1) & (hi >= b[:3]).all(axis=1)
        for a, bb, c, d in case["planes"] or []:
            far = np.where(np.asarray([a, bb, c]) >= 0, hi, lo)  # the corner farthest along the normal
            keep &= far @ [a, bb, c] + d >= 0
        assert got["chosen"] == [int(t) for t in np.flatnonzero(keep)], case


def test_frustum_planes_hold_exactly_the_points_in_clip_space(tmp_path):
    """frustumPlanes of a perspective × view matrix (column-major, WebGL clip space): a point is
    inside every plane exactly when its clip coordinates lie in [-w, w] on x, y and z."""
    rng = np.random.default_rng(5)
    f, near, far = 1 / np.tan(np.radians(30)), 0.5, 50.0
    proj = np.array([[f / 1.5, 0, 0, 0], [0, f, 0, 0], [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])
    c, s = np.cos(0.7), np.sin(0.7)
    view = np.array([[c, 0, -s, 1.0], [0, 1, 0, -2.0], [s, 0, c, 3.0], [0, 0, 0, 1]])
    m = proj @ view
    points = rng.uniform(-40, 40, (2000, 3))
    script = f"""import {{ frustumPlanes }} from {json.dumps(str(PKG / 'stream.mjs'))};
console.log(JSON.stringify(frustumPlanes({json.dumps(m.T.ravel().tolist())})));"""
    (tmp_path / "planes.mjs").write_text(script)
    res = subprocess.run([NODE, str(tmp_path / "planes.mjs")], capture_output=True, text=True, timeout=60)
    planes = np.asarray(json.loads(res.stdout))
    clip = np.c_[points, np.ones(len(points))] @ m.T
    inside = (np.abs(clip[:, :3]) <= clip[:, 3:4]).all(axis=1)
    by_planes = ((np.c_[points, np.ones(len(points))] @ planes.T) >= 0).all(axis=1)
    assert planes.shape == (6, 4) and 50 < inside.sum() < 1950
    assert np.array_equal(inside, by_planes)


CONFORMANCE_JS = """
import { stream } from %(index)s;
const jobs = JSON.parse(process.argv[2]);
const hex = (f) => Buffer.from(f.buffer, f.byteOffset, f.byteLength).toString('hex');
const out = [];
for (const { url, box } of jobs) {
    const tiles = [];
    try {
        const s = await stream(url, { box, workers: 1, headBytes: 64, onTile: (t) => tiles.push(t.tile) });
        const r = { count: s.count, tiles: tiles.sort((a, b) => a - b), bytesFetched: s.bytesFetched };
        for (const k of %(fields)s) r[k] = hex(s[k]);
        out.push(r);
    } catch (err) { out.push({ error: `${err.name}: ${err.message}` }); }
}
console.log(JSON.stringify(out));
""" % {"index": json.dumps(str(PKG / "index_node.mjs")), "fields": json.dumps(list(FIELDS))}


def test_conformance_partial_decodes_streamed():
    """Every box of the conformance suite's partial_decodes on a tiled stream of the explicit-Gaussian
    profile, streamed by Range requests (64-byte first request: the prelude takes several): the
    tiles test.yaml lists, the reference decoder's partial decode bit for bit, fewer bytes than the
    file when the box leaves tiles out."""
    from lghcc.common.units import GaussianParameterSet

    jobs, want = [], []
    for case in runner.load_cases():
        if case.expect != "decode" or not case.meta.get("partial_decodes"):
            continue
        data = case.stream.read_bytes()
        ps = parse_stream(data).ps
        if not isinstance(ps, GaussianParameterSet) or ps.hierarchy_enabled_flag:
            continue  # outside the JavaScript decoder's profile
        for entry in case.meta["partial_decodes"]:
            if "box" in entry and entry.get("level", 2) == 2:
                jobs.append((case, entry))
    assert len(jobs) >= 5, [c.id for c, _ in jobs]
    server, _ = range_server.serve(runner.STREAMS_DIR, None)
    try:
        port = server.server_address[1]
        arg = [{"url": f"http://127.0.0.1:{port}/{c.folder.name}/stream.lghcc", "box": e["box"]} for c, e in jobs]
        with tempfile.TemporaryDirectory() as tmp:  # the script beside no stream of the suite
            (Path(tmp) / "conf.mjs").write_text(CONFORMANCE_JS)
            res = subprocess.run([NODE, str(Path(tmp) / "conf.mjs"), json.dumps(arg)], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr[-2000:]
        got = json.loads(res.stdout.strip().splitlines()[-1])
    finally:
        server.shutdown()
    for (case, entry), g in zip(jobs, got):
        assert "error" not in g, (case.id, entry, g)
        if "tiles" in entry:
            assert g["tiles"] == sorted(entry["tiles"]), (case.id, entry["box"], g["tiles"])
        data = case.stream.read_bytes()
        n, ref = _reference(data, entry["box"])
        assert g["count"] == n, (case.id, entry["box"])
        for k in FIELDS:
            assert bytes.fromhex(g[k]) == ref[k].tobytes(), (case.id, entry["box"], k)
        if "tiles" in entry and len(entry["tiles"]) < len(parse_stream(data).tiles):
            assert g["bytesFetched"] < len(data), (case.id, entry["box"])


BATCHER_JS = """
import { TileBatcher } from %(stream)s;
const batches = [], delays = [];
const b = new TileBatcher((tiles) => { batches.push(tiles.slice()); delays.push(b.delay); }, { delay: 40, maxDelay: 200 });
b.push(0);                                                   // the first tile: handed on at once (timer 0)
await new Promise((r) => setTimeout(r, 20));
b.push(1); b.push(2);                                        // queued behind a 40 ms timer
const queued = batches.length;
b.flush();                                                   // the stream's end: what is queued now
b.flush();                                                   // nothing queued: no batch
for (let t = 3; t < 7; t++) { b.push(t); b.flush(); }        // the delay doubles up to maxDelay
let error = null;
try { new TileBatcher(() => {}, { delay: 0 }); } catch (e) { error = e.name; }
console.log(JSON.stringify({ batches, delays, queued, error }));
""" % {"stream": json.dumps(str(PKG / "stream.mjs"))}


def test_tile_batcher_hands_on_the_first_tile_at_once_then_growing_batches(tmp_path):
    """The loaders' shared batcher (lghcc-decoder's TileBatcher): the first tile alone at once, later
    tiles queued behind a timer whose delay doubles from `delay` up to `maxDelay`, every tile handed on
    exactly once and in order, flush() with nothing queued a no-op, a zero delay refused."""
    (tmp_path / "batcher.mjs").write_text(BATCHER_JS)
    res = subprocess.run([NODE, str(tmp_path / "batcher.mjs")], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["batches"] == [[0], [1, 2], [3], [4], [5], [6]]
    assert out["queued"] == 1                       # tiles 1 and 2 waited for their timer
    assert out["delays"] == [40, 80, 160, 200, 200, 200]
    assert out["error"] == "TypeError"
