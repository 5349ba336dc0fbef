"""lghcc-dec: decode a .lghcc file into the Scaffold-GS checkpoint layout."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

# Rendering (--render) runs torch's OpenMP kernels: passive waiting keeps 2 threads from spinning
# against other jobs on a shared machine (100k Gaussians forward: 7.6 s spinning, 1.8 s passive).
# Set before torch is imported; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from ..app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_OK, EXIT_RESOURCE_LIMIT,
                              EXIT_USAGE, exit_status_epilog, format_bytes, memory_size, with_prefix)
from ..app.cliargs import (OVERWRITE_RULE, add_overwrite_options, add_version_option, box_arg, jobs_arg,
                           positive_float, run_cli)
from ..app.cliargs import add_deprecated_alias
from ..common.errors import LghccError
from ..app.fileio import (atomic_write_bytes, check_output_folder, check_output_paths, check_overwrite,
                                 write_error)
from ..common.scene import GaussianScene

DESCRIPTION = """\
Decode an LG-HCC stream (.lghcc). An explicit-Gaussian stream (from a 3DGS PLY) decodes
to a 3DGS scene in the layout of 3DGS:
  OUT/point_cloud/iteration_0/point_cloud.ply   Gaussians (INRIA 3DGS PLY)
an anchor stream to an anchor scene in the Scaffold-GS layout:
  OUT/point_cloud/iteration_0/point_cloud.ply   anchors
  OUT/point_cloud/iteration_0/checkpoint.pth    render MLPs
The decoder needs nothing but the stream. It checks the hash of the decoded scene
carried in the stream and prints the size of each part (header, geometry,
attributes, model) in bytes and bits per anchor.

examples:
  lghcc-dec demo.lghcc -o decoded/
  lghcc-dec demo.lghcc --trace demo.trace.txt      (no -o: check and report only)
  lghcc-dec demo.lghcc --render orbit:8 --render-out views/    8 PNGs around the scene
  lghcc-dec demo.lghcc --render lego/transforms_test.json --render-out views/
  lghcc-dec demo.lghcc --export-ply demo_3dgs.ply   plain 3DGS PLY for standard viewers
  lghcc-dec big.lghcc -o out/ --jobs 2             at most 2 worker processes (as many as pay)
  lghcc-dec big.lghcc -o part/ --box -1,-1,-1,1,1,1   only the tiles that meet the box
  lghcc-dec big.lghcc -o coarse/ --level 1          level-1 preview (streams with the hierarchy)

A stream of a large scene is cut into tiles (spatial cells, each decodable on its own; the
encoder cuts scenes of 32,768 points or more). What the tile options do, by kind of stream:
  --jobs auto   (default) tiles go to worker processes only where the estimate says it pays:
                each tile's points x channels at the cost of its coding tool (per value, GG-Conv
                of the lghcc-* presets and the neighbour prediction of 3DGS input cost more than
                the per-channel prior of the low/medium/high presets) against a worker's start;
                small scenes of a few tiles stay in one process. The output is the same bit for
                bit; the log says how many workers ran and why. A stream without tiles is one
                tile: one process.
  --box         decodes only the tiles whose cell meets a box given in world coordinates
                (every point of those tiles is output, each tile's hash checked), any kind of
                stream; a stream without tiles decodes whole.
  --level 1     the level-1 preview of a stream with the hierarchy (lghcc-* presets): each
                tile's level-1 anchors, one per coarse voxel (a coarse scene, not hash-checked).
                A stream without the hierarchy (low/medium/high, 3DGS presets) has no preview:
                refused with exit status 2, nothing decoded.

--render takes orbit:N or the cameras of a dataset: a dataset folder of any layout
(NeRF-synthetic, COLMAP sparse/0, Mip-NeRF 360, LLFF poses_bounds.npy; its test views),
a transforms_<split>.json, a COLMAP sparse folder (all its views) or a poses_bounds.npy, or
the cameras a 3DGS capture comes with (all their views): an INRIA cameras.json, a nerfstudio
transforms.json, or a folder holding one (an INRIA model folder).
Dataset cameras render at the size of the dataset's images (COLMAP, LLFF: the full-resolution
images/; --render-scale 0.25 for a quarter of it).

No output may name the input stream or another output. An existing file, or an existing
non-empty -o or --render-out folder, is refused unless -y (--overwrite) is given (then
the decoded scene's files in it are replaced).

Before allocating anything sized by the stream, the decoder computes from its headers how
much memory decoding it takes and refuses a stream that needs more than --max-memory
(exit status 4), naming the amount.
"""


def setup_args() -> argparse.ArgumentParser:
    from .limits import DEFAULT_MAX_MEMORY

    p = argparse.ArgumentParser(prog="lghcc-dec", description=DESCRIPTION, epilog=OVERWRITE_RULE + "\n\n"
                                + exit_status_epilog(codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INVALID_STREAM,
                                                            EXIT_RESOURCE_LIMIT, EXIT_INTERRUPTED)),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    p.add_argument("stream", help="the .lghcc file to decode")
    p.add_argument("-o", "--output", metavar="DIR", help="folder to write the decoded scene to")
    add_overwrite_options(p, "outputs: files, and the decoded scene's files in a non-empty -o or --render-out folder")
    p.add_argument("--no-verify", action="store_true", help="do not check the decoded-scene hash")
    p.add_argument("--trace", metavar="FILE", help="write a bit trace: every syntax element with its position")
    p.add_argument("--threads", type=int, help="torch threads for inference (the output does not depend on it)")
    _add_tile_options(p)
    p.add_argument("--max-points", type=int,
                   help="refuse streams declaring more points (anchors or Gaussians) than this (exit status 4)")
    add_deprecated_alias(p, "--max-anchors", "--max-points", type=int)
    p.add_argument("--max-memory", type=memory_size, default=DEFAULT_MAX_MEMORY, metavar="SIZE",
                   help="refuse a stream whose decoding needs more memory than this, computed from its headers "
                        f"before anything is allocated: e.g. 512M, 8G; 0 or none: no bound "
                        f"(default {format_bytes(DEFAULT_MAX_MEMORY)}; exit status 4)")
    p.add_argument("--print-hash", action="store_true",
                   help="print only the SHA-256 of the decoded scene (spec clause 12), computed from the output")
    p.add_argument("--json", metavar="FILE", help="also write the size breakdown as JSON")
    g = p.add_argument_group("looking at the result")
    g.add_argument("--render", metavar="CAMERAS",
                   help="render the decoded scene: 'orbit:N' (N cameras on a circle around it), a dataset folder "
                        "(NeRF-synthetic, COLMAP, Mip-NeRF 360, LLFF: its test views), a transforms_<split>.json, "
                        "a COLMAP sparse folder, a poses_bounds.npy, or a 3DGS capture's cameras.json (INRIA) "
                        "or transforms.json (nerfstudio)")
    g.add_argument("--render-out", metavar="DIR", help="folder for the rendered PNGs (needed with --render)")
    g.add_argument("--render-size", default="256x256", metavar="WxH", help="image size of orbit cameras (256x256)")
    g.add_argument("--render-scale", type=positive_float, default=1.0,
                   help="scale of the image size of file cameras, a positive number (default 1)")
    g.add_argument("--background", default="black", choices=("black", "white"), help="render background")
    g.add_argument("--export", "--export-ply", dest="export_ply", metavar="FILE",
                   help="also write the decoded scene as a plain 3DGS scene for standard viewers, in the format "
                        "of FILE's extension: .ply (INRIA 3DGS PLY), .spz (Niantic SPZ) or .sog (PlayCanvas SOG); "
                        "--export-ply is the same option")
    g.add_argument("--export-sh-degree", type=int, choices=(0, 1, 2, 3),
                   help="SH degree of the exported colours (default: a Gaussian stream's own degree; for an "
                        "anchor stream, whose colours come from MLPs and are fitted, the source scene's degree "
                        "its source_info unit gives (a transcoded 3DGS scene), else 1)")
    g.add_argument("--export-directions", type=int,
                   help="view directions per anchor over which the MLPs are evaluated (default: 16, or twice "
                        "the SH coefficients per channel when that is more: 18 at degree 2, 32 at degree 3)")
    g.add_argument("--export-distance", type=float,
                   help="camera distance for those views (default 2.5 x the anchors' bounding radius)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    return p


def _add_tile_options(p: argparse.ArgumentParser) -> None:
    """--jobs, --box and --level: what a tiled stream allows (DESCRIPTION says it per stream kind)."""
    p.add_argument("--jobs", type=jobs_arg, default=None, metavar="N|auto",
                   help="worker processes decoding the tiles of a tiled stream: auto (the default) uses as many "
                        "as pay, up to the CPUs, by an estimate of each tile's time (its points, channels and "
                        "coding tool) against a worker's start; N: as many as pay, at most N; 1: this process "
                        "alone. The log says how many ran and why. The output does not depend on it")
    p.add_argument("--box", type=box_arg, metavar="X0,Y0,Z0,X1,Y1,Z1",
                   help="decode only the tiles whose cell meets this box (world coordinates, low corner then "
                        "high corner), every point of those tiles, each tile hash-checked; the other tiles are "
                        "not decoded (their units' CRCs and the tile index are still checked); a stream "
                        "without tiles decodes whole")
    p.add_argument("--level", type=int, choices=(1, 2), default=2,
                   help="1: the level-1 preview of a stream with the hierarchy (the lghcc-* presets; one point "
                        "per coarse voxel of each tile, not hash-checked); a stream without it (the other "
                        "presets) has no preview and is refused (exit status 2); 2: everything (default)")


def _render_size(text: str) -> tuple[int, int]:
    import re

    m = re.fullmatch(r"(\d+)x(\d+)", text)
    if not m or min(int(m.group(1)), int(m.group(2))) < 1:
        raise LghccError(f"--render-size must be WxH, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _render_views(args, scene, say) -> None:
    from ..render.imageio import write_png
    from ..render.scenes import renderer, resolve_cameras

    draw = renderer(scene, args.background)  # refuses a scene without render MLPs, before any file
    cams = resolve_cameras(args.render, scene, size=_render_size(args.render_size), scale=args.render_scale)
    out = Path(args.render_out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise write_error(out, e) from None
    t0 = time.perf_counter()
    for i, cam in enumerate(cams):
        img = draw(cam)
        stem = Path(cam.name).stem if cam.name else f"view_{i:03d}"
        try:
            write_png(out / f"{i:03d}_{stem}.png", img)
        except OSError as e:
            raise write_error(out / f"{i:03d}_{stem}.png", e) from None
    say(f"rendered {len(cams)} views into {out} in {time.perf_counter() - t0:.2f} s")


def export_degree(asked: int | None, source_info) -> tuple[int, str]:
    """SH degree of an anchor stream's export, and where it comes from (in words): the one
    asked for, else the source's (source_info, clause 7.3.10), else 1."""
    if asked is not None:
        return asked, "the degree asked for"
    if source_info is not None:
        return int(source_info.source_sh_degree), "the source's degree (source_info)"
    return 1, "the default degree of anchor streams"


def _other_iterations(path: str) -> list[str]:
    root = Path(path) / "point_cloud"
    return sorted(d.name for d in root.glob("iteration_*") if d.name != "iteration_0") if root.is_dir() else []


def main(argv: list[str] | None = None) -> int:
    """Exit status: lghcc.app.cli_common (0 decoded, 1 input/output error, 2 usage, 3 invalid stream,
    4 resource limit, 130 interrupted), through run_cli: a failure is one line on stderr."""
    return run_cli("lghcc-dec", _main, argv)


def _box_value_attached(argv: list[str]) -> list[str]:
    """'--box -1,-1,-1,1,1,1' as '--box=-1,...': argparse takes a value that starts with '-' and is
    not a plain number for an option."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--box" and i + 1 < len(argv) and argv[i + 1][:2].lstrip("-")[:1] in tuple("0123456789."):
            out.append("--box=" + argv[i + 1])
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def _main(argv: list[str] | None) -> int:
    args = setup_args().parse_args(_box_value_attached(sys.argv[1:] if argv is None else list(argv)))
    from .decode import decode_stream

    say = (lambda *a: None) if args.quiet else print
    note = (lambda *a: None) if args.print_hash else say  # --print-hash prints the hash alone
    _check_outputs(args)
    if args.threads is not None:
        import torch
        torch.set_num_threads(max(1, args.threads))
    try:
        data = Path(args.stream).read_bytes()
    except OSError as e:
        raise LghccError(f"{args.stream}: cannot read ({e.strerror})") from None
    t0 = time.perf_counter()
    try:  # a failure is reported by run_cli: one line, and the exit status of its kind (3 for a hash mismatch)
        result = decode_stream(data, verify_hash=not args.no_verify, trace=bool(args.trace),
                               max_points=args.max_points, max_memory=args.max_memory, progress=not args.quiet,
                               jobs=args.jobs, box=args.box, max_level=args.level)
    except LghccError as e:  # the same class (and exit status), with the stream's path
        raise with_prefix(e, args.stream) from None
    except BrokenProcessPool as e:  # a worker killed (by a signal, or out of memory): nothing is written
        raise LghccError(f"{args.stream}: a decoding worker process died ({e}); try --jobs 1") from None
    t_dec = time.perf_counter() - t0
    for text in result.notes:  # ancillary units reported and ignored (clause 6.3)
        print(f"lghcc-dec: warning: {text}", file=sys.stderr)
    t1 = time.perf_counter()
    if result.tiles_decoded == 0 and (args.output or args.render or args.export_ply):
        raise LghccError(f"{args.stream}: the box meets none of the stream's {result.num_tiles} tiles' cells "
                         "(clause 13.3): the decoded scene is empty, there is nothing to write or draw "
                         "(--print-hash prints the empty scene's hash)")
    if args.output:
        _write_decoded_scene(args, result.scene)
    result.timings["write"] = time.perf_counter() - t1
    if args.render:
        _render_views(args, result.scene, note)
    if args.export_ply:
        _export(args, result, note)
    if args.trace:
        _write_trace(args.trace, result.trace)
    if args.json:
        _write_json(args, result, len(data), t_dec)
    if args.print_hash:
        from ..common.hashing import digest_of
        print(digest_of(result.scene).hex())
        return 0
    if not args.quiet:  # (the summary's hash of a tiled stream's whole scene is a pass over it: not for nothing)
        _print_summary(args, result, len(data), t_dec, say)
    return 0


def _check_outputs(args) -> None:
    """Every output is checked before decoding: none may overwrite the stream or another output,
    nor an existing file without -y."""
    check_output_paths({"-o": args.output, "--json": args.json, "--trace": args.trace,
                        "--export-ply": args.export_ply, "--render-out": args.render_out},
                       {"input stream": args.stream})
    if args.output:
        check_output_folder(args.output, args.overwrite, replaced="the decoded scene's files are replaced; "
                            "other files are left as they are")
    for path in (args.json, args.trace, args.export_ply):
        if path:
            check_overwrite(path, args.overwrite)
    if args.export_ply and Path(args.export_ply).suffix.lower() not in (".ply", ".spz", ".sog"):
        raise LghccError(f"{args.export_ply}: --export writes .ply, .spz or .sog (the format follows the "
                         "extension)")
    if args.render and not args.render_out:
        raise LghccError("--render needs --render-out DIR")
    if args.render:
        _render_size(args.render_size)
    if args.render_out:
        check_output_folder(args.render_out, args.overwrite, replaced="its PNGs of the same names are replaced")


def _write_decoded_scene(args, scene) -> None:
    """-o: a Gaussian stream in the 3DGS layout, an anchor stream in Scaffold-GS's."""
    from ..formats import write_scene

    stale = _other_iterations(args.output)
    if stale and not args.quiet:
        print(f"lghcc-dec: warning: {args.output} also holds point_cloud/{', '.join(stale)}; readers "
              "that take the highest iteration will not read the decoded scene", file=sys.stderr)
    try:
        write_scene(scene, args.output)
    except OSError as e:
        raise write_error(args.output, e) from None


def export_directions(asked: int | None, degree: int) -> int:
    """View directions over which an anchor stream's MLPs are evaluated for its export: the
    number asked for, else 16, or twice the SH coefficients per channel when that is more."""
    return asked if asked is not None else max(16, 2 * (degree + 1) ** 2)


def _export(args, result, note) -> None:
    """--export: the decoded scene as a plain 3DGS scene (PLY, SPZ or SOG); an anchor stream's
    colours fitted at the degree export_degree gives."""
    from ..formats import write_scene

    t1 = time.perf_counter()
    scene = result.scene
    degree, how = args.export_sh_degree, ""
    if isinstance(scene, GaussianScene):
        # to_gaussians' rule for a 3DGS scene, without importing render/ (which loads torch: seconds)
        sc = scene if degree is None else scene.with_sh_degree(degree)
    else:
        from ..render.export import default_distance
        from ..render.scenes import to_gaussians

        degree, origin = export_degree(args.export_sh_degree, result.source_info)
        directions = export_directions(args.export_directions, degree)
        dist = args.export_distance if args.export_distance is not None else default_distance(scene)
        how = f", {origin}; the MLPs evaluated in {directions} directions at distance {dist:.4g}"
        sc = to_gaussians(scene, degree, directions=directions, distance=args.export_distance)
    try:
        write_scene(sc, args.export_ply)
    except OSError as e:
        raise write_error(args.export_ply, e) from None
    kind = {".ply": "3DGS PLY", ".spz": "SPZ", ".sog": "SOG"}[Path(args.export_ply).suffix.lower()]
    note(f"wrote {args.export_ply}: {sc.num_gaussians:,} Gaussians ({kind}, SH degree {sc.sh_degree}{how}) in "
         f"{time.perf_counter() - t1:.2f} s")


def _write_trace(path: str, trace) -> None:
    """--trace: every syntax element with its bit position, descriptor and value."""
    lines = [f"{e.bit_position:>10} {e.name:<60} {e.descriptor:<8} "
             f"{e.value.hex() if isinstance(e.value, bytes) else e.value}" for e in trace]
    try:
        atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())
    except OSError as e:
        raise write_error(path, e) from None


def _write_json(args, result, num_bytes: int, t_dec: float) -> None:
    """--json: the size breakdown, the decoding time and the scene hash, the workers, and the seconds
    of parsing (clause 13.1 steps 1-5), decoding the tiles and writing -o."""
    s = result.scene
    try:
        count = {"num_gaussians": s.num_gaussians} if isinstance(s, GaussianScene) else \
            {"num_anchors": s.num_anchors}
        atomic_write_bytes(args.json, json.dumps({
            "stream": args.stream, **count, "bytes": num_bytes,
            "breakdown": result.breakdown.bytes_by_category, "decode_s": t_dec,
            "hash_checked": result.hash_checked, "scene_sha256": result.stream_hash.hex(),
            "workers": result.workers.workers, "workers_reason": result.workers.reason,
            "tiles": result.num_tiles, "tiles_decoded": result.tiles_decoded,
            "seconds": {k: round(v, 6) for k, v in result.timings.items()}},
            indent=2).encode())
    except OSError as e:
        raise write_error(args.json, e) from None


def _print_summary(args, result, num_bytes: int, t_dec: float, say) -> None:
    s = result.scene
    if isinstance(s, GaussianScene):
        say(f"{args.stream}: {s.num_gaussians:,} Gaussians, SH degree {s.sh_degree}, {num_bytes:,} bytes, decoded in "
            f"{t_dec:.2f} s ({s.num_gaussians / max(t_dec, 1e-9):,.0f} Gaussians/s)")
    else:
        say(f"{args.stream}: {s.num_anchors:,} anchors, C={s.feature_dim}, K={s.num_offsets}, "
            f"{num_bytes:,} bytes, decoded in {t_dec:.2f} s ({s.num_anchors / max(t_dec, 1e-9):,.0f} anchors/s)")
    say(result.breakdown.table())
    if args.box is not None:
        say(f"box: decoded {result.tiles_decoded} of {result.num_tiles} tiles (those whose cell meets the box)")
    if result.preview:
        say("level-1 preview: one point per coarse voxel of each tile; not hash-checked")
    if result.num_tiles > 1:
        say(f"workers: {result.workers.reason}")
    if result.tools:
        say("tools: " + "; ".join(result.tools))
    if result.source_info is not None:
        say(f"source_info: the source scene had SH degree {result.source_info.source_sh_degree}")
    for u in result.skipped_units:
        say(f"skipped ancillary unit {u}")
    if result.num_tiles > 1:  # each tile carries the hash of its own points
        say(f"decoded scene hash: {result.stream_hash.hex()} ("
            + (f"the {result.tiles_decoded} tile hashes decoded match the stream" if result.hash_checked
               else "tile hashes not checked") + ")")
    else:
        say("decoded scene hash: " + ("matches the stream" if result.hash_checked else "not checked")
            + f" ({result.stream_hash.hex()})")
    if args.output:
        say(f"wrote {Path(args.output) / 'point_cloud' / 'iteration_0'}")


if __name__ == "__main__":
    sys.exit(main())
