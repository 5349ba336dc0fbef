"""Compare decoded .lghcc streams with their reference, on the same views.

    python tools/compare.py REFERENCE STREAM.lghcc [STREAM2.lghcc ...] [--views orbit:8]
        [--size 256x256] [--out-md compare.md] [--out-png compare.png]

REFERENCE: a plain 3DGS PLY (f_dc_0, rendered with SH colours) or an anchor checkpoint
(Scaffold-GS model folder, iteration folder or point_cloud.ply). Views: ``orbit:N``
(around the reference), a NeRF-synthetic transforms JSON or a COLMAP sparse folder.
Writes a markdown table (stream, bytes, bits/anchor, PSNR, SSIM, LPIPS or "skipped")
averaged over the views, and per stream a side-by-side PNG of the first view:
reference | decoded | |difference| x ``--diff-gain`` (default 4).
"""

from __future__ import annotations

import os

# Before torch is imported (OpenMP reads it once): without it, OpenMP threads spin at barriers and
# on a shared machine a 2-thread 100k-Gaussian forward took 7.55 s instead of 1.81 s (see encoder/training/__init__.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import datetime
import re
import sys
from pathlib import Path

import numpy as np

from lghcc.common.errors import LghccError
from lghcc.common.scene import GaussianScene
from lghcc.decoder.decode import decode_stream
from lghcc.formats import read_scene
from lghcc.render.imageio import background_color, write_png
from lghcc.render.metrics import lpips, lpips_status, psnr, ssim
from lghcc.render.scenes import framing_points, render_fn
from lghcc.render.views import cameras_from_spec


def _renderer(ref: str):
    """(render(camera, bg) -> [H, W, 3] numpy, positions for orbit cameras, description)."""
    scene = read_scene(ref)
    desc = (f"3DGS scene, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}"
            if isinstance(scene, GaussianScene) else f"anchor scene, {scene.num_anchors:,} anchors")
    return render_fn(scene), framing_points(scene), desc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("reference", help="3DGS PLY or Scaffold-GS checkpoint")
    p.add_argument("streams", nargs="+", help=".lghcc files")
    p.add_argument("--views", default="orbit:8", help="orbit:N, transforms JSON or COLMAP folder (default orbit:8)")
    p.add_argument("--size", default="256x256", help="image size of orbit views (default 256x256)")
    p.add_argument("--scale", type=float, default=1.0, help="scale of file cameras' image size")
    p.add_argument("--background", default="black", choices=("black", "white"))
    p.add_argument("--out-md", default="compare.md", help="markdown table to write")
    p.add_argument("--out-png", default="compare.png",
                   help="side-by-side PNG (with several streams, the stream's name is appended)")
    p.add_argument("--diff-gain", type=float, default=4.0, help="gain of the difference panel (default 4)")
    p.add_argument("--no-lpips", action="store_true", help="do not try LPIPS")
    p.add_argument("--note", default="", help="a line to add under the table (e.g. data credit)")
    args = p.parse_args(argv)
    try:
        m = re.fullmatch(r"(\d+)x(\d+)", args.size)
        if not m:
            raise LghccError(f"--size must be WxH, got {args.size!r}")
        render_ref, pos, desc = _renderer(args.reference)
        cams = cameras_from_spec(args.views, pos, width=int(m.group(1)), height=int(m.group(2)), scale=args.scale)
        bg = background_color(args.background)
        refs = [render_ref(c, bg) for c in cams]
        use_lpips = not args.no_lpips and lpips_status()[0]
        why_no_lpips = "--no-lpips" if args.no_lpips else lpips_status()[1]
        rows = []
        for s in args.streams:
            data = Path(s).read_bytes()
            res = decode_stream(data)
            draw = render_fn(res.scene)
            imgs = [draw(c, bg) for c in cams]
            ps = float(np.mean([psnr(a, b) for a, b in zip(imgs, refs)]))
            ss = float(np.mean([ssim(a, b) for a, b in zip(imgs, refs)]))
            lp = float(np.mean([lpips(a, b) for a, b in zip(imgs, refs)])) if use_lpips else None
            n = res.scene.num_points  # anchors, or Gaussians of an explicit-Gaussian stream
            rows.append((s, len(data), 8 * len(data) / n, n, ps, ss, lp))
            out_png = Path(args.out_png)
            if len(args.streams) > 1:
                out_png = out_png.with_name(f"{out_png.stem}_{Path(s).stem}{out_png.suffix}")
            diff = np.clip(np.abs(imgs[0] - refs[0]) * args.diff_gain, 0, 1)
            write_png(out_png, np.concatenate([refs[0], imgs[0], diff], axis=1))
            print(f"{s}: PSNR {ps:.2f} dB, SSIM {ss:.4f} -> {out_png}", flush=True)
    except (LghccError, OSError) as e:
        print(f"compare: error: {e}", file=sys.stderr)
        return 1
    lines = [f"# Decoded vs reference: {args.reference}", "",
             f"Reference: {desc}. Views: {args.views} ({len(cams)} views, {cams[0].width}x{cams[0].height}), "
             f"background {args.background}. Date: {datetime.date.today().isoformat()}.", "",
             "| stream | bytes | anchors | bits/anchor | PSNR dB | SSIM | LPIPS |", "|---|---:|---:|---:|---:|---:|---:|"]
    for s, nb, bpa, na, ps, ss, lp in rows:
        lines.append(f"| {Path(s).name} | {nb:,} | {na:,} | {bpa:.1f} | {ps:.2f} | {ss:.4f} | "
                     f"{'skipped' if lp is None else f'{lp:.4f}'} |")
    lines += ["", f"Side-by-side: reference | decoded | |difference| x {args.diff_gain:g}."]
    if not use_lpips:
        lines.append(f"LPIPS skipped: {why_no_lpips}.")
    if args.note:
        lines.append(args.note)
    Path(args.out_md).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
