// Rotations as a length index and x, y, z (spec clause 11.10, version 1.4): with a rotation_length
// unit, channel w of each Gaussian carries its length index k, and the rotation's w is implied:
// w = float32(sqrt(max(0, 2^-k - ((x*x + y*y) + z*z)))), every operation in binary64. Computed by the
// module (wasm/decoder.ts impliedRotations: wasm's f64 +, -, *, sqrt and the demotion to f32 are
// IEEE 754's, correctly rounded, so the bits are the spec's); impliedRotations here is the same in
// JavaScript (Math.sqrt and Math.fround are correctly rounded too), kept as the reference a test compares the module with.
import { BitstreamError } from './errors.mjs';

// 2^-k, k = 0 .. 15: exact binary64 constants (halving is exact)
const LENGTH_SQ = Float64Array.from({ length: 16 }, (_, k) => 1 / 2 ** k);

/** E66 for row r, whose length index (channel wc of q32: i64 [n * M] seen as Int32Array [2 n M]) is outside [0, maxIndex]. */
export function lengthIndexError(q32, r, M, wc, maxIndex) {
    const b = r * M, lo = q32[2 * (b + wc)], hi = q32[2 * (b + wc) + 1];
    const k = hi === -1 && lo < 0 ? lo : hi * 2 ** 32 + (lo >>> 0);
    return new BitstreamError(`row ${r}: a rotation length index ${k} outside [0, max_rotation_length_index = ${maxIndex}] (clause 11.10, E66)`);
}

/**
 * In place on the reconstructed values (Float32Array [n * M], row-major): channel wc of every row
 * becomes the implied w of its length index, read from q (the decoded quantized values, i64 [n * M]
 * little-endian, seen as Int32Array [2 n M]: no BigInt); an index below 0 or above maxIndex is E66.
 */
export function impliedRotations(values, q32, n, M, wc, maxIndex) {
    for (let r = 0, b = 0; r < n; r++, b += M) {
        const lo = q32[2 * (b + wc)], hi = q32[2 * (b + wc) + 1];
        if (hi !== 0 || lo < 0 || lo > maxIndex) throw lengthIndexError(q32, r, M, wc, maxIndex);
        const x = values[b + wc + 1], y = values[b + wc + 2], z = values[b + wc + 3];
        values[b + wc] = Math.fround(Math.sqrt(Math.max(0, LENGTH_SQ[lo] - ((x * x + y * y) + z * z))));
    }
}
