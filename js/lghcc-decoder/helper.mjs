// A helper thread of decode() in a browser: a module Web Worker (threads_browser.mjs starts it)
// that decodes the tiles the decoding thread hands it (pool.mjs's helperMessage).
import { helperMessage } from './pool.mjs';

self.onmessage = (e) => helperMessage(e.data, self);
