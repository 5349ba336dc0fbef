#!/usr/bin/env python
"""Do the encoder's views see what pruning removes? (informative; encoder/gaussians/gaussian_fit.py,
"views that resolve the Gaussians").

For each scene (a 3DGS PLY): the typical Gaussian's size in pixels of the orbit views at the
search (128 px) and fit (160 px) resolutions and the magnification ``resolve_px`` gives; then,
for the scene pruned by contribution (measured as the encoder measures it, at ``fit_resolution``
without magnification), the PSNR of the pruned scene against the source on the 128 px orbit
views, on 320 px orbit views (the resolution tools/bench_real.py evaluates at) and on 128 px
crops magnified as the search would (m at 128 px, at least 2 so that every scene shows one).
Views whose PSNR follows the 320 px column can judge pruning; views far above it are blind.

    python tools/bench_resolve.py donut playcanvas-logo          # writes tools/results/resolve.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import datetime  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from lghcc.encoder.stream.config import GaussianEncoderConfig  # noqa: E402
from lghcc.encoder.gaussians.gaussian_fit import measure_contributions  # noqa: E402
from lghcc.encoder.gaussians.gaussian_views import (crop_cameras, fit_cameras, magnification,  # noqa: E402
                                          prune_by_contribution, typical_size_px)
from lghcc.formats.ply3dgs import read_3dgs_ply  # noqa: E402
from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs  # noqa: E402

from benchutil import command_line  # noqa: E402  (tools/ is on the path when run as a script)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SCENES = {"donut": "donut/donut.ply", "playbot-lod4": "playbot/playbot_lod4_8k.ply",
          "playbot-lod3": "playbot/playbot_lod3_31k.ply", "playcanvas-logo": "playcanvas-logo/playcanvas_logo_307k.ply"}
SHARES = (0.01, 0.03, 0.1)


def _render_all(g, cams):
    with torch.no_grad():
        return [render_3dgs(g, c, background=(0, 0, 0), backend="torch").image for c in cams]


def _psnr(images, refs) -> float:
    mse = float(np.mean([((a - b) ** 2).double().mean().item() for a, b in zip(images, refs)]))
    return -10 * math.log10(max(mse, 1e-12))


def measure(name: str, path: Path, views: int) -> list[str]:
    cfg = GaussianEncoderConfig()
    scene = read_3dgs_ply(path)
    m_search = magnification(scene, cfg.search_resolution, cfg.resolve_px)
    m_fit = magnification(scene, cfg.fit_resolution, cfg.resolve_px)
    size_px = typical_size_px(scene, cfg.search_resolution)
    g = gaussians_from_scene(scene)
    contrib = measure_contributions(g, fit_cameras(scene, cfg.fit_views, cfg.fit_resolution), False)
    sets = {"orbit 128 px": fit_cameras(scene, views, 128), "orbit 320 px": fit_cameras(scene, views, 320),
            f"crops x{max(m_search, 2.0):.2f} at 128 px": crop_cameras(scene, views, 128, max(m_search, 2.0))}
    refs = {k: _render_all(g, c) for k, c in sets.items()}
    rows = []
    for share in SHARES:
        keep = prune_by_contribution(contrib, share)
        gk = gaussians_from_scene(scene.subset(keep))
        psnrs = [f"{_psnr(_render_all(gk, c), refs[k]):.2f}" for k, c in sets.items()]
        rows.append(f"| {name} | {scene.num_gaussians:,} | {size_px:.3f} | {m_search:.2f} / {m_fit:.2f} | {share:g} | "
                    f"{int((~keep).sum()):,} | " + " | ".join(psnrs) + f" | {list(sets)[2]} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 1)[1])
    ap.add_argument("scenes", nargs="*", default=list(SCENES), help=f"names ({', '.join(SCENES)}) or PLY paths")
    ap.add_argument("--views", type=int, default=8, help="views per set (default 8)")
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "resolve.md"))
    args = ap.parse_args()
    torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    t0 = time.perf_counter()
    rows = []
    for s in args.scenes:
        path = DATA / SCENES[s] if s in SCENES else Path(s)
        if not path.is_file():
            raise SystemExit(f"bench_resolve: {path}: no such file (scenes: {', '.join(SCENES)} under {DATA})")
        rows += measure(s if s in SCENES else path.stem, path, args.views)
        print("\n".join(rows[-len(SHARES):]), flush=True)
    text = (
        "# Do the encoder's views see what pruning removes?\n\n"
        f"Command: `{command_line('bench_resolve.py')}`  \nDate: {datetime.date.today()}; {time.perf_counter() - t0:.0f} s on a shared "
        "2-core machine.  \nPSNR of the scene pruned by contribution (the least contributing Gaussians holding the "
        "share given, contributions as the encoder measures them without magnification: 24 orbit views at 160 px) "
        f"against the source, on {args.views} views of each set. size = the typical Gaussian (median of exp(mean log "
        "scale)) in pixels of a 128 px orbit view; m = the magnification resolve_px = 0.1 gives at 128 px (search) / "
        "160 px (fit). The crops are magnified by max(m, 2). Views whose PSNR follows the 320 px column judge pruning "
        "as the evaluation at 320 px (tools/bench_real.py) does; views far above it are blind to it.\n\n"
        "| scene | Gaussians | size px at 128 | m search / fit | share pruned | Gaussians pruned | orbit 128 px dB | "
        "orbit 320 px dB | crops dB | crops |\n|---|---:|---:|---|---:|---:|---:|---:|---:|---|\n" + "\n".join(rows) + "\n")
    Path(args.out).write_text(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
