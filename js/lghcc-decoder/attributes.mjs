// Attribute decoding of explicit-Gaussian tiles (spec clause 11): the per-channel prior, chunks,
// cross-channel prediction (11.6), neighbour prediction (11.7), step adjustment (11.8), the
// per-Gaussian SH degree (11.9), reconstruction in binary32 (11.5), the implied rotation w (11.10) and the SH
// rest's inverse transform (11.11). Per chunk, one call of the
// WebAssembly module (wasm/decoder.ts: attributeChunk) decodes the rows' SH degrees, computes their
// means and levels, decodes the symbols of their coded channels and the values q, exact in 64-bit
// integers; q, the rows' step-adjustment indices and SH degrees live in the module's memory while
// the tile decodes, and the module reconstructs the binary32 values at the
// end (reconstruct). JS parses, finds the neighbours (knn.mjs) and turns the module's failures into
// the spec's errors.
import { BitstreamError } from './errors.mjs';
import { neighboursInModule } from './knn.mjs';
import { lengthIndexError } from './rotation.mjs';
import { symbolError, symbolsInModule } from './symbols.mjs';
import { alloc, callWasm, copyIn, wasm } from './wasm.mjs';

export const STEP_ADJUST_FACTORS = [1.0, 1.18920708, 1.41421354, 1.68179286, 2.0, 2.37841415, 2.82842708, 3.36358571].map(Math.fround);
export const ADJUST_FIXED_POINT = [4096, 4871, 5793, 6889, 8192, 9742, 11585, 13777];
export const ADJUST_LEVEL_SHIFT = [0, 1, 3, 4, 5, 6, 8, 9];
export const MAX_EXTENT = 1753413056;
const FIXED_POINT = Int32Array.from(ADJUST_FIXED_POINT), LEVEL_SHIFT = Int32Array.from(ADJUST_LEVEL_SHIFT);

/**
 * The rows of each LoD (clause 11.7.1) of n rows, in increasing order, as arithmetic progressions
 * {first, step, count}: LoD 0 the multiples of 2^(L-1), LoD l >= 1 the odd multiples of 2^(L-1-l).
 */
export function lodRows(n, L) {
    const rows = (first, step) => ({ first, step, count: n > first ? Math.floor((n - 1 - first) / step) + 1 : 0 });
    const out = [rows(0, 2 ** (L - 1))];
    for (let l = 1; l < L; l++) out.push(rows(2 ** (L - 1 - l), 2 ** (L - l)));
    return out;
}

/** count rows of a progression from its t-th on, as int32 in the module's memory (no per-row JS: cold in every worker). */
function rowsInModule(w, rows, t, count) {
    return w.progression(rows.first + t * rows.step, rows.step, count);
}

/** The per-axis minima and extents of the tile's points (decodeGeometry's min and max); throws E64 beyond MAX_EXTENT. */
function tileBounds(coords) {
    const lo = coords.min.slice(), ext = [0, 1, 2].map((a) => coords.max[a] - coords.min[a]);
    const e = Math.max(...ext);
    if (e > MAX_EXTENT) throw new BitstreamError(`the tile's points span ${e} voxels, beyond MAX_EXTENT = ${MAX_EXTENT} (clause 8.1, E64)`, 'E64');
    return { lo, ext };
}

/**
 * Neighbours (clause 11.7.2) of the rows of LoD l among the rows of LoDs < l, the tile's coordinates
 * at p in the module's memory: {idx, cnt, mark}, addresses in the module's memory (knn.mjs).
 */
function lodNeighbours(w, lods, l, k, p, bounds, n) {
    const step = 2 ** (lods.length - l); // the rows of LoDs < l are the multiples of 2^(L - l)
    const data = { first: 0, step, count: Math.ceil(n / step) }, queries = lods[l];
    return neighboursInModule(p, bounds.lo, bounds.ext, rowsInModule(w, data, 0, data.count), data.count, rowsInModule(w, queries, 0, queries.count), queries.count, k);
}

class TileAttributeDecoder {
    constructor(payload, h, coords, ctx) {
        this.payload = payload; this.h = h; this.coords = coords; this.ctx = ctx;
        this.M = ctx.M; this.n = h.numRows;
        this.off = h.dataOffset;
        this.chunk = 0;
        // kept in the module's memory until release(): q (i64 [n * M]), the indices and degrees (u8 [n] each), the tile's parameters, its coordinates
        const w = this.w = wasm(), M = this.M, np = ctx.np;
        w.reset();
        this.qAddr = alloc(w, 8 * this.n * M, false); // not zeroed: every chunk writes every value of its rows before any is read
        this.adjAddr = alloc(w, this.n);
        // predictions grouped by target (they are sorted by target, clause 7.3.5)
        const pStart = new Int32Array(M + 1);
        for (let i = 0; i < h.predTarget.length; i++) pStart[h.predTarget[i] + 1]++;
        for (let c = 0; c < M; c++) pStart[c + 1] += pStart[c];
        const at = (arr) => copyIn(w, arr);
        w.attributeTile(this.qAddr, M, this.adjAddr, ctx.stepAdjust ? 1 : 0, at(FIXED_POINT), at(LEVEL_SHIFT),
            at(np ? np.meanFlag : new Uint8Array(M)), at(np ? np.bucketLevel : new Uint8Array(1)), np ? np.B : 1,
            at(h.priorMean), at(h.priorLevel), at(pStart), at(h.predSource), at(Int32Array.from(h.predWeight)));
        if (ctx.shDegreeUnit) w.attributeDegrees(alloc(w, this.n), ctx.ps.shDegree, at(ctx.shDegreeUnit.freq));
        if (ctx.stepFlags) w.attributeStepFlags(ctx.stepAdjust.maxStepAdjust, at(ctx.stepFlags.freq));
        this.coordsAddr = ctx.np ? [coords.x, coords.y, coords.z].map(at) : null; // the k-NN's points, copied once
        this.mark = w.keep();
    }

    /** Give the module's memory of the tile back. */
    release() { this.w.release(this.mark); }

    take(size) {
        const b = this.payload.subarray(this.off, this.off + size);
        this.off += size;
        return b;
    }

    run() {
        const { np } = this.ctx;
        const lods = np ? lodRows(this.n, np.L) : [{ first: 0, step: 1, count: this.n }];
        const bounds = np ? tileBounds(this.coords) : null;
        for (let l = 0; l < lods.length; l++) {
            const rows = lods[l];
            this.w.reset();
            // the LoD's neighbours stay in the module's memory while its chunks decode (each chunk resets above them)
            const nb = l > 0 ? lodNeighbours(this.w, lods, l, np.k, this.coordsAddr, bounds, this.n) : null;
            const S = this.h.rowsPerChunk, chunks = Math.ceil(rows.count / S);
            const size = (m) => Math.min(rows.count - m * S, S);
            // several chunks at a time, their range decoders interleaved: four where the rows take the prior's means
            // and levels (no neighbours, no step adjustment, no SH-degree tool), else two, unless the indices are
            // symbols (decodeIndices between chunks); ctx.chunkPairs = false: one at a time (a test compares the two)
            const prior = !nb && !this.ctx.stepAdjust && !this.ctx.shDegreeUnit;
            const group = this.ctx.chunkPairs === false || (this.ctx.stepAdjust && !this.ctx.stepFlags) ? 1 : prior ? 4 : 2;
            for (let m = 0; m < chunks;) {
                const g = Math.min(group, chunks - m), parts = [];
                for (let i = m; i < m + g; i++) parts.push({ lo: i * S, nr: size(i) });
                if (g === 1) this.decodeChunk(rows, m * S, size(m), nb);
                else this.decodeChunkGroup(rows, parts, nb, prior);
                m += g;
            }
            if (nb) this.w.release(nb.mark);
        }
    }

    /** Chunk i: nr rows of the LoD's rows (a progression) from its lo-th on (clause 11.4, 11.7.5, 11.8, 11.9). */
    decodeChunk(rows, lo, nr, nb) {
        const i = this.chunk++, w = this.w, k = nb ? this.ctx.np.k : 0, flags = this.ctx.stepFlags;
        // the indices as symbols are decoded here; as flags (version 1.5) by attributeChunk, which has the neighbours
        if (this.ctx.stepAdjust && !flags) this.decodeIndices(i, rows.first + lo * rows.step, rows.step, nr);
        const stepData = flags ? this.takeWords(this.h.adjustSize[i], `step-adjustment flags chunk ${i}`) : EMPTY;
        const degrees = this.ctx.shDegreeUnit ? this.takeWords(this.h.degreeSize[i], `SH-degree chunk ${i}`) : EMPTY;
        const bytes = this.takeWords(this.h.chunkSize[i], `attribute chunk ${i}`);
        w.reset();
        const at = (arr) => copyIn(w, arr);
        const pBytes = at(bytes), pRows = rowsInModule(w, rows, lo, nr), pDegrees = at(degrees), pStep = at(stepData);
        const pIdx = nb ? nb.idx + 4 * lo * k : alloc(w, 0);
        const pCnt = nb ? nb.cnt + lo : alloc(w, nr);
        callWasm(() => w.attributeChunk(pBytes, bytes.length, pRows, nr, pIdx, pCnt, k, pDegrees, degrees.length, pStep, stepData.length),
            (code, a, b) => chunkError(`${STAGE_NAMES[w.errorStage()]} ${i}`, code, a, b, w));
    }

    /**
     * Chunks i, i + 1, ...: parts[t].nr rows of the LoD's rows from its parts[t].lo-th on, by the module's
     * attributePriorChunks (up to four chunks, prior) or attributeChunkPair (two); any failure decodes them again
     * one after the other (decodeChunk), whose error names the first fault in stream order.
     */
    decodeChunkGroup(rows, parts, nb, prior) {
        const off = this.off, chunk = this.chunk, w = this.w, k = nb ? this.ctx.np.k : 0;
        const again = (e) => {
            this.off = off; this.chunk = chunk;
            for (const { lo, nr } of parts) this.decodeChunk(rows, lo, nr, nb);
            throw e; // not reached: the same bytes fail again
        };
        let data;
        try {
            data = parts.map(() => this.takeChunk());
        } catch (e) {
            again(e);
        }
        w.reset();
        const at = (arr) => copyIn(w, arr);
        try {
            if (prior) {
                const desc = new Int32Array(4 * parts.length);
                parts.forEach(({ lo, nr }, t) => desc.set([at(data[t].bytes), data[t].bytes.length, rowsInModule(w, rows, lo, nr), nr], 4 * t));
                w.attributePriorChunks(at(desc), parts.length);
            } else {
                const args = (c, lo, nr) => [at(c.bytes), c.bytes.length, rowsInModule(w, rows, lo, nr), nr,
                    nb ? nb.idx + 4 * lo * k : alloc(w, 0), nb ? nb.cnt + lo : alloc(w, nr), at(c.degrees), c.degrees.length, at(c.stepData), c.stepData.length];
                w.attributeChunkPair(...args(data[0], parts[0].lo, parts[0].nr), ...args(data[1], parts[1].lo, parts[1].nr), k);
            }
        } catch (e) {
            if (!(e instanceof WebAssembly.RuntimeError)) throw e;
            again(e);
        }
    }

    /** The next chunk's range-coded parts (decodeChunk's, in stream order): {stepData, degrees, bytes}. */
    takeChunk() {
        const i = this.chunk++;
        const stepData = this.ctx.stepFlags ? this.takeWords(this.h.adjustSize[i], `step-adjustment flags chunk ${i}`) : EMPTY;
        const degrees = this.ctx.shDegreeUnit ? this.takeWords(this.h.degreeSize[i], `SH-degree chunk ${i}`) : EMPTY;
        return { stepData, degrees, bytes: this.takeWords(this.h.chunkSize[i], `attribute chunk ${i}`) };
    }

    /** The next range-coded chunk of `size` bytes, a whole number of 32-bit words (clause 10.6.6, E35). */
    takeWords(size, what) {
        const bytes = this.take(size);
        if (bytes.length % 4) throw new BitstreamError(`${what}: length ${bytes.length} is not a whole number of 32-bit words (clause 10.6.6)`, 'E35');
        return bytes;
    }

    /** The step-adjustment indices of the chunk's nr rows first, first + step, ... (clause 11.8), into the module's memory. */
    decodeIndices(i, first, step, nr) {
        const h = this.h, w = this.w, max = this.ctx.stepAdjust.maxStepAdjust;
        const { po } = symbolsInModule(w, this.take(h.adjustSize[i]), h.adjustLevel, nr, `step-adjustment chunk ${i}`);
        // residual + adjust mean, each checked against [0, max] (a residual beyond 2^53 is NaN: outside), into the rows' indices
        callWasm(() => w.stepIndices(po, nr, h.adjustMean, max, this.adjAddr, first, step),
            () => new BitstreamError(`step-adjustment chunk ${i}: an index is outside [0, max_step_adjust = ${max}] (clause 11.8, E65)`, 'E65'));
    }

    /** Reconstruction in binary32 (clause 11.5) of the tile's values, by the module: Float32Array [n * M]. */
    reconstruct() {
        const w = this.w, n = this.n, M = this.M;
        this.inverseShTransform();
        const scale = Float32Array.from({ length: 8 * M }, (_, j) => Math.fround(this.ctx.steps[j % M] * STEP_ADJUST_FACTORS[Math.floor(j / M)]));
        w.reset();
        const pScale = copyIn(w, scale), out = alloc(w, 4 * n * M, false);
        callWasm(() => w.reconstruct(n, pScale, out), (code, row, c) => new BitstreamError(`row ${row}, channel ${c}: the reconstructed value is not finite (clause 11.5, E52)`, 'E52'));
        const rl = this.ctx.rotationLength;
        if (rl) callWasm(() => w.impliedRotations(out, n, M - 4, rl.maxIndex), (code, row) => lengthIndexError(new Int32Array(w.memory.buffer, this.qAddr, 2 * n * M), row, M, M - 4, rl.maxIndex));
        // the values while they are in the module's memory (the tile's hash, the renderer's arrays); q is no longer needed: scratch
        if (this.onValues) this.onValues(w, out, this.qAddr, 8 * n * M);
        return new Float32Array(w.memory.buffer, out, n * M).slice();
    }

    /** With an sh_transform unit (clause 11.11), the SH-rest q of every row from its coefficients, in place, by the module. */
    inverseShTransform() {
        const st = this.ctx.shTransform, w = this.w;
        if (!st || st.size === 0) return;
        w.reset();
        const pT = copyIn(w, st.matrix), tmp = alloc(w, 20 * st.size);
        callWasm(() => w.inverseShTransform(this.n, st.size, pT, st.shift, tmp),
            (code, row, c) => new BitstreamError(`row ${row}, channel ${c}: an SH value's inverse transform ${BigInt.asIntN(64, w.errorWide())} exceeds the limit of 2^40 quantization steps (clause 11.11, E68)`, 'E68'));
    }
}

const ERR_Q_LIMIT = 11; // decoder.ts: |q| > 2^40
const EMPTY = new Uint8Array(0);
// decoder.ts: errorStage() of a failure in the symbol data, the SH-degree data, the step-adjustment flags
const STAGE_NAMES = ['attribute chunk', 'SH-degree chunk', 'step-adjustment flags chunk'];

/** The spec's error for the module's failure `code` in an attribute chunk. */
function chunkError(what, code, a, b, w) {
    if (code === ERR_Q_LIMIT) return new BitstreamError(`a quantized value ${BigInt.asIntN(64, w.errorWide())} of row ${a}, channel ${b} is beyond 2^40 (clause 11.6, E51)`, 'E51');
    return symbolError(what, code, w);
}

/**
 * Decode the attribute unit of a tile: returns the reconstructed values, Float32Array [n * M]
 * (row-major, channel order of clause 11.1). onValues(w, address, scratch, bytes): called with the values'
 * address in the module's memory before they are copied out (valid until the next call into the module), and a
 * region of `bytes` at scratch that is free by then (the tile's q).
 */
export function decodeTileAttributes(payload, header, coords, ctx, onValues = null) {
    const dec = new TileAttributeDecoder(payload, header, coords, ctx);
    dec.onValues = onValues;
    try {
        dec.run();
        return dec.reconstruct();
    } finally {
        dec.release();
    }
}
