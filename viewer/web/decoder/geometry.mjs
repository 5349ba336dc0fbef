// Geometry decoding (spec/geometry.md, clauses G.2 to G.6): the octree with direct coding (IDCM)
// and binary decisions with adaptive integer probabilities, output in the normative Morton order.
import { BitReader, checkRange } from './bitreader.mjs';
import { BitstreamError } from './errors.mjs';
import { RangeDecoder } from './range.mjs';

const TWO24 = 1 << 24;
const NUM_OCC_CONTEXTS = 432;
const DENS = [0, 1, 1, 2, 2, 3, 3];
const AXIS_BIT = [4, 2, 1];
const COUNT_LIMIT = 1024;
const LEVEL_COUNT_LIMIT = 64;
const POPCOUNT8 = Uint8Array.from({ length: 256 }, (_, v) => { let c = 0; for (; v; v &= v - 1) c++; return c; });

/** geometry_header() (G.2, G.3), checked; returns {bboxMin, bitDepth, idcmMode, dataOffset}. */
export function parseGeometryHeader(payload, n) {
    const r = new BitReader(payload, 'geometry_header');
    const bboxMin = [0, 0, 0], bitDepth = [0, 0, 0];
    for (let i = 0; i < 3; i++) {
        const sign = r.u(1, `geom_bbox_min_sign_flag[${i}]`);
        const abs = checkRange('geometry_header', `geom_bbox_min_abs[${i}]`, r.ue(`geom_bbox_min_abs[${i}]`), 0, 2 ** 31);
        if (!sign && abs > 2 ** 31 - 1) {
            throw new BitstreamError(`geometry_header.geom_bbox_min_abs[${i}] = ${abs} puts the bounding-box minimum outside [-2^31, 2^31) (G.3, E26)`);
        }
        bboxMin[i] = sign ? -abs : abs;
        bitDepth[i] = checkRange('geometry_header', `geom_bit_depth[${i}]`, r.u(6, `geom_bit_depth[${i}]`), 0, 32);
    }
    const idcmMode = checkRange('geometry_header', 'geom_idcm_mode', r.ue('geom_idcm_mode'), 0, 2);
    r.byteAlign();
    if (n > 2 ** (bitDepth[0] + bitDepth[1] + bitDepth[2])) {
        throw new BitstreamError(`geometry: ${n} points cannot be distinct in a bounding box of ${bitDepth} bits per axis (G.3, E27)`);
    }
    const dataOffset = r.bitPosition >>> 3;
    if (Math.max(...bitDepth) === 0 && dataOffset < payload.length) {
        throw new BitstreamError(`geometry: ${payload.length - dataOffset} bytes of coded data after a header of bit depth 0 (G.3, E28)`);
    }
    return { bboxMin, bitDepth, idcmMode, dataOffset };
}

/** Scratch arrays of decodeBinarySequence for up to n decisions over numCtx contexts. */
function binaryScratch(n, numCtx) {
    return { count: new Int32Array(numCtx + 1), order: new Int32Array(n) };
}

/** The binary procedure of G.6.1 over decisions with contexts ctx[0..n-1] and counts T (Int32Array [C * 2]). */
function decodeBinarySequence(dec, ctx, n, T, numCtx, out, scratch = binaryScratch(n, numCtx)) {
    const { count, order } = scratch;
    for (let c0 = 0; c0 < n;) {
        const c1 = Math.min(n, c0 === 0 ? 256 : 2 * c0); // blocks [0, 256), [256, 512), [512, 1024), ...
        count.fill(0);
        for (let j = c0; j < c1; j++) count[ctx[j] + 1]++;
        for (let c = 0; c < numCtx; c++) count[c + 1] += count[c];
        for (let j = c0; j < c1; j++) order[count[ctx[j]]++] = j;
        let start = 0;
        for (let c = 0; c < numCtx; c++) {
            const end = count[c];
            if (end === start) continue;
            const n0 = T[2 * c], n1 = T[2 * c + 1];
            let f1 = Math.floor((2 * n1 + 1) * TWO24 / (2 * (n0 + n1) + 2));
            if (f1 < 1) f1 = 1; else if (f1 > TWO24 - 1) f1 = TWO24 - 1;
            for (let t = start; t < end; t++) out[order[t]] = dec.decodeBinary(f1);
            start = end;
        }
        for (let j = c0; j < c1; j++) T[2 * ctx[j] + out[j]]++;
        limitCounts(T, numCtx, COUNT_LIMIT);
        c0 = c1;
    }
}

function limitCounts(T, numCtx, limit) {
    for (let c = 0; c < numCtx; c++) {
        while (T[2 * c] + T[2 * c + 1] > limit) {
            T[2 * c] = (T[2 * c] + 1) >> 1;
            T[2 * c + 1] = (T[2 * c + 1] + 1) >> 1;
        }
    }
}

/**
 * Face neighbours (G.5.3) of the children of `nodes` (occupancy occ, first[i] the index of node
 * i's first child): the neighbour of a child across a face is a sibling, or a child of the
 * parent's neighbour across the same face. nb[6 j + 2a] is the node at q - e_a, nb[6 j + 2a + 1]
 * at q + e_a, or -1.
 */
function childNeighbours(nodes, occ, first, children) {
    const m = nodes.m, pnb = nodes.nb, nb = new Int32Array(6 * children);
    for (let i = 0, j = 0; i < m; i++) {
        const o = occ[i];
        for (let k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            for (let a = 0; a < 3; a++) {
                const bit = AXIS_BIT[a], b = 6 * j + 2 * a, u = pnb[6 * i + 2 * a + ((k & bit) ? 1 : 0)];
                // the sibling on the other side of the axis, and the child across the parent's face
                const sib = childIndex(occ, first, i, k ^ bit), across = u < 0 ? -1 : childIndex(occ, first, u, k ^ bit);
                if (k & bit) { nb[b] = sib; nb[b + 1] = across; } else { nb[b] = across; nb[b + 1] = sib; }
            }
            j++;
        }
    }
    return nb;
}

/** The index of child k of node i (first[i] the index of its first child), or -1. */
function childIndex(occ, first, i, k) {
    const o = occ[i];
    return (o >> k) & 1 ? first[i] + POPCOUNT8[o & ((1 << k) - 1)] : -1;
}

class Nodes {
    constructor(m) {
        this.m = m;
        this.qx = new Float64Array(m); this.qy = new Float64Array(m); this.qz = new Float64Array(m);
        this.sib1 = new Uint8Array(m); this.parNbr = new Uint8Array(m); this.parSib1 = new Uint8Array(m);
        this.nb = null; // face neighbours (G.5.3), as childNeighbours
    }
}

/** Direct coding (G.5.2). Returns the nodes that are not direct; pushes the direct points. */
function directCoding(dec, st, nodes, R, bitDepth, mode, n, direct) {
    const m = nodes.m;
    const elig = [];
    const sib1 = nodes.sib1, parNbr = nodes.parNbr, parSib1 = nodes.parSib1;
    for (let i = 0; i < m; i++) {
        const ok = mode === 1 ? (sib1[i] === 1 && parNbr[i] === 0 && parSib1[i] <= 2) : parNbr[i] === 0;
        if (ok) elig.push(i);
    }
    if (!elig.length) return nodes;
    const ctx = new Int32Array(elig.length);
    for (let e = 0; e < elig.length; e++) { const i = elig[e]; ctx[e] = Math.min(sib1[i] - 1, 2) * 3 + Math.min(parSib1[i] - 1, 2); }
    const flag = new Int32Array(elig.length);
    decodeBinarySequence(dec, ctx, elig.length, st.idcm, 9, flag);
    const dnodes = [];
    for (let e = 0; e < elig.length; e++) if (flag[e] === 1) dnodes.push(elig[e]);
    const two = new Int32Array(dnodes.length);
    decodeBinarySequence(dec, new Int32Array(dnodes.length), dnodes.length, st.two, 1, two);
    const owners = [];
    for (let e = 0; e < dnodes.length; e++) { owners.push(dnodes[e]); if (two[e]) owners.push(dnodes[e]); }
    if (direct.count + owners.length + (m - dnodes.length) > n) {
        throw new BitstreamError(`geometry data: more than N = ${n} points (G.5.2 step 3, E29)`);
    }
    const P = owners.length;
    const low = [0, 1, 2].map((a) => dec.decodeBitsSame(Math.min(R, bitDepth[a]), P));
    const scale = 2 ** R;
    const qx = nodes.qx, qy = nodes.qy, qz = nodes.qz, [lx, ly, lz] = low;
    for (let o = 0; o < P; o++) {
        const i = owners[o];
        const px = qx[i] * scale + lx[o], py = qy[i] * scale + ly[o], pz = qz[i] * scale + lz[o];
        if (o > 0 && owners[o - 1] === i) {
            const prev = direct.count - 1;
            if (direct.x[prev] === px && direct.y[prev] === py && direct.z[prev] === pz) {
                throw new BitstreamError('geometry data: the two points of a two-point direct node are equal (G.5.2, E30)');
            }
        }
        direct.push(px, py, pz);
    }
    const isDirect = new Uint8Array(m);
    for (const i of dnodes) isDirect[i] = 1;
    const keep = new Nodes(m - dnodes.length), index = new Int32Array(m);
    for (let i = 0, j = 0; i < m; i++) {
        index[i] = isDirect[i] ? -1 : j;
        if (isDirect[i]) continue;
        keep.qx[j] = nodes.qx[i]; keep.qy[j] = nodes.qy[i]; keep.qz[j] = nodes.qz[i];
        keep.sib1[j] = nodes.sib1[i]; keep.parNbr[j] = nodes.parNbr[i]; keep.parSib1[j] = nodes.parSib1[i];
        j++;
    }
    // the face neighbours among the nodes that are not direct (G.5.3)
    keep.nb = new Int32Array(6 * keep.m);
    for (let i = 0; i < m; i++) {
        if (isDirect[i]) continue;
        const b = 6 * index[i];
        for (let d = 0; d < 6; d++) { const u = nodes.nb[6 * i + d]; keep.nb[b + d] = u < 0 ? -1 : index[u]; }
    }
    return keep;
}

/** Occupancy (G.5.4); returns the nodes of depth l + 1. */
function occupancy(dec, st, nodes, depth, R, bitDepth, n, numDirect) {
    const m = nodes.m;
    for (let k = 0; k < 8; k++) limitCounts(st.occ[k], NUM_OCC_CONTEXTS, LEVEL_COUNT_LIMIT);
    const nb = nodes.nb;
    const nbrCount = new Uint8Array(m), dens = new Uint8Array(m);
    // per node: the + neighbours by axis, and the term of each axis whose child bit is 0 (q - e_a exists)
    const up = new Int32Array(3 * m), lowTerm = new Uint8Array(3 * m);
    for (let i = 0; i < m; i++) {
        let c = 0;
        for (let d = 0; d < 6; d++) if (nb[6 * i + d] >= 0) c++;
        nbrCount[i] = c; dens[i] = DENS[c];
        for (let a = 0; a < 3; a++) { up[3 * i + a] = nb[6 * i + 2 * a + 1]; lowTerm[3 * i + a] = nb[6 * i + 2 * a] >= 0 ? 1 : 0; }
    }
    const splits = bitDepth.map((d) => R - 1 < d);
    const valid = [];
    for (let k = 0; k < 8; k++) if ([0, 1, 2].every((a) => splits[a] || !(k & AXIS_BIT[a]))) valid.push(k);
    const last = valid[valid.length - 1];
    const occ = new Uint8Array(m);
    const ctx = new Int32Array(m), coded = new Int32Array(m), dv = new Int32Array(m);
    const scratch = binaryScratch(m, NUM_OCC_CONTEXTS);
    for (const k of valid) {
        const nc = occupancyContexts(k, k === last, m, occ, up, lowTerm, dens, ctx, coded);
        decodeBinarySequence(dec, ctx, nc, st.occ[k], NUM_OCC_CONTEXTS, dv, scratch);
        const bit = 1 << k;
        for (let t = 0; t < nc; t++) if (dv[t]) occ[coded[t]] |= bit;
        if (k === last) for (let i = 0; i < m; i++) if (!(occ[i] & (bit - 1))) occ[i] |= bit; // inferred occupied
    }
    let children = 0;
    for (let i = 0; i < m; i++) children += POPCOUNT8[occ[i]];
    if (numDirect + children > n) {
        throw new BitstreamError(`geometry data: ${numDirect + children} points at depth ${depth + 1}, more than N = ${n} (G.5.4, E31)`);
    }
    const next = new Nodes(children), first = new Int32Array(m);
    for (let i = 0, j = 0; i < m; i++) {
        const o = occ[i];
        first[i] = j;
        for (let k = 0; k < 8; k++) {
            if (!((o >> k) & 1)) continue;
            next.qx[j] = 2 * nodes.qx[i] + ((k >> 2) & 1);
            next.qy[j] = 2 * nodes.qy[i] + ((k >> 1) & 1);
            next.qz[j] = 2 * nodes.qz[i] + (k & 1);
            next.sib1[j] = POPCOUNT8[o]; next.parNbr[j] = nbrCount[i]; next.parSib1[j] = nodes.sib1[i];
            j++;
        }
    }
    next.nb = childNeighbours(nodes, occ, first, children);
    return next;
}

/** The contexts of child k (G.5.4) of the nodes whose bit k is coded: ctx[0..nc-1], coded[0..nc-1] the nodes; returns nc. */
function occupancyContexts(k, isLast, m, occ, up, lowTerm, dens, ctx, coded) {
    const kx = k & 4, ky = k & 2, kz = k & 1, below = (1 << k) - 1;
    const jx = k ^ 4, jy = k ^ 2, jz = k ^ 1;
    let nc = 0;
    for (let i = 0; i < m; i++) {
        const o = occ[i];
        const before = POPCOUNT8[o & below];
        if (isLast && before === 0) continue;
        const b = 3 * i;
        let sx = lowTerm[b], sy = lowTerm[b + 1], sz = lowTerm[b + 2], u;
        if (kx) { u = up[b]; sx = ((o >> jx) & 1) + (u >= 0 ? (occ[u] >> jx) & 1 : 0); }
        if (ky) { u = up[b + 1]; sy = ((o >> jy) & 1) + (u >= 0 ? (occ[u] >> jy) & 1 : 0); }
        if (kz) { u = up[b + 2]; sz = ((o >> jz) & 1) + (u >= 0 ? (occ[u] >> jz) & 1 : 0); }
        ctx[nc] = (((sx * 3 + sy) * 3 + sz) * 4 + (before < 3 ? before : 3)) * 4 + dens[i];
        coded[nc++] = i;
    }
    return nc;
}

class PointList {
    constructor() { this.x = []; this.y = []; this.z = []; this.count = 0; }
    push(x, y, z) { this.x.push(x); this.y.push(y); this.z.push(z); this.count++; }
}

function lessMsb(a, b) { return a < b && a < ((a ^ b) >>> 0); }

/** Morton order comparison of offsets (G.4): x bits before y before z at each bit position. */
function mortonCompare(ax, ay, az, bx, by, bz) {
    let axis = 0, best = (ax ^ bx) >>> 0;
    const ty = (ay ^ by) >>> 0, tz = (az ^ bz) >>> 0;
    if (lessMsb(best, ty)) { axis = 1; best = ty; }
    if (lessMsb(best, tz)) { axis = 2; best = tz; }
    if (axis === 0) return ax - bx;
    return axis === 1 ? ay - by : az - bz;
}

/**
 * Decode a geometry payload of n points (G.2 to G.5). Returns {x, y, z} (Int32Array each: voxel
 * coordinates in normative order) and the header.
 */
export function decodeGeometry(payload, n) {
    const h = parseGeometryHeader(payload, n);
    const dec = new RangeDecoder(payload.subarray(h.dataOffset), 'geometry data');
    const D = Math.max(...h.bitDepth);
    const st = { occ: Array.from({ length: 8 }, () => new Int32Array(2 * NUM_OCC_CONTEXTS)), idcm: new Int32Array(18), two: new Int32Array(2) };
    let nodes = new Nodes(1);
    nodes.sib1[0] = 1; nodes.parSib1[0] = 1; nodes.nb = new Int32Array(6).fill(-1);
    const direct = new PointList();
    for (let l = 0; l < D; l++) {
        const R = D - l;
        if (h.idcmMode !== 0 && R >= 2) nodes = directCoding(dec, st, nodes, R, h.bitDepth, h.idcmMode, n, direct);
        if (nodes.m === 0) break;
        nodes = occupancy(dec, st, nodes, l, R, h.bitDepth, n, direct.count);
    }
    dec.checkExhausted();
    return { ...outputPoints(nodes, direct, h, n), header: h };
}

function outputPoints(leaves, direct, h, n) {
    const total = direct.count + leaves.m;
    if (total !== n) throw new BitstreamError(`geometry data holds ${total} points, N = ${n} (G.5.5, E32)`);
    const dorder = Array.from({ length: direct.count }, (_, i) => i);
    dorder.sort((a, b) => mortonCompare(direct.x[a], direct.y[a], direct.z[a], direct.x[b], direct.y[b], direct.z[b]));
    const ox = new Float64Array(n), oy = new Float64Array(n), oz = new Float64Array(n);
    let i = 0, j = 0, o = 0;
    while (o < n) { // merge the sorted direct points with the leaves (already in Morton order)
        let takeDirect;
        if (i >= dorder.length) takeDirect = false;
        else if (j >= leaves.m) takeDirect = true;
        else {
            const d = dorder[i];
            takeDirect = mortonCompare(direct.x[d], direct.y[d], direct.z[d], leaves.qx[j], leaves.qy[j], leaves.qz[j]) < 0;
        }
        if (takeDirect) { const d = dorder[i++]; ox[o] = direct.x[d]; oy[o] = direct.y[d]; oz[o] = direct.z[d]; }
        else { ox[o] = leaves.qx[j]; oy[o] = leaves.qy[j]; oz[o] = leaves.qz[j]; j++; }
        o++;
    }
    const out = [ox, oy, oz].map((c, a) => {
        let mn = Infinity;
        for (let t = 0; t < n; t++) if (c[t] < mn) mn = c[t];
        if (mn !== 0) throw new BitstreamError('geometry data: the decoded points do not attain the bounding-box minimum (G.5.5, E33)');
        const r = new Int32Array(n);
        for (let t = 0; t < n; t++) {
            const v = c[t] + h.bboxMin[a];
            if (v > 2 ** 31 - 1) throw new BitstreamError('geometry data: decoded coordinates exceed 2^31 - 1 (G.5.5, E34)');
            r[t] = v;
        }
        return r;
    });
    return { x: out[0], y: out[1], z: out[2] };
}
