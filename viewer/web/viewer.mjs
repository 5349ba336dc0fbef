// lghcc-view's page script: one or two Gaussian-splat panes (decoded, and the source beside it)
// rendered by the PlayCanvas engine (WebGL2), driven by ONE camera state so that the panes show
// the same view at every frame.
//
// Bundled with the pinned engine at set-up time (tools/node: `make viewer-bundle`), inlined into
// each page by lghcc.viewer.page; the page never reaches the network. The scenes arrive in the
// page as base64 3DGS PLYs (script elements `lghcc-ply-<pane>`) or as the .lghcc stream itself
// (`lghcc-stream-<pane>`: explicit-Gaussian streams, decoded in the page by js/lghcc-decoder in a
// Web Worker, whose bundle is the text of `lghcc-worker`, tile by tile, each tile's hash checked,
// the tiles of a tiled stream in parallel helper workers and drawn as they arrive; the renderer
// gets typed arrays, no PLY), the camera and settings as JSON (`lghcc-meta`). A
// .lghcc file dropped on the page, or named by #stream=URL (fetched as it arrives), is decoded the
// same way into the decoded pane.
//
// For tests and scripts, window.lghccViewer has:
//   ready          a Promise resolved once every pane has drawn a depth-sorted frame of its
//                  scene (or rejected with the load error); also `firstFrame` (bool) and `error`
//   setCamera({eye, target, up, fovX})  move every pane's camera (world coordinates, fovX in degrees)
//   settled()      a Promise resolved once every pane has drawn a sorted frame for the current camera
//   camera()       the current {eye, target, up, fovX}
//   paneRects()    [{name, x, width}]: each pane's part of the canvas #lghcc-canvas (CSS pixels)
//   state          frame and sort counters
//   decodes        per decoded stream: {pane, tiles, count, seconds, hashChecked} (or {pane, error})
//
// Rendering settings chosen to be the standard 3DGS image (what lghcc.render draws): colours
// blended as stored (3DGS colours are display values: GAMMA_SRGB with linear tone mapping makes
// the engine's decode-to-linear and encode-to-sRGB cancel, and blending happens on the stored
// values, as in 3DGS), every splat drawn however small
// (minPixelSize 0, minContribution 0, no splat budget), no anti-aliasing compensation, full-precision work
// buffer, SH colours re-evaluated after small camera moves.

import {
    Application, Asset, Color, Entity, FILLMODE_NONE, GAMMA_SRGB, GSPLATDATA_LARGE, GSplatResource, Layer,
    RESOLUTION_AUTO, TONEMAP_LINEAR, Vec3, Vec4
} from 'playcanvas';
import { gsplatData } from 'lghcc-playcanvas/gsplat-data';

const meta = JSON.parse(document.getElementById('lghcc-meta').textContent);

function base64Bytes(id) {
    const text = document.getElementById(id).textContent.replace(/\s+/g, '');
    if (Uint8Array.fromBase64) return Uint8Array.fromBase64(text);
    const bin = atob(text);
    const out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
}

// ---------------------------------------------------------------------------------------------
// The shared camera: eye, target, up (world), horizontal field of view in degrees.
// ---------------------------------------------------------------------------------------------

const v3 = (a) => new Vec3(a[0], a[1], a[2]);
const home = {
    eye: v3(meta.camera.eye), target: v3(meta.camera.target), up: v3(meta.camera.up).normalize(),
    fovX: meta.camera.fov_x_deg
};
const cam = { eye: home.eye.clone(), target: home.target.clone(), up: home.up.clone(), fovX: home.fovX, version: 0 };

function changed() {
    cam.version++;
    if (app) app.renderNextFrame = true;
}

function setCamera(c) {
    if (c.eye) cam.eye = v3(c.eye);
    if (c.target) cam.target = v3(c.target);
    if (c.up) cam.up = v3(c.up).normalize();
    if (c.fovX) cam.fovX = c.fovX;
    changed();
}

// orbit about the target: yaw about `up`, pitch about the camera's right axis (kept off the poles)
function orbit(dyaw, dpitch) {
    const off = new Vec3().sub2(cam.eye, cam.target);
    const r = off.length();
    const up = cam.up;
    let el = Math.asin(Math.max(-1, Math.min(1, off.dot(up) / r)));
    const horiz = new Vec3().copy(off).sub(new Vec3().copy(up).mulScalar(off.dot(up)));
    if (horiz.length() < 1e-9 * r) horiz.copy(Math.abs(up.x) < 0.9 ? Vec3.RIGHT : Vec3.UP);
    horiz.normalize();
    const side = new Vec3().cross(up, horiz).normalize();
    const az = dyaw;
    const h2 = new Vec3().copy(horiz).mulScalar(Math.cos(az)).add(new Vec3().copy(side).mulScalar(Math.sin(az)));
    el = Math.max(-1.5, Math.min(1.5, el + dpitch));
    cam.eye = new Vec3().copy(cam.target).add(h2.mulScalar(r * Math.cos(el))).add(new Vec3().copy(up).mulScalar(r * Math.sin(el)));
    changed();
}

function pan(dx, dy, paneHeight) {
    const fwd = new Vec3().sub2(cam.target, cam.eye);
    const r = fwd.length();
    fwd.normalize();
    const right = new Vec3().cross(fwd, cam.up).normalize();
    const camUp = new Vec3().cross(right, fwd).normalize();
    const s = 2 * r * Math.tan((cam.fovX * Math.PI / 180) / 2) / Math.max(paneHeight, 1);
    const d = right.mulScalar(-dx * s).add(camUp.mulScalar(dy * s));
    cam.eye.add(d);
    cam.target.add(d);
    changed();
}

function zoom(factor) {
    const off = new Vec3().sub2(cam.eye, cam.target).mulScalar(factor);
    cam.eye = new Vec3().add2(cam.target, off);
    changed();
}

function attachControls(canvas) {
    let last = null;
    canvas.addEventListener('contextmenu', (e) => e.preventDefault());
    canvas.addEventListener('pointerdown', (e) => {
        canvas.setPointerCapture(e.pointerId);
        last = { x: e.clientX, y: e.clientY, pan: e.button !== 0 || e.shiftKey };
    });
    canvas.addEventListener('pointermove', (e) => {
        if (!last) return;
        const dx = e.clientX - last.x, dy = e.clientY - last.y;
        if (last.pan) pan(dx, dy, canvas.clientHeight);
        else orbit(-dx * 0.008, dy * 0.008);
        last.x = e.clientX;
        last.y = e.clientY;
    });
    const end = () => { last = null; };
    canvas.addEventListener('pointerup', end);
    canvas.addEventListener('pointercancel', end);
    canvas.addEventListener('wheel', (e) => {
        e.preventDefault();
        zoom(Math.exp(e.deltaY * 0.001));
    }, { passive: false });
}

window.addEventListener('keydown', (e) => {
    if (e.key === 'r' || e.key === 'R') setCamera({ eye: [home.eye.x, home.eye.y, home.eye.z], target: [home.target.x, home.target.y, home.target.z] });
});

// ---------------------------------------------------------------------------------------------
// Panes: ONE engine application on one canvas, one camera and one layer per pane, the cameras'
// viewports side by side. (Two applications on one page do not work: with PlayCanvas 2.23 only
// the last one created ever draws its splats.)
// ---------------------------------------------------------------------------------------------

const GAP = 2;  // CSS pixels between panes (a divider drawn by the page)
const panes = [];
const canvas = document.getElementById('lghcc-canvas');
let app = null;
const state = { frames: 0, sorts: 0, loaded: 0, appliedVersion: -1, sortsAtApply: 0, framesAfterSort: 0, framesThisVersion: 0, readyVersion: -1 };

function layout() {
    // viewport of pane i: [x0, x1) of the canvas, in CSS pixels and as the camera's rect
    const w = canvas.clientWidth, n = panes.length;
    const pw = (w - GAP * (n - 1)) / n;
    panes.forEach((p, i) => {
        const x0 = i * (pw + GAP);
        p.x0 = x0;
        p.width = pw;
        p.camera.camera.rect = new Vec4(x0 / w, 0, pw / w, 1);
        const label = document.getElementById(`lghcc-label-${p.name}`);
        if (label) label.style.left = `${x0 + 8}px`;
        const div = document.getElementById(`lghcc-divider-${i}`);
        if (div) { div.style.left = `${x0 + pw}px`; div.style.width = `${GAP}px`; }
    });
}

function start() {
    app = new Application(canvas, { graphicsDeviceOptions: { antialias: false, alpha: false, powerPreference: 'high-performance' } });
    app.setCanvasFillMode(FILLMODE_NONE);
    app.setCanvasResolution(RESOLUTION_AUTO);
    app.graphicsDevice.maxPixelRatio = window.devicePixelRatio || 1;
    app.autoRender = false;  // draw on demand: after a camera move or when the engine asks
    const g = app.scene.gsplat;
    g.dataFormat = GSPLATDATA_LARGE;
    g.minPixelSize = 0;
    g.minContribution = 0;
    g.antiAlias = false;
    g.alphaClipForward = 1 / 255;
    g.colorUpdateAngle = 0.5;
    g.colorUpdateDistance = 0;
    g.splatBudget = 0;  // no budget: every splat, however many (the default budget is 1M)
    const bg = meta.background;
    const url = /[#&]stream=([^&]+)/.exec(location.hash);
    if (url || meta.panes.some((name) => document.getElementById(`lghcc-stream-${name}`))) decoderWorker(); // warming while the page sets up
    for (const name of meta.panes) {
        const layer = new Layer({ name: `lghcc-${name}` });
        app.scene.layers.push(layer);
        const camera = new Entity(`camera-${name}`);
        camera.addComponent('camera', {
            clearColor: new Color(bg[0], bg[1], bg[2], 1), horizontalFov: true, fov: cam.fovX, layers: [layer.id],
            nearClip: meta.camera.near, farClip: meta.camera.far, gammaCorrection: GAMMA_SRGB, toneMapping: TONEMAP_LINEAR
        });
        app.root.addChild(camera);
        const pane = { name, camera, layer, loaded: false, partial: [] };
        panes.push(pane);
        if (document.getElementById(`lghcc-stream-${name}`)) {
            decodeInto(pane, { bytes: base64Bytes(`lghcc-stream-${name}`) }, 'embedded stream');
            continue;
        }
        const bytes = base64Bytes(`lghcc-ply-${name}`);
        const asset = new Asset(name, 'gsplat', { url: `${name}.ply`, filename: `${name}.ply`, contents: new Response(bytes) });
        asset.on('error', (err) => fail(`${name}: ${err}`));
        asset.ready(() => {
            const e = new Entity(name);
            e.addComponent('gsplat', { asset, layers: [layer.id] });
            app.root.addChild(e);
            paneLoaded(pane, e);
        });
        app.assets.add(asset);
        app.assets.load(asset);
    }
    if (url) decodeInto(decodedPane(), { url: decodeURIComponent(url[1]) }, decodeURIComponent(url[1]));
    attachDrop();
    app.on('update', () => {
        if (state.appliedVersion !== cam.version) {
            for (const p of panes) {
                p.camera.camera.fov = cam.fovX;
                p.camera.setPosition(cam.eye);
                p.camera.lookAt(cam.target, cam.up);
            }
            state.appliedVersion = cam.version;
            state.sortsAtApply = state.sorts;
            state.framesAfterSort = 0;
            state.framesThisVersion = 0;
        }
    });
    app.systems.gsplat.on('frame:request', () => { app.renderNextFrame = true; });
    app.scene.on('gsplat:sorted', () => {
        state.sorts++;
        app.renderNextFrame = true;
    });
    app.on('frameend', () => {
        state.frames++;
        if (state.loaded < panes.length || state.readyVersion === cam.version || state.appliedVersion !== cam.version) {
            if (state.readyVersion !== cam.version) app.renderNextFrame = true;
            return;
        }
        state.framesThisVersion++;
        const sorted = state.sorts - state.sortsAtApply >= panes.length;  // one sort per pane's camera
        if (sorted) state.framesAfterSort++;
        // on screen: two frames drawn after every pane's sort for this camera came back; or, for a
        // move too small to start a sort (the engine re-sorts after a turn of 1e-3 rad), 60 frames
        if ((sorted && state.framesAfterSort >= 2) || state.framesThisVersion >= 60) {
            state.readyVersion = cam.version;
        } else {
            app.renderNextFrame = true;
        }
        checkSettled();
    });
    const resize = () => {
        app.resizeCanvas(canvas.clientWidth, canvas.clientHeight);
        layout();
        app.renderNextFrame = true;
    };
    new ResizeObserver(resize).observe(canvas);
    resize();
    attachControls(canvas);
    app.start();
}

// ---------------------------------------------------------------------------------------------
// Streams decoded in the page (js/lghcc-decoder in a Web Worker)
// ---------------------------------------------------------------------------------------------

function paneLoaded(pane, entity) {
    if (pane.entity) pane.entity.destroy();
    pane.entity = entity;
    if (!pane.loaded) { pane.loaded = true; state.loaded++; }
    state.readyVersion = -1;
    app.renderNextFrame = true;
}

function decodedPane() { return panes.find((p) => p.name === 'decoded') || panes[panes.length - 1]; }

function setCheck(text, bad = false) {
    const el = document.getElementById('lghcc-check');
    if (el) { el.textContent = text; el.style.color = bad ? '#f66' : ''; }
}

// a tile of the decoding worker (sh with the DC first) in decode()'s layout (colors, and sh above the DC),
// what lghcc-playcanvas's gsplatData takes
function tileScene(a) {
    const n = a.opacities.length, S3 = n ? a.sh.length / n : 3, R3 = S3 - 3;
    const colors = new Float32Array(3 * n), sh = new Float32Array(R3 * n);
    for (let i = 0; i < n; i++) {
        for (let k = 0; k < 3; k++) colors[3 * i + k] = a.sh[S3 * i + k];
        for (let k = 0; k < R3; k++) sh[R3 * i + k] = a.sh[S3 * i + 3 + k];
    }
    return { positions: a.positions, scales: a.scales, rotations: a.rotations, opacities: a.opacities, colors, sh };
}

// the tiles' arrays -> the engine's splat data (lghcc-playcanvas: the PLY property names), in the engine's Morton order
function splatData(parts) {
    const data = gsplatData(parts.map(tileScene));
    data.reorderData();
    return data;
}

function showSplats(pane, parts) {
    const resource = new GSplatResource(app.graphicsDevice, splatData(parts));
    const e = new Entity(`${pane.name}-decoded`);
    e.addComponent('gsplat', { resource, layers: [pane.layer.id] });
    app.root.addChild(e);
    paneLoaded(pane, e);
}

// a tile's splats drawn as the tile arrives (sorted within the tile only); the whole scene, sorted
// as one, replaces them once the stream has passed every check
function showTile(pane, arrays) {
    const e = new Entity(`${pane.name}-tile`);
    e.addComponent('gsplat', { resource: new GSplatResource(app.graphicsDevice, splatData([arrays])), layers: [pane.layer.id] });
    app.root.addChild(e);
    pane.partial.push(e);
    app.renderNextFrame = true;
}

function dropTiles(pane) {
    for (const e of pane.partial || []) e.destroy();
    pane.partial = [];
}

// decoding threads for a tiled stream's tiles: DECODE_WORKERS helpers the decoding worker starts (it hands the tiles out)
const DECODE_WORKERS = Math.max(1, navigator.hardwareConcurrency || 1);

// the decoding worker, kept from one stream to the next with its helpers; started and warmed ({warm}:
// the module compiled, the helpers started with it) as soon as the page knows it will decode
let worker = null;
let decoding = false;
function workerSource() { return document.getElementById('lghcc-worker').textContent; }
function decoderWorker() {
    if (worker && decoding) { worker.terminate(); worker = null; } // a new stream replaces one still decoding (and its helpers)
    if (!worker) {
        worker = new Worker(URL.createObjectURL(new Blob([workerSource()], { type: 'text/javascript' })));
        worker.postMessage({ warm: true, workers: DECODE_WORKERS, source: workerSource() });
    }
    return worker;
}

function decodeInto(pane, msg, what) {
    const w = decoderWorker();
    decoding = true;
    const parts = [];
    let firstTile = null;
    dropTiles(pane);
    setCheck(`decoding ${what}…`);
    w.onmessage = (ev) => {
        const m = ev.data;
        if (m.type === 'tile') {
            parts.push(m.arrays);
            if (firstTile === null) firstTile = m.ms / 1000;
            if (m.tiles > 1) showTile(pane, m.arrays);
            setCheck(`decoding ${what}: ${parts.length} of ${m.tiles} tiles (${m.count.toLocaleString()} Gaussians, hash of each tile checked)`);
        } else if (m.type === 'done') {
            decoding = false;
            dropTiles(pane);
            showSplats(pane, parts);
            const r = { pane: pane.name, tiles: m.tiles, count: m.count, seconds: m.seconds, firstTileSeconds: firstTile, hashChecked: true };
            api.decodes.push(r);
            setCheck(`decoded in this page: ${m.count.toLocaleString()} Gaussians, ${m.tiles} tile${m.tiles > 1 ? 's' : ''}, ` +
                `${m.seconds.toFixed(2)} s, hash ✓`);
        } else if (m.type === 'error') {
            decoding = false; // the worker stays (it replaces its helpers itself)
            dropTiles(pane);
            api.decodes.push({ pane: pane.name, error: `${m.kind}: ${m.message}` });
            setCheck(`✗ ${what}: not a valid stream`, true);
            fail(`${what}: stream rejected (${m.kind}): ${m.message}`);
        }
    };
    w.onerror = (ev) => {
        decoding = false;
        w.terminate();
        if (worker === w) worker = null;
        dropTiles(pane);
        fail(`${what}: the decoder stopped: ${ev.message}`);
    };
    w.postMessage({ ...msg, workers: DECODE_WORKERS, source: workerSource() }, msg.bytes ? [msg.bytes.buffer] : []);
}

function attachDrop() {
    window.addEventListener('dragover', (e) => e.preventDefault());
    window.addEventListener('drop', async (e) => {
        e.preventDefault();
        const f = e.dataTransfer && e.dataTransfer.files[0];
        if (!f) return;
        api.error = null;
        decodeInto(decodedPane(), { bytes: new Uint8Array(await f.arrayBuffer()) }, f.name);
    });
}

// ---------------------------------------------------------------------------------------------
// Ready / settled promises
// ---------------------------------------------------------------------------------------------

let waiters = [];
let resolveReady, rejectReady;
const api = {
    firstFrame: false,
    error: null,
    ready: new Promise((res, rej) => { resolveReady = res; rejectReady = rej; }),
    panes,
    state,
    decodes: [],
    paneRects: () => panes.map((p) => ({ name: p.name, x: p.x0, width: p.width })),
    setCamera,
    camera: () => ({ eye: [cam.eye.x, cam.eye.y, cam.eye.z], target: [cam.target.x, cam.target.y, cam.target.z], up: [cam.up.x, cam.up.y, cam.up.z], fovX: cam.fovX }),
    settled: () => new Promise((res, rej) => { waiters.push({ res, rej }); checkSettled(); })
};
window.lghccViewer = api;

function fail(msg) {
    api.error = String(msg);
    const el = document.getElementById('lghcc-status');
    if (el) el.textContent = `error: ${api.error}`;
    rejectReady(new Error(api.error));
    for (const w of waiters) w.rej(new Error(api.error));
    waiters = [];
}

function checkSettled() {
    if (!panes.length || api.error) return;
    if (state.readyVersion !== cam.version) return;
    if (!api.firstFrame) {
        api.firstFrame = true;
        document.body.dataset.firstFrame = 'true';
        const el = document.getElementById('lghcc-status');
        if (el) el.textContent = '';
        resolveReady();
    }
    for (const w of waiters) w.res();
    waiters = [];
}

try {
    start();
} catch (err) {
    fail(err && err.message ? err.message : err);
}
