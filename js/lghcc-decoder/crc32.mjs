// CRC-32/ISO-HDLC (zlib's crc32; spec clause 3 and 6.1): reflected polynomial 0xEDB88320.
import { moduleCrc32 } from './wasm.mjs';

const TABLE = (() => {
    const t = new Int32Array(256 * 8);
    for (let n = 0; n < 256; n++) {
        let c = n;
        for (let k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320 ^ (c >>> 1) : c >>> 1;
        t[n] = c;
    }
    // slicing-by-8 tables
    for (let n = 0; n < 256; n++) for (let s = 1; s < 8; s++) t[s * 256 + n] = (t[(s - 1) * 256 + n] >>> 8) ^ t[t[(s - 1) * 256 + n] & 255];
    return t;
})();

/** CRC-32 of bytes[start, end), continuing from crc (0 for a fresh one). Returns an unsigned 32-bit value. */
export function crc32(bytes, start = 0, end = bytes.length, crc = 0) {
    let c = ~crc;
    let i = start;
    const T = TABLE;
    for (; i + 8 <= end; i += 8) {
        const a = c ^ (bytes[i] | (bytes[i + 1] << 8) | (bytes[i + 2] << 16) | (bytes[i + 3] << 24));
        c = T[1792 + (a & 255)] ^ T[1536 + ((a >>> 8) & 255)] ^ T[1280 + ((a >>> 16) & 255)] ^ T[1024 + (a >>> 24)]
            ^ T[768 + bytes[i + 4]] ^ T[512 + bytes[i + 5]] ^ T[256 + bytes[i + 6]] ^ T[bytes[i + 7]];
    }
    for (; i < end; i++) c = T[(c ^ bytes[i]) & 255] ^ (c >>> 8);
    return ~c >>> 0;
}

/**
 * A unit's CRC-32 (of a fresh CRC) over bytes[start, end): long ranges by the module (wasm/decoder.ts's
 * crc32, the same slicing by 8: this file's loop runs cold, in a fresh worker, at a fraction of the speed), short ones here.
 */
export function unitCrc32(bytes, start, end) {
    return end - start >= 4096 ? moduleCrc32(bytes, start, end) : crc32(bytes, start, end);
}
