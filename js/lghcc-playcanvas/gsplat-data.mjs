// lghcc-playcanvas/gsplat-data: decoded arrays -> the PlayCanvas engine's GSplatData, without the
// decoder (for an application that decodes elsewhere, e.g. in its own worker, as lghcc-view does).
import { GSplatData } from 'playcanvas';

// the order of the PLY properties the engine reads (f_rest_* inserted after the DC)
const HEAD = ['x', 'y', 'z', 'f_dc_0', 'f_dc_1', 'f_dc_2'];
const TAIL = ['opacity', 'scale_0', 'scale_1', 'scale_2', 'rot_0', 'rot_1', 'rot_2', 'rot_3'];

/**
 * The engine's splat data of one decoded scene, or of several parts drawn as one (e.g. a stream's
 * tiles): the stored 3DGS values (decode()'s default, `activated: false`) under the PLY property
 * names, f_rest channel-major as in a 3DGS PLY. Every part must have the same SH degree.
 */
export function gsplatData(scene) {
    const parts = Array.isArray(scene) ? scene : [scene];
    const count = parts.reduce((n, p) => n + p.opacities.length, 0);
    const rest = parts.length && parts[0].opacities.length ? parts[0].sh.length / parts[0].opacities.length / 3 : 0;
    for (const p of parts) {
        if (p.sh.length !== 3 * rest * p.opacities.length) throw new RangeError('gsplatData: the parts have different SH degrees');
    }
    const names = [...HEAD];
    for (let k = 0; k < 3 * rest; k++) names.push(`f_rest_${k}`);
    names.push(...TAIL);
    const col = Object.fromEntries(names.map((n) => [n, new Float32Array(count)]));
    const fRest = Array.from({ length: 3 * rest }, (_, k) => col[`f_rest_${k}`]);
    let o = 0;
    for (const p of parts) {
        const n = p.opacities.length;
        const { positions: pos, colors: dc, sh, scales, rotations: rot, opacities } = p;
        for (let i = 0; i < n; i++, o++) {
            col.x[o] = pos[3 * i]; col.y[o] = pos[3 * i + 1]; col.z[o] = pos[3 * i + 2];
            col.f_dc_0[o] = dc[3 * i]; col.f_dc_1[o] = dc[3 * i + 1]; col.f_dc_2[o] = dc[3 * i + 2];
            // decoder: coefficient-major, R, G, B inner; PLY: f_rest_{c * rest + j}
            for (let j = 0; j < rest; j++) {
                for (let c = 0; c < 3; c++) fRest[c * rest + j][o] = sh[3 * (rest * i + j) + c];
            }
            col.opacity[o] = opacities[i];
            col.scale_0[o] = scales[3 * i]; col.scale_1[o] = scales[3 * i + 1]; col.scale_2[o] = scales[3 * i + 2];
            col.rot_0[o] = rot[4 * i]; col.rot_1[o] = rot[4 * i + 1]; col.rot_2[o] = rot[4 * i + 2]; col.rot_3[o] = rot[4 * i + 3];
        }
    }
    return new GSplatData([{
        name: 'vertex', count,
        properties: names.map((name) => ({ name, type: 'float', byteSize: 4, storage: col[name] }))
    }]);
}
