// The canonical k nearest neighbours of spec clause 11.7.2 (Annex H.3 with a ball holding the
// whole tile): for each query, the first k data points in increasing order of (d2, index), d2
// the exact squared Euclidean distance of integer coordinates. The search runs in WebAssembly
// (wasm/decoder.ts, gridNeighbours: a dense uniform grid of cells of side 2^b searched in shells
// around the query's cell, exact 64-bit distances for every extent up to MAX_EXTENT).
import { callWasm, copyIn, wasm } from './wasm.mjs';

/**
 * The neighbours of the query rows among the data rows (ascending) of the tile's points x, y, z
 * (Int32Array; lo: their per-axis minima, ext: their per-axis extents, at most MAX_EXTENT): ids to
 * idx[r * k ..] nearest first (the rest of idx untouched), counts to cnt[r].
 */
export function gridNeighbours(x, y, z, lo, ext, data, queries, k, idx, cnt) {
    const w = wasm();
    w.reset();
    const n = x.length, nq = queries.length;
    const at = (arr) => copyIn(w, arr);
    const px = at(x), py = at(y), pz = at(z), pd = at(data), pq = at(queries), pidx = at(idx.subarray(0, nq * k)), pcnt = at(cnt.subarray(0, nq));
    if (y.length !== n || z.length !== n) throw new Error('gridNeighbours: x, y, z differ in length');
    callWasm(() => w.gridNeighbours(px, py, pz, lo[0], lo[1], lo[2], ext[0], ext[1], ext[2], pd, data.length, pq, nq, k, pidx, pcnt), () => null);
    idx.set(new Int32Array(w.memory.buffer, pidx, nq * k));
    cnt.set(new Uint8Array(w.memory.buffer, pcnt, nq));
}
