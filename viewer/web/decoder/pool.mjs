// Tiles decoded in parallel (clause 13.2: a tile's decoding needs only the prelude and its own
// units): a pool of Web Workers that run this same worker script. The decoding worker hands each
// complete tile to an idle helper ({job}); a helper parses the prelude once ({init}), decodes and
// hash-checks the tile and sends back the renderer's arrays (and, for a digest, the decoded tile).
import { decodeTile, preludeContext, sceneArrays } from './decoder.mjs';
import * as errors from './errors.mjs';
import { adoptScaleTables, scaleTables } from './tables.mjs';
import { parseGaussianParameterSet } from './units.mjs';
import { adoptWasmModule, wasmModule } from './wasm.mjs';

// a typed array that owns its whole buffer (a view into a larger one would clone all of it)
function own(a) { return a.byteOffset === 0 && a.byteLength === a.buffer.byteLength ? a : a.slice(); }

function arrayBuffers(arrays) { return [arrays.positions, arrays.sh, arrays.opacities, arrays.scales, arrays.rotations].map((a) => a.buffer); }

// the helper's error as the same class (the page reports the class name)
function remoteError({ name, message }) {
    const C = Object.prototype.hasOwnProperty.call(errors, name) ? errors[name] : Error;
    const e = new C(message);
    if (e.name !== name) Object.defineProperty(e, 'name', { value: name });
    return e;
}

/** Milliseconds since the epoch of the page's clock (comparable across workers: the timeline). */
export function clock() { return performance.timeOrigin + performance.now(); }

/** f()'s result (a promise of a decoded tile) with its span on the timeline: {thread, start, end}. */
export async function timed(thread, f) {
    const start = clock();
    const r = await f();
    return { ...r, span: { thread, start, end: clock() } };
}

const AHEAD = 2; // jobs a helper holds (one running, one waiting): it never waits for this thread between tiles

export class TilePool {
    /**
     * size helpers of the worker script at url; keep: helpers send the decoded tiles back (for a
     * digest). This thread decodes tile 0 (runHere: the first tile does not wait for a helper to
     * start) and otherwise only hands tiles out and takes results: a thread that decoded tiles
     * too would answer a helper only between its own tiles, and the helper would wait (round 7 of
     * tools/results/js_decoder.md). So W decoding threads are W helpers.
     */
    constructor(size, url, { keep = false } = {}) {
        this.size = size;
        this.url = url;
        this.keep = keep;
        this.dispatching = false;
        this.workers = null;
        this.queue = [];
    }

    /** The prelude is known (ctx.payloads): start the helpers, at most one per tile after the first (decoded here). */
    start(ctx) {
        if (this.workers) return;
        const p = ctx.payloads;
        // the module and the scale tables as this thread compiled and checked them: a helper neither compiles nor builds them again
        const init = { ps: own(p.ps), np: p.np && own(p.np), sa: p.sa && own(p.sa), sd: p.sd && own(p.sd), rl: p.rl && own(p.rl), module: wasmModule(), tables: scaleTables() };
        this.workers = Array.from({ length: Math.min(this.size, ctx.tiles.length - 1) }, (_, i) => {
            const w = new Worker(this.url);
            w.jobs = [];
            w.onmessage = (e) => this._done(w, e.data);
            w.onerror = (e) => { e.preventDefault(); this._failAll(w, `a decoding worker stopped: ${e.message}`); };
            w.postMessage({ init, helper: i + 1 });
            return w;
        });
    }

    /** Promise of tile t's result {n, arrays, x, y, z, values (with keep)}. */
    decode(ctx, t) {
        return new Promise((resolve, reject) => {
            this.queue.push({ ctx, t, resolve, reject });
            // handed out once the tiles that arrived together are all queued: the largest go first
            if (!this.dispatching) {
                this.dispatching = true;
                queueMicrotask(() => { this.dispatching = false; this._next(); });
            }
        });
    }

    /** Promise of f()'s result, run on this thread once it is free (after the jobs handed out so far are posted). */
    runHere(f) {
        return new Promise((res) => setTimeout(res, 0)).then(() => timed('worker', f));
    }

    // the queued tile with the most points: the last tiles to finish are small ones
    _take() {
        let b = 0;
        for (let i = 1; i < this.queue.length; i++) if (this.queue[i].ctx.tiles[this.queue[i].t].points > this.queue[b].ctx.tiles[this.queue[b].t].points) b = i;
        return this.queue.splice(b, 1)[0];
    }

    _next() {
        for (const w of this.workers || []) {
            while (w.jobs.length < AHEAD && this.queue.length) {
                const job = this._take();
                w.jobs.push(job);
                const tile = job.ctx.tiles[job.t];
                const units = tile.units.map((u) => ({ type: u.type, payload: u.payload.slice() }));
                w.postMessage({ job: { t: job.t, points: tile.points, cell: tile.cell, units, keep: this.keep } }, units.map((u) => u.payload.buffer));
            }
        }
    }

    _done(w, m) {
        const i = w.jobs.findIndex((j) => j.t === m.t);
        const { resolve, reject } = w.jobs.splice(i, 1)[0];
        if (m.error) reject(remoteError(m.error));
        else resolve({ ...m.tile, arrays: m.arrays });
        this._next();
    }

    _failAll(w, message) {
        for (const j of w.jobs.splice(0)) j.reject(remoteError({ name: 'Error', message }));
    }

    close() {
        for (const w of this.workers || []) w.terminate();
        this.workers = [];
    }
}

let helperCtx = null;
const helperLoaded = clock(); // this script evaluated (the timeline's helper start)

/** A helper's side: {init} (the prelude's payloads) once, then {job} per tile. */
export async function helperMessage(data) {
    if (data.init) {
        adoptWasmModule(data.init.module);
        adoptScaleTables(data.init.tables);
        const ps = parseGaussianParameterSet(data.init.ps);
        helperCtx = { ...preludeContext(ps, data.init), tiles: [], id: data.helper, ready: [helperLoaded, clock()] };
        return;
    }
    const { t, points, cell, units, keep } = data.job;
    try {
        helperCtx.tiles[t] = { units, points, cell };
        const r = await timed(`helper ${helperCtx.id}`, () => decodeTile(helperCtx, t));
        helperCtx.tiles[t] = null;
        const arrays = sceneArrays(helperCtx.ps, [r]);
        const transfer = arrayBuffers(arrays);
        let tile = { n: r.n, span: { ...r.span, ready: helperCtx.ready } };
        if (keep) {
            tile = { ...tile, x: own(r.x), y: own(r.y), z: own(r.z), values: own(r.values) };
            transfer.push(tile.x.buffer, tile.y.buffer, tile.z.buffer, tile.values.buffer);
        }
        self.postMessage({ t, tile, arrays }, transfer);
    } catch (err) {
        self.postMessage({ t, error: { name: err && err.name ? err.name : 'Error', message: String(err && err.message ? err.message : err) } });
    }
}

export { arrayBuffers };
