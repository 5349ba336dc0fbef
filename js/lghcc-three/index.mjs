// lghcc-three: .lghcc scenes (LG-HCC compressed 3D Gaussian Splatting) for three.js with Spark
// (@sparkjsdev/spark). LghccLoader is a three.js Loader, as Spark's SplatLoader is: it gives a
// PackedSplats that a SplatMesh draws; packedSplats() converts a scene decoded by lghcc-decoder;
// LghccStream is a Group that streams a file by tiles (HTTP Range requests), a SplatMesh per tile.
import { Group, Loader, Matrix4, Vector3 } from 'three';
import { PackedSplats, SplatMesh, defines, utils } from '@sparkjsdev/spark';
import { TileBatcher, decode, frustumPlanes, stream } from 'lghcc-decoder';

// coefficients per colour channel of SH bands 1, 2, 3, and the uint32 words Spark packs each band in
const BAND_COEFFS = [3, 5, 7];
const BAND_WORDS = [2, 4, 4];
const ENCODE_BAND = [utils.encodeSh1Rgb, utils.encodeSh2Rgb, utils.encodeSh3Rgb];

/**
 * Spark's PackedSplats of a scene decoded with `activated: true` (linear scales, opacity in [0, 1],
 * RGB colours, unit quaternions w, x, y, z): Spark's 16-byte splats (half-float centres, 8-bit
 * colour and opacity, log-encoded scales, 24-bit quaternions) and its SH textures, in Spark's
 * default encoding, the one its own .spz and .ply loading uses (colours clamped to [0, 1], SH
 * coefficients to [-1, 1]): a SplatMesh made with `{packedSplats}` alone decodes them right.
 */
export function packedSplats(scene) {
    const n = scene.count;
    if (scene.opacities?.length !== n) throw new TypeError('packedSplats: not an LghccScene');
    if (scene.opacities.some((a) => !(a >= 0 && a <= 1))) {
        throw new RangeError('packedSplats: opacities outside [0, 1]: decode the scene with {activated: true}');
    }
    const { positions: p, scales: s, rotations: q, opacities: a, colors: c, sh } = scene;
    const { maxSplats } = utils.getTextureSize(n);
    const splatEncoding = { ...defines.DEFAULT_SPLAT_ENCODING };
    const packedArray = new Uint32Array(4 * maxSplats);
    for (let i = 0; i < n; i++) {
        utils.setPackedSplat(packedArray, i, p[3 * i], p[3 * i + 1], p[3 * i + 2], s[3 * i], s[3 * i + 1], s[3 * i + 2],
            q[4 * i + 1], q[4 * i + 2], q[4 * i + 3], q[4 * i], a[i], c[3 * i], c[3 * i + 1], c[3 * i + 2], splatEncoding);
    }
    // SH bands 1 to 3: the decoder's coefficient-major, R, G, B inner order is Spark's too
    const extra = {};
    const perGaussian = n ? sh.length / n : 0;  // 3 * ((d + 1)^2 - 1)
    for (let band = 0, offset = 0; band < 3 && offset < perGaussian; offset += 3 * BAND_COEFFS[band], band++) {
        const width = 3 * BAND_COEFFS[band];
        const words = new Uint32Array(BAND_WORDS[band] * maxSplats);
        for (let i = 0; i < n; i++) {
            const start = perGaussian * i + offset;
            ENCODE_BAND[band](words, i, sh.subarray(start, start + width), splatEncoding);
        }
        extra[`sh${band + 1}`] = words;
    }
    return new PackedSplats({ packedArray, numSplats: n, extra, splatEncoding });
}

function progressEvent(p) {
    const init = { lengthComputable: true, loaded: p.pointsDecoded, total: p.pointsTotal };
    return typeof ProgressEvent === 'function' ? new ProgressEvent('progress', init) : init;
}

/**
 * A three.js Loader of .lghcc files into Spark's PackedSplats:
 *
 *     const splats = await new LghccLoader().loadAsync('scene.lghcc');
 *     scene.add(new SplatMesh({ packedSplats: splats }));
 *
 * The file is fetched (the loader's path, request header and withCredentials apply, and its
 * LoadingManager is told) and decoded as it arrives, the tiles of a tiled stream in parallel
 * helper workers, each tile's hash checked. onProgress gets a ProgressEvent per decoded tile,
 * counting Gaussians; a stream the decoder refuses rejects with the decoder's error
 * (UnsupportedStreamError, BitstreamError, ...).
 */
export class LghccLoader extends Loader {
    constructor(manager) {
        super(manager);
        this.decodeOptions = {};
    }

    /** decode()'s `workers`, `box`, `maxMemory` and `signal` for the loads that follow. */
    setDecodeOptions(options) {
        this.decodeOptions = { ...options };
        return this;
    }

    load(url, onLoad, onProgress, onError) {
        const resolved = this.manager.resolveURL(this.path + url);
        this.manager.itemStart(resolved);
        fetch(resolved, {
            headers: this.requestHeader, credentials: this.withCredentials ? 'include' : 'same-origin',
            signal: this.decodeOptions.signal
        })
            .then((response) => {
                if (!response.ok) throw new Error(`${resolved}: HTTP ${response.status}`);
                return this.parseAsync(response, onProgress);
            })
            .then((splats) => {
                onLoad?.(splats);
                this.manager.itemEnd(resolved);
            }, (err) => {
                if (onError) onError(err); else console.error(err);
                this.manager.itemError(resolved);
                this.manager.itemEnd(resolved);
            });
    }

    /** The PackedSplats of a stream already at hand: any input decode() takes (bytes, Blob, Response, ...). */
    async parseAsync(input, onProgress) {
        const scene = await decode(input, {
            ...this.decodeOptions, activated: true,
            onProgress: onProgress ? (p) => onProgress(progressEvent(p)) : null
        });
        return packedSplats(scene);
    }
}

/**
 * A three.js Group that streams a .lghcc file by tiles (lghcc-decoder's stream(): HTTP Range
 * requests, the tiles nearest the camera first, a box or the camera's frustum limiting what is
 * fetched) and draws the tiles as they are decoded: a SplatMesh per batch of tiles is added to the group.
 *
 *     const splats = new LghccStream('scene.lghcc', { camera });
 *     splats.quaternion.set(1, 0, 0, 0);   // placed before the tiles are chosen (see onIndex)
 *     scene.add(splats);
 *     await splats.loaded;
 *
 * options: camera (a THREE.Camera: the tiles nearest it first; its position, and with cull: true its
 * frustum, taken in the group's coordinates once the tile index is in, after onIndex), cull, box
 * ([x0, y0, z0, x1, y1, z1] in the stream's coordinates), onIndex(index, group) (the index before any
 * tile is fetched: {tiles, count, shDegree, bounds of the cells in the stream's coordinates}: frame the
 * camera here), onProgress(ProgressEvent), workers, maxMemory, signal, headers, credentials.
 * Events: 'tiles' ({tiles: tile numbers, count, mesh}) per SplatMesh added (a batch of tiles: the
 * first tile alone, at once), 'loaded' ({result}) at the end, 'error' ({error}).
 */
export class LghccStream extends Group {
    constructor(url, options = {}) {
        super();
        const { camera = null, cull = false, onIndex = null, onProgress = null, signal = null, ...rest } = options;
        if (cull && !camera) throw new TypeError('LghccStream: cull needs a camera');
        this.url = url;
        this.count = 0; // Gaussians drawn so far
        // a SplatMesh per batch of tiles: Spark generates every splat of the scene again when a mesh is
        // added (with a software renderer that costs as much as the first draw, and slows the transfer it
        // competes with), so the batches grow: the first tile at once, then 250 ms, 500 ms, 1 s ... (at most 8 s) apart
        this.batcher = new TileBatcher((tiles) => this._add(tiles));
        this.abortController = new AbortController();
        if (signal) signal.addEventListener('abort', () => this.abortController.abort(signal.reason), { once: true });
        const atIndex = (index) => {
            if (onIndex) onIndex(index, this);
            return camera ? this._local(camera) : null;
        };
        this.loaded = stream(url, {
            ...withoutUndefined(rest), activated: true, signal: this.abortController.signal,
            camera: camera || onIndex ? atIndex : null,
            frustum: cull ? () => this._frustum(camera) : null,
            onTile: (tile) => this.batcher.push(tile),
            onProgress: onProgress ? (p) => onProgress(progressEvent(p)) : null,
        }).then((scene) => {
            this.batcher.flush(); // the tiles still queued drawn now
            const result = { count: scene.count, tiles: scene.tiles, bounds: scene.bounds, ranged: scene.ranged, requests: scene.requests, bytesFetched: scene.bytesFetched, bytesTotal: scene.bytesTotal };
            this.dispatchEvent({ type: 'loaded', result });
            return result;
        }, (error) => {
            this.dispatchEvent({ type: 'error', error });
            throw error;
        });
    }

    /** Stop streaming (the promise `loaded` rejects with reason); the tiles drawn so far stay. */
    abort(reason) {
        this.abortController.abort(reason);
    }

    _add(tiles) {
        const mesh = new SplatMesh({ packedSplats: packedSplats(joined(tiles)) });
        this.add(mesh);
        const count = tiles.reduce((n, t) => n + t.count, 0);
        this.count += count;
        this.dispatchEvent({ type: 'tiles', tiles: tiles.map((t) => t.tile), count, mesh });
    }

    // the camera's position in the group's (the stream's) coordinates
    _local(camera) {
        this.updateWorldMatrix(true, false);
        camera.updateWorldMatrix(true, false);
        const p = camera.getWorldPosition(new Vector3()).applyMatrix4(new Matrix4().copy(this.matrixWorld).invert());
        return [p.x, p.y, p.z];
    }

    // the camera's frustum in the group's coordinates: planes [a, b, c, d], inside where a·x + b·y + c·z + d >= 0
    _frustum(camera) {
        this.updateWorldMatrix(true, false);
        camera.updateWorldMatrix(true, false);
        const m = new Matrix4().multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse).multiply(this.matrixWorld);
        return frustumPlanes(m.elements);
    }
}

// the tiles' Gaussians as one scene (packedSplats() takes it)
function joined(tiles) {
    if (tiles.length === 1) return tiles[0];
    const out = { count: tiles.reduce((n, t) => n + t.count, 0) };
    for (const k of ['positions', 'scales', 'rotations', 'opacities', 'colors', 'sh']) {
        out[k] = new Float32Array(tiles.reduce((n, t) => n + t[k].length, 0));
        let at = 0;
        for (const t of tiles) { out[k].set(t[k], at); at += t[k].length; }
    }
    return out;
}

function withoutUndefined(o) {
    return Object.fromEntries(Object.entries(o).filter(([, v]) => v !== undefined));
}
