// The decoding process of spec clause 13 for the explicit-Gaussian profile (see README.md):
// container, parameter set, neighbour prediction, step adjustment (its indices as symbols or flags), SH degree and rotation length units, tile index, then
// every tile (geometry, attributes, hash check).
import { decodeTileAttributes } from './attributes.mjs';
import { parseContainer, unitStructure, UNIT } from './container.mjs';
import { BitstreamError, HashMismatchError, ResourceLimitError, UnsupportedStreamError } from './errors.mjs';
import { decodeGeometry } from './geometry.mjs';
import { Sha256, sha256, toHex } from './sha256.mjs';
import { scaleTables } from './tables.mjs';
import { alloc, copyIn, wasm } from './wasm.mjs';
import {
    parseAttributeHeader, parseGaussianParameterSet, parseHashUnit, parseNeighbourPrediction, parseRotationLength, parseShDegree, parseShTransform, parseStepAdjust, parseStepAdjustFlags, parseTileIndex,
} from './units.mjs';

export { BitstreamError, HashMismatchError, ResourceLimitError, UnsupportedStreamError };
export const DEFAULT_MAX_MEMORY = 2 ** 31; // bytes a decode may hold (decodeStream's maxMemory)

/**
 * Parse everything before the tiles (clause 13.1 steps 1 to 5). Returns the stream's context:
 * {ps, np, stepAdjust, stepFlags, shDegreeUnit, rotationLength, tiles: [{units, points, cell}], M, steps, payloads}.
 * verifiedEnd: the units ending at or before this byte passed their CRC-32 check already (progressive.mjs).
 */
export function parseStream(bytes, { maxMemory = DEFAULT_MAX_MEMORY, verifiedEnd = 0 } = {}) {
    scaleTables(); // digest of clause 10.2.2 checked before anything is decoded
    const container = parseContainer(bytes, { verifiedEnd });
    const s = unitStructure(container.units);
    const ps = parseGaussianParameterSet(s.ps.payload);
    if (s.np && ps.hierarchyEnabled) throw new BitstreamError('a neighbour_prediction unit in a stream with the hierarchy (clause 7.3.12, E60)', 'E60');
    if (s.cm && !ps.hierarchyEnabled) throw new BitstreamError('a context_model unit with hierarchy_enabled_flag = 0 (clause 8.3, E16)', 'E16');
    if (ps.hierarchyEnabled) throw new UnsupportedStreamError('hierarchy_enabled_flag = 1: the two-level hierarchy is outside the explicit-Gaussian profile this decoder implements');
    const payload = (u) => u?.payload ?? null;
    const ctx = preludeContext(ps, { ps: s.ps.payload, np: payload(s.np), sa: payload(s.sa), sf: payload(s.sf), sd: payload(s.sd), rl: payload(s.rl), st: payload(s.st) });
    ctx.tiles = tileList(container.units, s, ps);
    checkMemory(ctx, bytes.length, maxMemory);
    return ctx;
}

/**
 * The stream's context (clause 13.1 step 4) from the prelude's payloads {ps, np, sa, sf, sd, rl} (parameter
 * set, neighbour_prediction, step_adjust, step_adjust_flags, sh_degree, rotation_length and sh_transform units; null when absent), ps parsed. The
 * payloads stay in it: a worker decoding tiles in parallel parses them itself.
 */
export function preludeContext(ps, payloads) {
    // parsed in stream order (the first faulty unit names the error)
    const np = payloads.np ? parseNeighbourPrediction(payloads.np, ps.M) : null;
    const stepAdjust = payloads.sa ? parseStepAdjust(payloads.sa) : null;
    // a step_adjust_flags unit comes only right after a step_adjust unit (container.mjs, clause 6.3)
    const stepFlags = payloads.sf ? parseStepAdjustFlags(payloads.sf, stepAdjust.maxStepAdjust) : null;
    return {
        ps, M: ps.M, steps: ps.steps, payloads, np, stepAdjust, stepFlags,
        shDegreeUnit: payloads.sd ? parseShDegree(payloads.sd, ps.shDegree) : null,
        rotationLength: payloads.rl ? parseRotationLength(payloads.rl) : null,
        shTransform: payloads.st ? parseShTransform(payloads.st, ps.shDegree) : null,
    };
}

function tileList(units, s, ps) {
    if (!!s.ti !== !!ps.tilesEnabled) {
        throw new BitstreamError(`tiles_enabled_flag = ${ps.tilesEnabled} ${s.ti ? 'with' : 'without'} a tile_index unit (clause 7.3.11, E54)`, 'E54');
    }
    if (!s.ti) {
        if (s.tiles.length !== 1) throw new BitstreamError(`${s.tiles.length} tiles without a tile_index unit (E54)`, 'E54');
        return [{ units: s.tiles[0].units, points: ps.numGaussians, cell: null }];
    }
    const index = parseTileIndex(s.ti.payload, ps.numGaussians);
    if (index.length !== s.tiles.length) throw new BitstreamError(`the tile index lists ${index.length} tiles, the stream holds ${s.tiles.length} (clause 7.3.11, E55)`, 'E55');
    let pos = s.ti.end;
    index.forEach((t, i) => {
        const tile = s.tiles[i];
        if (tile.start !== pos || tile.end !== pos + t.size) {
            throw new BitstreamError(`tile ${i} does not start at byte ${pos} and take tile_data_size = ${t.size} bytes (clause 7.3.11, E55)`, 'E55');
        }
        pos += t.size;
    });
    if (units.some((u) => u.type >= 0x80 && u.start >= s.ti.end && u.start < pos)) {
        throw new BitstreamError('an ancillary unit between the tile index and the end of the last tile (clause 7.3.11, E55)', 'E55');
    }
    return index.map((t, i) => ({ units: s.tiles[i].units, points: t.points, cell: t.cell }));
}

// the WebAssembly memory one tile may use: the module's sizes are 32-bit (wasm.mjs, wasm/decoder.ts)
export const WASM_TILE_MEMORY = 2 ** 31 - 2 ** 24;

/**
 * Refuse before allocating a stream whose declared sizes need more than maxMemory, or a tile that
 * needs more than the module can address (ResourceLimitError).
 */
export function checkMemory(ctx, streamBytes, maxMemory) {
    const N = ctx.ps.numGaussians, M = ctx.M;
    const largest = Math.max(...ctx.tiles.map((t) => t.points));
    const k = ctx.np ? ctx.np.k : 0;
    // output: coordinates (int32) and values (binary32); per tile (in the module): q (int64), values, geometry and k-NN working sets
    const tile = largest * (8 * M + 4 * M + 160 + 4 * k + 64);
    const need = streamBytes + N * (12 + 4 * M) + tile;
    const mib = (b) => Math.ceil(b / 2 ** 20);
    if (need > maxMemory) {
        throw new ResourceLimitError(`decoding needs about ${mib(need)} MiB (N = ${N}, M = ${M}, largest tile ${largest} points), more than the bound of ${Math.floor(maxMemory / 2 ** 20)} MiB`);
    }
    if (tile > WASM_TILE_MEMORY) {
        throw new ResourceLimitError(`a tile of ${largest} points (M = ${M}) needs about ${mib(tile)} MiB of WebAssembly memory, more than the ${mib(WASM_TILE_MEMORY)} MiB the decoder's module addresses per tile`);
    }
}

/**
 * Decode tile t of the stream context (clause 13.2). Returns {x, y, z, values, n}. digest (default: checkHash):
 * the tile's clause-12 serialization is made and handed to the hash while its values are still in the module
 * (no copy of them back in), for checkTileHash, which also serializes the tile itself where this was not asked;
 * arrays: the renderer's arrays likewise, for tileSceneArrays.
 */
export async function decodeTile(ctx, t, { checkHash = true, digest = checkHash, arrays = false } = {}) {
    const tile = ctx.tiles[t];
    const [G, ...rest] = tile.units;
    const H = rest.pop();
    const A = rest;
    const n = tile.points;
    const coords = decodeGeometry(G.payload, n);
    if (tile.cell) checkCell(coords, tile.cell, ctx.ps.tileSize, t);
    if (A.length !== 1) throw new BitstreamError(`tile ${t} has ${A.length} attribute units; without the hierarchy it has 1 (clause 6.3, ${ctx.np ? 'E63' : 'E15'})`, ctx.np ? 'E63' : 'E15');
    const sceneHash = parseHashUnit(H.payload);
    const h = parseAttributeHeader(A[0].payload, ctx);
    if (h.numRows !== n) throw new BitstreamError(`attribute unit of tile ${t}: num_rows_minus1 + 1 = ${h.numRows}, the tile has ${n} points (clause 8.3, E59)`, 'E59');
    let hashed = null, made = null;
    const values = decodeTileAttributes(A[0].payload, h, coords, ctx, digest || arrays ? (w, pv, scratch, room) => {
        // in the attribute decode's free scratch where they fit (the memory bound of checkMemory holds), one after the other
        const pc = [coords.x, coords.y, coords.z].map((a) => copyIn(w, a)), M = ctx.ps.M;
        const place = (bytes) => (bytes <= room ? scratch : alloc(w, bytes, false));
        if (arrays) {
            const v = rendererViews(ctx.ps, w, pc, pv, n, place(4 * n * (3 + M)));
            made = { ...v };
            for (const [name] of RENDERER_PARTS(0)) made[name] = v[name].slice();
        }
        if (!digest) return;
        hashed = sha256(serialization(ctx.ps, w, pc, pv, n, place(3 + HEAD + n * (24 + 4 * M))));
        hashed.catch(() => {}); // awaited by checkTileHash
    } : null);
    const out = { x: coords.x, y: coords.y, z: coords.z, values, n, sceneHash: toHex(sceneHash) };
    if (hashed) digests.set(out, hashed);
    if (made) madeArrays.set(out, made);
    if (checkHash) await checkTileHash(ctx, t, out);
    return out;
}

// decodeTile's digests of its results, started while the values were in the module (checkTileHash takes them),
// and their renderer arrays where asked (tileSceneArrays takes them)
const digests = new WeakMap(), madeArrays = new WeakMap();

/**
 * Clause 12's check of a decoded tile (decodeTile's result) against its scene_hash; rejects with
 * HashMismatchError. The serialization is made and handed to the hash at the call (Web Crypto copies
 * the bytes and hashes them off this thread), so the caller may go on before awaiting it.
 */
export async function checkTileHash(ctx, t, out) {
    const started = digests.get(out);
    digests.delete(out);
    const digest = await (started || sha256(serializeTile(ctx.ps, out)));
    if (toHex(digest) !== out.sceneHash) throw new HashMismatchError(`tile ${t}: the decoded scene does not match its scene_hash (clause 12, E53)`, 'E53');
}

// E58 from the points' per-axis bounds (decodeGeometry's min and max)
function checkCell(coords, cell, T, t) {
    for (let a = 0; a < 3; a++) {
        const lo = cell[a] * T, hi = lo + T - 1;
        if (coords.min[a] < lo || coords.max[a] > hi) throw new BitstreamError(`tile ${t}: a decoded point lies outside the tile's cell (clause 7.3.11, E58)`, 'E58');
    }
}

const HEAD = 17 + 16 + 16; // clause 12's header: tag, N and sh_degree (int64), voxel size and origin (float32)

/** The header of clause 12's serialization of a scene of N points. */
function serialHeader(ps, N) {
    const hb = new Uint8Array(HEAD), dv = new DataView(hb.buffer);
    hb.set(new TextEncoder().encode('LGHC-gaussians-v1'));
    dv.setBigInt64(17, BigInt(N), true);
    dv.setBigInt64(25, BigInt(ps.shDegree), true);
    dv.setFloat32(33, ps.voxelSize, true);
    for (let i = 0; i < 3; i++) dv.setFloat32(37 + 4 * i, ps.origin[i], true);
    return hb;
}

/**
 * Clause 12's serialization of one tile's points as a scene, made by the module (serializeTile):
 * a view of the module's memory, valid until the next call into it (hash it at once). With
 * `parts`, the body's parts [coordinates, SH, opacity, scales, rotations] as copies instead.
 */
function serializeTile(ps, t, parts = false) {
    const w = wasm(), M = ps.M, S3 = 3 * ps.S, n = t.n;
    w.reset();
    const pc = [t.x, t.y, t.z].map((a) => copyIn(w, a)), pv = copyIn(w, t.values);
    if (!parts) return serialization(ps, w, pc, pv, n, alloc(w, 3 + HEAD + n * (24 + 4 * M), false));
    const out = alloc(w, n * (24 + 4 * M), false);
    w.serializeTile(...pc, pv, n, M, S3, out);
    const ends = [24, 4 * S3, 4, 12, 4 * (M - S3 - 4)];
    let at = out;
    return ends.map((size) => { at += size * n; return new Uint8Array(w.memory.buffer, at - size * n, size * n).slice(); });
}

/**
 * Clause 12's serialization of a tile's n points, coordinates at pc ([x, y, z] addresses, int32) and values at pv
 * in the module's memory, made at out (3 + 49 + n (24 + 4 M) bytes): a view of it, valid until the next call into
 * the module.
 */
function serialization(ps, w, pc, pv, n, out) {
    const M = ps.M, lead = 3 + HEAD, body = n * (24 + 4 * M); // 3 bytes before the header align the body to 4
    w.serializeTile(...pc, pv, n, M, 3 * ps.S, out + lead); // the module writes the body, the header is set below
    const bytes = new Uint8Array(w.memory.buffer, out + 3, HEAD + body);
    bytes.set(serialHeader(ps, n));
    return bytes;
}

/** Hex SHA-256 of the clause-12 serialization of the tiles' points: the header, then each part of the body over the tiles in order. */
export function sceneDigestHex(ps, tiles) {
    const h = new Sha256();
    h.update(serialHeader(ps, tiles.reduce((a, t) => a + t.n, 0)));
    const parts = tiles.map((t) => serializeTile(ps, t, true));
    for (let j = 0; j < 5; j++) for (const p of parts) h.update(p[j]);
    return toHex(h.digest());
}

/** Tiles a box selects (clause 13.3): box = [x0, y0, z0, x1, y1, z1] in world coordinates. */
export function tilesInBox(ctx, box) {
    const ps = ctx.ps;
    return ctx.tiles.map((t, i) => i).filter((i) => {
        const cell = ctx.tiles[i].cell;
        if (!cell) return true;
        for (let a = 0; a < 3; a++) {
            const lo = cell[a] * ps.tileSize * ps.voxelSize + ps.origin[a];
            const hi = (cell[a] + 1) * ps.tileSize * ps.voxelSize + ps.origin[a];
            if (lo > box[a + 3] || hi < box[a]) return false;
        }
        return true;
    });
}

/**
 * Decode a whole stream (or the tiles a box selects). Returns {ps, tiles: [{x, y, z, values, n}]}.
 * onTile(t, tileResult) is called after each tile is decoded and hash-checked.
 */
export async function decodeStream(bytes, { box = null, maxMemory = DEFAULT_MAX_MEMORY, onTile = null } = {}) {
    const ctx = parseStream(bytes, { maxMemory });
    const selected = box ? tilesInBox(ctx, box) : ctx.tiles.map((_, i) => i);
    const tiles = [];
    // Tile t's hash runs (Web Crypto, off this thread) while tile t + 1 decodes; its result is awaited
    // before t + 1's is kept, and before t + 1's own error is thrown, so the first faulty tile names the error.
    let prev = null;
    const settle = async () => {
        await prev.hashed;
        tiles.push(prev.r);
        if (onTile) onTile(prev.t, prev.r, ctx);
    };
    for (const t of selected) {
        let r;
        try {
            r = await decodeTile(ctx, t, { checkHash: false, digest: true });
        } catch (e) {
            if (prev) await prev.hashed;
            throw e;
        }
        const hashed = checkTileHash(ctx, t, r); // the digest was started by decodeTile (Web Crypto: off this thread)
        hashed.catch(() => {}); // awaited by settle
        if (prev) await settle();
        prev = { t, r, hashed };
    }
    if (prev) await settle();
    return { ps: ctx.ps, ctx, tiles };
}

/**
 * The decoded scene as renderer arrays (no PLY): positions (world, float32), SH, opacity, log scales,
 * rotations; each tile's made by the module (rendererArrays: a per-point loop in JS was 40-140 ms of
 * CPU for a 590k-Gaussian scene, cold in every worker that decodes once). views: one tile's arrays as views of
 * the module's memory, valid until the next call into it (a caller that copies them at once makes no garbage: a
 * 172k-point SH-3 tile's arrays are 40 MB).
 */
export function sceneArrays(ps, tiles, { views = false } = {}) {
    if (views && tiles.length === 1) return tileArrayViews(ps, tiles[0]);
    const N = tiles.reduce((a, t) => a + t.n, 0), S3 = 3 * ps.S;
    const out = {
        count: N, shDegree: ps.shDegree, positions: new Float32Array(3 * N), sh: new Float32Array(S3 * N),
        opacities: new Float32Array(N), scales: new Float32Array(3 * N), rotations: new Float32Array(4 * N),
    };
    let o = 0;
    for (const t of tiles) {
        const v = tileArrayViews(ps, t);
        for (const [name, width] of RENDERER_PARTS(S3)) out[name].set(v[name], width * o);
        o += t.n;
    }
    return out;
}

// the renderer arrays' parts in the order the module writes them (rendererArrays), with their widths
const RENDERER_PARTS = (S3) => [['positions', 3], ['sh', S3], ['opacities', 1], ['scales', 3], ['rotations', 4]];

// sceneArrays of one tile as views of the module's memory
function tileArrayViews(ps, t) {
    const w = wasm();
    w.reset();
    const pc = [t.x, t.y, t.z].map((c) => copyIn(w, c)), pv = copyIn(w, t.values);
    return rendererViews(ps, w, pc, pv, t.n, alloc(w, 4 * t.n * (3 + ps.M), false));
}

/**
 * sceneArrays of one tile's n points, coordinates at pc ([x, y, z] addresses, int32) and values at pv in the
 * module's memory, made by the module (rendererArrays) at pa (4 n (3 + M) bytes): views of its memory, valid
 * until the next call into it.
 */
function rendererViews(ps, w, pc, pv, n, pa) {
    w.rendererArrays(...pc, pv, n, ps.M, 3 * ps.S, Math.fround(ps.voxelSize), ps.origin[0], ps.origin[1], ps.origin[2], pa);
    const out = { count: n, shDegree: ps.shDegree };
    let at = pa;
    for (const [name, width] of RENDERER_PARTS(3 * ps.S)) {
        out[name] = new Float32Array(w.memory.buffer, at, width * n);
        at += 4 * width * n;
    }
    return out;
}

/**
 * sceneArrays(ps, [tile]) of a tile decodeTile decoded with `arrays` (made while its values were in the module),
 * else made now.
 */
export function tileSceneArrays(ps, tile) {
    const made = madeArrays.get(tile);
    if (!made) return sceneArrays(ps, [tile]);
    madeArrays.delete(tile);
    return made;
}
