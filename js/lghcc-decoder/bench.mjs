#!/usr/bin/env node
// Decode speed of one stream: node bench.mjs STREAM [--repeat R]. Prints one JSON line:
// {count, seconds (best of R, the tables already loaded), gaussiansPerSecond, first: the first decode's
// seconds (V8 still warming up: what a page that decodes once sees), cpuSeconds: the best decode's
// process CPU time (user + system; less noisy than wall time on a loaded machine)}.
import { readFileSync } from 'node:fs';
import { decodeStream } from './decoder.mjs';
import { scaleTables } from './tables.mjs';
import './sha256_node.mjs'; // node:crypto's hash for the tiles' checks

const args = process.argv.slice(2);
const repeat = args.includes('--repeat') ? Number(args[args.indexOf('--repeat') + 1]) : 3;
const bytes = new Uint8Array(readFileSync(args[0]));
scaleTables();
let best = Infinity, bestCpu = Infinity, first = 0, count = 0;
for (let i = 0; i < repeat; i++) {
    const c0 = process.cpuUsage(), t0 = performance.now();
    const r = await decodeStream(bytes);
    const s = (performance.now() - t0) / 1000, c = process.cpuUsage(c0);
    count = r.tiles.reduce((a, t) => a + t.n, 0);
    if (i === 0) first = s;
    best = Math.min(best, s);
    bestCpu = Math.min(bestCpu, (c.user + c.system) / 1e6);
}
console.log(JSON.stringify({ count, seconds: best, gaussiansPerSecond: count / best, first, cpuSeconds: bestCpu }));
