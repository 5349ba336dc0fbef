#!/usr/bin/env node
// The JavaScript decoder as a long-lived process for the differential fuzzer
// (lghcc/conformance/differential.py): one Node start for a whole campaign instead of one per case.
//   node tools/js_decode_server.mjs [DECODER_DIR]     (default: js/lghcc-decoder; a mutated copy in tests)
// Reads requests from stdin, each framed as a 4-byte big-endian length, a JSON object
// {box: [x0, y0, z0, x1, y1, z1] | null, maxMemory: bytes, decoder?: DIR}, a 4-byte big-endian length, the
// stream. decoder: another copy of the decoder to decode this stream with (the differential fuzzer's copies
// with the checks of a condition removed), imported on its first request and kept loaded.
// Answers one JSON line per request on stdout, in order:
//   {outcome: 'decoded', hash, count, tiles}
//   {outcome: 'rejected', kind, message, condition}   a BitstreamError (UnsupportedStreamError, HashMismatchError);
//                                          condition: the row of clause 8.2 it names (null: none)
//   {outcome: 'resource', message}          a ResourceLimitError: this decoder's bound, no verdict
//   {outcome: 'crash', kind, message}       anything else (TypeError, a WebAssembly trap): a bug
// A hang is the caller's to detect (it kills this process after its timeout).
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

const here = dirname(fileURLToPath(import.meta.url));
const decoderDir = resolve(process.argv[2] || join(here, '..', 'js', 'lghcc-decoder'));
const decoders = new Map(); // folder -> its modules (each copy its own module instances, WebAssembly included)

async function load(dir) {
    if (!decoders.has(dir)) {
        const { decodeStream, sceneDigestHex } = await import(pathToFileURL(join(dir, 'decoder.mjs')).href);
        const { BitstreamError, ResourceLimitError } = await import(pathToFileURL(join(dir, 'errors.mjs')).href);
        decoders.set(dir, { decodeStream, sceneDigestHex, BitstreamError, ResourceLimitError });
    }
    return decoders.get(dir);
}
await load(decoderDir);

async function answer(options, bytes) {
    let d;
    try {
        d = await load(options.decoder ? resolve(options.decoder) : decoderDir);
    } catch (e) {
        return { outcome: 'crash', kind: 'LoadError', message: String(e && e.stack ? e.stack : e).slice(0, 1000) };
    }
    const { decodeStream, sceneDigestHex, BitstreamError, ResourceLimitError } = d;
    try {
        const r = await decodeStream(bytes, { box: options.box || null, maxMemory: options.maxMemory });
        const count = r.tiles.reduce((a, t) => a + t.n, 0);
        return { outcome: 'decoded', hash: sceneDigestHex(r.ps, r.tiles), count, tiles: r.tiles.length };
    } catch (e) {
        const kind = e && e.name ? e.name : typeof e;
        const message = String(e && e.message !== undefined ? e.message : e).slice(0, 300);
        if (e instanceof ResourceLimitError) return { outcome: 'resource', message };
        if (e instanceof BitstreamError) return { outcome: 'rejected', kind, message, condition: e.condition || null };
        return { outcome: 'crash', kind, message: String(e && e.stack ? e.stack : message).slice(0, 1000) };
    }
}

// frames from stdin: the buffered bytes are consumed as whole frames arrive; one request at a time
let pending = Buffer.alloc(0);
let busy = false;
async function drain() {
    if (busy) return;
    busy = true;
    for (;;) {
        if (pending.length < 4) break;
        const jsonLength = pending.readUInt32BE(0);
        if (pending.length < 8 + jsonLength) break;
        const dataLength = pending.readUInt32BE(4 + jsonLength);
        const end = 8 + jsonLength + dataLength;
        if (pending.length < end) break;
        const options = JSON.parse(pending.subarray(4, 4 + jsonLength).toString('utf8'));
        const bytes = new Uint8Array(pending.subarray(8 + jsonLength, end)); // a copy: the buffer is reused
        pending = pending.subarray(end);
        process.stdout.write(`${JSON.stringify(await answer(options, bytes))}\n`);
    }
    busy = false;
}
process.stdin.on('data', (chunk) => { pending = Buffer.concat([pending, chunk]); drain(); });
process.stdin.on('end', async () => { await drain(); });
process.stdout.write(`${JSON.stringify({ ready: decoderDir })}\n`);
