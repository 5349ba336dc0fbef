// SHA-256 (FIPS 180-4), incremental, for the scene digest of clause 12 and the scale-table digest of
// clause 10.2.2 where no incremental native hash exists (Web Crypto's digest is one-shot).
const K = new Uint32Array([
    0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4, 0xab1c5ed5,
    0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe, 0x9bdc06a7, 0xc19bf174,
    0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f, 0x4a7484aa, 0x5cb0a9dc, 0x76f988da,
    0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7, 0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967,
    0x27b70a85, 0x2e1b2138, 0x4d2c6dfc, 0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85,
    0xa2bfe8a1, 0xa81a664b, 0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070,
    0x19a4c116, 0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
    0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7, 0xc67178f2]);

export class Sha256 {
    constructor() {
        this.h = new Int32Array([0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab, 0x5be0cd19]);
        this.buf = new Uint8Array(64);
        this.fill = 0;
        this.length = 0;
        this.w = new Int32Array(64);
    }

    /** Add bytes (a Uint8Array or any ArrayBufferView). */
    update(view) {
        const data = view instanceof Uint8Array ? view : new Uint8Array(view.buffer, view.byteOffset, view.byteLength);
        let i = 0;
        const n = data.length;
        this.length += n;
        if (this.fill) {
            while (i < n && this.fill < 64) this.buf[this.fill++] = data[i++];
            if (this.fill < 64) return this;
            this._block(this.buf, 0);
            this.fill = 0;
        }
        for (; i + 64 <= n; i += 64) this._block(data, i);
        while (i < n) this.buf[this.fill++] = data[i++];
        return this;
    }

    /** The 32-byte digest (the hash cannot be updated afterwards). */
    digest() {
        const bits = this.length * 8;
        const pad = new Uint8Array(((this.fill < 56 ? 56 : 120) - this.fill) + 8);
        pad[0] = 0x80;
        const hi = Math.floor(bits / 2 ** 32), lo = bits >>> 0;
        const e = pad.length;
        pad[e - 8] = hi >>> 24; pad[e - 7] = hi >>> 16; pad[e - 6] = hi >>> 8; pad[e - 5] = hi;
        pad[e - 4] = lo >>> 24; pad[e - 3] = lo >>> 16; pad[e - 2] = lo >>> 8; pad[e - 1] = lo;
        const len = this.length;
        this.update(pad);
        this.length = len;
        const out = new Uint8Array(32);
        for (let j = 0; j < 8; j++) {
            out[4 * j] = this.h[j] >>> 24; out[4 * j + 1] = this.h[j] >>> 16;
            out[4 * j + 2] = this.h[j] >>> 8; out[4 * j + 3] = this.h[j];
        }
        return out;
    }

    _block(d, o) {
        const w = this.w;
        for (let t = 0; t < 16; t++) w[t] = (d[o + 4 * t] << 24) | (d[o + 4 * t + 1] << 16) | (d[o + 4 * t + 2] << 8) | d[o + 4 * t + 3];
        for (let t = 16; t < 64; t++) {
            const a = w[t - 15], b = w[t - 2];
            const s0 = ((a >>> 7) | (a << 25)) ^ ((a >>> 18) | (a << 14)) ^ (a >>> 3);
            const s1 = ((b >>> 17) | (b << 15)) ^ ((b >>> 19) | (b << 13)) ^ (b >>> 10);
            w[t] = (w[t - 16] + s0 + w[t - 7] + s1) | 0;
        }
        const h = this.h;
        let A = h[0], B = h[1], C = h[2], D = h[3], E = h[4], F = h[5], G = h[6], H = h[7];
        for (let t = 0; t < 64; t++) {
            const S1 = ((E >>> 6) | (E << 26)) ^ ((E >>> 11) | (E << 21)) ^ ((E >>> 25) | (E << 7));
            const ch = (E & F) ^ (~E & G);
            const t1 = (H + S1 + ch + K[t] + w[t]) | 0;
            const S0 = ((A >>> 2) | (A << 30)) ^ ((A >>> 13) | (A << 19)) ^ ((A >>> 22) | (A << 10));
            const mj = (A & B) ^ (A & C) ^ (B & C);
            const t2 = (S0 + mj) | 0;
            H = G; G = F; F = E; E = (D + t1) | 0; D = C; C = B; B = A; A = (t1 + t2) | 0;
        }
        h[0] += A; h[1] += B; h[2] += C; h[3] += D; h[4] += E; h[5] += F; h[6] += G; h[7] += H;
    }
}

export function toHex(bytes) {
    let s = '';
    for (const b of bytes) s += b.toString(16).padStart(2, '0');
    return s;
}

let syncSha256 = null;

/** Use fn(bytes) -> 32-byte digest (synchronous, native: sha256_node.mjs's node:crypto) for sha256() instead of Web Crypto. */
export function useSyncSha256(fn) { syncSha256 = fn; }

/** One-shot SHA-256 of a byte array: a native synchronous hash where one was given, native Web Crypto where present, else this module. */
export async function sha256(bytes) {
    if (syncSha256) return syncSha256(bytes);
    const subtle = globalThis.crypto && globalThis.crypto.subtle;
    if (subtle) return new Uint8Array(await subtle.digest('SHA-256', bytes));
    return new Sha256().update(bytes).digest();
}
