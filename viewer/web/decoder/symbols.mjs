// One symbol chunk (spec/entropy.md clauses 10.4, 10.5, 10.7): the bins of every residual grouped
// by scale level, then the escape section (signs, magnitude classes, remainders).
import { BitstreamError } from './errors.mjs';
import { RangeDecoder } from './range.mjs';
import { scaleTables } from './tables.mjs';

const MAX_RESIDUAL = 2n ** 62n - 1n;

/** Scratch arrays reused across chunks (grown on demand). */
class Scratch {
    constructor() { this.order = new Int32Array(0); this.esc = new Uint8Array(0); this.count = new Int32Array(65); }
    ensure(n) {
        if (this.order.length < n) { this.order = new Int32Array(n); this.esc = new Uint8Array(n); }
    }
}
const SCRATCH = new Scratch();

/**
 * Decode the chunk `bytes` of n residuals whose levels are levels[0..n-1] into out[0..n-1]
 * (numbers). A residual of magnitude >= 2^53 is not exact as a number: it is put in `wide`
 * (index -> BigInt) and out[j] is set to NaN. Checks the chunk is exhausted. Returns the number
 * of escaped residuals.
 */
export function decodeSymbolChunk(bytes, levels, n, out, wide, what) {
    const dec = new RangeDecoder(bytes, what);
    const esc = decodeWithDecoder(dec, levels, n, out, wide);
    dec.checkExhausted();
    return esc;
}

export function decodeWithDecoder(dec, levels, n, out, wide) {
    const T = scaleTables();
    const models = T.levels, half = T.half;
    const S = SCRATCH;
    S.ensure(n);
    const count = S.count, order = S.order, escf = S.esc;
    count.fill(0);
    for (let j = 0; j < n; j++) count[levels[j] + 1]++;
    for (let i = 0; i < 64; i++) count[i + 1] += count[i];
    for (let j = 0; j < n; j++) order[count[levels[j]]++] = j;
    // count[i] is now the end of level i's group
    let nesc = 0;
    let start = 0;
    for (let i = 0; i < 64; i++) {
        const end = count[i];
        if (end === start) continue;
        const L = half[i], ESC = 2 * L + 1;
        for (let t = start; t < end; t++) {
            const j = order[t];
            const b = dec.decode(models, i);
            if (b === ESC) { escf[j] = 1; nesc++; } else { escf[j] = 0; out[j] = b - L; }
        }
        start = end;
    }
    if (nesc) decodeEscapes(dec, T, levels, n, out, wide, escf, nesc);
    return nesc;
}

function decodeEscapes(dec, T, levels, n, out, wide, escf, nesc) {
    const idx = new Int32Array(nesc);
    for (let j = 0, e = 0; j < n; j++) if (escf[j]) idx[e++] = j;
    const sign = dec.decodeBits(new Array(nesc).fill(1));
    const k = new Array(nesc);
    for (let e = 0; e < nesc; e++) k[e] = dec.decode(T.classes, 0);
    const rem = dec.decodeBits(k.map((x) => Math.max(x - 1, 0)));
    for (let e = 0; e < nesc; e++) {
        const j = idx[e], L = T.half[levels[j]];
        if (k[e] <= 52) {
            const m = k[e] === 0 ? 0 : 2 ** (k[e] - 1) + rem[e];
            const mag = L + 1 + m; // < 2^52 + 4097: exact
            out[j] = sign[e] ? -mag : mag;
            if (mag >= 2 ** 53) throw new Error('unreachable');
        } else {
            const mag = BigInt(L + 1) + (1n << BigInt(k[e] - 1)) + BigInt(rem[e]);
            if (mag > MAX_RESIDUAL) {
                throw new BitstreamError(`${dec.what}: escaped residual magnitude ${mag} exceeds 2^62 - 1 (clause 10.5)`);
            }
            if (mag < 2n ** 53n) {
                out[j] = sign[e] ? -Number(mag) : Number(mag);
            } else {
                out[j] = NaN;
                wide.set(j, sign[e] ? -mag : mag);
            }
        }
    }
}
