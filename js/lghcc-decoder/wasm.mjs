// The WebAssembly part of the decoder (wasm/decoder.ts, built into wasm_module.mjs by
// tools/node/build-wasm.mjs): instantiated once per thread, synchronously (decoding runs in Node or
// in a Web Worker, where synchronous compilation of any size is allowed), with no imports. The
// scale tables of clause 10.2 are copied into its memory once, below everything reset() releases.
import { ResourceLimitError } from './errors.mjs';
import { scaleTables } from './tables.mjs';
import { DECODER_WASM_BASE64 } from './wasm_module.mjs';

let module = null;
let exports = null;

/**
 * The compiled module (compiled once per thread, or adopted: a WebAssembly.Module posted to a
 * helper worker shares its compiled, and tiered-up, code instead of compiling it again).
 */
export function wasmModule() {
    if (!module) module = new WebAssembly.Module(wasmBytes());
    return module;
}

function wasmBytes() { return Uint8Array.from(atob(DECODER_WASM_BASE64), (c) => c.charCodeAt(0)); }

/**
 * Compile and instantiate the module asynchronously (once): a browser's main thread may refuse to
 * compile or instantiate a module of this size synchronously, as wasm() does. After it, wasm() and
 * wasmModule() return at once.
 */
export async function loadWasm() {
    if (exports) return;
    if (!module) module = await WebAssembly.compile(wasmBytes());
    const instance = await WebAssembly.instantiate(module, {});
    if (!exports) { // another caller may have instantiated it meanwhile
        exports = instance.exports;
        loadTables(exports);
    }
}

/** Use a module compiled by another thread (before the first wasm()). */
export function adoptWasmModule(m) { module = module || m; }

/** The module's exports (reset, alloc, decodeGeometry, ...; memory). */
export function wasm() {
    if (!exports) {
        exports = new WebAssembly.Instance(wasmModule(), {}).exports;
        loadTables(exports);
    }
    return exports;
}

const ERR_MEMORY = 9; // decoder.ts: linear memory could not grow

/** `bytes` of the module's arena, zeroed (or not: `zero` false, for bytes the caller overwrites); returns their address. */
export function alloc(w, bytes, zero = true) {
    if (!(bytes >= 0 && bytes < 2 ** 31)) throw new ResourceLimitError(`decoding needs ${bytes} bytes at once, beyond the 2 GiB the decoder's WebAssembly module addresses`);
    return callWasm(() => (zero ? w.alloc(bytes) : w.reserve(bytes)), () => null);
}

/** Copy arr (a typed array) into the module's arena; returns its address. */
export function copyIn(w, arr) {
    const p = alloc(w, Math.max(arr.byteLength, 1), false);
    new arr.constructor(w.memory.buffer, p, arr.length).set(arr);
    return p;
}

function loadTables(w) {
    const T = scaleTables();
    w.reset();
    const t = [T.levels.cum, T.levels.off, T.levels.lut, T.half, T.classes.cum, T.classes.off, T.classes.lut];
    w.setTables(...t.map((a) => copyIn(w, a)));
    w.crcTables();
    w.keep();
}

/** CRC-32 of bytes[start, end) by the module (crc32.mjs's crc32 of a fresh CRC), the bytes copied into a fresh arena. */
export function moduleCrc32(bytes, start, end) {
    const w = wasm();
    w.reset();
    const n = end - start, p = alloc(w, Math.max(n, 1), false);
    new Uint8Array(w.memory.buffer, p, n).set(bytes.subarray(start, end));
    return w.crc32(p, n) >>> 0;
}

/** Copy bytes into a fresh arena (the previous call's memory is released); returns their address. */
export function arenaWith(bytes) {
    const w = wasm();
    w.reset();
    const p = alloc(w, bytes.length, false);
    new Uint8Array(w.memory.buffer, p, bytes.length).set(bytes);
    return p;
}

/**
 * Run f() (a call into the module); a trap with an error code set (`fail` in decoder.ts) is
 * rethrown as describe(code, a, b), the spec's error (ResourceLimitError when memory ran out).
 */
export function callWasm(f, describe) {
    const w = wasm();
    try {
        return f(w);
    } catch (e) {
        if (!(e instanceof WebAssembly.RuntimeError)) throw e;
        const code = w.errorCode();
        if (!code) throw e;
        if (code === ERR_MEMORY) throw new ResourceLimitError(`decoding needs more WebAssembly memory than this runtime gives (${Math.round(w.memory.buffer.byteLength / 2 ** 20)} MiB in use)`);
        throw describe(code, w.errorA(), w.errorB());
    }
}

/** A copy of n int32 at address p of the module's memory. */
export function int32Copy(p, n) {
    return new Int32Array(wasm().memory.buffer, p, n).slice();
}
