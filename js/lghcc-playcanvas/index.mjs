// lghcc-playcanvas: .lghcc scenes (LG-HCC compressed 3D Gaussian Splatting) as PlayCanvas gsplat
// assets. LghccParser joins the engine's gsplat resource handler, as the engine's own SpzParser does,
// so that `new Asset(name, 'gsplat', {url: 'scene.lghcc'})` loads like a .ply or .sog; gsplatData()
// turns decoded arrays into the engine's GSplatData for an application that decodes by itself.
import { GSplatResource, http } from 'playcanvas';
import { decode } from 'lghcc-decoder';
import { gsplatData } from './gsplat-data.mjs';

export { gsplatData };
export { LghccStream } from './stream.mjs';

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
