// The decoder in a Web Worker: {bytes} (a Uint8Array) or {url} (fetched as a stream) in; out,
// as the bytes arrive: {type: 'tile', t, tiles, count, arrays} per decoded, hash-checked tile
// (positions, sh, opacities, scales, rotations: transferred typed arrays, no PLY), then
// {type: 'done', count, tiles, seconds, digest, helpers, timeline} once the whole stream passed every check, or
// {type: 'error', kind, message}. With {digest: true} 'done' carries the decoded scene's SHA-256
// (clause 12); with {bytes, box} only the tiles the box selects are decoded. With {workers: W, source}
// (W >= 2, e.g. navigator.hardwareConcurrency; source: this script's text) the tiles of a tiled stream are decoded by W
// helper workers of this same script in parallel, this worker handing them out (pool.mjs; where a worker cannot start
// workers, tile after tile), and 'tile' messages come in the order tiles finish. The worker keeps its helpers for the
// next stream; {warm: true, workers: W, source} starts and warms them (and compiles the module) before any stream,
// answered by {type: 'ready', helpers}: a page sends it when it makes the worker, so a stream does not wait for them.
// timeline: {start, end, marks: [[what, when]], tiles: [{t, points, thread, start, decoded, end}]}, milliseconds of
// performance.timeOrigin + now() (decoded: the tile decoded and its arrays made; end: its hash checked too).
import { ProgressiveDecoder, sceneArrays } from './progressive.mjs';
import { decodeStream, sceneDigestHex } from './decoder.mjs';
import { TilePool, arrayBuffers, clock, helperMessage, marks } from './pool.mjs';
import { wasm } from './wasm.mjs';

async function* chunksOf(msg) {
    if (msg.bytes) { yield msg.bytes; return; }
    const res = await fetch(msg.url);
    if (!res.ok) throw new Error(`${msg.url}: HTTP ${res.status}`);
    const reader = res.body.getReader();
    for (;;) {
        const { value, done } = await reader.read();
        if (done) return;
        yield value;
    }
}

// {bytes, box, digest: true}: the tiles a box selects (clause 13.3), decoded at once
async function decodeBox(msg) {
    const t0 = performance.now();
    try {
        const r = await decodeStream(msg.bytes, { box: msg.box });
        const count = r.tiles.reduce((a, t) => a + t.n, 0);
        self.postMessage({ type: 'done', count, tiles: r.tiles.length, seconds: (performance.now() - t0) / 1000, digest: sceneDigestHex(r.ps, r.tiles) });
    } catch (err) {
        self.postMessage({ type: 'error', kind: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err), condition: err && err.condition });
    }
}

// the helpers' script: this worker's own, from the source text the page passes ({source}: a page on
// file: has an opaque origin, and a worker may not start another from the page's blob: URL)
function helperUrl(msg) {
    return msg.source ? URL.createObjectURL(new Blob([msg.source], { type: 'text/javascript' })) : self.location.href;
}

// the helpers, kept from one stream to the next (a viewer keeps its decoder)
let pool = null;

let helperScript = null; // the helpers' URL (a blob: URL made of msg.source is revoked with its pool)

function poolFor(msg) {
    const W = msg.workers >= 2 && typeof Worker !== 'undefined' ? msg.workers : 0;
    if (pool && (pool.size !== W || pool.closed)) closePool(); // a pool whose helper stopped is closed: a fresh one
    if (W && !pool) {
        const url = helperScript = helperUrl(msg);
        pool = new TilePool(W, () => new Worker(url));
    }
    return pool;
}

function closePool() {
    pool.close();
    if (helperScript !== self.location.href) URL.revokeObjectURL(helperScript);
    pool = null;
}

// {warm: true, workers, source}: compile and instantiate the module, check the scale tables and start
// and warm the helpers now, before a stream arrives; answers {type: 'ready', helpers}
async function warm(msg) {
    wasm();
    const p = poolFor(msg);
    const helpers = p ? await p.warm() : 0;
    self.postMessage({ type: 'ready', helpers });
}

self.onmessage = async (e) => {
    if (e.data.init || e.data.job || e.data.prelude || e.data.forget) { await helperMessage(e.data, self); return; }
    if (e.data.box) { await decodeBox(e.data); return; }
    if (e.data.warm) { await warm(e.data); return; }
    const t0 = performance.now();
    const timeline = { start: clock(), tiles: [] }; // when each tile was decoded, by which thread (pool.mjs)
    marks.length = 0;
    let count = 0;
    const p = poolFor(e.data), warmed = !!(p && p.workers);
    const side = p ? p.stream({ keep: !!e.data.digest }) : null;
    const dec = new ProgressiveDecoder({
        pool: side,
        onTile: (t, tile, info) => {
            const arrays = tile.arrays || sceneArrays(info.ps, [tile]);
            if (tile.span) timeline.tiles.push({ t, points: tile.n, ...tile.span });
            delete tile.arrays;
            delete tile.span;
            count += tile.n;
            self.postMessage({ type: 'tile', t, tiles: info.tiles, count, arrays, ms: performance.now() - t0 }, arrayBuffers(arrays));
        },
    });
    try {
        for await (const chunk of chunksOf(e.data)) await dec.push(chunk);
        const r = await dec.finish();
        if (side) side.end();
        const digest = e.data.digest ? sceneDigestHex(r.ps, r.tiles) : null;
        const helpers = new Set(timeline.tiles.map((x) => x.thread).filter((th) => th !== 'worker')).size; // helpers that decoded tiles
        timeline.end = clock();
        timeline.marks = marks.splice(0);
        self.postMessage({ type: 'done', count, tiles: r.tiles.length, seconds: (performance.now() - t0) / 1000, digest, helpers, timeline });
    } catch (err) {
        // the helpers may still hold tiles of the rejected stream: a fresh pool for the next one (warmed if this one was)
        if (p) {
            closePool();
            if (warmed) poolFor(e.data).warm();
        }
        self.postMessage({ type: 'error', kind: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err), condition: err && err.condition });
    }
};
