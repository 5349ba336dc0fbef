// The decoder's hot loops in WebAssembly (AssemblyScript; built by tools/node/build-wasm.mjs into
// ../wasm_module.mjs): the range decoder of spec/entropy.md clause 10.6 with native 64-bit
// integers, and geometry decoding (spec/geometry.md G.5, G.6). No managed objects: every array
// lives in an arena of linear memory that the caller resets per call (reset / alloc). A failure
// sets `err` (and errA, errB) and traps; the JS side turns the code into the spec's error.

// ---------------------------------------------------------------- arena

let top: usize = 0;

function heapStart(): usize { return (__heap_base + 15) & ~(<usize>15); }

/** Forget every allocation (the next alloc starts at the heap base). */
export function reset(): void { top = heapStart(); }

/** `bytes` of zeroed memory, 16-byte aligned; grows the memory when needed. */
export function alloc(bytes: i32): usize {
    if (top == 0) top = heapStart();
    const p = top;
    top = (p + <usize>bytes + 15) & ~(<usize>15);
    const have = <usize>memory.size() << 16;
    if (top > have) {
        if (memory.grow(<i32>((top - have + 0xFFFF) >> 16)) < 0) fail(ERR_MEMORY, 0, 0);
    }
    memory.fill(p, 0, <usize>bytes);
    return p;
}

@inline function i32At(p: usize, i: i32): i32 { return load<i32>(p + (<usize>i << 2)); }
@inline function setI32(p: usize, i: i32, v: i32): void { store<i32>(p + (<usize>i << 2), v); }
@inline function u8At(p: usize, i: i32): i32 { return <i32>load<u8>(p + <usize>i); }
@inline function setU8(p: usize, i: i32, v: i32): void { store<u8>(p + <usize>i, <u8>v); }

// ---------------------------------------------------------------- errors

const ERR_RANGE: i32 = 1;      // q >= 2^24 (10.6.4)
const ERR_EXHAUSTED: i32 = 2;  // data left over (10.6.5)
const ERR_DIRECT_COUNT: i32 = 3; // G.5.2 step 3, E29
const ERR_DIRECT_EQUAL: i32 = 4; // G.5.2, E30
const ERR_OCC_COUNT: i32 = 5;  // G.5.4, E31 (errA points at depth errB)
const ERR_TOTAL: i32 = 6;      // G.5.5, E32 (errA points)
const ERR_MIN: i32 = 7;        // G.5.5, E33
const ERR_MAX: i32 = 8;        // G.5.5, E34
const ERR_MEMORY: i32 = 9;     // linear memory could not grow

let err: i32 = 0;
let errA: i32 = 0;
let errB: i32 = 0;
export function errorCode(): i32 { return err; }
export function errorA(): i32 { return errA; }
export function errorB(): i32 { return errB; }

function fail(code: i32, a: i32, b: i32): void {
    err = code; errA = a; errB = b;
    unreachable();
}

// ---------------------------------------------------------------- range decoder (10.6)

// State as D = (point - lower) mod 2^64 and R = range (10.6.4 uses point, lower and range; only
// their difference enters decoding and the exhaustion check of 10.6.5).
let rBytes: usize = 0;
let rWords: i32 = 0;
let rPos: i32 = 0;
let rD: u64 = 0;
let rR: u64 = 0;

function word(): u64 {
    if (rPos >= rWords) return 0; // missing words read as 0 (10.6.6)
    const w = <u64>load<u32>(rBytes + (<usize>rPos << 2));
    rPos++;
    return w;
}

/** Start decoding the chunk of nbytes (a multiple of 4, checked by the caller) at p. */
export function rangeStart(p: usize, nbytes: i32): void {
    rBytes = p; rWords = nbytes >> 2; rPos = 0;
    const w0 = word();
    rD = (w0 << 32) | word();
    rR = 0xFFFFFFFFFFFFFFFF;
}

@inline function setState(R: u64, D: u64): void {
    if (R < 0x100000000) { // R < 2^32: shift in the next word
        rR = R << 32;
        rD = (D << 32) | word();
    } else { rR = R; rD = D; }
}

/** A binary decision with frequency f1 of symbol 1 ({0: 2^24 - f1, 1: f1}, symbol 0 first). */
function decodeBinary(f1: u64): i32 {
    const scale = rR >> 24, D = rD;
    if (D >> 24 >= scale) fail(ERR_RANGE, 0, 0); // q >= 2^24
    const X = (0x1000000 - f1) * scale;
    if (D < X) { setState(X, D); return 0; }
    setState(f1 * scale, D - X);
    return 1;
}

/** The quantile q = D / scale of a model decode, checked < 2^24. */
@inline function quantile(scale: u64): u64 {
    const q = rD / scale;
    if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
    return q;
}

/** A symbol of Uniform(2^w), 1 <= w <= 16. */
function decodeUniform(w: i32): u32 {
    const scale = rR >> 24, q = quantile(scale), sh = <u64>(24 - w);
    const s = q >> sh;
    setState(scale << sh, rD - ((s << sh) * scale));
    return <u32>s;
}

/** Clause 10.6.5: every word consumed, and no symbol decoded or (point - lower) < 2^33 - 1. */
function checkExhausted(): void {
    if (rPos < rWords || !(rR == 0xFFFFFFFFFFFFFFFF || rD < 0x1FFFFFFFF)) fail(ERR_EXHAUSTED, 0, 0);
}

// ---------------------------------------------------------------- geometry (G.5, G.6)

const NUM_OCC_CONTEXTS: i32 = 432;
const COUNT_LIMIT: i32 = 1024;
const LEVEL_COUNT_LIMIT: i32 = 64;

@inline function popcnt8(v: i32): i32 { return <i32>popcnt<u32>(<u32>v); }

/** The binary procedure of G.6.1 over decisions with contexts ctx[0..n-1] and counts T (i32 [2 C]) into out. */
function decodeBinarySequence(ctx: usize, n: i32, T: usize, numCtx: i32, out: usize, count: usize, order: usize): void {
    for (let c0 = 0; c0 < n;) {
        const c1 = min(n, c0 == 0 ? 256 : 2 * c0); // blocks [0, 256), [256, 512), [512, 1024), ...
        memory.fill(count, 0, <usize>(numCtx + 1) << 2);
        for (let j = c0; j < c1; j++) { const c = i32At(ctx, j) + 1; setI32(count, c, i32At(count, c) + 1); }
        for (let c = 0; c < numCtx; c++) setI32(count, c + 1, i32At(count, c + 1) + i32At(count, c));
        for (let j = c0; j < c1; j++) { const c = i32At(ctx, j), o = i32At(count, c); setI32(order, o, j); setI32(count, c, o + 1); }
        let start = 0;
        for (let c = 0; c < numCtx; c++) {
            const end = i32At(count, c);
            if (end == start) continue;
            const n0 = <i64>i32At(T, 2 * c), n1 = <i64>i32At(T, 2 * c + 1);
            let f1 = ((2 * n1 + 1) << 24) / (2 * (n0 + n1) + 2);
            if (f1 < 1) f1 = 1; else if (f1 > 0xFFFFFF) f1 = 0xFFFFFF;
            for (let t = start; t < end; t++) setI32(out, i32At(order, t), decodeBinary(<u64>f1));
            start = end;
        }
        for (let j = c0; j < c1; j++) { const a = 2 * i32At(ctx, j) + i32At(out, j); setI32(T, a, i32At(T, a) + 1); }
        limitCounts(T, numCtx, COUNT_LIMIT);
        c0 = c1;
    }
}

function limitCounts(T: usize, numCtx: i32, limit: i32): void {
    for (let c = 0; c < numCtx; c++) {
        let a = i32At(T, 2 * c), b = i32At(T, 2 * c + 1);
        while (a + b > limit) { a = (a + 1) >> 1; b = (b + 1) >> 1; }
        setI32(T, 2 * c, a); setI32(T, 2 * c + 1, b);
    }
}

/** The nodes of one level: coordinates q, sib1, parNbr, parSib1 and face neighbours nb (6 per node, -1 none). */
@unmanaged class Nodes {
    m: i32;
    qx: usize; qy: usize; qz: usize; sib1: usize; parNbr: usize; parSib1: usize; nb: usize;
}

/** Nodes of capacity cap, in the arena. */
function newNodes(cap: i32): Nodes {
    const s = changetype<Nodes>(alloc(<i32>offsetof<Nodes>()));
    s.qx = alloc(cap << 2); s.qy = alloc(cap << 2); s.qz = alloc(cap << 2);
    s.sib1 = alloc(cap); s.parNbr = alloc(cap); s.parSib1 = alloc(cap);
    s.nb = alloc(24 * cap);
    return s;
}

// scratch of capacity n (the most nodes a level can have), allocated per decode
let sOcc: usize = 0; let sCtx: usize = 0; let sCoded: usize = 0; let sDv: usize = 0;
let sNbrCount: usize = 0; let sDens: usize = 0; let sFirst: usize = 0; let sIndex: usize = 0;
let sCount: usize = 0; let sOrder: usize = 0; let sOwners: usize = 0;
let sLowX: usize = 0; let sLowY: usize = 0; let sLowZ: usize = 0;
let stOcc: usize = 0; let stIdcm: usize = 0; let stTwo: usize = 0;
let dx: usize = 0; let dy: usize = 0; let dz: usize = 0; let dCount: i32 = 0;
let outX: usize = 0; let outY: usize = 0; let outZ: usize = 0;
let gN: i32 = 0;

export function resultX(): usize { return outX; }
export function resultY(): usize { return outY; }
export function resultZ(): usize { return outZ; }

/**
 * Geometry decoding (G.5) of n points from the coded data at p (nbytes, after the header): bit
 * depths b0..b2, IDCM mode, bounding-box minimum. Leaves x, y, z (i32 [n], normative order) at
 * resultX/Y/Z().
 */
export function decodeGeometry(p: usize, nbytes: i32, n: i32, b0: i32, b1: i32, b2: i32, idcmMode: i32, m0: i32, m1: i32, m2: i32): void {
    err = 0;
    gN = n;
    const cap = n + 1;
    sOcc = alloc(cap); sCtx = alloc(cap << 2); sCoded = alloc(cap << 2); sDv = alloc(cap << 2);
    sNbrCount = alloc(cap); sDens = alloc(cap); sFirst = alloc(cap << 2); sIndex = alloc(cap << 2);
    sCount = alloc((NUM_OCC_CONTEXTS + 1) << 2); sOrder = alloc(cap << 2); sOwners = alloc((2 * cap) << 2);
    sLowX = alloc((2 * cap) << 2); sLowY = alloc((2 * cap) << 2); sLowZ = alloc((2 * cap) << 2);
    stOcc = alloc(8 * 2 * NUM_OCC_CONTEXTS * 4); stIdcm = alloc(18 * 4); stTwo = alloc(2 * 4);
    dx = alloc(cap << 2); dy = alloc(cap << 2); dz = alloc(cap << 2); dCount = 0;
    let a = newNodes(cap), b = newNodes(cap);
    a.m = 1; setU8(a.sib1, 0, 1); setU8(a.parSib1, 0, 1);
    for (let d = 0; d < 6; d++) setI32(a.nb, d, -1);
    rangeStart(p, nbytes);
    const D = max(b0, max(b1, b2));
    for (let l = 0; l < D; l++) {
        const R = D - l;
        if (idcmMode != 0 && R >= 2 && directCoding(a, b, R, b0, b1, b2, idcmMode)) { const t = a; a = b; b = t; }
        if (a.m == 0) break;
        occupancy(a, b, l, R, b0, b1, b2);
        const t = a; a = b; b = t;
    }
    checkExhausted();
    outputPoints(a, m0, m1, m2);
}

/** Direct coding (G.5.2) of the nodes `nodes`: pushes the direct points; returns true with the others in `keep`, false if none is eligible. */
function directCoding(nodes: Nodes, keep: Nodes, R: i32, b0: i32, b1: i32, b2: i32, mode: i32): bool {
    const m = nodes.m, sib1 = nodes.sib1, parNbr = nodes.parNbr, parSib1 = nodes.parSib1;
    const elig = sCoded, ctx = sCtx, flag = sDv;
    let ne = 0;
    for (let i = 0; i < m; i++) {
        const ok = mode == 1 ? (u8At(sib1, i) == 1 && u8At(parNbr, i) == 0 && u8At(parSib1, i) <= 2) : u8At(parNbr, i) == 0;
        if (ok) {
            setI32(elig, ne, i);
            setI32(ctx, ne, min(u8At(sib1, i) - 1, 2) * 3 + min(u8At(parSib1, i) - 1, 2));
            ne++;
        }
    }
    if (ne == 0) return false;
    decodeBinarySequence(ctx, ne, stIdcm, 9, flag, sCount, sOrder);
    // the direct nodes, in place of elig; isDirect in sOcc
    const isDirect = sOcc;
    memory.fill(isDirect, 0, <usize>m);
    let nd = 0;
    for (let e = 0; e < ne; e++) if (i32At(flag, e) == 1) { const i = i32At(elig, e); setI32(elig, nd++, i); setU8(isDirect, i, 1); }
    memory.fill(ctx, 0, <usize>nd << 2);
    decodeBinarySequence(ctx, nd, stTwo, 1, flag, sCount, sOrder);
    let P = 0;
    for (let e = 0; e < nd; e++) {
        const i = i32At(elig, e);
        setI32(sOwners, P++, i);
        if (i32At(flag, e)) setI32(sOwners, P++, i);
    }
    if (<i64>dCount + P + (m - nd) > <i64>gN) fail(ERR_DIRECT_COUNT, 0, 0);
    decodeBitsSame(min(R, b0), P, sLowX);
    decodeBitsSame(min(R, b1), P, sLowY);
    decodeBitsSame(min(R, b2), P, sLowZ);
    for (let o = 0; o < P; o++) {
        const i = i32At(sOwners, o);
        const px = (i32At(nodes.qx, i) << R) + i32At(sLowX, o);
        const py = (i32At(nodes.qy, i) << R) + i32At(sLowY, o);
        const pz = (i32At(nodes.qz, i) << R) + i32At(sLowZ, o);
        if (o > 0 && i32At(sOwners, o - 1) == i) {
            const prev = dCount - 1;
            if (i32At(dx, prev) == px && i32At(dy, prev) == py && i32At(dz, prev) == pz) fail(ERR_DIRECT_EQUAL, 0, 0);
        }
        setI32(dx, dCount, px); setI32(dy, dCount, py); setI32(dz, dCount, pz); dCount++;
    }
    const index = sIndex;
    let j = 0;
    for (let i = 0; i < m; i++) {
        if (u8At(isDirect, i)) { setI32(index, i, -1); continue; }
        setI32(index, i, j);
        setI32(keep.qx, j, i32At(nodes.qx, i)); setI32(keep.qy, j, i32At(nodes.qy, i)); setI32(keep.qz, j, i32At(nodes.qz, i));
        setU8(keep.sib1, j, u8At(sib1, i)); setU8(keep.parNbr, j, u8At(parNbr, i)); setU8(keep.parSib1, j, u8At(parSib1, i));
        j++;
    }
    keep.m = j;
    // the face neighbours among the nodes that are not direct (G.5.3)
    for (let i = 0; i < m; i++) {
        if (u8At(isDirect, i)) continue;
        const bk = 6 * i32At(index, i);
        for (let d = 0; d < 6; d++) { const u = i32At(nodes.nb, 6 * i + d); setI32(keep.nb, bk + d, u < 0 ? -1 : i32At(index, u)); }
    }
    return true;
}

/** P values of n bits each (G.6.3) into out (i32, as u32), 16-bit pieces low first. */
function decodeBitsSame(n: i32, count: i32, out: usize): void {
    memory.fill(out, 0, <usize>count << 2);
    for (let shift = 0; shift < n; shift += 16) {
        const w = min(n - shift, 16);
        for (let j = 0; j < count; j++) setI32(out, j, i32At(out, j) | <i32>(decodeUniform(w) << shift));
    }
}

/** Occupancy (G.5.4) of `nodes` at depth `depth`; the nodes of depth + 1 go to `next`. */
function occupancy(nodes: Nodes, next: Nodes, depth: i32, R: i32, b0: i32, b1: i32, b2: i32): void {
    const m = nodes.m, nb = nodes.nb;
    for (let k = 0; k < 8; k++) limitCounts(stOcc + <usize>(k * 2 * NUM_OCC_CONTEXTS * 4), NUM_OCC_CONTEXTS, LEVEL_COUNT_LIMIT);
    for (let i = 0; i < m; i++) {
        let c = 0;
        for (let d = 0; d < 6; d++) if (i32At(nb, 6 * i + d) >= 0) c++;
        setU8(sNbrCount, i, c); setU8(sDens, i, (c + 1) >> 1); // DENS = [0, 1, 1, 2, 2, 3, 3]
    }
    // the child bits k whose axes all split (an axis of bit depth <= R - 1 does not)
    const sx = R - 1 < b0, sy = R - 1 < b1, sz = R - 1 < b2;
    let last = 0;
    for (let k = 0; k < 8; k++) if ((sx || !(k & 4)) && (sy || !(k & 2)) && (sz || !(k & 1))) last = k;
    const occ = sOcc;
    memory.fill(occ, 0, <usize>m);
    for (let k = 0; k < 8; k++) {
        if (!((sx || !(k & 4)) && (sy || !(k & 2)) && (sz || !(k & 1)))) continue;
        const nc = occupancyContexts(k, k == last, m, occ, nb);
        decodeBinarySequence(sCtx, nc, stOcc + <usize>(k * 2 * NUM_OCC_CONTEXTS * 4), NUM_OCC_CONTEXTS, sDv, sCount, sOrder);
        const bit = 1 << k;
        for (let t = 0; t < nc; t++) if (i32At(sDv, t)) { const i = i32At(sCoded, t); setU8(occ, i, u8At(occ, i) | bit); }
        if (k == last) for (let i = 0; i < m; i++) if (!(u8At(occ, i) & (bit - 1))) setU8(occ, i, u8At(occ, i) | bit); // inferred occupied
    }
    let children = 0;
    for (let i = 0; i < m; i++) children += popcnt8(u8At(occ, i));
    if (<i64>dCount + children > <i64>gN) fail(ERR_OCC_COUNT, dCount + children, depth + 1);
    for (let i = 0, j = 0; i < m; i++) {
        const o = u8At(occ, i);
        setI32(sFirst, i, j);
        const x2 = i32At(nodes.qx, i) << 1, y2 = i32At(nodes.qy, i) << 1, z2 = i32At(nodes.qz, i) << 1;
        const pc = popcnt8(o), nbc = u8At(sNbrCount, i), s1 = u8At(nodes.sib1, i);
        for (let k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            setI32(next.qx, j, x2 + ((k >> 2) & 1)); setI32(next.qy, j, y2 + ((k >> 1) & 1)); setI32(next.qz, j, z2 + (k & 1));
            setU8(next.sib1, j, pc); setU8(next.parNbr, j, nbc); setU8(next.parSib1, j, s1);
            j++;
        }
    }
    next.m = children;
    childNeighbours(nodes, next, occ);
}

/** The contexts of child k (G.5.4) of the nodes whose bit k is coded: sCtx/sCoded [0..nc-1]; returns nc. */
function occupancyContexts(k: i32, isLast: bool, m: i32, occ: usize, nb: usize): i32 {
    const kx = k & 4, ky = k & 2, kz = k & 1, below = (1 << k) - 1;
    const jx = k ^ 4, jy = k ^ 2, jz = k ^ 1;
    let nc = 0;
    for (let i = 0; i < m; i++) {
        const o = u8At(occ, i);
        const before = popcnt8(o & below);
        if (isLast && before == 0) continue;
        const b = 6 * i;
        let sx: i32, sy: i32, sz: i32, u: i32;
        if (kx) { u = i32At(nb, b + 1); sx = ((o >> jx) & 1) + (u >= 0 ? (u8At(occ, u) >> jx) & 1 : 0); } else sx = i32At(nb, b) >= 0 ? 1 : 0;
        if (ky) { u = i32At(nb, b + 3); sy = ((o >> jy) & 1) + (u >= 0 ? (u8At(occ, u) >> jy) & 1 : 0); } else sy = i32At(nb, b + 2) >= 0 ? 1 : 0;
        if (kz) { u = i32At(nb, b + 5); sz = ((o >> jz) & 1) + (u >= 0 ? (u8At(occ, u) >> jz) & 1 : 0); } else sz = i32At(nb, b + 4) >= 0 ? 1 : 0;
        setI32(sCtx, nc, (((sx * 3 + sy) * 3 + sz) * 4 + (before < 3 ? before : 3)) * 4 + u8At(sDens, i));
        setI32(sCoded, nc++, i);
    }
    return nc;
}

/** The index of child k of node i, or -1. */
@inline function childIndex(occ: usize, i: i32, k: i32): i32 {
    const o = u8At(occ, i);
    return (o >> k) & 1 ? i32At(sFirst, i) + popcnt8(o & ((1 << k) - 1)) : -1;
}

/**
 * Face neighbours (G.5.3) of the children: the neighbour of a child across a face is a sibling,
 * or a child of the parent's neighbour across the same face.
 */
function childNeighbours(nodes: Nodes, next: Nodes, occ: usize): void {
    const m = nodes.m, pnb = nodes.nb, nb = next.nb;
    for (let i = 0, j = 0; i < m; i++) {
        const o = u8At(occ, i);
        for (let k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            for (let a = 0; a < 3; a++) {
                const bit = 4 >> a, b = 6 * j + 2 * a, up = (k & bit) ? 1 : 0;
                const u = i32At(pnb, 6 * i + 2 * a + up);
                const sib = childIndex(occ, i, k ^ bit), across = u < 0 ? -1 : childIndex(occ, u, k ^ bit);
                if (up) { setI32(nb, b, sib); setI32(nb, b + 1, across); } else { setI32(nb, b, across); setI32(nb, b + 1, sib); }
            }
            j++;
        }
    }
}

@inline function lessMsb(a: u32, b: u32): bool { return a < b && a < (a ^ b); }

/** Morton order (G.4) of offsets: x bits before y before z at each bit position; a < b. */
function mortonLess(ax: u32, ay: u32, az: u32, bx: u32, by: u32, bz: u32): bool {
    let best = ax ^ bx;
    const ty = ay ^ by, tz = az ^ bz;
    let axis = 0;
    if (lessMsb(best, ty)) { axis = 1; best = ty; }
    if (lessMsb(best, tz)) axis = 2;
    if (axis == 0) return ax < bx;
    return axis == 1 ? ay < by : az < bz;
}

@inline function directLess(a: i32, b: i32): bool {
    return mortonLess(<u32>i32At(dx, a), <u32>i32At(dy, a), <u32>i32At(dz, a), <u32>i32At(dx, b), <u32>i32At(dy, b), <u32>i32At(dz, b));
}

/** The direct points' indices sorted in Morton order (bottom-up merge sort; the points are distinct). */
function sortDirect(): usize {
    let src = alloc(dCount << 2), dst = alloc(dCount << 2);
    for (let i = 0; i < dCount; i++) setI32(src, i, i);
    for (let w = 1; w < dCount; w <<= 1) {
        for (let lo = 0; lo < dCount; lo += 2 * w) {
            const mid = min(lo + w, dCount), hi = min(lo + 2 * w, dCount);
            let i = lo, j = mid, o = lo;
            while (i < mid && j < hi) setI32(dst, o++, directLess(i32At(src, j), i32At(src, i)) ? i32At(src, j++) : i32At(src, i++));
            while (i < mid) setI32(dst, o++, i32At(src, i++));
            while (j < hi) setI32(dst, o++, i32At(src, j++));
        }
        const t = src; src = dst; dst = t;
    }
    return src;
}

/** G.5.5: the direct points merged with the leaves in Morton order, offset by the bounding-box minimum. */
function outputPoints(leaves: Nodes, m0: i32, m1: i32, m2: i32): void {
    const n = gN, total = dCount + leaves.m;
    if (total != n) fail(ERR_TOTAL, total, 0);
    const order = sortDirect();
    outX = alloc(n << 2); outY = alloc(n << 2); outZ = alloc(n << 2);
    let i = 0, j = 0;
    for (let o = 0; o < n; o++) {
        let takeDirect: bool;
        if (i >= dCount) takeDirect = false;
        else if (j >= leaves.m) takeDirect = true;
        else {
            const d = i32At(order, i);
            takeDirect = mortonLess(<u32>i32At(dx, d), <u32>i32At(dy, d), <u32>i32At(dz, d),
                <u32>i32At(leaves.qx, j), <u32>i32At(leaves.qy, j), <u32>i32At(leaves.qz, j));
        }
        if (takeDirect) { const d = i32At(order, i++); setI32(outX, o, i32At(dx, d)); setI32(outY, o, i32At(dy, d)); setI32(outZ, o, i32At(dz, d)); }
        else { setI32(outX, o, i32At(leaves.qx, j)); setI32(outY, o, i32At(leaves.qy, j)); setI32(outZ, o, i32At(leaves.qz, j)); j++; }
    }
    offsetAxis(outX, n, m0); offsetAxis(outY, n, m1); offsetAxis(outZ, n, m2);
}

function offsetAxis(c: usize, n: i32, bmin: i32): void {
    let mn: u32 = 0xFFFFFFFF;
    for (let t = 0; t < n; t++) { const v = <u32>i32At(c, t); if (v < mn) mn = v; }
    if (mn != 0) fail(ERR_MIN, 0, 0);
    for (let t = 0; t < n; t++) {
        const v = <i64><u32>i32At(c, t) + <i64>bmin;
        if (v > 0x7FFFFFFF) fail(ERR_MAX, 0, 0);
        setI32(c, t, <i32>v);
    }
}
