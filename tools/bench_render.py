#!/usr/bin/env python3
"""Benchmark the CPU renderer (lghcc.render): rasterizer forward/backward time at 800x800 for
10k / 100k / 1M Gaussians, and what frustum culling and opacity masking save when anchors
become neural Gaussians, on the lego test cameras.

Scenes:
  * rasterizer: M Gaussians on an ellipsoid shell filling lego's bounding box
    (centre (0, 0, 0.35), semi-axes 0.65 x 1.1 x 0.6), scales uniform in [0.3, 0.9] x
    sqrt(area / M) (so the shell stays covered at every M), random rotations, opacities
    uniform in [0.05, 0.95], random colours; seen from lego test camera r_0 at 800x800.
  * anchors: lghcc.formats.procedural.make_procedural_scene (torus, sphere, ground plane in
    [-1, 1]^3, Scaffold-GS MLP shapes, random weights), scaled by 0.65 and lifted by 0.35 in
    z into lego's bounding box; with the HAC offset mask. Views: the lego test cameras at
    800x800 (orbit radius about 4: the whole object is in view), and the same cameras moved
    to 25% of their distance (close-ups, where culling matters).
  * ``--scene DIR`` (repeatable): a trained anchor scene instead of / besides the procedural
    one (``--scene procedural``), e.g. a lghcc-train output folder (Scaffold-GS layout), used
    as it is, on the same cameras.

Writes a markdown report (``--out``, default tools/results/render.md).
"""

from __future__ import annotations

import os

# Before torch is imported (OpenMP reads it once): without it, OpenMP threads spin at barriers and
# on a shared machine a 2-thread 100k-Gaussian forward took 7.55 s instead of 1.81 s (see encoder/training/__init__.py).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import datetime
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from benchutil import command_line  # noqa: E402  (tools/ is on the path when run as a script)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_LEGO = ROOT.parent / "shared" / "data" / "lego" / "lego_100"


def _lego_cameras(lego: Path, n: int, size: int):
    from lghcc.render.camera import Camera, load_nerf_synthetic

    if not (lego / "transforms_test.json").is_file():
        sys.exit(f"bench_render: lego test cameras not found at {lego} (pass --lego DIR)")
    cams = load_nerf_synthetic(lego, "test", load_images=False)
    step = max(1, len(cams) // n)
    return [c.scaled(size / c.width) for c in cams[::step][:n]], Camera


def _shell(m: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(m, 3, generator=g)
    means = d / d.norm(dim=1, keepdim=True) * torch.tensor([0.65, 1.1, 0.6]) + torch.tensor([0.0, 0.0, 0.35])
    area = 4 * math.pi * ((0.65 * 1.1) ** 1.6 + (0.65 * 0.6) ** 1.6 + (1.1 * 0.6) ** 1.6) ** (1 / 1.6) / 3 ** (1 / 1.6)
    s = math.sqrt(area / m)
    scales = (torch.rand(m, 3, generator=g) * 0.6 + 0.3) * s
    return [means, torch.randn(m, 4, generator=g), scales, torch.rand(m, generator=g) * 0.9 + 0.05,
            torch.rand(m, 3, generator=g)]


def _timed(fn, repeat: int):
    best, out = math.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def bench_rasterizer(cam, sizes, repeat, rows, threads):
    from lghcc.render.rasterizer import rasterize

    for m in sizes:
        params = _shell(m)
        rep = 1 if m >= 1_000_000 else repeat
        with torch.no_grad():
            rasterize(*params, cam)  # warm-up
            t_fwd, r = _timed(lambda: rasterize(*params, cam), rep)
        ps = [p.clone().requires_grad_() for p in params]
        t_fg, t_bw = math.inf, math.inf
        for _ in range(rep):
            for p in ps:
                p.grad = None
            t0 = time.perf_counter()
            rr = rasterize(*ps, cam)
            t1 = time.perf_counter()
            (rr.image.sum() + rr.alpha.sum()).backward()
            t2 = time.perf_counter()
            t_fg, t_bw = min(t_fg, t1 - t0), min(t_bw, t2 - t1)
        finite = all(torch.isfinite(p.grad).all() for p in ps)
        rows.append((m, threads, r.stats["rasterized"], r.stats["tile_pairs"], t_fwd, t_fg, t_bw, finite))
        print(f"  {m:>9,} Gaussians, {threads} threads: forward {t_fwd:.2f} s, forward with grad {t_fg:.2f} s, backward {t_bw:.2f} s, "
              f"pairs {r.stats['tile_pairs']:,}", flush=True)


def load_bench_scene(spec: str, anchors: int):
    """(SceneTensors, description) for ``procedural`` or a Scaffold-GS model folder."""
    from lghcc.render.neural_gaussians import SceneTensors

    if spec == "procedural":
        from lghcc.formats.procedural import make_procedural_scene

        scene = make_procedural_scene(anchors, seed=0, with_mask=True)
        st = SceneTensors.from_scene(scene)
        with torch.no_grad():
            st.positions = st.positions * 0.65 + torch.tensor([0.0, 0.0, 0.35])
            st.scalings = st.scalings + math.log(0.65)
        return st, (f"Procedural anchor scene: {st.num_anchors:,} anchors, K={scene.num_offsets} offsets, "
                    f"{int(scene.offset_mask.sum()):,} live offsets (HAC mask), scaled into lego's bounding box "
                    "(see the tool's doc)")
    from lghcc.formats.scaffold_io import read_scaffold

    scene = read_scaffold(spec)
    live = scene.num_anchors * scene.num_offsets if scene.offset_mask is None else int(scene.offset_mask.sum())
    return SceneTensors.from_scene(scene), (f"Trained anchor scene `{spec}`: {scene.num_anchors:,} anchors, "
                                            f"C={scene.feature_dim}, K={scene.num_offsets}, {live:,} offsets "
                                            f"({'no mask' if scene.offset_mask is None else 'masked'}), as trained")


def bench_neural(cams, st, rows_out, repeat):
    from lghcc.render.neural_gaussians import generate_neural_gaussians
    from lghcc.render.rasterizer import rasterize

    variants = {"cull + opacity mask (default)": dict(cull=True, mask_opacity=True),
                "no frustum culling": dict(cull=False, mask_opacity=True),
                "no opacity mask": dict(cull=True, mask_opacity=False),
                "neither": dict(cull=False, mask_opacity=False)}
    from dataclasses import replace

    close = []
    for c in cams:  # the same view from 25% of the distance to the origin
        c2w = c.camera_to_world.copy()
        c2w[:3, 3] *= 0.25
        w2c = np.linalg.inv(c2w)
        close.append(replace(c, world_to_camera=w2c))
    for view_name, vcams in (("lego test cameras", cams), ("close-ups (25% distance)", close)):
        for name, kw in variants.items():
            acc = {"anchors_in_view": 0, "anchors_run": 0, "gaussians": 0, "rasterized": 0, "pairs": 0}
            t_gen = t_ras = 0.0
            for c in vcams:
                best_g = best_r = math.inf
                for _ in range(repeat):
                    with torch.no_grad():
                        t0 = time.perf_counter()
                        ng = generate_neural_gaussians(st, c, **kw)
                        t1 = time.perf_counter()
                        r = rasterize(ng.means, ng.quats, ng.scales, ng.opacities, ng.colors, c,
                                      background=torch.ones(3))
                        t2 = time.perf_counter()
                    best_g, best_r = min(best_g, t1 - t0), min(best_r, t2 - t1)
                t_gen += best_g
                t_ras += best_r
                for k in ("anchors_in_view", "anchors_run", "gaussians"):
                    acc[k] += ng.stats[k]
                acc["rasterized"] += r.stats["rasterized"]
                acc["pairs"] += r.stats["tile_pairs"]
            n = len(vcams)
            rows_out.append((view_name, name, acc["anchors_in_view"] / n, acc["gaussians"] / n,
                             acc["rasterized"] / n, acc["pairs"] / n, t_gen / n, t_ras / n))
            print(f"  {view_name}, {name}: anchors in view {acc['anchors_in_view'] / n:,.0f}, Gaussians built "
                  f"{acc['gaussians'] / n:,.0f}, neural {t_gen / n:.3f} s, raster {t_ras / n:.3f} s", flush=True)


def bench_tile_sides(specs: list[str], repeat: int) -> list[str]:
    """The rasterizer's tile side (16, 8, 4 px, or its own choice) on real 3DGS scenes, through the
    encoder's views (encoder/gaussians/gaussian_fit.py resolving_views: 8 sphere views, and magnified crops
    where the Gaussians are below a pixel). ``specs``: PATH[:N]@PX (N: Gaussians drawn, seed 0)."""
    from lghcc.encoder.gaussians.gaussian_views import resolving_views
    from lghcc.formats import read_scene
    from lghcc.render.rasterizer import rasterize
    from lghcc.render.sh import sh_to_rgb

    lines = ["| scene | Gaussians | px | views | tile side | Gaussian-tile pairs | forward (no grad) s "
             "| forward + backward s | forward + backward / 16 px |", "|---|---:|---:|---:|---|---:|---:|---:|---:|"]
    for spec in specs:
        path_n, px = spec.rsplit("@", 1)
        path, _, n = path_n.partition(":")
        scene = read_scene(path)
        if n and int(n) < scene.num_gaussians:
            keep = np.zeros(scene.num_gaussians, bool)
            keep[np.random.default_rng(0).choice(scene.num_gaussians, int(n), replace=False)] = True
            scene = scene.subset(keep)
        cams = resolving_views(scene, 8, int(px), 0.1)
        t = lambda a: torch.tensor(np.asarray(a, np.float64), dtype=torch.float32)  # noqa: E731
        means, sh = t(scene.means), t(scene.sh).requires_grad_(True)
        op, ls, rot = t(scene.opacity).requires_grad_(True), t(scene.log_scales), t(scene.rotations)

        def render(cam, side):
            colors = sh_to_rgb(scene.sh_degree, sh, means - torch.as_tensor(cam.center, dtype=torch.float32))
            return rasterize(means, rot, torch.exp(ls), torch.sigmoid(op), colors, cam, tile_size=side)

        base = None
        for side in (16, 8, 4, None):
            def forward():
                with torch.no_grad():
                    return [render(c, side) for c in cams]

            def both():
                for c in cams:
                    render(c, side).image.sum().backward()
            tf, results = _timed(forward, repeat)
            tb, _ = _timed(both, repeat)
            base = base or tb
            chosen = sorted({r.stats["tile_size"] for r in results})
            label = f"{side} px" if side else "chosen: " + ", ".join(f"{c} px" for c in chosen)
            lines.append(f"| {Path(path).name} | {scene.num_gaussians:,} | {px} | {len(cams)} | {label} | "
                         f"{sum(r.stats['tile_pairs'] for r in results):,} | {tf:.2f} | {tb:.2f} | {tb / base:.2f} |")
            print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10000,100000,1000000",
                    help="Gaussian counts for the rasterizer timing (comma separated; default %(default)s)")
    ap.add_argument("--size", type=int, default=800, help="image width and height (default %(default)s)")
    ap.add_argument("--repeat", type=int, default=3, help="timing repeats, best kept (1M: once) (default %(default)s)")
    ap.add_argument("--anchors", type=int, default=20000, help="anchors of the procedural scene (default %(default)s)")
    ap.add_argument("--views", type=int, default=8, help="lego test cameras used (default %(default)s)")
    ap.add_argument("--lego", type=Path, default=DEFAULT_LEGO, help="NeRF-synthetic lego folder (for cameras)")
    ap.add_argument("--threads", default="0",
                    help="torch thread counts for the rasterizer timing, comma separated (0: torch's default); "
                         "the neural-Gaussian part uses the first (default %(default)s)")
    ap.add_argument("--skip-neural", action="store_true", help="only time the rasterizer")
    ap.add_argument("--skip-rasterizer", action="store_true", help="only the culling/masking section")
    ap.add_argument("--scene", action="append", metavar="DIR",
                    help="anchor scene for the culling/masking section: 'procedural' (default) or a Scaffold-GS "
                         "model folder (e.g. a lghcc-train output); repeat for several")
    ap.add_argument("--tile-sides", action="append", metavar="PATH[:N]@PX",
                    help="time the rasterizer's tile sides (16, 8, 4 px and its own choice) on a 3DGS scene (N of "
                         "its Gaussians, seed 0) through the encoder's views at PX pixels; repeatable")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "render.md",
                    help="markdown report (default %(default)s)")
    a = ap.parse_args(argv)
    threads = [int(t) or torch.get_num_threads() for t in a.threads.split(",") if t]
    sizes = [int(s) for s in a.sizes.split(",") if s]
    cams, _ = _lego_cameras(a.lego, a.views, a.size)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; image {a.size}x{a.size}", flush=True)
    rrows = []
    for th in threads if not a.skip_rasterizer else []:
        torch.set_num_threads(th)
        bench_rasterizer(cams[0], sizes, a.repeat, rrows, th)
    torch.set_num_threads(threads[0])
    nsections = []  # (description, rows)
    for spec in ([] if a.skip_neural else (a.scene or ["procedural"])):
        st, desc = load_bench_scene(spec, a.anchors)
        print(desc, flush=True)
        nrows = []
        bench_neural(cams, st, nrows, a.repeat)
        nsections.append((desc, nrows))
    tile_lines = bench_tile_sides(a.tile_sides, a.repeat) if a.tile_sides else []
    cmd = command_line("bench_render.py", argv)
    lines = [
        "# Renderer benchmark (lghcc.render, pure torch on CPU)", "",
        f"Command: `{cmd.strip()}`  ",
        f"Date: {datetime.date.today().isoformat()}; torch {torch.__version__}, threads {threads}, "
        f"{platform.processor() or platform.machine()}; the 2 cores were shared with other jobs, so times vary.", "",
    ]
    if rrows:
        lines += [
            f"## Rasterizer, {a.size}x{a.size}, lego test camera r_0", "",
            "Gaussians on an ellipsoid shell in lego's bounding box (scales ~ sqrt(area/M): the shell stays covered); "
            "time is the best of the repeats (1M: one run). Backward: `(image.sum() + alpha.sum()).backward()`.", "",
            "| Gaussians | threads | drawn | Gaussian-tile pairs | forward (no grad) s | forward (grad) s | backward s "
            "| grads finite |",
            "|---:|---:|---:|---:|---:|---:|---:|:---:|",
        ]
    for m, th, drawn, pairs, tf, tfg, tb, fin in rrows:
        lines.append(f"| {m:,} | {th} | {drawn:,} | {pairs:,} | {tf:.2f} | {tfg:.2f} | {tb:.2f} | "
                     f"{'yes' if fin else 'NO'} |")
    for desc, nrows in nsections:
        lines += ["", f"## Neural Gaussians: frustum culling and opacity masking, {a.size}x{a.size}", "",
                  f"{desc}; per-view averages over {len(cams)} lego test cameras, best of {a.repeat} per view, {threads[0]} thread(s). 'no opacity mask' builds the Gaussians with opacity <= 0 too "
                  "(the rasterizer then skips them).", "",
                  "| views | variant | anchors in view | Gaussians built | drawn | tile pairs | anchors -> Gaussians s | rasterize s |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        for v, name, av, gb, dr, pr, tg, tr in nrows:
            lines.append(f"| {v} | {name} | {av:,.0f} | {gb:,.0f} | {dr:,.0f} | {pr:,.0f} | {tg:.3f} | {tr:.3f} |")
    if tile_lines:
        lines += ["", "## Tile side on real scenes, the encoder's views", "",
                  "Each (Gaussian, tile) pair costs the tile's pixels plus a fixed overhead, so footprints of a "
                  "pixel or two want small tiles (render/rasterizer.py choose_tile_size picks the side of least "
                  f"work per view). Best of {a.repeat}; backward: `image.sum().backward()` per view.", ""] + tile_lines
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
