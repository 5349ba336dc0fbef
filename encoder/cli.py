"""lghcc-enc: compress a 3DGS scene (plain 3DGS or anchor-based) into one .lghcc file."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

# torch's OpenMP threads wait passively: spinning against other jobs on a shared machine made a
# transcode take 178.6 s instead of 72.1 s. Set before torch is imported; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from lghcc.common.cliargs import positive_float
from lghcc.common.errors import LghccError
from lghcc.common.fileio import atomic_write_bytes, check_output_paths, check_writable_file, write_error

DESCRIPTION = """\
Compress a 3D Gaussian Splatting scene into a single .lghcc file that lghcc-dec turns back
into exactly the same decoded scene on any machine. The file holds everything: geometry,
attributes, models and a hash of the decoded scene.

A plain 3DGS scene (INRIA PLY, as 3DGS, gsplat, nerfstudio and SuperSplat write it) is coded
as explicit Gaussians: every Gaussian a point with its SH colour, opacity, scales and
rotation. The encoder renders the source from views around it, measures what each Gaussian
contributes, and chooses the pruning, the position grid and the quantization steps that give
the fewest bytes at the quality asked for: the presets ask for a PSNR against renders of the
source (low 40 dB, medium 45 dB, high 50 dB; --psnr sets another), --lambda instead minimizes
-PSNR + lambda x log2(bytes). Then it tunes the kept Gaussians to the source renders with
their quantization simulated (--fit-iterations; medium and high), which adds about 1 dB.
An anchor scene (Scaffold-GS / HAC checkpoint) is coded with its anchors and render MLPs.

examples:
  lghcc-enc scene.ply -o scene.lghcc                   3DGS PLY, preset medium
  lghcc-enc scene.spz -o scene.lghcc                   SPZ (or SOG) input
  lghcc-enc scene.ply --preset high -o scene.lghcc     higher fidelity, more bytes
  lghcc-enc --procedural 20000 -o demo.lghcc           built-in procedural anchor scene
  lghcc-enc outputs/garden -o garden.lghcc             Scaffold-GS model folder
  lghcc-enc point_cloud.ply --preset lghcc-medium -o g.lghcc   anchor PLY (MLPs from checkpoint.pth beside it)
"""


def setup_args() -> argparse.ArgumentParser:
    from lghcc.encoder.config import preset_names

    p = argparse.ArgumentParser(prog="lghcc-enc", description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", nargs="?", help="a 3DGS scene (INRIA PLY, SPZ or SOG), or a Scaffold-GS model folder, "
                                             "iteration folder or point_cloud.ply")
    p.add_argument("-o", "--output", required=True, help="the .lghcc file to write")
    p.add_argument("--procedural", type=int, metavar="N",
                   help="encode the built-in procedural scene with about N anchors instead of an input")
    p.add_argument("--seed", type=int, default=0, help="seed of the procedural scene (default 0)")
    names = sorted(set(preset_names()) | set(preset_names("gaussians")))
    p.add_argument("--preset", default="medium", choices=names,
                   help="rate point (default: medium). 3DGS input: " + ", ".join(preset_names("gaussians"))
                        + "; anchor scenes: " + ", ".join(preset_names()))
    p.add_argument("--config", metavar="YAML", help="YAML file overriding preset options")
    p.add_argument("--feature-step", type=float, help="quantization step of anchor features")
    p.add_argument("--scaling-step", type=float, help="quantization step of the log scalings")
    p.add_argument("--offset-step", type=float, help="quantization step of the offsets")
    p.add_argument("--mlp-weight-bits", type=int, help="bits per quantized render-MLP weight (2..24)")
    p.add_argument("--voxel-size", type=positive_float,
                   help="anchor voxel size (default: inferred from the anchor grid of the input)")
    pr = p.add_argument_group("anchor pruning before coding (default: none)")
    pr.add_argument("--prune", choices=("none", "naap", "opacity"),
                    help="naap: Neighborhood-Aware Anchor Pruning (importance from each anchor's opacity and its "
                         "k-NN neighbourhood; pruned anchors are merged into their nearest kept neighbour); "
                         "opacity: drop anchors below an opacity threshold (Context-GS)")
    pr.add_argument("--prune-keep", type=float, metavar="RATIO", help="keep this fraction of the anchors (0..1]")
    pr.add_argument("--prune-tau", type=float, metavar="TAU", help="or: prune anchors whose importance is below TAU")
    p.add_argument("--merge-duplicates", action="store_true",
                   help="merge anchors that fall in the same voxel (attributes averaged) instead of failing")
    gs = p.add_argument_group("plain 3DGS input (an SPZ or SOG file, or a PLY with f_dc_0 and no f_anchor_feat_0)")
    gs.add_argument("--mode", choices=("gaussians", "anchors"), default="gaussians",
                    help="gaussians (default): code every Gaussian explicitly; anchors: transcode to an anchor "
                         "scene first by fitting anchors and MLPs to renders of the source (minutes; "
                         "tools/results/transcode.md)")
    gs.add_argument("--psnr", dest="target_psnr", type=float, metavar="DB",
                    help="quality asked for: PSNR in dB of the decoded scene against renders of the source "
                         "(views around the scene); the encoder finds the fewest bytes that reach it "
                         "(the presets: low 40, medium 45, high 50)")
    gs.add_argument("--lambda", dest="rd_lambda", type=float, metavar="L",
                    help="instead of a PSNR: rate-distortion weight in dB of PSNR per doubling of the stream; "
                         "the encoder stops where twice the bytes would buy less than L dB (larger: fewer "
                         "bytes, lower PSNR; 0 with --psnr 0: the preset's steps as they are, no search)")
    gs.add_argument("--fit-iterations", type=int, metavar="N",
                    help="steps tuning the kept Gaussians to the source renders (0: none)")
    gs.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), help="code at most this SH degree")
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
    p.add_argument("-f", "--force", action="store_true", help="overwrite the output file if it exists")
    p.add_argument("--no-verify", action="store_true",
                   help="skip decoding the written stream to check it (faster)")
    p.add_argument("--report-ideal", action="store_true",
                   help="also report how close attribute coding comes to its model's ideal code length")
    p.add_argument("--no-context-twin", action="store_true",
                   help="ignore the GG-Conv twin lghcc-train --rate-lambda saved beside the scene "
                        "(context_twin.pt; by default the GG-Conv fit also starts from it, the smaller stream kept)")
    p.add_argument("--json", metavar="FILE", help="also write the size breakdown and timings as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors and warnings")
    return p


def _transcode_presets() -> dict:
    from lghcc.encoder.config import TRANSCODE_PRESETS

    return TRANSCODE_PRESETS


def is_gaussian_file(path) -> bool:
    """A plain 3DGS scene file: an INRIA 3DGS PLY (not a Scaffold-GS anchor PLY), SPZ or SOG."""
    from lghcc.formats import detect_format
    from lghcc.render.gaussians3dgs import is_3dgs_ply

    p = Path(path)
    if is_3dgs_ply(p):
        return True
    if not p.exists() or (p.is_dir() and not (p / "meta.json").is_file()):
        return False
    try:
        return detect_format(p).name in ("spz", "sog")
    except LghccError:
        return False


def _transcode(args, coding):
    """--mode anchors on a plain 3DGS scene (PLY, SPZ or SOG): the rate-aware transcode of the
    preset (encoder/transcode.py) -> its TranscodeResult."""
    from lghcc.encoder.transcode import preset_transcode_config, transcode_3dgs
    from lghcc.render.gaussians3dgs import gaussians_from_scene, is_3dgs_ply

    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    if is_3dgs_ply(args.input):
        source = args.input
    else:  # SPZ or SOG
        from lghcc.formats import read_scene

        source = gaussians_from_scene(read_scene(args.input), source=str(args.input))
    cfg = preset_transcode_config(
        args.preset, coding, anchors=args.transcode_anchors, voxel_size=args.transcode_voxel_size,
        iterations=args.transcode_iterations, distill_steps=args.transcode_distill_steps,
        rate_lambda=args.transcode_rate_lambda, prune_keep=args.transcode_prune_keep,
        views=args.transcode_views, resolution=args.transcode_resolution, feature_dim=args.transcode_feature_dim,
        num_offsets=args.transcode_offsets, device=args.device, progress=not args.quiet and sys.stderr.isatty())
    say(f"{args.input}: a plain 3DGS scene: transcoding it to an anchor scene first, by fitting against renders of "
        f"it (preset {args.preset}: rate lambda {cfg.rate_lambda:g}, {cfg.distill_steps} distillation steps, "
        f"{cfg.iterations} fitting iterations; minutes on a CPU; see --transcode-*)")
    res = transcode_3dgs(source, cfg, log=say)
    say(f"transcoded in {res.stats['time_total_s']:.1f} s: {res.scene.num_anchors:,} anchors, held-out PSNR "
        f"against the source renders {res.stats['psnr_final']:.2f} dB")
    return res


def _load_scene(args, coding=None):
    """-> (scene, source name, the TranscodeResult when the input was transcoded, else None)."""
    from lghcc.common.procedural import make_procedural_scene
    from lghcc.common.scaffold_io import MissingMlpWarning, read_scaffold
    from lghcc.encoder.scene_prep import merge_duplicate_anchors

    if (args.input is None) == (args.procedural is None):
        raise LghccError("give exactly one of an input path or --procedural N")
    if args.procedural is not None:
        if args.procedural < 1:
            raise LghccError("--procedural needs a positive anchor count")
        return make_procedural_scene(args.procedural, seed=args.seed,
                                     progress=not args.quiet and sys.stderr.isatty()), "procedural", None
    if not Path(args.input).exists():
        raise LghccError(f"{args.input}: no such file or folder")
    if args.mode == "gaussians" and is_gaussian_file(args.input):
        from lghcc.formats import read_scene

        return read_scene(args.input), args.input, None
    if is_gaussian_file(args.input):
        from lghcc.encoder.config import load_config

        res = _transcode(args, coding or load_config(args.preset))
        return res.scene, args.input, res
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", MissingMlpWarning)
        scene = read_scaffold(args.input, voxel_size=args.voxel_size)
    for w in caught:  # e.g. a folder without a recognised MLP file: said even with -q
        if issubclass(w.category, MissingMlpWarning):
            print(f"lghcc-enc: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if args.merge_duplicates:
        scene, merged = merge_duplicate_anchors(scene)
        if merged and not args.quiet:
            print(f"merged {merged} anchors that shared a voxel", file=sys.stderr)
    return scene, args.input, None


def _encode_gaussians(scene, cfg, args):
    """Rate-aware preparation (when the settings call for it), then the explicit-Gaussian coding.
    -> (result, the settings used: the preset's, or those the search chose)."""
    from lghcc.encoder.gaussian_fit import prepare_gaussians
    from lghcc.encoder.gaussians import encode_gaussian_scene

    log = (lambda *a: None) if args.quiet else (lambda msg: print(f"lghcc-enc: {msg}", file=sys.stderr, flush=True))
    progress = not args.quiet and sys.stderr.isatty()
    t0 = time.perf_counter()
    weights, prep_stats = None, {}
    if cfg.rd_lambda > 0 or cfg.target_psnr > 0 or cfg.fit_iterations > 0 or cfg.prune_share > 0:
        goal = (f", choosing settings for {cfg.target_psnr:g} dB" if cfg.target_psnr
                else f", choosing settings for lambda {cfg.rd_lambda:g}" if cfg.rd_lambda else "")
        log(f"{scene.num_gaussians:,} Gaussians (SH degree {scene.sh_degree}): measuring contributions on "
            f"{cfg.fit_views} views" + goal
            + (f", then {cfg.fit_iterations} fitting steps" if cfg.fit_iterations else ""))
        prep = prepare_gaussians(scene, cfg, log=log, progress=progress)
        scene, weights, cfg, prep_stats = prep.scene, prep.weights, prep.cfg, prep.stats
    result = encode_gaussian_scene(scene, cfg, weights=weights, progress=progress, measure_ideal=args.report_ideal)
    result.stats.update({f"prepare_{k}": v for k, v in prep_stats.items()})
    bands = ", ".join(f"{s:.3g}" for s in cfg.sh_band_steps[:result.decoded.sh_degree])
    result.stats["settings"] = (
        f"pruned {prep_stats.get('gaussians_pruned', 0):,} Gaussians; position step {cfg.position_step:.3g} x the "
        f"typical size; steps SH DC {cfg.sh_dc_step:.3g}" + (f", bands {bands}" if bands else "")
        + f", opacity {cfg.opacity_step:.3g}, scale {cfg.scale_step:.3g}, rotation {cfg.rotation_step:.3g}")
    result.stats["time_total_s"] = time.perf_counter() - t0
    return result, cfg


def main(argv: list[str] | None = None) -> int:
    args = setup_args().parse_args(argv)
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.config import load_config
    from lghcc.encoder.encode import encode_scene

    say = (lambda *a: None) if args.quiet else print
    try:
        out = Path(args.output)
        # Every output is checked before encoding: none may overwrite the input or another output.
        inputs = {"input": args.input, "--config file": args.config}
        if args.input and Path(args.input).is_dir():  # a model folder: its PLY is the input
            from lghcc.common.scaffold_io import locate_ply
            try:
                inputs["input PLY"] = locate_ply(args.input)
            except LghccError:
                pass  # reported when the scene is read
        check_output_paths({"-o": args.output, "--json": args.json}, inputs)
        if out.exists() and not out.is_dir() and not args.force:
            raise LghccError(f"{out} exists; use --force to overwrite it")
        for path in (args.output, args.json):
            if path:
                check_writable_file(path)
        if args.device != "cpu":  # checked before minutes of loading and transcoding
            from lghcc.render.rasterizer import select_device
            select_device(args.device)
        gaussians = args.input is not None and args.mode == "gaussians" and is_gaussian_file(args.input)
        if gaussians:
            overrides = {"rd_lambda": args.rd_lambda, "target_psnr": args.target_psnr,
                         "fit_iterations": args.fit_iterations, "sh_degree": args.sh_degree}
            if args.rd_lambda is not None and args.target_psnr is None:
                overrides["target_psnr"] = 0.0  # --lambda given: it replaces the preset's quality
            cfg = load_config(args.preset, args.config, overrides, kind="gaussians")
        else:
            cfg = load_config(args.preset, args.config, {
                "feature_step": args.feature_step, "scaling_step": args.scaling_step,
                "offset_step": args.offset_step, "mlp_weight_bits": args.mlp_weight_bits, "pruning": args.prune,
                "prune_keep_ratio": args.prune_keep, "prune_tau": args.prune_tau})
        t0 = time.perf_counter()
        scene, source, transcoded = _load_scene(args, None if gaussians else cfg)
        t_load = time.perf_counter() - t0
        twin = None
        if gaussians:
            result, cfg = _encode_gaussians(scene, cfg, args)
        else:
            ancillary = []
            if transcoded is not None:  # what the decoded anchors cannot tell: the source's SH degree
                from lghcc.common.container import AncillaryUnitType, DataUnit
                from lghcc.common.units import SourceInfo

                info = SourceInfo(source_sh_degree=int(transcoded.stats["sh_degree"]))
                ancillary.append(DataUnit(AncillaryUnitType.SOURCE_INFO, info.to_bytes()))
            if args.input and not args.no_context_twin and cfg.context_model == "ggconv":
                if transcoded is not None:
                    twin = transcoded.context_twin  # trained in the transcoder's rate phase
                else:
                    from lghcc.encoder.ggconv_train import find_context_twin
                    twin = find_context_twin(args.input)
            result = encode_scene(scene, cfg, progress=not args.quiet and sys.stderr.isatty(),
                                  measure_ideal=args.report_ideal, context_twin=twin, ancillary=ancillary)
            if transcoded is not None:
                result.stats.update({f"transcode_{k}": v for k, v in transcoded.stats.items()})
        if twin is not None:
            why = result.stats.get("context_twin_unused")
            say("context twin of the training run: " + (f"not used ({why})" if why else
                "kept (smallest stream)" if result.stats.get("context_parent_base") == "twin" else
                "tried, a fresh fit coded smaller"))
        verified = None
        if not args.no_verify:
            decoded = decode_stream(result.data)
            verified = decoded.stream_hash == result.scene_hash
            if not verified:
                raise LghccError("internal error: the written stream does not decode to the encoded scene")
        try:
            atomic_write_bytes(out, result.data)
        except OSError as e:
            raise write_error(out, e) from None
        if args.json:
            st = result.stats
            count = {"num_gaussians": result.decoded.num_gaussians} if gaussians else \
                {"num_anchors": scene.num_anchors}
            try:
                atomic_write_bytes(args.json, json.dumps({
                    "input": source, "output": str(out), **count,
                    "bytes": len(result.data), "breakdown": result.breakdown.bytes_by_category, "stats": st,
                    "scene_sha256": result.scene_hash.hex(), "config": vars(cfg)}, indent=2).encode())
            except OSError as e:
                raise write_error(args.json, e) from None
    except LghccError as e:
        print(f"lghcc-enc: error: {e}", file=sys.stderr)
        return 1
    st = result.stats
    if "pruning" in st:
        say(st["pruning"])
    if gaussians:
        d = result.decoded
        say(f"{source}: {scene.num_gaussians:,} Gaussians (SH degree {scene.sh_degree}) -> {out}: {d.num_gaussians:,} "
            f"Gaussians, SH degree {d.sh_degree} ({len(result.data):,} bytes, "
            f"{8 * len(result.data) / scene.num_gaussians:.1f} bits per source Gaussian)")
        if "settings" in st:
            say("settings: " + st["settings"])
    else:
        say(f"{source}: {result.decoded.num_anchors:,} anchors, C={scene.feature_dim}, K={scene.num_offsets} -> {out} "
            f"({len(result.data):,} bytes)")
    say(result.breakdown.table())
    if args.report_ideal:
        overhead = st["attribute_coded_bits"] / max(st["attribute_ideal_bits"], 1) - 1
        say(f"attribute coding: {st['attribute_coded_bits']:,} bits, {100 * overhead:+.3f}% over the model's ideal")
    say(f"time: load {t_load:.2f} s, encode {st['time_total_s']:.2f} s"
        + ("" if verified is None else ", decoded and verified: hash matches"))
    say(f"decoded scene SHA-256: {result.scene_hash.hex()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
