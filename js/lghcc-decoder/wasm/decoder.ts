// The decoder's hot loops in WebAssembly (AssemblyScript; built by tools/node/build-wasm.mjs into
// ../wasm_module.mjs): the range decoder of spec/entropy.md clause 10.6 with native 64-bit
// integers, and geometry decoding (spec/geometry.md G.5, G.6). No managed objects: every array
// lives in an arena of linear memory that the caller resets per call (reset / alloc). A failure
// sets `err` (and errA, errB) and traps; the JS side turns the code into the spec's error.

// ---------------------------------------------------------------- arena

let top: usize = 0;
let floor: usize = 0; // the end of what stays (the scale tables), set by keep()

function heapStart(): usize { return (__heap_base + 15) & ~(<usize>15); }

/** Forget every allocation since keep() (or all). */
export function reset(): void { top = floor ? floor : heapStart(); }

/** Keep every allocation made so far across later resets; returns the previous mark for release(). */
export function keep(): usize { const prev = floor; floor = top; return prev; }

/** Drop what keep() kept since the mark `prev`. */
export function release(prev: usize): void { floor = prev; top = prev ? prev : heapStart(); }

/** `bytes` of zeroed memory, 16-byte aligned; grows the memory when needed. */
export function alloc(bytes: i32): usize {
    const p = reserve(bytes);
    memory.fill(p, 0, <usize>bytes);
    return p;
}

/** The arithmetic progression first, first + step, ... of n int32 (rows of a LoD, 11.7.1) in fresh memory; returns its address. */
export function progression(first: i32, step: i32, n: i32): usize {
    const p = reserve(n << 2);
    for (let t = 0; t < n; t++) setI32(p, t, first + t * step);
    return p;
}

/** `bytes` of memory as alloc, not zeroed (for what the caller overwrites whole). */
export function reserve(bytes: i32): usize {
    err = 0; // a trap after this without fail() is no decoding error
    if (top == 0) top = heapStart();
    const p = top, end = p + <usize>bytes + 15;
    if (end < p) fail(ERR_MEMORY, 0, 0); // beyond the 4 GiB a 32-bit memory addresses (the sum wrapped)
    top = end & ~(<usize>15);
    const have = <usize>memory.size() << 16;
    if (top > have) {
        if (memory.grow(<i32>((top - have + 0xFFFF) >> 16)) < 0) fail(ERR_MEMORY, 0, 0);
    }
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
const ERR_ESCAPE: i32 = 10;    // escaped magnitude beyond 2^62 - 1 (10.5; errorWide() the magnitude)

let err: i32 = 0;
let errA: i32 = 0;
let errB: i32 = 0;
export function errorCode(): i32 { return err; }
export function errorA(): i32 { return errA; }
export function errorB(): i32 { return errB; }
let errWide: u64 = 0;
export function errorWide(): u64 { return errWide; }

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

/** Word pos of the chunk, 0 past its end (10.6.6); word() without the state in globals. */
@inline function wordAt(pos: i32): u64 { return pos < rWords ? <u64>load<u32>(rBytes + (<usize>pos << 2)) : 0; }

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

/** A binary decision with frequencies f0 = 2^24 - f1 of symbol 0 and f1 of symbol 1 (symbol 0 first); no branch on the symbol. */
@inline function decodeBinary(f0: u64, f1: u64): i32 {
    const scale = rR >> 24, D = rD;
    if (D >> 24 >= scale) fail(ERR_RANGE, 0, 0); // q >= 2^24
    const X = f0 * scale, one = D >= X;
    setState(select<u64>(f1 * scale, X, one), select<u64>(D - X, D, one));
    return <i32>one;
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

// The binary procedure of G.6.1 by chains: the decisions of a chunk are linked per context in
// sequence order (chainAdd) as their contexts are computed; at the chunk's end (chainDecode) the
// contexts present are visited in increasing order, each chain decoded in order, and each
// context's counts updated and limited as soon as its decisions are known (the frequency of
// one context never depends on another's counts, so this is the order of G.6.1 steps 1 to 3).
let chHead: usize = 0;    // i32 per context: the first id of its chain
let chTail: usize = 0;    // i32 per context: the address of its chain's open link
let chCount: usize = 0;   // i32 per context: its decisions in the chunk
let chPresent: usize = 0; // u32 bitmap of the contexts present in the chunk
let chNext: usize = 0;    // i32 per id: the next id of the same context
const CHAIN_WORDS: i32 = (NUM_OCC_CONTEXTS + 31) >> 5;

/** Chain scratch for ids below cap. */
function chainAlloc(cap: i32): void {
    chHead = alloc(NUM_OCC_CONTEXTS << 2); chTail = alloc(NUM_OCC_CONTEXTS << 2); chCount = alloc(NUM_OCC_CONTEXTS << 2);
    chPresent = alloc(CHAIN_WORDS << 2); chNext = alloc(cap << 2);
    for (let c = 0; c < NUM_OCC_CONTEXTS; c++) setI32(chTail, c, <i32>(chHead + (<usize>c << 2)));
}

/** Append decision `id` (its place in the output) with context c to the current chunk. */
@inline function chainAdd(id: i32, c: i32): void {
    const cc = <usize>c << 2;
    store<i32>(<usize>load<i32>(chTail + cc), id);
    store<i32>(chTail + cc, <i32>(chNext + (<usize>id << 2)));
    store<i32>(chCount + cc, load<i32>(chCount + cc) + 1);
    const pw = chPresent + (<usize>(c >> 5) << 2);
    store<u32>(pw, load<u32>(pw) | (<u32>1 << <u32>(c & 31)));
}

/**
 * Decode the current chunk with count table T: decision v of id to out[id] |= v << shift (u8);
 * the contexts whose counts changed are marked in the bitmap `dirty`.
 */
function chainDecode(T: usize, out: usize, shift: i32, dirty: usize): void {
    for (let w = 0; w < CHAIN_WORDS; w++) {
        const pw = chPresent + (<usize>w << 2);
        let bits = load<u32>(pw);
        if (!bits) continue;
        store<u32>(pw, 0);
        const dw = dirty + (<usize>w << 2);
        store<u32>(dw, load<u32>(dw) | bits);
        while (bits) {
            const c = (w << 5) + <i32>ctz(bits);
            bits &= bits - 1;
            const cc = <usize>c << 2, n = load<i32>(chCount + cc);
            const n0 = i32At(T, 2 * c), n1 = i32At(T, 2 * c + 1);
            let f1 = ((2 * <i64>n1 + 1) << 24) / (2 * (<i64>n0 + <i64>n1) + 2);
            if (f1 < 1) f1 = 1; else if (f1 > 0xFFFFFF) f1 = 0xFFFFFF;
            const f0 = <u64>(0x1000000 - f1);
            let id = load<i32>(chHead + cc), ones = 0;
            for (let t = 0; t < n; t++) {
                const v = decodeBinary(f0, <u64>f1);
                const o = out + <usize>id;
                store<u8>(o, load<u8>(o) | <u8>(v << shift));
                ones += v;
                id = i32At(chNext, id);
            }
            store<i32>(chCount + cc, 0);
            store<i32>(chTail + cc, <i32>(chHead + cc));
            let a = n0 + n - ones, b = n1 + ones;
            while (a + b > COUNT_LIMIT) { a = (a + 1) >> 1; b = (b + 1) >> 1; }
            setI32(T, 2 * c, a); setI32(T, 2 * c + 1, b);
        }
    }
}

/** The end of the chunk that starts at sequence index c0 (G.6.1: 0, 256, 512, 1024, ...). */
@inline function chunkEnd(c0: i32): i32 { return c0 == 0 ? 256 : 2 * c0; }

/** The binary procedure (G.6.1) over n decisions with contexts ctx (i32 [n]) and table T: decisions to out (u8 [n]). */
function decodeBinarySequence(ctx: usize, n: i32, T: usize, out: usize): void {
    memory.fill(out, 0, <usize>n);
    for (let c0 = 0; c0 < n;) {
        const c1 = min(n, chunkEnd(c0));
        for (let j = c0; j < c1; j++) chainAdd(j, i32At(ctx, j));
        chainDecode(T, out, 0, sDirtyNone);
        c0 = c1;
    }
}

/** The count limit (G.6.2) with L to the contexts of T marked in `dirty` (the others are within L already); clears the marks. */
function limitDirty(T: usize, dirty: usize, limit: i32): void {
    for (let w = 0; w < CHAIN_WORDS; w++) {
        const pw = dirty + (<usize>w << 2);
        let bits = load<u32>(pw);
        store<u32>(pw, 0);
        while (bits) {
            const c = (w << 5) + <i32>ctz(bits);
            bits &= bits - 1;
            let a = i32At(T, 2 * c), b = i32At(T, 2 * c + 1);
            while (a + b > limit) { a = (a + 1) >> 1; b = (b + 1) >> 1; }
            setI32(T, 2 * c, a); setI32(T, 2 * c + 1, b);
        }
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
let sOwners: usize = 0; let sDirtyNone: usize = 0; let stOccDirty: usize = 0;
let sLowX: usize = 0; let sLowY: usize = 0; let sLowZ: usize = 0;
let stOcc: usize = 0; let stIdcm: usize = 0; let stTwo: usize = 0;
let dx: usize = 0; let dy: usize = 0; let dz: usize = 0; let dCount: i32 = 0;
let sRuns: usize = 0; let nRuns: i32 = 0; // the ends of the direct points' runs
let outX: usize = 0; let outY: usize = 0; let outZ: usize = 0;
let gN: i32 = 0;

export function resultX(): usize { return outX; }
export function resultY(): usize { return outY; }
export function resultZ(): usize { return outZ; }
let outMax: StaticArray<i32> = [0, 0, 0]; // per axis, the largest decoded coordinate (the smallest is the bounding-box minimum, G.5.5)
export function resultMax(axis: i32): i32 { return outMax[axis]; }

/**
 * Geometry decoding (G.5) of n points from the coded data at p (nbytes, after the header): bit
 * depths b0..b2, IDCM mode, bounding-box minimum. Leaves x, y, z (i32 [n], normative order) at
 * resultX/Y/Z().
 */
export function decodeGeometry(p: usize, nbytes: i32, n: i32, b0: i32, b1: i32, b2: i32, idcmMode: i32, m0: i32, m1: i32, m2: i32): void {
    err = 0;
    gN = n;
    const cap = n + 1;
    sOcc = alloc(cap + 1); sCtx = alloc(cap << 2); sCoded = alloc(cap << 2); sDv = alloc(cap);
    sNbrCount = alloc(cap); sDens = alloc(cap); sFirst = alloc(cap << 2); sIndex = alloc(cap << 2);
    sOwners = alloc((2 * cap) << 2); chainAlloc(cap);
    sDirtyNone = alloc(CHAIN_WORDS << 2); stOccDirty = alloc(8 * CHAIN_WORDS << 2);
    sLowX = alloc((2 * cap) << 2); sLowY = alloc((2 * cap) << 2); sLowZ = alloc((2 * cap) << 2);
    stOcc = alloc(8 * 2 * NUM_OCC_CONTEXTS * 4); stIdcm = alloc(18 * 4); stTwo = alloc(2 * 4);
    dx = alloc(cap << 2); dy = alloc(cap << 2); dz = alloc(cap << 2); dCount = 0;
    sRuns = alloc(33 << 2); nRuns = 0; // at most one run per level, D <= 32
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
    decodeBinarySequence(ctx, ne, stIdcm, flag);
    // the direct nodes, in place of elig; isDirect in sOcc
    const isDirect = sOcc;
    memory.fill(isDirect, 0, <usize>m);
    let nd = 0;
    for (let e = 0; e < ne; e++) if (u8At(flag, e) == 1) { const i = i32At(elig, e); setI32(elig, nd++, i); setU8(isDirect, i, 1); }
    memory.fill(ctx, 0, <usize>nd << 2);
    decodeBinarySequence(ctx, nd, stTwo, flag);
    let P = 0;
    for (let e = 0; e < nd; e++) {
        const i = i32At(elig, e);
        setI32(sOwners, P++, i);
        if (u8At(flag, e)) setI32(sOwners, P++, i);
    }
    if (<i64>dCount + P + (m - nd) > <i64>gN) fail(ERR_DIRECT_COUNT, 0, 0);
    if (nd == 0) return false; // the node list is unchanged
    decodeBitsSame(min(R, b0), P, sLowX);
    decodeBitsSame(min(R, b1), P, sLowY);
    decodeBitsSame(min(R, b2), P, sLowZ);
    for (let o = 0; o < P; o++) {
        const i = i32At(sOwners, o);
        const px = (i32At(nodes.qx, i) << R) + i32At(sLowX, o);
        const py = (i32At(nodes.qy, i) << R) + i32At(sLowY, o);
        const pz = (i32At(nodes.qz, i) << R) + i32At(sLowZ, o);
        setI32(dx, dCount, px); setI32(dy, dCount, py); setI32(dz, dCount, pz); dCount++;
        if (o > 0 && i32At(sOwners, o - 1) == i) { // a node's second point: the two differ; kept in Morton order
            const prev = dCount - 2;
            if (i32At(dx, prev) == px && i32At(dy, prev) == py && i32At(dz, prev) == pz) fail(ERR_DIRECT_EQUAL, 0, 0);
            if (directLess(prev + 1, prev)) { swapI32(dx, prev); swapI32(dy, prev); swapI32(dz, prev); }
        }
    }
    setI32(sRuns, nRuns++, dCount); // this level's direct points: in Morton order (its nodes are, and their cells are disjoint)
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
    for (let k = 0; k < 8; k++) limitDirty(stOcc + <usize>(k * 2 * NUM_OCC_CONTEXTS * 4), stOccDirty + <usize>(k * CHAIN_WORDS * 4), LEVEL_COUNT_LIMIT);
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
    memory.fill(occ, 0, <usize>m + 1); // occ[m] = 0: the occupancy of a missing neighbour
    for (let k = 0; k < 8; k++) {
        if (!((sx || !(k & 4)) && (sy || !(k & 2)) && (sz || !(k & 1)))) continue;
        occupancyPass(k, k == last, m, occ, nb);
    }
    let children = 0;
    for (let i = 0; i < m; i++) { setI32(sFirst, i, children); children += popcnt8(u8At(occ, i)); }
    if (<i64>dCount + children > <i64>gN) fail(ERR_OCC_COUNT, dCount + children, depth + 1);
    next.m = children;
    nextLevel(nodes, next, occ);
}

/** The occupancy bits of a node's neighbour u (-1: none, whose bits are 0: occ[m]). */
@inline function occOf(occ: usize, u: i32, m: i32): i32 { return u8At(occ, select<i32>(m, u, u < 0)); }

/**
 * Pass k of G.5.4 step 3: each node's context as it comes (bits j < k only, so no decision of this
 * pass changes another's context), the decisions by chains per G.6.1 chunk, bit k into occ.
 */
function occupancyPass(k: i32, isLast: bool, m: i32, occ: usize, nb: usize): void {
    const kx = k & 4, ky = k & 2, kz = k & 1, below = (1 << k) - 1, bit = 1 << k;
    const jx = k ^ 4, jy = k ^ 2, jz = k ^ 1;
    const T = stOcc + <usize>(k * 2 * NUM_OCC_CONTEXTS * 4), dirty = stOccDirty + <usize>(k * CHAIN_WORDS * 4);
    let t = 0, start = 0, end = 256; // decisions so far; the current chunk [start, end)
    for (let i = 0; i < m; i++) {
        const o = u8At(occ, i);
        const before = popcnt8(o & below);
        if (isLast && before == 0) { setU8(occ, i, o | bit); continue; } // inferred occupied
        const b = 6 * i;
        const sx = kx ? ((o >> jx) & 1) + ((occOf(occ, i32At(nb, b + 1), m) >> jx) & 1) : <i32>(i32At(nb, b) >= 0);
        const sy = ky ? ((o >> jy) & 1) + ((occOf(occ, i32At(nb, b + 3), m) >> jy) & 1) : <i32>(i32At(nb, b + 2) >= 0);
        const sz = kz ? ((o >> jz) & 1) + ((occOf(occ, i32At(nb, b + 5), m) >> jz) & 1) : <i32>(i32At(nb, b + 4) >= 0);
        chainAdd(i, (((sx * 3 + sy) * 3 + sz) * 4 + min(before, 3)) * 4 + u8At(sDens, i));
        if (++t == end) { chainDecode(T, occ, k, dirty); start = end; end = chunkEnd(end); }
    }
    if (t > start) chainDecode(T, occ, k, dirty);
}

/** The index of child j of a node with occupancy o whose first child is `first`, or -1. */
@inline function childAt(o: i32, first: i32, j: i32): i32 {
    return select<i32>(first + popcnt8(o & ((1 << j) - 1)), -1, (o >> j) & 1);
}

/**
 * The nodes of depth + 1 (G.5.4 step 5) and their face neighbours (G.5.3): the neighbour of a
 * child across a face is a sibling, or a child of the parent's neighbour across the same face.
 */
function nextLevel(nodes: Nodes, next: Nodes, occ: usize): void {
    const m = nodes.m, pnb = nodes.nb, nb = next.nb;
    for (let i = 0, j = 0; i < m; i++) {
        const o = u8At(occ, i), first = i32At(sFirst, i);
        const x2 = i32At(nodes.qx, i) << 1, y2 = i32At(nodes.qy, i) << 1, z2 = i32At(nodes.qz, i) << 1;
        const pc = popcnt8(o), nbc = u8At(sNbrCount, i), s1 = u8At(nodes.sib1, i);
        for (let bits = o; bits; bits &= bits - 1, j++) {
            const k = <i32>ctz(bits);
            setI32(next.qx, j, x2 + ((k >> 2) & 1)); setI32(next.qy, j, y2 + ((k >> 1) & 1)); setI32(next.qz, j, z2 + (k & 1));
            setU8(next.sib1, j, pc); setU8(next.parNbr, j, nbc); setU8(next.parSib1, j, s1);
            for (let a = 0; a < 3; a++) {
                const bit = 4 >> a, up = (k & bit) != 0, sibling = k ^ bit;
                const u = i32At(pnb, 6 * i + 2 * a + <i32>up), uu = select<i32>(m, u, u < 0); // occ[m] = 0: no neighbour
                const sib = childAt(o, first, sibling), across = childAt(u8At(occ, uu), i32At(sFirst, uu), sibling);
                setI32(nb, 6 * j + 2 * a, select<i32>(sib, across, up)); setI32(nb, 6 * j + 2 * a + 1, select<i32>(across, sib, up));
            }
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

@inline function swapI32(p: usize, i: i32): void { const t = i32At(p, i); setI32(p, i, i32At(p, i + 1)); setI32(p, i + 1, t); }

/**
 * The direct points' indices sorted in Morton order: the runs of sRuns (one per level, each in
 * order) merged pairwise until one is left (the points are distinct).
 */
function sortDirect(): usize {
    let src = alloc(dCount << 2), dst = alloc(dCount << 2);
    for (let i = 0; i < dCount; i++) setI32(src, i, i);
    for (let runs = nRuns; runs > 1;) {
        let out = 0;
        for (let r = 0; r < runs; r += 2) {
            const lo = r == 0 ? 0 : i32At(sRuns, r - 1), mid = i32At(sRuns, r), hi = r + 1 < runs ? i32At(sRuns, r + 1) : mid;
            let i = lo, j = mid, o = lo;
            while (i < mid && j < hi) setI32(dst, o++, directLess(i32At(src, j), i32At(src, i)) ? i32At(src, j++) : i32At(src, i++));
            while (i < mid) setI32(dst, o++, i32At(src, i++));
            while (j < hi) setI32(dst, o++, i32At(src, j++));
            setI32(sRuns, out++, hi);
        }
        runs = out;
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
    outMax[0] = offsetAxis(outX, n, m0); outMax[1] = offsetAxis(outY, n, m1); outMax[2] = offsetAxis(outZ, n, m2);
}

/** The offsets c (u32 [n]) plus bmin, in place; returns the largest coordinate. */
function offsetAxis(c: usize, n: i32, bmin: i32): i32 {
    let mn: u32 = 0xFFFFFFFF, mx: u32 = 0;
    for (let t = 0; t < n; t++) { const v = <u32>i32At(c, t); mn = min(mn, v); mx = max(mx, v); }
    if (mn != 0) fail(ERR_MIN, 0, 0);
    if (<i64>mx + <i64>bmin > 0x7FFFFFFF) fail(ERR_MAX, 0, 0);
    for (let t = 0; t < n; t++) setI32(c, t, i32At(c, t) + bmin);
    return <i32>(<i64>mx + <i64>bmin);
}

// ---------------------------------------------------------------- k nearest neighbours (11.7.2)

// The canonical k-NN (Annex H.3 with a ball holding the whole tile): for each query, the first k
// data points in increasing order of (d2, index), d2 the exact squared distance (u64: offsets
// are below MAX_EXTENT < 2^31, so d2 < 3 * 2^62). The data points are binned in a dense grid of
// cubic cells (side 2^b); a query visits the cells in growing shells around its own and stops
// once every unvisited point is provably (strictly) farther than its k-th, so points at equal
// distance compete by index exactly.
const CELLS_PER_POINT: i32 = 2; // grid size: at most this many cells per data point (and 4096); 4 beat 2 once rows were visited as runs, 2 beats 4 (1.02-1.08x) since the k-list insertion has no branch

let gB: i32 = 0; let gSide: i64 = 0; let gNx: i32 = 0; let gNy: i32 = 0; let gNz: i32 = 0;
// the grid's points in cell order: offsets gPx, gPy, gPz and ids gPid (i32 each, 3 more read past the end by visitPacked)
let gStart: usize = 0; let gPx: usize = 0; let gPy: usize = 0; let gPz: usize = 0; let gPid: usize = 0;
let worst: u64 = 0; // the k-th distance of the list once it holds k, else the largest u64
let hD: usize = 0; let hI: usize = 0; let kK: i32 = 0; // the list: distances hD (u64) and ids hI (i32), or keys hD when gPacked
// Extents up to PACKED_EXTENT (3 e^2 < 2^32, every tile seen in practice): the list holds keys
// d2 * 2^32 + id (u64), whose order is the (d2, index) order, and d2 is computed in 32 bits.
const PACKED_EXTENT: i32 = 37837;
let gPacked: bool = false;
let gLanes: usize = 0; // 16 bytes: the d2 of visitPacked's four points

@inline function u64At(p: usize, i: i32): u64 { return load<u64>(p + (<usize>i << 3)); }
@inline function setU64(p: usize, i: i32, v: u64): void { store<u64>(p + (<usize>i << 3), v); }

/**
 * Neighbours of the query rows (qs [nq]) among the data rows (ds [nd], ascending) of the tile's
 * points x, y, z (i32 [*]; lo: their minima, e: their extents): ids to idx [nq * k] nearest first,
 * counts to cnt (u8 [nq]).
 */
export function gridNeighbours(x: usize, y: usize, z: usize, lo0: i32, lo1: i32, lo2: i32, e0: i32, e1: i32, e2: i32,
    ds: usize, nd: i32, qs: usize, nq: i32, k: i32, idx: usize, cnt: usize): void {
    err = 0;
    buildGrid(x, y, z, lo0, lo1, lo2, e0, e1, e2, ds, nd);
    hD = alloc(k << 3); hI = alloc(k << 2); kK = k; gLanes = alloc(16);
    gPacked = max(e0, max(e1, e2)) <= PACKED_EXTENT;
    for (let r = 0; r < nq; r++) {
        const i = i32At(qs, r);
        const size = search(i32At(x, i) - lo0, i32At(y, i) - lo1, i32At(z, i) - lo2);
        for (let m = 0; m < size; m++) setI32(idx, r * k + m, gPacked ? <i32>u64At(hD, m) : i32At(hI, m));
        setU8(cnt, r, size);
    }
}

function buildGrid(x: usize, y: usize, z: usize, lo0: i32, lo1: i32, lo2: i32, e0: i32, e1: i32, e2: i32, ds: usize, n: i32): void {
    const limit = <f64>max(4096, CELLS_PER_POINT * n);
    let b = 0;
    while (<f64>((e0 >> b) + 1) * <f64>((e1 >> b) + 1) * <f64>((e2 >> b) + 1) > limit) b++;
    gB = b; gSide = <i64>1 << b;
    gNx = (e0 >> b) + 1; gNy = (e1 >> b) + 1; gNz = (e2 >> b) + 1;
    const cells = gNx * gNy * gNz;
    const start = alloc((cells + 1) << 2), cell = alloc(n << 2);
    for (let t = 0; t < n; t++) {
        const j = i32At(ds, t);
        const c = (((i32At(x, j) - lo0) >> b) * gNy + ((i32At(y, j) - lo1) >> b)) * gNz + ((i32At(z, j) - lo2) >> b);
        setI32(cell, t, c);
        setI32(start, c + 1, i32At(start, c + 1) + 1);
    }
    for (let c = 1; c <= cells; c++) setI32(start, c, i32At(start, c) + i32At(start, c - 1));
    // the points sorted by cell (stable), as offsets from lo
    gPx = alloc((n + 3) << 2); gPy = alloc((n + 3) << 2); gPz = alloc((n + 3) << 2); gPid = alloc(n << 2);
    const fill = alloc(cells << 2);
    memory.copy(fill, start, <usize>cells << 2);
    for (let t = 0; t < n; t++) {
        const j = i32At(ds, t), c = i32At(cell, t), o = i32At(fill, c);
        setI32(fill, c, o + 1);
        setI32(gPx, o, i32At(x, j) - lo0); setI32(gPy, o, i32At(y, j) - lo1); setI32(gPz, o, i32At(z, j) - lo2); setI32(gPid, o, j);
    }
    gStart = start;
}

/** The k nearest of (qx, qy, qz) (offsets from lo) sorted by (d2, id) into hD/hI; returns their count. */
function search(qx: i32, qy: i32, qz: i32): i32 {
    const b = gB, cx = qx >> b, cy = qy >> b, cz = qz >> b;
    worst = u64.MAX_VALUE;
    if (gPacked) for (let j = 0; j < kK; j++) setU64(hD, j, u64.MAX_VALUE); // offerKey's empty places
    let size = visitBlock(cx, cy, cz, qx, qy, qz);
    for (let s = 1; ; s++) {
        if (s > 1) size = visitShell(cx, cy, cz, s, qx, qy, qz, size);
        const bound = unvisitedBound(cx, cy, cz, s, qx, qy, qz);
        if (bound < 0 || worst < <u64>(bound * bound)) break; // worst < MAX: size == k
    }
    return size;
}

/**
 * The cells within Chebyshev distance 1 of the query's, the query's own first: for each (X, Y)
 * the cells Z = cz - 1 .. cz + 1 are consecutive, and so are their points: one run per (X, Y),
 * less its end cells that lie wholly farther than the k-th (or the whole run). Returns the list's size.
 */
function visitBlock(cx: i32, cy: i32, cz: i32, qx: i32, qy: i32, qz: i32): i32 {
    const ny = gNy, nz = gNz, own = (cx * ny + cy) * nz + cz;
    const below = cz > 0, above = cz + 1 < nz, gBelow = gap(cz - 1, cz, qz), gAbove = gap(cz + 1, cz, qz);
    let size = visitCell(own, qx, qy, qz, 0);
    const half = gSide >> 1; // the rows on the query's nearer sides first: the k-th distance falls sooner
    const sx: i32 = <i64>qx - (<i64>cx << gB) >= half ? 1 : -1, sy: i32 = <i64>qy - (<i64>cy << gB) >= half ? 1 : -1;
    for (let t = 0; t < 9; t++) {
        const X = cx + sx * unchecked(ROWS1[2 * t]), Y = cy + sy * unchecked(ROWS1[2 * t + 1]);
        if (<u32>X >= <u32>gNx || <u32>Y >= <u32>ny) continue;
        const exy = gap(X, cx, qx) + gap(Y, cy, qy);
        if (exy > worst) continue;
        const row = (X * ny + Y) * nz;
        const z0 = below && exy + gBelow <= worst ? cz - 1 : cz, z1 = above && exy + gAbove <= worst ? cz + 1 : cz;
        if (t == 0) { // the own cell is done
            if (z0 < cz) size = visitCell(row + z0, qx, qy, qz, size);
            if (z1 > cz) size = visitCell(row + z1, qx, qy, qz, size);
        } else size = visitPoints(i32At(gStart, row + z0), i32At(gStart, row + z1 + 1), qx, qy, qz, size);
    }
    return size;
}

// The rows (X, Y) of visitBlock as steps towards the query's nearer sides: its own, the faces, the diagonals.
const ROWS1: StaticArray<i32> = [0, 0, 1, 0, 0, 1, -1, 0, 0, -1, 1, 1, 1, -1, -1, 1, -1, -1];

/** The least distance along one axis from the query to a point outside the block of radius s; -1 if the block covers the grid. */
function unvisitedBound(cx: i32, cy: i32, cz: i32, s: i32, qx: i32, qy: i32, qz: i32): i64 {
    const S = gSide;
    let bound: i64 = i64.MAX_VALUE;
    if (cx - s > 0) bound = min(bound, <i64>qx - <i64>(cx - s) * S + 1);
    if (cx + s < gNx - 1) bound = min(bound, <i64>(cx + s + 1) * S - <i64>qx);
    if (cy - s > 0) bound = min(bound, <i64>qy - <i64>(cy - s) * S + 1);
    if (cy + s < gNy - 1) bound = min(bound, <i64>(cy + s + 1) * S - <i64>qy);
    if (cz - s > 0) bound = min(bound, <i64>qz - <i64>(cz - s) * S + 1);
    if (cz + s < gNz - 1) bound = min(bound, <i64>(cz + s + 1) * S - <i64>qz);
    return bound == i64.MAX_VALUE ? -1 : bound;
}

/** The squared distance along one axis from the query (cell c, offset q) to cell C. */
@inline function gap(C: i32, c: i32, q: i32): u64 {
    const d: i64 = C < c ? <i64>q - <i64>(C + 1) * gSide + 1 : C > c ? <i64>C * gSide - <i64>q : 0;
    return <u64>(d * d);
}

/** The cells at Chebyshev distance s from (cx, cy, cz), clipped to the grid; a cell wholly farther than the k-th is skipped. */
function visitShell(cx: i32, cy: i32, cz: i32, s: i32, qx: i32, qy: i32, qz: i32, size: i32): i32 {
    const ny = gNy, nz = gNz, k = kK;
    const x0 = max(0, cx - s), x1 = min(gNx - 1, cx + s);
    const y0 = max(0, cy - s), y1 = min(ny - 1, cy + s);
    const z0 = max(0, cz - s), z1 = min(nz - 1, cz + s);
    for (let X = x0; X <= x1; X++) {
        const fx = X == cx - s || X == cx + s, ex = gap(X, cx, qx);
        for (let Y = y0; Y <= y1; Y++) {
            const row = (X * ny + Y) * nz, exy = ex + gap(Y, cy, qy);
            if (exy > worst) continue;
            if (fx || Y == cy - s || Y == cy + s) { // the whole row: one run, less its end cells wholly farther than the k-th
                let a = z0, b = z1;
                while (a < cz && exy + gap(a, cz, qz) > worst) a++;
                while (b > cz && exy + gap(b, cz, qz) > worst) b--;
                size = visitPoints(i32At(gStart, row + a), i32At(gStart, row + b + 1), qx, qy, qz, size);
            } else {
                if (cz - s >= 0) size = visitNear(row, cz - s, cz, qx, qy, qz, exy, size);
                if (cz + s < nz) size = visitNear(row, cz + s, cz, qx, qy, qz, exy, size);
            }
        }
    }
    return size;
}

@inline function visitNear(row: i32, Z: i32, cz: i32, qx: i32, qy: i32, qz: i32, exy: u64, size: i32): i32 {
    if (exy + gap(Z, cz, qz) > worst) return size;
    return visitCell(row + Z, qx, qy, qz, size);
}

@inline function visitCell(c: i32, qx: i32, qy: i32, qz: i32, size: i32): i32 {
    return visitPoints(i32At(gStart, c), i32At(gStart, c + 1), qx, qy, qz, size);
}

/** The grid's points p0 .. p1 - 1 offered to the list (those within the k-th distance). */
function visitPoints(p0: i32, p1: i32, qx: i32, qy: i32, qz: i32, size: i32): i32 {
    return gPacked ? visitPacked(p0, p1, qx, qy, qz, size) : visitWide(p0, p1, qx, qy, qz, size);
}

/**
 * Four points at a time: their d2 (each square < 2^31, the sum < 2^32: exact in u32 lanes), and
 * those within the k-th distance (as it was before the four; offerKey checks again) offered.
 */
function visitPacked(p0: i32, p1: i32, qx: i32, qy: i32, qz: i32, size: i32): i32 {
    const vx = i32x4.splat(qx), vy = i32x4.splat(qy), vz = i32x4.splat(qz), lanes = gLanes;
    for (let p = p0; p < p1; p += 4) {
        const o = <usize>p << 2;
        const dx = i32x4.sub(v128.load(gPx + o), vx), dy = i32x4.sub(v128.load(gPy + o), vy), dz = i32x4.sub(v128.load(gPz + o), vz);
        const d2 = i32x4.add(i32x4.add(i32x4.mul(dx, dx), i32x4.mul(dy, dy)), i32x4.mul(dz, dz));
        let bits = i32x4.bitmask(i32x4.le_u(d2, i32x4.splat(<i32>min<u64>(worst, 0xFFFFFFFF))));
        const rest = p1 - p;
        if (rest < 4) bits &= (1 << rest) - 1;
        if (!bits) continue;
        v128.store(lanes, d2);
        do {
            const t = <i32>ctz(bits);
            bits &= bits - 1;
            size = offerKey((<u64>load<u32>(lanes + (<usize>t << 2)) << 32) | <u64><u32>i32At(gPid, p + t), size);
        } while (bits);
    }
    return size;
}

/**
 * Insert key into the ascending list hD of k keys, u64.MAX_VALUE at the empty places (no key is: its
 * id would be 2^32 - 1), with no branch on the data: place j becomes min(a[j], max(a[j - 1], key)),
 * which is a[j] below the key's place, the key at it, a[j - 1] above it (keys are distinct: the ids
 * are); a key above the k-th leaves the list as it was. Returns the number of keys in the list.
 */
function offerKey(key: u64, size: i32): i32 {
    const k = kK;
    let above = u64At(hD, k - 1);
    for (let j = k - 1; j > 0; j--) {
        const below = u64At(hD, j - 1);
        setU64(hD, j, min(above, max(below, key)));
        above = below;
    }
    setU64(hD, 0, min(above, key));
    const last = u64At(hD, k - 1);
    if (last != u64.MAX_VALUE) worst = last >> 32;
    return size + <i32>(size < k);
}

function visitWide(p0: i32, p1: i32, qx: i32, qy: i32, qz: i32, size: i32): i32 {
    for (let p = p0; p < p1; p++) {
        const dx = <i64>i32At(gPx, p) - <i64>qx, dy = <i64>i32At(gPy, p) - <i64>qy, dz = <i64>i32At(gPz, p) - <i64>qz;
        const d = <u64>(dx * dx) + <u64>(dy * dy) + <u64>(dz * dz);
        if (d <= worst) size = offer(d, i32At(gPid, p), size);
    }
    return size;
}

/** Insert (d, id) into the ascending list hD/hI of at most k entries; returns its new size. */
function offer(d: u64, id: i32, size: i32): i32 {
    const k = kK;
    if (size == k) {
        const ld = u64At(hD, k - 1);
        if (d > ld || (d == ld && id > i32At(hI, k - 1))) return size;
    } else size++;
    let j = size - 1;
    while (j > 0) {
        const pd = u64At(hD, j - 1), pi = i32At(hI, j - 1);
        if (!(pd > d || (pd == d && pi > id))) break;
        setU64(hD, j, pd); setI32(hI, j, pi); j--;
    }
    setU64(hD, j, d); setI32(hI, j, id);
    if (size == k) worst = u64At(hD, k - 1);
    return size;
}

// ---------------------------------------------------------------- symbol chunks (10.4, 10.5, 10.7)

const LUT_SHIFT: u64 = 12; // symbol search starts at lut[q >> 12] (tables.mjs's ModelSet)
const LUT_SIZE: i32 = 4097;
const MAX_RESIDUAL: u64 = 0x3FFFFFFFFFFFFFFF; // 2^62 - 1
const TWO53: u64 = 0x20000000000000;

// the 64 level tables and the escape class table, as tables.mjs's ModelSet (cum, off, lut); half widths L_i
let lvCum: usize = 0; let lvOff: usize = 0; let lvLut: usize = 0; let lvHalf: usize = 0;
let clCum: usize = 0; let clOff: usize = 0; let clLut: usize = 0;

export function setTables(a: usize, b: usize, c: usize, d: usize, e: usize, f: usize, g: usize): void {
    lvCum = a; lvOff = b; lvLut = c; lvHalf = d; clCum = e; clOff = f; clLut = g;
}

/** One symbol of model m of a model set (10.6.1). */
function decodeModel(cum: usize, off: usize, lut: usize, m: i32): i32 {
    const scale = rR >> 24, q = quantile(scale), o = i32At(off, m);
    let s = <i32>load<u16>(lut + ((<usize>(m * LUT_SIZE) + <usize>(q >> LUT_SHIFT)) << 1));
    while (<u64>i32At(cum, o + s + 1) <= q) s++;
    const c = <u64>i32At(cum, o + s);
    setState((<u64>i32At(cum, o + s + 1) - c) * scale, rD - c * scale);
    return s;
}

/**
 * The symbol chunk of nbytes at p holding n residuals of levels lv (u8 [n]): the bins grouped by
 * level, then the escape section (signs, magnitude classes, remainders); checks the chunk is
 * exhausted. Residuals to out (f64 [n]; NaN where |r| >= 2^53) and wide (i64 [n], every escaped
 * one). Returns the number of escapes.
 */
export function decodeSymbols(p: usize, nbytes: i32, lv: usize, n: i32, out: usize, wide: usize): i32 {
    err = 0;
    return symbolChunk(p, nbytes, lv, n, out, wide, false);
}

/** decodeSymbols; with wideOnly, every residual goes to wide (i64 [n]) and out is not written (attributeChunk's values). */
@inline function symbolChunk(p: usize, nbytes: i32, lv: usize, n: i32, out: usize, wide: usize, wideOnly: bool): i32 {
    rangeStart(p, nbytes);
    const count = alloc(65 << 2), order = reserve(n << 2), esc = alloc(n); // order: overwritten whole
    for (let j = 0; j < n; j++) { const c = u8At(lv, j) + 1; setI32(count, c, i32At(count, c) + 1); }
    for (let i = 0; i < 64; i++) setI32(count, i + 1, i32At(count, i + 1) + i32At(count, i));
    for (let j = 0; j < n; j++) { const c = u8At(lv, j), o = i32At(count, c); setI32(order, o, j); setI32(count, c, o + 1); }
    // count[i] is now the end of level i's group
    let nesc = 0, start = 0;
    for (let i = 0; i < 64; i++) {
        const end = i32At(count, i);
        if (end == start) continue;
        const L = i32At(lvHalf, i), ESC = 2 * L + 1;
        // decodeModel of level i's model with the decoder's state in locals (a global is a memory access in the serial chain)
        const cum = lvCum + (<usize>i32At(lvOff, i) << 2), lut = lvLut + (<usize>(i * LUT_SIZE) << 1);
        let R = rR, D = rD, pos = rPos;
        for (let t = start; t < end; t++) {
            const scale = R >> 24, q = D / scale;
            if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
            let b = <i32>load<u16>(lut + (<usize>(q >> LUT_SHIFT) << 1));
            while (<u64>i32At(cum, b + 1) <= q) b++;
            const c = <u64>i32At(cum, b);
            R = (<u64>i32At(cum, b + 1) - c) * scale; D -= c * scale;
            if (R < 0x100000000) { // R < 2^32: shift in the next word (missing words read as 0, 10.6.6)
                R <<= 32;
                D = (D << 32) | wordAt(pos); pos += <i32>(pos < rWords);
            }
            const j = i32At(order, t);
            if (b == ESC) { setU8(esc, j, 1); nesc++; }
            else if (wideOnly) setI64(wide, j, <i64>(b - L));
            else store<f64>(out + (<usize>j << 3), <f64>(b - L));
        }
        rR = R; rD = D; rPos = pos;
        start = end;
    }
    if (nesc) decodeEscapes(lv, n, out, wide, esc, nesc, wideOnly, 0);
    checkExhausted();
    return nesc;
}

/** Raw values (10.6.3) of widths w[0..n-1] (0..64 bits) to v (u64 [n]), in 16-bit pieces grouped by width. */
function decodeBits(w: usize, n: i32, v: usize): void {
    let maxw = 0;
    for (let j = 0; j < n; j++) maxw = max(maxw, i32At(w, j));
    for (let shift = 0; shift < maxw; shift += 16) {
        for (let piece = 1; piece <= 16; piece++) {
            for (let j = 0; j < n; j++) {
                const wj = i32At(w, j);
                if (wj <= shift || min(wj - shift, 16) != piece) continue;
                setU64(v, j, u64At(v, j) | (<u64>decodeUniform(piece) << <u64>shift));
            }
        }
    }
}

/** The escape section (10.7) of n residuals of levels lv[j], or lv[j % period] when period > 0 (rows of one level pattern). */
function decodeEscapes(lv: usize, n: i32, out: usize, wide: usize, esc: usize, nesc: i32, wideOnly: bool, period: i32): void {
    const idx = alloc(nesc << 2), sign = alloc(nesc), k = alloc(nesc << 2), width = alloc(nesc << 2), rem = alloc(nesc << 3);
    for (let j = 0, e = 0; j < n; j++) if (u8At(esc, j)) setI32(idx, e++, j);
    for (let e = 0; e < nesc; e++) setU8(sign, e, <i32>decodeUniform(1));
    for (let e = 0; e < nesc; e++) {
        const c = decodeModel(clCum, clOff, clLut, 0);
        setI32(k, e, c); setI32(width, e, max(c - 1, 0));
    }
    decodeBits(width, nesc, rem);
    for (let e = 0; e < nesc; e++) {
        const j = i32At(idx, e), c = i32At(k, e), L = <u64>i32At(lvHalf, u8At(lv, period ? j % period : j));
        const m: u64 = c == 0 ? 0 : (<u64>1 << <u64>(c - 1)) + u64At(rem, e); // c <= 62: below 2^62
        const mag = L + 1 + m;
        if (mag > MAX_RESIDUAL) { errWide = mag; fail(ERR_ESCAPE, 0, 0); }
        const r: i64 = u8At(sign, e) ? -<i64>mag : <i64>mag;
        store<i64>(wide + (<usize>j << 3), r);
        if (!wideOnly) store<f64>(out + (<usize>j << 3), mag < TWO53 ? <f64>r : NaN);
    }
}

// ---------------------------------------------------------------- attribute chunks (11.3-11.8)

// The tile's attribute parameters (attributeTile): q (i64 [n * M], the values decoded so far), the rows'
// step-adjustment indices adj (u8 [n]), the fixed-point factors fix (i32 [8]) and level shifts shift
// (i32 [8]) of 11.8 when sa, the neighbour_mean_flag (u8 [M]) and bucket_level (u8 [M * B]) of
// 11.7.3, the prior (f64 [M] means, u8 [M] levels) and the predictions of 11.6 grouped by target
// (pStart i32 [M + 1]; pSrc, pW i32 per prediction).
let aQ: usize = 0; let aM: i32 = 0; let aAdj: usize = 0; let aSa: i32 = 0; let aFix: usize = 0; let aShift: usize = 0;
let aMeanFlag: usize = 0; let aBucket: usize = 0; let aB: i32 = 1; let aPrior: usize = 0; let aPriorLevel: usize = 0;
let aPStart: usize = 0; let aPSrc: usize = 0; let aPW: usize = 0;

export function attributeTile(q: usize, M: i32, adj: usize, sa: i32, fix: usize, shift: usize, meanFlag: usize, bucket: usize, B: i32,
    prior: usize, priorLevel: usize, pStart: usize, pSrc: usize, pW: usize): void {
    aQ = q; aM = M; aAdj = adj; aSa = sa; aFix = fix; aShift = shift; aMeanFlag = meanFlag; aBucket = bucket; aB = B;
    aPrior = prior; aPriorLevel = priorLevel; aPStart = pStart; aPSrc = pSrc; aPW = pW;
    aDeg = 0; aStepFlags = 0;
    priorGroups();
}

// The step-adjustment indices as flags (11.8, version 1.5; attributeStepFlags after attributeTile, when
// the stream has a step_adjust_flags unit): max_step_adjust and the flags' frequencies f[1] = 4096
// step_flag_prob + 2048 (i32 [max * 6], b-major); the indices go to adj. aStepFlags 0: indices as symbols
// (stepIndices), or no step adjustment.
let aStepFlags: i32 = 0; let aMaxStep: i32 = 0; let aStepFreq: usize = 0;

export function attributeStepFlags(max: i32, freq: usize): void {
    aStepFlags = 1; aMaxStep = max; aStepFreq = freq;
}

// The per-Gaussian SH degree (11.9, version 1.3; attributeDegrees after attributeTile, when the stream
// has an sh_degree unit): the rows' degrees D (u8 [n], decoded chunk by chunk), d = sh_degree and the
// flags' frequencies f[1] = 4096 degree_flag_prob + 2048 (i32 [d * 6], band-major). aDeg 0: no tool.
let aDeg: usize = 0; let aD: i32 = 0; let aFreq: usize = 0;

export function attributeDegrees(deg: usize, d: i32, freq: usize): void {
    aDeg = deg; aD = d; aFreq = freq;
}

// which range-coded chunk of an attribute chunk failed (errorStage(), after a trap)
const STAGE_SYMBOLS: i32 = 0;
const STAGE_FLAGS: i32 = 1;
const STAGE_STEP_FLAGS: i32 = 2;
let stage: i32 = STAGE_SYMBOLS;
export function errorStage(): i32 { return stage; }

const ERR_Q_LIMIT: i32 = 11;   // |q| > 2^40 (11.6, E51; errA the row, errB the channel, errorWide() q)
const ERR_NOT_FINITE: i32 = 12; // a reconstructed value not finite (11.5, E52; errA the row, errB the channel)
const ERR_LENGTH_INDEX: i32 = 13; // a rotation length index outside [0, max_rotation_length_index] (11.10, E66; errA the row)
const ERR_STEP_INDEX: i32 = 14; // a step-adjustment index outside [0, max_step_adjust] (11.8, E65; errA the row of the chunk)
const ERR_SH_TRANSFORM: i32 = 15; // an SH-rest value's inverse transform with |q| > 2^40 (11.11, E68; errA the row, errB the channel)
const Q_LIMIT: i64 = 0x10000000000; // 2^40

@inline function i64At(p: usize, i: i32): i64 { return load<i64>(p + (<usize>i << 3)); }
@inline function setI64(p: usize, i: i32, v: i64): void { store<i64>(p + (<usize>i << 3), v); }

/** The prior's mean of channel c (11.3; |prior_mean| < 2^31), scaled by the row's step adjustment F (11.8) when sa. */
@inline function priorMean(c: i32, F: i64): i64 {
    const p = <i64>load<f64>(aPrior + (<usize>c << 3));
    return aSa ? floorDiv(p * 4096 + (F >> 1), F) : p;
}

/**
 * Chunk of nr rows (rows: i32 [nr]) with symbol data of nbytes at p, with the step-adjustment flags
 * (version 1.5) step-adjustment data of sbytes at sp and, with the SH-degree tool, SH-degree data of
 * dbytes at dp: the rows' step-adjustment indices (11.8) and degrees (11.9), means and levels (11.3,
 * 11.7.3, 11.8; row r has cnt[r] neighbours idx[r * k ..], none: the prior's), the symbols of the
 * coded channels (10.7) and the values q (11.6) into the tile's q. Returns the number of escapes.
 */
export function attributeChunk(p: usize, nbytes: i32, rows: usize, nr: i32, idx: usize, cnt: usize, k: i32, dp: usize, dbytes: i32,
    sp: usize, sbytes: i32): i32 {
    err = 0;
    if (priorRows(k)) {
        const desc = alloc(16);
        setI32(desc, 0, <i32>p); setI32(desc, 1, nbytes); setI32(desc, 2, <i32>rows); setI32(desc, 3, nr);
        return attributePriorChunks(desc, 1);
    }
    if (aStepFlags) { stage = STAGE_STEP_FLAGS; decodeFlags(sp, sbytes, rows, nr, idx, cnt, k, aAdj, aMaxStep, aStepFreq); }
    if (aDeg) { stage = STAGE_FLAGS; decodeFlags(dp, dbytes, rows, nr, idx, cnt, k, aDeg, aD, aFreq); }
    stage = STAGE_SYMBOLS;
    const M = aM, n = nr * M;
    // not zeroed: rowMeans writes every coded channel's mean and level, symbolChunk every residual, and only those are read
    const mean = reserve(n << 3), level = reserve(n), res = reserve(n << 3);
    rowMeans(rows, nr, idx, cnt, k, mean, level);
    const ns = aDeg ? codedLevels(rows, nr, level) : n;
    const nesc = symbolChunk(p, nbytes, level, ns, 0, res, true);
    if (aDeg) for (let r = 0, j = 0; r < nr; r++) j = rowValuesCoded(i32At(rows, r), r * M, j, mean, res);
    else for (let r = 0; r < nr; r++) rowValuesLanes(i32At(rows, r), mean + (<usize>(r * M) << 3), res + (<usize>(r * M) << 3));
    return nesc;
}

/**
 * Two chunks of one LoD (A, then B: attributeChunk's arguments of each) decoded as attributeChunk decodes
 * them one after the other, with their symbols' range decoders interleaved (symbolPair): the rows of a
 * LoD take their neighbours from coarser LoDs only (11.7.2), so B's flags, means and levels do not wait
 * for A's values, and the two serial chains of the range decoders overlap in the processor. A failure
 * traps with no error order between A and B: the caller decodes them again one after the other, which
 * names the first fault (attributes.mjs).
 */
export function attributeChunkPair(pa: usize, nba: i32, rowsA: usize, nrA: i32, idxA: usize, cntA: usize, dpa: usize, dba: i32, spa: usize, sba: i32,
    pb: usize, nbb: i32, rowsB: usize, nrB: i32, idxB: usize, cntB: usize, dpb: usize, dbb: i32, spb: usize, sbb: i32, k: i32): void {
    err = 0;
    const M = aM;
    chunkFlags(rowsA, nrA, idxA, cntA, k, dpa, dba, spa, sba);
    chunkFlags(rowsB, nrB, idxB, cntB, k, dpb, dbb, spb, sbb);
    stage = STAGE_SYMBOLS;
    const meanA = reserve((nrA * M) << 3), levelA = reserve(nrA * M), resA = reserve((nrA * M) << 3);
    const meanB = reserve((nrB * M) << 3), levelB = reserve(nrB * M), resB = reserve((nrB * M) << 3);
    rowMeans(rowsA, nrA, idxA, cntA, k, meanA, levelA);
    rowMeans(rowsB, nrB, idxB, cntB, k, meanB, levelB);
    const nsA = aDeg ? codedLevels(rowsA, nrA, levelA) : nrA * M, nsB = aDeg ? codedLevels(rowsB, nrB, levelB) : nrB * M;
    symbolPair(pa, nba, levelA, nsA, resA, pb, nbb, levelB, nsB, resB);
    chunkValues(rowsA, nrA, meanA, resA);
    chunkValues(rowsB, nrB, meanB, resB);
}

/** A chunk's step-adjustment flags and SH-degree flags, when the stream has them (attributeChunk's first steps). */
function chunkFlags(rows: usize, nr: i32, idx: usize, cnt: usize, k: i32, dp: usize, dbytes: i32, sp: usize, sbytes: i32): void {
    if (aStepFlags) { stage = STAGE_STEP_FLAGS; decodeFlags(sp, sbytes, rows, nr, idx, cnt, k, aAdj, aMaxStep, aStepFreq); }
    if (aDeg) { stage = STAGE_FLAGS; decodeFlags(dp, dbytes, rows, nr, idx, cnt, k, aDeg, aD, aFreq); }
}

/** A chunk's values q from its means and residuals (attributeChunk's last step). */
function chunkValues(rows: usize, nr: i32, mean: usize, res: usize): void {
    const M = aM;
    if (aDeg) for (let r = 0, j = 0; r < nr; r++) j = rowValuesCoded(i32At(rows, r), r * M, j, mean, res);
    else for (let r = 0; r < nr; r++) rowValuesLanes(i32At(rows, r), mean + (<usize>(r * M) << 3), res + (<usize>(r * M) << 3));
}

/**
 * The positions 0 .. n - 1 of residuals of levels lv (u8 [n]) grouped by level, in increasing level and
 * position (symbolChunk's order) to order (i32 [n]), and their levels in that order to sorted (u8 [n]).
 */
function levelOrder(lv: usize, n: i32, order: usize, sorted: usize): void {
    const count = alloc(65 << 2);
    for (let j = 0; j < n; j++) { const c = u8At(lv, j) + 1; setI32(count, c, i32At(count, c) + 1); }
    for (let i = 0; i < 64; i++) setI32(count, i + 1, i32At(count, i + 1) + i32At(count, i));
    for (let j = 0; j < n; j++) { const c = u8At(lv, j), o = i32At(count, c); setI32(order, o, j); setU8(sorted, o, c); setI32(count, c, o + 1); }
}

@inline function wordOf(bytes: usize, words: i32, pos: i32): u64 { return pos < words ? <u64>load<u32>(bytes + (<usize>pos << 2)) : 0; }

/**
 * symbolChunk (wideOnly) of two chunks A and B: their bins a symbol of A, a symbol of B in turn while
 * both have symbols left (the decoders' states in locals), then the rest of the longer one's
 * (binsFrom), then each chunk's escapes and exhaustion check.
 */
function symbolPair(pa: usize, nba: i32, lva: usize, na: i32, wa: usize, pb: usize, nbb: i32, lvb: usize, nb: i32, wb: usize): void {
    const oa = reserve(na << 2), sa = reserve(na), ea = alloc(na), ob = reserve(nb << 2), sb = reserve(nb), eb = alloc(nb);
    levelOrder(lva, na, oa, sa); levelOrder(lvb, nb, ob, sb);
    rangeStart(pb, nbb);
    let Rb = rR, Db = rD, posB = rPos, neb = 0;
    rangeStart(pa, nba);
    let Ra = rR, Da = rD, posA = rPos, nea = 0;
    const wordsA = nba >> 2, wordsB = nbb >> 2, m = min(na, nb);
    for (let t = 0; t < m; t++) {
        { // A's symbol t
            const lev = u8At(sa, t), L = i32At(lvHalf, lev);
            const cum = lvCum + (<usize>i32At(lvOff, lev) << 2), lut = lvLut + (<usize>(lev * LUT_SIZE) << 1);
            const scale = Ra >> 24, q = Da / scale;
            if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
            let b = <i32>load<u16>(lut + (<usize>(q >> LUT_SHIFT) << 1));
            while (<u64>i32At(cum, b + 1) <= q) b++;
            const c = <u64>i32At(cum, b);
            Ra = (<u64>i32At(cum, b + 1) - c) * scale; Da -= c * scale;
            if (Ra < 0x100000000) { Ra <<= 32; Da = (Da << 32) | wordOf(pa, wordsA, posA); posA += <i32>(posA < wordsA); }
            const j = i32At(oa, t);
            if (b == 2 * L + 1) { setU8(ea, j, 1); nea++; } else setI64(wa, j, <i64>(b - L));
        }
        { // B's symbol t
            const lev = u8At(sb, t), L = i32At(lvHalf, lev);
            const cum = lvCum + (<usize>i32At(lvOff, lev) << 2), lut = lvLut + (<usize>(lev * LUT_SIZE) << 1);
            const scale = Rb >> 24, q = Db / scale;
            if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
            let b = <i32>load<u16>(lut + (<usize>(q >> LUT_SHIFT) << 1));
            while (<u64>i32At(cum, b + 1) <= q) b++;
            const c = <u64>i32At(cum, b);
            Rb = (<u64>i32At(cum, b + 1) - c) * scale; Db -= c * scale;
            if (Rb < 0x100000000) { Rb <<= 32; Db = (Db << 32) | wordOf(pb, wordsB, posB); posB += <i32>(posB < wordsB); }
            const j = i32At(ob, t);
            if (b == 2 * L + 1) { setU8(eb, j, 1); neb++; } else setI64(wb, j, <i64>(b - L));
        }
    }
    rBytes = pa; rWords = wordsA; rR = Ra; rD = Da; rPos = posA;
    nea += binsFrom(m, na, oa, sa, wa, ea);
    if (nea) decodeEscapes(lva, na, 0, wa, ea, nea, true, 0);
    checkExhausted();
    rBytes = pb; rWords = wordsB; rR = Rb; rD = Db; rPos = posB;
    neb += binsFrom(m, nb, ob, sb, wb, eb);
    if (neb) decodeEscapes(lvb, nb, 0, wb, eb, neb, true, 0);
    checkExhausted();
}

/** The bins t0 .. n - 1 of symbolPair's order (order, sorted) with the decoder's state in the globals; returns their escapes. */
function binsFrom(t0: i32, n: i32, order: usize, sorted: usize, wide: usize, esc: usize): i32 {
    let R = rR, D = rD, pos = rPos, nesc = 0;
    for (let t = t0; t < n; t++) {
        const lev = u8At(sorted, t), L = i32At(lvHalf, lev);
        const cum = lvCum + (<usize>i32At(lvOff, lev) << 2), lut = lvLut + (<usize>(lev * LUT_SIZE) << 1);
        const scale = R >> 24, q = D / scale;
        if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
        let b = <i32>load<u16>(lut + (<usize>(q >> LUT_SHIFT) << 1));
        while (<u64>i32At(cum, b + 1) <= q) b++;
        const c = <u64>i32At(cum, b);
        R = (<u64>i32At(cum, b + 1) - c) * scale; D -= c * scale;
        if (R < 0x100000000) { R <<= 32; D = (D << 32) | wordAt(pos); pos += <i32>(pos < rWords); }
        const j = i32At(order, t);
        if (b == 2 * L + 1) { setU8(esc, j, 1); nesc++; } else setI64(wide, j, <i64>(b - L));
    }
    rR = R; rD = D; rPos = pos;
    return nesc;
}

// ---------------------------------------------------------------- chunks of prior rows (11.3, 10.7)

// Where no row of a chunk has neighbours (no neighbour prediction, or LoD 0) and the stream has neither
// step adjustment nor the SH-degree tool, every row's means and levels are the prior's (11.3): the same
// for every row. The chunk's bins, grouped by level (10.7), are then for each level its channels of
// row 0, row 1, ...: no per-row means and levels, no sort by level, one model per run of symbols.
// Per chunk a record of PC_SIZE bytes: its data's address and words, the decoder's word position and
// state R, D, its rows (i32 [nr]) and nr, residuals res (i64 [nr * M]), escape marks esc (u8 [nr * M])
// and escape count.
const PC_BYTES = 0; const PC_WORDS = 4; const PC_POS = 8; const PC_ROWS = 12; const PC_NR = 16;
const PC_RES = 20; const PC_ESC = 24; const PC_NESC = 28; const PC_R = 32; const PC_D = 40; const PC_SIZE = 48;

// the prior's channels in increasing (level, channel): pcChans (i32 [M]); group g (one level, pcLev[g])
// from pcStart[g] to pcStart[g + 1]; pcMean the prior's means (i64 [M]); set by attributeTile
let pcChans: usize = 0; let pcStart: usize = 0; let pcLev: usize = 0; let pcGroups: i32 = 0; let pcMean: usize = 0;
// the channels with a cross-channel prediction (11.6), increasing (i32 [pvCount]); set by attributeTile
let pvTargets: usize = 0; let pvCount: i32 = 0;

function priorGroups(): void {
    const M = aM;
    pcChans = alloc(M << 2); pcStart = alloc((M + 1) << 2); pcLev = alloc(M << 2); pcMean = alloc(M << 3);
    let j = 0, g = 0;
    for (let l = 0; l < 64; l++) { // prior_level is 6 bits (7.3.4)
        const j0 = j;
        for (let c = 0; c < M; c++) if (u8At(aPriorLevel, c) == l) setI32(pcChans, j++, c);
        if (j > j0) { setI32(pcStart, g, j0); setI32(pcLev, g, l); g++; }
    }
    setI32(pcStart, g, j);
    pcGroups = g;
    for (let c = 0; c < M; c++) setI64(pcMean, c, <i64>load<f64>(aPrior + (<usize>c << 3)));
    pvTargets = alloc(M << 2); pvCount = 0;
    for (let c = 0; c < M; c++) if (i32At(aPStart, c + 1) > i32At(aPStart, c)) setI32(pvTargets, pvCount++, c);
}

/** Whether attributeChunk's rows (k == 0: no neighbours) take the prior's means and levels unchanged. */
@inline function priorRows(k: i32): bool { return k == 0 && !aSa && !aDeg; }

/**
 * count (1 .. 4) chunks of one LoD decoded as attributeChunk decodes them one after the other, where
 * priorRows holds: chunk i's data at desc[4 i] of desc[4 i + 1] bytes, its rows at desc[4 i + 2], nr =
 * desc[4 i + 3] (i32). The symbols of a level, row by row, with the chunks' range decoders interleaved
 * (priorQuad, priorPair: their serial chains overlap in the processor), then each chunk's escapes and
 * exhaustion check, then the values. Returns the escapes' number. A failure of several chunks traps with
 * no order between them: the caller decodes them again one at a time, which names the first fault.
 */
export function attributePriorChunks(desc: usize, count: i32): i32 {
    err = 0; stage = STAGE_SYMBOLS;
    const M = aM, recs = alloc(count * PC_SIZE);
    let nr4 = 0x7FFFFFFF, nr2 = 0x7FFFFFFF; // the fewest rows of chunks 0 .. 3 and of chunks 0, 1
    for (let i = 0; i < count; i++) {
        const rec = recs + <usize>(i * PC_SIZE), nr = i32At(desc, 4 * i + 3);
        rangeStart(<usize>i32At(desc, 4 * i), i32At(desc, 4 * i + 1));
        store<i32>(rec + PC_BYTES, <i32>rBytes); store<i32>(rec + PC_WORDS, rWords); store<i32>(rec + PC_POS, rPos);
        store<u64>(rec + PC_R, rR); store<u64>(rec + PC_D, rD);
        store<i32>(rec + PC_ROWS, i32At(desc, 4 * i + 2)); store<i32>(rec + PC_NR, nr);
        store<i32>(rec + PC_RES, <i32>reserve((nr * M) << 3)); store<i32>(rec + PC_ESC, <i32>alloc(nr * M));
        nr4 = min(nr4, nr); if (i < 2) nr2 = min(nr2, nr);
    }
    const joint = count >= 4 ? 4 : count >= 2 ? 2 : 0, shared = joint == 4 ? nr4 : nr2;
    for (let g = 0; g < pcGroups; g++) {
        const c0 = i32At(pcStart, g), c1 = i32At(pcStart, g + 1), lev = i32At(pcLev, g), L = i32At(lvHalf, lev);
        const cum = lvCum + (<usize>i32At(lvOff, lev) << 2), lut = lvLut + (<usize>(lev * LUT_SIZE) << 1);
        if (joint == 4) priorQuad(recs, c0, c1, shared, L, cum, lut);
        else if (joint == 2) priorPair(recs, c0, c1, shared, L, cum, lut);
        for (let i = 0; i < count; i++) {
            const rec = recs + <usize>(i * PC_SIZE);
            priorRun(rec, c0, c1, i < joint ? shared : 0, load<i32>(rec + PC_NR), L, cum, lut);
        }
    }
    let nesc = 0;
    for (let i = 0; i < count; i++) nesc += priorFinish(recs + <usize>(i * PC_SIZE));
    return nesc;
}

/** A prior chunk after its bins: its escapes (10.7) and exhaustion check (10.6.5), then its values q (11.6). */
function priorFinish(rec: usize): i32 {
    const M = aM, nr = load<i32>(rec + PC_NR), rows = <usize>load<i32>(rec + PC_ROWS), res = <usize>load<i32>(rec + PC_RES);
    const nesc = load<i32>(rec + PC_NESC);
    rBytes = <usize>load<i32>(rec + PC_BYTES); rWords = load<i32>(rec + PC_WORDS); rPos = load<i32>(rec + PC_POS);
    rR = load<u64>(rec + PC_R); rD = load<u64>(rec + PC_D);
    if (nesc) decodeEscapes(aPriorLevel, nr * M, 0, res, <usize>load<i32>(rec + PC_ESC), nesc, true, M);
    checkExhausted();
    for (let r = 0; r < nr; r++) rowValuesLanes(i32At(rows, r), pcMean, res + (<usize>(r * M) << 3));
    return nesc;
}

/** The bin of quantile q in a level's model (cum, lut: tables.mjs's ModelSet), from the table's guess up. */
@inline function binOf(q: u64, cum: usize, lut: usize): i32 {
    let b = <i32>load<u16>(lut + (<usize>(q >> LUT_SHIFT) << 1));
    while (<u64>i32At(cum, b + 1) <= q) b++;
    return b;
}

/** Word pos of a prior chunk's data, 0 past its end (10.6.6). */
@inline function recWord(rec: usize, pos: i32): u64 {
    return pos < load<i32>(rec + PC_WORDS) ? <u64>load<u32>(<usize>load<i32>(rec + PC_BYTES) + (<usize>pos << 2)) : 0;
}

/** Residual j of a prior chunk is an escape (its magnitude follows in the escape section, 10.7). */
@inline function escapeAt(rec: usize, j: i32): void {
    setU8(<usize>load<i32>(rec + PC_ESC), j, 1);
    store<i32>(rec + PC_NESC, load<i32>(rec + PC_NESC) + 1);
}

/**
 * The bins of rows r0 .. r1 - 1 of one level's channels pcChans[c0 .. c1 - 1] (half width L, model cum,
 * lut) of the prior chunk at rec, its decoder's state in locals; every bin's b - L to res (an escape's
 * is replaced by decodeEscapes).
 */
function priorRun(rec: usize, c0: i32, c1: i32, r0: i32, r1: i32, L: i32, cum: usize, lut: usize): void {
    const M = aM, ESC = 2 * L + 1, res = <usize>load<i32>(rec + PC_RES);
    let R = load<u64>(rec + PC_R), D = load<u64>(rec + PC_D), pos = load<i32>(rec + PC_POS);
    for (let r = r0; r < r1; r++) {
        for (let i = c0; i < c1; i++) {
            const scale = R >> 24, q = D / scale;
            if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
            const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
            R = (<u64>i32At(cum, b + 1) - c) * scale; D -= c * scale;
            if (R < 0x100000000) { R <<= 32; D = (D << 32) | recWord(rec, pos); pos += <i32>(pos < load<i32>(rec + PC_WORDS)); }
            const j = r * M + i32At(pcChans, i);
            setI64(res, j, <i64>(b - L)); if (b == ESC) escapeAt(rec, j);
        }
    }
    store<u64>(rec + PC_R, R); store<u64>(rec + PC_D, D); store<i32>(rec + PC_POS, pos);
}

/** priorRun of rows 0 .. nr - 1 of two chunks (records recs[0], recs[1]), a symbol of each in turn. */
function priorPair(recs: usize, c0: i32, c1: i32, nr: i32, L: i32, cum: usize, lut: usize): void {
    const M = aM, ESC = 2 * L + 1;
    const rec0 = recs + <usize>(0 * PC_SIZE), res0 = <usize>load<i32>(rec0 + PC_RES);
    let R0 = load<u64>(rec0 + PC_R), D0 = load<u64>(rec0 + PC_D), pos0 = load<i32>(rec0 + PC_POS);
    const rec1 = recs + <usize>(1 * PC_SIZE), res1 = <usize>load<i32>(rec1 + PC_RES);
    let R1 = load<u64>(rec1 + PC_R), D1 = load<u64>(rec1 + PC_D), pos1 = load<i32>(rec1 + PC_POS);
    for (let r = 0; r < nr; r++) {
        for (let i = c0; i < c1; i++) {
            const j = r * M + i32At(pcChans, i);
            { const scale = R0 >> 24, q = D0 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R0 = (<u64>i32At(cum, b + 1) - c) * scale; D0 -= c * scale;
              if (R0 < 0x100000000) { R0 <<= 32; D0 = (D0 << 32) | recWord(rec0, pos0); pos0 += <i32>(pos0 < load<i32>(rec0 + PC_WORDS)); }
              setI64(res0, j, <i64>(b - L)); if (b == ESC) escapeAt(rec0, j); }
            { const scale = R1 >> 24, q = D1 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R1 = (<u64>i32At(cum, b + 1) - c) * scale; D1 -= c * scale;
              if (R1 < 0x100000000) { R1 <<= 32; D1 = (D1 << 32) | recWord(rec1, pos1); pos1 += <i32>(pos1 < load<i32>(rec1 + PC_WORDS)); }
              setI64(res1, j, <i64>(b - L)); if (b == ESC) escapeAt(rec1, j); }
        }
    }
    store<u64>(rec0 + PC_R, R0); store<u64>(rec0 + PC_D, D0); store<i32>(rec0 + PC_POS, pos0);
    store<u64>(rec1 + PC_R, R1); store<u64>(rec1 + PC_D, D1); store<i32>(rec1 + PC_POS, pos1);
}

/** priorRun of rows 0 .. nr - 1 of four chunks (records recs[0 .. 3]), a symbol of each in turn: four serial chains overlap. */
function priorQuad(recs: usize, c0: i32, c1: i32, nr: i32, L: i32, cum: usize, lut: usize): void {
    const M = aM, ESC = 2 * L + 1;
    const rec0 = recs + <usize>(0 * PC_SIZE), res0 = <usize>load<i32>(rec0 + PC_RES);
    let R0 = load<u64>(rec0 + PC_R), D0 = load<u64>(rec0 + PC_D), pos0 = load<i32>(rec0 + PC_POS);
    const rec1 = recs + <usize>(1 * PC_SIZE), res1 = <usize>load<i32>(rec1 + PC_RES);
    let R1 = load<u64>(rec1 + PC_R), D1 = load<u64>(rec1 + PC_D), pos1 = load<i32>(rec1 + PC_POS);
    const rec2 = recs + <usize>(2 * PC_SIZE), res2 = <usize>load<i32>(rec2 + PC_RES);
    let R2 = load<u64>(rec2 + PC_R), D2 = load<u64>(rec2 + PC_D), pos2 = load<i32>(rec2 + PC_POS);
    const rec3 = recs + <usize>(3 * PC_SIZE), res3 = <usize>load<i32>(rec3 + PC_RES);
    let R3 = load<u64>(rec3 + PC_R), D3 = load<u64>(rec3 + PC_D), pos3 = load<i32>(rec3 + PC_POS);
    for (let r = 0; r < nr; r++) {
        for (let i = c0; i < c1; i++) {
            const j = r * M + i32At(pcChans, i);
            { const scale = R0 >> 24, q = D0 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R0 = (<u64>i32At(cum, b + 1) - c) * scale; D0 -= c * scale;
              if (R0 < 0x100000000) { R0 <<= 32; D0 = (D0 << 32) | recWord(rec0, pos0); pos0 += <i32>(pos0 < load<i32>(rec0 + PC_WORDS)); }
              setI64(res0, j, <i64>(b - L)); if (b == ESC) escapeAt(rec0, j); }
            { const scale = R1 >> 24, q = D1 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R1 = (<u64>i32At(cum, b + 1) - c) * scale; D1 -= c * scale;
              if (R1 < 0x100000000) { R1 <<= 32; D1 = (D1 << 32) | recWord(rec1, pos1); pos1 += <i32>(pos1 < load<i32>(rec1 + PC_WORDS)); }
              setI64(res1, j, <i64>(b - L)); if (b == ESC) escapeAt(rec1, j); }
            { const scale = R2 >> 24, q = D2 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R2 = (<u64>i32At(cum, b + 1) - c) * scale; D2 -= c * scale;
              if (R2 < 0x100000000) { R2 <<= 32; D2 = (D2 << 32) | recWord(rec2, pos2); pos2 += <i32>(pos2 < load<i32>(rec2 + PC_WORDS)); }
              setI64(res2, j, <i64>(b - L)); if (b == ESC) escapeAt(rec2, j); }
            { const scale = R3 >> 24, q = D3 / scale;
              if (q >= 0x1000000) fail(ERR_RANGE, 0, 0);
              const b = binOf(q, cum, lut), c = <u64>i32At(cum, b);
              R3 = (<u64>i32At(cum, b + 1) - c) * scale; D3 -= c * scale;
              if (R3 < 0x100000000) { R3 <<= 32; D3 = (D3 << 32) | recWord(rec3, pos3); pos3 += <i32>(pos3 < load<i32>(rec3 + PC_WORDS)); }
              setI64(res3, j, <i64>(b - L)); if (b == ESC) escapeAt(rec3, j); }
        }
    }
    store<u64>(rec0 + PC_R, R0); store<u64>(rec0 + PC_D, D0); store<i32>(rec0 + PC_POS, pos0);
    store<u64>(rec1 + PC_R, R1); store<u64>(rec1 + PC_D, D1); store<i32>(rec1 + PC_POS, pos1);
    store<u64>(rec2 + PC_R, R2); store<u64>(rec2 + PC_D, D2); store<i32>(rec2 + PC_POS, pos2);
    store<u64>(rec3 + PC_R, R3); store<u64>(rec3 + PC_D, D3); store<i32>(rec3 + PC_POS, pos3);
}

/**
 * q of one row (11.4 step 3, 11.6): residual + mean + prediction from the channels before, each
 * checked against |q| <= 2^40 as it is computed. Exact in i64: residuals below 2^62, means below
 * 2^42 and at most M - 1 terms of |weight| <= 2^15 times |q - mean| < 2^43. Without the SH-degree
 * tool every channel is coded: this loop has no coded-channel tests (rowValuesCoded's cost 8-15%
 * on the logo's stream).
 */
function rowValues(row: i32, mb: usize, rb: usize): void {
    const M = aM, qb = aQ + (<usize>(row * M) << 3);
    for (let c = 0; c < M; c++) {
        const rv = i64At(rb, c);
        let pr: i64 = 0;
        for (let i = i32At(aPStart, c), e = i32At(aPStart, c + 1); i < e; i++) {
            const s = i32At(aPSrc, i);
            pr += <i64>i32At(aPW, i) * (i64At(qb, s) - i64At(mb, s));
        }
        storeValue(qb, row, c, rv + i64At(mb, c) + ((pr + 128) >> 8));
    }
}

/**
 * rowValues in two passes: residual + mean of every channel two at a time in i64x2 lanes, then the
 * channels with a prediction in increasing order (their sources, channels before, are final by then).
 * A row with a value beyond 2^40 in the first pass (a predicted channel's residual + mean may be, and its
 * prediction bring it back) is computed again by rowValues, which checks in channel order (E51).
 */
function rowValuesLanes(row: i32, mb: usize, rb: usize): void {
    const M = aM, qb = aQ + (<usize>(row * M) << 3), hi = i64x2.splat(Q_LIMIT), lo = i64x2.splat(-Q_LIMIT);
    let bad = i64x2.splat(0), c = 0;
    for (; c + 1 < M; c += 2) {
        const o = <usize>c << 3, v = i64x2.add(v128.load(rb + o), v128.load(mb + o));
        v128.store(qb + o, v);
        bad = v128.or(bad, v128.or(i64x2.gt_s(v, hi), i64x2.lt_s(v, lo)));
    }
    let out = v128.any_true(bad);
    if (c < M) { const v = i64At(rb, c) + i64At(mb, c); setI64(qb, c, v); out = out || v > Q_LIMIT || v < -Q_LIMIT; }
    for (let t = 0; t < pvCount; t++) {
        const tc = i32At(pvTargets, t);
        let pr: i64 = 0;
        for (let i = i32At(aPStart, tc), e = i32At(aPStart, tc + 1); i < e; i++) {
            const s = i32At(aPSrc, i);
            pr += <i64>i32At(aPW, i) * (i64At(qb, s) - i64At(mb, s));
        }
        const v = i64At(rb, tc) + i64At(mb, tc) + ((pr + 128) >> 8);
        setI64(qb, tc, v);
        out = out || v > Q_LIMIT || v < -Q_LIMIT;
    }
    if (out) rowValues(row, mb, rb);
}

@inline function storeValue(qb: usize, row: i32, c: i32, v: i64): void {
    if (v > Q_LIMIT || v < -Q_LIMIT) { errWide = <u64>v; fail(ERR_Q_LIMIT, row, c); }
    setI64(qb, c, v);
}

/** The end of the coded SH channels of a row (11.9): 3 (D + 1)^2, or all of them (M - 8) without the tool. */
@inline function codedEnd(row: i32): i32 {
    if (!aDeg) return aM - 8;
    const D1 = u8At(aDeg, row) + 1;
    return 3 * D1 * D1;
}

/**
 * q of one row as rowValues, in a stream with the SH-degree tool (11.9): the row's residuals are
 * res[j ..] (its coded channels'); the channels e <= c < M - 8 it does not code have q = 0 and give
 * no prediction term. Returns j after the row's residuals.
 */
function rowValuesCoded(row: i32, base: i32, j: i32, mean: usize, res: usize): i32 {
    const M = aM, qb = aQ + (<usize>(row * M) << 3), mb = mean + (<usize>base << 3);
    const e = codedEnd(row), gap = <u32>(M - 8 - e); // c is not coded when <u32>(c - e) < gap
    for (let c = 0; c < M; c++) {
        if (<u32>(c - e) < gap) { setI64(qb, c, 0); continue; }
        const rv = i64At(res, j);
        j++;
        let pr: i64 = 0;
        for (let i = i32At(aPStart, c), ie = i32At(aPStart, c + 1); i < ie; i++) {
            const s = i32At(aPSrc, i);
            if (<u32>(s - e) < gap) continue;
            pr += <i64>i32At(aPW, i) * (i64At(qb, s) - i64At(mb, s));
        }
        storeValue(qb, row, c, rv + i64At(mb, c) + ((pr + 128) >> 8));
    }
    return j;
}

/**
 * The flags "v >= b" (11.9's SH degrees D, and 11.8's step-adjustment indices a in version 1.5) of
 * the chunk's rows from nbytes at p into v (u8 [rows], the rows' values, 0 .. max): in b-major order,
 * b's flag of each row whose value is b - 1, with the context of the share of the row's neighbours
 * (rows of coarser LoDs, whose values are known) whose value is at least b, and the frequency f[1]
 * of freq[(b - 1) * 6 + context].
 */
function decodeFlags(p: usize, nbytes: i32, rows: usize, nr: i32, idx: usize, cnt: usize, k: i32, v: usize, max: i32, freq: usize): void {
    rangeStart(p, nbytes);
    for (let r = 0; r < nr; r++) setU8(v, i32At(rows, r), 0);
    for (let b = 1; b <= max; b++) {
        const f = freq + (<usize>((b - 1) * 6) << 2);
        for (let r = 0; r < nr; r++) {
            const row = i32At(rows, r);
            if (u8At(v, row) != b - 1) continue;
            const f1 = <u64>i32At(f, flagContext(v, r, b, idx, cnt, k));
            if (decodeBinary(0x1000000 - f1, f1)) setU8(v, row, b);
        }
    }
    checkExhausted();
}

/** The context x (0 .. 5) of b's flag of the chunk's row r (11.9; 11.8 as flags), the rows' values v. */
@inline function flagContext(v: usize, r: i32, b: i32, idx: usize, cnt: usize, k: i32): i32 {
    const n = u8At(cnt, r);
    if (n == 0) return 0; // LoD 0 (a row of a finer LoD has at least one neighbour)
    let m = 0;
    for (let t = 0; t < n; t++) if (u8At(v, i32At(idx, r * k + t)) >= b) m++;
    return m == 0 ? 1 : m == n ? 5 : 2 + (3 * m) / n;
}

/** The levels of the rows' coded channels (11.9), row after row in increasing c, moved to the front of level; returns their number. */
function codedLevels(rows: usize, nr: i32, level: usize): i32 {
    const M = aM;
    let j = 0;
    for (let r = 0; r < nr; r++) {
        const e = codedEnd(i32At(rows, r)), base = r * M;
        for (let c = 0; c < e; c++) setU8(level, j++, u8At(level, base + c));
        for (let c = M - 8; c < M; c++) setU8(level, j++, u8At(level, base + c));
    }
    return j;
}

/**
 * Floor division a // b (b > 0, |a| < 2^62) from a binary64 estimate, corrected to the exact
 * quotient with the remainder (i64 division is several times slower than this).
 */
@inline function floorDiv(a: i64, b: i64): i64 {
    let d = <i64>Math.floor(<f64>a / <f64>b), r = a - d * b;
    while (r < 0) { d--; r += b; }
    while (r >= b) { d++; r -= b; }
    return d;
}

/** floorDiv(a, b) with inv = 1 / b: the estimate from a product (the correction makes it exact; |a / b| < 2^45 here). */
@inline function floorDivInv(a: i64, b: i64, inv: f64): i64 {
    let d = <i64>Math.floor(<f64>a * inv), r = a - d * b;
    while (r < 0) { d--; r += b; }
    while (r >= b) { d++; r -= b; }
    return d;
}

/**
 * The mean (i64) and level (u8) of every coded channel (11.9) of nr rows to mean [nr * M] and level [nr * M].
 * Sums of up to 32 q F (|q| <= 2^40, F < 2^14) stay below 2^59: exact in i64.
 */
function rowMeans(rows: usize, nr: i32, idx: usize, cnt: usize, k: i32, mean: usize, level: usize): void {
    const M = aM, sa = aSa, qa = alloc(k << 2), fa = alloc(k << 4);
    for (let r = 0; r < nr; r++) {
        const n = u8At(cnt, r), F: i64 = sa ? <i64>i32At(aFix, u8At(aAdj, i32At(rows, r))) : 1, base = r * M;
        if (n == 0) { priorRow(mean, level, base, F, i32At(rows, r)); continue; }
        let G: i64 = 0, same = true; // same: every neighbour has the factor G
        for (let m = 0; m < n; m++) { // the neighbours' rows of q and factors (both lanes)
            const j = i32At(idx, r * k + m), f: i64 = sa ? <i64>i32At(aFix, u8At(aAdj, j)) : 1;
            setI32(qa, m, <i32>(aQ + (<usize>(j * M) << 3)));
            v128.store(fa + (<usize>m << 4), i64x2.splat(f));
            if (m == 0) G = f; else same = same && f == G;
        }
        const nF = <i64>n * F, inv = 1.0 / <f64>nF, e = codedEnd(i32At(rows, r)); // only the coded channels' (11.9)
        if (same) { // sum, max and min of q G are G times those of q (G > 0; exact in i64): no product per neighbour
            if (e == M - 8) neighbourRangeSame(qa, n, 0, M, G, F, nF, inv, mean, level, base);
            else { neighbourRangeSame(qa, n, 0, e, G, F, nF, inv, mean, level, base); neighbourRangeSame(qa, n, M - 8, M, G, F, nF, inv, mean, level, base); }
        } else if (e == M - 8) neighbourRange(qa, fa, n, 0, M, F, nF, inv, mean, level, base);
        else { neighbourRange(qa, fa, n, 0, e, F, nF, inv, mean, level, base); neighbourRange(qa, fa, n, M - 8, M, F, nF, inv, mean, level, base); }
    }
}

/** neighbourRange for neighbours that share one factor G. */
@inline function neighbourRangeSame(qa: usize, n: i32, c0: i32, c1: i32, G: i64, F: i64, nF: i64, inv: f64, mean: usize, level: usize, base: i32): void {
    let c = c0;
    for (; c + 1 < c1; c += 2) {
        const o = <usize>c << 3;
        let v = v128.load(<usize>i32At(qa, 0) + o);
        let sum = v, mx = v, mn = v;
        for (let m = 1; m < n; m++) {
            v = v128.load(<usize>i32At(qa, m) + o);
            sum = i64x2.add(sum, v);
            mx = v128.bitselect(v, mx, i64x2.gt_s(v, mx));
            mn = v128.bitselect(v, mn, i64x2.lt_s(v, mn));
        }
        const act = i64x2.sub(mx, mn);
        channelParameters(c, G * i64x2.extract_lane(sum, 0), G * i64x2.extract_lane(act, 0), F, nF, inv, mean, level, base);
        channelParameters(c + 1, G * i64x2.extract_lane(sum, 1), G * i64x2.extract_lane(act, 1), F, nF, inv, mean, level, base);
    }
    if (c < c1) {
        const o = <usize>c << 3;
        let sum: i64 = 0, mx: i64 = i64.MIN_VALUE, mn: i64 = i64.MAX_VALUE;
        for (let m = 0; m < n; m++) {
            const v = load<i64>(<usize>i32At(qa, m) + o);
            sum += v; mx = max(mx, v); mn = min(mn, v);
        }
        channelParameters(c, G * sum, G * (mx - mn), F, nF, inv, mean, level, base);
    }
}

/** Channels c0 .. c1 - 1 of a row with n neighbours, two at a time. */
@inline function neighbourRange(qa: usize, fa: usize, n: i32, c0: i32, c1: i32, F: i64, nF: i64, inv: f64, mean: usize, level: usize, base: i32): void {
    let c = c0;
    for (; c + 1 < c1; c += 2) neighbourPair(qa, fa, n, c, F, nF, inv, mean, level, base);
    if (c < c1) neighbourOne(qa, fa, n, c, F, nF, inv, mean, level, base);
}

/** Channels c and c + 1 of a row with n neighbours (rows of q at qa, factors fa): sum, max and min of q F two lanes at a time. */
@inline function neighbourPair(qa: usize, fa: usize, n: i32, c: i32, F: i64, nF: i64, inv: f64, mean: usize, level: usize, base: i32): void {
    const o = <usize>c << 3;
    let v = i64x2.mul(v128.load(<usize>i32At(qa, 0) + o), v128.load(fa));
    let sum = v, mx = v, mn = v;
    for (let m = 1; m < n; m++) {
        v = i64x2.mul(v128.load(<usize>i32At(qa, m) + o), v128.load(fa + (<usize>m << 4)));
        sum = i64x2.add(sum, v);
        mx = v128.bitselect(v, mx, i64x2.gt_s(v, mx));
        mn = v128.bitselect(v, mn, i64x2.lt_s(v, mn));
    }
    const act = i64x2.sub(mx, mn);
    channelParameters(c, i64x2.extract_lane(sum, 0), i64x2.extract_lane(act, 0), F, nF, inv, mean, level, base);
    channelParameters(c + 1, i64x2.extract_lane(sum, 1), i64x2.extract_lane(act, 1), F, nF, inv, mean, level, base);
}

/** Channel c of a row with n neighbours, one lane. */
@inline function neighbourOne(qa: usize, fa: usize, n: i32, c: i32, F: i64, nF: i64, inv: f64, mean: usize, level: usize, base: i32): void {
    const o = <usize>c << 3;
    let sum: i64 = 0, mx: i64 = i64.MIN_VALUE, mn: i64 = i64.MAX_VALUE;
    for (let m = 0; m < n; m++) {
        const v = load<i64>(<usize>i32At(qa, m) + o) * load<i64>(fa + (<usize>m << 4));
        sum += v; mx = max(mx, v); mn = min(mn, v);
    }
    channelParameters(c, sum, mx - mn, F, nF, inv, mean, level, base);
}

/**
 * Mean and level of channel c (11.7.3, 11.8) from the neighbours' sum of q F and its spread
 * (max - min >= 0); nF = n F and inv = 1 / nF.
 */
@inline function channelParameters(c: i32, sum: i64, spread: i64, F: i64, nF: i64, inv: f64, mean: usize, level: usize, base: i32): void {
    setI64(mean, base + c, u8At(aMeanFlag, c) ? floorDivInv(sum + (nF >> 1), nF, inv) : priorMean(c, F));
    setU8(level, base + c, u8At(aBucket, c * aB + min(quotientBits(spread, F), aB - 1)));
}

/** bit_length(a // F) for 0 <= a < 2^62 and 1 <= F < 2^14, with no division: a // F >= 2^s exactly when a >= F * 2^s. */
@inline function quotientBits(a: i64, F: i64): i32 {
    const s = <i32>(clz<i64>(F) - clz<i64>(a)); // bit_length(a) - bit_length(F): the answer is s or s + 1
    return s < 0 ? 0 : s + <i32>(a >= (F << s));
}

/** The prior's means and levels (11.3; 11.8 when sa) of a row with no neighbours. */
function priorRow(mean: usize, level: usize, base: i32, F: i64, row: i32): void {
    const sh = aSa ? i32At(aShift, u8At(aAdj, row)) : 0;
    for (let c = 0; c < aM; c++) {
        setI64(mean, base + c, priorMean(c, F));
        setU8(level, base + c, max(0, u8At(aPriorLevel, c) - sh));
    }
}

/**
 * Reconstruction in binary32 (11.5) of the tile's n rows into out (f32 [n * M]): float32(q) times
 * the binary32 step scale[a * M + c] (f32 [8 * M]: float32(step(c)) * STEP_ADJUST_FACTORS[a]) of
 * the row's index a; a value that is not finite fails (E52).
 */
export function reconstruct(n: i32, scale: usize, out: usize): void {
    err = 0;
    const M = aM, M4 = M & ~3, zero = f32x4.splat(0);
    for (let i = 0; i < n; i++) {
        const s = scale + (<usize>(u8At(aAdj, i) * M) << 2), qb = aQ + (<usize>(i * M) << 3), ob = out + (<usize>(i * M) << 2);
        let bad = zero;
        for (let c = 0; c < M4; c += 4) {
            const v = f32x4.mul(float32Lanes(qb + (<usize>c << 3)), v128.load(s + (<usize>c << 2)));
            bad = v128.or(bad, f32x4.ne(f32x4.sub(v, v), zero)); // inf - inf and NaN - NaN are NaN
            v128.store(ob + (<usize>c << 2), v);
        }
        reconstructFrom(v128.any_true(bad) ? 0 : M4, i, s, qb, ob); // a lane not finite: again in channel order, which fails at the first
    }
}

/** reconstruct's channels c0 .. M - 1 of row i, one at a time. */
@inline function reconstructFrom(c0: i32, i: i32, s: usize, qb: usize, ob: usize): void {
    for (let c = c0; c < aM; c++) {
        const v = <f32>load<i64>(qb + (<usize>c << 3)) * load<f32>(s + (<usize>c << 2));
        if (v - v != 0) fail(ERR_NOT_FINITE, i, c);
        store<f32>(ob + (<usize>c << 2), v);
    }
}

// 2^52 + 2^51: for an integer |q| < 2^51, the binary64 number with the bits of MAGIC's plus q is MAGIC + q, exactly
const MAGIC: f64 = 6755399441055744.0;
const MAGIC_BITS: i64 = 0x4338000000000000;

/**
 * float32(q) of the four i64 at p (|q| <= 2^40, checked as each was computed: E51, E68): q to binary64 exactly
 * (MAGIC), then one rounding to binary32, as the scalar conversion rounds.
 */
@inline function float32Lanes(p: usize): v128 {
    const m = f64x2.splat(MAGIC), mb = i64x2.splat(MAGIC_BITS);
    const a = f64x2.sub(i64x2.add(v128.load(p), mb), m), b = f64x2.sub(i64x2.add(v128.load(p, 16), mb), m);
    return v128.shuffle<i32>(f32x4.demote_f64x2_zero(a), f32x4.demote_f64x2_zero(b), 0, 1, 4, 5);
}

/**
 * Clause 11.11 in place on the tile's q (at aQ, before reconstruct): the nRest SH-rest channels from 3 on
 * of every row hold transform coefficients t; each becomes (sum_k T[j][k] t_k + floor(2^shift / 2)) >>
 * shift, T (i64 [nRest * nRest], row-major) the sh_transform unit's matrix, tmp (i64 [nRest]) scratch.
 * Exact in i64: |t| <= 2^40, |T| <= 2^15, nRest <= 45, every sum below 2^61. |q| > 2^40 fails (E68).
 * A row whose coefficients are all below 2^32 in magnitude (every row seen in practice) sums in binary64
 * lanes (shTransformRow): each product is below 2^47 and each partial sum of at most 45 of them below
 * 2^53, so every binary64 operation is exact and the sums are the i64 sums.
 */
export function inverseShTransform(n: i32, nRest: i32, T: usize, shift: i32, tmp: usize): void {
    err = 0;
    const M = aM, half: i64 = (<i64>1 << <i64>shift) >> 1, P = (nRest + 7) & ~7;
    // tmp: the row's new values (i64 [nRest]), then its non-zero coefficients' indices (i32 [nRest]) and values (i64 [nRest]):
    // the terms of zero coefficients (most, after RDOQ, and every uncoded one) are skipped
    const nzIdx = tmp + (<usize>nRest << 3), nzVal = nzIdx + (<usize>nRest << 2);
    // T by columns in binary64, each padded with zeros to P (a multiple of 8 lanes): Tt[k * P + j] = T[j][k]
    const Tt = alloc((nRest * P) << 3), tv = alloc(nRest << 4), sums = alloc(P << 3);
    for (let j = 0; j < nRest; j++) for (let k = 0; k < nRest; k++) store<f64>(Tt + (<usize>(k * P + j) << 3), <f64>i64At(T, j * nRest + k));
    for (let i = 0; i < n; i++) {
        const qb = aQ + (<usize>(i * M + 3) << 3);
        let nz = 0, small = true;
        for (let k = 0; k < nRest; k++) {
            const t = i64At(qb, k);
            if (t != 0) { store<i32>(nzIdx + (<usize>nz << 2), k); setI64(nzVal, nz, t); nz++; small = small && t < 0x100000000 && t > -0x100000000; }
        }
        if (nz == 0) { memory.fill(qb, 0, <usize>nRest << 3); continue; } // (0 + half) >> shift = 0
        if (small) { shTransformRow(i, qb, nz, nRest, P, Tt, tv, sums, nzIdx, nzVal, half, shift); continue; }
        for (let j = 0; j < nRest; j++) {
            const row = T + (<usize>(j * nRest) << 3);
            let u: i64 = 0;
            for (let m = 0; m < nz; m++) u += i64At(row, load<i32>(nzIdx + (<usize>m << 2))) * i64At(nzVal, m);
            shTransformValue(tmp, i, j, u, half, shift);
        }
        memory.copy(qb, tmp, <usize>nRest << 3);
    }
}

/** Value j of row i of the inverse SH transform from its sum u (inverseShTransform), checked (E68), to out[j]. */
@inline function shTransformValue(out: usize, i: i32, j: i32, u: i64, half: i64, shift: i32): void {
    const v = (u + half) >> <i64>shift;
    if (v < -Q_LIMIT || v > Q_LIMIT) { errWide = <u64>v; fail(ERR_SH_TRANSFORM, i, 3 + j); }
    setI64(out, j, v);
}

/**
 * inverseShTransform's row i (its SH rest at qb, nz non-zero coefficients below 2^32 in magnitude) in
 * binary64 lanes: for eight outputs j at a time, the sum over the coefficients of Tt's column times t,
 * four f64x2 accumulators, then the values in increasing j (the order of the E68 check).
 */
function shTransformRow(i: i32, qb: usize, nz: i32, nRest: i32, P: i32, Tt: usize, tv: usize, sums: usize, nzIdx: usize, nzVal: usize, half: i64, shift: i32): void {
    for (let m = 0; m < nz; m++) {
        v128.store(tv + (<usize>m << 4), f64x2.splat(<f64>i64At(nzVal, m)));
        store<i32>(nzIdx + (<usize>m << 2), (load<i32>(nzIdx + (<usize>m << 2)) * P) << 3); // the column's byte offset
    }
    for (let j0 = 0; j0 < nRest; j0 += 8) {
        let a0 = f64x2.splat(0), a1 = a0, a2 = a0, a3 = a0;
        const base = Tt + (<usize>j0 << 3);
        for (let m = 0; m < nz; m++) {
            const col = base + <usize>load<i32>(nzIdx + (<usize>m << 2)), t = v128.load(tv + (<usize>m << 4));
            a0 = f64x2.add(a0, f64x2.mul(v128.load(col), t));
            a1 = f64x2.add(a1, f64x2.mul(v128.load(col, 16), t));
            a2 = f64x2.add(a2, f64x2.mul(v128.load(col, 32), t));
            a3 = f64x2.add(a3, f64x2.mul(v128.load(col, 48), t));
        }
        const o = sums + (<usize>j0 << 3);
        v128.store(o, a0); v128.store(o, a1, 16); v128.store(o, a2, 32); v128.store(o, a3, 48);
    }
    for (let j = 0; j < nRest; j++) shTransformValue(qb, i, j, <i64>load<f64>(sums + (<usize>j << 3)), half, shift);
}

/**
 * Clause 11.10 in place on the reconstructed values out (f32 [n * M]) of the tile (q at aQ): channel
 * wc of every row becomes its implied w, float32(sqrt(max(0, 2^-k - ((x*x + y*y) + z*z)))) with every
 * operation in binary64 (wasm's f64 arithmetic and sqrt are IEEE 754's, correctly rounded; the demotion
 * rounds to nearest even, as Math.fround: rotation.mjs's bits), k the row's quantized value of channel
 * wc and x, y, z its next three values; an index outside [0, maxIndex] fails (E66).
 */
export function impliedRotations(out: usize, n: i32, wc: i32, maxIndex: i32): void {
    err = 0;
    const M = aM;
    for (let i = 0; i < n; i++) {
        const b = out + (<usize>(i * M + wc) << 2);
        const k = load<i64>(aQ + (<usize>(i * M + wc) << 3));
        if (k < 0 || k > <i64>maxIndex) fail(ERR_LENGTH_INDEX, i, 0);
        const x = <f64>load<f32>(b + 4), y = <f64>load<f32>(b + 8), z = <f64>load<f32>(b + 12);
        const lengthSq = reinterpret<f64>(<u64>(1023 - <i32>k) << 52); // 2^-k, exactly (k <= 15)
        store<f32>(b, <f32>Math.sqrt(Math.max(0.0, lengthSq - ((x * x + y * y) + z * z))));
    }
}

/**
 * The step-adjustment indices (11.8) of a chunk's n rows first, first + step, ... into adj (u8 [rows]):
 * residual r (f64 [n], decodeSymbols' output; NaN beyond 2^53) plus the adjust mean, in binary64 as
 * attributes.mjs did; an index outside [0, max] fails (E65).
 */
export function stepIndices(r: usize, n: i32, mean: f64, max: f64, adj: usize, first: i32, step: i32): void {
    err = 0;
    for (let t = 0; t < n; t++) {
        const a = load<f64>(r + (<usize>t << 3)) + mean;
        if (!(a >= 0 && a <= max)) fail(ERR_STEP_INDEX, t, 0);
        store<u8>(adj + <usize>(first + t * step), <u8><i32>a);
    }
}

// ---------------------------------------------------------------- serialization (clause 12)

/**
 * The body of clause 12's serialization of one tile's n points (after the 49-byte header) into out:
 * the coordinates (x, y, z at x, y, z: i32 [n]) as int64, then the values (f32 [n * M], channel
 * order of 11.1) in the groups SH (S3 channels), opacity (1), scales (3) and rotations (M - S3 - 4),
 * each group point-major. A scene's serialization is these parts of its tiles, in tile order.
 */
export function serializeTile(x: usize, y: usize, z: usize, values: usize, n: i32, M: i32, S3: i32, out: usize): void {
    for (let i = 0; i < n; i++) {
        const p = out + <usize>i * 24, o = <usize>i << 2;
        store<i64>(p, <i64>load<i32>(x + o));
        store<i64>(p + 8, <i64>load<i32>(y + o));
        store<i64>(p + 16, <i64>load<i32>(z + o));
    }
    let at = out + <usize>n * 24;
    at = serializeGroup(values, n, M, 0, S3, at);
    at = serializeGroup(values, n, M, S3, S3 + 1, at);
    at = serializeGroup(values, n, M, S3 + 1, S3 + 4, at);
    serializeGroup(values, n, M, S3 + 4, M, at);
}

/**
 * The renderer's arrays of one tile's n points (decoder.mjs's sceneArrays) at out, one after the other:
 * positions (f32 [3 n]: float32(c) * voxel_size + origin per axis, each step rounded to binary32 as
 * Math.fround does), SH (f32 [S3 n]), opacities (f32 [n]), log scales (f32 [3 n]) and rotations
 * (f32 [(M - S3 - 4) n]), from the coordinates x, y, z (i32 [n]) and values (f32 [n M], 11.1's order).
 */
export function rendererArrays(x: usize, y: usize, z: usize, values: usize, n: i32, M: i32, S3: i32, vs: f32, o0: f32, o1: f32, o2: f32, out: usize): void {
    for (let i = 0; i < n; i++) {
        const o = <usize>i << 2, p = out + <usize>i * 12;
        store<f32>(p, <f32>load<i32>(x + o) * vs + o0);
        store<f32>(p + 4, <f32>load<i32>(y + o) * vs + o1);
        store<f32>(p + 8, <f32>load<i32>(z + o) * vs + o2);
    }
    let at = out + <usize>n * 12;
    at = serializeGroup(values, n, M, 0, S3, at);
    at = serializeGroup(values, n, M, S3, S3 + 1, at);
    at = serializeGroup(values, n, M, S3 + 1, S3 + 4, at);
    serializeGroup(values, n, M, S3 + 4, M, at);
}

/** Channels a .. b - 1 of n rows of M values, point-major, at `at`; returns the end. */
function serializeGroup(values: usize, n: i32, M: i32, a: i32, b: i32, at: usize): usize {
    const w = b - a;
    for (let i = 0; i < n; i++) {
        const src = values + (<usize>(i * M + a) << 2), dst = at + (<usize>(i * w) << 2);
        let c = 0;
        for (; c + 4 <= w; c += 4) v128.store(dst + (<usize>c << 2), v128.load(src + (<usize>c << 2)));
        for (; c < w; c++) store<u32>(dst + (<usize>c << 2), load<u32>(src + (<usize>c << 2)));
    }
    return at + (<usize>(n * w) << 2);
}

// ---------------------------------------------------------------- CRC-32 (clause 3, 6.1)

let crcT: usize = 0; // slicing-by-8 tables, 8 x 256 u32 (crc32.mjs's TABLE)

/** Build the CRC-32/ISO-HDLC tables (reflected polynomial 0xEDB88320) in fresh memory (kept by the caller's keep()). */
export function crcTables(): void {
    crcT = reserve(8 * 256 * 4);
    for (let n: u32 = 0; n < 256; n++) {
        let c = n;
        for (let k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320 ^ (c >>> 1) : c >>> 1;
        store<u32>(crcT + (<usize>n << 2), c);
    }
    for (let s: usize = 1; s < 8; s++) {
        for (let n: usize = 0; n < 256; n++) {
            const prev = load<u32>(crcT + ((((s - 1) << 8) + n) << 2));
            store<u32>(crcT + (((s << 8) + n) << 2), (prev >>> 8) ^ load<u32>(crcT + (<usize>(prev & 255) << 2)));
        }
    }
}

@inline function crcAt(s: usize, i: u32): u32 { return load<u32>(crcT + (((s << 8) + <usize>i) << 2)); }

/** CRC-32 of the n bytes at p (crc32.mjs's crc32 of a fresh CRC, slicing by 8). */
export function crc32(p: usize, n: i32): u32 {
    let c: u32 = 0xFFFFFFFF;
    let i: i32 = 0;
    for (; i + 8 <= n; i += 8) {
        const a = c ^ load<u32>(p + <usize>i), b = load<u32>(p + <usize>i + 4);
        c = crcAt(7, a & 255) ^ crcAt(6, (a >>> 8) & 255) ^ crcAt(5, (a >>> 16) & 255) ^ crcAt(4, a >>> 24)
            ^ crcAt(3, b & 255) ^ crcAt(2, (b >>> 8) & 255) ^ crcAt(1, (b >>> 16) & 255) ^ crcAt(0, b >>> 24);
    }
    for (; i < n; i++) c = crcAt(0, (c ^ <u32>load<u8>(p + <usize>i)) & 255) ^ (c >>> 8);
    return ~c;
}
