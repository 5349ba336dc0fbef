"""The encoder as functions (informative): what ``lghcc.encode`` and ``lghcc-enc`` both call.

* ``scene_kind``: which kind of scene a path holds, or one error saying what it holds instead.
* ``load_source``: the scene a path names, ready for coding: a plain 3DGS scene (any format
  lghcc.formats reads) as a GaussianScene, or (``mode="anchors"``) transcoded to anchors; a Scaffold-GS model
  as an AnchorScene (duplicates in a voxel merged on request); the procedural scene.
  ``read_source`` returns the same scene with what a transcode produced beside it (its
  statistics, the source's SH degree, the context twin of its rate phase), which ``encode``
  takes to write the stream's source_info unit.
* ``encoder_config``: a preset, a YAML file and overrides, for the kind of scene.
* ``check_encodable``: refuses an anchor scene without render MLPs (its decoded scene could
  be neither rendered nor exported).
* ``estimate_seconds``: a time estimate for the presets that fit a context model.
* ``encode``: either kind of scene -> ``EncodeResult`` (stream bytes, sizes, decoded scene,
  hash), the stream decoded again and its hash checked unless ``verify=False``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from ..common.errors import InputError, LghccError
from ..common.scene import AnchorScene, GaussianScene

if TYPE_CHECKING:
    from .anchors.transcode import TranscodeResult
    from .stream.config import AttributeCodingConfig

Log = Callable[[str], None]

MLP_ROLES = ("opacity", "cov", "color")

# Seconds per GG-Conv training step on 2 CPU threads: about 0.025 + 1e-6 x anchors, from the
# measured encode times of tools/results/presets.md (lego 2.8k anchors, procedural 20k).
_STEP_S, _STEP_S_PER_ANCHOR = 0.025, 1.0e-6


def _quiet(_msg: str) -> None:
    pass


def scene_kind(path: str | Path) -> str:
    """'gaussians' for a plain 3DGS scene of any format ``read_scene`` reads, 'anchors' for a
    Scaffold-GS model; otherwise the InputError of ``detect_format``, which says what was expected
    and what the path holds (before any preset of the wrong kind of scene is looked up)."""
    from ..formats import detect_format

    return "anchors" if detect_format(path).name == "scaffold-gs" else "gaussians"


def is_gaussian_file(path: str | Path) -> bool:
    """A plain 3DGS scene (any format ``read_scene`` reads, not a Scaffold-GS model)."""
    try:
        return scene_kind(path) == "gaussians"
    except LghccError:
        return False


@dataclass
class TranscodeOptions:
    """How ``load_source(mode="anchors")`` turns a plain 3DGS scene (PLY, SPZ, SOG) into an
    anchor scene: the transcode preset of ``preset`` (encoder/stream/config.py TRANSCODE_PRESETS, its
    rate model matched to the coding configuration), then these TranscodeConfig fields (None:
    the preset's, or TranscodeConfig's default)."""

    preset: str = "medium"
    anchors: int | None = None
    voxel_size: float | None = None
    iterations: int | None = None
    distill_steps: int | None = None
    rate_lambda: float | None = None
    prune_keep: float | None = None
    views: int | None = None
    resolution: int | None = None
    feature_dim: int | None = None
    num_offsets: int | None = None
    device: str = "cpu"


@dataclass
class Source:
    """A scene ready for coding, and the transcode that made it (None: it was read as it is)."""

    scene: AnchorScene | GaussianScene
    transcoded: TranscodeResult | None = None


def transcode_source(path: Path, options: TranscodeOptions, coding=None, *, progress: bool = False,
                     log: Log = _quiet, lod: int | None = None) -> TranscodeResult:
    """A plain 3DGS scene file (any format ``read_scene`` reads; ``lod``: a streamed SOG's level)
    fitted to anchors (encoder/anchors/transcode.py) with the settings of ``options`` for the
    coding configuration ``coding`` (None: its preset's)."""
    from ..formats.ply3dgs import is_3dgs_ply
    from .stream.config import load_config
    from .anchors.transcode import preset_transcode_config, transcode_3dgs

    o = options
    coding = coding if coding is not None else load_config(o.preset)
    fields = {k: v for k, v in vars(o).items() if k != "preset"}
    cfg = preset_transcode_config(o.preset, coding, **fields, progress=progress)
    source: Any = str(path)
    if not is_3dgs_ply(path):  # the other formats, read into a scene first
        from ..formats import read_scene
        from ..render.gaussians3dgs import gaussians_from_scene

        source = gaussians_from_scene(read_scene(path, lod=lod), source=str(path))
    log(f"{path}: a plain 3DGS scene: transcoding it to an anchor scene first, by fitting against renders of it "
        f"(preset {o.preset}: rate lambda {cfg.rate_lambda:g}, {cfg.distill_steps} distillation steps, "
        f"{cfg.iterations} fitting iterations; minutes on a CPU; see --transcode-*)")
    res = transcode_3dgs(source, cfg, log=log)
    log(f"transcoded in {res.stats.time_total_s:.1f} s: {res.scene.num_anchors:,} anchors, held-out PSNR "
        f"against the source renders {res.stats.psnr_final:.2f} dB")
    return res


def load_source(path: str | Path | None = None, *, mode: str = "gaussians", procedural: int | None = None,
                seed: int = 0, voxel_size: float | None = None, merge_duplicates: bool = False,
                transcode: TranscodeOptions | None = None, coding=None, progress: bool = False, log: Log = _quiet,
                warn: Log = _quiet, lod: int | None = None) -> AnchorScene | GaussianScene:
    """The scene to encode (see the module doc). ``warn`` gets the warnings a user must see
    (a folder without render MLPs); ``log`` the progress notes. ``coding``: the configuration
    the scene will be coded with, which a transcode's rate model matches (None: the preset's).
    ``lod``: the level of detail of a streamed SOG (None: the level with the most Gaussians)."""
    return read_source(path, mode=mode, procedural=procedural, seed=seed, voxel_size=voxel_size,
                       merge_duplicates=merge_duplicates, transcode=transcode, coding=coding, progress=progress,
                       log=log, warn=warn, lod=lod).scene


def read_source(path: str | Path | None = None, *, mode: str = "gaussians", procedural: int | None = None,
                seed: int = 0, voxel_size: float | None = None, merge_duplicates: bool = False,
                transcode: TranscodeOptions | None = None, coding=None, progress: bool = False, log: Log = _quiet,
                warn: Log = _quiet, lod: int | None = None) -> Source:
    """``load_source``'s scene, with the transcode that made it (``Source``); ``lod``: the level
    of detail of a streamed SOG (None: the level with the most Gaussians)."""
    if (path is None) == (procedural is None):
        raise InputError("give exactly one of an input path or a procedural anchor count")
    if procedural is not None:
        from ..formats.procedural import make_procedural_scene

        if procedural < 1:
            raise InputError("--procedural needs a positive anchor count")
        return Source(make_procedural_scene(procedural, seed=seed, progress=progress))
    p = Path(path)
    if mode not in ("gaussians", "anchors"):
        raise InputError(f"mode must be gaussians or anchors, got {mode!r}")
    if scene_kind(p) == "gaussians":
        if mode == "gaussians":
            from ..formats import read_scene

            return Source(read_scene(p, lod=lod))
        res = transcode_source(p, transcode or TranscodeOptions(), coding, progress=progress, log=log, lod=lod)
        return Source(res.scene, res)
    if lod is not None:
        raise InputError(f"{p}: a level of detail (--lod) is chosen in a streamed SOG (lod-meta.json); this is a "
                         "Scaffold-GS model")
    return Source(read_model(p, voxel_size, merge_duplicates, log, warn))


def read_model(p: Path, voxel_size: float | None, merge_duplicates: bool, log: Log, warn: Log) -> AnchorScene:
    """A Scaffold-GS model (folder or PLY), duplicates in a voxel merged on request."""
    from ..formats.scaffold_io import MissingMlpWarning, read_scaffold
    from .anchors.scene_prep import merge_duplicate_anchors

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MissingMlpWarning)
        scene = read_scaffold(p, voxel_size=voxel_size, log=log)
    for w in caught:
        if issubclass(w.category, MissingMlpWarning):
            warn(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if merge_duplicates:
        scene, merged = merge_duplicate_anchors(scene)
        if merged:
            log(f"merged {merged} anchors that shared a voxel")
    return scene


def encoder_config(scene: AnchorScene | GaussianScene, preset: str = "medium", config_file: str | Path | None = None,
                   overrides: dict[str, Any] | None = None):
    """EncoderConfig (anchor scene) or GaussianEncoderConfig (Gaussian scene) of ``preset``,
    then ``config_file`` (YAML), then ``overrides`` (None values ignored)."""
    from .stream.config import load_config

    kind = "gaussians" if isinstance(scene, GaussianScene) else "anchors"
    return load_config(preset, config_file, overrides, kind=kind)


def check_encodable(scene: AnchorScene | GaussianScene, allow_missing_mlps: bool = False,
                    warn: Log = _quiet) -> None:
    """InputError for an anchor scene without render MLPs (unless allowed): the stream would
    decode, but the decoded scene could be neither rendered nor exported. A scene with only
    some of the three (opacity, cov, color) is coded, with a warning."""
    if isinstance(scene, GaussianScene):
        return
    if not isinstance(scene, AnchorScene):
        raise InputError(f"expected an AnchorScene or a GaussianScene, got {type(scene).__name__}")
    missing = [r for r in MLP_ROLES if r not in scene.mlps]
    if not scene.mlps and not allow_missing_mlps:
        raise InputError("the anchor scene has no render MLPs: its decoded scene could not be rendered or exported. "
                         "Give the model folder whose checkpoint.pth holds them (opacity_mlp, cov_mlp, color_mlp), "
                         "or code the anchors alone on purpose (lghcc-enc --allow-no-mlps; "
                         "allow_missing_mlps=True)")
    if scene.mlps and missing:
        warn(f"the anchor scene has no {', '.join(missing)} MLP: its decoded scene cannot be rendered or exported")


def estimate_seconds(scene: AnchorScene | GaussianScene, cfg: AttributeCodingConfig) -> tuple[float, str] | None:
    """(seconds, what takes them) for a configuration that fits a context model to the scene
    (the lghcc-* presets), on 2 CPU threads; None when coding takes seconds."""
    if isinstance(scene, GaussianScene) or cfg.context_model != "ggconv":
        return None
    fits = (2 if cfg.context_parent_base == "auto" else 1) * (2 if cfg.context_neighbour_level == "auto" else 1)
    steps = cfg.context_float_steps + cfg.context_qat_steps
    n = min(scene.num_anchors, cfg.context_train_points)
    seconds = fits * steps * (_STEP_S + _STEP_S_PER_ANCHOR * n)
    return seconds, f"{fits} GG-Conv fit{'s' if fits > 1 else ''} of {steps:,} steps"


def _encode_gaussians(scene: GaussianScene, cfg, *, progress: bool, log: Log, measure_ideal: bool, workers=None,
                      cameras=None):
    """Rate-aware preparation (when the settings call for it, from ``cameras``, the capture's, where
    given), then the explicit-Gaussian coding and its check on views the preparation did not use
    -> (result, the settings used: the preset's, or those the search chose)."""
    from .gaussians.gaussian_fit import check_on_held_back_views, needs_preparation, prepare_gaussians
    from .gaussians.gaussian_views import scene_views
    from .gaussians.gaussians import encode_gaussian_scene, without_invisible

    t0 = time.perf_counter()
    weights, sensitivity, prepared = None, None, None
    scene, invisible = without_invisible(scene, cfg)
    source = scene
    if needs_preparation(cfg):
        goal = (f", choosing settings for {cfg.target_psnr:g} dB" if cfg.target_psnr
                else f", choosing settings for lambda {cfg.rd_lambda:g}" if cfg.rd_lambda else "")
        log(f"{scene.num_gaussians:,} Gaussians (SH degree {scene.sh_degree}): measuring contributions on "
            f"{cfg.fit_views} views" + goal
            + (f", then {cfg.fit_iterations} fitting steps" if cfg.fit_iterations else ""))
        prep = prepare_gaussians(scene, cfg, views=scene_views(scene, cfg.views, cameras), log=log, progress=progress)
        scene, weights, sensitivity, cfg, prepared = prep.scene, prep.weights, prep.sensitivity, prep.cfg, prep.stats
    result = encode_gaussian_scene(scene, cfg, weights=weights, sensitivity=sensitivity, progress=progress,
                                   measure_ideal=measure_ideal, workers=workers)
    result.stats.prepare = prepared
    if prepared is not None:  # the first stage, before the coding's own
        check_on_held_back_views(source, result.decoded, prep.views, cfg, prepared, log)
        result.stats.stage_times_s = {"prepare": prepared.time_total_s, **result.stats.stage_times_s}
        if prepared.time_held_back_s is not None:
            result.stats.stage_times_s["check"] = prepared.time_held_back_s
    bands = ", ".join(f"{s:.3g}" for s in cfg.sh_band_steps[:result.decoded.sh_degree])
    result.stats.settings = (
        f"pruned {(prepared.gaussians_pruned if prepared else 0) + invisible:,} Gaussians"
        + (f" ({invisible:,} of opacity below {cfg.min_opacity:.3g})" if invisible else "")
        + f"; position step {cfg.position_step:.3g} x the typical size; steps SH DC {cfg.sh_dc_step:.3g}"
        + (f", bands {bands}" if bands else "")
        + f", opacity {cfg.opacity_step:.3g}, scale {cfg.scale_step:.3g}, rotation {cfg.rotation_step:.3g}")
    result.stats.time_total_s = time.perf_counter() - t0
    return result, cfg


def _verify_jobs(workers) -> int:
    """The decoder's worker processes for the check of the written stream: the encoder's (--jobs;
    auto: one per CPU), one process when the tiles went to Ray."""
    if workers is None or workers.ray:
        return 1
    from ..app.workers import available_cpus

    return workers.jobs or available_cpus()


def encode(scene: AnchorScene | GaussianScene, cfg=None, *, progress: bool = False, log: Log = _quiet,
           measure_ideal: bool = False, context_twin=None, verify: bool = True, allow_missing_mlps: bool = False,
           transcoded: TranscodeResult | None = None, workers=None, cameras=None):
    """Encode either kind of scene with ``cfg`` (``encoder_config``; None: preset medium).
    ``cameras``: a Gaussian scene's capture cameras (render/camera.py ``load_capture_cameras``), the
    views its render-based choices are made from (None: ``cfg.views`` places them).
    -> (EncodeResult, the configuration used). ``verify`` decodes the stream again and
    checks that it gives the encoded scene (its hash). ``transcoded``: the transcode that made
    the anchor scene (``read_source``): the stream gets a source_info unit with the source's
    SH degree (spec clause 7.3.10) and the stats its statistics (its context twin, trained in
    its rate phase, is ``context_twin`` when wanted). ``workers`` (encoder/stream/tile_workers.py
    TileWorkers; None: this process): where a tiled scene's tiles are coded (worker processes,
    Ray); the stream does not depend on it."""
    from .stream.encode import encode_scene, source_info_unit

    check_encodable(scene, allow_missing_mlps)
    if cfg is None:
        cfg = encoder_config(scene)
    if isinstance(scene, GaussianScene):
        result, cfg = _encode_gaussians(scene, cfg, progress=progress, log=log, measure_ideal=measure_ideal,
                                        workers=workers, cameras=cameras)
    else:
        ancillary = []
        if transcoded is not None:  # what the decoded anchors cannot tell: the source's SH degree
            ancillary.append(source_info_unit(transcoded.stats.sh_degree))
        result = encode_scene(scene, cfg, progress=progress, measure_ideal=measure_ideal, context_twin=context_twin,
                              ancillary=ancillary, workers=workers)
        result.stats.transcode = None if transcoded is None else transcoded.stats
    if verify:
        from ..decoder.decode import decode_stream

        t0 = time.perf_counter()
        # max_memory=None: the scene is in memory already (the decoder's bound is for untrusted streams)
        decoded = decode_stream(result.data, max_memory=None, jobs=_verify_jobs(workers), progress=progress)
        result.stats.stage_times_s["verify"] = time.perf_counter() - t0
        if decoded.stream_hash != result.scene_hash:
            from ..common.errors import HashMismatchError  # exit status 3, as lghcc-enc --help says

            raise HashMismatchError("internal error: the written stream does not decode to the encoded scene")
        result.stats.verified = True
    return result, cfg
