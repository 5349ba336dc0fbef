#!/usr/bin/env node
// Peak memory of a decode in lghcc's JavaScript decoder against the arrays it hands over (issue 54's target: a
// decode's peak memory <= 1.3x the decoded arrays), beside splat-transform's SPZ reader on the same scene:
//     node tools/bench_js_memory.mjs SCENE.lghcc [SCENE.spz] [--workers 0,2] [--json]
// Each measurement runs in a child Node process of its own (Linux: it reads /proc/self/status), which imports the
// decoder, reads the file and collects garbage, then resets the kernel's peak-RSS mark (/proc/self/clear_refs) and
// decodes once: "decode peak" = the process's peak RSS during the decode less its RSS just before, so the runtime,
// the module and the input bytes are not counted, and every thread's memory is (the helper threads and their
// WebAssembly instances live in the process). "arrays" = the byteLength of the arrays handed over: lghcc's
// LghccScene (positions, scales, rotations, opacities, colours, SH; index.d.ts) or splat-transform's columns of its
// materialized DataTable. One line per measurement, a markdown table at the end (--json: JSON lines only).
import { spawnSync } from 'node:child_process';
import { readFileSync, writeFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath, pathToFileURL } from 'node:url';

const here = dirname(fileURLToPath(import.meta.url));
const MIB = 1024 * 1024;

function status(field) { // kB fields of /proc/self/status, in bytes
    const line = readFileSync('/proc/self/status', 'utf8').split('\n').find((l) => l.startsWith(`${field}:`));
    if (!line) throw new Error(`/proc/self/status has no ${field} (this tool needs Linux)`);
    return Number(line.split(/\s+/)[1]) * 1024;
}

async function child(kind, file, workers) {
    const bytes = new Uint8Array(readFileSync(file));
    let run;
    if (kind === 'lghcc') {
        const { decode } = await import(pathToFileURL(join(here, '..', 'js', 'lghcc-decoder', 'index_node.mjs')).href);
        run = async () => {
            const s = await decode(bytes, { workers });
            return { count: s.count, arrays: [s.positions, s.scales, s.rotations, s.opacities, s.colors, s.sh] };
        };
    } else {
        const st = await import(pathToFileURL(join(here, 'node', 'node_modules', '@playcanvas', 'splat-transform',
            'dist', 'index.mjs')).href);
        run = async () => {
            const fs = new st.MemoryReadFileSystem();
            fs.set('scene.spz', bytes);
            const [source] = await st.readFile({ filename: 'scene.spz', inputFormat: 'spz', options: {}, params: [],
                fileSystem: fs });
            const table = await st.materializeToDataTable(source, st.createChunkDataPool());
            if (source.close) source.close();
            return { count: table.numRows, arrays: table.columns.map((c) => c.data) };
        };
    }
    globalThis.gc();
    const rssBefore = status('VmRSS');
    writeFileSync('/proc/self/clear_refs', '5'); // the peak-RSS mark starts again from the RSS now
    const t0 = performance.now();
    const out = await run();
    const seconds = (performance.now() - t0) / 1000;
    const peak = status('VmHWM');
    const arraysBytes = out.arrays.reduce((a, x) => a + x.byteLength, 0);
    process.stdout.write(JSON.stringify({ kind, file, workers, count: out.count, seconds, rssBefore, peak,
        decodePeak: peak - rssBefore, arraysBytes, ratio: (peak - rssBefore) / arraysBytes }) + '\n');
    process.exit(0); // the helper threads end with the process
}

function usage(msg) {
    console.error(`${msg}\nusage: node tools/bench_js_memory.mjs SCENE.lghcc [SCENE.spz] [--workers 0,2] [--json]`);
    process.exit(2);
}

async function main() {
    const args = process.argv.slice(2);
    if (args[0] === '--child') return child(args[1], args[2], Number(args[3]));
    const opt = (name) => (args.includes(name) ? args[args.indexOf(name) + 1] : null);
    const workers = (opt('--workers') ?? '0,2').split(',').map(Number);
    if (workers.some((w) => !Number.isInteger(w) || w < 0)) usage(`--workers: integers >= 0, got ${opt('--workers')}`);
    const files = args.filter((a, i) => !a.startsWith('--') && args[i - 1] !== '--workers');
    const lghcc = files.find((f) => f.endsWith('.lghcc')), spz = files.find((f) => f.endsWith('.spz'));
    if (!lghcc || files.length > (spz ? 2 : 1)) usage('give one .lghcc stream and at most one .spz file');
    const runs = workers.map((w) => ['lghcc', lghcc, w]);
    if (spz) runs.push(['spz', spz, 0]);
    const rows = [];
    for (const [kind, file, w] of runs) {
        const r = spawnSync(process.execPath, ['--expose-gc', fileURLToPath(import.meta.url), '--child', kind, file,
            String(w)], { encoding: 'utf8', maxBuffer: 1 << 20 });
        if (r.status !== 0) {
            console.error(`${kind} ${file} (workers ${w}) failed with exit ${r.status}:\n${r.stderr}`);
            process.exit(1);
        }
        const row = JSON.parse(r.stdout.trim().split('\n').pop());
        rows.push(row);
        process.stdout.write(JSON.stringify(row) + '\n');
    }
    if (args.includes('--json')) return;
    console.log('\n| decoder | file | helper threads | Gaussians | decode s | RSS before MiB | peak RSS MiB | decode peak MiB | arrays MiB | decode peak / arrays |');
    console.log('|---|---|---:|---:|---:|---:|---:|---:|---:|---:|');
    for (const r of rows) {
        const m = (x) => (x / MIB).toFixed(1);
        console.log(`| ${r.kind === 'lghcc' ? 'lghcc-decoder' : 'splat-transform SPZ'} | ${r.file.split('/').pop()} | `
            + `${r.kind === 'lghcc' ? r.workers : '-'} | ${r.count.toLocaleString('en-US')} | ${r.seconds.toFixed(2)} | `
            + `${m(r.rssBefore)} | ${m(r.peak)} | ${m(r.decodePeak)} | ${m(r.arraysBytes)} | ${r.ratio.toFixed(2)} |`);
    }
}

await main();
