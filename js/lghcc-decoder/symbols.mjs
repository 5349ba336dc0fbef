// One symbol chunk (spec/entropy.md clauses 10.4, 10.5, 10.7): the bins of every residual grouped
// by scale level, then the escape section (signs, magnitude classes, remainders). Decoded in
// WebAssembly (wasm/decoder.ts: decodeSymbols and the range decoder of 10.6 with 64-bit integers).
import { BitstreamError } from './errors.mjs';
import { alloc, callWasm, wasm } from './wasm.mjs';

/** The spec's error for the module's failure `code` in the symbol chunk `what`. */
export function symbolError(what, code, w) {
    if (code === 1) return new BitstreamError(`${what}: range decoding failed: q >= 2^24 (clause 10.6.4)`, 'E36');
    if (code === 2) return new BitstreamError(`${what}: data left over after decoding (clause 10.6.5)`, 'E38');
    return new BitstreamError(`${what}: escaped residual magnitude ${BigInt.asUintN(64, w.errorWide())} exceeds 2^62 - 1 (clause 10.5)`, 'E37');
}

/**
 * Decode the chunk `bytes` of n residuals whose levels are levels[0..n-1] into out[0..n-1]
 * (numbers). A residual of magnitude >= 2^53 is not exact as a number: it is put in `wide`
 * (index -> BigInt) and out[j] is set to NaN. Checks the chunk is exhausted. Returns the number
 * of escaped residuals.
 */
export function decodeSymbolChunk(bytes, levels, n, out, wide, what) {
    const w = wasm();
    const { po, pw, nesc } = symbolsInModule(w, bytes, levels, n, what);
    const res = new Float64Array(w.memory.buffer, po, n);
    out.set(res);
    if (nesc) {
        const big = new BigInt64Array(w.memory.buffer, pw, n);
        for (let j = 0; j < n; j++) if (Number.isNaN(res[j])) wide.set(j, big[j]);
    }
    return nesc;
}

/**
 * decodeSymbolChunk's decoding, its results left in the module's fresh arena: {po: the residuals (f64 [n];
 * NaN where |r| >= 2^53), pw: the escaped ones (i64 [n]), nesc}. levels: Uint8Array [n], or one level for all.
 */
export function symbolsInModule(w, bytes, levels, n, what) {
    if (bytes.length % 4) {
        throw new BitstreamError(`${what}: length ${bytes.length} is not a whole number of 32-bit words (clause 10.6.6)`, 'E35');
    }
    w.reset();
    const p = alloc(w, bytes.length), pl = alloc(w, n), po = alloc(w, 8 * n), pw = alloc(w, 8 * n);
    new Uint8Array(w.memory.buffer, p, bytes.length).set(bytes);
    const lv = new Uint8Array(w.memory.buffer, pl, n);
    if (typeof levels === 'number') lv.fill(levels);
    else lv.set(levels.subarray(0, n));
    const nesc = callWasm(() => w.decodeSymbols(p, bytes.length, pl, n, po, pw), (code) => symbolError(what, code, w));
    return { po, pw, nesc };
}
