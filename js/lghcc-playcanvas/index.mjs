// lghcc-playcanvas: .lghcc scenes (LG-HCC compressed 3D Gaussian Splatting) as PlayCanvas gsplat
// assets. LghccParser joins the engine's gsplat resource handler, as the engine's own SpzParser does,
// so that `new Asset(name, 'gsplat', {url: 'scene.lghcc'})` loads like a .ply or .sog; gsplatData()
// turns decoded arrays into the engine's GSplatData for an application that decodes by itself.
import { GSplatData, GSplatResource, http } from 'playcanvas';
import { decode } from 'lghcc-decoder';

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

/**
 * A parser of the engine's gsplat resource handler for .lghcc files:
 *
 *     app.loader.getHandler('gsplat').addParser(new LghccParser(app));
 *     const asset = new Asset('scene', 'gsplat', { url: 'scene.lghcc' });
 *
 * The stream is fetched and decoded as it arrives (the tiles of a tiled stream in parallel helper
 * workers, each tile's hash checked); a stream the decoder refuses fails the asset with the
 * decoder's error (`asset.on('error', (err) => ...)`: an UnsupportedStreamError, BitstreamError, ...).
 * `options`: decode()'s `workers` and `maxMemory`. Per asset (`new Asset(name, 'gsplat', file,
 * data)`): `data.box` (decode only the tiles meeting [x0, y0, z0, x1, y1, z1]) and `data.reorder`
 * (false: keep the stream's order instead of the engine's Morton order, as for a .ply).
 */
export class LghccParser {
    constructor(app, options = {}) {
        this.app = app;
        this.options = { workers: options.workers, maxMemory: options.maxMemory };
    }

    canParse(context) {
        return context.ext === 'lghcc';
    }

    async load(url, callback, asset) {
        const prepareCenters = this.app.scene?.gsplatCentersEnabled !== false;
        const abort = new AbortController();
        const unload = () => abort.abort();
        asset?.once('unload', unload);
        try {
            const href = typeof url === 'string' ? url : url.load;
            // the engine's fetch rules: an asset's in-memory file first, credentials as its loader's
            const input = asset?.file?.contents ?? await fetch(href, { credentials: http.withCredentials ? 'include' : 'same-origin', signal: abort.signal });
            if (input instanceof Response && !input.ok) throw new Error(`${href}: HTTP ${input.status}`);
            const data = asset?.data ?? {};
            const scene = await decode(input, {
                ...withoutUndefined(this.options), box: data.box ?? null, signal: abort.signal,
                onProgress: (p) => asset?.fire('progress', p.pointsDecoded, p.pointsTotal)
            });
            const splats = gsplatData(scene);
            asset?.fire('load:data', splats);
            if (data.reorder ?? true) splats.reorderData();
            callback(null, new GSplatResource(this.app.graphicsDevice, splats, { prepareCenters }));
        } catch (err) {
            callback(err, null);
        } finally {
            asset?.off('unload', unload);
        }
    }

    open(url, data) {
        return data;
    }
}

function withoutUndefined(o) {
    return Object.fromEntries(Object.entries(o).filter(([, v]) => v !== undefined));
}
