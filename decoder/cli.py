"""lghcc-dec: decode a .lghcc file into the Scaffold-GS checkpoint layout."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# Rendering (--render) runs torch's OpenMP kernels: passive waiting keeps 2 threads from spinning
# against other jobs on a shared machine (100k Gaussians forward: 7.6 s spinning, 1.8 s passive).
# Set before torch is imported; a user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np

from lghcc.common.cliargs import positive_float
from lghcc.common.errors import HashMismatchError, LghccError
from lghcc.common.scene import GaussianScene
from lghcc.common.fileio import atomic_write_bytes, check_output_paths, check_writable_file, write_error

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

No output may name the input stream or another output. An existing, non-empty -o folder
is refused unless --force is given (then the decoded scene's files in it are replaced).
"""


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lghcc-dec", description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("stream", help="the .lghcc file to decode")
    p.add_argument("-o", "--output", metavar="DIR", help="folder to write the decoded scene to")
    p.add_argument("-f", "--force", action="store_true",
                   help="write into an existing non-empty -o folder (the decoded scene's files are replaced)")
    p.add_argument("--no-verify", action="store_true", help="do not check the decoded-scene hash")
    p.add_argument("--trace", metavar="FILE", help="write a bit trace: every syntax element with its position")
    p.add_argument("--threads", type=int, help="torch threads for inference (the output does not depend on it)")
    p.add_argument("--max-anchors", type=int, help="refuse streams declaring more anchors than this")
    p.add_argument("--print-hash", action="store_true",
                   help="print only the SHA-256 of the decoded scene (spec clause 12), computed from the output")
    p.add_argument("--json", metavar="FILE", help="also write the size breakdown as JSON")
    g = p.add_argument_group("looking at the result")
    g.add_argument("--render", metavar="CAMERAS",
                   help="render the decoded scene: 'orbit:N' (N cameras on a circle around it), a NeRF-synthetic "
                        "transforms_<split>.json, or a COLMAP sparse folder")
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


def _render_views(args, scene, say) -> None:
    import re

    import torch

    from lghcc.render.imageio import background_color, write_png
    from lghcc.render.rasterizer import render_scene
    from lghcc.render.views import cameras_from_spec

    m = re.fullmatch(r"(\d+)x(\d+)", args.render_size)
    if not m or min(int(m.group(1)), int(m.group(2))) < 1:
        raise LghccError(f"--render-size must be WxH, got {args.render_size!r}")
    if not args.render_out:
        raise LghccError("--render needs --render-out DIR")
    gaussians = isinstance(scene, GaussianScene)
    cams = cameras_from_spec(args.render, scene.means if gaussians else scene.positions(), width=int(m.group(1)),
                             height=int(m.group(2)), scale=args.render_scale)
    out = Path(args.render_out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise write_error(out, e) from None
    bg = background_color(args.background)
    if gaussians:
        from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs

        g = gaussians_from_scene(scene)
        render = lambda cam: render_3dgs(g, cam, background=bg)  # noqa: E731
    else:
        from lghcc.render.neural_gaussians import SceneTensors

        st = SceneTensors.from_scene(scene)
        render = lambda cam: render_scene(st, cam, background=bg)  # noqa: E731
    t0 = time.perf_counter()
    with torch.no_grad():
        for i, cam in enumerate(cams):
            img = render(cam).image.clamp(0, 1).numpy()
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


def _check_output_folder(path: str, force: bool) -> None:
    """-o: an existing folder must be empty unless --force; an existing file is an error; a new
    folder must be creatable. Raises LghccError before any decoding work is done."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise LghccError(f"cannot write {p} (it exists and is not a folder)")
    if p.is_dir():
        if any(p.iterdir()) and not force:
            raise LghccError(f"{p} is not empty; use --force to write the decoded scene into it "
                             "(its files are replaced; other files are left as they are)")
        if not os.access(p, os.W_OK | os.X_OK):
            raise LghccError(f"cannot write {p} (permission denied)")
        return
    parent = p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise LghccError(f"cannot write {p} (cannot create a folder in {parent})")


def _other_iterations(path: str) -> list[str]:
    root = Path(path) / "point_cloud"
    return sorted(d.name for d in root.glob("iteration_*") if d.name != "iteration_0") if root.is_dir() else []


def main(argv: list[str] | None = None) -> int:
    args = setup_args().parse_args(argv)
    from lghcc.common.scaffold_io import write_scaffold
    from lghcc.decoder.decode import decode_stream
    from lghcc.formats.ply3dgs import write_3dgs_ply

    say = (lambda *a: None) if args.quiet else print
    note = (lambda *a: None) if args.print_hash else say  # --print-hash prints the hash alone
    try:
        # Every output is checked before decoding: none may overwrite the stream or another output.
        check_output_paths({"-o": args.output, "--json": args.json, "--trace": args.trace,
                            "--export-ply": args.export_ply, "--render-out": args.render_out},
                           {"input stream": args.stream})
        if args.output:
            _check_output_folder(args.output, args.force)
        for path in (args.json, args.trace, args.export_ply):
            if path:
                check_writable_file(path)
        if args.export_ply and Path(args.export_ply).suffix.lower() not in (".ply", ".spz", ".sog"):
            raise LghccError(f"{args.export_ply}: --export writes .ply, .spz or .sog (the format follows the "
                             "extension)")
        if args.render and not args.render_out:
            raise LghccError("--render needs --render-out DIR")
        if args.render_out and Path(args.render_out).exists() and not Path(args.render_out).is_dir():
            raise LghccError(f"cannot write {args.render_out} (it exists and is not a folder)")
        if args.threads is not None:
            import torch
            torch.set_num_threads(max(1, args.threads))
        try:
            data = Path(args.stream).read_bytes()
        except OSError as e:
            raise LghccError(f"{args.stream}: cannot read ({e.strerror})") from None
        t0 = time.perf_counter()
        try:
            result = decode_stream(data, verify_hash=not args.no_verify, trace=bool(args.trace),
                                   max_anchors=args.max_anchors, progress=not args.quiet and sys.stderr.isatty())
        except HashMismatchError as e:
            print(f"lghcc-dec: error: {args.stream}: {e}", file=sys.stderr)
            return 3
        except LghccError as e:
            raise LghccError(f"{args.stream}: {e}") from None
        t_dec = time.perf_counter() - t0
        if args.output:
            stale = _other_iterations(args.output)
            if stale and not args.quiet:
                print(f"lghcc-dec: warning: {args.output} also holds point_cloud/{', '.join(stale)}; readers "
                      "that take the highest iteration will not read the decoded scene", file=sys.stderr)
            try:
                if isinstance(result.scene, GaussianScene):  # the 3DGS layout
                    folder = Path(args.output) / "point_cloud" / "iteration_0"
                    folder.mkdir(parents=True, exist_ok=True)
                    write_3dgs_ply(folder / "point_cloud.ply", result.scene)
                else:
                    write_scaffold(result.scene, args.output)
            except OSError as e:
                raise write_error(args.output, e) from None
        if args.render:
            _render_views(args, result.scene, note)
        if args.export_ply:
            t1 = time.perf_counter()
            from lghcc.formats import write_scene

            if isinstance(result.scene, GaussianScene):
                sc = result.scene if args.export_sh_degree is None else result.scene.with_sh_degree(args.export_sh_degree)
                how = ""
            else:
                from lghcc.render.export import export_3dgs

                degree, origin = export_degree(args.export_sh_degree, result.source_info)
                directions = args.export_directions
                if directions is None:
                    directions = max(16, 2 * (degree + 1) ** 2)
                ex = export_3dgs(result.scene, None, sh_degree=degree, num_directions=directions,
                                 distance=args.export_distance)
                sc = GaussianScene(ex.means.astype(np.float32), ex.sh.astype(np.float32),
                                   ex.opacity_logits.astype(np.float32), ex.log_scales.astype(np.float32),
                                   ex.quats.astype(np.float32))
                how = (f", {origin}; the MLPs evaluated in {directions} directions at distance "
                       f"{ex.stats['distance']:.4g}")
            try:
                write_scene(sc, args.export_ply)
            except OSError as e:
                raise write_error(args.export_ply, e) from None
            kind = {".ply": "3DGS PLY", ".spz": "SPZ", ".sog": "SOG"}[Path(args.export_ply).suffix.lower()]
            note(f"wrote {args.export_ply}: {sc.num_gaussians:,} Gaussians ({kind}, SH degree {sc.sh_degree}{how}) in "
                 f"{time.perf_counter() - t1:.2f} s")
        if args.trace:
            lines = [f"{e.bit_position:>10} {e.name:<60} {e.descriptor:<8} "
                     f"{e.value.hex() if isinstance(e.value, bytes) else e.value}" for e in result.trace]
            try:
                atomic_write_bytes(args.trace, ("\n".join(lines) + "\n").encode())
            except OSError as e:
                raise write_error(args.trace, e) from None
        s = result.scene
        if args.json:
            try:
                count = {"num_gaussians": s.num_gaussians} if isinstance(s, GaussianScene) else \
                    {"num_anchors": s.num_anchors}
                atomic_write_bytes(args.json, json.dumps({
                    "stream": args.stream, **count, "bytes": len(data),
                    "breakdown": result.breakdown.bytes_by_category, "decode_s": t_dec,
                    "hash_checked": result.hash_checked, "scene_sha256": result.stream_hash.hex()},
                    indent=2).encode())
            except OSError as e:
                raise write_error(args.json, e) from None
    except LghccError as e:
        print(f"lghcc-dec: error: {e}", file=sys.stderr)
        return 1
    if args.print_hash:
        from lghcc.common.hashing import digest_of
        print(digest_of(s).hex())
        return 0
    if isinstance(s, GaussianScene):
        say(f"{args.stream}: {s.num_gaussians:,} Gaussians, SH degree {s.sh_degree}, {len(data):,} bytes, decoded in "
            f"{t_dec:.2f} s ({s.num_gaussians / max(t_dec, 1e-9):,.0f} Gaussians/s)")
    else:
        say(f"{args.stream}: {s.num_anchors:,} anchors, C={s.feature_dim}, K={s.num_offsets}, "
            f"{len(data):,} bytes, decoded in {t_dec:.2f} s ({s.num_anchors / max(t_dec, 1e-9):,.0f} anchors/s)")
    say(result.breakdown.table())
    if result.tools:
        say("tools: " + "; ".join(result.tools))
    if result.source_info is not None:
        say(f"source_info: the source scene had SH degree {result.source_info.source_sh_degree}")
    for u in result.skipped_units:
        say(f"skipped ancillary unit {u}")
    for note_text in result.notes:
        print(f"lghcc-dec: warning: {note_text}", file=sys.stderr)
    say("decoded scene hash: " + ("matches the stream" if result.hash_checked else "not checked")
        + f" ({result.stream_hash.hex()})")
    if args.output:
        say(f"wrote {Path(args.output) / 'point_cloud' / 'iteration_0'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
