// Types of lghcc-three's public API (index.mjs). Hand-written.
import type { Loader, LoadingManager } from 'three';
import type { PackedSplats } from '@sparkjsdev/spark';
import type { LghccInput, LghccScene } from 'lghcc-decoder';

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
