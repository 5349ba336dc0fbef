#!/usr/bin/env node
// The conformance of this decoder (the second implementation, spec clause 8.4): decodes every
// conformance stream of the explicit-Gaussian profile and checks the decoded scene's SHA-256
// against test.yaml (decoded_sha256 and the box partial decodes), and that every error stream
// of the profile is rejected (an error, never a hang, for the condition of clause 8.2 that an isolated stream names: each stream runs in a worker with a
// timeout, never a scene).
//   node js/lghcc-decoder/conformance.mjs [--streams DIR] [--timeout S] [--list] [ID ...]
// Exit status: 0 all passed, 1 a stream failed, 2 usage error.
import { readdirSync, readFileSync, existsSync } from 'node:fs';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { Worker } from 'node:worker_threads';
import { inProfile } from './profile.mjs';
import { parseTestYaml } from './yaml_subset.mjs';

const here = dirname(fileURLToPath(import.meta.url));
const REJECTIONS = new Set(['BitstreamError', 'UnsupportedStreamError', 'HashMismatchError']);
const args = process.argv.slice(2);
let root = join(here, '../../conformance/streams'), timeout = 60, list = false;
const ids = [];
for (let i = 0; i < args.length; i++) {
    if (args[i] === '--streams') root = args[++i];
    else if (args[i] === '--timeout') timeout = Number(args[++i]);
    else if (args[i] === '--list') list = true;
    else if (args[i].startsWith('-')) { console.error(`unknown option ${args[i]}`); process.exit(2); }
    else ids.push(args[i]);
}
if (!existsSync(root)) { console.error(`${root}: no conformance streams folder`); process.exit(2); }

/** The profile's cases: [{id, meta, bytes}], and the others with the reason. */
export function loadCases(dir, only = []) {
    const cases = [], skipped = [];
    for (const id of readdirSync(dir).sort()) {
        if (only.length && !only.includes(id)) continue;
        const yml = join(dir, id, 'test.yaml');
        if (!existsSync(yml)) continue;
        const meta = parseTestYaml(readFileSync(yml, 'utf8'));
        const bytes = new Uint8Array(readFileSync(join(dir, id, 'stream.lghcc')));
        const [yes, why] = inProfile(meta, bytes);
        (yes ? cases : skipped).push({ id, meta, bytes, why });
    }
    return { cases, skipped };
}

class Runner {
    constructor() { this.worker = null; }
    start() {
        this.worker = new Worker(join(here, 'conformance_worker.mjs'));
        this.worker.unref();
    }
    run(bytes, box) {
        if (!this.worker) this.start();
        return new Promise((resolve) => {
            const w = this.worker;
            const done = (m) => { clearTimeout(timer); w.off('message', onMessage); w.off('error', onError); resolve(m); };
            const onMessage = (m) => done(m);
            const onError = (e) => { this.worker = null; done({ crash: String(e) }); };
            const timer = setTimeout(() => { w.terminate(); this.worker = null; done({ timeout: true }); }, timeout * 1000);
            w.on('message', onMessage);
            w.on('error', onError);
            w.postMessage({ bytes, box });
        });
    }
    stop() { if (this.worker) this.worker.terminate(); }
}

async function check(runner, c) {
    const t0 = performance.now();
    const r = await runner.run(c.bytes, null);
    const notes = [];
    let ok;
    if (r.timeout) { ok = false; notes.push(`no result within ${timeout} s`); }
    else if (r.crash) { ok = false; notes.push(`worker crashed: ${r.crash}`); }
    else if (c.meta.expect === 'error') {
        ok = !!r.error && REJECTIONS.has(r.kind); // a TypeError or a resource limit is no verdict on the stream
        notes.push(r.error ? `rejected: ${r.kind} (${r.condition || 'no condition'}): ${r.error}` : 'decoded, expected a rejection');
        // a stream that breaks one condition alone (test.yaml condition: an isolated stream) is rejected for it
        if (ok && c.meta.condition && r.condition !== c.meta.condition) {
            ok = false;
            notes.push(`expected the rejection for ${c.meta.condition}, got ${r.condition || 'none'}`);
        }
    } else {
        ok = !r.error && r.hash === c.meta.decoded_sha256;
        notes.push(r.error ? `${r.kind}: ${r.error}` : ok ? `${r.count} Gaussians` : `hash ${r.hash} != ${c.meta.decoded_sha256}`);
        for (const p of Array.isArray(c.meta.partial_decodes) ? c.meta.partial_decodes : []) {
            if (p.level !== undefined) { // no stream of the profile has a level-1 preview (spec 13.3)
                notes.push('level-1 preview skipped: it needs the hierarchy, outside the profile');
                continue;
            }
            if (!Array.isArray(p.box)) continue;
            const pr = await runner.run(c.bytes, p.box);
            const pok = !pr.error && pr.hash === p.decoded_sha256 && pr.tiles === p.tiles_decoded;
            ok = ok && pok;
            notes.push(`box ${pok ? 'ok' : `FAIL (${pr.error || `${pr.hash}, ${pr.tiles} tiles`})`}`);
        }
    }
    return { ok, note: notes.join('; '), seconds: (performance.now() - t0) / 1000 };
}

async function main() {
    const { cases, skipped } = loadCases(root, ids);
    if (list) {
        for (const c of cases) console.log(`in   ${c.id} (${c.why})`);
        for (const c of skipped) console.log(`out  ${c.id} (${c.why})`);
        return 0;
    }
    const runner = new Runner();
    let failed = 0;
    for (const c of cases) {
        const r = await check(runner, c);
        if (!r.ok) failed++;
        console.log(`${r.ok ? 'PASS' : 'FAIL'} ${c.id} (${r.seconds.toFixed(2)} s): ${r.note}`);
    }
    runner.stop();
    const dec = cases.filter((c) => c.meta.expect !== 'error').length;
    console.log(`${cases.length - failed}/${cases.length} streams of the explicit-Gaussian profile passed ` +
        `(${dec} decode, ${cases.length - dec} error); ${skipped.length} streams outside the profile`);
    return failed ? 1 : 0;
}

if (process.argv[1] === fileURLToPath(import.meta.url)) process.exitCode = await main();
