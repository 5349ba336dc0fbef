"""lghcc-view: a decoded .lghcc stream as one self-contained, interactive HTML page."""

from __future__ import annotations

import os

# Rendering the metric views runs torch's OpenMP kernels: passive waiting keeps threads from
# spinning against other jobs on a shared machine (see decoder/cli.py). Set before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import html  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from ..app.cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_OK,  # noqa: E402
                              EXIT_RESOURCE_LIMIT, EXIT_USAGE, exit_status_epilog, with_prefix)
from ..common.errors import HashMismatchError, LghccError  # noqa: E402
from ..app.cliargs import (OVERWRITE_RULE, add_overwrite_options, add_version_option,  # noqa: E402
                                  run_cli)
from ..app.fileio import atomic_write_bytes, check_output_paths, check_overwrite, write_error  # noqa: E402

DESCRIPTION = """\
Write a decoded LG-HCC stream as ONE self-contained HTML page that shows the scene
interactively in a WebGL2 browser, with no network: the renderer (the PlayCanvas engine,
pinned in tools/node and bundled once by `make viewer-bundle`) and the decoded scene (as a
3DGS PLY) are inside the file.

The page shows the stream's size per part (bytes, bits per anchor and per Gaussian) and,
with --source, the decoded scene beside its source with one camera for both, and the PSNR/SSIM
of the decoded scene against the source over orbit views rendered by lghcc.render on the CPU.
It also shows the "export PSNR": how close the 3DGS Gaussians on the page come to the decoded
anchor scene (neural Gaussians are view-dependent; a 3DGS PLY only through its SH colours).

The stream's hash is checked first: a stream whose decoded scene does not match it gets no page.

examples:
  lghcc-view scene.lghcc -o scene.html
  lghcc-view scene.lghcc -o scene.html --source ../shared/data/donut/donut.ply
  lghcc-view scene.lghcc -o scene.html --source runs/lego100 --views 8
"""


def _size(text: str, opt: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text)
    if not m or min(int(m.group(1)), int(m.group(2))) < 1:
        raise LghccError(f"{opt} must be WxH, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _vector(text: str, opt: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",")], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) == 0:
        raise LghccError(f"{opt} must be three numbers x,y,z, not all zero, got {text!r}")
    return v / np.linalg.norm(v)


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lghcc-view", description=DESCRIPTION,
                                epilog=OVERWRITE_RULE + "\n\n" + exit_status_epilog(
                                    {EXIT_INVALID_STREAM: "invalid stream (malformed, unsupported, or its decoded "
                                                          "scene does not match its hash): no page is written",
                                     EXIT_RESOURCE_LIMIT: "resource limit (the decoder's default memory bound, "
                                                          "or the system ran out of memory)"},
                                    codes=(EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INVALID_STREAM, EXIT_RESOURCE_LIMIT,
                                           EXIT_INTERRUPTED)),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(p)
    p.add_argument("stream", help="the .lghcc file to show")
    p.add_argument("-o", "--output", required=True, metavar="HTML", help="the page to write")
    add_overwrite_options(p, "page (-o)")
    p.add_argument("--source", metavar="SCENE",
                   help="the scene the stream was encoded from (plain 3DGS PLY, or Scaffold-GS model folder / PLY): "
                        "shown beside the decoded scene, same camera; PSNR/SSIM against it")
    p.add_argument("--views", type=int, default=4, help="orbit views for the PSNR on the page (default 4)")
    p.add_argument("--psnr-size", default="256x256", metavar="WxH", help="image size of those views (256x256)")
    p.add_argument("--no-psnr", action="store_true", help="render nothing on the CPU: no PSNR on the page (faster)")
    p.add_argument("--up", default="0,0,1", metavar="X,Y,Z",
                   help="the scene's up direction for the orbit views and the page's camera (default 0,0,1)")
    p.add_argument("--background", default="black", choices=("black", "white"), help="background (black)")
    p.add_argument("--title", help="page title (default: the stream's file name)")
    p.add_argument("--note", default="", help="a line to show on the page (e.g. the data's credit)")
    p.add_argument("--export-sh-degree", type=int, default=1, choices=(0, 1, 2, 3),
                   help="SH degree of anchor scenes exported for the page (default 1)")
    p.add_argument("--export-directions", type=int, default=16, help="view directions of that export (default 16)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    return p


def orbit_view(positions: np.ndarray, up: np.ndarray, *, width: int, height: int) -> tuple[object, dict]:
    """The first orbit camera around ``positions`` (lghcc.render.views.orbit_cameras: the
    PSNR views and the page's first view are the same camera) and its page form: eye,
    target (the centre of the points' 1%..99% box, which orbit_cameras looks at), up,
    horizontal field of view, near and far."""
    from ..render.views import orbit_cameras

    cam = orbit_cameras(positions, 1, width=width, height=height, up=tuple(up))[0]
    p = np.asarray(positions, np.float64)
    target = (np.quantile(p, 0.01, axis=0) + np.quantile(p, 0.99, axis=0)) / 2
    return cam, {"eye": [float(x) for x in cam.center], "target": [float(x) for x in target],
                 "up": [float(x) for x in up], "fov_x_deg": math.degrees(cam.fov_x), "near": cam.near,
                 "far": cam.far}


def in_js_profile(data: bytes) -> bool:
    """Whether the page's JavaScript decoder (js/lghcc-decoder) decodes this stream: a
    gaussian_parameter_set without the hierarchy (the explicit-Gaussian profile, spec clause 8.4)."""
    from ..common.bitio import BitReader
    from ..common.container import UnitType, read_container
    from ..common.units import GaussianParameterSet

    first = next(u for u in read_container(data).units if u.unit_type < 0x80)
    if first.unit_type != UnitType.GAUSSIAN_PARAMETER_SET:
        return False
    return not GaussianParameterSet.parse(BitReader(first.payload, "gaussian_parameter_set")).hierarchy_enabled_flag


def _say_nothing(*_a, **_k) -> None:
    return None


def main(argv: list[str] | None = None) -> int:
    """Exit status: lghcc.app.cli_common (0 page written, 1 input/output error, 2 usage, 3 invalid stream
    (malformed, or its decoded scene fails its hash: no page), 4 resource limit, 130 interrupted)."""
    return run_cli("lghcc-view", _main, argv)


def _main(argv: list[str] | None) -> int:
    args = setup_args().parse_args(argv)
    say = _say_nothing if args.quiet else (lambda *a: print(*a, flush=True))
    try:
        return _run(args, say)
    except HashMismatchError as e:
        raise type(e)(f"{args.stream}: {e}; no page written", condition=e.condition) from None  # exit status 3


def _check_args(args) -> tuple[int, int, np.ndarray]:
    """Everything a user can get wrong, checked before minutes of decoding and rendering:
    (PSNR width, height, up vector)."""
    from .page import bundle_js

    check_output_paths({"-o": args.output}, {"input stream": args.stream, "--source": args.source})
    check_overwrite(Path(args.output), args.overwrite)
    if args.views < 1:
        raise LghccError(f"--views must be at least 1, got {args.views}")
    if args.export_directions < (args.export_sh_degree + 1) ** 2:
        raise LghccError(f"--export-sh-degree {args.export_sh_degree} needs --export-directions >= "
                         f"{(args.export_sh_degree + 1) ** 2}")
    pw, ph = _size(args.psnr_size, "--psnr-size")
    up = _vector(args.up, "--up")
    if args.source and not Path(args.source).exists():
        raise LghccError(f"--source {args.source}: no such file or folder")
    bundle_js()  # a missing set-up step is reported now, not after the work
    return pw, ph, up


def _decode(args, say):
    """(the stream's bytes, its decode with the hash checked, seconds)."""
    from ..decoder.decode import decode_stream

    try:
        data = Path(args.stream).read_bytes()
    except OSError as e:
        raise LghccError(f"{args.stream}: cannot read ({e.strerror})") from None
    t0 = time.perf_counter()
    try:
        result = decode_stream(data, verify_hash=True)
    except HashMismatchError:
        raise
    except LghccError as e:  # the same class (and exit status), with the stream's path
        raise with_prefix(e, args.stream) from None
    t_dec = time.perf_counter() - t0
    say(f"{args.stream}: {len(data):,} bytes, decoded in {t_dec:.2f} s, hash matches")
    return data, result, t_dec


def _scenes(args, result, say):
    """(the decoded scene as Gaussians, the --source scene or None)."""
    from .scenes import gaussians_of_decoded, load_source

    t0 = time.perf_counter()
    decoded = gaussians_of_decoded(result.scene, sh_degree=args.export_sh_degree,
                                   num_directions=args.export_directions)
    say(f"decoded scene: {decoded.description} ({time.perf_counter() - t0:.2f} s)")
    if not args.source:
        return decoded, None
    t0 = time.perf_counter()
    try:
        source = load_source(args.source, sh_degree=args.export_sh_degree, num_directions=args.export_directions)
    except LghccError as e:
        raise LghccError(f"--source {args.source}: {e}") from None
    say(f"source: {source.description} ({time.perf_counter() - t0:.2f} s)")
    return decoded, source


def _fidelity(args, decoded, source, frame, size: tuple[int, int], up, bg, say):
    """(decoded against source, shown Gaussians against the decoded scene): mean metrics over the
    orbit views, each None where it does not apply."""
    from ..render.views import orbit_cameras
    from .page import mean_metrics
    from .scenes import render_gaussians_fn

    if args.no_psnr:
        return None, None
    fidelity, export = None, None
    t0 = time.perf_counter()
    cams = orbit_cameras(frame, args.views, width=size[0], height=size[1], up=tuple(up))
    dec_imgs = [decoded.render(c, bg) for c in cams]
    if source is not None:
        fidelity = mean_metrics(dec_imgs, [source.render(c, bg) for c in cams])
    if decoded.export_stats is not None:  # what the page shows against what the decoder rebuilds
        shown = render_gaussians_fn(decoded.gaussians)
        export = mean_metrics([shown(c, bg) for c in cams], dec_imgs)
    say(f"rendered {len(cams)} views of {size[0]}x{size[1]} on the CPU in {time.perf_counter() - t0:.2f} s: "
        + ", ".join(x for x in (
            f"PSNR vs source {fidelity['psnr']:.2f} dB" if fidelity else "",
            f"export PSNR {export['psnr']:.2f} dB" if export else "") if x))
    return fidelity, export


def _summary_html(args, data: bytes, num_anchors, ng: int, fidelity) -> str:
    from .page import fmt_db

    nbits = 8 * len(data)
    summary = [f"<b>{len(data):,} bytes</b>"]
    if num_anchors:
        summary.append(f"{nbits / num_anchors:.1f} bits/anchor ({num_anchors:,} anchors)")
    summary.append(f"{nbits / ng:.2f} bits/Gaussian ({ng:,} Gaussians shown)")
    if fidelity:
        summary.append(f"PSNR vs source <b>{fmt_db(fidelity['psnr'])}</b>, SSIM {fidelity['ssim']:.4f}")
    elif args.no_psnr:
        summary.append("PSNR not computed (--no-psnr)")
    else:
        summary.append("PSNR: no --source given")
    summary.append("hash ✓")
    return " · ".join(summary)


def _details_html(args, result, decoded, source, t_dec: float, fidelity, export, size, num_anchors) -> str:
    from .page import ENGINE_NAME, ENGINE_VERSION, fmt_db, size_table_html

    details = [size_table_html(result.breakdown.bytes_by_category, num_anchors, decoded.gaussians.num_gaussians),
               f"<div>decoded: {html.escape(decoded.description)}; decoded in {t_dec:.2f} s</div>"]
    if result.tools:
        details.append(f"<div>tools: {html.escape('; '.join(result.tools))}</div>")
    if source is not None:
        details.append(f"<div>source: {html.escape(Path(args.source).name)}: {html.escape(source.description)}</div>")
    if fidelity:
        per_view = ", ".join(f"{p:.2f}" for p in fidelity["psnr_views"])
        details.append(f"<div>decoded vs source: PSNR {fmt_db(fidelity['psnr'])} (per view: {per_view}), "
                       f"SSIM {fidelity['ssim']:.4f}: {args.views} orbit views of {size[0]}x{size[1]}, rendered "
                       "on the CPU by lghcc.render (the decoded scene as the decoder rebuilds it)</div>")
    if export:
        details.append(f"<div>export PSNR {fmt_db(export['psnr'])}, SSIM {export['ssim']:.4f}: the 3DGS Gaussians "
                       "shown here against the decoded anchor scene, same views</div>")
    details.append(f"<div class='hash'>decoded scene SHA-256 (checked): {result.stream_hash.hex()}</div>")
    details.append(f"<div>renderer: {ENGINE_NAME} {ENGINE_VERSION} (WebGL2), bundled in this page</div>")
    return "\n".join(details)


def _run(args, say) -> int:
    from ..render.imageio import background_color
    from .page import Pane, build_page
    from .scenes import ply_bytes

    pw, ph, up = _check_args(args)
    out = Path(args.output)
    data, result, t_dec = _decode(args, say)
    decoded, source = _scenes(args, result, say)
    frame = source.positions if source is not None else decoded.positions
    _, camera = orbit_view(frame, up, width=pw, height=ph)
    bg = background_color(args.background)
    fidelity, export = _fidelity(args, decoded, source, frame, (pw, ph), up, bg, say)
    num_anchors = getattr(result.scene, "num_anchors", None)
    # an explicit-Gaussian stream the page's own decoder takes (spec clause 8.4) travels as itself and is
    # decoded in the page; any other as the decoded scene's PLY
    panes = [Pane("decoded", "decoded", stream=data) if in_js_profile(data)
             else Pane("decoded", "decoded", ply_bytes(decoded.gaussians))]
    if source is not None:
        panes.insert(0, Pane("source", "source", ply_bytes(source.gaussians)))
    page = build_page(title=args.title or f"{Path(args.stream).name} (lghcc)", panes=panes,
                      meta={"camera": camera, "background": [float(x) for x in bg]},
                      summary_html=_summary_html(args, data, num_anchors, decoded.gaussians.num_gaussians, fidelity),
                      details_html=_details_html(args, result, decoded, source, t_dec, fidelity, export, (pw, ph),
                                                 num_anchors), note=args.note)
    try:
        atomic_write_bytes(out, page.encode("utf-8"))
    except OSError as e:
        raise write_error(out, e) from None
    say(f"wrote {out} ({out.stat().st_size:,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
