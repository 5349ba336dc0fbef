// lghcc-decoder in browsers (and every runtime but Node; README.md): decode() with module Web
// Workers as its helpers. index_node.mjs is the same API with Node's worker threads.
import { decodeWith, SH_C0 } from './decode.mjs';
import { streamWith } from './stream.mjs';
export { frustumPlanes, TileBatcher } from './stream.mjs';
import * as threads from './threads_browser.mjs';

export { BitstreamError, HashMismatchError, LghccError, ResourceLimitError, UnsupportedStreamError } from './errors.mjs';
export { DEFAULT_MAX_MEMORY } from './decoder.mjs';
export { SH_C0 };

/** Decode a .lghcc stream (README.md; index.d.ts). */
export function decode(input, options) { return decodeWith(threads, input, options); }

/** Stream a .lghcc file from a URL by tiles with HTTP Range requests (README.md; index.d.ts). */
export function stream(url, options) { return streamWith(threads, url, options); }
