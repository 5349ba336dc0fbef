// Types of lghcc-playcanvas's public API (index.mjs). Hand-written.
import type { AppBase, Asset, Entity, EventHandler, GSplatResource, ResourceHandler } from 'playcanvas';
import type { LghccBounds, LghccStreamIndex } from 'lghcc-decoder';

export { gsplatData, type LghccSplatArrays } from './gsplat-data.js';

/** Options of every .lghcc load by one parser: decode()'s (lghcc-decoder). */
export interface LghccParserOptions {
    /** Helper workers decoding the tiles; 0: on the page's thread. Default: navigator.hardwareConcurrency. */
    workers?: number;
    /** Bytes a decode may hold; a stream declaring more fails the asset with ResourceLimitError. Default 2 GiB. */
    maxMemory?: number;
}

/**
 * A parser of the engine's gsplat resource handler for .lghcc files:
 * `app.loader.getHandler('gsplat').addParser(new LghccParser(app))`, then
 * `new Asset(name, 'gsplat', { url: 'scene.lghcc' }, { box?, reorder? })` loads as a .ply does.
 */
export class LghccParser {
    constructor(app: AppBase, options?: LghccParserOptions);
    app: AppBase;
    options: LghccParserOptions;
    /** Set by ResourceHandler.addParser. */
    handler?: ResourceHandler;
    /** True for a URL ending in .lghcc (query string aside). */
    canParse(context: { url: string | null; ext: string; basename: string; asset: Asset | undefined; app: AppBase }): boolean;
    /**
     * Fetches (or takes asset.file.contents), decodes and calls back with a GSplatResource, or with the
     * decoder's error object (typed `any`: the engine's ResourceHandlerCallback says string, its own parsers pass errors too).
     */
    load(url: string | { load: string; original: string }, callback: (err: any, resource?: GSplatResource | null) => void, asset?: Asset): Promise<void>;
    open(url: string, data: GSplatResource): GSplatResource;
}

/** Options of an LghccStream. */
export interface LghccStreamOptions {
    /** An entity with a camera component: the tiles nearest it are fetched first (its position in the stream's coordinates once the tile index is in, after onIndex). */
    camera?: Entity | null;
    /** With a camera: only the tiles whose cells meet its frustum are fetched. */
    cull?: boolean;
    /** [x0, y0, z0, x1, y1, z1] in the stream's coordinates: only the tiles meeting it are fetched. */
    box?: [number, number, number, number, number, number] | null;
    /** The tile index is in, no tile fetched yet: place the entity and frame the camera here. */
    onIndex?: ((index: LghccStreamIndex, entity: Entity) => void) | null;
    /** Helper workers decoding the tiles. Default: navigator.hardwareConcurrency. */
    workers?: number;
    /** Bytes a decode may hold. Default 2 GiB. */
    maxMemory?: number;
    /** Aborting it stops the streaming. */
    signal?: AbortSignal | null;
    /** Request headers of every request. */
    headers?: Record<string, string>;
    /** The tiles' gsplat components in the engine's unified mode (one sort of all tiles). Default false. */
    unified?: boolean;
    /** false: keep the stream's order within a tile instead of the engine's Morton order. Default true. */
    reorder?: boolean;
}

/** What LghccStream.loaded resolves to. */
export interface LghccStreamLoaded {
    count: number;
    tiles: number;
    bounds: LghccBounds | null;
    ranged: boolean;
    requests: number;
    bytesFetched: number;
    bytesTotal: number | null;
}

/**
 * A .lghcc file streamed by tiles (HTTP Range requests) into `entity`, a gsplat child entity per batch
 * of decoded tiles (the first tile alone, at once; then batches 250 ms, 500 ms, ... up to 8 s apart).
 * Events: 'tiles' (tile numbers, count, entity), 'progress' (pointsDecoded, pointsTotal),
 * 'loaded' (result), 'error' (err).
 */
export class LghccStream extends EventHandler {
    constructor(app: AppBase, url: string | URL, options?: LghccStreamOptions);
    app: AppBase;
    url: string | URL;
    /** The entity the tiles are added to; add it to the scene. */
    entity: Entity;
    /** Gaussians drawn so far. */
    count: number;
    /** Resolves once every chosen tile is added; rejects with the decoder's error or the abort reason. */
    loaded: Promise<LghccStreamLoaded>;
    /** Stop streaming; the tiles added stay. */
    abort(reason?: unknown): void;
}
