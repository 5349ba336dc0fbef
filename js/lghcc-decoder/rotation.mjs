// Rotations as a length index and x, y, z (spec clause 11.10, version 1.4): with a rotation_length
// unit, channel w of each Gaussian carries its length index k, and the rotation's w is implied:
// w = float32(sqrt(max(0, 2^-k - ((x*x + y*y) + z*z)))), every operation in binary64. Computed by the
// module (wasm/decoder.ts impliedRotations: wasm's f64 +, -, *, sqrt and the demotion to f32 are
// IEEE 754's, correctly rounded, so the bits are the spec's; tests/test_js_decoder.py compares it bit for bit
// with the normative Python, common/attributes.implied_w). This file keeps the length index check's message.
import { BitstreamError } from './errors.mjs';

/** E66 for row r, whose length index (channel wc of q32: i64 [n * M] seen as Int32Array [2 n M]) is outside [0, maxIndex]. */
export function lengthIndexError(q32, r, M, wc, maxIndex) {
    const b = r * M, lo = q32[2 * (b + wc)], hi = q32[2 * (b + wc) + 1];
    const k = hi === -1 && lo < 0 ? lo : hi * 2 ** 32 + (lo >>> 0);
    return new BitstreamError(`row ${r}: a rotation length index ${k} outside [0, max_rotation_length_index = ${maxIndex}] (clause 11.10, E66)`, 'E66');
}
