// Types of lghcc-three's public API (index.mjs). Hand-written.
import type { Camera, Group, Loader, LoadingManager, Object3DEventMap } from 'three';
import type { PackedSplats, SplatMesh } from '@sparkjsdev/spark';
import type { LghccBounds, LghccInput, LghccScene, LghccStreamIndex } from 'lghcc-decoder';

/** decode()'s options (lghcc-decoder) a loader passes on; `activated` is always true here. */
export interface LghccLoaderDecodeOptions {
    /** Helper workers decoding the tiles; 0: on the page's thread. Default: navigator.hardwareConcurrency. */
    workers?: number;
    /** [x0, y0, z0, x1, y1, z1]: decode only the tiles meeting the box. */
    box?: [number, number, number, number, number, number] | null;
    /** Bytes a decode may hold; a stream declaring more is refused with ResourceLimitError. Default 2 GiB. */
    maxMemory?: number;
    /** Aborting it stops the fetch and the decode; the load rejects with signal.reason. */
    signal?: AbortSignal | null;
}

/** Spark's PackedSplats (default encoding, SH bands as textures) of a scene decoded with `activated: true`. */
export function packedSplats(scene: LghccScene): PackedSplats;

/** A three.js Loader of .lghcc files into Spark's PackedSplats: `new SplatMesh({ packedSplats: await new LghccLoader().loadAsync(url) })`. */
export class LghccLoader extends Loader<PackedSplats> {
    constructor(manager?: LoadingManager);
    decodeOptions: LghccLoaderDecodeOptions;
    /** Options for the loads that follow; returns the loader. */
    setDecodeOptions(options: LghccLoaderDecodeOptions): this;
    /** onProgress: once per decoded tile, loaded and total counting Gaussians. */
    load(url: string, onLoad?: (splats: PackedSplats) => void, onProgress?: (event: ProgressEvent) => void, onError?: (err: unknown) => void): void;
    /** The PackedSplats of a stream already at hand (any input decode() takes). */
    parseAsync(input: LghccInput, onProgress?: (event: ProgressEvent) => void): Promise<PackedSplats>;
}

/** Options of an LghccStream. */
export interface LghccStreamOptions {
    /** The tiles nearest this camera are fetched first (its position in the group's coordinates once the tile index is in, after onIndex). */
    camera?: Camera | null;
    /** With a camera: only the tiles whose cells meet its frustum are fetched. */
    cull?: boolean;
    /** [x0, y0, z0, x1, y1, z1] in the stream's coordinates: only the tiles meeting it are fetched. */
    box?: [number, number, number, number, number, number] | null;
    /** The tile index is in, no tile fetched yet: place the group and frame the camera here. */
    onIndex?: ((index: LghccStreamIndex, group: LghccStream) => void) | null;
    /** Once per decoded tile; loaded and total count Gaussians. */
    onProgress?: ((event: ProgressEvent) => void) | null;
    /** Helper workers decoding the tiles. Default: navigator.hardwareConcurrency. */
    workers?: number;
    /** Bytes a decode may hold. Default 2 GiB. */
    maxMemory?: number;
    /** Aborting it stops the streaming. */
    signal?: AbortSignal | null;
    /** Request headers of every request. */
    headers?: Record<string, string>;
    /** fetch()'s credentials mode. */
    credentials?: RequestCredentials;
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

export interface LghccStreamEventMap extends Object3DEventMap {
    tiles: { tiles: number[]; count: number; mesh: SplatMesh };
    loaded: { result: LghccStreamLoaded };
    error: { error: unknown };
}

/** A Group that streams a .lghcc file by tiles (HTTP Range requests), a SplatMesh per batch of decoded tiles (the first tile alone, at once; then batches 250 ms, 500 ms, ... up to 8 s apart). */
export class LghccStream extends Group<LghccStreamEventMap> {
    constructor(url: string | URL, options?: LghccStreamOptions);
    url: string | URL;
    /** Gaussians drawn so far. */
    count: number;
    /** Resolves once every chosen tile is drawn; rejects with the decoder's error or the abort reason. */
    loaded: Promise<LghccStreamLoaded>;
    /** Stop streaming; the tiles drawn stay. */
    abort(reason?: unknown): void;
}
