// The heart of lghcc-decoder's public API (index.mjs in browsers, index_node.mjs in Node, which
// give it their helper threads): decode a .lghcc stream of the explicit-Gaussian profile into the
// typed arrays splat renderers take (README.md). The decoding thread (the caller's) reads the bytes,
// checks every unit's CRC-32 and hands each tile, as soon as its bytes are in, to a pool of helper
// threads (pool.mjs; module Web Workers, or worker_threads under Node), which decode it and check
// its hash; the arrays are assembled in stream order.
import { DEFAULT_MAX_MEMORY, sceneArrays, tilesInBox } from './decoder.mjs';
import { BitstreamError } from './errors.mjs';
import { TilePool } from './pool.mjs';
import { ProgressiveDecoder } from './progressive.mjs';
import { loadWasm } from './wasm.mjs';

/** The zeroth-order SH basis constant: colour = 0.5 + SH_C0 * DC (the 3DGS convention). */
export const SH_C0 = 0.28209479177387814;

/**
 * Decode a .lghcc stream, with threads ({defaultWorkers(), startHelper()}: threads_browser.mjs or
 * threads_node.mjs) as the helpers. input: Uint8Array (or any ArrayBufferView), ArrayBuffer, Blob, Response,
 * ReadableStream of Uint8Array, or a URL (string or URL object, fetched). Resolves to the scene once
 * every byte passed every check of the format (README.md: the fields and their layout); rejects
 * with BitstreamError (or its subclasses) for a non-conforming stream, ResourceLimitError beyond
 * maxMemory, signal.reason when aborted.
 */
export async function decodeWith(threads, input, options = {}) {
    const o = decodeOptions(threads, options);
    if (o.signal) o.signal.throwIfAborted();
    return decodeChunks(threads, byteChunks(input, o.signal), o);
}

/** decode()'s options with their defaults (README.md), checked (TypeError). */
export function decodeOptions(threads, options) {
    const { workers = threads.defaultWorkers(), onProgress = null, signal = null, box = null, maxMemory = DEFAULT_MAX_MEMORY, activated = false } = options;
    checkOptions({ workers, onProgress, signal, box, maxMemory });
    return { workers, onProgress, signal, box, maxMemory, activated };
}

/**
 * decodeWith's decode of the stream's bytes as reading (an async iterator of Uint8Array chunks)
 * gives them; o: decodeOptions(). select(ctx), onTile(view): SceneAssembly's; pool: a PoolSide already
 * warming (stream.mjs's whole-file read).
 */
export async function decodeChunks(threads, reading, o, { select = null, onTile = null, pool: warmed = null } = {}) {
    const { workers, onProgress, signal, box, maxMemory, activated } = o;
    const pool = warmed || (workers >= 1 ? new PoolSide(workers, threads.startHelper) : null);
    const scene = new SceneAssembly(box, activated, onProgress, { select, onTile });
    const onDecoded = (t, tile, info) => {
        if (signal && signal.aborted) throw signal.reason; // stops a decode on this thread at its next tile
        scene.add(t, tile, info);
        // the scene's arrays hold the tile now: its decoded coordinates and values are not kept to the end
        tile.x = tile.y = tile.z = tile.values = null;
    };
    const dec = new ProgressiveDecoder({ maxMemory, box, select, pool, minPoolTiles: 1, onTile: onDecoded });
    const run = (async () => {
        await loadWasm(); // compiled asynchronously: a browser's main thread may not compile it synchronously
        for await (const chunk of reading) await dec.push(chunk);
        const r = await dec.finish();
        return scene.result(r);
    })();
    return settle(run, signal, () => {
        if (pool) pool.close();
        reading.return().catch(() => {}); // stops a fetch or stream still being read
    });
}

/** run's result, or signal.reason at an abort (run is left to fail alone); cleanup() after either. */
export async function settle(run, signal, cleanup) {
    run.catch(() => {}); // after an abort nobody awaits it; its rejection is the abort's
    const abort = signal ? aborted(signal) : null;
    try {
        return await (abort ? Promise.race([run, abort.promise]) : run);
    } finally {
        if (abort) abort.forget();
        cleanup();
    }
}

export function checkOptions({ workers, onProgress, signal, box, maxMemory }) {
    if (!(Number.isInteger(workers) && workers >= 0)) throw new TypeError(`workers: a whole number of helper threads (0: decode on this thread), got ${workers}`);
    if (onProgress !== null && typeof onProgress !== 'function') throw new TypeError('onProgress: a function');
    if (signal !== null && !(typeof signal === 'object' && typeof signal.aborted === 'boolean' && typeof signal.addEventListener === 'function')) {
        throw new TypeError('signal: an AbortSignal');
    }
    if (box !== null && !(Array.isArray(box) && box.length === 6 && box.every(Number.isFinite))) {
        throw new TypeError('box: [x0, y0, z0, x1, y1, z1], six finite numbers in world coordinates');
    }
    if (!(maxMemory > 0)) throw new TypeError(`maxMemory: a positive number of bytes, got ${maxMemory}`);
}

// {promise: rejected with signal.reason at the abort, forget(): stop listening (a signal may outlive many decodes)}
export function aborted(signal) {
    let listener = null;
    const promise = new Promise((_, reject) => {
        listener = () => reject(signal.reason);
        signal.addEventListener('abort', listener, { once: true });
    });
    return { promise, forget: () => signal.removeEventListener('abort', listener) };
}

/** The input's bytes as they arrive: one chunk for bytes in memory, the body's chunks for a stream or a URL. */
export async function* byteChunks(input, signal) {
    if (input instanceof Uint8Array) { yield input; return; }
    if (input instanceof ArrayBuffer) { yield new Uint8Array(input); return; }
    if (ArrayBuffer.isView(input)) { yield new Uint8Array(input.buffer, input.byteOffset, input.byteLength); return; }
    let stream;
    if (typeof input === 'string' || input instanceof URL) {
        const res = await fetch(input, { signal });
        if (!res.ok) throw new Error(`${input}: HTTP ${res.status} ${res.statusText}`.trim());
        stream = res.body;
    } else if (typeof Response !== 'undefined' && input instanceof Response) {
        if (!input.ok) throw new Error(`${input.url || 'the response'}: HTTP ${input.status} ${input.statusText}`.trim());
        stream = input.body;
    } else if (typeof Blob !== 'undefined' && input instanceof Blob) {
        stream = input.stream();
    } else if (input && typeof input.getReader === 'function') {
        stream = input;
    } else {
        throw new TypeError('decode: input is a Uint8Array, ArrayBuffer, Blob, Response, ReadableStream or URL');
    }
    if (!stream) throw new BitstreamError('the response has no body: an empty stream', 'E1');
    const reader = stream.getReader();
    // an abort cancels the read under way (a stream the caller made knows nothing of the signal)
    const stop = () => { reader.cancel(signal.reason).catch(() => {}); };
    if (signal) signal.addEventListener('abort', stop, { once: true });
    try {
        for (;;) {
            const { value, done } = await reader.read();
            if (done) return;
            if (!(value instanceof Uint8Array)) throw new TypeError('decode: the ReadableStream gave a chunk that is not a Uint8Array');
            yield value;
        }
    } finally {
        if (signal) signal.removeEventListener('abort', stop);
        reader.cancel().catch(() => {}); // a decode that ended early (an error) reads no further
    }
}

/**
 * The pool as ProgressiveDecoder takes it (pool.mjs's stream side), its helpers started once the
 * tile index is known: no more helpers than tiles.
 */
export class PoolSide {
    constructor(workers, startHelper, count = (ctx) => ctx.tiles.length) {
        this.workers = workers;
        this.count = count; // the tiles a stream decodes (ctx): no more helpers than them
        this.startHelper = startHelper;
        this.pool = null;
        this.side = null;
    }

    /** Start `workers` helpers now, before the tile index is known (stream.mjs: while the first request is under way). */
    async warm() {
        await loadWasm(); // the helpers get the compiled module
        if (!this.pool && !this.closed) {
            this.pool = new TilePool(this.workers, this.startHelper);
            this.pool.warm();
        }
    }

    start(ctx) {
        if (!this.pool) this.pool = new TilePool(Math.max(1, Math.min(this.workers, this.count(ctx))), this.startHelper);
        this.side = this.pool.stream();
        this.side.start(ctx);
    }

    decode(ctx, t) { return this.side.decode(ctx, t); }

    flush() { this.side.flush(); }

    close() { this.closed = true; if (this.pool) this.pool.close(); }
}

const FIELDS = [['positions', 3], ['scales', 3], ['rotations', 4], ['opacities', 1], ['colors', 3]];

/** Each decoded tile's arrays copied into the scene's, at the tile's place in stream order. */
export class SceneAssembly {
    /**
     * select(ctx): the numbers of the tiles decoded (default: those the box selects, or all).
     * onTile(view): each tile's Gaussians once in the scene's arrays (tileView).
     */
    constructor(box, activated, onProgress, { select = null, onTile = null } = {}) {
        this.box = box;
        this.select = select;
        this.onTile = onTile;
        this.activated = activated;
        this.onProgress = onProgress;
        this.out = null;
        this.offset = null; // per tile of the stream, its first point in the output (selected tiles)
        this.tilesDecoded = 0;
        this.pointsDecoded = 0;
    }

    // the output, sized from the tile index (the tiles to decode and their points) at the first tile
    _allocate(ctx) {
        const selected = this.select ? this.select(ctx) : this.box ? tilesInBox(ctx, this.box) : ctx.tiles.map((_, t) => t);
        this.offset = new Map();
        let n = 0;
        for (const t of selected) { this.offset.set(t, n); n += ctx.tiles[t].points; }
        const rest = 3 * ((ctx.ps.shDegree + 1) ** 2 - 1);
        this.rest = rest;
        this.tilesTotal = selected.length;
        this.out = { count: n, shDegree: ctx.ps.shDegree, sh: new Float32Array(rest * n) };
        for (const [name, width] of FIELDS) this.out[name] = new Float32Array(width * n);
    }

    add(t, tile, info) {
        if (!this.out) this._allocate(info.ctx);
        // the pool's helpers made them; here, made now as views of the module's memory, copied below before any other call into it
        const a = tile.arrays || sceneArrays(info.ps, [tile], { views: true });
        delete tile.arrays; // the scene's arrays hold them now
        const n = tile.n, o = this.offset.get(t), out = this.out, S3 = 3 * info.ps.S, rest = this.rest;
        out.positions.set(a.positions, 3 * o);
        out.scales.set(a.scales, 3 * o);
        out.rotations.set(a.rotations, 4 * o);
        out.opacities.set(a.opacities, o);
        for (let i = 0; i < n; i++) { // SH: DC -> colors, the other coefficients -> sh
            const src = S3 * i, dst = 3 * (o + i);
            out.colors[dst] = a.sh[src]; out.colors[dst + 1] = a.sh[src + 1]; out.colors[dst + 2] = a.sh[src + 2];
            if (rest) out.sh.set(a.sh.subarray(src + 3, src + S3), rest * (o + i));
        }
        if (this.activated) activate(out, o, n);
        this.tilesDecoded++;
        this.pointsDecoded += n;
        if (this.onTile) this.onTile(this.tileView(t, o, n));
        if (this.onProgress) {
            this.onProgress({ tile: t, tilesDecoded: this.tilesDecoded, tilesTotal: this.tilesTotal, pointsDecoded: this.pointsDecoded, pointsTotal: out.count });
        }
    }

    /** Tile t's Gaussians [o, o + n) of the scene: {tile, offset, count, shDegree, bounds, and views of the scene's arrays}. */
    tileView(t, o, n) {
        const v = { tile: t, offset: o, count: n, shDegree: this.out.shDegree };
        for (const [name, width] of FIELDS) v[name] = this.out[name].subarray(width * o, width * (o + n));
        v.sh = this.out.sh.subarray(this.rest * o, this.rest * (o + n));
        v.bounds = bounds(v.positions, n);
        return v;
    }

    result(r) {
        if (!this.out) this._allocate({ ps: r.ps, tiles: [] }); // no tile decoded: a box that selects none
        const out = this.out;
        return { ...out, tiles: r.tiles.length, bounds: bounds(out.positions, out.count) };
    }
}

/** Points [o, o + n) of the scene from the stored 3DGS parameters to renderer values (README.md "activated"). */
function activate(out, o, n) {
    for (let i = o; i < o + n; i++) {
        out.opacities[i] = 1 / (1 + Math.exp(-out.opacities[i]));
        for (let a = 3 * i; a < 3 * i + 3; a++) {
            out.scales[a] = Math.exp(out.scales[a]);
            out.colors[a] = 0.5 + SH_C0 * out.colors[a];
        }
        const q = 4 * i, r = out.rotations;
        const norm = Math.hypot(r[q], r[q + 1], r[q + 2], r[q + 3]);
        if (norm > 0) for (let j = q; j < q + 4; j++) r[j] /= norm;
        else { r[q] = 1; r[q + 1] = r[q + 2] = r[q + 3] = 0; } // no rotation: the identity
    }
}

/** The box around the Gaussians' centres, {min: [x, y, z], max: [x, y, z]}; null for no Gaussian. */
function bounds(positions, count) {
    if (!count) return null;
    const min = [Infinity, Infinity, Infinity], max = [-Infinity, -Infinity, -Infinity];
    for (let i = 0; i < 3 * count; i += 3) {
        for (let a = 0; a < 3; a++) {
            const v = positions[i + a];
            if (v < min[a]) min[a] = v;
            if (v > max[a]) max[a] = v;
        }
    }
    return { min, max };
}
