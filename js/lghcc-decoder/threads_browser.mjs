// Helper threads in browsers (and other runtimes with Web Workers): module workers of helper.mjs.
// The `new Worker(new URL(...), {type: 'module'})` form is the one bundlers (Vite, webpack 5,
// Parcel, esbuild with a plugin) recognise and bundle the worker script from; unbundled, helper.mjs
// is fetched from beside this file. index.mjs uses it; index_node.mjs uses threads_node.mjs.

/** Helpers a decode starts when the caller does not say: one per logical core. */
export function defaultWorkers() {
    return (typeof navigator !== 'undefined' && navigator.hardwareConcurrency) || 4;
}

/** A helper thread running helper.mjs (a Web Worker: postMessage, onmessage, onerror, terminate). */
export function startHelper() {
    return new Worker(new URL('./helper.mjs', import.meta.url), { type: 'module' });
}
