// Syntax structures of the explicit-Gaussian profile (spec clause 7, syntax_tables.md), each
// element checked against its range of clause 7.2 as it is parsed.
import { BitReader, checkPositive, checkRange } from './bitreader.mjs';
import { BitstreamError } from './errors.mjs';

const UE_MAX = 2 ** 32 - 2;
const NUM_DEGREE_CONTEXTS = 6; // clause 7.3.14
const NUM_STEP_FLAG_CONTEXTS = 6; // clause 7.3.16

/** gaussian_parameter_set() (clause 7.3.9). */
export function parseGaussianParameterSet(payload) {
    const W = 'gaussian_parameter_set';
    const r = new BitReader(payload, W);
    const p = {};
    p.numGaussians = checkRange(W, 'num_gaussians_minus1', r.ue('num_gaussians_minus1'), 0, 2 ** 24 - 1) + 1;
    p.shDegree = r.u(2, 'sh_degree');
    p.voxelSize = checkPositive(W, 'voxel_size', r.f32('voxel_size'));
    p.origin = [0, 1, 2].map((i) => r.f32(`origin[${i}]`));
    p.shDcStep = checkPositive(W, 'sh_dc_step', r.f32('sh_dc_step'));
    p.shBandStep = [];
    for (let b = 0; b < p.shDegree; b++) p.shBandStep.push(checkPositive(W, `sh_band_step[${b}]`, r.f32(`sh_band_step[${b}]`)));
    p.opacityStep = checkPositive(W, 'opacity_step', r.f32('opacity_step'));
    p.scaleStep = checkPositive(W, 'scale_step', r.f32('scale_step'));
    p.rotationStep = checkPositive(W, 'rotation_step', r.f32('rotation_step'));
    p.hierarchyEnabled = r.u(1, 'hierarchy_enabled_flag');
    p.coarseVoxelScale = p.hierarchyEnabled
        ? checkRange(W, 'coarse_voxel_scale_minus1', r.ue('coarse_voxel_scale_minus1'), 0, 2 ** 20 - 1) + 1 : 1;
    p.tilesEnabled = r.u(1, 'tiles_enabled_flag');
    p.tileScale = p.tilesEnabled ? checkRange(W, 'tile_scale_minus1', r.ue('tile_scale_minus1'), 0, 2 ** 20 - 1) + 1 : 0;
    // the 0 to 7 bits after the last element are ignored; whole bytes after it are rejected (clause 6.4)
    r.expectEnd(true);
    p.S = (p.shDegree + 1) ** 2;
    p.M = 3 * p.S + 8;
    p.tileSize = p.tileScale * (p.hierarchyEnabled ? p.coarseVoxelScale : 1);
    if (p.numGaussians * p.M > 2 ** 31) throw new BitstreamError(`N * M = ${p.numGaussians * p.M} exceeds 2^31 (clause 8.1, E22)`, 'E22');
    p.steps = channelSteps(p);
    return p;
}

/** step(c) of clause 11.1, per channel. */
function channelSteps(p) {
    const steps = new Float64Array(p.M);
    for (let c = 0; c < 3 * p.S; c++) {
        const i = Math.floor(c / 3);
        steps[c] = i === 0 ? p.shDcStep : p.shBandStep[Math.floor(Math.sqrt(i)) - 1];
    }
    steps[3 * p.S] = p.opacityStep;
    for (let a = 0; a < 3; a++) steps[3 * p.S + 1 + a] = p.scaleStep;
    for (let j = 0; j < 4; j++) steps[3 * p.S + 4 + j] = p.rotationStep;
    return steps;
}

/** neighbour_prediction_unit() (clause 7.3.12). */
export function parseNeighbourPrediction(payload, M) {
    const r = new BitReader(payload, 'neighbour_prediction_unit');
    const np = {};
    np.L = r.u(4, 'num_lods_minus1') + 1;
    np.k = r.u(5, 'num_neighbours_minus1') + 1;
    np.B = r.u(4, 'num_buckets_minus1') + 1;
    np.meanFlag = Uint8Array.from({ length: M }, (_, c) => r.u(1, `neighbour_mean_flag[${c}]`));
    np.bucketLevel = Uint8Array.from({ length: M * np.B }, (_, i) => r.u(6, `bucket_level[${i}]`));
    r.byteAlign();
    r.expectEnd();
    return np;
}

/** step_adjust_unit() (clause 7.3.13). */
export function parseStepAdjust(payload) {
    const r = new BitReader(payload, 'step_adjust_unit');
    const maxStepAdjust = r.u(3, 'max_step_adjust');
    r.byteAlign();
    r.expectEnd();
    return { maxStepAdjust };
}

/**
 * step_adjust_flags_unit() (clause 7.3.16, version 1.5) of the step_adjust unit's max_step_adjust: the flags'
 * frequencies f[1] = 4096 step_flag_prob + 2048 (Int32Array [max_step_adjust * 6]; empty payload for 0).
 */
export function parseStepAdjustFlags(payload, maxStepAdjust) {
    const r = new BitReader(payload, 'step_adjust_flags_unit');
    const freq = Int32Array.from({ length: maxStepAdjust * NUM_STEP_FLAG_CONTEXTS }, (_, i) => 4096 * r.u(12, `step_flag_prob[${i}]`) + 2048);
    r.byteAlign();
    r.expectEnd();
    return { freq };
}

/** rotation_length_unit() (clause 7.3.15): the largest rotation length index a row may have. */
export function parseRotationLength(payload) {
    const r = new BitReader(payload, 'rotation_length_unit');
    const maxIndex = r.u(4, 'max_rotation_length_index');
    r.byteAlign();
    r.expectEnd();
    return { maxIndex };
}

/**
 * sh_transform_unit() (clause 7.3.17) of sh_degree d: {size: NumShRest = 3 (d + 1)^2 - 3, shift: R, matrix: BigInt64Array
 * [size * size] of T[j][k] = sh_transform_coeff[j * size + k] - 2^(B - 1), row-major}.
 */
export function parseShTransform(payload, d) {
    const r = new BitReader(payload, 'sh_transform_unit');
    const shift = r.u(5, 'sh_transform_shift');
    const bits = r.u(4, 'sh_transform_bits_minus1') + 1;
    const size = 3 * (d + 1) ** 2 - 3, offset = 2 ** (bits - 1);
    const matrix = BigInt64Array.from({ length: size * size }, (_, i) => BigInt(r.u(bits, `sh_transform_coeff[${i}]`) - offset));
    r.byteAlign();
    r.expectEnd();
    return { size, shift, matrix };
}

/** sh_degree_unit() (clause 7.3.14) of sh_degree d: the flags' frequencies f[1] = 4096 degree_flag_prob + 2048 (Int32Array [d * 6]). */
export function parseShDegree(payload, d) {
    const r = new BitReader(payload, 'sh_degree_unit');
    const freq = Int32Array.from({ length: d * NUM_DEGREE_CONTEXTS }, (_, i) => 4096 * r.u(12, `degree_flag_prob[${i}]`) + 2048);
    r.byteAlign();
    r.expectEnd();
    return { freq };
}

/** tile_index_unit() (clause 7.3.11), with the checks on its own elements (E56, E57). */
export function parseTileIndex(payload, N) {
    const W = 'tile_index_unit';
    const r = new BitReader(payload, W);
    const T = checkRange(W, 'num_tiles_minus1', r.ue('num_tiles_minus1'), 0, N - 1) + 1;
    const tiles = [];
    let total = 0;
    for (let t = 0; t < T; t++) {
        const cell = ['x', 'y', 'z'].map((a) => r.se(`tile_${a}[${t}]`));
        const points = checkRange(W, `tile_num_points_minus1[${t}]`, r.ue(`tile_num_points_minus1[${t}]`), 0, N - 1) + 1;
        const size = checkRange(W, `tile_data_size[${t}]`, r.ue(`tile_data_size[${t}]`), 0, UE_MAX);
        if (t > 0 && !lexLess(tiles[t - 1].cell, cell)) {
            throw new BitstreamError(`tile_index_unit: cell ${cell} of tile ${t} does not follow ${tiles[t - 1].cell} in strictly increasing order (E56)`, 'E56');
        }
        tiles.push({ cell, points, size });
        total += points;
    }
    r.byteAlign();
    r.expectEnd();
    if (total !== N) throw new BitstreamError(`tile_index_unit: the tiles' point counts add up to ${total}, not N = ${N} (E57)`, 'E57');
    return tiles;
}

function lexLess(a, b) {
    for (let i = 0; i < 3; i++) if (a[i] !== b[i]) return a[i] < b[i];
    return false;
}

/** decoded_scene_hash_unit() (clause 7.3.6): the 32-byte scene_hash. */
export function parseHashUnit(payload) {
    const r = new BitReader(payload, 'decoded_scene_hash_unit');
    checkRange('decoded_scene_hash_unit', 'hash_type', r.u(8, 'hash_type'), 1, 1);
    if (payload.length < 33) throw new BitstreamError(`decoded_scene_hash_unit: truncated: ${payload.length} bytes, 33 needed (clause 6.4)`, 'E17');
    if (payload.length > 33) throw new BitstreamError(`decoded_scene_hash_unit: ${payload.length - 33} bytes after scene_hash (clause 6.4, E21)`, 'E21');
    return payload.subarray(1, 33);
}

/** The LoD sizes n_l of clause 7.3.12 for NumRows rows and L LoDs. */
export function lodSizes(rows, L) {
    const ceilDiv = (a, t) => Math.ceil(a / 2 ** t);
    const n = [ceilDiv(rows, L - 1)];
    for (let l = 1; l < L; l++) { const t = L - 1 - l; n.push(ceilDiv(rows, t) - ceilDiv(rows, t + 1)); }
    return n;
}

/**
 * attribute_unit_header() (clause 7.3.5) of an explicit-Gaussian stream without the hierarchy:
 * NumChannels = M, no offsets, ChannelPredictionAllowed = 1. ctx: {M, np (or null), stepAdjust, stepFlags, shDegreeUnit}.
 */
export function parseAttributeHeader(payload, ctx) {
    const W = 'attribute_unit_header';
    const r = new BitReader(payload, W);
    const M = ctx.M;
    const h = {};
    h.level = checkRange(W, 'attribute_level', r.u(2, 'attribute_level'), 0, 2);
    if (h.level !== 0) throw new BitstreamError(`attribute_unit_header.attribute_level = ${h.level}: the unit's position requires 0 (clause 7.3.5, E45)`, 'E45');
    h.contextModelId = checkRange(W, 'context_model_id', r.u(3, 'context_model_id'), 0, 2);
    if (h.contextModelId !== 0) {
        throw new BitstreamError(`attribute_unit_header.context_model_id = ${h.contextModelId} in a unit of attribute_level 0 (clause 7.3.5, ${ctx.np ? 'E62' : 'E46'})`, ctx.np ? 'E62' : 'E46');
    }
    h.priorMean = new Float64Array(M);
    h.priorLevel = new Uint8Array(M);
    for (let c = 0; c < M; c++) { h.priorMean[c] = r.se(`prior_mean[${c}]`); h.priorLevel[c] = r.u(6, `prior_level[${c}]`); }
    const np = checkRange(W, 'num_channel_predictions', r.ue('num_channel_predictions'), 0, M * (M - 1) / 2);
    h.predTarget = new Int32Array(np); h.predSource = new Int32Array(np); h.predWeight = new Float64Array(np);
    for (let i = 0; i < np; i++) {
        const t = checkRange(W, `pred_target_channel[${i}]`, r.ue(`pred_target_channel[${i}]`), 1, M - 1);
        const s = checkRange(W, `pred_source_channel[${i}]`, r.ue(`pred_source_channel[${i}]`), 0, M - 2);
        if (s >= t) throw new BitstreamError(`attribute_unit_header: prediction ${i}: source ${s} is not before its target ${t} (E48)`, 'E48');
        if (i > 0 && !(t > h.predTarget[i - 1] || (t === h.predTarget[i - 1] && s > h.predSource[i - 1]))) {
            throw new BitstreamError(`attribute_unit_header: predictions not in strictly increasing (target, source) order at ${i} (E49)`, 'E49');
        }
        h.predTarget[i] = t; h.predSource[i] = s;
        h.predWeight[i] = checkRange(W, `pred_weight[${i}]`, r.se(`pred_weight[${i}]`), -(2 ** 15), 2 ** 15);
    }
    if (ctx.stepAdjust) { h.adjustMean = r.u(3, 'adjust_mean'); h.adjustLevel = r.u(6, 'adjust_level'); }
    if (ctx.stepFlags && (h.adjustMean || h.adjustLevel)) {
        throw new BitstreamError(`attribute_unit_header: adjust_mean = ${h.adjustMean}, adjust_level = ${h.adjustLevel} in a stream with a step_adjust_flags unit: both shall be 0 (clause 7.3.16, E67)`, 'E67');
    }
    h.numRows = checkRange(W, 'num_rows_minus1', r.ue('num_rows_minus1'), 0, 2 ** 24 - 1) + 1;
    h.rowsPerChunk = checkRange(W, 'rows_per_chunk_minus1', r.ue('rows_per_chunk_minus1'), 0, h.numRows - 1) + 1;
    h.lods = ctx.np ? lodSizes(h.numRows, ctx.np.L) : [h.numRows];
    const numChunks = h.lods.reduce((a, n) => a + Math.ceil(n / h.rowsPerChunk), 0);
    h.adjustSize = ctx.stepAdjust ? new Float64Array(numChunks) : null;
    h.degreeSize = ctx.shDegreeUnit ? new Float64Array(numChunks) : null;
    h.chunkSize = new Float64Array(numChunks);
    for (let i = 0; i < numChunks; i++) {
        if (ctx.stepAdjust) h.adjustSize[i] = checkRange(W, `adjust_chunk_size[${i}]`, r.ue(`adjust_chunk_size[${i}]`), 0, UE_MAX);
        if (ctx.shDegreeUnit) h.degreeSize[i] = checkRange(W, `degree_chunk_size[${i}]`, r.ue(`degree_chunk_size[${i}]`), 0, UE_MAX);
        h.chunkSize[i] = checkRange(W, `chunk_size[${i}]`, r.ue(`chunk_size[${i}]`), 0, UE_MAX);
    }
    r.byteAlign();
    h.dataOffset = r.bitPosition >>> 3;
    let total = 0;
    for (let i = 0; i < numChunks; i++) total += h.chunkSize[i] + (ctx.stepAdjust ? h.adjustSize[i] : 0) + (ctx.shDegreeUnit ? h.degreeSize[i] : 0);
    if (total !== payload.length - h.dataOffset) {
        throw new BitstreamError(`attribute unit: the chunk sizes add up to ${total} bytes, the payload holds ${payload.length - h.dataOffset} after the header (clause 6.4, E50)`, 'E50');
    }
    return h;
}
