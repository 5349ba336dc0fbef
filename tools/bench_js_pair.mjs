#!/usr/bin/env node
// The JavaScript decoder's CPU time per Gaussian on two streams, in one process:
//     node tools/bench_js_pair.mjs STREAM_A STREAM_B [--rounds R]
// e.g. one scene coded with and without a coding tool (tools/results/sh_coding.md: the SH transform of
// format 1.6). Every tile of both streams is decoded (without its hash check) in turn, A and B
// alternating (ABBA), and each decode's process CPU time summed over R rounds after one round of
// warm-up (a whole decode of each, hash-checked), so that a shared machine's load falls on both alike
// (as js/lghcc-decoder/bench_ab.mjs does for two decoders on one stream). Prints one JSON line:
// {gaussiansA, gaussiansB, cpuNsPerGaussianA, cpuNsPerGaussianB, ratio: B / A per Gaussian}.
import { readFileSync } from 'node:fs';
import { decodeStream, decodeTile, parseStream } from '../js/lghcc-decoder/decoder.mjs';

const args = process.argv.slice(2);
const rounds = args.includes('--rounds') ? Number(args[args.indexOf('--rounds') + 1]) : 3;
const streams = args.filter((a, i) => !a.startsWith('--') && args[i - 1] !== '--rounds');
if (streams.length !== 2 || !(rounds >= 1)) {
    console.error('usage: node tools/bench_js_pair.mjs STREAM_A STREAM_B [--rounds R]');
    process.exit(2);
}
const bytes = streams.map((s) => new Uint8Array(readFileSync(s)));
const counts = [];
for (const b of bytes) {
    const r = await decodeStream(b); // the warm-up round, hash-checked
    counts.push(r.tiles.reduce((a, t) => a + t.n, 0));
}
const ctx = bytes.map((b) => parseStream(b));
const cpu = [0, 0];
for (let i = 0; i < rounds; i++) {
    for (const k of i % 2 ? [1, 0] : [0, 1]) {
        for (let t = 0; t < ctx[k].tiles.length; t++) {
            const c0 = process.cpuUsage();
            await decodeTile(ctx[k], t, { checkHash: false });
            const c = process.cpuUsage(c0);
            cpu[k] += c.user + c.system;
        }
    }
}
const ns = cpu.map((c, k) => (1000 * c) / rounds / counts[k]);
console.log(JSON.stringify({ gaussiansA: counts[0], gaussiansB: counts[1], cpuNsPerGaussianA: ns[0], cpuNsPerGaussianB: ns[1],
    ratio: ns[1] / ns[0] }));
