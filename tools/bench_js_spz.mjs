#!/usr/bin/env node
// lghcc's JavaScript decoder beside splat-transform's SPZ reader on the same scene, in one Node process,
// one thread (issue 54's target: decoded Gaussians per second, lghcc >= 1.5x SPZ):
//     node tools/bench_js_spz.mjs SCENE.lghcc SCENE.spz [--rounds R]
// Each round decodes both files whole, alternating which goes first (ABBA), after one warm-up round:
// lghcc with decodeStream (no helper threads: workers 0, every tile's hash checked, as a page decodes it),
// SPZ with splat-transform's readSpz materialized into its columns (readFile + materializeToDataTable,
// what its readers hand an engine). Times are wall-clock per decode (performance.now), best and median
// over the rounds. Prints one JSON line: {lghcc: {gaussians, bytes, bestS, medianS, gaussiansPerS},
// spz: {...}, ratio: lghcc Gaussians/s over SPZ's (best rounds)}.
import { readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';
import { decodeStream } from '../js/lghcc-decoder/decoder.mjs';
import '../js/lghcc-decoder/sha256_node.mjs'; // node:crypto's hash for the tiles' checks, as the package's Node entry uses

const here = dirname(fileURLToPath(import.meta.url));
// splat-transform pinned in tools/node (make node-tools): its ES module build
const st = await import(pathToFileURL(join(here, 'node', 'node_modules', '@playcanvas', 'splat-transform', 'dist',
    'index.mjs')).href);

const args = process.argv.slice(2);
const rounds = args.includes('--rounds') ? Number(args[args.indexOf('--rounds') + 1]) : 5;
const files = args.filter((a, i) => !a.startsWith('--') && args[i - 1] !== '--rounds');
if (files.length !== 2 || !files[0].endsWith('.lghcc') || !files[1].endsWith('.spz') || !(rounds >= 1)) {
    console.error('usage: node tools/bench_js_spz.mjs SCENE.lghcc SCENE.spz [--rounds R]');
    process.exit(2);
}
const lghccBytes = new Uint8Array(readFileSync(files[0]));
const spzBytes = new Uint8Array(readFileSync(files[1]));

async function decodeLghcc() {
    const r = await decodeStream(lghccBytes);
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

const runs = { lghcc: [], spz: [] };
const counts = { lghcc: await decodeLghcc(), spz: await decodeSpz() }; // the warm-up round
for (let i = 0; i < rounds; i++) {
    for (const k of i % 2 ? ['spz', 'lghcc'] : ['lghcc', 'spz']) {
        const t0 = performance.now();
        const n = k === 'lghcc' ? await decodeLghcc() : await decodeSpz();
        runs[k].push((performance.now() - t0) / 1000);
        if (n !== counts[k]) throw new Error(`${k}: ${n} Gaussians, ${counts[k]} in the warm-up`);
    }
}
const stats = (k, bytes) => {
    const s = [...runs[k]].sort((a, b) => a - b);
    return { gaussians: counts[k], bytes, bestS: s[0], medianS: s[s.length >> 1], gaussiansPerS: counts[k] / s[0] };
};
const out = { lghcc: stats('lghcc', lghccBytes.length), spz: stats('spz', spzBytes.length), rounds };
out.ratio = out.lghcc.gaussiansPerS / out.spz.gaussiansPerS;
console.log(JSON.stringify(out));
