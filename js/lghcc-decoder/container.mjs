// The container (spec clause 6): header, data units with CRC-32, unit types, and the unit
// grammar of clause 6.3 for explicit-Gaussian streams.
import { unitCrc32 } from './crc32.mjs';
import { BitstreamError, UnsupportedStreamError } from './errors.mjs';

export const MAGIC = 0x4C474843;
export const UNIT = {
    SCENE_PARAMETER_SET: 0x01, RENDER_MODEL: 0x02, GEOMETRY: 0x03, ATTRIBUTE: 0x04, CONTEXT_MODEL: 0x05,
    DECODED_SCENE_HASH: 0x06, GAUSSIAN_PARAMETER_SET: 0x07, TILE_INDEX: 0x08, NEIGHBOUR_PREDICTION: 0x09,
    STEP_ADJUST: 0x0A, SH_DEGREE: 0x0B, ROTATION_LENGTH: 0x0C, STEP_ADJUST_FLAGS: 0x0D, SH_TRANSFORM: 0x0E, SOURCE_INFO: 0x80,
};
export const LAST_KNOWN_CRITICAL = 0x0E;

/** Clause 6.1: the 8-byte container header of bytes (at least its first 8 bytes); returns {major, minor}. */
export function parseHeader(bytes) {
    if (bytes.length < 8) throw new BitstreamError(`the stream has ${bytes.length} bytes, shorter than the 8-byte container header (E1)`, 'E1');
    const magic = ((bytes[0] << 24) | (bytes[1] << 16) | (bytes[2] << 8) | bytes[3]) >>> 0;
    if (magic !== MAGIC) throw new BitstreamError(`magic 0x${magic.toString(16)} is not 0x4c474843 ("LGHC") (E2)`, 'E2');
    const major = bytes[4], minor = bytes[5];
    if (major !== 1) throw new UnsupportedStreamError(`stream version ${major}.${minor}: this decoder decodes version 1 streams (E3)`, 'E3');
    if (bytes[6] !== 1) throw new UnsupportedStreamError(`profile_idc ${bytes[6]} is not 1 (main) (E4)`, 'E4');
    if (bytes[7] !== 0) throw new BitstreamError(`reserved_zero_8bits = ${bytes[7]} is not 0 (E5)`, 'E5');
    return { major, minor };
}

/**
 * Clause 6.1, 6.2: the container header and every data unit (header, size, CRC), before any payload
 * is interpreted. verifiedEnd: the units that end at or before this byte passed their CRC check already.
 */
export function parseContainer(bytes, { verifiedEnd = 0 } = {}) {
    const { major, minor } = parseHeader(bytes);
    const units = [];
    let pos = 8;
    while (pos < bytes.length) {
        const left = bytes.length - pos;
        if (left < 9) throw new BitstreamError(`${left} bytes after the last data unit, too few for a unit (clause 6.4, E6)`, 'E6');
        const type = bytes[pos];
        const size = ((bytes[pos + 1] << 24) | (bytes[pos + 2] << 16) | (bytes[pos + 3] << 8) | bytes[pos + 4]) >>> 0;
        if (type === 0) throw new BitstreamError(`data unit at byte ${pos}: unit_type 0 is forbidden (E7)`, 'E7');
        if (size + 9 > left) throw new BitstreamError(`data unit at byte ${pos} (type 0x${type.toString(16)}): payload of ${size} bytes extends beyond the end of the stream (E8)`, 'E8');
        const end = pos + 5 + size;
        const stored = ((bytes[end] << 24) | (bytes[end + 1] << 16) | (bytes[end + 2] << 8) | bytes[end + 3]) >>> 0;
        if (end + 4 > verifiedEnd && unitCrc32(bytes, pos, end) !== stored) throw new BitstreamError(`data unit at byte ${pos} (type 0x${type.toString(16)}) fails its CRC-32 check (E9)`, 'E9');
        units.push({ type, start: pos, end: end + 4, payload: bytes.subarray(pos + 5, end) });
        pos = end + 4;
    }
    return { versionMajor: major, versionMinor: minor, units };
}

export const isCritical = (type) => type < 0x80;

/**
 * The unit grammar of clause 6.3 before the tiles, `P [N [Q [F]] [B]] [W] [T] [C] [I]`, for units (the
 * stream's, or its first ones: every unit type is checked, E10). Returns {s: {ps, np, sa, sf, sd, rl,
 * cm, ti, tiles: []}, critical: the critical units, i: the index in critical of the first unit after them}.
 */
export function preludeStructure(units) {
    for (const u of units) {
        if (isCritical(u.type) && u.type > LAST_KNOWN_CRITICAL) {
            throw new UnsupportedStreamError(`critical unit type 0x${u.type.toString(16)} is not defined by version 1.6, the last this decoder knows (E10)`, 'E10');
        }
    }
    const critical = units.filter((u) => isCritical(u.type));
    if (units.length && !isCritical(units[0].type) && critical.length) {
        throw new BitstreamError('an ancillary unit before the parameter set (clause 6.3, E11)', 'E11');
    }
    const first = critical[0];
    if (!first || (first.type !== UNIT.GAUSSIAN_PARAMETER_SET && first.type !== UNIT.SCENE_PARAMETER_SET)) {
        if (!critical.some((u) => u.type === UNIT.GAUSSIAN_PARAMETER_SET || u.type === UNIT.SCENE_PARAMETER_SET)) {
            throw new BitstreamError('the stream has no parameter set (E12)', 'E12');
        }
        throw new BitstreamError('the first critical unit is not the parameter set (clause 6.3, E14)', 'E14');
    }
    if (!units.length || !isCritical(units[0].type)) throw new BitstreamError('an ancillary unit before the parameter set (clause 6.3, E11)', 'E11');
    if (first.type === UNIT.SCENE_PARAMETER_SET) {
        throw new UnsupportedStreamError('an anchor stream (scene_parameter_set): outside the explicit-Gaussian profile this decoder implements');
    }
    const s = { ps: first, np: null, sa: null, sf: null, sd: null, rl: null, st: null, cm: null, ti: null, tiles: [] };
    let i = 1;
    const peek = () => critical[i] && critical[i].type;
    if (peek() === UNIT.NEIGHBOUR_PREDICTION) {
        s.np = critical[i++];
        if (peek() === UNIT.STEP_ADJUST) {
            s.sa = critical[i++];
            if (peek() === UNIT.STEP_ADJUST_FLAGS) s.sf = critical[i++];
        }
        if (peek() === UNIT.SH_DEGREE) s.sd = critical[i++];
    }
    if (peek() === UNIT.ROTATION_LENGTH) s.rl = critical[i++];
    if (peek() === UNIT.SH_TRANSFORM) s.st = critical[i++];
    if (peek() === UNIT.CONTEXT_MODEL) s.cm = critical[i++];
    if (peek() === UNIT.TILE_INDEX) s.ti = critical[i++];
    return { s, critical, i };
}

/**
 * The unit grammar of clause 6.3 for an explicit-Gaussian stream:
 *   P [N [Q [F]] [B]] [W] [T] [C] [I] tile+,  tile = G A [A] H
 * Returns {ps, np, sa, sf, sd, rl, cm, ti, tiles: [{units: [G, A.., H], start, end}]}; the tile index's byte
 * positions are checked later against the index (clause 7.3.11).
 */
export function unitStructure(units) {
    const { s, critical, i: first } = preludeStructure(units);
    let i = first;
    const peek = () => critical[i] && critical[i].type;
    const kinds = new Set(critical.slice(i).map((u) => u.type));
    for (const t of [UNIT.GEOMETRY, UNIT.ATTRIBUTE, UNIT.DECODED_SCENE_HASH]) {
        if (!kinds.has(t)) throw new BitstreamError(`the stream has no ${t === UNIT.GEOMETRY ? 'geometry' : t === UNIT.ATTRIBUTE ? 'attribute' : 'decoded_scene_hash'} unit (E13)`, 'E13');
    }
    while (i < critical.length) {
        const tile = [];
        if (peek() !== UNIT.GEOMETRY) throw orderError(critical[i]);
        tile.push(critical[i++]);
        while (peek() === UNIT.ATTRIBUTE) tile.push(critical[i++]);
        if (tile.length < 2 || peek() !== UNIT.DECODED_SCENE_HASH) throw orderError(critical[i] || tile[tile.length - 1]);
        tile.push(critical[i++]);
        s.tiles.push({ units: tile, start: tile[0].start, end: tile[tile.length - 1].end });
    }
    return s;
}

/** E14 for unit u, which breaks the unit order of clause 6.3; E61 (a case of E14 with a row of its own) when u is a
 * neighbour_prediction unit (repeated, or not right after the gaussian_parameter_set). */
export function orderError(u) {
    const name = Object.keys(UNIT).find((k) => UNIT[k] === u.type) || `0x${u.type.toString(16)}`;
    // a misplaced step_adjust_flags unit (version 1.5): its rule named
    const condition = u.type === UNIT.NEIGHBOUR_PREDICTION ? 'E61' : 'E14';
    const where = u.type === UNIT.STEP_ADJUST_FLAGS ? ': it may appear only right after the step_adjust unit, once (clause 7.3.16)' : '';
    return new BitstreamError(`unit ${name.toLowerCase()} at byte ${u.start} breaks the unit order of clause 6.3 (${condition})${where}`, condition);
}
