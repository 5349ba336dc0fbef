// Progressive decoding (spec clause 6.1): tiles are decoded, and hash-checked, as soon as their
// bytes have arrived; the scene is final only once the whole stream has passed the checks of
// clauses 6 and 13.1 (parseStream on every byte). A stream rejected then is rejected whole.
import { unitCrc32 } from './crc32.mjs';
import { decodeTile, parseStream, preludeContext, sceneArrays, tilesInBox, DEFAULT_MAX_MEMORY } from './decoder.mjs';
import { BitstreamError } from './errors.mjs';
import { parseGaussianParameterSet, parseTileIndex } from './units.mjs';
import { UNIT } from './container.mjs';
import { mark, timed } from './pool.mjs';

export class ProgressiveDecoder {
    /**
     * onTile(t, tile, info): a tile decoded and hash-checked (provisional until finish()).
     * pool: null (tiles decoded here, one after the other, in order) or a stream's side of a pool
     * (TilePool.stream(): start(ctx) once the prelude is known, decode(ctx, t) promises tile t's
     * result; tiles in parallel workers, onTile in any order). minPoolTiles: a stream of fewer tiles is
     * decoded here, without the pool (a decoding worker pays for helpers only with two tiles or more;
     * a page's main thread, which should decode nothing, gives 1). box: only the tiles it selects
     * (clause 13.3, tilesInBox) are decoded; the others are skipped as their bytes pass. select:
     * instead of a box, select(ctx) gives the numbers of the tiles to decode (stream.mjs's choice).
     */
    constructor({ onTile = null, maxMemory = DEFAULT_MAX_MEMORY, pool = null, minPoolTiles = 2, box = null, select = null } = {}) {
        this.onTile = onTile;
        this.maxMemory = maxMemory;
        this.pool = pool;
        this.minPoolTiles = minPoolTiles;
        this.box = box;
        this.select = select;
        this.pending = []; // per tile started, the promise of its result
        this.failed = null; // the first tile that failed
        this.buf = new Uint8Array(1 << 16);
        this.len = 0;
        this.units = []; // complete units seen so far: {type, start, end, payload}
        this.scan = 8;
        this.verified = 0; // units[0, verified) passed their CRC-32 check
        this.ctx = null; // the prelude, once parsed
        this.tiles = []; // decoded tiles, by tile number
        this.busy = Promise.resolve();
    }

    /** Add the next bytes of the stream; decodes the tiles they complete. */
    push(chunk) {
        if (this.len + chunk.length > this.buf.length) {
            let cap = this.buf.length;
            while (cap < this.len + chunk.length) cap *= 2;
            const b = new Uint8Array(cap);
            b.set(this.buf.subarray(0, this.len));
            this.buf = b;
        }
        this.buf.set(chunk, this.len);
        this.len += chunk.length;
        this.busy = this.busy.then(() => this._advance());
        return this.busy;
    }

    // the units' boundaries; a unit's CRC-32 is checked by _verify, before its payload is parsed or
    // its tile decoded here (with a pool: right after the tiles complete so far are handed out)
    _scanUnits() {
        this.scan = scanUnits(this.buf, this.len, this.scan, this.units);
    }

    // E9 for the units scanned so far before index upTo, in stream order
    _verify(upTo = this.units.length) {
        for (; this.verified < upTo; this.verified++) {
            const u = this.units[this.verified];
            if (unitCrc32(this.buf, u.start, u.end - 4) !== u.stored) throw new BitstreamError(`data unit at byte ${u.start} fails its CRC-32 check (E9)`, 'E9');
        }
    }

    // the prelude from the units so far (preludeFromUnits), their CRCs checked first
    _prelude() {
        return preludeFromUnits(this.units, (upTo) => this._verify(upTo));
    }

    async _advance() {
        if (this.failed) throw this.failed; // a tile the pool rejected: the stream is rejected now
        this._scanUnits();
        mark(`scanned ${this.scan}`);
        if (!this.ctx) {
            this.ctx = this._prelude();
            if (!this.ctx) { this._verify(); return; }
            mark('prelude');
            this._startPool(this.ctx);
        }
        if (!this.pool) this._verify(); // one thread: every unit so far checked before a tile is decoded
        const ctx = this.ctx;
        while (this.pending.length < ctx.tiles.length) {
            const t = this.pending.length, tile = ctx.tiles[t];
            if (!this._selected(ctx, t)) { this.pending.push(null); continue; } // not in the box: not decoded
            const units = this.units.filter((u) => u.type < 0x80 && u.start >= tile.start && u.end <= tile.end);
            const last = units[units.length - 1];
            const complete = last && last.type === UNIT.DECODED_SCENE_HASH && (tile.end === Infinity || last.end === tile.end);
            if (!complete) break;
            tile.units = units;
            const p = this._start(ctx, t);
            if (!this.pool) await p; // one after the other: tile 0 is shown before tile 1 is started
        }
        if (this.pool) {
            this.pool.flush(); // the tiles complete so far handed out (largest first), then their units checked here
            this._verify();
            mark('verified');
        }
    }

    // a pool pays only for several tiles (minPoolTiles); fewer are decoded here
    _startPool(ctx) {
        if (this.pool && ctx.tiles.length < this.minPoolTiles) this.pool = null;
        if (this.pool) this.pool.start(ctx);
    }

    // whether tile t is decoded: every tile, or those the box (or select) selects
    _selected(ctx, t) {
        if (!this.box && !this.select) return true;
        if (!ctx.selected) ctx.selected = new Set(this.select ? this.select(ctx) : tilesInBox(ctx, this.box));
        return ctx.selected.has(t);
    }

    // tile t decoded (here, or by the pool: every tile, this thread only hands them out), kept and reported
    _start(ctx, t) {
        let p = this.pool ? this.pool.decode(ctx, t) : timed('worker', () => decodeTile(ctx, t));
        p = p.then((r) => {
            this.tiles[t] = r;
            if (this.onTile) this.onTile(t, r, { tiles: ctx.tiles.length, ps: ctx.ps, ctx });
        });
        p.catch((err) => { this.failed = this.failed || err; }); // reported by the next push() or finish()
        this.pending.push(p);
        return p;
    }

    /**
     * The stream is complete: every check of clauses 6 and 13.1 on all its bytes, the tiles not
     * decoded yet decoded. Returns {ps, tiles} (the decoded tiles in stream order); throws for a
     * stream that is not conforming.
     */
    async finish() {
        await this.busy;
        mark('finish');
        const bytes = this.buf.subarray(0, this.len);
        // the units _verify checked are not checked again (the same bytes: the buffer only grows)
        const ctx = parseStream(bytes, { maxMemory: this.maxMemory, verifiedEnd: this.verified ? this.units[this.verified - 1].end : 0 });
        mark('parsed');
        // the tiles decoded early were cut by the index this full parse has now checked
        if (this.ctx && this.ctx.tiles.length !== ctx.tiles.length) throw new BitstreamError('the tiles changed between the progressive and the full parse');
        if (!this.ctx) this._startPool(ctx);
        for (let t = this.pending.length; t < ctx.tiles.length; t++) {
            if (!this._selected(ctx, t)) { this.pending.push(null); continue; }
            const p = this._start(ctx, t);
            if (!this.pool) await p;
        }
        await Promise.all(this.pending);
        mark('tiles');
        return { ps: ctx.ps, tiles: this.tiles.filter(Boolean) }; // in stream order (a box's tiles only)
    }
}

/**
 * The complete data units of bytes[scan, len) appended to units ({type, start, end, stored, index,
 * payload (a copy)}; CRCs not checked); returns the byte after the last complete one.
 */
export function scanUnits(b, len, scan, units) {
    while (scan + 9 <= len) {
        const p = scan;
        const size = ((b[p + 1] << 24) | (b[p + 2] << 16) | (b[p + 3] << 8) | b[p + 4]) >>> 0;
        if (p + 9 + size > len) break;
        const end = p + 5 + size;
        const stored = ((b[end] << 24) | (b[end + 1] << 16) | (b[end + 2] << 8) | b[end + 3]) >>> 0;
        units.push({ type: b[p], start: p, end: end + 4, stored, index: units.length, payload: b.slice(p + 5, end) });
        scan = end + 4;
    }
    return scan;
}

/**
 * The prelude (parameter set, neighbour prediction, step adjustment (and its flags), SH degree,
 * rotation length, tile index) from the complete units of a stream's first bytes ({type, start, end,
 * index, payload}, in stream order): the stream's context with ctx.tiles = [{points, cell, start,
 * end}] (byte positions from the index; an untiled stream's one tile ends at Infinity), or null while
 * a unit of it is missing. verify(upTo) checks the CRC-32 of units[0, upTo) before they are parsed.
 * A stream with the hierarchy gives null (the full parse rejects it).
 */
export function preludeFromUnits(units, verify) {
    const crit = units.filter((u) => u.type < 0x80);
    if (!crit.length || crit[0].type !== UNIT.GAUSSIAN_PARAMETER_SET) return null;
    const last = crit.findIndex((u) => u.type === UNIT.TILE_INDEX || u.type === UNIT.GEOMETRY);
    if (last < 0) return null;
    verify(crit[last].index + 1); // the units this parses
    const ps = parseGaussianParameterSet(crit[0].payload);
    if (ps.hierarchyEnabled) return null; // rejected by the full parse
    let i = 1;
    const payloads = { ps: crit[0].payload, np: null, sa: null, sf: null, sd: null, rl: null, st: null };
    const next = (type) => (crit[i] && crit[i].type === type ? crit[i++].payload : null);
    payloads.np = next(UNIT.NEIGHBOUR_PREDICTION);
    if (payloads.np) {
        payloads.sa = next(UNIT.STEP_ADJUST);
        if (payloads.sa) payloads.sf = next(UNIT.STEP_ADJUST_FLAGS);
        payloads.sd = next(UNIT.SH_DEGREE);
    }
    payloads.rl = next(UNIT.ROTATION_LENGTH);
    payloads.st = next(UNIT.SH_TRANSFORM);
    const ctx = preludeContext(ps, payloads);
    if (!crit[i]) return null;
    if (ps.tilesEnabled) {
        if (crit[i].type !== UNIT.TILE_INDEX) return null;
        const ti = crit[i];
        let pos = ti.end;
        ctx.tiles = parseTileIndex(ti.payload, ps.numGaussians).map((t) => {
            const r = { points: t.points, cell: t.cell, start: pos, end: pos + t.size };
            pos += t.size;
            return r;
        });
        ctx.tileIndexEnd = ti.end;
    } else {
        ctx.tiles = [{ points: ps.numGaussians, cell: null, start: crit[i].start, end: Infinity }];
    }
    return ctx;
}

export { sceneArrays };
