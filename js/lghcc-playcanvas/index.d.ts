// Types of lghcc-playcanvas's public API (index.mjs). Hand-written.
import type { AppBase, Asset, GSplatResource, ResourceHandler } from 'playcanvas';

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
