// Geometry decoding (spec/geometry.md, clauses G.2 to G.6): the header here; the octree with
// direct coding (IDCM) and binary decisions with adaptive integer probabilities, output in the
// normative Morton order, in WebAssembly (wasm/decoder.ts: decodeGeometry and the range decoder).
import { BitReader, checkRange } from './bitreader.mjs';
import { BitstreamError } from './errors.mjs';
import { arenaWith, callWasm, int32Copy } from './wasm.mjs';

/** geometry_header() (G.2, G.3), checked; returns {bboxMin, bitDepth, idcmMode, dataOffset}. */
export function parseGeometryHeader(payload, n) {
    const r = new BitReader(payload, 'geometry_header');
    const bboxMin = [0, 0, 0], bitDepth = [0, 0, 0];
    for (let i = 0; i < 3; i++) {
        const sign = r.u(1, `geom_bbox_min_sign_flag[${i}]`);
        const abs = checkRange('geometry_header', `geom_bbox_min_abs[${i}]`, r.ue(`geom_bbox_min_abs[${i}]`), 0, 2 ** 31);
        if (!sign && abs > 2 ** 31 - 1) {
            throw new BitstreamError(`geometry_header.geom_bbox_min_abs[${i}] = ${abs} puts the bounding-box minimum outside [-2^31, 2^31) (G.3, E26)`, 'E26');
        }
        bboxMin[i] = sign ? -abs : abs;
        bitDepth[i] = checkRange('geometry_header', `geom_bit_depth[${i}]`, r.u(6, `geom_bit_depth[${i}]`), 0, 32);
    }
    const idcmMode = checkRange('geometry_header', 'geom_idcm_mode', r.ue('geom_idcm_mode'), 0, 2);
    r.byteAlign();
    if (n > 2 ** (bitDepth[0] + bitDepth[1] + bitDepth[2])) {
        throw new BitstreamError(`geometry: ${n} points cannot be distinct in a bounding box of ${bitDepth} bits per axis (G.3, E27)`, 'E27');
    }
    const dataOffset = r.bitPosition >>> 3;
    if (Math.max(...bitDepth) === 0 && dataOffset < payload.length) {
        throw new BitstreamError(`geometry: ${payload.length - dataOffset} bytes of coded data after a header of bit depth 0 (G.3, E28)`, 'E28');
    }
    return { bboxMin, bitDepth, idcmMode, dataOffset };
}

/** The spec's error for a failure code of wasm/decoder.ts's decodeGeometry. */
function geometryError(code, a, b, n) {
    const messages = {
        1: 'geometry data: range decoding failed: q >= 2^24 (clause 10.6.4)',
        2: 'geometry data: data left over after decoding (clause 10.6.5)',
        3: `geometry data: more than N = ${n} points (G.5.2 step 3, E29)`,
        4: 'geometry data: the two points of a two-point direct node are equal (G.5.2, E30)',
        5: `geometry data: ${a} points at depth ${b}, more than N = ${n} (G.5.4, E31)`,
        6: `geometry data holds ${a} points, N = ${n} (G.5.5, E32)`,
        7: 'geometry data: the decoded points do not attain the bounding-box minimum (G.5.5, E33)',
        8: 'geometry data: decoded coordinates exceed 2^31 - 1 (G.5.5, E34)',
    };
    const conditions = { 1: 'E36', 2: 'E38', 3: 'E29', 4: 'E30', 5: 'E31', 6: 'E32', 7: 'E33', 8: 'E34' };
    return new BitstreamError(messages[code], conditions[code]);
}

/**
 * Decode a geometry payload of n points (G.2 to G.5). Returns {x, y, z} (Int32Array each: voxel
 * coordinates in normative order), the header, and min, max: per axis the smallest (the
 * bounding-box minimum, which the points attain: G.5.5) and the largest coordinate.
 */
export function decodeGeometry(payload, n) {
    const h = parseGeometryHeader(payload, n);
    const data = payload.subarray(h.dataOffset);
    if (data.length % 4) {
        throw new BitstreamError(`geometry data: length ${data.length} is not a whole number of 32-bit words (clause 10.6.6)`, 'E35');
    }
    const p = arenaWith(data);
    const [b0, b1, b2] = h.bitDepth, [m0, m1, m2] = h.bboxMin;
    return callWasm((w) => {
        w.decodeGeometry(p, data.length, n, b0, b1, b2, h.idcmMode, m0, m1, m2);
        const max = [0, 1, 2].map((a) => w.resultMax(a));
        return { x: int32Copy(w.resultX(), n), y: int32Copy(w.resultY(), n), z: int32Copy(w.resultZ(), n), header: h, min: h.bboxMin, max };
    }, (code, a, b) => geometryError(code, a, b, n));
}
