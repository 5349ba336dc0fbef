// Bit-level parsing of syntax structures (spec clause 2): u(n), ue(v), se(v), f(32), byte_alignment(),
// every element checked against its range (clause 7.2) as it is parsed.
import { BitstreamError } from './errors.mjs';

const F32 = new Float32Array(1);
const U32 = new Uint32Array(F32.buffer);

export class BitReader {
    /** bytes: Uint8Array of the structure's payload; what: its name, for messages. */
    constructor(bytes, what) {
        this.bytes = bytes;
        this.what = what;
        this.pos = 0; // bit position
        this.nbits = bytes.length * 8;
    }

    get bitPosition() { return this.pos; }

    _need(n, name) {
        if (this.pos + n > this.nbits) {
            throw new BitstreamError(`${this.what}: truncated: ${name} needs ${n} bits beyond the end of the payload (clause 6.4)`, 'E17');
        }
    }

    /** u(n), 0 <= n <= 32 (a number). */
    u(n, name = 'element') {
        this._need(n, name);
        let v = 0;
        for (let i = 0; i < n; i++) {
            const p = this.pos++;
            v = v * 2 + ((this.bytes[p >>> 3] >>> (7 - (p & 7))) & 1);
        }
        return v;
    }

    /** u(n) for 32 < n <= 62, as a BigInt. */
    uBig(n, name = 'element') {
        this._need(n, name);
        let v = 0n;
        for (let i = 0; i < n; i++) {
            const p = this.pos++;
            v = (v << 1n) | BigInt((this.bytes[p >>> 3] >>> (7 - (p & 7))) & 1);
        }
        return v;
    }

    /** ue(v) with at most 31 leading zero bits (clause 2, E18): 0 .. 2^32 - 2. */
    ue(name = 'element') {
        let zeros = 0;
        for (;;) {
            this._need(1, name);
            const p = this.pos++;
            if ((this.bytes[p >>> 3] >>> (7 - (p & 7))) & 1) break;
            zeros++;
            if (zeros >= 32) {
                throw new BitstreamError(`${this.what}: ${name}: an Exp-Golomb code with 32 or more leading zero bits (clause 2)`, 'E18');
            }
        }
        return 2 ** zeros - 1 + this.u(zeros, name);
    }

    /** se(v): k = 1, 2, 3, 4 ... maps to 1, -1, 2, -2 ... */
    se(name = 'element') {
        const k = this.ue(name);
        return k % 2 === 1 ? (k + 1) / 2 : -(k / 2);
    }

    /** f(32): a finite binary32 value (as a number). */
    f32(name = 'element') {
        U32[0] = this.u(32, name);
        const v = F32[0];
        if (!Number.isFinite(v)) throw new BitstreamError(`${this.what}.${name} = ${v} is not finite (clause 2)`, 'E19');
        return v;
    }

    /** byte_alignment(): zero bits up to the next byte boundary (E20). */
    byteAlign() {
        while (this.pos & 7) {
            if (this.u(1, 'byte_alignment') !== 0) {
                throw new BitstreamError(`${this.what}: non-zero byte_alignment() bits (clause 2, E20)`, 'E20');
            }
        }
    }

    /** Whole bytes left after the current position (rounded down). */
    bytesLeft() { return (this.nbits - this.pos) >> 3; }

    /** The payload ends here: reject one or more whole bytes after the last element (E21). */
    expectEnd(allowPartialByte = false) {
        const endByte = Math.ceil(this.pos / 8);
        if (endByte < this.bytes.length) {
            throw new BitstreamError(`${this.what}: ${this.bytes.length - endByte} bytes after its last element (clause 6.4)`, 'E21');
        }
        if (!allowPartialByte && (this.pos & 7)) throw new Error('expectEnd inside a byte');
    }
}

/** Check an element's range (clause 7.2), BitstreamError naming it. */
export function checkRange(what, name, v, lo, hi) {
    if (!(v >= lo && v <= hi)) {
        throw new BitstreamError(`${what}.${name} = ${v} is outside its allowed range [${lo}, ${hi}] (clause 7.2)`, 'E19');
    }
    return v;
}

/** f(32) elements that shall be > 0 (clause 7.2). */
export function checkPositive(what, name, v) {
    if (!(v > 0)) throw new BitstreamError(`${what}.${name} = ${v} is outside its allowed range: finite and > 0 (clause 7.2)`, 'E19');
    return v;
}
