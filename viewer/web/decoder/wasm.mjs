// The WebAssembly part of the decoder (wasm/decoder.ts, built into wasm_module.mjs by
// tools/node/build-wasm.mjs): instantiated once per thread, synchronously (decoding runs in Node or
// in a Web Worker, where synchronous compilation of any size is allowed), with no imports.
import { DECODER_WASM_BASE64 } from './wasm_module.mjs';

let exports = null;

/** The module's exports (reset, alloc, decodeGeometry, ...; memory). */
export function wasm() {
    if (!exports) {
        const bytes = Uint8Array.from(atob(DECODER_WASM_BASE64), (c) => c.charCodeAt(0));
        exports = new WebAssembly.Instance(new WebAssembly.Module(bytes), {}).exports;
    }
    return exports;
}

/** Copy bytes into a fresh arena (the previous call's memory is released); returns their address. */
export function arenaWith(bytes) {
    const w = wasm();
    w.reset();
    const p = w.alloc(bytes.length);
    new Uint8Array(w.memory.buffer, p, bytes.length).set(bytes);
    return p;
}

/**
 * Run f() (a call into the module); a trap with an error code set (`fail` in decoder.ts) is
 * rethrown as describe(code, a, b), the spec's error.
 */
export function callWasm(f, describe) {
    const w = wasm();
    try {
        return f(w);
    } catch (e) {
        if (!(e instanceof WebAssembly.RuntimeError)) throw e;
        const code = w.errorCode();
        if (!code) throw e;
        throw describe(code, w.errorA(), w.errorB());
    }
}

/** A copy of n int32 at address p of the module's memory. */
export function int32Copy(p, n) {
    return new Int32Array(wasm().memory.buffer, p, n).slice();
}
