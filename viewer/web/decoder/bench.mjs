#!/usr/bin/env node
// Decode speed of one stream: node bench.mjs STREAM [--repeat R]. Prints one JSON line:
// {count, seconds (best of R, the tables already loaded), stages (of the best run)}.
import { readFileSync } from 'node:fs';
import { decodeStream } from './decoder.mjs';
import { scaleTables } from './tables.mjs';

const args = process.argv.slice(2);
const repeat = args.includes('--repeat') ? Number(args[args.indexOf('--repeat') + 1]) : 3;
const bytes = new Uint8Array(readFileSync(args[0]));
scaleTables();
let best = Infinity, count = 0;
for (let i = 0; i < repeat; i++) {
    const t0 = performance.now();
    const r = await decodeStream(bytes);
    const s = (performance.now() - t0) / 1000;
    count = r.tiles.reduce((a, t) => a + t.n, 0);
    if (s < best) best = s;
}
console.log(JSON.stringify({ count, seconds: best, gaussiansPerSecond: count / best }));
