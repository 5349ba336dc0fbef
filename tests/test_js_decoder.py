"""The JavaScript decoder of the explicit-Gaussian profile (js/lghcc-decoder, spec clause 8.4),
run with Node: every conformance stream of the profile bit-exact or rejected, through its own
runner and through lghcc-conformance --js; its range decoder against the reference coder on random
chunks (escapes up to 2^62 - 1 included); and corrupted streams, which it must reject or decode
exactly as the reference decoder does, never hang. Skips with the reason where node is absent."""

import base64
import json
import re
import shutil
import subprocess
import zlib

import numpy as np
import pytest
import yaml

from lghcc.conformance import runner
from lghcc.common.entropy.symbol_coder import encode_symbols
from lghcc.common.errors import LghccError

NODE = shutil.which("node")
pytestmark = [pytest.mark.integration,  # Node
              pytest.mark.skipif(NODE is None, reason="node (Node.js) is not on the PATH: the JavaScript decoder runs in it")]
JS = runner.JS_DECODER_DIR
STREAMS = runner.STREAMS_DIR


def node(script: str, stdin: str = "", timeout: float = 300) -> str:
    res = subprocess.run([NODE, "--input-type=module", "-e", script], input=stdin, capture_output=True, text=True,
                         cwd=JS, timeout=timeout)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout


def test_node_runner_passes_every_profile_stream():
    res = subprocess.run([NODE, str(JS / "conformance.mjs")], capture_output=True, text=True, timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    last = res.stdout.strip().splitlines()[-1]
    passed, total = (int(x) for x in last.split()[0].split("/"))
    assert passed == total >= 54, last
    assert "FAIL" not in res.stdout


def test_every_rejection_names_its_condition():
    """Each error stream of the profile is rejected with a condition of clause 8.2 (err.condition);
    each isolated one (test.yaml condition) with exactly its condition, as the reference decoder."""
    ids = set(runner.js_profile_ids(STREAMS))
    cases = [c for c in runner.load_cases() if c.expect == "error" and c.id in ids]
    script = """
import { readFileSync } from 'node:fs';
const { decodeStream } = await import(process.argv[1] + '/decoder.mjs');
const out = {};
for (const [id, path] of JSON.parse(readFileSync(0, 'utf8'))) {
    try { await decodeStream(new Uint8Array(readFileSync(path))); out[id] = ['decoded', null]; }
    catch (e) { out[id] = [e.name, e.condition === undefined ? null : e.condition]; }
}
console.log(JSON.stringify(out));
"""
    res = subprocess.run([NODE, "--input-type=module", "-e", script, str(JS)], capture_output=True, text=True,
                         timeout=600, input=json.dumps([[c.id, str(c.stream)] for c in cases]))
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    isolated = [c for c in cases if c.meta.get("condition")]
    assert len(cases) >= 100 and len(isolated) >= 20
    for c in cases:
        kind, condition = got[c.id]
        assert kind in ("BitstreamError", "UnsupportedStreamError", "HashMismatchError"), (c.id, kind)
        assert condition is not None and re.fullmatch(r"E[1-9][0-9]?", condition), (c.id, kind, condition)
        if c.meta.get("condition"):
            assert condition == c.meta["condition"], (c.id, condition)


def test_profile_membership():
    ids = set(runner.js_profile_ids(STREAMS))
    # decodable streams of every tool of the profile, and error streams of Gaussian streams
    for want in ("c032_gaussians_sh0", "c078_neighbour_prediction_tiles", "c084_neighbour_prediction_extent_at_the_limit",
                 "c086_step_adjust_tiles", "e148_step_adjust_index_above_max", "e085_stream_shorter_than_header"):
        assert want in ids
    # anchor streams, the hierarchy and context models are outside it
    for not_in in ("c001_one_anchor", "c034_gaussians_hierarchy_parent_mlp", "c063_tiles_gaussians",
                   "e137_neighbour_prediction_with_hierarchy", "e007_crc_mismatch"):
        assert not_in not in ids


def test_lghcc_conformance_js(capsys):
    rc = runner.main(["--js", "c033_gaussians_sh3_prediction", "c086_step_adjust_tiles", "e084_prediction_value_limit",
                      "c001_one_anchor"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "3 passed, 0 failed" in out and "3 streams of the explicit-Gaussian profile run, 1 outside it" in out
    assert "partial decodes match" in out  # c086's box decode through {options}


def test_js_rejects_decoder_cmd_together(capsys):
    with pytest.raises(SystemExit) as e:
        runner.main(["--js", "--decoder-cmd", "x {stream}"])
    assert e.value.code == 2


DECODE_CHUNKS = """
import { decodeSymbolChunk } from './symbols.mjs';
let text = '';
process.stdin.on('data', (d) => { text += d; });
process.stdin.on('end', () => {
    const out = [];
    for (const c of JSON.parse(text)) {
        const bytes = Uint8Array.from(Buffer.from(c.hex, 'hex'));
        const levels = Uint8Array.from(c.levels), res = new Float64Array(levels.length), wide = new Map();
        try {
            decodeSymbolChunk(bytes, levels, levels.length, res, wide, 'chunk');
            out.push(Array.from(res, (v, j) => (wide.has(j) ? wide.get(j) : BigInt(v)).toString()));
        } catch (e) { out.push(e.constructor.name); }
    }
    console.log(JSON.stringify(out));
});
"""


KNN = """
import { gridNeighbours } from './knn.mjs';
import { readFileSync } from 'node:fs';
const out = [];
for (const c of JSON.parse(readFileSync(0, 'utf8'))) {
    const [x, y, z] = [0, 1, 2].map((a) => Int32Array.from(c.points, (p) => p[a]));
    const lo = [0, 1, 2].map((a) => Math.min(...[x, y, z][a])), ext = [0, 1, 2].map((a) => Math.max(...[x, y, z][a]) - lo[a]);
    const idx = new Int32Array(c.queries.length * c.k).fill(-1), cnt = new Uint8Array(c.queries.length);
    gridNeighbours(x, y, z, lo, ext, Int32Array.from(c.data), Int32Array.from(c.queries), c.k, idx, cnt);
    out.push(Array.from(idx));
}
console.log(JSON.stringify(out));
"""


def test_grid_knn_matches_reference_ball_knn():
    """The JS decoder's grid k-NN (clause 11.7.2) against common/knn.py's canonical Ball k-NN on
    point sets full of equal distances (small lattices, flat and needle-shaped tiles, clusters far
    apart, clusters near MAX_EXTENT apart where d2 passes 2^53, one data point, cubes whose corners
    are at the largest extent of the 32-bit distances and one beyond), data = the rows of LoD < l as
    the decoder's, ties by lower row."""
    from lghcc.common.knn import ball_knn
    from lghcc.common.neighbour_prediction import WHOLE_EXTENT_RADIUS_SQ
    rng = np.random.default_rng(11)
    shapes = [(6, 6, 6), (40, 3, 1), (1, 1, 500), (2000, 2000, 2), (5, 5, 5)]
    cases, want = [], []
    for trial in range(25):
        span = np.array(shapes[trial % len(shapes)])
        n = int(rng.integers(1, min(400, int(np.prod(span))) + 1))
        flat = rng.choice(int(np.prod(span)), n, replace=False)  # distinct points, as a tile's
        pts = np.stack(np.unravel_index(flat, span), 1).astype(np.int64) - 3
        if trial % 5 == 4:
            pts[: n // 2] += 10**6  # two clusters far apart
        if trial % 5 == 3:
            pts[: n // 3] += 1_750_000_000  # extent near MAX_EXTENT: squared distances beyond 2^53
        step = int(2 ** rng.integers(0, 5))
        rows = np.arange(n)
        data, queries = rows[rows % step == 0], rows[rows % step != 0] if step > 1 else rows[1:]
        k = int(rng.integers(1, 9))
        idx, valid = ball_knn(pts[data], k, WHOLE_EXTENT_RADIUS_SQ, query=pts[queries], exclude_self=False)
        want.append(np.where(valid, data[np.maximum(idx, 0)], -1).reshape(-1).tolist())
        cases.append({"points": pts.tolist(), "data": data.tolist(), "queries": queries.tolist(), "k": k})
    for side in (37837, 37838):  # the largest extent whose squared distances the search keeps in 32 bits, and one beyond
        corners = np.array([[a, b, c] for a in (0, side) for b in (0, side) for c in (0, side)])
        pts = np.concatenate([corners, rng.integers(1, side, (40, 3))])  # corner 7 = (side, side, side)
        data, queries = np.arange(7), np.arange(7, len(pts))  # k = 7: every query reaches the far corners (d2 up to 3 side^2)
        idx, valid = ball_knn(pts[data], 7, WHOLE_EXTENT_RADIUS_SQ, query=pts[queries], exclude_self=False)
        want.append(np.where(valid, data[np.maximum(idx, 0)], -1).reshape(-1).tolist())
        cases.append({"points": pts.tolist(), "data": data.tolist(), "queries": queries.tolist(), "k": 7})
    assert json.loads(node(KNN, json.dumps(cases))) == want


def test_range_decoder_matches_reference_coder():
    rng = np.random.default_rng(7)
    chunks, want = [], []
    for trial in range(40):
        n = int(rng.integers(1, 400))
        levels = rng.integers(0, 64, n)
        sigma = np.exp(rng.uniform(-2, 8, n))
        r = np.rint(rng.normal(0, sigma)).astype(np.int64)
        if trial % 3 == 0:  # escapes of every class, up to the largest magnitude
            k = rng.integers(0, n, 5)
            r[k] = rng.choice([1 << 20, (1 << 53) + 1, (1 << 62) - 1, -(1 << 61) - 12345, -5000], 5)
        chunks.append({"hex": encode_symbols(r, levels).hex(), "levels": levels.tolist()})
        want.append([str(int(x)) for x in r])
    # the reference coder's verdicts on damaged chunks: one word more is read into point and passes
    # the exhaustion check (clause 10.6.5) here, two words more do not, a cut chunk does not
    good = encode_symbols(np.arange(-50, 50), np.full(100, 20))
    for data in (good + b"\xff" * 4, good + b"\x01\x02\x03\x04" * 2, good[:-4]):
        chunks.append({"hex": data.hex(), "levels": [20] * 100})
    got = json.loads(node(DECODE_CHUNKS, json.dumps(chunks)))
    assert got[:-3] == want
    assert got[-3:] == [[str(x) for x in range(-50, 50)], "BitstreamError", "BitstreamError"]


DECODE_FILES = """
import { readFileSync } from 'node:fs';
import { decodeStream, sceneDigestHex } from './decoder.mjs';
const out = [];
for (const f of JSON.parse(readFileSync(0, 'utf8'))) {
    try {
        const r = await decodeStream(new Uint8Array(readFileSync(f)));
        out.push(sceneDigestHex(r.ps, r.tiles));
    } catch (e) { out.push(e.constructor.name); }
}
console.log(JSON.stringify(out));
"""


def _corrupt(data: bytes, rng) -> bytes:
    """Flip a byte inside one unit's payload and fix the unit's CRC, so the fault reaches decoding."""
    units, pos = [], 8
    while pos + 9 <= len(data):
        size = int.from_bytes(data[pos + 1:pos + 5], "big")
        units.append((pos, size))
        pos += 9 + size
    start, size = units[int(rng.integers(0, len(units)))]
    if size == 0:
        return data
    b = bytearray(data)
    b[start + 5 + int(rng.integers(0, size))] ^= 1 << int(rng.integers(0, 8))
    b[start + 5 + size:start + 9 + size] = zlib.crc32(bytes(b[start:start + 5 + size])).to_bytes(4, "big")
    return bytes(b)


def test_corrupted_streams_agree_with_reference_decoder(tmp_path):
    from lghcc.common.hashing import digest_of
    from lghcc.decoder.decode import decode_stream

    rng = np.random.default_rng(11)
    sources = ["c032_gaussians_sh0", "c076_neighbour_prediction", "c085_step_adjust", "c078_neighbour_prediction_tiles"]
    files, ref = [], []
    for i in range(24):
        data = _corrupt((STREAMS / sources[i % len(sources)] / "stream.lghcc").read_bytes(), rng)
        f = tmp_path / f"m{i}.lghcc"
        f.write_bytes(data)
        files.append(str(f))
        try:
            ref.append(digest_of(decode_stream(data).scene).hex())
        except LghccError:
            ref.append(None)
    got = json.loads(node(DECODE_FILES, json.dumps(files), timeout=600))
    for f, g, r in zip(files, got, ref):
        if r is None:
            assert g in ("BitstreamError", "UnsupportedStreamError", "HashMismatchError"), (f, g)
        else:
            assert g == r, (f, g, r)


CHUNK_PAIRS = """
import { readFileSync } from 'node:fs';
import { decodeTile, parseStream } from './decoder.mjs';
const { root, ids, trials } = JSON.parse(readFileSync(0, 'utf8'));
let seed = 7;
const rand = (n) => { seed = (seed * 1103515245 + 12345) % 2147483648; return seed % n; };
const outcome = async (ctx) => {
    try {
        const r = await decodeTile(ctx, 0, { checkHash: false });
        return Buffer.from(r.values.buffer).toString('base64');
    } catch (e) { return `${e.constructor.name}: ${e.message}`; }
};
const out = [];
for (const id of ids) {
    const bytes = new Uint8Array(readFileSync(`${root}/${id}/stream.lghcc`));
    const ctx = parseStream(bytes); // the CRC-32s checked; the attribute unit's bytes are flipped below, in place
    const a = ctx.tiles[0].units[1].payload;
    for (let i = 0; i <= trials; i++) {
        const saved = a.slice();
        // trial 0 intact; then 1 to 3 random bytes, in the second half (the chunks' data) more often than not
        if (i) for (let m = 1 + rand(3); m > 0; m--) { const j = rand(2) ? (a.length >> 1) + rand(a.length - (a.length >> 1)) : rand(a.length); a[j] ^= 1 + rand(255); }
        ctx.chunkPairs = true;
        const paired = await outcome(ctx);
        ctx.chunkPairs = false;
        out.push({ id, i, paired, single: await outcome(ctx) });
        a.set(saved);
    }
}
console.log(JSON.stringify(out));
"""


@pytest.mark.parametrize("trials", [40])
def test_chunk_pairs_decode_and_fail_as_single_chunks(trials):
    """Two chunks of a LoD decoded together (attributeChunkPair, the range decoders interleaved) give the
    values of chunks decoded one at a time, and on flipped bytes the same error (the first fault in
    stream order names it: a failed pair is decoded again one chunk at a time)."""
    ids = ["c082_neighbour_prediction_small_chunks", "c091_sh_degree_2_channel_prediction", "c098_sh_degree_empty_degree_chunks",
           "c101_rotation_length_prior", "c111_step_adjust_flags_empty_chunks", "c115_sh_transform_prior"]
    got = json.loads(node(CHUNK_PAIRS, json.dumps({"root": str(STREAMS), "ids": ids, "trials": trials}), timeout=600))
    assert len(got) == len(ids) * (trials + 1)
    for g in got:
        assert g["paired"] == g["single"], g
    intact = [g for g in got if g["i"] == 0]
    assert all(":" not in g["paired"] for g in intact), intact  # every intact stream decodes
    errors = [g for g in got if g["paired"].startswith("BitstreamError")]
    assert len(errors) >= len(got) // 4, f"only {len(errors)} of {len(got)} trials failed: the flips miss the chunks"



@pytest.mark.parametrize("chunks", [5, 6, 7])
def test_prior_chunk_groups_decode_and_fail_as_single_chunks(shared_data, tmp_path, chunks):
    """Without neighbour prediction every row takes the prior's means and levels, and the module decodes
    up to four chunks at a time (attributePriorChunks: four range decoders interleaved, then two, then
    one): a tile of 5, 6 or 7 chunks (groups 4 + 1, 4 + 2, 4 + 3) decodes to the reference decoder's
    scene, and on flipped bytes gives the values or the error of chunks decoded one at a time."""
    import math

    import lghcc
    from lghcc.common.hashing import digest_of
    from lghcc.decoder.decode import decode_stream

    ply = shared_data / "playbot" / "playbot_lod4_8k.ply"
    n = lghcc.decode(lghcc.encode(ply, preset="web", verify=False)).num_gaussians
    rpc = math.ceil(n / chunks)
    assert math.ceil(n / rpc) == chunks and n < 16384  # one tile of `chunks` chunks
    data = lghcc.encode(ply, preset="web", rows_per_chunk=rpc)
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "stream.lghcc").write_bytes(data)
    got = json.loads(node(DECODE_FILES, json.dumps([str(tmp_path / "s" / "stream.lghcc")]), timeout=120))
    assert got == [digest_of(decode_stream(data).scene).hex()]
    got = json.loads(node(CHUNK_PAIRS, json.dumps({"root": str(tmp_path), "ids": ["s"], "trials": 30}), timeout=600))
    assert len(got) == 31 and ":" not in got[0]["paired"]
    for g in got:
        assert g["paired"] == g["single"], g
    assert sum(g["paired"].startswith("BitstreamError") for g in got) >= 8, got


FIRST_FAULT = """
import { readFileSync } from 'node:fs';
import { decodeStream } from './decoder.mjs';
const { files, node } = JSON.parse(readFileSync(0, 'utf8'));
if (node) await import('./sha256_node.mjs');
const out = [];
for (const f of files) {
    try {
        const r = await decodeStream(new Uint8Array(readFileSync(f)));
        out.push(`decoded ${r.tiles.length} tiles`);
    } catch (e) { out.push(`${e.constructor.name}: ${e.message}`); }
}
console.log(JSON.stringify(out));
"""


@pytest.mark.parametrize("node_hash", [False, True], ids=["web-crypto", "node-crypto"])
def test_the_first_faulty_tile_names_the_error(tmp_path, node_hash):
    """decodeStream hashes tile t while tile t + 1 decodes: a wrong scene_hash of tile 0 is still the error when
    tile 1 fails to decode too (the order of clause 13.2), with Web Crypto's hash and with node:crypto's."""
    from lghcc.common.container import DataUnit, UnitType, read_container, write_container

    c = read_container((STREAMS / "c078_neighbour_prediction_tiles" / "stream.lghcc").read_bytes())
    hashes = [i for i, u in enumerate(c.units) if u.unit_type == UnitType.DECODED_SCENE_HASH]
    attributes = [i for i, u in enumerate(c.units) if u.unit_type == UnitType.ATTRIBUTE]
    assert len(hashes) >= 2 and len(attributes) >= 2

    def variant(name, wrong_hash, broken_tile1):
        units = list(c.units)
        if wrong_hash:  # tile 0's scene hash, its last byte flipped
            u = units[hashes[0]]
            units[hashes[0]] = DataUnit(u.unit_type, u.payload[:-1] + bytes([u.payload[-1] ^ 1]))
        if broken_tile1:  # tile 1's attribute data, the same length, every byte after the first 16 inverted
            u = units[attributes[1]]
            units[attributes[1]] = DataUnit(u.unit_type, u.payload[:16] + bytes(b ^ 0xFF for b in u.payload[16:]))
        path = tmp_path / f"{name}.lghcc"
        path.write_bytes(write_container(units, c.header))
        return str(path)

    files = [variant("hash0", True, False), variant("tile1", False, True), variant("both", True, True)]
    got = json.loads(node(FIRST_FAULT, json.dumps({"files": files, "node": node_hash})))
    assert got[0].startswith("HashMismatchError: tile 0:"), got
    assert got[1].startswith("BitstreamError"), got  # tile 1 alone fails to decode
    assert got[2] == got[0], got  # both: tile 0's hash first


def big_tile_stream(tmp_path):
    """c032 (one tile, SH 0) declaring 2^24 Gaussians: within E22 and a raised --max-memory, but its
    tile needs more WebAssembly memory than the module addresses; refused before any allocation."""
    from lghcc.common.container import DataUnit, UnitType, read_container, write_container
    from lghcc.common.units import GaussianParameterSet

    c = read_container((STREAMS / "c032_gaussians_sh0" / "stream.lghcc").read_bytes())
    units = []
    for u in c.units:
        if u.unit_type == UnitType.GAUSSIAN_PARAMETER_SET:
            ps = GaussianParameterSet.from_bytes(u.payload)
            ps.num_gaussians_minus1 = 2 ** 24 - 1
            u = DataUnit(u.unit_type, ps.to_bytes())
        units.append(u)
    path = tmp_path / "big_tile.lghcc"
    path.write_bytes(write_container(units, c.header))
    return path


def test_cli_exit_codes(tmp_path):
    cli = str(JS / "cli.mjs")
    s = str(STREAMS / "c033_gaussians_sh3_prediction" / "stream.lghcc")
    res = subprocess.run([NODE, cli, s], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip().splitlines()[-1] == \
        runner.load_cases(STREAMS, ["c033_gaussians_sh3_prediction"])[0].meta["decoded_sha256"]
    res = subprocess.run([NODE, cli, s, "--max-memory", "1000"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 4 and "resource limit" in res.stderr and "MiB" in res.stderr
    res = subprocess.run([NODE, cli, str(big_tile_stream(tmp_path)), "--max-memory", str(2 ** 40)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 4 and "WebAssembly memory" in res.stderr and "16777216 points" in res.stderr, res.stderr
    res = subprocess.run([NODE, cli, str(STREAMS / "e148_step_adjust_index_above_max" / "stream.lghcc")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 3 and "max_step_adjust" in res.stderr
    res = subprocess.run([NODE, cli, str(tmp_path / "missing.lghcc")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    res = subprocess.run([NODE, cli], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2


PROGRESSIVE = """
import { readFileSync } from 'node:fs';
import { ProgressiveDecoder } from './progressive.mjs';
import { decodeStream, decodeTile, preludeContext, sceneDigestHex } from './decoder.mjs';
import { HashMismatchError } from './errors.mjs';
import { parseGaussianParameterSet } from './units.mjs';
const { path, failTile } = JSON.parse(readFileSync(0, 'utf8'));
const bytes = new Uint8Array(readFileSync(path));
// a pool as pool.mjs's, in this process: tiles finish in reverse order of their start, each decoded
// with the context a helper builds from the prelude's payloads
const helper = (ctx) => ({ ...preludeContext(parseGaussianParameterSet(ctx.payloads.ps), ctx.payloads), tiles: ctx.tiles });
const pool = { started: 0, start(ctx) { this.started++; }, flush() {}, decode(ctx, t) {
    const delay = 40 - 4 * t;
    return new Promise((res, rej) => setTimeout(() => t === failTile
        ? rej(new HashMismatchError(`tile ${t}`)) : decodeTile(helper(ctx), t).then(res, rej), delay));
} };
const order = [];
const dec = new ProgressiveDecoder({ pool, onTile: (t) => order.push(t) });
let out;
try {
    for (let p = 0; p < bytes.length; p += 997) await dec.push(bytes.subarray(p, p + 997));
    const r = await dec.finish();
    const ref = await decodeStream(bytes);
    out = { digest: sceneDigestHex(r.ps, r.tiles), ref: sceneDigestHex(ref.ps, ref.tiles), order, started: pool.started };
} catch (err) { out = { error: err.name }; }
console.log(JSON.stringify(out));
"""


@pytest.mark.parametrize("name", ["c078_neighbour_prediction_tiles", "c086_step_adjust_tiles", "c092_sh_degree_tiles"])
def test_progressive_decoding_with_a_tile_pool(name):
    """Tiles handed to a pool as their bytes arrive (997-byte chunks) and finished out of order,
    each with the context a helper parses from the prelude's payloads, give the scene of test.yaml
    (as decodeStream); a tile the pool rejects rejects the stream with its class."""
    path = str(STREAMS / name / "stream.lghcc")
    got = json.loads(node(PROGRESSIVE, json.dumps({"path": path, "failTile": -1})))
    tiles = len(got["order"])
    expected = yaml.safe_load((STREAMS / name / "test.yaml").read_text())["decoded_sha256"]
    assert got["digest"] == got["ref"] == expected and tiles >= 2 and got["started"] == 1
    assert sorted(got["order"]) == list(range(tiles)) and got["order"] != sorted(got["order"])
    assert json.loads(node(PROGRESSIVE, json.dumps({"path": path, "failTile": 1}))) == {"error": "HashMismatchError"}


CELL_CHECK = """
import { readFileSync } from 'node:fs';
import { decodeTile, parseStream } from './decoder.mjs';
const ctx = parseStream(new Uint8Array(readFileSync(readFileSync(0, 'utf8'))));
const out = [];
for (const t of [0, ctx.tiles.length - 1]) {
    const cell = ctx.tiles[t].cell;
    for (const shift of [null, [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]) {
        ctx.tiles[t].cell = shift ? cell.map((c, a) => c + shift[a]) : cell;
        try { await decodeTile(ctx, t); out.push('ok'); } catch (e) { out.push(e.name + ': ' + e.message); }
    }
    ctx.tiles[t].cell = cell;
}
console.log(JSON.stringify(out));
"""


def test_points_outside_their_tile_cell_are_rejected():
    """E58 (clause 7.3.11) from the decoded points' per-axis bounds: a tiled stream's tiles decode in
    their own cells and are rejected in a cell moved by one along any axis, either way (the points
    then leave it through its lower or its upper face)."""
    path = str(STREAMS / "c078_neighbour_prediction_tiles" / "stream.lghcc")
    got = json.loads(node(CELL_CHECK, stdin=path))
    assert len(got) == 14 and got[0] == got[7] == "ok", got
    for r in got[1:7] + got[8:]:
        assert r.startswith("BitstreamError") and "E58" in r, r


ASC = runner.JS_DECODER_DIR.parents[1] / "tools" / "node" / "node_modules" / "assemblyscript"


@pytest.mark.skipif(not ASC.is_dir(), reason="AssemblyScript is not installed (make node-tools)")
def test_wasm_module_rebuilds_byte_for_byte():
    """The committed wasm_module.mjs is what the pinned AssemblyScript makes of wasm/decoder.ts."""
    res = subprocess.run([NODE, "build-wasm.mjs", "--check"], capture_output=True, text=True,
                         cwd=ASC.parents[1], timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr[-2000:]


SCENE_ARRAYS = """
import { readFileSync } from 'node:fs';
import { decodeStream, sceneArrays } from './decoder.mjs';
const r = await decodeStream(new Uint8Array(readFileSync(process.argv[1])));
const a = sceneArrays(r.ps, r.tiles), hex = (f) => Buffer.from(f.buffer, f.byteOffset, f.byteLength).toString('hex');
console.log(JSON.stringify({ count: a.count, positions: hex(a.positions), sh: hex(a.sh), opacities: hex(a.opacities),
    scales: hex(a.scales), rotations: hex(a.rotations) }));
"""


@pytest.mark.parametrize("stream", ["c086_step_adjust_tiles", "c033_gaussians_sh3_prediction"])
def test_scene_arrays_match_the_reference_decoder(stream):
    """The renderer's arrays (decoder.mjs sceneArrays, made by the module: world positions in binary32
    as float32(c) * voxel_size + origin, the values split into SH, opacity, log scales and rotations)
    bit for bit those of the reference decoder's scene, over several tiles and with SH degree 3."""
    from lghcc.decoder.decode import decode_stream
    path = STREAMS / stream / "stream.lghcc"
    scene = decode_stream(path.read_bytes()).scene
    res = subprocess.run([NODE, "--input-type=module", "-e", SCENE_ARRAYS, str(path)], capture_output=True, text=True,
                         cwd=JS, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout)
    n = scene.num_gaussians
    assert got["count"] == n
    for name, want in (("positions", scene.means), ("sh", scene.sh), ("opacities", scene.opacity),
                       ("scales", scene.log_scales), ("rotations", scene.rotations)):
        assert bytes.fromhex(got[name]) == np.ascontiguousarray(want, dtype="<f4").reshape(n, -1).tobytes(), name


CRC = """
import { crc32, unitCrc32 } from './crc32.mjs';
import { moduleCrc32 } from './wasm.mjs';
const out = [];
let seed = 12345;
for (const n of [0, 1, 7, 8, 9, 4095, 4096, 4097, 65539, 1 << 20]) {
    const b = new Uint8Array(n + 5);
    for (let i = 0; i < b.length; i++) { seed = (seed * 1103515245 + 12345) >>> 0; b[i] = seed >>> 24; }
    out.push([crc32(b, 3, 3 + n), moduleCrc32(b, 3, 3 + n), unitCrc32(b, 3, 3 + n), Buffer.from(b.subarray(3, 3 + n)).toString('hex')]);
}
console.log(JSON.stringify(out));
"""


def test_module_crc32_is_zlibs():
    """The module's CRC-32 (wasm/decoder.ts crc32, slicing by 8, used for units of 4 KiB and more) and
    crc32.mjs's give zlib's CRC-32 on every length around the 8-byte steps and the 4 KiB switch."""
    for js, mod, unit, data in json.loads(node(CRC)):
        want = zlib.crc32(bytes.fromhex(data))
        assert js == mod == unit == want, (len(data) // 2, js, mod, unit, want)


IMPLIED_ROTATIONS = """
import { alloc, copyIn, wasm } from './wasm.mjs';
const n = 50000, M = 11, wc = 7, w = wasm();
let seed = 7;
const rand = () => { seed = (seed * 1103515245 + 12345) >>> 0; return seed / 2 ** 32; };
const q = new BigInt64Array(n * M), values = new Float32Array(n * M);
for (let r = 0; r < n; r++) {
    q[r * M + wc] = BigInt(Math.floor(rand() * 16));
    // x, y, z of every size: around the unit sphere, tiny, huge, zero, negative zero
    for (let c = wc + 1; c < M; c++) {
        const kind = Math.floor(rand() * 5);
        values[r * M + c] = kind === 0 ? 0 : kind === 1 ? -0 : (rand() - 0.5) * 2 ** Math.floor(rand() * 60 - 40);
    }
}
w.reset();
const zero = alloc(w, 64), pq = copyIn(w, q);
w.attributeTile(pq, M, zero, 0, zero, zero, zero, zero, 1, zero, zero, zero, zero, zero);
const pv = copyIn(w, values);
w.impliedRotations(pv, n, wc, 15);
const got = new Float32Array(w.memory.buffer, pv, n * M).slice();
const b64 = (a) => Buffer.from(a.buffer, a.byteOffset, a.byteLength).toString('base64');
console.log(JSON.stringify({ n, M, wc, q: b64(q), values: b64(values), got: b64(got) }));
"""


def test_module_implied_rotations_match_the_reference():
    """Clause 11.10's implied w by the module (wasm/decoder.ts impliedRotations) has the bits of the
    normative Python (common/attributes.implied_w) on 50,000 rows of every length index and of x, y, z
    from 2^-40 to 2^20, zeros of either sign included; the other channels are left as they were."""
    from lghcc.common.attributes import implied_w

    r = json.loads(node(IMPLIED_ROTATIONS))
    n, m, wc = r["n"], r["M"], r["wc"]
    q = np.frombuffer(base64.b64decode(r["q"]), dtype="<i8").reshape(n, m)
    values = np.frombuffer(base64.b64decode(r["values"]), dtype="<f4").reshape(n, m)
    got = np.frombuffer(base64.b64decode(r["got"]), dtype="<f4").reshape(n, m)
    want = values.copy()
    want[:, wc] = implied_w(q[:, wc], values[:, wc + 1:wc + 4])
    assert np.array_equal(got.view("<u4"), want.view("<u4"))
    assert np.count_nonzero(want[:, wc]) > 1000  # not all clamped to 0


ARENA_LIMIT = """
import { wasm, alloc } from './wasm.mjs';
const w = wasm();
w.reset();
const out = [];
for (let i = 0; i < 3; i++) {
    try { out.push(alloc(w, 2 ** 31 - 1, false)); } catch (e) { out.push(`${e.name}: ${e.message}`); }
}
w.reset();
out.push(alloc(w, 16) > 0);
console.log(JSON.stringify(out));
"""


def test_module_arena_beyond_4_gib_is_a_resource_limit():
    """Reservations in the module's arena that end beyond the 4 GiB of a 32-bit memory are refused
    with the resource-limit error (before, the address sum wrapped and the arena handed out memory it
    had already given: no error, overlapping arrays); the arena is usable again after reset. Pages
    are reserved, not touched: the 2 GiB cost no resident memory."""
    first, second, third, after = json.loads(node(ARENA_LIMIT))
    assert isinstance(first, int) and first > 0
    for refused in (second, third):
        assert refused.startswith("ResourceLimitError: decoding needs more WebAssembly memory"), refused
        assert "-" not in refused.split("(")[1]  # the MiB in use, not a signed 32-bit shift of 2 GiB
    assert after is True


def test_bench_ab_compares_two_trees_on_one_stream():
    """js/lghcc-decoder/bench_ab.mjs: the per-tile A/B of two decoder trees (here the same tree
    twice) checks that both decode to the same digest, the stream's, and reports CPU per decode."""
    stream = STREAMS / "c100_rotation_length" / "stream.lghcc"
    res = subprocess.run([NODE, str(JS / "bench_ab.mjs"), str(JS), str(JS), str(stream), "--rounds", "1"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    r = json.loads(res.stdout)
    want = yaml.safe_load((stream.parent / "test.yaml").read_text())
    assert r["sameDigest"] is True and r["tiles"] >= 1
    assert r["cpuMsA"] > 0 and r["cpuMsB"] > 0 and r["ratio"] == pytest.approx(r["cpuMsA"] / r["cpuMsB"])
    assert r["digest"] == want["decoded_sha256"]
    bad = subprocess.run([NODE, str(JS / "bench_ab.mjs"), str(JS)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "usage" in bad.stderr


def test_web_preset_streams_decode_bit_for_bit(shared_data, tmp_path):
    """The web preset (encoder/presets/web.yaml) writes a stream without neighbour prediction, its
    attributes in chunks of 2048 rows (several per tile, which the decoder takes up to four at a time), and
    the JavaScript decoder's arrays of it are the reference decoder's bit for bit."""
    import lghcc
    from lghcc.common.container import UnitType, read_container
    from lghcc.decoder.decode import decode_stream

    ply = shared_data / "playbot" / "playbot_lod4_8k.ply"
    data = lghcc.encode(ply, preset="web")
    units = [u.unit_type for u in read_container(data).units]
    assert UnitType.NEIGHBOUR_PREDICTION not in units and UnitType.ATTRIBUTE in units
    fast = [u.unit_type for u in read_container(lghcc.encode(ply, preset="fast")).units]
    assert UnitType.NEIGHBOUR_PREDICTION in fast  # what the web preset leaves out
    scene = decode_stream(data).scene
    n = scene.num_gaussians
    assert n > 2 * 2048  # more than two chunks of rows: at least one pair
    path = tmp_path / "web.lghcc"
    path.write_bytes(data)
    res = subprocess.run([NODE, "--input-type=module", "-e", SCENE_ARRAYS, str(path)], capture_output=True, text=True,
                         cwd=JS, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout)
    assert got["count"] == n
    for name, want in (("positions", scene.means), ("sh", scene.sh), ("opacities", scene.opacity),
                       ("scales", scene.log_scales), ("rotations", scene.rotations)):
        assert bytes.fromhex(got[name]) == np.ascontiguousarray(want, dtype="<f4").reshape(n, -1).tobytes(), name
