"""lghcc-enc: compress a 3DGS scene (plain 3DGS or anchor-based) into one .lghcc file."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

# torch's OpenMP threads wait passively: spinning against other jobs on a shared machine made a
# transcode take 178.6 s instead of 72.1 s. Set before torch is imported; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# numpy's OpenBLAS on one thread: its products here are small or tall-and-thin, and its threads
# spin while they wait (2-core machine, 200k SH-3 scene at `fast`: np.cov's product 2.6 s on two
# threads against 0.4 on one, the quantization stage 10.3 -> 7.9 s, the same stream; the tiles'
# workers, --jobs, are the parallelism). Set before numpy is imported; a user's own setting wins.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from ..app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_OK, EXIT_RESOURCE_LIMIT,
                              EXIT_USAGE, exit_status_epilog)
from ..app.cli_common import format_bytes, memory_size
from ..app.cliargs import (OVERWRITE_RULE, add_overwrite_options, add_version_option, positive_float, positive_int,
                           run_cli)
from ..common.errors import LghccError, UsageError
from ..app.fileio import atomic_write_bytes, check_output_paths, check_overwrite, write_error
from .api import is_gaussian_file  # noqa: F401  (lghcc-enc's test of its input; kept importable here)

if TYPE_CHECKING:
    from .stream.encode import EncodeResult
    from .stream.stats import EncodeStats


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min" if seconds < 5400 else \
        f"{seconds / 3600:.1f} h"

DESCRIPTION = """\
Compress a 3D Gaussian Splatting scene into a single .lghcc file that lghcc-dec turns back
into exactly the same decoded scene on any machine. The file holds everything: geometry,
attributes, models and a hash of the decoded scene.

A plain 3DGS scene (INRIA PLY, as 3DGS, gsplat, nerfstudio and SuperSplat write it) is coded
as explicit Gaussians: every Gaussian a point with its SH colour, opacity, scales and
rotation. The encoder renders the source from where the scene is watched: the capture's own
cameras (--cameras, or the cameras.json of an INRIA training output beside the PLY), else views
around an object or from inside a room or street, as the scene's geometry says (--views). It
measures what each Gaussian contributes (no view loses more than the pruning share of what it
shows), and chooses the pruning, the position grid and the quantization steps that give the
fewest bytes at the quality asked for: the presets ask for a PSNR against renders of the source
(low 40 dB, medium 45 dB, high 50 dB; --psnr sets another), met on 12 more views of 256 px at the end;
--lambda instead minimizes -PSNR + lambda x log2(bytes). Then it tunes the kept Gaussians to the
source renders with their quantization simulated (--fit-iterations; medium and high), which adds
about 1 dB. The log's "check:" line gives the PSNR on 12 more views that no stage used: what a
viewer from those places sees.
Above 100,000 Gaussians the settings search runs on a spatial sample (search_sample_gaussians in a
YAML --config; 0 searches the whole scene, every trial on every Gaussian; tools/results/search_sampling.md (f)).
The fast preset renders nothing: the Gaussians of opacity below 1/255 (which no rasterizer
draws) are dropped and the rest coded at fixed steps.
The web preset is fast for a web page that decodes the stream with the JavaScript decoder: no
neighbour prediction and chunks of 2048 rows, 1.5-1.9x faster to decode in one thread for 1.8-4.7% more
bytes at equal PSNR (tools/results/js_decoder.md, Round 12).
An anchor scene (Scaffold-GS / HAC checkpoint) is coded with its anchors and render MLPs.

examples:
  lghcc-enc scene.ply -o scene.lghcc                   3DGS PLY, preset medium
  lghcc-enc scene.spz -o scene.lghcc                   SPZ (or SOG) input
  lghcc-enc scene.ply --preset high -o scene.lghcc     higher fidelity, more bytes
  lghcc-enc scene.ply --preset fast -o scene.lghcc     no renders: SPZ-like turnaround, more bytes
  lghcc-enc scene.ply --preset web -o scene.lghcc      fast's coding made to decode faster in JavaScript
  lghcc-enc room.ply --cameras sparse/0 -o room.lghcc  choices made from the capture's cameras
  lghcc-enc room.ply --views inside -o room.lghcc      from inside the scene, looking outward
  lghcc-enc --procedural 20000 -o demo.lghcc           built-in procedural anchor scene
  lghcc-enc outputs/garden -o garden.lghcc             Scaffold-GS model folder
  lghcc-enc point_cloud.ply --preset lghcc-medium -o g.lghcc   anchor PLY (MLPs from checkpoint.pth beside it)
  lghcc-enc big.ply -o big.lghcc --jobs auto          tiles coded in one worker process per CPU
  lghcc-enc big.ply -o big.lghcc --ray --address HEAD_IP:6379
                                                       tiles as tasks on a Ray cluster (`ray start --head` on
                                                       HEAD_IP, `ray start --address HEAD_IP:6379` on the others)

The lghcc-* presets fit a context model to the scene: minutes (an estimate is printed first).
An anchor scene without its render MLPs is refused (--allow-no-mlps codes it anyway).
Progress goes to stderr: a bar on a terminal, a line every 10 s in a log
(LGHCC_PROGRESS_INTERVAL=S to change it), each stage with its share done and the time left.
The stream does not depend on --jobs or --ray: the tiles are coded alone, wherever they run.
"""


def _epilog() -> str:
    return OVERWRITE_RULE + "\n\n" + exit_status_epilog(
        {EXIT_ERROR: "error in the input or the environment (a scene that cannot be read "
                     "or coded, an output that cannot be written, an option value)",
         EXIT_INVALID_STREAM: "the written stream failed its own decoding check (a bug: "
                              "please report it)",
         EXIT_RESOURCE_LIMIT: "the scene would need more memory than --max-memory, by default the "
                              "memory available (refused before any work), or the system ran out of memory"},
        codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INVALID_STREAM, EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED))


def add_source_arguments(p: argparse.ArgumentParser) -> None:
    """The scene, the output and the preset."""
    from .stream.config import preset_names

    p.add_argument("input", nargs="?", help="a 3DGS scene (INRIA PLY, compressed PLY, SPZ, SOG, streamed SOG "
                                             "lod-meta.json, .splat, .ksplat, a 3DGS model folder), or a Scaffold-GS "
                                             "model folder, iteration folder or point_cloud.ply")
    p.add_argument("--lod", type=int, metavar="N",
                   help="streamed SOG input (lod-meta.json): code level of detail N (negative: from the coarsest "
                        "end, as splat-transform's -L; default: the level with the most Gaussians, the finest)")
    p.add_argument("-o", "--output", required=True, help="the .lghcc file to write")
    p.add_argument("--procedural", type=int, metavar="N",
                   help="encode the built-in procedural scene with about N anchors instead of an input")
    p.add_argument("--seed", type=int, default=0, help="seed of the procedural scene (default 0)")
    p.add_argument("--preset", default="medium", choices=preset_names(None),
                   help="rate point (default: medium), one file each: encoder/presets/<name>.yaml, with a section "
                        "per kind of scene it applies to. 3DGS input: " + ", ".join(preset_names("gaussians"))
                        + "; anchor scenes: " + ", ".join(preset_names("anchors")))
    p.add_argument("--config", metavar="YAML", help="YAML file overriding preset options")
    p.add_argument("--tile-points", type=int, metavar="N",
                   help="cut the scene into spatial tiles (each decodable alone: lghcc-dec --jobs, --box) of about "
                        "N points each (default 16384; a scene under 2N points has no tiles); 0: no tiles")


def add_anchor_arguments(p: argparse.ArgumentParser) -> None:
    """The coding of anchor scenes: steps, voxel size, pruning, duplicates."""
    p.add_argument("--feature-step", type=float, help="quantization step of anchor features")
    p.add_argument("--scaling-step", type=float, help="quantization step of the log scalings")
    p.add_argument("--offset-step", type=float, help="quantization step of the offsets")
    p.add_argument("--mlp-weight-bits", type=int, help="bits per quantized render-MLP weight (2..24)")
    p.add_argument("--voxel-size", type=positive_float,
                   help="anchor voxel size (default: lghcc's PLY header comment, else voxel_size in the model's "
                        "cfg_args, else inferred from the anchor grid; the log says which)")
    pr = p.add_argument_group("anchor pruning before coding (default: none)")
    pr.add_argument("--prune", choices=("none", "naap", "opacity"),
                    help="naap: Neighborhood-Aware Anchor Pruning (importance from each anchor's opacity and its "
                         "k-NN neighbourhood; pruned anchors are merged into their nearest kept neighbour); "
                         "opacity: drop anchors below an opacity threshold (Context-GS)")
    pr.add_argument("--prune-keep", type=float, metavar="RATIO", help="keep this fraction of the anchors (0..1]")
    pr.add_argument("--prune-tau", type=float, metavar="TAU", help="or: prune anchors whose importance is below TAU")
    p.add_argument("--merge-duplicates", action="store_true",
                   help="merge anchors that fall in the same voxel (attributes averaged) instead of failing")


def add_gaussian_arguments(p: argparse.ArgumentParser) -> None:
    gs = p.add_argument_group("plain 3DGS input (any 3DGS scene format above: not a Scaffold-GS model)")
    gs.add_argument("--mode", choices=("gaussians", "anchors"), default="gaussians",
                    help="gaussians (default): code every Gaussian explicitly; anchors: transcode to an anchor "
                         "scene first by fitting anchors and MLPs to renders of the source (minutes; "
                         "tools/results/transcode.md)")
    gs.add_argument("--psnr", dest="target_psnr", type=float, metavar="DB",
                    help="quality asked for: PSNR in dB of the decoded scene against renders of the source, "
                         "from where the scene is watched (--views); the encoder finds the fewest bytes that "
                         "reach it on its own views and reports, at the end, the PSNR on views of the same kind "
                         "it did not use (the presets: low 40, medium 45, high 50)")
    gs.add_argument("--cameras", metavar="PATH",
                    help="the capture's cameras, which every render-based choice is then made from (a spread "
                         "subset): an INRIA cameras.json, a COLMAP sparse folder, a transforms.json, or a folder "
                         "holding one. Default: the cameras.json of an INRIA training output "
                         "(<model>/point_cloud/iteration_N/point_cloud.ply), when there is one")
    gs.add_argument("--no-cameras", action="store_true",
                    help="do not look for the capture's cameras beside the input (--views places the views)")
    gs.add_argument("--views", choices=("auto", "orbit", "inside", "both"),
                    help="without the capture's cameras, where the views look from: orbit (around an object), "
                         "inside (from the free space a room or street surrounds, looking outward), both, or "
                         "auto (the default: decided from the scene's geometry, the log says what and why)")
    gs.add_argument("--lambda", dest="rd_lambda", type=float, metavar="L",
                    help="instead of a PSNR: rate-distortion weight in dB of PSNR per doubling of the stream; "
                         "the encoder stops where twice the bytes would buy less than L dB (larger: fewer "
                         "bytes, lower PSNR; 0 with --psnr 0: the preset's steps as they are, no search)")
    gs.add_argument("--fit-iterations", type=int, metavar="N",
                    help="steps tuning the kept Gaussians to the source renders (0: none)")
    gs.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), help="code at most this SH degree")
    gs.add_argument("--neighbour-prediction", choices=("auto", "always", "never"),
                    help="code each Gaussian's attributes from its nearest already-decoded neighbours (format "
                         "1.1; auto, the default: where that codes smaller than without, which it does on "
                         "dense scenes; never: streams a version-1.0 decoder reads)")
    gs.add_argument("--rd-quantization", type=float, metavar="W",
                    help="rate-distortion optimized quantization: each value rounded or moved one step towards "
                         "its prediction, by how much the pictures show it against the bits saved; W weighs "
                         "the bits (default 1; 0: plain rounding). Used where the encoder measures the "
                         "pictures (--psnr, --lambda, fitting or pruning)")
    gs.add_argument("--step-adjust", type=int, metavar="A", choices=range(8),
                    help="step adjustment (format 1.2): each Gaussian's steps made up to 2^(A/4) times coarser "
                         "where the pictures barely show it, chosen with the rate-distortion optimized "
                         "quantization (default 7, the presets'; 0: off, streams a version-1.1 decoder reads)")


def add_transcode_arguments(p: argparse.ArgumentParser) -> None:
    t = p.add_argument_group(
        "anchor transcoding of plain 3DGS input (--mode anchors)",
        "The scene is fitted to anchors against renders of the source, rate-aware: the loss adds "
        "lambda x the attribute bits the stream's entropy models estimate, with the preset's "
        "quantization simulated and NAAP pruning in the loop. Presets (low, medium, high; lghcc-* the same): "
        + "; ".join(f"{k} lambda {v['rate_lambda']:g}, {v['iterations']} iterations, keep {v['prune_keep']:g} of "
                    f"the anchors, {v['resolution']} px renders" for k, v in _transcode_presets().items())
        + ". The source's SH degree goes into the stream (source_info), and lghcc-dec --export writes it back.")
    t.add_argument("--transcode-anchors", type=int, metavar="N",
                   help="target anchor count of the voxel grid (default: a quarter of the Gaussians; every "
                        "Gaussian gets an offset slot, so the final count can be higher)")
    t.add_argument("--transcode-voxel-size", type=positive_float, metavar="V", help="anchor voxel size (overrides the count)")
    t.add_argument("--transcode-iterations", type=int,
                   help="render-fitting iterations (default: the preset's; 0: distillation only)")
    t.add_argument("--transcode-distill-steps", type=int,
                   help="attribute-distillation steps that initialize features and MLPs (default: the preset's)")
    t.add_argument("--transcode-rate-lambda", type=float, metavar="L",
                   help="weight of the estimated bits per attribute value in the fit (default: the preset's; "
                        "0: no rate term)")
    t.add_argument("--transcode-prune-keep", type=float, metavar="RATIO",
                   help="fraction of the anchors NAAP keeps during the fit (default: the preset's; 1: no pruning)")
    t.add_argument("--transcode-views", type=int, default=32, help="training views on a sphere (default 32)")
    t.add_argument("--transcode-resolution", type=int, help="square render size for fitting (default: the preset's)")
    t.add_argument("--transcode-feature-dim", type=int, default=32, help="anchor feature size C (default 32)")
    t.add_argument("--transcode-offsets", type=int, default=10, help="offsets per anchor K (default 10)")
    t.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="where transcoding renders: cpu (default), or cuda (gsplat's CUDA rasterizer: pip install "
                        "'lghcc[gsplat]'); coding itself is the same on every machine")


def jobs_arg(text: str) -> int:
    """argparse type of --jobs: a whole number >= 1, or auto (0)."""
    return 0 if text.strip().lower() == "auto" else positive_int(text)


def add_execution_arguments(p: argparse.ArgumentParser) -> None:
    """Where the tiles are coded, and the memory bound."""
    x = p.add_argument_group(
        "execution at scale (none of these changes a byte of the stream)",
        "A tiled scene (--tile-points) codes each tile on its own: in worker processes (--jobs) or as "
        "Ray tasks (--ray), on this machine or a cluster.")
    x.add_argument("--jobs", type=jobs_arg, default=1, metavar="N",
                   help="code the tiles in N worker processes (default 1: this process; auto: one per CPU, "
                        "one process for a scene under 2 tiles of 16,384 points)")
    x.add_argument("--ray", action="store_true",
                   help="code the tiles as Ray tasks, one per tile: on a local Ray instance, or on the cluster "
                        "of --address (pip install 'lghcc[batch]'; the workers need lghcc installed, no shared "
                        "filesystem: each task gets its tile through Ray's object store)")
    x.add_argument("--address", metavar="HOST:PORT",
                   help="with --ray: a running Ray cluster (its head's address as `ray start --head` prints it; "
                        "ray://HOST:PORT for Ray Client; auto: the cluster this machine belongs to)")
    x.add_argument("--ray-cpus", type=positive_int, metavar="N",
                   help="with --ray and no --address: CPUs of the local Ray instance (default: all)")
    x.add_argument("--max-memory", type=memory_size, default=AVAILABLE, metavar="SIZE",
                   help="refuse, before any work, a scene whose encoding would need more memory than SIZE "
                        "(e.g. 4G, 512M; none: no bound; exit status 4); the estimate counts the scene, the "
                        "encoder's arrays, the render-based preparation and the worker processes "
                        "(encoder/stream/memory.py, tools/results/scale.md); default: the memory the system has "
                        "available when the encoder starts (MemAvailable, or a cgroup's limit), so a scene that "
                        "would not fit is refused rather than killed half way")


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """Overwriting, checks, reports."""
    add_overwrite_options(p, "output files (-o, --json)")
    p.add_argument("--allow-no-mlps", action="store_true",
                   help="code an anchor scene that has no render MLPs (its decoded scene can then be neither "
                        "rendered nor exported; refused by default)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip decoding the written stream to check it (faster)")
    p.add_argument("--report-ideal", action="store_true",
                   help="also report how close attribute coding comes to its model's ideal code length")
    p.add_argument("--no-context-twin", action="store_true",
                   help="ignore the GG-Conv twin lghcc-train --rate-lambda saved beside the scene "
                        "(context_twin.pt; by default the GG-Conv fit also starts from it, the smaller stream kept)")
    p.add_argument("--json", metavar="FILE", help="also write the size breakdown and timings as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors and warnings")


def _transcode_presets() -> dict:
    from .stream.config import TRANSCODE_PRESETS

    return TRANSCODE_PRESETS


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lghcc-enc", description=DESCRIPTION, epilog=_epilog(),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    add_source_arguments(p)
    add_anchor_arguments(p)
    add_gaussian_arguments(p)
    add_transcode_arguments(p)
    add_execution_arguments(p)
    add_run_arguments(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Exit status: lghcc.app.cli_common (0 written, 1 input/output error, 2 usage, 3 the stream failed its
    own check, 4 out of memory, 130 interrupted: the output is written atomically, never in part)."""
    return run_cli("lghcc-enc", _main, argv)


def check_outputs(args: argparse.Namespace) -> None:
    """Every output is checked before encoding: none may overwrite the input or another output;
    an existing one only with the overwrite option; a --device that is not there."""
    inputs = {"input": args.input, "--config file": args.config}
    if args.input and Path(args.input).is_dir():  # a model folder: its PLY is the input
        from ..formats.scaffold_io import locate_ply
        try:
            inputs["input PLY"] = locate_ply(args.input)
        except LghccError:
            pass  # reported when the scene is read
    check_output_paths({"-o": args.output, "--json": args.json}, inputs)
    for path in (args.output, args.json):
        if path:
            check_overwrite(path, args.overwrite)
    if args.device != "cpu":  # checked before minutes of loading and transcoding
        from ..render.rasterizer import select_device
        select_device(args.device)


def config_overrides(args: argparse.Namespace, gaussians: bool) -> dict:
    """The options that override the preset, for the kind of scene."""
    if args.tile_points is not None and args.tile_points < 0:
        raise LghccError(f"--tile-points must be 0 (no tiles) or more, got {args.tile_points}")
    if gaussians:
        overrides = {"rd_lambda": args.rd_lambda, "target_psnr": args.target_psnr,
                     "fit_iterations": args.fit_iterations, "sh_degree": args.sh_degree,
                     "tile_points": args.tile_points, "rd_quantization": args.rd_quantization,
                     "step_adjust_max": args.step_adjust, "views": args.views,
                     "neighbour_prediction": {"auto": True, "always": "always", "never": False, None: None}[
                         args.neighbour_prediction]}
        if args.rd_lambda is not None and args.target_psnr is None:
            overrides["target_psnr"] = 0.0  # --lambda given: it replaces the preset's quality
        return overrides
    return {"feature_step": args.feature_step, "scaling_step": args.scaling_step,
            "offset_step": args.offset_step, "mlp_weight_bits": args.mlp_weight_bits,
            "pruning": args.prune, "prune_keep_ratio": args.prune_keep, "prune_tau": args.prune_tau,
            "tile_points": args.tile_points}


def capture_cameras(args: argparse.Namespace, gaussians: bool, log):
    """The capture's cameras for a Gaussian scene: --cameras, else those of an INRIA training output
    the input lies in (none with --no-cameras); a usage error where they contradict --views or the
    input is not a Gaussian scene."""
    from ..render.camera import find_capture_cameras, load_capture_cameras

    if args.cameras and (args.no_cameras or args.views):
        raise UsageError("--cameras places the views: give it without --no-cameras and --views")
    if args.cameras and not gaussians:
        raise UsageError("--cameras is for plain 3DGS input (a PLY, SPZ or SOG file coded as Gaussians)")
    path = args.cameras
    if path is None and gaussians and not (args.no_cameras or args.views):
        path = find_capture_cameras(args.input)
        if path is not None:
            log(f"cameras: {path}, found beside the input (--no-cameras: place the views by the scene instead)")
    if path is None:
        return None
    cams = load_capture_cameras(path)
    log(f"cameras: {len(cams)} from {path}")
    return cams


def load_scene(args: argparse.Namespace, cfg):
    """The scene to code (read, transcoded or procedural), checked to be encodable
    -> api.Source. A transcode (--mode anchors on a plain 3DGS scene) follows the preset and
    matches its rate model to ``cfg``, the configuration the scene will be coded with."""
    from . import api

    transcode = api.TranscodeOptions(
        preset=args.preset, anchors=args.transcode_anchors, voxel_size=args.transcode_voxel_size,
        iterations=args.transcode_iterations, distill_steps=args.transcode_distill_steps,
        rate_lambda=args.transcode_rate_lambda, prune_keep=args.transcode_prune_keep, views=args.transcode_views,
        resolution=args.transcode_resolution, feature_dim=args.transcode_feature_dim,
        num_offsets=args.transcode_offsets, device=args.device)
    source = api.read_source(args.input, mode=args.mode, procedural=args.procedural, seed=args.seed,
                             voxel_size=args.voxel_size, merge_duplicates=args.merge_duplicates,
                             transcode=transcode, coding=cfg, progress=not args.quiet,
                             log=(lambda m: print(m, file=sys.stderr, flush=True)) if not args.quiet
                             else (lambda m: None),
                             warn=lambda m: print(f"lghcc-enc: warning: {m}", file=sys.stderr), lod=args.lod)
    api.check_encodable(source.scene, args.allow_no_mlps, warn=lambda m: print(f"lghcc-enc: warning: {m}",
                                                                                file=sys.stderr))
    return source


def announce_estimate(args: argparse.Namespace, scene, cfg, log) -> None:
    """The time a preset that fits a context model will take, before it starts."""
    from . import api

    estimate = api.estimate_seconds(scene, cfg)
    if estimate is not None:
        secs, what = estimate
        log(f"preset {args.preset}: {what} on {min(scene.num_anchors, cfg.context_train_points):,} anchors, "
            f"about {_duration(secs)} on 2 CPU threads (tools/results/presets.md); the preset "
            f"{args.preset.removeprefix('lghcc-')} codes with the same steps in seconds. Ctrl-C stops it "
            "and writes nothing")


# --max-memory's default: the memory the system has available (app/workers.py available_memory); not a
# string, which argparse would parse as a size
AVAILABLE = -1


def check_memory(scene, cfg, workers, max_memory: int | None, source: str, log) -> None:
    """Refuse a scene whose encoding would need more than ``max_memory`` (ResourceLimitError, exit
    status 4), before the work starts; with a bound, say what the estimate is. ``AVAILABLE``: the
    memory the system has available now (no bound where it does not say)."""
    from .stream.memory import check_encode_memory

    limit = "--max-memory"
    if max_memory == AVAILABLE:
        from ..app.workers import available_memory

        max_memory, limit = available_memory(), "the memory available"
    if max_memory is None:
        return
    need = check_encode_memory(scene, cfg, workers, max_memory, source, limit)
    log(f"memory: about {format_bytes(need)} needed, within {limit} {format_bytes(max_memory)}")


def context_twin_of(args: argparse.Namespace, gaussians: bool, cfg, transcoded=None):
    """The GG-Conv twin trained with the scene, when it may be used (else None): the one of the
    transcode's rate phase (``transcoded``), or the one lghcc-train saved beside the scene."""
    if args.input and not gaussians and not args.no_context_twin and cfg.context_model == "ggconv":
        if transcoded is not None:
            return transcoded.context_twin
        from .context.ggconv_train import find_context_twin
        return find_context_twin(args.input)
    return None


def twin_outcome(stats: EncodeStats) -> str:
    why = stats.context_twin_unused
    fit = stats.context_fit
    return "context twin of the training run: " + (
        f"not used ({why})" if why else
        "kept (smallest stream)" if fit is not None and fit.parent_base == "twin" else
        "tried, a fresh fit coded smaller")


def write_outputs(args: argparse.Namespace, result: EncodeResult, scene, cfg, gaussians: bool, source: str) -> None:
    """The stream, and the --json report."""
    out = Path(args.output)
    try:
        atomic_write_bytes(out, result.data)
    except OSError as e:
        raise write_error(out, e) from None
    if not args.json:
        return
    count = {"num_gaussians": result.decoded.num_gaussians} if gaussians else {"num_anchors": scene.num_anchors}
    try:
        atomic_write_bytes(args.json, json.dumps({
            "input": source, "output": str(out), **count,
            "bytes": len(result.data), "breakdown": result.breakdown.bytes_by_category, "stats": result.stats.to_json(),
            "scene_sha256": result.scene_hash.hex(), "config": vars(cfg)}, indent=2).encode())
    except OSError as e:
        raise write_error(args.json, e) from None


def step_adjust_summary(st, num_gaussians: int) -> str:
    """One line on the step-adjustment indices (format 1.2; as flags, 1.5): their bytes, and how many Gaussians
    have each index (index a: steps 2^(a/4) times the channels')."""
    bits = st.step_adjust_coded_bits
    share = 100 * bits / max(bits + st.attribute_coded_bits, 1)
    counts = ", ".join(f"{a}: {c:,}" for a, c in enumerate(st.step_adjust_counts or []))
    coding = "as flags, " if st.step_adjust_flags else ""
    return (f"step adjustment: indices {bits // 8:,} bytes ({coding}{bits / max(num_gaussians, 1):.2f} bits per "
            "Gaussian, "
            f"{share:.1f}% of the attribute chunks); Gaussians per index {counts}")


def print_summary(say, args: argparse.Namespace, result: EncodeResult, scene, gaussians: bool, source: str,
                  t_load: float) -> None:
    st = result.stats
    if st.pruning is not None:
        say(st.pruning)
    if gaussians:
        d = result.decoded
        say(f"{source}: {scene.num_gaussians:,} Gaussians (SH degree {scene.sh_degree}) -> {Path(args.output)}: "
            f"{d.num_gaussians:,} Gaussians, SH degree {d.sh_degree} ({len(result.data):,} bytes, "
            f"{8 * len(result.data) / scene.num_gaussians:.1f} bits per source Gaussian)")
        if st.settings is not None:
            say("settings: " + st.settings)
    else:
        say(f"{source}: {result.decoded.num_anchors:,} anchors, C={scene.feature_dim}, K={scene.num_offsets} -> "
            f"{Path(args.output)} ({len(result.data):,} bytes)")
    say(result.breakdown.table())
    if st.step_adjust_coded_bits is not None:
        say(step_adjust_summary(st, result.decoded.num_gaussians))
    if args.report_ideal:
        overhead = st.attribute_coded_bits / max(st.attribute_ideal_bits, 1) - 1
        say(f"attribute coding: {st.attribute_coded_bits:,} bits, {100 * overhead:+.3f}% over the model's ideal")
    say(f"time: load {t_load:.2f} s, encode {st.time_total_s:.2f} s"
        + ("" if not st.verified else ", decoded and verified: hash matches"))
    say(f"decoded scene SHA-256: {result.scene_hash.hex()}")


def tile_workers_of(args: argparse.Namespace):
    """Where the tiles are coded (--jobs, --ray, --address, --ray-cpus); a usage error when the
    options contradict each other."""
    from .stream.tile_workers import TileWorkers

    if args.address and not args.ray:
        args.ray = True  # --address names a Ray cluster: it asks for Ray
    if args.ray and args.jobs != 1:
        raise LghccError("--jobs and --ray are two ways of coding the tiles: give one")
    if args.ray_cpus is not None and (not args.ray or args.address):
        raise LghccError("--ray-cpus sizes a local Ray instance: give it with --ray and without --address")
    if args.address:  # an unreachable cluster is an error before minutes of work, not after
        from ..app.cluster import check_reachable
        check_reachable(args.address, TileWorkers.connect_timeout_s)
    return TileWorkers(jobs=args.jobs, ray=args.ray, address=args.address, ray_cpus=args.ray_cpus)


def _main(argv: list[str] | None) -> int:
    from . import api
    from .stream.config import load_config

    args = setup_args().parse_args(argv)
    say = (lambda *a: None) if args.quiet else print
    log = (lambda *a: None) if args.quiet else (lambda msg: print(f"lghcc-enc: {msg}", file=sys.stderr, flush=True))
    # A failure is reported by run_cli: one line, and the exit status of its kind (lghcc.app.cli_common).
    check_outputs(args)
    workers = tile_workers_of(args)
    # what the input is decides which presets apply: a path that is no scene is one error saying so, first
    gaussians = args.input is not None and api.scene_kind(args.input) == "gaussians" and args.mode == "gaussians"
    cfg = load_config(args.preset, args.config, config_overrides(args, gaussians),
                      kind="gaussians" if gaussians else "anchors")
    t0 = time.perf_counter()
    loaded = load_scene(args, None if gaussians else cfg)
    scene = loaded.scene
    source = args.input if args.input is not None else "procedural"
    t_load = time.perf_counter() - t0
    check_memory(scene, cfg, workers, args.max_memory, source, log)
    announce_estimate(args, scene, cfg, log)
    twin = context_twin_of(args, gaussians, cfg, loaded.transcoded)
    cameras = capture_cameras(args, gaussians, log)
    result, cfg = api.encode(scene, cfg, progress=not args.quiet, log=log, measure_ideal=args.report_ideal,
                             context_twin=twin, verify=not args.no_verify, allow_missing_mlps=args.allow_no_mlps,
                             transcoded=loaded.transcoded, workers=workers, cameras=cameras)
    if twin is not None:
        say(twin_outcome(result.stats))
    write_outputs(args, result, scene, cfg, gaussians, source)
    print_summary(say, args, result, scene, gaussians, source, t_load)
    return 0


if __name__ == "__main__":
    sys.exit(main())
