// Types of lghcc-decoder's public API (index.mjs). Hand-written; tests/test_js_package.py checks
// that every name and field declared here exists at run time, and no other.

/** What decode() reads: the stream's bytes, or where they come from. A string or URL is fetched with fetch(). */
export type LghccInput = Uint8Array | ArrayBufferView | ArrayBuffer | Blob | Response | ReadableStream<Uint8Array> | string | URL;

/** Passed to onProgress once per decoded tile, after its hash check. */
export interface LghccProgress {
    /** The tile's number in the stream (tiles finish in any order when decoded in parallel). */
    tile: number;
    /** Tiles decoded so far, this one included. */
    tilesDecoded: number;
    /** Tiles this decode decodes (all of the stream's, or those the box selects). */
    tilesTotal: number;
    /** Gaussians decoded so far. */
    pointsDecoded: number;
    /** Gaussians this decode gives (the scene's count). */
    pointsTotal: number;
}

export interface LghccDecodeOptions {
    /** Helper threads that decode the tiles (module Web Workers; worker_threads in Node); at most one per tile. 0: every tile decoded on the calling thread. Default: navigator.hardwareConcurrency, or os.availableParallelism() in Node. */
    workers?: number;
    /** Called once per decoded, hash-checked tile. */
    onProgress?: ((progress: LghccProgress) => void) | null;
    /** Aborting it stops reading, stops the helpers and rejects decode() with signal.reason. */
    signal?: AbortSignal | null;
    /** [x0, y0, z0, x1, y1, z1] in world coordinates: only the tiles whose cells meet the box are decoded. */
    box?: [number, number, number, number, number, number] | null;
    /** Bytes the decode may hold; a stream that declares more is refused with ResourceLimitError before anything is allocated. Default DEFAULT_MAX_MEMORY (2 GiB). */
    maxMemory?: number;
    /** false (default): the stored 3DGS parameters, bit for bit the reference decoder's. true: renderer values (opacity in [0, 1], linear scales, RGB colours, unit quaternions). */
    activated?: boolean;
}

/** An axis-aligned box: per axis x, y, z. */
export interface LghccBounds {
    min: [number, number, number];
    max: [number, number, number];
}

/** The decoded scene: count Gaussians, per-Gaussian values interleaved (Gaussian i's at [width * i, width * (i + 1))). */
export interface LghccScene {
    /** Number of Gaussians. */
    count: number;
    /** The scene's SH degree, 0 to 3. */
    shDegree: number;
    /** Tiles decoded. */
    tiles: number;
    /** The box around the Gaussians' centres; null when count is 0. */
    bounds: LghccBounds | null;
    /** 3 per Gaussian: x, y, z in world coordinates. */
    positions: Float32Array;
    /** 3 per Gaussian: log (natural) of the scale along the local x, y, z axes; activated: the scales themselves. */
    scales: Float32Array;
    /** 4 per Gaussian: quaternion w, x, y, z (any norm); activated: of unit norm. */
    rotations: Float32Array;
    /** 1 per Gaussian: opacity logit; activated: opacity in [0, 1]. */
    opacities: Float32Array;
    /** 3 per Gaussian: the SH DC coefficients of R, G, B; activated: colour R, G, B = 0.5 + SH_C0 * DC (not clamped). */
    colors: Float32Array;
    /** 3 * ((shDegree + 1)^2 - 1) per Gaussian: the SH coefficients above DC, coefficient-major, R, G, B inner (as SPZ). */
    sh: Float32Array;
}

/** Decode a .lghcc stream of the explicit-Gaussian profile. */
export function decode(input: LghccInput, options?: LghccDecodeOptions): Promise<LghccScene>;

/** Default maxMemory: 2^31 bytes. */
export const DEFAULT_MAX_MEMORY: number;
/** The zeroth-order SH basis constant (colour = 0.5 + SH_C0 * DC). */
export const SH_C0: number;

/** The base of the decoder's errors. */
export class LghccError extends Error {}
/** The stream is non-conforming (truncated, corrupted, or violating a constraint of the format). */
export class BitstreamError extends LghccError {}
/** A stream this decoder does not decode: another version, or outside the explicit-Gaussian profile (anchor streams, the hierarchy). */
export class UnsupportedStreamError extends BitstreamError {}
/** A tile's decoded Gaussians do not match the hash the stream carries for them. */
export class HashMismatchError extends BitstreamError {}
/** A conforming stream that needs more memory than maxMemory (or than WebAssembly addresses per tile). */
export class ResourceLimitError extends LghccError {}
