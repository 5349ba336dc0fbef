"""lghcc-train: the command line of the Scaffold-GS trainer (informative).

What it trains and how: encoder/training/ (the package docstring). Here: the options, in
argument groups with TrainConfig's defaults; a ``--config`` YAML file, under the options given
on the command line; ``--resume`` with the run's saved settings; the refusal to overwrite a run
without ``--resume`` or ``-y``; ``--evaluate``; the exit statuses (lghcc.app.cli_common).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see encoder/training/__init__.py

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

import torch
import yaml

from ..common.errors import InputError
from .training.checkpoints import STATE_NAME
from .training.config import TrainConfig
from .training.evaluation import evaluate_model
from .training.loop import train

DESCRIPTION = """\
Train an anchor-based 3D Gaussian Splatting scene (Scaffold-GS) from posed images, on the
CPU, with lghcc's own differentiable renderer, and write it in the Scaffold-GS checkpoint
layout that lghcc-enc compresses.

The data folder's layout is found by its files: NeRF-synthetic (transforms_train.json,
transforms_test.json and the images they name), COLMAP (sparse/0 or sparse/ as .bin or .txt,
and images/), Mip-NeRF 360 (COLMAP sparse/0 with images_2/4/8: --downscale 4 reads images_4),
LLFF (poses_bounds.npy and images/; its sparse/0, when kept, gives the cameras and the SfM
points). Anchors start from the COLMAP model's points3D when there are some (--init sfm),
else from random points in the region all training cameras see (NeRF-synthetic) or on random
camera rays; they then grow where the image gradients are large and are pruned where they
stay transparent.

Time: one iteration renders one view. On lego at 100x100 pixels an iteration took 0.19 s on
2 CPU threads (tools/results/training.md): 8,000 iterations in 25 minutes, the default 30,000
in about 1.5 hours; more pixels take proportionally longer. Try --iterations 2000 first;
--time-limit MIN bounds a run, --resume continues it.

The output folder gets point_cloud/iteration_<N>/ (the scene), train_state.pth (to resume
with --resume), metrics.json/metrics.csv (test PSNR/SSIM over training) and config.yaml.

examples:
  lghcc-train data/lego -o runs/lego --iterations 7000
  lghcc-train data/lego -o runs/lego --resume             continue an interrupted run
  lghcc-train data/lego -o runs/lego --config my.yaml     options from a YAML file
  lghcc-enc runs/lego -o lego.lghcc                       then compress the result
  lghcc-dec lego.lghcc -o dec/ && lghcc-train data/lego --evaluate dec/    quality after decoding
"""


def setup_args() -> argparse.ArgumentParser:
    """lghcc-train's parser; the defaults are TrainConfig's."""
    from ..app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_OK, EXIT_RESOURCE_LIMIT, EXIT_USAGE,
                                  exit_status_epilog)
    from ..app.cliargs import add_version_option

    p = argparse.ArgumentParser(prog="lghcc-train", description=DESCRIPTION,
                                epilog=exit_status_epilog(
                                    {EXIT_RESOURCE_LIMIT: "the system ran out of memory",
                                     EXIT_INTERRUPTED: "interrupted (Ctrl-C); continue with --resume from the last "
                                                       "checkpoint (every file is written atomically)"},
                                    codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED)),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    _add_run_options(p)
    d = TrainConfig()
    for add in (_add_training_options, _add_scene_options, _add_image_options, _add_evaluation_options,
                _add_growing_options, _add_pruning_options, _add_rate_options):
        add(p, d)
    return p


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """The data and output folders, --evaluate, --config, the overwrite rule and --resume."""
    from ..app.cliargs import add_overwrite_options

    p.add_argument("data", nargs="?", help="folder with the posed images (NeRF-synthetic, LLFF or COLMAP layout)")
    p.add_argument("-o", "--output", help="output folder (the trained model and logs)")
    p.add_argument("--evaluate", metavar="MODEL",
                   help="do not train: render the test views of the data with this Scaffold-GS model folder "
                        "(e.g. lghcc-dec's output) and print PSNR / SSIM")
    p.add_argument("--config", metavar="YAML",
                   help="YAML file of options (keys as the long options, with _ or -); the command line wins")
    add_overwrite_options(p, "run files in the output folder (a fresh run replaces them)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in the output folder from its last checkpoint (its saved settings are "
                        "used, except --threads; a larger --iterations extends the run, also a finished one)")


def _add_training_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Iterations, seed, threads, device and when to stop."""
    g = p.add_argument_group("training")
    g.add_argument("--iterations", type=int, default=d.iterations, help=f"training steps, one view each (default {d.iterations})")
    g.add_argument("--seed", type=int, default=d.seed, help="random seed (default 0): same seed, same result")
    g.add_argument("--threads", type=int, default=d.threads, help=f"CPU threads for torch (default {d.threads})")
    g.add_argument("--device", choices=("cpu", "cuda"), default=d.device,
                   help="where the rasterizer runs: cpu (default), or cuda (gsplat's CUDA rasterizer: pip install "
                        "'lghcc[gsplat]'; the MLPs and the optimizer stay on the CPU)")
    g.add_argument("--time-limit", type=float, metavar="MIN",
                   help="stop after this many minutes of training (checkpoint + full evaluation); resume later")
    g.add_argument("--stop-after", type=int, metavar="N",
                   help="stop after iteration N with a checkpoint, as if interrupted (resume later)")


def _add_scene_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """The anchors: feature size, offsets, voxel size and initial points."""
    g = p.add_argument_group("scene")
    g.add_argument("--feature-dim", type=int, default=d.feature_dim, help=f"anchor feature size C (default {d.feature_dim})")
    g.add_argument("--num-offsets", "-K", type=int, default=d.num_offsets,
                   help=f"neural Gaussians per anchor K (default {d.num_offsets})")
    g.add_argument("--voxel-size", type=float, help="anchor voxel size eps (default: the extent of the initial "
                   f"points / --voxels-per-extent, {d.voxels_per_extent:g})")
    g.add_argument("--voxels-per-extent", type=float, default=d.voxels_per_extent, metavar="N",
                   help=f"without --voxel-size: the voxel size is the extent of the initial points / N (default "
                        f"{d.voxels_per_extent:g}; larger: finer anchors, more of them)")
    g.add_argument("--init", choices=("auto", "random", "sfm"), default=d.init,
                   help="initial points: random (see above) or the COLMAP model's points; auto: sfm when present")
    g.add_argument("--init-points", type=int, default=d.init_points,
                   help=f"random initial points before voxelization (default {d.init_points})")


def _add_image_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Background, resolution and image folder."""
    g = p.add_argument_group("images")
    g.add_argument("--background", default=d.background,
                   help="colour behind transparent pixels and the scene: white, black or r,g,b in [0,1] (default white)")
    g.add_argument("--downscale", type=int, default=d.downscale,
                   help="train and test at 1/N of the image resolution: the dataset's images_N when it has them "
                        "(Mip-NeRF 360, LLFF), else area averaging (default 1)")
    g.add_argument("--images", default=d.images,
                   help="image folder of LLFF/COLMAP/Mip-NeRF 360 scenes (default: images_N for --downscale N when "
                        "the folder has it, else images)")


def _add_evaluation_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Evaluation and checkpoint intervals."""
    g = p.add_argument_group("evaluation and checkpoints")
    g.add_argument("--eval-interval", type=int, default=d.eval_interval,
                   help=f"evaluate on the test views every N iterations (default {d.eval_interval})")
    g.add_argument("--eval-views", type=int, default=d.eval_views,
                   help="test views used at the intermediate evaluations (0 = all; the final one uses all)")
    g.add_argument("--checkpoint-interval", type=int, default=d.checkpoint_interval,
                   help=f"write a checkpoint every N iterations (default {d.checkpoint_interval}) and at the end")
    g.add_argument("--keep-checkpoints", type=int, default=d.keep_checkpoints,
                   help="keep the last N point_cloud/iteration_* folders (0 = all; default 2)")


def _add_growing_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Scaffold-GS's anchor growing and pruning schedule and thresholds."""
    g = p.add_argument_group("anchor growing and pruning (Scaffold-GS defaults)")
    g.add_argument("--stats-from", type=int, default=d.stats_from, help="start gathering statistics (default 500)")
    g.add_argument("--densify-from", type=int, default=d.densify_from, help="first growing/pruning (default 1500)")
    g.add_argument("--densify-until", type=int, default=d.densify_until, help="last growing/pruning (default 15000)")
    g.add_argument("--densify-interval", type=int, default=d.densify_interval, help="every N iterations (default 100)")
    g.add_argument("--densify-grad-threshold", type=float, default=d.densify_grad_threshold,
                   help="screen-space gradient that spawns anchors (default 0.0002)")
    g.add_argument("--min-opacity", type=float, default=d.min_opacity,
                   help="prune anchors whose summed neural opacity per view stays below this (default 0.005)")
    g.add_argument("--skip-finer-levels", action="store_true",
                   help="Scaffold-GS's literal growing rule: no finer level when the coarsest adds no anchor")


def _add_pruning_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """NAAP or opacity pruning once growing ends."""
    g = p.add_argument_group("anchor pruning after growing (then training goes on with the pruned set)")
    g.add_argument("--prune", choices=("none", "naap", "opacity"), default=d.prune,
                   help="naap: Neighborhood-Aware Anchor Pruning (importance from each anchor's accumulated opacity "
                        "and its k-NN neighbourhood; pruned anchors merged into their nearest kept neighbour); "
                        "opacity: drop the anchors of lowest accumulated opacity (Context-GS). Default none")
    g.add_argument("--prune-keep", type=float, default=d.prune_keep,
                   help=f"fraction of the anchors kept (default {d.prune_keep})")
    g.add_argument("--prune-at", type=int, help="iteration of the pruning (default: --densify-until)")


def _add_rate_options(p: argparse.ArgumentParser, d: TrainConfig) -> None:
    """Rate-distortion training; also -q, listed in this group."""
    g = p.add_argument_group("rate-distortion training (LG-HCC: L = L_render + lambda x estimated attribute bits)")
    g.add_argument("--rate-lambda", type=float, default=d.rate_lambda,
                   help="weight of the estimated bits per attribute value under the codec's hierarchy and GG-Conv "
                        "context (0: plain Scaffold-GS, the default; on lego 100x100, 0.004: -0.1 dB, "
                        "0.05: -2.3 dB and half the attribute bits; tools/results/training.md)")
    g.add_argument("--rate-from", type=int, help="first iteration with the rate term (default: --densify-until; "
                   "not earlier, the anchor set must be final)")
    g.add_argument("--rate-step", type=float, default=d.rate_step,
                   help=f"the quantization step the encoder will use (default {d.rate_step}, preset medium)")
    g.add_argument("--rate-voxel-scale", type=int, default=d.rate_voxel_scale,
                   help=f"the encoder's coarse voxel scale (default {d.rate_voxel_scale})")
    g.add_argument("--rate-neighbour-level", type=int, choices=(1, 2), default=d.rate_neighbour_level,
                   help="the encoder's GG-Conv neighbour level (default 1)")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def _config_from_yaml(path: str) -> dict:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: config file not found")
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as e:
        raise InputError(f"{p}: not valid YAML ({e})") from None
    if not isinstance(data, dict):
        raise InputError(f"{p}: expected a mapping of option: value")
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    out = {}
    for key, v in data.items():
        k = str(key).replace("-", "_")
        if k not in fields:
            raise InputError(f"{p}: unknown option {key!r} (known: {', '.join(sorted(fields))})")
        out[k] = v
    return out


def explicit_options(args: argparse.Namespace, argv: list[str] | None) -> set[str]:
    """TrainConfig fields the user set: on the command line or in the --config file."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    given = setup_args()
    for action in given._actions:
        action.default = argparse.SUPPRESS
        action.required = False
    out = {k for k in vars(given.parse_args(argv)) if k in fields}
    if args.config:
        out |= set(_config_from_yaml(args.config)) & fields
    return out


def config_from_args(args: argparse.Namespace, argv: list[str] | None) -> TrainConfig:
    """Defaults, then the YAML file, then the options given on the command line."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    values = {k: v for k, v in vars(args).items() if k in fields}
    if args.config:
        values.update(_config_from_yaml(args.config))
        given = setup_args()
        for action in given._actions:
            action.default = argparse.SUPPRESS
            action.required = False
        values.update({k: v for k, v in vars(given.parse_args(argv)).items() if k in fields})
    if args.data is not None:
        values["data"] = str(Path(args.data).absolute())
    try:
        return TrainConfig(**values)
    except TypeError as e:
        raise InputError(str(e)) from None


OUTPUT_NAMES = (STATE_NAME, "point_cloud", "metrics.json", "metrics.csv", "config.yaml")


def check_fresh_output(out: Path, overwrite: bool) -> None:
    """A new run's output folder: one that holds a run's files (OUTPUT_NAMES) needs --resume,
    or -y, which removes those files first (nothing else in the folder is touched)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"cannot write {out} (it exists and is not a folder)")
    present = [n for n in OUTPUT_NAMES if (out / n).exists()]
    if not present:
        return
    if not overwrite:
        what = "a training run" if STATE_NAME in present else ", ".join(present)
        raise InputError(f"{out} already holds {what}; use --resume to continue it, -y (--overwrite) to start "
                         "over (its run files are replaced), or choose another output folder")
    for n in present:
        p = out / n
        shutil.rmtree(p) if p.is_dir() else p.unlink()


def main(argv: list[str] | None = None) -> int:
    """Exit status: lghcc.app.cli_common (0, 1 input error, 2 usage, 4 out of memory, 130 interrupted), through
    run_cli: one line on stderr."""
    from ..app.cliargs import run_cli

    return run_cli("lghcc-train", _main, argv, "continue with --resume from the last checkpoint")


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = setup_args().parse_args(argv)
    # a failure is reported by run_cli: one line, the exit status of its kind (lghcc.app.cli_common)
    if args.evaluate:
        if not args.data:
            raise InputError("--evaluate needs the data folder")
        torch.set_num_threads(args.threads)
        r = evaluate_model(args.evaluate, args.data, args.background, args.downscale, args.images)
        print(f"{r['model']}: {r['anchors']:,} anchors, test PSNR {r['psnr']:.3f} dB, SSIM {r['ssim']:.4f} "
              f"({r['views']} views)")
        return 0
    if not args.output:
        raise InputError("give the output folder with -o")
    cfg = config_from_args(args, argv)
    if not args.resume and not cfg.data:
        raise InputError("give the data folder (or --resume an existing run)")
    if not args.resume:
        check_fresh_output(Path(args.output), args.overwrite)
    iterations = None
    if args.resume:
        given = explicit_options(args, argv) - {"data"}
        iterations = cfg.iterations if "iterations" in given else None
        ignored = sorted(given - {"iterations", "threads", "device"})
        if ignored:
            print("lghcc-train: --resume uses the run's saved settings; ignored: "
                  + ", ".join("--" + k.replace("_", "-") for k in ignored), file=sys.stderr)
    res = train(cfg, args.output, resume=args.resume, stop_after=args.stop_after,
                time_limit_s=None if args.time_limit is None else 60.0 * args.time_limit,
                progress=not args.quiet, iterations=iterations)
    last = res.history[-1] if res.history else None
    state = "finished" if res.finished else "stopped (continue with --resume)"
    print(f"{state} at iteration {res.iteration}: {res.scene.num_anchors:,} anchors"
          + (f", test PSNR {last['psnr']:.2f} dB, SSIM {last['ssim']:.4f}" if last else "")
          + f" -> {res.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
