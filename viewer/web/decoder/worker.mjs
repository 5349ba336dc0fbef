// The decoder in a Web Worker: {bytes} (a Uint8Array) or {url} (fetched as a stream) in; out,
// as the bytes arrive: {type: 'tile', t, tiles, count, arrays} per decoded, hash-checked tile
// (positions, sh, opacities, scales, rotations: transferred typed arrays, no PLY), then
// {type: 'done', count, tiles, seconds, digest} once the whole stream passed every check, or
// {type: 'error', kind, message}.
import { ProgressiveDecoder, sceneArrays } from './progressive.mjs';
import { sceneDigestHex } from './decoder.mjs';

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

self.onmessage = async (e) => {
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
        self.postMessage({ type: 'error', kind: err && err.constructor ? err.constructor.name : 'Error', message: String(err && err.message ? err.message : err) });
    }
};
