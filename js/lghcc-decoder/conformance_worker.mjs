// The worker of conformance.mjs: decodes one stream per message, answers {hash, count, tiles} or {error, kind, condition}.
import { parentPort } from 'node:worker_threads';
import { decodeStream, sceneDigestHex } from './decoder.mjs';
import './sha256_node.mjs'; // node:crypto's hash for the tiles' checks

parentPort.on('message', async ({ bytes, box }) => {
    try {
        const r = await decodeStream(bytes, { box });
        const count = r.tiles.reduce((a, t) => a + t.n, 0);
        parentPort.postMessage({ hash: sceneDigestHex(r.ps, r.tiles), count, tiles: r.tiles.length });
    } catch (e) {
        const kind = e && e.name ? e.name : 'Error';
        parentPort.postMessage({ error: e && e.message ? e.message : String(e), kind, condition: e && e.condition, stack: kind === 'Error' || kind === 'TypeError' || kind === 'RangeError' ? e.stack : undefined });
    }
});
