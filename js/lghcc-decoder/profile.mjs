// Membership of a conformance stream in the explicit-Gaussian profile (spec clause 8.4), from
// test.yaml's tools and the units present in the stream.
import { MAGIC } from './container.mjs';

/** Tools of test.yaml that lie outside the profile. */
export const OUTSIDE_TOOLS = new Set([
    'hierarchy', 'context_model', 'context_model_unit', 'parent_mlp_context', 'ggconv_context', 'render_model',
    'render_model_empty', 'offset_mask', 'scene_parameter_set', 'ggconv_neighbour_level_1', 'ggconv_neighbour_level_2',
    'context_parent_base_0', 'context_parent_base_1', 'tile_without_level2',
]);

/** Unit types found by walking the units by their sizes, CRCs unchecked (a damaged stream included). */
export function scanUnitTypes(bytes) {
    const types = [];
    if (bytes.length < 8) return types;
    let pos = 8;
    while (pos + 9 <= bytes.length) {
        const size = ((bytes[pos + 1] << 24) | (bytes[pos + 2] << 16) | (bytes[pos + 3] << 8) | bytes[pos + 4]) >>> 0;
        types.push(bytes[pos]);
        pos += 9 + size;
    }
    return types;
}

/**
 * In the profile: no tool outside it, no scene_parameter_set unit, and either a
 * gaussian_parameter_set (0x07) among the units or (an error stream) no parameter set at all
 * (faults of the container a decoder of any profile meets first). Returns [inProfile, reason].
 */
export function inProfile(meta, bytes) {
    const outside = (meta.tools || []).filter((t) => OUTSIDE_TOOLS.has(t));
    if (outside.length) return [false, `tools outside the profile: ${outside.join(', ')}`];
    const types = scanUnitTypes(bytes);
    const magicOk = bytes.length >= 4 && (((bytes[0] << 24) | (bytes[1] << 16) | (bytes[2] << 8) | bytes[3]) >>> 0) === MAGIC;
    if (types.includes(0x01)) return [false, 'an anchor stream (scene_parameter_set)'];
    if (types.includes(0x07)) return [true, 'explicit Gaussians'];
    if (meta.expect === 'error' && (!magicOk || !types.length || !types.some((t) => t === 0x01 || t === 0x07))) {
        return [true, 'no parameter set: a container fault'];
    }
    return [false, 'no gaussian_parameter_set'];
}
