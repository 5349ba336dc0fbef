// Streaming by tiles (README.md "stream()"): a .lghcc file read from a URL with HTTP Range requests.
// The header, the prelude units and the tile index come first (one request, more only when the
// prelude is longer); the index gives every tile's byte range (clause 7.3.11), so the reader chooses
// the tiles a box or a camera frustum meets, orders them nearest the camera first and fetches them,
// byte-adjacent tiles in one request. Each tile is decoded (the pool's helpers) as soon as its bytes
// are in and handed to onTile; the scene is assembled in stream order, as a partial decode of the
// same tiles (clause 13.3) gives it. A server that ignores Range (200) is read whole, tiles decoded
// as they arrive (decode.mjs's path), with a note.
import { checkOptions, decodeChunks, PoolSide, SceneAssembly, settle } from './decode.mjs';
import { checkMemory, decodeTile, DEFAULT_MAX_MEMORY, tilesInBox } from './decoder.mjs';
import { unitCrc32 } from './crc32.mjs';
import { isCritical, LAST_KNOWN_CRITICAL, orderError, parseHeader, preludeStructure, UNIT } from './container.mjs';
import { BitstreamError, UnsupportedStreamError } from './errors.mjs';
import { preludeFromUnits, scanUnits } from './progressive.mjs';
import { parseGaussianParameterSet } from './units.mjs';
import { loadWasm } from './wasm.mjs';

/** Bytes of the first request: the header, the prelude units and the tile index of a stream of a few hundred tiles (a longer prelude takes more requests, each doubling what is in hand). */
export const HEAD_BYTES = 1 << 13;

/**
 * Stream the .lghcc file at url by tiles (README.md): threads as decodeWith's. Resolves to the scene
 * of the fetched tiles in stream order (decode()'s LghccScene) with {ranged, requests, bytesFetched,
 * bytesTotal}; onTile(tile) gets each tile's arrays as it is decoded.
 */
export async function streamWith(threads, url, options = {}) {
    const o = streamOptions(threads, url, options);
    if (o.signal) o.signal.throwIfAborted();
    // every request is cancelled at the end, or at the first error (a request of the other connection stops too)
    const requests = new AbortController();
    const stop = () => requests.abort(o.signal.reason);
    if (o.signal) o.signal.addEventListener('abort', stop, { once: true });
    const net = new Fetcher(url, o, requests.signal);
    // the helpers start while the first request is under way (their start is most of a first tile's wait)
    const pool = o.workers >= 1 ? new PoolSide(o.workers, threads.startHelper) : null;
    if (pool) pool.warm().catch(() => {});
    try {
        const first = await net.range(0, o.headBytes);
        if (first.status === 200) return await wholeFile(threads, net, first, o, pool);
        const head = await headAndPrelude(net, first);
        if (!head.ctx.ps.tilesEnabled) return await wholeFile(threads, net, first, o, pool, head); // one tile: the rest of the file
        return await rangedTiles(net, head, o, pool);
    } finally {
        if (pool) pool.close();
        if (o.signal) o.signal.removeEventListener('abort', stop);
        requests.abort();
    }
}

function streamOptions(threads, url, options) {
    if (!(typeof url === 'string' || url instanceof URL)) throw new TypeError('stream: url is a string or a URL (a file to fetch with Range requests)');
    const {
        workers = threads.defaultWorkers(), onProgress = null, onTile = null, onNote = null, signal = null, box = null,
        frustum = null, camera = null, maxMemory = DEFAULT_MAX_MEMORY, activated = false, headers = {}, credentials = 'same-origin', headBytes = HEAD_BYTES, connections = 2,
    } = options;
    checkOptions({ workers, onProgress, signal, box, maxMemory });
    if (onTile !== null && typeof onTile !== 'function') throw new TypeError('onTile: a function');
    if (onNote !== null && typeof onNote !== 'function') throw new TypeError('onNote: a function');
    if (camera !== null && typeof camera !== 'function') checkCamera(camera);
    if (frustum !== null && typeof frustum !== 'function') checkFrustum(frustum);
    if (!(Number.isInteger(headBytes) && headBytes >= 64)) throw new TypeError(`headBytes: a whole number of bytes >= 64, got ${headBytes}`);
    if (!(Number.isInteger(connections) && connections >= 1)) throw new TypeError(`connections: a whole number of requests in flight >= 1, got ${connections}`);
    if (headers === null || typeof headers !== 'object') throw new TypeError('headers: an object of request headers');
    return { workers, onProgress, onTile, onNote, signal, box, frustum, camera, maxMemory, activated, headers, credentials, headBytes, connections };
}

function checkCamera(camera) {
    if (!(Array.isArray(camera) && camera.length === 3 && camera.every(Number.isFinite))) {
        throw new TypeError('camera: [x, y, z], three finite numbers: the camera position in the stream\'s world coordinates (or a function of the index giving them)');
    }
}

function checkFrustum(frustum) {
    if (!(Array.isArray(frustum) && frustum.every((p) => Array.isArray(p) && p.length === 4 && p.every(Number.isFinite)))) {
        throw new TypeError('frustum: planes [a, b, c, d], each four finite numbers, inside where a·x + b·y + c·z + d >= 0 (or a function of the index giving them)');
    }
}

/**
 * What a stream's camera and frustum options say once its prelude (ctx) is known: a function is called
 * with the index, {tiles, count, shDegree, bounds: the box of every tile's cell (world coordinates;
 * null for an untiled stream)}, so that an application can frame the scene before the tiles are
 * chosen. Evaluated once per stream; returns {camera, frustum}.
 */
function view(ctx, o) {
    if (!o.view) {
        const index = streamIndex(ctx);
        const camera = (typeof o.camera === 'function' ? o.camera(index) : o.camera) ?? null;
        const frustum = (typeof o.frustum === 'function' ? o.frustum(index) : o.frustum) ?? null;
        if (camera !== null) checkCamera(camera);
        if (frustum !== null) checkFrustum(frustum);
        o.view = { camera, frustum };
    }
    return o.view;
}

/** The stream's index as view() hands it out. */
export function streamIndex(ctx) {
    let bounds = null;
    for (let t = 0; t < ctx.tiles.length; t++) {
        const b = cellBox(ctx, t);
        if (!b) break;
        if (!bounds) bounds = { min: b.slice(0, 3), max: b.slice(3) };
        for (let a = 0; a < 3; a++) { bounds.min[a] = Math.min(bounds.min[a], b[a]); bounds.max[a] = Math.max(bounds.max[a], b[a + 3]); }
    }
    return { tiles: ctx.tiles.length, count: ctx.ps.numGaussians, shDegree: ctx.ps.shDegree, bounds };
}

/** The tiles a stream fetches (ctx: its prelude): those the box and the frustum both meet, in stream order. */
export function selectTiles(ctx, o) {
    const { frustum } = view(ctx, o);
    let tiles = o.box ? tilesInBox(ctx, o.box) : ctx.tiles.map((_, t) => t);
    if (frustum) tiles = tiles.filter((t) => cellInFrustum(cellBox(ctx, t), frustum));
    return tiles;
}

/**
 * The six planes of a view frustum, [a, b, c, d] with inside a·x + b·y + c·z + d >= 0, from a 4x4
 * view-projection matrix in column-major order (WebGL clip space, z in [-w, w]: three.js's
 * Matrix4.elements, PlayCanvas's Mat4.data): projection × view × the model's world matrix gives them in
 * the model's (the stream's) coordinates. The planes stream()'s frustum option takes.
 */
export function frustumPlanes(m) {
    if (!(m && m.length === 16)) throw new TypeError('frustumPlanes: a 4x4 matrix of 16 numbers in column-major order');
    const row = (r) => [m[r], m[4 + r], m[8 + r], m[12 + r]];
    const w = row(3);
    const planes = [];
    for (let r = 0; r < 3; r++) {
        const v = row(r);
        planes.push(w.map((x, k) => x + v[k]), w.map((x, k) => x - v[k]));
    }
    return planes;
}

/**
 * Tiles handed on in batches that grow, for a loader that makes one engine object per batch (each
 * costs the engine a sort or a regeneration): push() each tile stream() hands to onTile; the first
 * tile goes to onBatch(tiles) at once, the next batches `delay`, 2 `delay`, 4 `delay` ... (at most
 * `maxDelay`) milliseconds apart; flush() hands on what is queued now (at the stream's end).
 */
export class TileBatcher {
    constructor(onBatch, { delay = 250, maxDelay = 8000 } = {}) {
        if (typeof onBatch !== 'function') throw new TypeError('TileBatcher: onBatch must be a function');
        if (!(delay > 0 && maxDelay >= delay)) throw new TypeError('TileBatcher: needs 0 < delay <= maxDelay');
        this.onBatch = onBatch;
        this.minDelay = delay;
        this.maxDelay = maxDelay;
        this.pending = [];
        this.timer = null;
        this.delay = 0; // the first batch at once
    }

    push(tile) {
        this.pending.push(tile);
        if (this.timer === null) this.timer = setTimeout(() => this.flush(), this.delay);
    }

    flush() {
        if (this.timer !== null) clearTimeout(this.timer);
        this.timer = null;
        const tiles = this.pending.splice(0);
        if (!tiles.length) return;
        this.delay = Math.min(this.maxDelay, Math.max(this.minDelay, 2 * this.delay));
        this.onBatch(tiles);
    }
}

/** Tile t's cell in world coordinates, [x0, y0, z0, x1, y1, z1] (clause 13.3's lo and hi); null for an untiled stream's one tile. */
export function cellBox(ctx, t) {
    const cell = ctx.tiles[t].cell, ps = ctx.ps;
    if (!cell) return null;
    const lo = cell.map((c, a) => c * ps.tileSize * ps.voxelSize + ps.origin[a]);
    return [...lo, ...cell.map((c, a) => (c + 1) * ps.tileSize * ps.voxelSize + ps.origin[a])];
}

// whether the box b (a cell) is not wholly outside any plane: its corner farthest along the plane's normal is inside
function cellInFrustum(b, planes) {
    if (!b) return true;
    return planes.every(([a, bb, c, d]) => a * (a >= 0 ? b[3] : b[0]) + bb * (bb >= 0 ? b[4] : b[1]) + c * (c >= 0 ? b[5] : b[2]) + d >= 0);
}

/** The tiles in fetch order: nearest the camera first (distance to the cell, then to its centre), or stream order. */
export function fetchOrder(ctx, tiles, camera) {
    if (!camera) return tiles.slice();
    const key = (t) => {
        const b = cellBox(ctx, t);
        if (!b) return [0, 0];
        let near = 0, centre = 0;
        for (let a = 0; a < 3; a++) {
            const p = camera[a], gap = Math.max(b[a] - p, 0, p - b[a + 3]);
            near += gap * gap;
            centre += (p - (b[a] + b[a + 3]) / 2) ** 2;
        }
        return [near, centre];
    };
    const keys = new Map(tiles.map((t) => [t, key(t)]));
    return tiles.slice().sort((s, t) => keys.get(s)[0] - keys.get(t)[0] || keys.get(s)[1] - keys.get(t)[1] || s - t);
}

/**
 * The requests: in fetch order, each started by the first tile not yet requested and running on
 * over the tiles right after it in the stream while they are fetched too and not yet requested, at
 * most maxBytes long unless one tile is longer (a request's bytes arrive in stream order: its first
 * tile, the one that ranks first, comes first). Returns [{start, end, tiles: [t in stream order]}].
 */
export function planRequests(ctx, order, maxBytes) {
    const want = new Set(order), taken = new Set(), plan = [];
    for (const t of order) {
        if (taken.has(t)) continue;
        let hi = t;
        while (want.has(hi + 1) && !taken.has(hi + 1) && ctx.tiles[hi + 1].end - ctx.tiles[t].start <= maxBytes) hi++;
        const tiles = [];
        for (let u = t; u <= hi; u++) { tiles.push(u); taken.add(u); }
        plan.push({ start: ctx.tiles[t].start, end: ctx.tiles[hi].end, tiles });
    }
    return plan;
}

/** fetch() with the caller's headers, credentials and signal; counts requests and bytes. */
class Fetcher {
    constructor(url, o, signal) {
        this.url = url;
        this.o = o;
        this.signal = signal;
        this.total = undefined; // the file's size, as the first 206 said (null: not said)
        this.requests = 0;
        this.bytes = 0;
    }

    /** A request of bytes [start, end) (end null: to the end of the file); the Response, checked: 206 or 200. */
    async range(start, end) {
        this.requests++;
        const res = await fetch(this.url, {
            headers: { ...this.o.headers, Range: `bytes=${start}-${end === null ? '' : end - 1}` },
            credentials: this.o.credentials, signal: this.signal,
        });
        if (res.status !== 206 && !(res.status === 200 && start === 0)) {
            throw new Error(`${this.url}: HTTP ${res.status} ${res.statusText} to a request of bytes ${start} to ${end === null ? 'the end' : end - 1}`.replace(/ +/g, ' '));
        }
        if (res.status === 206) {
            const range = res.headers.get('Content-Range');
            if (range === null) throw new Error(`${this.url}: a 206 answer without a readable Content-Range header (cross-origin, the server must expose it: Access-Control-Expose-Headers: Content-Range)`);
            const m = /^bytes (\d+)-(\d+)\/(\d+|\*)$/.exec(range);
            if (!m || Number(m[1]) !== start) throw new Error(`${this.url}: the server answered a request for bytes ${start}- with Content-Range "${range}"`);
            res.total = m[3] === '*' ? null : Number(m[3]);
            if (this.total === undefined) this.total = res.total;
            else if (res.total !== this.total) throw new Error(`${this.url}: the file's size changed from ${this.total} to ${res.total} bytes while it was streamed`);
        }
        return res;
    }

    /** The response's body chunks as they arrive (counted). */
    async* chunks(res) {
        if (!res.body) return;
        const reader = res.body.getReader();
        try {
            for (;;) {
                const { value, done } = await reader.read();
                if (done) return;
                this.bytes += value.length;
                yield value;
            }
        } finally {
            reader.cancel().catch(() => {});
        }
    }

    /** The whole body of a (short) response. */
    async body(res) {
        const parts = [];
        for await (const c of this.chunks(res)) parts.push(c);
        return concat(parts);
    }
}

function concat(parts) {
    const out = new Uint8Array(parts.reduce((a, p) => a + p.length, 0));
    let at = 0;
    for (const p of parts) { out.set(p, at); at += p.length; }
    return out;
}

/**
 * The file's first bytes, fetched until the prelude is complete: {bytes, total, ctx} (ctx.tiles with
 * their byte ranges). Checks the header, the units' CRC-32 and the unit order before the tiles.
 */
async function headAndPrelude(net, first) {
    let bytes = await net.body(first);
    const total = first.total;
    for (;;) {
        if (bytes.length >= 8) parseHeader(bytes);
        const units = [];
        const scan = scanUnits(bytes, bytes.length, 8, units);
        // an untiled stream's prelude ends where its geometry unit starts: its header is enough
        if (scan < bytes.length && bytes[scan] === UNIT.GEOMETRY) units.push({ type: UNIT.GEOMETRY, start: scan, end: Infinity, partial: true });
        const ctx = bytes.length >= 8 ? prelude(bytes, units, total) : null;
        if (ctx) return { bytes, total, ctx };
        if (total !== null && bytes.length >= total) {
            if (bytes.length < 8) parseHeader(bytes); // E1
            throw new BitstreamError('the stream ends before its first tile (E13)', 'E13');
        }
        const more = await net.range(bytes.length, bytes.length * 2);
        if (more.status !== 206) throw new Error(`${net.url}: the server stopped answering Range requests`);
        bytes = concat([bytes, await net.body(more)]);
    }
}

// the prelude of the units so far, its unit order checked; null while the tile index (or an untiled stream's geometry) has not arrived
function prelude(bytes, units, total) {
    const critical = units.filter((u) => isCritical(u.type));
    const end = critical.findIndex((u) => u.type === UNIT.TILE_INDEX || u.type === UNIT.GEOMETRY);
    if (end < 0) {
        if (units.length) preludeStructure(units); // a stream that starts wrong (an anchor stream, an ancillary unit first) fails now
        return null;
    }
    const before = units.filter((u) => u.start <= critical[end].start);
    for (const u of before) {
        if (!u.partial && unitCrc32(bytes, u.start, u.end - 4) !== u.stored) throw new BitstreamError(`data unit at byte ${u.start} fails its CRC-32 check (E9)`, 'E9');
    }
    const { s, critical: crit, i } = preludeStructure(before);
    if (i < crit.length && crit[i].type !== UNIT.GEOMETRY) throw orderError(crit[i]);
    const ps = parseGaussianParameterSet(s.ps.payload);
    if (ps.hierarchyEnabled) throw new UnsupportedStreamError('hierarchy_enabled_flag = 1: the two-level hierarchy is outside the explicit-Gaussian profile this decoder implements');
    if (s.cm) throw new BitstreamError('a context_model unit with hierarchy_enabled_flag = 0 (clause 8.3, E16)', 'E16');
    if (!!s.ti !== !!ps.tilesEnabled) {
        throw new BitstreamError(`tiles_enabled_flag = ${ps.tilesEnabled} ${s.ti ? 'with' : 'without'} a tile_index unit (clause 7.3.11, E54)`, 'E54');
    }
    const ctx = preludeFromUnits(before, () => {}); // CRCs checked above
    const last = ctx.tiles[ctx.tiles.length - 1];
    if (s.ti && total !== null && last.end > total) {
        throw new BitstreamError(`the tile index puts the end of tile ${ctx.tiles.length - 1} at byte ${last.end}, beyond the ${total}-byte stream (clause 7.3.11, E55)`, 'E55');
    }
    return ctx;
}

/**
 * Tile t's units from the bytes [tile.start, tile.end) of the stream at buf[at...]: exactly its
 * critical units G A.. H, each CRC-checked (E9, E55, E14). Returns [{type, start, end, payload}].
 */
export function tileUnits(buf, at, tile, t) {
    const units = [];
    for (let p = tile.start; p < tile.end;) {
        const i = p - tile.start + at, left = tile.end - p;
        const size = left >= 9 ? ((buf[i + 1] << 24) | (buf[i + 2] << 16) | (buf[i + 3] << 8) | buf[i + 4]) >>> 0 : Infinity;
        if (size + 9 > left) throw new BitstreamError(`tile ${t}: its units do not end at the tile_data_size of the tile index (clause 7.3.11, E55)`, 'E55');
        const type = buf[i], end = i + 5 + size;
        if (!isCritical(type)) throw new BitstreamError(`an ancillary unit between the tile index and the end of the last tile (clause 7.3.11, E55)`, 'E55');
        if (type === 0) throw new BitstreamError(`data unit at byte ${p}: unit_type 0 is forbidden (E7)`, 'E7');
        if (type > LAST_KNOWN_CRITICAL) throw new UnsupportedStreamError(`critical unit type 0x${type.toString(16)} is not defined by version 1.6, the last this decoder knows (E10)`, 'E10');
        const stored = ((buf[end] << 24) | (buf[end + 1] << 16) | (buf[end + 2] << 8) | buf[end + 3]) >>> 0;
        if (unitCrc32(buf, i, end) !== stored) throw new BitstreamError(`data unit at byte ${p} (type 0x${type.toString(16)}) fails its CRC-32 check (E9)`, 'E9');
        units.push({ type, start: p, end: p + 9 + size, payload: buf.slice(i + 5, end) });
        p += 9 + size;
    }
    const types = units.map((u) => u.type);
    const bad = types.findIndex((ty, k) => ty !== (k === 0 ? UNIT.GEOMETRY : k === types.length - 1 ? UNIT.DECODED_SCENE_HASH : UNIT.ATTRIBUTE));
    if (bad >= 0 || units.length < 3) throw orderError(units[bad >= 0 ? bad : units.length - 1]);
    return units;
}

/**
 * The whole file through decode()'s progressive path (tiles decoded as they arrive, in stream order):
 * res is the answer to the first request; a 200 is the whole file (with a note), a 206 after the
 * prelude (an untiled stream) is followed by a request for the rest.
 */
async function wholeFile(threads, net, res, o, pool, head = null) {
    if (res.status === 200) {
        const note = `${net.url}: the server does not answer Range requests (HTTP 200, not 206): the whole file is fetched and its tiles decoded in stream order`;
        if (o.onNote) o.onNote(note); else console.warn(note);
    }
    async function* reading() {
        if (head) {
            yield head.bytes;
            if (head.total === null || head.bytes.length < head.total) yield* net.chunks(await net.range(head.bytes.length, null));
        } else {
            yield* net.chunks(res);
        }
    }
    const select = (ctx) => selectTiles(ctx, o); // (a camera function is called there too, with the index)
    const scene = await decodeChunks(threads, reading(), o, { select, onTile: o.onTile, pool });
    return { ...scene, ranged: res.status === 206, requests: net.requests, bytesFetched: net.bytes, bytesTotal: head ? head.total : net.bytes };
}

/** The tiled path: the chosen tiles by Range requests, nearest the camera first, each decoded as it arrives. */
async function rangedTiles(net, head, o, pool) {
    const { ctx } = head;
    const chosen = selectTiles(ctx, o);
    const order = fetchOrder(ctx, chosen, view(ctx, o).camera);
    ctx.rank = new Map(order.map((t, k) => [t, k])); // the pool hands out the nearest tile first
    checkMemory({ ...ctx, tiles: chosen.map((t) => ctx.tiles[t]) }, chosen.reduce((a, t) => a + ctx.tiles[t].end - ctx.tiles[t].start, 0), o.maxMemory);
    const scene = new SceneAssembly(null, o.activated, o.onProgress, { select: () => chosen, onTile: o.onTile });
    const run = (async () => {
        await loadWasm();
        if (pool && chosen.length) pool.start(ctx);
        const decoding = [];
        let failed = null; // the first tile that failed stops the fetching at its next chunk
        const decodeOne = (t, buf, at) => {
            if (o.signal && o.signal.aborted) throw o.signal.reason;
            if (failed) throw failed;
            ctx.tiles[t].units = tileUnits(buf, at, ctx.tiles[t], t);
            const p = (pool && pool.side ? pool.decode(ctx, t) : decodeTile(ctx, t)).then((r) => {
                ctx.tiles[t].units = null; // its payloads are the pool's, or decoded
                scene.add(t, r, { ctx, ps: ctx.ps, tiles: ctx.tiles.length });
            });
            p.catch((err) => { failed = failed || err; });
            decoding.push(p);
        };
        const inHead = (t) => ctx.tiles[t].end <= head.bytes.length;
        for (const t of order) if (inHead(t)) decodeOne(t, head.bytes, ctx.tiles[t].start);
        if (pool && pool.side) pool.flush();
        const plan = planRequests(ctx, order.filter((t) => !inHead(t)), requestBytes(ctx, chosen));
        await fetchPlan(net, plan, ctx, decodeOne, pool, o.connections, head.bytes);
        await Promise.all(decoding);
        return { ...scene.result({ ps: ctx.ps, tiles: chosen }), ranged: true, requests: net.requests, bytesFetched: net.bytes, bytesTotal: head.total };
    })();
    return settle(run, o.signal, () => { if (pool) pool.close(); });
}

// the longest request: a 32nd of the chosen tiles' bytes, at least 64 KiB (few requests, the order kept)
function requestBytes(ctx, chosen) {
    const bytes = chosen.reduce((a, t) => a + ctx.tiles[t].end - ctx.tiles[t].start, 0);
    return Math.max(1 << 16, Math.ceil(bytes / 32));
}

// the plan's requests, `connections` at a time in plan order; each tile handed to decodeOne as soon as its
// bytes are in. head: the file's first bytes, in hand (a request that starts in them asks for the rest only).
async function fetchPlan(net, plan, ctx, decodeOne, pool, connections, head) {
    let next = 0;
    const lane = async () => {
        while (next < plan.length) {
            const req = plan[next++];
            const buf = new Uint8Array(req.end - req.start);
            let len = Math.max(0, Math.min(head.length, req.end) - req.start), k = 0;
            buf.set(head.subarray(req.start, req.start + len));
            const res = await net.range(req.start + len, req.end);
            if (res.status !== 206) throw new Error(`${net.url}: the server stopped answering Range requests`);
            for await (const chunk of net.chunks(res)) {
                if (len + chunk.length > buf.length) throw new Error(`${net.url}: the server sent more than the ${buf.length} bytes asked for`);
                buf.set(chunk, len);
                len += chunk.length;
                for (; k < req.tiles.length && ctx.tiles[req.tiles[k]].end - req.start <= len; k++) {
                    decodeOne(req.tiles[k], buf, ctx.tiles[req.tiles[k]].start - req.start);
                }
                if (pool && pool.side) pool.flush();
            }
            if (len < buf.length) throw new BitstreamError(`the stream ends at byte ${req.start + len}, inside tile ${req.tiles[k]} (clause 7.3.11, E55)`, 'E55');
        }
    };
    await Promise.all(Array.from({ length: Math.min(connections, plan.length) }, lane));
}

