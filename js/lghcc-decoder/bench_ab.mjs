#!/usr/bin/env node
// Two decoders' per-thread speed on one stream, in one process: node bench_ab.mjs DIR_A DIR_B STREAM [--rounds R].
// DIR_A, DIR_B: the js/lghcc-decoder folders of two trees (e.g. a `git archive` of main and a branch). Every
// tile is decoded (without its hash check) by A and by B in turn, the order alternating (ABBA), and each decode's
// process CPU time summed over R rounds after one round of warm-up: the load of a shared machine falls on both
// alike, so A/B resolves a few per cent where separate runs scatter by tens (tools/results/js_decoder.md, round 10).
// Both trees' whole decodes must give the same scene digest. Prints one JSON line:
// {sameDigest, digest, tiles, cpuMsA, cpuMsB (per decode of the stream), ratio: A / B}.
import { readFileSync } from 'node:fs';
import { resolve } from 'node:path';
import { pathToFileURL } from 'node:url';

const args = process.argv.slice(2);
const rounds = args.includes('--rounds') ? Number(args[args.indexOf('--rounds') + 1]) : 3;
const [dirA, dirB, stream] = args;
if (!stream || !(rounds >= 1)) {
    console.error('usage: node bench_ab.mjs DIR_A DIR_B STREAM [--rounds R]');
    process.exit(2);
}
const trees = await Promise.all([dirA, dirB].map((d) => import(pathToFileURL(resolve(d, 'decoder.mjs')).href)));
const bytes = new Uint8Array(readFileSync(stream));
const digests = [];
for (const T of trees) {
    const r = await T.decodeStream(bytes); // also the warm-up round
    digests.push(T.sceneDigestHex(r.ps, r.tiles));
}
const ctx = trees.map((T) => T.parseStream(bytes));
const cpu = [0, 0], nt = ctx[0].tiles.length;
for (let i = 0; i < rounds; i++) {
    for (let t = 0; t < nt; t++) {
        for (const k of (i * nt + t) % 2 ? [1, 0] : [0, 1]) {
            const c0 = process.cpuUsage();
            await trees[k].decodeTile(ctx[k], t, { checkHash: false });
            const c = process.cpuUsage(c0);
            cpu[k] += c.user + c.system;
        }
    }
}
const ms = cpu.map((c) => c / rounds / 1000);
console.log(JSON.stringify({ sameDigest: digests[0] === digests[1], digest: digests[1], tiles: nt, cpuMsA: ms[0], cpuMsB: ms[1], ratio: ms[0] / ms[1] }));
process.exit(digests[0] === digests[1] ? 0 : 1);
