// Attribute decoding of explicit-Gaussian tiles (spec clause 11): the per-channel prior, chunks,
// cross-channel prediction (11.6), neighbour prediction (11.7), step adjustment (11.8) and
// reconstruction in binary32 (11.5). Integers are exact doubles; the rare values beyond 2^53
// (escapes near 2^62, predictions of huge deviations, step-adjusted sums of huge values) take an
// exact BigInt path.
import { BitstreamError } from './errors.mjs';
import { gridNeighbours } from './knn.mjs';
import { decodeSymbolChunk } from './symbols.mjs';

export const STEP_ADJUST_FACTORS = [1.0, 1.18920708, 1.41421354, 1.68179286, 2.0, 2.37841415, 2.82842708, 3.36358571].map(Math.fround);
export const ADJUST_FIXED_POINT = [4096, 4871, 5793, 6889, 8192, 9742, 11585, 13777];
export const ADJUST_LEVEL_SHIFT = [0, 1, 3, 4, 5, 6, 8, 9];
export const MAX_EXTENT = 1753413056;
const Q_LIMIT = 2 ** 40;
const SAFE_DEV = 2 ** 31; // |q - mean| below this: a row's prediction sum stays below 2^52
const SAFE_SA_SUM = 2 ** 45; // |q F| below this (so |q| < 2^33 when F >= 4096): step-adjusted sums of k <= 32 neighbours stay below 2^50

function bitLength(a) {
    return a < 4294967296 ? 32 - Math.clz32(a) : 64 - Math.clz32(Math.floor(a / 4294967296));
}

function floorDiv(a, b) { // exact for integers a, b > 0 with |a| < 2^53
    let m = Math.floor(a / b);
    if (m * b > a) m--; else if ((m + 1) * b <= a) m++;
    return m;
}

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
        this.q = new Float64Array(this.n * this.M);
        this.adj = new Uint8Array(this.n);
        this.off = h.dataOffset;
        this.chunk = 0;
        const S = h.rowsPerChunk, M = this.M;
        const cap = Math.min(S, this.n) * M;
        this.mean = new Float64Array(cap); this.level = new Uint8Array(cap); this.res = new Float64Array(cap);
        // predictions grouped by target (they are sorted by target, clause 7.3.5)
        this.pStart = new Int32Array(M + 1);
        const k = ctx.np ? ctx.np.k : 0;
        this.nbRow = new Int32Array(k); this.nbFactor = new Float64Array(k); // a row's neighbours: j * M and F(adj[j])
        this.nbSum = new Float64Array(M); this.nbMax = new Float64Array(M); this.nbMin = new Float64Array(M);
        for (let i = 0; i < h.predTarget.length; i++) this.pStart[h.predTarget[i] + 1]++;
        for (let c = 0; c < M; c++) this.pStart[c + 1] += this.pStart[c];
    }

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
        return this.q;
    }

    decodeChunk(rows, lo, hi, nb) {
        const i = this.chunk++;
        const nr = hi - lo, M = this.M, h = this.h;
        const rowAt = rows ? (t) => rows[t] : (t) => t;
        if (this.ctx.stepAdjust) this.decodeIndices(i, rowAt, lo, hi);
        for (let t = lo; t < hi; t++) this.rowParameters(rowAt(t), (t - lo) * M, nb, t);
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

    /** mean[c] and level[c] of row `row` (clauses 11.3, 11.7.3, 11.8) at base in the chunk buffers. */
    rowParameters(row, base, nb, t) {
        const M = this.M, h = this.h, np = this.ctx.np, sa = this.ctx.stepAdjust;
        const F = ADJUST_FIXED_POINT[this.adj[row]];
        if (!nb) {
            for (let c = 0; c < M; c++) {
                if (sa) {
                    this.mean[base + c] = floorDiv(h.priorMean[c] * 4096 + Math.floor(F / 2), F);
                    this.level[base + c] = Math.max(0, h.priorLevel[c] - ADJUST_LEVEL_SHIFT[this.adj[row]]);
                } else {
                    this.mean[base + c] = h.priorMean[c];
                    this.level[base + c] = h.priorLevel[c];
                }
            }
            return;
        }
        const k = np.k, n = nb.cnt[t], q = this.q, jm = this.nbRow, fac = this.nbFactor;
        for (let m = 0; m < n; m++) { const j = nb.idx[t * k + m]; jm[m] = j * M; fac[m] = sa ? ADJUST_FIXED_POINT[this.adj[j]] : 1; }
        // sum, max and min of the neighbours' (step-adjusted) values, neighbour by neighbour: rows are contiguous
        const sum = this.nbSum, mx = this.nbMax, mn = this.nbMin;
        for (let c = 0, j = jm[0], f = fac[0]; c < M; c++) { const v = q[j + c] * f; sum[c] = v; mx[c] = v; mn[c] = v; }
        for (let m = 1; m < n; m++) {
            const j = jm[m], f = fac[m];
            for (let c = 0; c < M; c++) {
                const v = q[j + c] * f;
                sum[c] += v;
                if (v > mx[c]) mx[c] = v;
                if (v < mn[c]) mn[c] = v;
            }
        }
        if (sa ? this.meansAdjusted(base, n, F) : this.means(base, n)) this.rowParametersExact(row, base, nb.idx.subarray(t * k, t * k + n));
    }

    /** mean and level from nbSum/Max/Min of n neighbours (clause 11.7.3). */
    means(base, n) {
        const np = this.ctx.np, B = np.B, meanFlag = np.meanFlag, bucketLevel = np.bucketLevel, priorMean = this.h.priorMean;
        const sum = this.nbSum, mx = this.nbMax, mn = this.nbMin, halfN = Math.floor(n / 2);
        for (let c = 0; c < this.M; c++) {
            this.mean[base + c] = meanFlag[c] ? floorDiv(sum[c] + halfN, n) : priorMean[c];
            const b = bitLength(mx[c] - mn[c]);
            this.level[base + c] = bucketLevel[c * B + (b < B - 1 ? b : B - 1)];
        }
        return false;
    }

    /**
     * The same with step adjustment (clause 11.8), F the row's fixed-point factor. Returns true when
     * a neighbour's value reached 2^45 in magnitude (|q| >= 2^33 for some): sums may then pass 2^53,
     * and the exact path redoes the row.
     */
    meansAdjusted(base, n, F) {
        const np = this.ctx.np, B = np.B, meanFlag = np.meanFlag, bucketLevel = np.bucketLevel, priorMean = this.h.priorMean;
        const sum = this.nbSum, mx = this.nbMax, mn = this.nbMin, half = Math.floor(n * F / 2), halfF = Math.floor(F / 2);
        let wide = false;
        for (let c = 0; c < this.M; c++) {
            if (mx[c] >= SAFE_SA_SUM || mn[c] <= -SAFE_SA_SUM) wide = true;
            this.mean[base + c] = meanFlag[c] ? floorDiv(sum[c] + half, n * F) : floorDiv(priorMean[c] * 4096 + halfF, F);
            const b = bitLength(floorDiv(mx[c] - mn[c], F));
            this.level[base + c] = bucketLevel[c * B + (b < B - 1 ? b : B - 1)];
        }
        return wide;
    }

    rowParametersExact(row, base, nbr) {
        const M = this.M, h = this.h, np = this.ctx.np, q = this.q;
        const F = BigInt(ADJUST_FIXED_POINT[this.adj[row]]);
        const n = BigInt(nbr.length);
        const fdiv = (a, b) => { const d = a / b; return (a % b !== 0n && (a < 0n) !== (b < 0n)) ? d - 1n : d; };
        for (let c = 0; c < M; c++) {
            const v = Array.from(nbr, (j) => BigInt(q[j * M + c]) * BigInt(ADJUST_FIXED_POINT[this.adj[j]]));
            let sum = 0n, mx = v[0], mn = v[0];
            for (const x of v) { sum += x; if (x > mx) mx = x; if (x < mn) mn = x; }
            const mean = np.meanFlag[c] ? fdiv(sum + (n * F) / 2n, n * F) : fdiv(BigInt(h.priorMean[c]) * 4096n + F / 2n, F);
            const act = fdiv(mx - mn, F);
            this.mean[base + c] = Number(mean);
            this.level[base + c] = np.bucketLevel[c * np.B + Math.min(act.toString(2).length - (act === 0n ? 1 : 0), np.B - 1)];
        }
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
    const q = dec.run();
    const M = ctx.M, n = header.numRows;
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
