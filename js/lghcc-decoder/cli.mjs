#!/usr/bin/env node
// Decode an lghcc stream of the explicit-Gaussian profile and print the decoded scene's SHA-256
// (spec clause 12), following the exit-status protocol of lghcc-conformance --decoder-cmd:
// 0 decoded (last stdout line: the hash), 3 rejected (non-conforming or outside the profile
// is reported as 3 too, with the reason on stderr), 1 input error, 2 usage, 4 resource limit.
//   node js/lghcc-decoder/cli.mjs STREAM [--box=X0,Y0,Z0,X1,Y1,Z1] [--level 1] [--max-memory BYTES]
import { readFileSync } from 'node:fs';
import { decodeStream, sceneDigestHex } from './decoder.mjs';
import { BitstreamError, ResourceLimitError } from './errors.mjs';
import './sha256_node.mjs'; // node:crypto's hash for the tiles' checks

function usage(msg) {
    process.stderr.write(`cli.mjs: ${msg}\nusage: node cli.mjs STREAM [--box=X0,Y0,Z0,X1,Y1,Z1] [--level 1] [--max-memory BYTES]\n`);
    process.exit(2);
}

const args = process.argv.slice(2);
let stream = null, box = null, maxMemory;
for (let i = 0; i < args.length; i++) {
    const a = args[i];
    if (a.startsWith('--box=')) {
        box = a.slice(6).split(',').map(Number);
        if (box.length !== 6 || box.some((v) => !Number.isFinite(v))) usage(`--box needs six numbers, got ${a.slice(6)}`);
    } else if (a === '--level') {
        if (args[++i] !== '1') usage('--level takes 1 (the level-1 preview)');
        // without the hierarchy (this profile) the level-1 preview is the full decode (clause 13.3)
    } else if (a === '--max-memory') {
        maxMemory = Number(args[++i]);
        if (!(maxMemory > 0)) usage('--max-memory needs a positive number of bytes');
    } else if (a.startsWith('-')) usage(`unknown option ${a}`);
    else if (stream === null) stream = a;
    else usage('one stream only');
}
if (stream === null) usage('no stream given');
let bytes;
try {
    bytes = new Uint8Array(readFileSync(stream));
} catch (e) {
    process.stderr.write(`cli.mjs: cannot read ${stream}: ${e.message}\n`);
    process.exit(1);
}
try {
    const r = await decodeStream(bytes, { box, maxMemory });
    process.stdout.write(`${sceneDigestHex(r.ps, r.tiles)}\n`);
    process.exit(0);
} catch (e) {
    if (e instanceof ResourceLimitError) { process.stderr.write(`resource limit: ${e.message}\n`); process.exit(4); }
    if (e instanceof BitstreamError) { process.stderr.write(`${e.name}: ${e.message}\n`); process.exit(3); }
    process.stderr.write(`internal error: ${e.stack}\n`);
    process.exit(1);
}
