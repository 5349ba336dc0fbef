// The canonical k nearest neighbours of spec clause 11.7.2 (Annex H.3 with a ball holding the
// whole tile): for each query, the first k data points in increasing order of (d2, index), d2
// the exact squared Euclidean distance of integer coordinates. The data points are binned in a
// dense uniform grid of cubic cells (side 2^b); a query visits the cells in growing shells
// around its own and stops once every unvisited point is provably farther than its k-th nearest
// (strictly, so that points at equal distance compete by index exactly). Distances are exact
// doubles when 3 E^2 < 2^53 (E the coordinates' extent); wider tiles take an exact BigInt search.
export const EXACT_EXTENT = Math.floor(Math.sqrt((2 ** 53 - 1) / 3));
const CELLS_PER_POINT = 2; // grid size: at most this many cells per data point (and 4096)

/**
 * The neighbours of the query rows among the data rows (ascending) of the tile's points x, y, z
 * (lo: their per-axis minima, ext: their per-axis extents): ids to idx[r * k ..] nearest first,
 * counts to cnt[r].
 */
export function gridNeighbours(x, y, z, lo, ext, data, queries, k, idx, cnt) {
    const g = new Grid(x, y, z, lo, ext, data);
    const hd = new Float64Array(k), hi = new Int32Array(k);
    for (let r = 0; r < queries.length; r++) {
        const i = queries[r];
        const size = g.search(x[i] - lo[0], y[i] - lo[1], z[i] - lo[2], k, hd, hi);
        for (let m = 0; m < size; m++) idx[r * k + m] = hi[m];
        cnt[r] = size;
    }
}

class Grid {
    constructor(x, y, z, lo, ext, data) {
        const n = data.length, limit = Math.max(4096, CELLS_PER_POINT * n);
        let b = 0;
        while (((ext[0] >> b) + 1) * ((ext[1] >> b) + 1) * ((ext[2] >> b) + 1) > limit) b++;
        this.b = b; this.side = 2 ** b;
        this.nx = (ext[0] >> b) + 1; this.ny = (ext[1] >> b) + 1; this.nz = (ext[2] >> b) + 1;
        const start = new Int32Array(this.nx * this.ny * this.nz + 1), cell = new Int32Array(n);
        for (let t = 0; t < n; t++) {
            const j = data[t];
            cell[t] = (((x[j] - lo[0]) >> b) * this.ny + ((y[j] - lo[1]) >> b)) * this.nz + ((z[j] - lo[2]) >> b);
            start[cell[t] + 1]++;
        }
        for (let c = 1; c < start.length; c++) start[c] += start[c - 1];
        // the points sorted by cell (stable), as offsets from lo
        const px = new Int32Array(n), py = new Int32Array(n), pz = new Int32Array(n), id = new Int32Array(n);
        const fill = start.slice(0, -1);
        for (let t = 0; t < n; t++) {
            const j = data[t], o = fill[cell[t]]++;
            px[o] = x[j] - lo[0]; py[o] = y[j] - lo[1]; pz[o] = z[j] - lo[2]; id[o] = j;
        }
        this.start = start; this.px = px; this.py = py; this.pz = pz; this.id = id;
    }

    /** The k nearest of (qx, qy, qz) (offsets from lo) sorted by (d2, id) into hd/hi; returns their count. */
    search(qx, qy, qz, k, hd, hi) {
        const b = this.b, cx = qx >> b, cy = qy >> b, cz = qz >> b;
        let size = this.visitCell((cx * this.ny + cy) * this.nz + cz, qx, qy, qz, k, 0, hd, hi);
        for (let s = 1; ; s++) {
            size = this.visitShell(cx, cy, cz, s, qx, qy, qz, k, size, hd, hi);
            const bound = this.unvisitedBound(cx, cy, cz, s, qx, qy, qz);
            if (bound < 0 || (size === k && hd[k - 1] < bound * bound)) return size;
        }
    }

    /** The least distance along one axis from the query to a point outside the block of radius s; -1 if the block covers the grid. */
    unvisitedBound(cx, cy, cz, s, qx, qy, qz) {
        const S = this.side;
        let bound = Infinity;
        if (cx - s > 0) bound = Math.min(bound, qx - (cx - s) * S + 1);
        if (cx + s < this.nx - 1) bound = Math.min(bound, (cx + s + 1) * S - qx);
        if (cy - s > 0) bound = Math.min(bound, qy - (cy - s) * S + 1);
        if (cy + s < this.ny - 1) bound = Math.min(bound, (cy + s + 1) * S - qy);
        if (cz - s > 0) bound = Math.min(bound, qz - (cz - s) * S + 1);
        if (cz + s < this.nz - 1) bound = Math.min(bound, (cz + s + 1) * S - qz);
        return bound === Infinity ? -1 : bound;
    }

    /** The cells at Chebyshev distance s from (cx, cy, cz), clipped to the grid; a cell wholly farther than the k-th is skipped. */
    visitShell(cx, cy, cz, s, qx, qy, qz, k, size, hd, hi) {
        const ny = this.ny, nz = this.nz;
        const x0 = Math.max(0, cx - s), x1 = Math.min(this.nx - 1, cx + s);
        const y0 = Math.max(0, cy - s), y1 = Math.min(ny - 1, cy + s);
        const z0 = Math.max(0, cz - s), z1 = Math.min(nz - 1, cz + s);
        for (let X = x0; X <= x1; X++) {
            const fx = X === cx - s || X === cx + s, ex = this.gap(X, cx, qx);
            for (let Y = y0; Y <= y1; Y++) {
                const row = (X * ny + Y) * nz, exy = ex + this.gap(Y, cy, qy);
                if (size === k && exy > hd[k - 1]) continue;
                if (fx || Y === cy - s || Y === cy + s) {
                    for (let Z = z0; Z <= z1; Z++) size = this.visitNear(row, Z, cz, qx, qy, qz, exy, k, size, hd, hi);
                } else {
                    if (cz - s >= 0) size = this.visitNear(row, cz - s, cz, qx, qy, qz, exy, k, size, hd, hi);
                    if (cz + s < nz) size = this.visitNear(row, cz + s, cz, qx, qy, qz, exy, k, size, hd, hi);
                }
            }
        }
        return size;
    }

    /** The squared distance along one axis from the query (cell c, offset q) to cell C. */
    gap(C, c, q) {
        const d = C < c ? q - (C + 1) * this.side + 1 : C > c ? C * this.side - q : 0;
        return d * d;
    }

    visitNear(row, Z, cz, qx, qy, qz, exy, k, size, hd, hi) {
        if (size === k && exy + this.gap(Z, cz, qz) > hd[k - 1]) return size;
        return this.visitCell(row + Z, qx, qy, qz, k, size, hd, hi);
    }

    visitCell(c, qx, qy, qz, k, size, hd, hi) {
        const px = this.px, py = this.py, pz = this.pz, id = this.id;
        for (let p = this.start[c], e = this.start[c + 1]; p < e; p++) {
            const dx = px[p] - qx, dy = py[p] - qy, dz = pz[p] - qz;
            size = offer(dx * dx + dy * dy + dz * dz, id[p], size, k, hd, hi);
        }
        return size;
    }
}

/** Insert (d, id) into the ascending list hd/hi of at most k entries; returns its new size. */
function offer(d, id, size, k, hd, hi) {
    if (size === k) {
        const ld = hd[k - 1];
        if (d > ld || (d === ld && id > hi[k - 1])) return size;
    } else size++;
    let j = size - 1;
    while (j > 0 && (hd[j - 1] > d || (hd[j - 1] === d && hi[j - 1] > id))) { hd[j] = hd[j - 1]; hi[j] = hi[j - 1]; j--; }
    hd[j] = d; hi[j] = id;
    return size;
}

/** Exact search for wide tiles (BigInt distances; brute force over the data points). */
export function nearestExact(px, py, pz, ids, qx, qy, qz, k, out, base) {
    const n = ids.length;
    const cand = [];
    const bx = BigInt(qx), by = BigInt(qy), bz = BigInt(qz);
    for (let i = 0; i < n; i++) {
        const dx = BigInt(px[i]) - bx, dy = BigInt(py[i]) - by, dz = BigInt(pz[i]) - bz;
        cand.push([dx * dx + dy * dy + dz * dz, ids[i]]);
    }
    cand.sort((a, b) => (a[0] < b[0] ? -1 : a[0] > b[0] ? 1 : a[1] - b[1]));
    const m = Math.min(k, n);
    for (let i = 0; i < m; i++) out[base + i] = cand[i][1];
    return m;
}
