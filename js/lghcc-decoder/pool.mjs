// Tiles decoded in parallel (clause 13.2: a tile's decoding needs only the prelude and its own
// units): a pool of Web Workers that run this same worker script. The pool is started and warmed
// once ({init}: the compiled module and the checked scale tables; each helper instantiates the
// module and answers {ready}), before a stream arrives where the page asks for it ({warm} to the
// worker), and kept for the streams that follow. Per stream the helpers get its prelude's payloads
// ({prelude}), then the decoding worker hands each complete tile to a helper ({job}); a helper
// decodes it, says so ({decoded}: its next job is sent then, while this tile's hash is computed off
// its thread), hash-checks it and sends back the renderer's arrays (and, for a digest, the decoded tile).
import { checkTileHash, decodeTile, preludeContext, tileSceneArrays } from './decoder.mjs';
import * as errors from './errors.mjs';
import { adoptScaleTables, scaleTables } from './tables.mjs';
import { parseGaussianParameterSet } from './units.mjs';
import { adoptWasmModule, wasm, wasmModule } from './wasm.mjs';

// a typed array that owns its whole buffer (a view into a larger one would clone all of it)
function own(a) { return a.byteOffset === 0 && a.byteLength === a.buffer.byteLength ? a : a.slice(); }

function arrayBuffers(arrays) { return [arrays.positions, arrays.sh, arrays.opacities, arrays.scales, arrays.rotations].map((a) => a.buffer); }

// the helper's error as the same class (the page reports the class name)
function remoteError({ name, message, condition }) {
    const C = Object.prototype.hasOwnProperty.call(errors, name) ? errors[name] : Error;
    const e = new C(message, condition);
    if (e.name !== name) Object.defineProperty(e, 'name', { value: name });
    return e;
}

/** Milliseconds since the epoch of the page's clock (comparable across workers: the timeline). */
export function clock() { return performance.timeOrigin + performance.now(); }

/** The decoding worker's steps on the timeline ([what, clock()]; worker.mjs takes them per stream). */
export const marks = [];
export function mark(what) { if (marks.length < 1000) marks.push([what, clock()]); }

/** f()'s result (a promise of a decoded tile) with its span on the timeline: {thread, start, end}. */
export async function timed(thread, f) {
    const start = clock();
    const r = await f();
    return { ...r, span: { thread, start, end: clock() } };
}

// tiles a helper holds not yet decoded: two (one running, one waiting: it never waits for this thread
// between tiles) while the queue is long, one at the end (the next comes when it says it decoded the
// last, while it hashes that one and makes its arrays), so that the helpers finish together
const AHEAD = 2;

export class TilePool {
    /**
     * size helpers, each started by startHelper(). The decoding thread decodes no tile itself: it hands
     * tiles out and takes results, so it answers a helper at once, and it leaves the helpers' start
     * alone (Chromium starts a nested worker through its parent's thread: a parent busy decoding
     * held its helpers back by that long, round 9 of tools/results/js_decoder.md).
     */
    constructor(size, startHelper) {
        this.size = size;
        this.startHelper = startHelper; // () => a Worker (or an object with its postMessage, onmessage, onerror, terminate) running helperMessage
        this.dispatching = false;
        this.workers = null;
        this.ready = null; // promise: every helper has instantiated the module
        this.queue = [];
        this.streams = 0;
    }

    /** Start the helpers and send them the module and the scale tables (once); returns the promise of their being ready. */
    warm() {
        if (this.workers) return this.ready;
        // the module and the scale tables as this thread compiled and checked them: a helper neither compiles nor builds them again
        const init = { module: wasmModule(), tables: scaleTables() };
        let left = this.size;
        this.ready = new Promise((resolve) => { this._ready = () => { if (--left === 0) resolve(this.workers.length); }; });
        this.workers = Array.from({ length: this.size }, (_, i) => {
            const w = this.startHelper();
            w.jobs = [];
            w.onmessage = (e) => this._message(w, e.data);
            w.onerror = (e) => {
                e.preventDefault();
                if (!w.ready) this._message(w, { ready: true }); // 'ready' answered all the same; its tiles fail
                this._failAll(w, `a decoding worker stopped: ${e.message}`);
                this.close(); // no tile is handed to a stopped helper: every stream on the pool fails now, none waits
            };
            w.postMessage({ init, helper: i + 1 });
            return w;
        });
        return this.ready;
    }

    /**
     * A stream's side of the pool (the pool warmed first if it was not): {start(ctx): its prelude
     * known, decode(ctx, t): promise of tile t's result {n, arrays, span, x, y, z, values (with
     * keep)}, handed out at the next flush() or microtask, end(): the stream decoded}. keep: helpers send the decoded tiles back (for a digest).
     */
    stream({ keep = false } = {}) {
        const id = ++this.streams;
        let started = false;
        return {
            start: (ctx) => {
                if (started) return;
                started = true;
                this.warm();
                const p = ctx.payloads;
                const prelude = { id, ps: own(p.ps), np: p.np && own(p.np), sa: p.sa && own(p.sa), sf: p.sf && own(p.sf), sd: p.sd && own(p.sd), rl: p.rl && own(p.rl), st: p.st && own(p.st) };
                for (const w of this.workers) w.postMessage({ prelude });
            },
            decode: (ctx, t) => new Promise((resolve, reject) => {
                this.queue.push({ id, ctx, t, keep, resolve, reject });
                // handed out once the tiles that arrived together are all queued: the largest go first
                if (!this.dispatching) {
                    this.dispatching = true;
                    queueMicrotask(() => { this.dispatching = false; this._next(); });
                }
            }),
            flush: () => this._next(), // hand out the queued tiles now
            end: () => {
                this.queue = this.queue.filter((j) => j.id !== id);
                if (started) for (const w of this.workers) w.postMessage({ forget: id });
            },
        };
    }

    // the queued tile a stream ranks first (ctx.rank: stream.mjs's nearest-first order), else the one
    // with the most points: the last tiles to finish are small ones
    _take() {
        const key = (j) => (j.ctx.rank ? -j.ctx.rank.get(j.t) : j.ctx.tiles[j.t].points);
        let b = 0;
        for (let i = 1; i < this.queue.length; i++) if (key(this.queue[i]) > key(this.queue[b])) b = i;
        return this.queue.splice(b, 1)[0];
    }

    _next() {
        if (this.queue.length) mark(`dispatch ${this.queue.length}`);
        for (const w of this.workers || []) {
            while (w.jobs.filter((j) => !j.decoded).length < (this.queue.length > AHEAD * this.workers.length ? AHEAD : 1) && this.queue.length) {
                const job = this._take();
                w.jobs.push(job);
                const tile = job.ctx.tiles[job.t];
                // the payloads moved, not copied (the progressive decoder's units own their bytes; a view is copied)
                const units = tile.units.map((u) => ({ type: u.type, payload: own(u.payload) }));
                w.postMessage({ job: { id: job.id, t: job.t, points: tile.points, cell: tile.cell, units, keep: job.keep } }, units.map((u) => u.payload.buffer));
            }
        }
    }

    _message(w, m) {
        if (m.ready) { if (!w.ready) { w.ready = true; this._ready(); } return; }
        const i = w.jobs.findIndex((j) => j.t === m.t && j.id === m.id);
        if (i < 0) return; // a job rejected already: its pool closed while the helper's answer was on its way
        if (m.decoded) { w.jobs[i].decoded = true; this._next(); return; }
        const { resolve, reject } = w.jobs.splice(i, 1)[0];
        if (m.error) reject(remoteError(m.error));
        else resolve({ ...m.tile, arrays: m.arrays });
        this._next();
    }

    _failAll(w, message) {
        for (const j of w.jobs.splice(0)) j.reject(remoteError({ name: 'Error', message }));
    }

    /** Stop the helpers; every tile still queued or held by a helper (of any stream) is rejected, none waits forever. */
    close() {
        const message = 'the decoding pool was closed';
        for (const w of this.workers || []) {
            w.terminate();
            this._failAll(w, message);
        }
        this.workers = [];
        this.closed = true;
        for (const j of this.queue.splice(0)) j.reject(remoteError({ name: 'Error', message }));
    }
}

const helper = { id: 0, ready: null, streams: new Map() };
const helperLoaded = clock(); // this script evaluated (the timeline's helper start)

/**
 * A helper's side: {init} once, {prelude} and {forget} per stream, {job} per tile; answers through
 * port.postMessage(message, transfer) (a Web Worker's self, or Node's parentPort).
 */
export async function helperMessage(data, port) {
    if (data.init) {
        adoptWasmModule(data.init.module);
        adoptScaleTables(data.init.tables);
        wasm(); // instantiated now, before a stream arrives
        helper.id = data.helper;
        helper.ready = [helperLoaded, clock()];
        port.postMessage({ ready: true });
        return;
    }
    if (data.prelude) {
        const p = data.prelude;
        helper.streams.set(p.id, { ...preludeContext(parseGaussianParameterSet(p.ps), p), tiles: [] });
        return;
    }
    if (data.forget) { helper.streams.delete(data.forget); return; }
    const { id, t, points, cell, units, keep } = data.job;
    try {
        const ctx = helper.streams.get(id);
        ctx.tiles[t] = { units, points, cell };
        const start = clock();
        const r = await decodeTile(ctx, t, { checkHash: false, digest: true, arrays: true });
        ctx.tiles[t] = null;
        port.postMessage({ id, t, decoded: true }); // the next tile may come while this one is hash-checked
        const hashed = checkTileHash(ctx, t, r); // the digest was started by decodeTile (Web Crypto: off this thread)
        hashed.catch(() => {}); // awaited below
        const arrays = tileSceneArrays(ctx.ps, r);
        const decoded = clock();
        await hashed;
        const transfer = arrayBuffers(arrays);
        let tile = { n: r.n, span: { thread: `helper ${helper.id}`, start, end: clock(), decoded, ready: helper.ready } };
        if (keep) {
            tile = { ...tile, x: own(r.x), y: own(r.y), z: own(r.z), values: own(r.values) };
            transfer.push(tile.x.buffer, tile.y.buffer, tile.z.buffer, tile.values.buffer);
        }
        port.postMessage({ id, t, tile, arrays }, transfer);
    } catch (err) {
        port.postMessage({ id, t, error: { name: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err), condition: err && err.condition } });
    }
}

export { arrayBuffers };
