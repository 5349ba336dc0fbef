// The canonical k nearest neighbours of spec clause 11.7.2 (Annex H.3 with a ball holding the
// whole tile): for each query, the first k data points in increasing order of (d2, index), d2
// the exact squared Euclidean distance of integer coordinates. A k-d tree finds them; pruning
// keeps every subtree whose plane distance is <= the current k-th distance, so points at equal
// distance compete by index exactly. Distances are exact doubles when 3 E^2 < 2^53 (E the
// coordinates' extent); wider tiles take an exact BigInt search.
const LEAF = 8;
export const EXACT_EXTENT = Math.floor(Math.sqrt((2 ** 53 - 1) / 3));

/** Build a k-d tree over points (x, y, z arrays) with ids (their row indices). */
export function buildTree(x, y, z, ids) {
    const n = ids.length;
    const t = { n, x: Float64Array.from(x), y: Float64Array.from(y), z: Float64Array.from(z), id: Int32Array.from(ids), axis: new Uint8Array(n) };
    const stack = [0, n];
    while (stack.length) {
        const hi = stack.pop(), lo = stack.pop();
        if (hi - lo <= LEAF) continue;
        const a = widestAxis(t, lo, hi);
        const mid = (lo + hi) >>> 1;
        select(t, a, lo, hi - 1, mid);
        t.axis[mid] = a;
        stack.push(lo, mid, mid + 1, hi);
    }
    return t;
}

function coordArray(t, a) { return a === 0 ? t.x : a === 1 ? t.y : t.z; }

function widestAxis(t, lo, hi) {
    let best = 0, bestSpread = -1;
    for (let a = 0; a < 3; a++) {
        const c = coordArray(t, a);
        let mn = Infinity, mx = -Infinity;
        for (let i = lo; i < hi; i++) { const v = c[i]; if (v < mn) mn = v; if (v > mx) mx = v; }
        if (mx - mn > bestSpread) { bestSpread = mx - mn; best = a; }
    }
    return best;
}

function swap(t, i, j) {
    let v = t.x[i]; t.x[i] = t.x[j]; t.x[j] = v;
    v = t.y[i]; t.y[i] = t.y[j]; t.y[j] = v;
    v = t.z[i]; t.z[i] = t.z[j]; t.z[j] = v;
    v = t.id[i]; t.id[i] = t.id[j]; t.id[j] = v;
}

// nth_element on axis a over [left, right] (inclusive): c[k] is the k-th smallest, left of it <=, right of it >=
function select(t, a, left, right, k) {
    const c = coordArray(t, a);
    while (right > left) {
        const pivot = c[(left + right) >>> 1];
        let i = left, j = right;
        while (i <= j) {
            while (c[i] < pivot) i++;
            while (c[j] > pivot) j--;
            if (i <= j) { swap(t, i, j); i++; j--; }
        }
        if (k <= j) right = j;
        else if (k >= i) left = i;
        else return;
    }
}

/**
 * The k nearest data points of the query (qx, qy, qz): writes their ids to out[base ..] in order
 * (nearest first, ties by id) and returns their count min(k, n). heapD/heapI: scratch of size k; stack: Float64Array of 5 * 256.
 */
export function nearest(t, qx, qy, qz, k, out, base, heapD, heapI, stack) {
    let size = 0;
    const X = t.x, Y = t.y, Z = t.z, ID = t.id, AX = t.axis;
    // a stack entry: lo, hi and the squared distances from the query to the subtree's cell along each axis
    let sp = 0;
    stack[sp++] = 0; stack[sp++] = t.n; stack[sp++] = 0; stack[sp++] = 0; stack[sp++] = 0;
    while (sp) {
        sp -= 5;
        const lo = stack[sp], hi = stack[sp + 1], ox = stack[sp + 2], oy = stack[sp + 3], oz = stack[sp + 4];
        if (size === k && ox + oy + oz > heapD[0]) continue;
        if (hi - lo <= LEAF) {
            for (let i = lo; i < hi; i++) size = offer(X[i] - qx, Y[i] - qy, Z[i] - qz, ID[i], size, k, heapD, heapI);
            continue;
        }
        const mid = (lo + hi) >>> 1, a = AX[mid];
        const dx = X[mid] - qx, dy = Y[mid] - qy, dz = Z[mid] - qz;
        size = offer(dx, dy, dz, ID[mid], size, k, heapD, heapI);
        const d = a === 0 ? dx : a === 1 ? dy : dz; // split - query: the far child is at least |d| away along a
        const pd = d * d;
        // far child first (popped last), with axis a's distance replaced by pd; then the near child
        if (d > 0) { stack[sp] = mid + 1; stack[sp + 1] = hi; } else { stack[sp] = lo; stack[sp + 1] = mid; }
        stack[sp + 2] = a === 0 ? pd : ox; stack[sp + 3] = a === 1 ? pd : oy; stack[sp + 4] = a === 2 ? pd : oz;
        sp += 5;
        if (d > 0) { stack[sp] = lo; stack[sp + 1] = mid; } else { stack[sp] = mid + 1; stack[sp + 1] = hi; }
        stack[sp + 2] = ox; stack[sp + 3] = oy; stack[sp + 4] = oz;
        sp += 5;
    }
    // heap -> sorted ascending by (d, id)
    for (let m = size - 1; m >= 0; m--) {
        out[base + m] = heapI[0];
        const ld = heapD[m], li = heapI[m];
        heapD[0] = ld; heapI[0] = li;
        siftDown(heapD, heapI, 0, m);
    }
    return size;
}

function offer(dx, dy, dz, id, size, k, hd, hi) {
    const d = dx * dx + dy * dy + dz * dz;
    if (size < k) { // sift up
        let i = size++;
        while (i > 0) {
            const p = (i - 1) >> 1;
            if (hd[p] > d || (hd[p] === d && hi[p] > id)) break;
            hd[i] = hd[p]; hi[i] = hi[p]; i = p;
        }
        hd[i] = d; hi[i] = id;
        return size;
    }
    if (d > hd[0] || (d === hd[0] && id > hi[0])) return size;
    hd[0] = d; hi[0] = id;
    siftDown(hd, hi, 0, size);
    return size;
}

function siftDown(hd, hi, i, size) {
    const d = hd[i], id = hi[i];
    for (;;) {
        let c = 2 * i + 1;
        if (c >= size) break;
        if (c + 1 < size && (hd[c + 1] > hd[c] || (hd[c + 1] === hd[c] && hi[c + 1] > hi[c]))) c++;
        if (hd[c] < d || (hd[c] === d && hi[c] < id)) break;
        hd[i] = hd[c]; hi[i] = hi[c]; i = c;
    }
    hd[i] = d; hi[i] = id;
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
