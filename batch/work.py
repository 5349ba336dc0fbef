"""The work of a sweep as plain functions: what runs on a Ray worker runs the same way in
``--local`` mode (this module never imports Ray; batch/runner.py decides where it runs).

Two steps, each a function of its arguments only, returning bytes and a JSON-able dict (so
that nothing depends on a filesystem shared between the driver and the workers, except the
scenes' input paths, which every worker reads):

``prepare(scene, lam, sweep options)``: the anchor scene to code, and the reference images
    to evaluate against: the procedural scene; an anchor model as read; a plain 3DGS PLY
    transcoded once (lghcc.encoder.anchors.transcode); or a scene trained from posed images under rate
    lambda ``lam`` (lghcc-train). Returned as a tar of a folder: the Scaffold-GS model
    (``model/``, with the training run's context twin when there is one) and
    ``reference.npz``: the source rendered from the fixed orbit cameras (the input itself:
    the 3DGS PLY for a transcoded scene, the trained model for a trained one).

``run_cell(prepared tar, preset, sweep options)``: encode with the preset, decode (the hash
    is checked), render the decoded scene from the same cameras; PSNR/SSIM against the
    reference images, bytes per part, times. Returns (result dict, stream bytes).
"""

from __future__ import annotations

import io
import os
import platform
import shutil
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from .sweep import Evaluation, SceneSpec

PREPARED_FORMAT = 1


def _threads(n: int | None) -> None:
    if n:
        import torch

        torch.set_num_threads(max(1, int(n)))


def orbit(positions: np.ndarray, scene: SceneSpec, ev: Evaluation) -> list:
    from ..render.views import orbit_cameras

    return orbit_cameras(positions, ev.views, width=ev.width, height=ev.height, up=scene.up)


def _render_anchor(scene, cams, bg) -> np.ndarray:
    from ..render.scenes import render_fn

    draw = render_fn(scene)
    return np.stack([draw(c, bg) for c in cams]).astype(np.float32)


def _render_3dgs(path: str, cams, bg) -> tuple[np.ndarray, np.ndarray]:
    """Renders of a plain 3DGS PLY, and the points the orbit frames (lghcc.render.scenes)."""
    from ..formats.ply3dgs import read_3dgs_ply
    from ..render.scenes import framing_points, render_fn

    g = read_3dgs_ply(path)
    pos = framing_points(g)
    if cams is None:
        return np.zeros(0), pos
    draw = render_fn(g)
    return np.stack([draw(c, bg) for c in cams]).astype(np.float32), pos


def _tar_folder(folder: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for p in sorted(folder.rglob("*")):
            tar.add(p, arcname=str(p.relative_to(folder)), recursive=False)
    return buf.getvalue()


def unpack(prepared: bytes, into: Path) -> Path:
    """Extract a prepared tar (only plain files and folders, no absolute or '..' names)."""
    with tarfile.open(fileobj=io.BytesIO(prepared), mode="r") as tar:
        if hasattr(tarfile, "data_filter"):  # Python 3.10.12+, 3.11.4+
            tar.extractall(into, filter="data")
            return into
        for m in tar.getmembers():
            if not (m.isfile() or m.isdir()) or m.name.startswith("/") or ".." in Path(m.name).parts:
                raise ValueError(f"prepared scene: unexpected member {m.name!r}")
        tar.extractall(into)
    return into


def _prepare_procedural(scene: SceneSpec, ev: Evaluation, bg, model: Path) -> tuple:
    from ..formats.procedural import make_procedural_scene
    from ..formats.scaffold_io import write_scaffold

    anchors = make_procedural_scene(scene.procedural, seed=scene.seed)
    write_scaffold(anchors, model)
    cams = orbit(anchors.positions(), scene, ev)
    return anchors, cams, _render_anchor(anchors, cams, bg), {}


def _prepare_trained(scene: SceneSpec, ev: Evaluation, bg, model: Path, tmp: Path, lam, threads) -> tuple:
    from ..encoder.training.config import TrainConfig
    from ..encoder.training.loop import train

    cfg = TrainConfig(**dict(scene.train_options), data=scene.path, rate_lambda=float(lam or 0.0),
                      threads=threads or TrainConfig().threads)
    res = train(cfg, tmp / "run", progress=False, log=lambda *a: None)
    final = tmp / "run" / "point_cloud" / f"iteration_{res.iteration}"
    shutil.copytree(final, model / "point_cloud" / "iteration_0")
    cams = orbit(res.scene.positions(), scene, ev)
    return res.scene, cams, _render_anchor(res.scene, cams, bg), dict(train_iteration=res.iteration,
                                                                      train_finished=res.finished)


def _prepare_transcoded(scene: SceneSpec, ev: Evaluation, bg, model: Path, transcode: dict | None, threads) -> tuple:
    from ..encoder.anchors.transcode import TranscodeConfig, transcode_3dgs
    from ..formats.scaffold_io import write_scaffold

    res = transcode_3dgs(scene.path, TranscodeConfig(**(transcode or {}), threads=threads))
    write_scaffold(res.scene, model)
    _, pos = _render_3dgs(scene.path, None, bg)
    cams = orbit(pos, scene, ev)
    ref, _ = _render_3dgs(scene.path, cams, bg)
    return res.scene, cams, ref, dict(transcode_psnr=res.stats.psnr_final, source_kind="3dgs")


def _prepare_model(scene: SceneSpec, ev: Evaluation, bg, model: Path) -> tuple:
    """A Scaffold-GS model as it is; the training run's context twin goes with it."""
    from ..encoder.context.ggconv_train import TWIN_FILE
    from ..formats.scaffold_io import locate_ply, read_scaffold, write_scaffold

    anchors = read_scaffold(scene.path)
    write_scaffold(anchors, model)
    twin = locate_ply(scene.path).parent / TWIN_FILE
    if twin.is_file():
        written = next((model / "point_cloud").glob("iteration_*"))
        shutil.copy2(twin, written / TWIN_FILE)
    cams = orbit(anchors.positions(), scene, ev)
    return anchors, cams, _render_anchor(anchors, cams, bg), {}


def _prepared_anchors(scene: SceneSpec, ev: Evaluation, bg, model: Path, tmp: Path, lam, transcode, threads) -> tuple:
    """(anchors, cameras, reference images, what was done) of a scene of any kind."""
    if scene.kind == "procedural":
        return _prepare_procedural(scene, ev, bg, model)
    if scene.kind == "train":
        return _prepare_trained(scene, ev, bg, model, tmp, lam, threads)
    from ..formats.ply3dgs import is_3dgs_ply

    if is_3dgs_ply(scene.path):
        return _prepare_transcoded(scene, ev, bg, model, transcode, threads)
    return _prepare_model(scene, ev, bg, model)


def prepare(scene: SceneSpec, lam: float | None, ev: Evaluation, transcode: dict | None = None,
            threads: int | None = None) -> tuple[bytes, dict]:
    """The prepared scene (module doc) as tar bytes, and what was done (a JSON-able dict)."""
    from ..render.imageio import background_color

    _threads(threads)
    bg = background_color(ev.background)
    info: dict = {"scene": scene.name, "kind": scene.kind, "lambda": lam, "host": platform.node()}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="lghcc-batch-") as tmp:
        root = Path(tmp) / "prepared"
        model = root / "model"
        root.mkdir()
        anchors, cams, ref, done = _prepared_anchors(scene, ev, bg, model, Path(tmp), lam, transcode, threads)
        info.update(done)
        np.savez_compressed(root / "reference.npz", images=ref, format=PREPARED_FORMAT,
                            world_to_camera=np.stack([c.world_to_camera for c in cams]),
                            intrinsics=np.array([[c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.near, c.far]
                                                 for c in cams], np.float64))
        info.update(num_anchors=anchors.num_anchors, prepare_s=time.perf_counter() - t0)
        return _tar_folder(root), info


def reference_cameras(w2c: np.ndarray, intrinsics: np.ndarray) -> list:
    """The cameras a prepared scene's reference images were rendered from."""
    from ..render.camera import Camera

    return [Camera(w, fx, fy, cx, cy, int(wd), int(ht), near, far)
            for w, (fx, fy, cx, cy, wd, ht, near, far) in zip(w2c, intrinsics)]


def run_cell(prepared: bytes, preset: str, ev: Evaluation, encoder: dict | None = None,
             threads: int | None = None) -> tuple[dict, bytes]:
    """Encode the prepared scene with ``preset`` (and the sweep's encoder overrides), decode it,
    evaluate it against the reference images (module doc). Raises on any failure."""
    from ..formats.scaffold_io import read_scaffold
    from ..decoder.decode import decode_stream
    from ..encoder.stream.config import load_config
    from ..encoder.stream.encode import encode_scene
    from ..render.imageio import background_color
    from ..render.metrics import psnr, ssim

    _threads(threads)
    with tempfile.TemporaryDirectory(prefix="lghcc-batch-") as tmp:
        root = unpack(prepared, Path(tmp))
        with np.load(root / "reference.npz") as z:
            ref, cams = z["images"], reference_cameras(z["world_to_camera"], z["intrinsics"])
        anchors = read_scaffold(root / "model")
        cfg = load_config(preset, overrides=encoder or {})
        twin = None
        if cfg.context_model == "ggconv":
            from ..encoder.context.ggconv_train import find_context_twin

            twin = find_context_twin(root / "model")
        t0 = time.perf_counter()
        enc = encode_scene(anchors, cfg, context_twin=twin)
        t_enc = time.perf_counter() - t0
    t0 = time.perf_counter()
    dec = decode_stream(enc.data)  # raises HashMismatchError when the decoded scene is not the encoded one
    t_dec = time.perf_counter() - t0
    if dec.stream_hash != enc.scene_hash:
        raise RuntimeError("the stream does not decode to the encoded scene (internal error)")
    t0 = time.perf_counter()
    imgs = _render_anchor(dec.scene, cams, background_color(ev.background))
    ps = [psnr(a, b) for a, b in zip(imgs, ref)]
    ss = [ssim(a, b) for a, b in zip(imgs, ref)]
    t_eval = time.perf_counter() - t0
    n = dec.scene.num_anchors
    return ({"preset": preset, "bytes": len(enc.data), "breakdown": dict(dec.breakdown.bytes_by_category),
             "num_anchors": n, "bits_per_anchor": 8 * len(enc.data) / n,
             "psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "psnr_views": [float(p) for p in ps],
             "encode_s": t_enc, "decode_s": t_dec, "eval_s": t_eval, "scene_sha256": enc.scene_hash.hex(),
             "tools": list(dec.tools), "host": platform.node(), "pid": os.getpid()}, enc.data)
