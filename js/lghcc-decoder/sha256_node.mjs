// Node's native SHA-256 for the tiles' hash checks (imported for its effect by the Node entry points:
// index_node.mjs, helper_node.mjs, cli.mjs, the conformance and bench scripts). Synchronous and over
// the caller's bytes where they lie, a view of the WebAssembly module's memory: Web Crypto's digest
// copies them first, and the copy of a 21 MB tile serialization cost the decoding thread more than
// node:crypto's whole hash (tools/results/js_decoder.md, "Round 11").
import { createHash } from 'node:crypto';
import { useSyncSha256 } from './sha256.mjs';

useSyncSha256((bytes) => createHash('sha256').update(bytes).digest());
