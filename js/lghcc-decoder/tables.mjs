// The scale tables of spec/entropy.md clause 10.2, rebuilt from the normative data
// (scale_tables_data.mjs, generated from spec/tables/scale_tables.txt) and checked against the
// digest of clause 10.2.2 before first use.
import { SCALE_TABLES_VARINTS } from './scale_tables_data.mjs';
import { Sha256, toHex } from './sha256.mjs';

export const NUM_LEVELS = 64;
export const SCALE_TABLES_SHA256 = 'd190e032e31f5d4f0aaca7804206cdad1b718a0fbd79e00c1f458764b3da9d87';
export const ESCAPE_CLASS_FREQS = [
    4194289, 3145717, 2359288, 1769466, 1327100, 995325, 746494, 559871, 419904,
    314928, 236196, 177147, 132861, 99646, 74735, 56051, 42039, 31529, 23647,
    17736, 13302, 9977, 7483, 5612, 4210, 3157, 2368, 1777, 1333, 1000, 750, 563,
    422, 317, 238, 179, 134, 101, 76, 57, 43, 33, 25, 19, 14, 11, 9, 7, 5, 4, 3, 3,
    2, 2, 2, 2, 1, 1, 1, 1, 1, 1, 1];
export const HALF_WIDTHS_LIST = [
    4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 4, 5, 6, 6, 7, 8, 9, 10, 12, 13, 15, 17, 20,
    22, 26, 29, 33, 38, 43, 50, 57, 65, 74, 84, 96, 110, 126, 144, 165, 188, 215,
    246, 281, 321, 367, 420, 480, 549, 628, 717, 820, 938, 1072, 1226, 1402, 1603,
    1833, 2096, 2396, 2740, 3133, 3583, 4096];

export const LUT_SHIFT = 12; // symbol search starts at lut[q >> 12]
const LUT_SIZE = (1 << (24 - LUT_SHIFT)) + 1;

/**
 * A set of frequency models in flat arrays: model m has n_m symbols, cumulative frequencies
 * cum[off[m] + s] (s = 0..n_m, cum[off[m] + n_m] = 2^24) and a search table
 * lut[m * LUT_SIZE + (q >> LUT_SHIFT)] = the first symbol whose range can hold q.
 */
export class ModelSet {
    constructor(freqLists) {
        const count = freqLists.length;
        this.off = new Int32Array(count + 1);
        for (let m = 0; m < count; m++) this.off[m + 1] = this.off[m] + freqLists[m].length + 1;
        this.cum = new Int32Array(this.off[count]);
        this.size = new Int32Array(count);
        this.lut = new Uint16Array(count * LUT_SIZE);
        for (let m = 0; m < count; m++) {
            const f = freqLists[m], o = this.off[m];
            let c = 0;
            for (let s = 0; s < f.length; s++) { this.cum[o + s] = c; c += f[s]; }
            this.cum[o + f.length] = c;
            if (c !== 1 << 24) throw new Error(`model ${m}: frequencies sum to ${c}, not 2^24`);
            this.size[m] = f.length;
            let s = 0;
            for (let k = 0; k < LUT_SIZE; k++) {
                const q = Math.min(k << LUT_SHIFT, (1 << 24) - 1);
                while (this.cum[o + s + 1] <= q) s++;
                this.lut[m * LUT_SIZE + k] = s;
            }
        }
    }
}

function readVarints(b64) {
    const bin = typeof atob === 'function' ? atob(b64) : Buffer.from(b64, 'base64').toString('latin1');
    const out = [];
    let v = 0, mul = 1;
    for (let i = 0; i < bin.length; i++) {
        const c = bin.charCodeAt(i);
        v += (c & 127) * mul;
        if (c & 128) mul *= 128; else { out.push(v); v = 0; mul = 1; }
    }
    return out;
}

function canonicalDigest(levels) {
    const h = new Sha256();
    h.update(new TextEncoder().encode('LGHCC scale tables v1\n'));
    const words = [64, ...levels.map((f) => (f.length - 2) / 2)];
    for (const f of levels) words.push(...f);
    words.push(63, ...ESCAPE_CLASS_FREQS);
    const u = new Uint32Array(words.length);
    u.set(words);
    const bytes = new Uint8Array(u.buffer);
    if (new Uint8Array(new Uint16Array([1]).buffer)[0] !== 1) throw new Error('big-endian hosts are not supported');
    h.update(bytes);
    return toHex(h.digest());
}

let TABLES = null;

/**
 * Use tables another thread built and checked (a helper worker of pool.mjs gets them in its init
 * message: structured clones of scaleTables()'s typed arrays), instead of building them again.
 */
export function adoptScaleTables(tables) { TABLES = TABLES || tables; }

/** {levels: ModelSet of the 64 level tables, classes: ModelSet of the escape class table, half: Int32Array}. */
export function scaleTables() {
    if (TABLES) return TABLES;
    const v = readVarints(SCALE_TABLES_VARINTS);
    const levels = [];
    let p = 0;
    for (let i = 0; i < NUM_LEVELS; i++) {
        const L = v[p++];
        const half = v.slice(p, p + L + 1);
        p += L + 1;
        const f = new Array(2 * L + 2);
        for (let r = 0; r <= L; r++) { f[L + r] = half[r]; f[L - r] = half[r]; }
        f[2 * L + 1] = v[p++];
        levels.push(f);
    }
    const digest = canonicalDigest(levels);
    if (digest !== SCALE_TABLES_SHA256) {
        throw new Error(`scale tables: digest ${digest} is not the SCALE_TABLES_SHA256 of clause 10.2.2`);
    }
    const half = Int32Array.from(levels, (f) => (f.length - 2) / 2);
    for (let i = 0; i < NUM_LEVELS; i++) {
        if (half[i] !== HALF_WIDTHS_LIST[i]) throw new Error(`scale tables: L_${i} differs from clause 10.2.1`);
    }
    TABLES = { levels: new ModelSet(levels), classes: new ModelSet([ESCAPE_CLASS_FREQS]), half };
    return TABLES;
}
