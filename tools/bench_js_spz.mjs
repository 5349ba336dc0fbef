#!/usr/bin/env node
// lghcc's JavaScript decoder beside splat-transform's SPZ reader on the same scene, in one Node process,
// one thread (issue 54's target: decoded Gaussians per second, lghcc >= 1.5x SPZ):
//     node tools/bench_js_spz.mjs SCENE.lghcc SCENE.spz [--rounds R] [--baseline TREE] [--also OTHER.lghcc ...]
// Each round decodes both files whole, the order alternating (ABBA; with a baseline the three rotate),
// after one warm-up round: lghcc with decodeStream (no helper threads: workers 0, every tile's hash checked,
// with node:crypto as the package's Node entry hashes), SPZ with splat-transform's readSpz materialized into
// its columns (readFile + materializeToDataTable, what its readers hand an engine). --baseline TREE: the
// decoder of another tree (a checkout or `git archive` of main, its js/lghcc-decoder) decodes the stream
// too, in the same rotation: before/after in one process, the load falling on both alike. --also OTHER.lghcc
// (repeatable): another stream of the same scene (e.g. coded with other encoder settings) decoded by this tree's
// decoder in the same rotation: what a setting gains in decode speed, against the same SPZ decodes. Times are
// wall-clock per decode (performance.now) and the process's CPU time (user + system, every thread: SPZ's
// DecompressionStream and Web Crypto's hash run in Node's thread pool), best and median over the rounds.
// Prints one JSON line: {lghcc: {gaussians, bytes, bestS, medianS, bestCpuS, medianCpuS, gaussiansPerS},
// spz: {...}, ratio: lghcc Gaussians/s over SPZ's (best rounds), cpuRatio: the same per CPU second; with
// --baseline also baseline: {...}, baselineRatio, speedup: lghcc's Gaussians/s over the baseline's; with --also,
// also: {OTHER: {...stats, ratio, cpuRatio, speedup, cpuSpeedup}}, speedups over the first stream}.
import { existsSync, readFileSync } from 'node:fs';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';
import { decodeStream } from '../js/lghcc-decoder/decoder.mjs';
import '../js/lghcc-decoder/sha256_node.mjs'; // node:crypto's hash for the tiles' checks, as the package's Node entry uses

const here = dirname(fileURLToPath(import.meta.url));
// splat-transform pinned in tools/node (make node-tools): its ES module build
const st = await import(pathToFileURL(join(here, 'node', 'node_modules', '@playcanvas', 'splat-transform', 'dist',
    'index.mjs')).href);

const args = process.argv.slice(2);
const opt = (name) => (args.includes(name) ? args[args.indexOf(name) + 1] : null);
const rounds = opt('--rounds') ? Number(opt('--rounds')) : 5;
const baselineTree = opt('--baseline');
const alsoFiles = args.filter((a, i) => args[i - 1] === '--also');
const files = args.filter((a, i) => !a.startsWith('--') && !['--rounds', '--baseline', '--also'].includes(args[i - 1]));
if (files.length !== 2 || !files[0].endsWith('.lghcc') || !files[1].endsWith('.spz') || !(rounds >= 1)) {
    console.error('usage: node tools/bench_js_spz.mjs SCENE.lghcc SCENE.spz [--rounds R] [--baseline TREE] [--also OTHER.lghcc ...]');
    process.exit(2);
}
// the baseline tree's decoder (and its node:crypto hash where that tree has one: older trees hash with Web Crypto)
let baseline = null;
if (baselineTree) {
    const dir = join(baselineTree, 'js', 'lghcc-decoder');
    if (!existsSync(join(dir, 'decoder.mjs'))) {
        console.error(`--baseline ${baselineTree}: no js/lghcc-decoder/decoder.mjs in that tree`);
        process.exit(2);
    }
    baseline = await import(pathToFileURL(resolve(dir, 'decoder.mjs')).href);
    if (existsSync(join(dir, 'sha256_node.mjs'))) await import(pathToFileURL(resolve(dir, 'sha256_node.mjs')).href);
}
const lghccBytes = new Uint8Array(readFileSync(files[0]));
const spzBytes = new Uint8Array(readFileSync(files[1]));

if (alsoFiles.some((f) => !f.endsWith('.lghcc'))) {
    console.error(`--also takes .lghcc streams, got ${alsoFiles.filter((f) => !f.endsWith('.lghcc')).join(', ')}`);
    process.exit(2);
}
const alsoBytes = alsoFiles.map((f) => new Uint8Array(readFileSync(f)));

async function decodeLghcc(decoder = decodeStream, bytes = lghccBytes) {
    const r = await decoder(bytes);
    return r.tiles.reduce((a, t) => a + t.n, 0);
}

async function decodeSpz() {
    const fs = new st.MemoryReadFileSystem();
    fs.set('scene.spz', spzBytes);
    const [source] = await st.readFile({ filename: 'scene.spz', inputFormat: 'spz', options: {}, params: [], fileSystem: fs });
    const table = await st.materializeToDataTable(source, st.createChunkDataPool());
    if (source.close) source.close();
    return table.numRows;
}

const decoders = { lghcc: () => decodeLghcc(), spz: decodeSpz };
if (baseline) decoders.baseline = () => decodeLghcc(baseline.decodeStream);
alsoFiles.forEach((f, i) => { decoders[`also:${f}`] = () => decodeLghcc(decodeStream, alsoBytes[i]); });
const keys = Object.keys(decoders), runs = {}, cpu = {}, counts = {};
for (const k of keys) { counts[k] = await decoders[k](); runs[k] = []; cpu[k] = []; } // the warm-up round
for (let i = 0; i < rounds; i++) {
    const order = keys.map((_, j) => keys[(i + j) % keys.length]); // each decoder first in turn
    if (i % 2) order.reverse();
    for (const k of order) {
        const c0 = process.cpuUsage(), t0 = performance.now();
        const n = await decoders[k]();
        runs[k].push((performance.now() - t0) / 1000);
        const c = process.cpuUsage(c0);
        cpu[k].push((c.user + c.system) / 1e6);
        if (n !== counts[k]) throw new Error(`${k}: ${n} Gaussians, ${counts[k]} in the warm-up`);
    }
}
const sorted = (a) => [...a].sort((x, y) => x - y);
const stats = (k, bytes) => {
    const s = sorted(runs[k]), c = sorted(cpu[k]);
    return { gaussians: counts[k], bytes, bestS: s[0], medianS: s[s.length >> 1], bestCpuS: c[0], medianCpuS: c[c.length >> 1], gaussiansPerS: counts[k] / s[0] };
};
const out = { lghcc: stats('lghcc', lghccBytes.length), spz: stats('spz', spzBytes.length), rounds };
const perCpu = (r) => r.gaussians / r.bestCpuS;
out.ratio = out.lghcc.gaussiansPerS / out.spz.gaussiansPerS;
out.cpuRatio = perCpu(out.lghcc) / perCpu(out.spz);
if (baseline) {
    out.baseline = stats('baseline', lghccBytes.length);
    out.baselineRatio = out.baseline.gaussiansPerS / out.spz.gaussiansPerS;
    out.speedup = out.lghcc.gaussiansPerS / out.baseline.gaussiansPerS;
    out.cpuSpeedup = perCpu(out.lghcc) / perCpu(out.baseline);
}
if (alsoFiles.length) {
    out.also = {};
    alsoFiles.forEach((f, i) => {
        const r = stats(`also:${f}`, alsoBytes[i].length);
        out.also[f] = { ...r, ratio: r.gaussiansPerS / out.spz.gaussiansPerS, cpuRatio: perCpu(r) / perCpu(out.spz),
            speedup: r.gaussiansPerS / out.lghcc.gaussiansPerS, cpuSpeedup: perCpu(r) / perCpu(out.lghcc) };
    });
}
console.log(JSON.stringify(out));
