// Attribute decoding of explicit-Gaussian tiles (spec clause 11): the per-channel prior, chunks,
// cross-channel prediction (11.6), neighbour prediction (11.7), step adjustment (11.8) and
// reconstruction in binary32 (11.5). The rows' means and levels (11.3, 11.7.3, 11.8) are computed
// in WebAssembly (wasm/decoder.ts: rowMeans, exact in 64-bit integers) on the values q, which live in
// the module's memory while the tile decodes. Elsewhere integers are exact doubles; the rare values
// beyond 2^53 (escapes near 2^62, predictions of huge deviations) take an exact BigInt path.
import { BitstreamError } from './errors.mjs';
import { gridNeighbours } from './knn.mjs';
import { decodeSymbolChunk } from './symbols.mjs';
import { alloc, callWasm, copyIn, wasm } from './wasm.mjs';

export const STEP_ADJUST_FACTORS = [1.0, 1.18920708, 1.41421354, 1.68179286, 2.0, 2.37841415, 2.82842708, 3.36358571].map(Math.fround);
export const ADJUST_FIXED_POINT = [4096, 4871, 5793, 6889, 8192, 9742, 11585, 13777];
export const ADJUST_LEVEL_SHIFT = [0, 1, 3, 4, 5, 6, 8, 9];
export const MAX_EXTENT = 1753413056;
const Q_LIMIT = 2 ** 40;
const SAFE_DEV = 2 ** 31; // |q - mean| below this: a row's prediction sum stays below 2^52
const FIXED_POINT = Int32Array.from(ADJUST_FIXED_POINT), LEVEL_SHIFT = Int32Array.from(ADJUST_LEVEL_SHIFT);

/** The rows of each LoD (clause 11.7.1), in increasing order. */
export function lodRows(n, L) {
    const out = [];
    const step0 = 2 ** (L - 1);
    const r0 = [];
    for (let i = 0; i < n; i += step0) r0.push(i);
    out.push(Int32Array.from(r0));
    for (let l = 1; l < L; l++) {
        const t = L - 1 - l, s = 2 ** t, rows = [];
        for (let i = s; i < n; i += 2 * s) rows.push(i);
        out.push(Int32Array.from(rows));
    }
    return out;
}

/** The per-axis minima and extents of the tile's points; throws E64 beyond MAX_EXTENT. */
function tileBounds(x, y, z, n) {
    const lo = [0, 0, 0], ext = [0, 0, 0];
    [x, y, z].forEach((c, a) => {
        let mn = Infinity, mx = -Infinity;
        for (let i = 0; i < n; i++) { if (c[i] < mn) mn = c[i]; if (c[i] > mx) mx = c[i]; }
        lo[a] = mn; ext[a] = mx - mn;
    });
    const e = Math.max(...ext);
    if (e > MAX_EXTENT) throw new BitstreamError(`the tile's points span ${e} voxels, beyond MAX_EXTENT = ${MAX_EXTENT} (clause 8.1, E64)`);
    return { lo, ext };
}

/** Neighbours (clause 11.7.2) of the rows of LoD l among the rows of LoDs < l: {idx: Int32Array [n_l * k], cnt}. */
function lodNeighbours(lods, l, k, coords, bounds, n) {
    const step = 2 ** (lods.length - l); // the rows of LoDs < l are the multiples of 2^(L - l)
    const ids = new Int32Array(Math.ceil(n / step));
    for (let t = 0; t < ids.length; t++) ids[t] = t * step;
    const rows = lods[l];
    const idx = new Int32Array(rows.length * k), cnt = new Uint8Array(rows.length);
    gridNeighbours(coords.x, coords.y, coords.z, bounds.lo, bounds.ext, ids, rows, k, idx, cnt);
    return { idx, cnt };
}

class TileAttributeDecoder {
    constructor(payload, h, coords, ctx) {
        this.payload = payload; this.h = h; this.coords = coords; this.ctx = ctx;
        this.M = ctx.M; this.n = h.numRows;
        // q in the module's memory, kept across its calls until release()
        const w = this.w = wasm();
        w.reset();
        this.qAddr = alloc(w, 8 * this.n * this.M);
        this.mark = w.keep();
        this.qView = null;
        this.adj = new Uint8Array(this.n);
        this.off = h.dataOffset;
        this.chunk = 0;
        const S = h.rowsPerChunk, M = this.M;
        const cap = Math.min(S, this.n) * M;
        this.mean = new Float64Array(cap); this.level = new Uint8Array(cap); this.res = new Float64Array(cap);
        // predictions grouped by target (they are sorted by target, clause 7.3.5)
        this.pStart = new Int32Array(M + 1);
        for (let i = 0; i < h.predTarget.length; i++) this.pStart[h.predTarget[i] + 1]++;
        for (let c = 0; c < M; c++) this.pStart[c + 1] += this.pStart[c];
    }

    /** The values q (Float64Array [n * M]), a view renewed when the module's memory grew. */
    get q() {
        if (!this.qView || this.qView.buffer !== this.w.memory.buffer) this.qView = new Float64Array(this.w.memory.buffer, this.qAddr, this.n * this.M);
        return this.qView;
    }

    /** Give the module's memory of q back (after the last use of q). */
    release() { this.w.release(this.mark); this.qView = null; }

    take(size, what) {
        const b = this.payload.subarray(this.off, this.off + size);
        this.off += size;
        return b;
    }

    run() {
        const { np } = this.ctx;
        const lods = np ? lodRows(this.n, np.L) : [null];
        const bounds = np ? tileBounds(this.coords.x, this.coords.y, this.coords.z, this.n) : null;
        for (let l = 0; l < lods.length; l++) {
            const rows = lods[l];
            const nl = rows ? rows.length : this.n;
            const nb = l > 0 ? lodNeighbours(lods, l, np.k, this.coords, bounds, this.n) : null;
            const S = this.h.rowsPerChunk;
            for (let m = 0; m * S < nl; m++) {
                const lo = m * S, hi = Math.min(nl, lo + S);
                this.decodeChunk(rows, lo, hi, nb);
            }
        }
    }

    decodeChunk(rows, lo, hi, nb) {
        const i = this.chunk++;
        const nr = hi - lo, M = this.M, h = this.h;
        const rowAt = rows ? (t) => rows[t] : (t) => t;
        if (this.ctx.stepAdjust) this.decodeIndices(i, rowAt, lo, hi);
        this.rowParameters(rows, lo, hi, nb);
        const wide = new Map();
        const bytes = this.take(h.chunkSize[i]);
        decodeSymbolChunk(bytes, this.level, nr * M, this.res, wide, `attribute chunk ${i}`);
        for (let t = lo; t < hi; t++) this.rowValues(rowAt(t), (t - lo) * M, wide);
    }

    decodeIndices(i, rowAt, lo, hi) {
        const h = this.h, nr = hi - lo;
        const bytes = this.take(h.adjustSize[i]);
        const levels = new Uint8Array(nr).fill(h.adjustLevel);
        const r = new Float64Array(nr);
        decodeSymbolChunk(bytes, levels, nr, r, new Map(), `step-adjustment chunk ${i}`);
        const max = this.ctx.stepAdjust.maxStepAdjust;
        for (let t = 0; t < nr; t++) {
            const a = r[t] + h.adjustMean;
            if (!(a >= 0 && a <= max)) throw new BitstreamError(`step-adjustment chunk ${i}: an index is outside [0, max_step_adjust = ${max}] (clause 11.8, E65)`);
            this.adj[rowAt(lo + t)] = a;
        }
    }

    /** mean and level of the rows lo..hi-1 (clauses 11.3, 11.7.3, 11.8) into the chunk buffers, by the module's rowMeans. */
    rowParameters(rows, lo, hi, nb) {
        const w = this.w, M = this.M, h = this.h, np = this.ctx.np, nr = hi - lo, k = nb ? np.k : 0;
        w.reset();
        const at = (arr) => copyIn(w, arr);
        const pRows = rows ? at(rows.subarray(lo, hi)) : at(Int32Array.from({ length: nr }, (_, t) => lo + t));
        const pIdx = nb ? at(nb.idx.subarray(lo * k, hi * k)) : at(new Int32Array(0));
        const pCnt = nb ? at(nb.cnt.subarray(lo, hi)) : at(new Uint8Array(nr));
        const meanFlag = np ? np.meanFlag : new Uint8Array(M), bucket = np ? np.bucketLevel : new Uint8Array(1);
        const args = [at(this.adj), this.ctx.stepAdjust ? 1 : 0, at(FIXED_POINT), at(LEVEL_SHIFT), at(meanFlag), at(bucket), np ? np.B : 1,
            at(h.priorMean), at(h.priorLevel)];
        const pMean = alloc(w, 8 * nr * M), pLevel = alloc(w, nr * M);
        callWasm(() => w.rowMeans(this.qAddr, M, pRows, nr, pIdx, pCnt, k, ...args, pMean, pLevel), () => null);
        this.mean.set(new Float64Array(w.memory.buffer, pMean, nr * M));
        this.level.set(new Uint8Array(w.memory.buffer, pLevel, nr * M));
    }

    /** q of one row (clauses 11.4 step 3, 11.6): residual + mean + prediction, |q| <= 2^40 checked. */
    rowValues(row, base, wide) {
        const M = this.M, h = this.h, q = this.q, mean = this.mean, res = this.res;
        const qb = row * M, ps = this.pStart, src = h.predSource, w = h.predWeight;
        for (let c = 0; c < M; c++) {
            const rv = res[base + c];
            let ok = Math.abs(rv) < 2 ** 52; // false for NaN: a wide residual
            let p = 0;
            for (let i = ps[c]; i < ps[c + 1] && ok; i++) {
                const dev = q[qb + src[i]] - mean[base + src[i]];
                if (Math.abs(dev) >= SAFE_DEV) ok = false;
                p += w[i] * dev;
            }
            let v;
            if (ok) v = rv + mean[base + c] + Math.floor((p + 128) / 256);
            else v = this.valueExact(qb, base, c, wide);
            if (!(Math.abs(v) <= Q_LIMIT)) {
                throw new BitstreamError(`a quantized value ${v} of row ${row}, channel ${c} is beyond 2^40 (clause 11.6, E51)`);
            }
            q[qb + c] = v;
        }
    }

    valueExact(qb, base, c, wide) {
        const h = this.h, q = this.q, mean = this.mean;
        const rv = wide.has(base + c) ? wide.get(base + c) : BigInt(this.res[base + c]);
        let p = 0n;
        for (let i = this.pStart[c]; i < this.pStart[c + 1]; i++) {
            p += BigInt(h.predWeight[i]) * (BigInt(q[qb + h.predSource[i]]) - BigInt(mean[base + h.predSource[i]]));
        }
        const v = rv + BigInt(mean[base + c]) + ((p + 128n) >> 8n);
        if (v > 2n ** 40n || v < -(2n ** 40n)) return Infinity;
        return Number(v);
    }
}

/**
 * Decode the attribute unit of a tile: returns the reconstructed values, Float32Array [n * M]
 * (row-major, channel order of clause 11.1).
 */
export function decodeTileAttributes(payload, header, coords, ctx) {
    const dec = new TileAttributeDecoder(payload, header, coords, ctx);
    try {
        dec.run();
        return reconstruct(dec, ctx, header.numRows);
    } finally {
        dec.release();
    }
}

/** Reconstruction in binary32 (clause 11.5) of the tile's values q. */
function reconstruct(dec, ctx, n) {
    const M = ctx.M, q = dec.q;
    const scales = STEP_ADJUST_FACTORS.map((f) => Float64Array.from(ctx.steps, (s) => Math.fround(s * f)));
    const out = new Float32Array(n * M);
    for (let i = 0; i < n; i++) {
        const s = scales[dec.adj[i]];
        for (let c = 0; c < M; c++) {
            const v = Math.fround(Math.fround(q[i * M + c]) * s[c]);
            if (!Number.isFinite(v)) throw new BitstreamError(`row ${i}, channel ${c}: the reconstructed value is not finite (clause 11.5, E52)`);
            out[i * M + c] = v;
        }
    }
    return out;
}
