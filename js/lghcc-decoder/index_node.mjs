// lghcc-decoder in Node (package.json's "node" condition; README.md): decode() with worker threads
// as its helpers. index.mjs is the same API with module Web Workers.
import { decodeWith, SH_C0 } from './decode.mjs';
import { streamWith } from './stream.mjs';
export { frustumPlanes, TileBatcher } from './stream.mjs';
import * as threads from './threads_node.mjs';
import './sha256_node.mjs'; // node:crypto's hash for the tiles' checks

export { BitstreamError, HashMismatchError, LghccError, ResourceLimitError, UnsupportedStreamError } from './errors.mjs';
export { DEFAULT_MAX_MEMORY } from './decoder.mjs';
export { SH_C0 };

/** Decode a .lghcc stream (README.md; index.d.ts). */
export function decode(input, options) { return decodeWith(threads, input, options); }

/** Stream a .lghcc file from a URL by tiles with HTTP Range requests (README.md; index.d.ts). */
export function stream(url, options) { return streamWith(threads, url, options); }
