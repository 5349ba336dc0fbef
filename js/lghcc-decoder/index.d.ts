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

/** A plane [a, b, c, d] of a frustum: inside where a·x + b·y + c·z + d >= 0 (world coordinates of the stream). */
export type LghccPlane = [number, number, number, number];

/** What stream() knows once the tile index is in, before any tile is fetched (the camera and frustum functions get it). */
export interface LghccStreamIndex {
    /** Tiles in the stream. */
    tiles: number;
    /** Gaussians in the stream (all tiles). */
    count: number;
    /** The scene's SH degree, 0 to 3. */
    shDegree: number;
    /** The box of every tile's cell in world coordinates (holds every Gaussian); null for a stream without tiles. */
    bounds: LghccBounds | null;
}

/** One decoded tile, handed to onTile: its Gaussians in the layout of LghccScene (views of the scene's arrays). */
export interface LghccTile {
    /** The tile's number in the stream. */
    tile: number;
    /** Its first Gaussian in the streamed scene (stream order). */
    offset: number;
    /** Its Gaussians. */
    count: number;
    /** The scene's SH degree. */
    shDegree: number;
    /** The box around its Gaussians' centres; null when count is 0. */
    bounds: LghccBounds | null;
    positions: Float32Array;
    scales: Float32Array;
    rotations: Float32Array;
    opacities: Float32Array;
    colors: Float32Array;
    sh: Float32Array;
}

export interface LghccStreamOptions {
    /** As decode()'s. */
    workers?: number;
    /** As decode()'s: once per decoded tile. */
    onProgress?: ((progress: LghccProgress) => void) | null;
    /** Each tile as soon as it is decoded and hash-checked, in the order they finish. */
    onTile?: ((tile: LghccTile) => void) | null;
    /** A note on how the file is read (a server without Range support); default console.warn. */
    onNote?: ((note: string) => void) | null;
    /** Aborting it cancels the requests, stops the helpers and rejects stream() with signal.reason. */
    signal?: AbortSignal | null;
    /** [x0, y0, z0, x1, y1, z1] in world coordinates: only the tiles whose cells meet the box are fetched. */
    box?: [number, number, number, number, number, number] | null;
    /** Only the tiles whose cells meet every plane's inside are fetched (frustumPlanes() makes them); or a function of the index giving them (null: none). */
    frustum?: LghccPlane[] | ((index: LghccStreamIndex) => LghccPlane[] | null) | null;
    /** The camera position in world coordinates: the tiles nearest it are fetched first; or a function of the index giving it (frame the camera there). */
    camera?: [number, number, number] | ((index: LghccStreamIndex) => [number, number, number] | null) | null;
    /** As decode()'s. */
    maxMemory?: number;
    /** As decode()'s. */
    activated?: boolean;
    /** Request headers sent with every request (Range is added). */
    headers?: Record<string, string>;
    /** fetch()'s credentials mode. Default 'same-origin'. */
    credentials?: RequestCredentials;
    /** Bytes of the first request (header, prelude and tile index; more are fetched when the prelude is longer). Default 8192. */
    headBytes?: number;
    /** Requests in flight at once. Default 2. */
    connections?: number;
}

/** stream()'s result: the scene of the fetched tiles in stream order, and how it was fetched. */
export interface LghccStreamResult extends LghccScene {
    /** True when the tiles were fetched by Range requests; false when the server answered the whole file (200). */
    ranged: boolean;
    /** HTTP requests made. */
    requests: number;
    /** Body bytes received. */
    bytesFetched: number;
    /** The file's size (Content-Range), or null when the server did not say. */
    bytesTotal: number | null;
}

/**
 * Stream a .lghcc file from a URL by tiles with HTTP Range requests: the header, the prelude and the
 * tile index first, then the tiles the box and the frustum meet, nearest the camera first, each
 * decoded as it arrives and handed to onTile.
 */
export function stream(url: string | URL, options?: LghccStreamOptions): Promise<LghccStreamResult>;

/** A frustum's six planes from a column-major 4x4 view-projection matrix (WebGL clip space): the planes stream()'s frustum takes. */
export function frustumPlanes(matrix: ArrayLike<number>): LghccPlane[];

/**
 * Tiles handed on in batches that grow (for a loader making one engine object per batch): push() each
 * tile of stream()'s onTile; the first goes to onBatch at once, the next batches delay, 2 delay, 4 delay ...
 * (at most maxDelay) ms apart; flush() hands on what is queued now.
 */
export class TileBatcher {
    constructor(onBatch: (tiles: LghccTile[]) => void, options?: { delay?: number; maxDelay?: number });
    push(tile: LghccTile): void;
    flush(): void;
}

/** Default maxMemory: 2^31 bytes. */
export const DEFAULT_MAX_MEMORY: number;
/** The zeroth-order SH basis constant (colour = 0.5 + SH_C0 * DC). */
export const SH_C0: number;

/** The base of the decoder's errors. */
export class LghccError extends Error {}
/** The stream is non-conforming (truncated, corrupted, or violating a constraint of the format). */
export class BitstreamError extends LghccError {
    constructor(message?: string, condition?: string);
    /** The row of the spec's clause 8.2 the stream breaks ('E1' .. 'E68'); undefined for a stream outside the profile. */
    readonly condition: string | undefined;
}
/** A stream this decoder does not decode: another version, or outside the explicit-Gaussian profile (anchor streams, the hierarchy). */
export class UnsupportedStreamError extends BitstreamError {}
/** A tile's decoded Gaussians do not match the hash the stream carries for them. */
export class HashMismatchError extends BitstreamError {}
/** A conforming stream that needs more memory than maxMemory (or than WebAssembly addresses per tile). */
export class ResourceLimitError extends LghccError {}
