// The decoder in a Web Worker: {bytes} (a Uint8Array) or {url} (fetched as a stream) in; out,
// as the bytes arrive: {type: 'tile', t, tiles, count, arrays} per decoded, hash-checked tile
// (positions, sh, opacities, scales, rotations: transferred typed arrays, no PLY), then
// {type: 'done', count, tiles, seconds, digest} once the whole stream passed every check, or
// {type: 'error', kind, message}. With {digest: true} 'done' carries the decoded scene's SHA-256
// (clause 12); with {bytes, box} only the tiles the box selects are decoded.
import { ProgressiveDecoder, sceneArrays } from './progressive.mjs';
import { decodeStream, sceneDigestHex } from './decoder.mjs';

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
        self.postMessage({ type: 'error', kind: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err) });
    }
}

self.onmessage = async (e) => {
    if (e.data.box) { await decodeBox(e.data); return; }
    const t0 = performance.now();
    let count = 0;
    const dec = new ProgressiveDecoder({
        onTile: (t, tile, info) => {
            const arrays = sceneArrays(info.ps, [tile]);
            count += tile.n;
            self.postMessage({ type: 'tile', t, tiles: info.tiles, count, arrays, ms: performance.now() - t0 },
                [arrays.positions.buffer, arrays.sh.buffer, arrays.opacities.buffer, arrays.scales.buffer, arrays.rotations.buffer]);
        },
    });
    try {
        for await (const chunk of chunksOf(e.data)) await dec.push(chunk);
        const r = await dec.finish();
        const digest = e.data.digest ? sceneDigestHex(r.ps, r.tiles) : null;
        self.postMessage({ type: 'done', count, tiles: r.tiles.length, seconds: (performance.now() - t0) / 1000, digest });
    } catch (err) {
        self.postMessage({ type: 'error', kind: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err) });
    }
};
