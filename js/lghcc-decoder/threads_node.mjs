// Helper threads in Node: worker_threads behind the Web Worker interface pool.mjs uses
// (postMessage, onmessage, onerror, terminate). index_node.mjs uses it (package.json's "node"
// condition); index.mjs uses threads_browser.mjs.
import { availableParallelism } from 'node:os';
import { Worker } from 'node:worker_threads';

/** Helpers a decode starts when the caller does not say: one per core Node may use. */
export function defaultWorkers() {
    return availableParallelism();
}

/** A helper thread running helper_node.mjs, as a Web Worker looks to pool.mjs. */
export function startHelper() {
    const thread = new Worker(new URL('./helper_node.mjs', import.meta.url));
    let stopped = false;
    const helper = {
        onmessage: null,
        onerror: null,
        postMessage: (message, transfer) => thread.postMessage(message, transfer),
        terminate: () => { stopped = true; thread.terminate(); },
    };
    const fail = (message) => { if (helper.onerror) helper.onerror({ message, preventDefault() {} }); };
    // messages already queued when it was terminated are not delivered (as a Web Worker's are not)
    thread.on('message', (data) => { if (!stopped && helper.onmessage) helper.onmessage({ data }); });
    thread.on('error', (err) => fail(err && err.message ? err.message : String(err)));
    // a thread that ends unasked (process.exit in it, out of memory) fails its tiles as an error would
    thread.on('exit', (code) => { if (!stopped) fail(`the helper thread exited with code ${code}`); });
    return helper;
}
