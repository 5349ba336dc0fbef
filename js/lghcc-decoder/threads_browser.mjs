// Helper threads in browsers (and other runtimes with Web Workers): module workers of helper.mjs.
// The `new Worker(new URL(...), {type: 'module'})` form is the one bundlers (Vite, webpack 5,
// esbuild with its plugins, Parcel) recognise and bundle the worker script from. package.json's
// "imports" picks this file, or threads_node.mjs under Node, as '#threads'.

/** Helpers a decode starts when the caller does not say: one per logical core. */
export function defaultWorkers() {
    return (typeof navigator !== 'undefined' && navigator.hardwareConcurrency) || 4;
}

/** A helper thread running helper.mjs (a Web Worker: postMessage, onmessage, onerror, terminate). */
export function startHelper() {
    return new Worker(new URL('./helper.mjs', import.meta.url), { type: 'module' });
}

/** Inside a helper: the messages from the thread that started it, and the way back. */
export const hostPort = {
    listen(handle) { self.onmessage = (e) => handle(e.data); },
    postMessage(message, transfer) { self.postMessage(message, transfer); },
};
