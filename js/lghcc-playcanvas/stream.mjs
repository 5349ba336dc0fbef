// lghcc-playcanvas/stream: a .lghcc file streamed by tiles into a PlayCanvas entity (lghcc-decoder's
// stream(): HTTP Range requests, the tiles nearest the camera first), a gsplat child entity per batch
// of decoded tiles (the first at once), so that the engine draws before the last byte has arrived.
import { Entity, EventHandler, GSplatResource, Mat4, Vec3, http } from 'playcanvas';
import { TileBatcher, frustumPlanes, stream } from 'lghcc-decoder';
import { gsplatData } from './gsplat-data.mjs';

/**
 * Stream url into `entity` (a new Entity named 'lghcc', to be added to the scene and placed by the
 * application before the tile index arrives: onIndex is the last moment):
 *
 *     const s = new LghccStream(app, 'scene.lghcc', { camera });
 *     s.entity.setLocalEulerAngles(180, 0, 0);
 *     app.root.addChild(s.entity);
 *     await s.loaded;
 *
 * options: camera (an Entity with a camera component: the tiles nearest it first; with cull: true
 * only those in its frustum), box ([x0, y0, z0, x1, y1, z1] in the stream's coordinates), onIndex(index,
 * entity) ({tiles, count, shDegree, bounds of the cells in the stream's coordinates}, before any tile is
 * fetched: frame the camera here), workers, maxMemory, signal, headers, unified (the gsplat
 * components' unified mode: one sort of every tile), reorder (false: keep the stream's order in a tile).
 * Events (stream.on): 'tiles' (tile numbers, count, entity) per gsplat entity added (a batch of
 * tiles: the first tile alone, at once), 'progress' (pointsDecoded, pointsTotal), 'loaded' (result), 'error' (err).
 */
export class LghccStream extends EventHandler {
    constructor(app, url, options = {}) {
        super();
        const { camera = null, cull = false, onIndex = null, signal = null, unified = false, reorder = true, ...rest } = options;
        if (cull && !camera) throw new TypeError('LghccStream: cull needs a camera');
        this.app = app;
        this.url = url;
        this.entity = new Entity('lghcc');
        this.count = 0; // Gaussians drawn so far
        // a gsplat entity per batch of tiles, each with its own resource and sort: the first tile at
        // once, then batches 250 ms, 500 ms, 1 s ... (at most 8 s) apart (few entities and sorts, the near tiles early)
        this.batcher = new TileBatcher((tiles) => this._add(tiles));
        this.unified = unified;
        this.reorder = reorder;
        this.abortController = new AbortController();
        if (signal) signal.addEventListener('abort', () => this.abortController.abort(signal.reason), { once: true });
        const atIndex = (index) => {
            if (onIndex) onIndex(index, this.entity);
            return camera ? this._local(camera) : null;
        };
        this.loaded = stream(url, {
            credentials: http.withCredentials ? 'include' : 'same-origin',
            ...Object.fromEntries(Object.entries(rest).filter(([, v]) => v !== undefined)),
            signal: this.abortController.signal,
            camera: camera || onIndex ? atIndex : null,
            frustum: cull ? () => this._frustum(camera) : null,
            onTile: (tile) => this.batcher.push(tile),
            onProgress: (p) => this.fire('progress', p.pointsDecoded, p.pointsTotal),
        }).then((scene) => {
            this.batcher.flush(); // the tiles still queued added now
            const result = { count: scene.count, tiles: scene.tiles, bounds: scene.bounds, ranged: scene.ranged, requests: scene.requests, bytesFetched: scene.bytesFetched, bytesTotal: scene.bytesTotal };
            this.fire('loaded', result);
            return result;
        }, (err) => {
            this.fire('error', err);
            throw err;
        });
    }

    /** Stop streaming (the promise `loaded` rejects with reason); the tiles drawn so far stay. */
    abort(reason) {
        this.abortController.abort(reason);
    }

    _add(tiles) {
        const data = gsplatData(tiles);
        if (this.reorder) data.reorderData();
        const prepareCenters = this.app.scene?.gsplatCentersEnabled !== false;
        const child = new Entity(`tiles ${tiles.map((t) => t.tile).join(',')}`);
        child.addComponent('gsplat', { resource: new GSplatResource(this.app.graphicsDevice, data, { prepareCenters }), unified: this.unified });
        this.entity.addChild(child);
        const count = tiles.reduce((n, t) => n + t.count, 0);
        this.count += count;
        this.fire('tiles', tiles.map((t) => t.tile), count, child);
    }

    // the camera's position in the entity's (the stream's) coordinates
    _local(camera) {
        const inverse = new Mat4().copy(this.entity.getWorldTransform()).invert();
        const p = inverse.transformPoint(camera.getPosition(), new Vec3());
        return [p.x, p.y, p.z];
    }

    // the camera's frustum in the entity's coordinates (lghcc-decoder's frustumPlanes)
    _frustum(camera) {
        const c = camera.camera;
        const m = new Mat4().mul2(c.projectionMatrix, c.viewMatrix).mul(this.entity.getWorldTransform());
        return frustumPlanes(m.data);
    }
}
