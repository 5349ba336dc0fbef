// The range decoder of spec/entropy.md clause 10.6 (constriction's queue RangeDecoder: 64-bit
// state, 32-bit words, 24-bit precision), bit-exact, without BigInt.
//
// The state is kept as D = (point - lower) mod 2^64 and range R (clause 10.6.4 uses point, lower
// and range; only their difference enters the decoding, and the exhaustion check of 10.6.5 is on
// it too). D < R holds after every symbol (q < 2^24 implies D < 2^24 * scale <= R), and
// R is in [2^32, 2^64) between symbols. Each 64-bit quantity X is held as two exact doubles,
// X = hi * 2^24 + lo with 0 <= lo < 2^24, so that scale = R >> 24 is R's hi part and every
// product below stays under 2^53.
import { BitstreamError } from './errors.mjs';
import { LUT_SHIFT } from './tables.mjs';

const TWO24 = 16777216;
const TWO16 = 65536;
const INV24 = 1 / TWO24; // power-of-two scalings are exact: no division in the hot paths
const INV16 = 1 / TWO16;
const MAX_Q = TWO24; // q >= 2^24: non-conforming (clause 10.6.4)
const LUT_SIZE = (1 << (24 - LUT_SHIFT)) + 1;

export class RangeDecoder {
    /** bytes: the chunk (a Uint8Array of a multiple of 4 bytes, clause 10.6.6); what: its name. */
    constructor(bytes, what = 'chunk') {
        if (bytes.length % 4) {
            throw new BitstreamError(`${what}: length ${bytes.length} is not a whole number of 32-bit words (clause 10.6.6)`);
        }
        this.what = what;
        this.bytes = bytes;
        this.nwords = bytes.length >>> 2;
        this.pos = 0;
        const w0 = this._word(), w1 = this._word();
        // point = w0 * 2^32 + w1; lower = 0
        this.dhi = w0 * 256 + (w1 >>> 24);
        this.dlo = w1 & 0xFFFFFF;
        this.rhi = TWO24 * TWO16 - 1; // R = 2^64 - 1
        this.rlo = TWO24 - 1;
        this.q = 0; // the quantile of the last _quantile()
        this.r = 0; // D - q * scale
    }

    _word() {
        if (this.pos >= this.nwords) return 0; // missing words read as 0 (clause 10.6.6)
        const b = this.bytes, o = 4 * this.pos++;
        return (b[o] | (b[o + 1] << 8) | (b[o + 2] << 16) | (b[o + 3] << 24)) >>> 0;
    }

    _fail() {
        throw new BitstreamError(`${this.what}: range decoding failed: q >= 2^24 (clause 10.6.4)`);
    }

    /** q = D // scale, exactly; sets this.q and this.r. */
    _quantile() {
        const S = this.rhi, dhi = this.dhi, dlo = this.dlo;
        if (dhi >= S) this._fail(); // D >= 2^24 * scale
        let q = Math.floor((dhi * TWO24 + dlo) / S);
        const sh = Math.floor(S * INV16), sl = S - sh * TWO16;
        let r = (dhi * 256 - q * sh) * TWO16 + (dlo - q * sl);
        while (r < 0) { q--; r += S; }
        while (r >= S) { q++; r -= S; }
        this.q = q;
        this.r = r;
        return q;
    }

    /** After _quantile(): the symbol with cumulative c and frequency f was decoded. */
    _advance(c, f) {
        const S = this.rhi;
        const sh = Math.floor(S * INV24), sl = S - sh * TWO24;
        // R' = f * S
        const t = f * sl, th = Math.floor(t * INV24);
        const rhi = f * sh + th, rlo = t - th * TWO24;
        // D' = r + (q - c) * S
        const g = this.q - c, u = g * sl, uh = Math.floor(u * INV24);
        const r = this.r, rh = Math.floor(r * INV24);
        let lo = (u - uh * TWO24) + (r - rh * TWO24);
        let hi = g * sh + uh + rh;
        if (lo >= TWO24) { lo -= TWO24; hi += 1; }
        this._set(rhi, rlo, hi, lo);
    }

    /** New state R = (rhi, rlo), D = (dhi, dlo), renormalized when R < 2^32. */
    _set(rhi, rlo, dhi, dlo) {
        if (rhi < 256) { // R < 2^32: shift in the next word
            const w = this._word();
            this.rhi = (rhi * TWO24 + rlo) * 256;
            this.rlo = 0;
            this.dhi = (dhi * TWO24 + dlo) * 256 + (w >>> 24);
            this.dlo = w & 0xFFFFFF;
        } else {
            this.rhi = rhi; this.rlo = rlo; this.dhi = dhi; this.dlo = dlo;
        }
    }

    /** One symbol of model m of a ModelSet (clause 10.6.1). */
    decode(models, m) {
        const q = this._quantile();
        const cum = models.cum, o = models.off[m];
        let s = models.lut[m * LUT_SIZE + (q >>> LUT_SHIFT)];
        while (cum[o + s + 1] <= q) s++;
        const c = cum[o + s];
        this._advance(c, cum[o + s + 1] - c);
        return s;
    }

    /** A binary decision with frequency f1 of symbol 1 ({0: 2^24 - f1, 1: f1}, symbol 0 first). */
    decodeBinary(f1) {
        // q < c1 exactly when D < c1 * scale: compared in the hi/lo form, no division
        const S = this.rhi, dhi = this.dhi, dlo = this.dlo;
        if (dhi >= S) this._fail();
        const sh = Math.floor(S * INV24), sl = S - sh * TWO24;
        const c1 = TWO24 - f1;
        let t = c1 * sl, th = Math.floor(t * INV24);
        const xh = c1 * sh + th, xl = t - th * TWO24; // X = c1 * scale
        if (dhi < xh || (dhi === xh && dlo < xl)) {
            this._set(xh, xl, dhi, dlo);
            return 0;
        }
        t = f1 * sl; th = Math.floor(t * INV24);
        let lo = dlo - xl, hi = dhi - xh;
        if (lo < 0) { lo += TWO24; hi -= 1; }
        this._set(f1 * sh + th, t - th * TWO24, hi, lo);
        return 1;
    }

    /** A symbol of Uniform(2^w), 1 <= w <= 16. */
    decodeUniform(w) {
        const q = this._quantile();
        const f = 2 ** (24 - w);
        const s = Math.floor(q / f);
        this._advance(s * f, f);
        return s;
    }

    /**
     * Raw values (clause 10.6.3): widths[j] bits each (0..64), in 16-bit pieces; returns the pieces
     * assembled as numbers when every width is <= 53, else as BigInts where wider.
     */
    decodeBits(widths) {
        const n = widths.length;
        const out = new Array(n).fill(0);
        let maxw = 0;
        for (let j = 0; j < n; j++) if (widths[j] > maxw) maxw = widths[j];
        for (let shift = 0; shift < maxw; shift += 16) {
            for (let p = 1; p <= 16; p++) {
                for (let j = 0; j < n; j++) {
                    const w = widths[j];
                    if (w <= shift || Math.min(w - shift, 16) !== p) continue;
                    const piece = this.decodeUniform(p);
                    if (w > 53) out[j] = BigInt(out[j]) + (BigInt(piece) << BigInt(shift));
                    else out[j] += piece * 2 ** shift;
                }
            }
        }
        return out;
    }

    /** P values of n bits each (geometry raw values, clause G.6.3), as numbers (n <= 32). */
    decodeBitsSame(n, count) {
        const out = new Float64Array(count);
        for (let shift = 0; shift < n; shift += 16) {
            const w = Math.min(n - shift, 16), mul = 2 ** shift;
            for (let j = 0; j < count; j++) out[j] += this.decodeUniform(w) * mul;
        }
        return out;
    }

    /** Clause 10.6.5: every word consumed, and no symbol decoded or (point - lower) < 2^33 - 1. */
    checkExhausted() {
        const noSymbol = this.rhi === TWO24 * TWO16 - 1 && this.rlo === TWO24 - 1;
        const small = this.dhi * TWO24 + this.dlo < 2 ** 33 - 1; // exact: compared where it matters
        if (this.pos < this.nwords || !(noSymbol || small)) {
            throw new BitstreamError(`${this.what}: data left over after decoding (clause 10.6.5)`);
        }
    }
}
