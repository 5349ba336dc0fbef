// Build lghcc-view's JavaScript bundle (run by `make viewer-bundle`, i.e. at set-up time):
// viewer/web/viewer.mjs with the pinned PlayCanvas engine -> viewer/assets/lghcc-viewer.js,
// one minified IIFE that every page inlines. The engine's MIT licence heads the bundle.
import { build } from 'esbuild';
import { readFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const here = dirname(fileURLToPath(import.meta.url));
const root = join(here, '..', '..');
const engine = JSON.parse(readFileSync(join(here, 'node_modules', 'playcanvas', 'package.json'), 'utf8'));
const licence = readFileSync(join(here, 'node_modules', 'playcanvas', 'LICENSE'), 'utf8').trim();
const banner = `/*! lghcc-view bundle: viewer/web/viewer.mjs + PlayCanvas engine ${engine.version} (${engine.license}).\n` +
    `${licence.replace(/\*\//g, '* /')}\n*/`;

await build({
    entryPoints: [join(root, 'viewer', 'web', 'viewer.mjs')],
    outfile: join(root, 'viewer', 'assets', 'lghcc-viewer.js'),
    // the engine from tools/node; lghcc-playcanvas (its gsplatData) from js/, as an application that installed it
    nodePaths: [join(here, 'node_modules'), join(root, 'js')],
    bundle: true,
    minify: true,
    format: 'iife',
    target: 'es2020',
    legalComments: 'eof',
    banner: { js: banner },
    logLevel: 'warning',
});
// the stream decoder's Web Worker: the npm package lghcc-decoder's `lghcc-decoder/worker` (js/lghcc-decoder,
// resolved by its package.json's exports, as an application that installed it would), inlined into
// every page as text and started from a blob: URL, so that pages decode their .lghcc stream off the main thread
await build({
    entryPoints: ['lghcc-decoder/worker'],
    nodePaths: [join(root, 'js')],
    outfile: join(root, 'viewer', 'assets', 'lghcc-decoder-worker.js'),
    bundle: true,
    minify: true,
    format: 'iife',
    target: 'es2020',
    logLevel: 'warning',
});
console.log(`built viewer/assets/lghcc-viewer.js with playcanvas ${engine.version} and viewer/assets/lghcc-decoder-worker.js`);
