// A helper thread of decode() (index.mjs): decodes the tiles the decoding thread hands it
// (pool.mjs's helperMessage), in a module Web Worker or a Node worker thread (#threads).
import { helperMessage } from './pool.mjs';
import { hostPort } from '#threads';

hostPort.listen((data) => helperMessage(data, hostPort));
