// The canonical k nearest neighbours of spec clause 11.7.2 (Annex H.3 with a ball holding the
// whole tile): for each query, the first k data points in increasing order of (d2, index), d2
// the exact squared Euclidean distance of integer coordinates. The search runs in WebAssembly
// (wasm/decoder.ts, gridNeighbours: a dense uniform grid of cells of side 2^b searched in shells
// around the query's cell, exact 64-bit distances for every extent up to MAX_EXTENT).
import { alloc, callWasm, copyIn, wasm } from './wasm.mjs';

/**
 * The neighbours of the nq query rows among the nd data rows (ascending; int32 each, at pq and pd in
 * the module's memory) of the points whose coordinates lie in the module's memory at p = [px, py, pz]
 * (int32 each; lo: their per-axis minima, ext: their per-axis extents, at most MAX_EXTENT), left in the module's memory: returns
 * {idx, cnt, mark}, the addresses of the ids (int32 [nq * k], nearest first) and counts (uint8 [nq]),
 * which the module keeps across resets (the search's working memory is not kept) until release(mark).
 */
export function neighboursInModule(p, lo, ext, pd, nd, pq, nq, k) {
    const w = wasm();
    const idx = alloc(w, 4 * nq * k), cnt = alloc(w, Math.max(nq, 1)), mark = w.keep();
    callWasm(() => w.gridNeighbours(p[0], p[1], p[2], lo[0], lo[1], lo[2], ext[0], ext[1], ext[2], pd, nd, pq, nq, k, idx, cnt), () => null);
    return { idx, cnt, mark };
}

/**
 * The same for coordinates x, y, z (Int32Array): ids to idx[r * k ..] nearest first (the rest of
 * idx untouched), counts to cnt[r].
 */
export function gridNeighbours(x, y, z, lo, ext, data, queries, k, idx, cnt) {
    const w = wasm(), nq = queries.length;
    if (y.length !== x.length || z.length !== x.length) throw new Error('gridNeighbours: x, y, z differ in length');
    w.reset();
    const r = neighboursInModule([x, y, z].map((a) => copyIn(w, a)), lo, ext, copyIn(w, data), data.length, copyIn(w, queries), nq, k);
    const got = new Int32Array(w.memory.buffer, r.idx, nq * k), counts = new Uint8Array(w.memory.buffer, r.cnt, nq);
    for (let q = 0; q < nq; q++) idx.set(got.subarray(q * k, q * k + counts[q]), q * k);
    cnt.set(counts);
    w.release(r.mark);
}
