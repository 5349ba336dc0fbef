// A helper thread of decode() in Node: a worker thread (threads_node.mjs starts it) that decodes
// the tiles the decoding thread hands it (pool.mjs's helperMessage).
import { parentPort } from 'node:worker_threads';
import { helperMessage } from './pool.mjs';
import './sha256_node.mjs'; // node:crypto's hash for the tiles' checks

parentPort.on('message', (data) => helperMessage(data, parentPort));
