#!/usr/bin/env python3
"""Tiles (format version 1): what they cost in bytes, and what they buy in decoding.

1. Tiling cost: each scene coded twice with the same settings, without tiles and with tiles of
   about ``--tile-points`` points (default the encoder's, 16384; and 65536 to show a coarser
   grid), bytes compared. Real 3DGS scenes of shared/data are coded as explicit Gaussians at
   the medium preset's steps (no settings search, no fit: tiles change the coding, not the
   choice of steps); a procedural anchor scene of ``--anchors`` anchors with the hierarchy and
   GG-Conv (lghcc-low, short context training: the decoder's speed does not depend on it).
2. Decoding the anchor scene: the untiled stream in one process; the tiled one with 1 and 2
   worker processes (lghcc-dec --jobs; and again with each worker's k-NN candidate generator on
   one thread per CPU, the setting before commit 1047ba9), a box holding 10% of the anchors (a
   cube around the anchor nearest the point 30% of the way along each axis of the bounding box,
   grown until it holds 10% of them) (--box) and the level-1 preview (--level 1). Each time the
   median of ``--repeats`` runs in this process, the cases alternated; ratios are to the tiled
   1-worker decode of the same run. Beside it, for tile
   sides from 32 to 256 voxels, the tiles that box meets and the share of the anchors they hold
   (the grid's cells only, nothing coded): what a box decode reads at each tile size.
3. The preview's quality: a smaller procedural anchor scene (``--preview-anchors``), rendered
   from 8 orbit views at 256 px, preview against the full decode (PSNR), with both times.

    python tools/bench_tiles.py                         # writes tools/results/tiles.md
    python tools/bench_tiles.py --anchors 200000 --scenes donut --out /tmp/tiles.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse  # noqa: E402
import datetime
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SCENES = {"donut": DATA / "donut" / "donut.ply", "playbot-lod3": DATA / "playbot" / "playbot_lod3_31k.ply",
          "playcanvas-logo": DATA / "playcanvas-logo" / "playcanvas_logo_307k.ply"}


def _timed(fn, repeats: int):
    out, times = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return out, statistics.median(times)


def _cost_cells(untiled, tiled) -> str:
    """bytes without and with tiles, the cost, and the geometry's share of it."""
    g0, g1 = untiled.breakdown.bytes_by_category["geometry"], tiled.breakdown.bytes_by_category["geometry"]
    cost = 100.0 * (len(tiled.data) / len(untiled.data) - 1)
    return (f"{len(untiled.data):,} | {len(tiled.data):,} | {cost:+.2f}% | {g0:,} | {g1:,} | "
            f"{100.0 * (g1 / g0 - 1):+.2f}%")


def gaussian_cost_rows(names: list[str], tile_points: list[int]) -> list[str]:
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
    from lghcc.formats.ply3dgs import read_3dgs_ply

    rows = []
    for name in names:
        scene = read_3dgs_ply(SCENES[name])
        base_cfg = load_config("medium", kind="gaussians")
        t = time.perf_counter()
        untiled = encode_gaussian_scene(scene, load_config("medium", overrides={"tile_points": 0}, kind="gaussians"))
        t_untiled = time.perf_counter() - t
        for tp in tile_points:
            t = time.perf_counter()
            res = encode_gaussian_scene(scene, load_config("medium", overrides={"tile_points": tp}, kind="gaussians"))
            dt = time.perf_counter() - t
            rows.append(f"| {name} (3DGS, medium steps) | {scene.num_gaussians:,} | {tp:,} | {res.stats.num_tiles} | "
                        + _cost_cells(untiled, res) + f" | {t_untiled:.1f} | {dt:.1f} |")
            print(rows[-1], flush=True)
        del base_cfg
    return rows


def anchor_config(tile_points: int):
    from lghcc.encoder.stream.config import load_config

    return load_config("lghcc-low", overrides={
        "tile_points": tile_points, "context_neighbour_level": 1, "context_parent_base": "choose",
        "context_float_steps": 150, "context_qat_steps": 30, "context_train_anchors": 50_000})


def box_holding(points: np.ndarray, share: float):
    """A cube (lghcc.common.tiles.Box) around the point nearest 30% of the bounding box's diagonal
    that holds ``share`` of the points (bisection on its side)."""
    from lghcc.common.tiles import Box

    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = points[np.argmin(((points - (lo + 0.3 * (hi - lo))) ** 2).sum(axis=1))]
    a, b = 0.0, float((hi - lo).max()) * 2
    for _ in range(40):
        half = (a + b) / 2
        inside = (np.abs(points - centre) <= half).all(axis=1).mean()
        a, b = (half, b) if inside < share else (a, half)
    return Box(tuple(centre - b), tuple(centre + b))


def box_reach_rows(coords: np.ndarray, voxel_size: float, origin, box, unit: int, scales: list[int]) -> list[str]:
    """For tile sides of ``scales`` x ``unit`` voxels: the tiles a box meets (the decoder's own test,
    common/tiles.cell_intersects_box) and the share of the points they hold, which is what a box
    decode costs (no encoding needed: the tiles are cells of the grid)."""
    from lghcc.common.tiles import cell_intersects_box, tile_cells

    rows = []
    for scale in scales:
        size = scale * unit
        cells, counts = np.unique(tile_cells(coords, size), axis=0, return_counts=True)
        meets = np.array([cell_intersects_box(c, size, voxel_size, origin, box) for c in cells])
        rows.append(f"| {size} | {cells.shape[0]:,} | {coords.shape[0] / cells.shape[0]:,.0f} | {int(meets.sum())} | "
                    f"{counts[meets].sum() / coords.shape[0]:.1%} |")
    return rows


def anchor_section(n: int, tile_points: list[int], repeats: int) -> tuple[list[str], list[str], list[str]]:
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.formats.procedural import make_procedural_scene

    scene = make_procedural_scene(n, seed=0)
    t = time.perf_counter()
    untiled = encode_scene(scene, anchor_config(0))
    t_untiled = time.perf_counter() - t
    cost_rows, dec_rows = [], []
    tiled = None
    for tp in tile_points:
        t = time.perf_counter()
        res = encode_scene(scene, anchor_config(tp))
        dt = time.perf_counter() - t
        cost_rows.append(f"| procedural anchors (lghcc-low, GG-Conv) | {scene.num_anchors:,} | {tp:,} | "
                         f"{res.stats.num_tiles} | " + _cost_cells(untiled, res) + f" | {t_untiled:.1f} | {dt:.1f} |")
        print(cost_rows[-1], flush=True)
        tiled = tiled or res
    decode_stream(untiled.data)  # warm-up: imports, tables
    box = box_holding(scene.coords * scene.voxel_size + scene.origin, 0.1)
    unit = anchor_config(0).coarse_voxel_scale  # tile sides are multiples of the coarse voxel
    reach = box_reach_rows(scene.coords, float(scene.voxel_size), scene.origin, box, unit,
                           [8, 12, 16, 24, 32, 48, 64])
    # (label, stream, decode_stream's arguments, the workers' k-NN threads)
    cases = [("untiled stream, 1 process", untiled.data, {}, None),
             ("tiled, --jobs 1", tiled.data, {}, None),
             ("tiled, --jobs 2", tiled.data, {"jobs": 2}, None),
             ("tiled, --jobs 2, each worker's k-NN on one thread per CPU (before 1047ba9)", tiled.data, {"jobs": 2},
              -1),
             ("tiled, --box (a cube holding 10% of the anchors), --jobs 1", tiled.data, {"box": box}, None),
             ("tiled, --level 1 (preview), --jobs 1", tiled.data, {"max_level": 1}, None),
             ("tiled, --level 1 (preview), --jobs 2", tiled.data, {"max_level": 1, "jobs": 2}, None)]
    times: list[list[float]] = [[] for _ in cases]
    results = [None] * len(cases)
    for _ in range(repeats):  # the cases alternated, so that the machine's drift falls on all of them
        for i, (_, data, kw, threads) in enumerate(cases):
            results[i], dt = _timed(lambda: _decode_with_worker_threads(data, kw, threads), 1)
            times[i].append(dt)
    base = statistics.median(times[1])  # the tiled 1-worker decode
    for (label, data, kw, _), res, ts in zip(cases, results, times):
        dt = statistics.median(ts)
        assert kw or res.stream_hash == (untiled.scene_hash if data is untiled.data else tiled.scene_hash)
        ratio = "-" if data is untiled.data else f"{dt / base:.2f}"
        dec_rows.append(f"| {label} | {res.tiles_decoded} of {res.num_tiles} | {res.scene.num_anchors:,} | "
                        f"{dt:.2f} | {res.scene.num_anchors / dt:,.0f} | {ratio} |")
        print(dec_rows[-1], flush=True)
    return cost_rows, dec_rows, reach


def _decode_with_worker_threads(data: bytes, kw: dict, threads: int | None):
    """decode_stream(data, **kw), its workers' k-NN on ``threads`` threads (None: the decoder's
    setting); the forked workers read the setting from this process."""
    from lghcc.decoder import decode

    default = decode.WORKER_CANDIDATE_THREADS
    decode.WORKER_CANDIDATE_THREADS = default if threads is None else threads
    try:
        return decode.decode_stream(data, **kw)
    finally:
        decode.WORKER_CANDIDATE_THREADS = default


def preview_rows(n: int) -> list[str]:
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.render.metrics import psnr
    from lghcc.render.scenes import render_views, resolve_cameras

    scene = make_procedural_scene(n, seed=1)
    res = encode_scene(scene, anchor_config(max(n // 8, 1)))
    full, t_full = _timed(lambda: decode_stream(res.data), 1)
    prev, t_prev = _timed(lambda: decode_stream(res.data, max_level=1), 1)
    cams = resolve_cameras("orbit:8", full.scene, size=(256, 256))
    with torch.no_grad():
        a = render_views(full.scene, cams)
        b = render_views(prev.scene, cams)
    p = float(np.mean([psnr(x, y) for x, y in zip(a, b)]))
    return [f"| procedural anchors (lghcc-low), {res.stats.num_tiles} tiles | {full.scene.num_anchors:,} | "
            f"{t_full:.2f} | {prev.scene.num_anchors:,} | {t_prev:.2f} | {p:.2f} |"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--anchors", type=int, default=1_000_000)
    ap.add_argument("--preview-anchors", type=int, default=100_000)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--tile-points", type=int, nargs="+", default=[16384, 65536])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "tiles.md"))
    args = ap.parse_args(argv)
    torch.set_num_threads(2)
    load_before = load_average()
    cost = gaussian_cost_rows(args.scenes, args.tile_points)
    anchor_cost, decode, reach = anchor_section(args.anchors, args.tile_points, args.repeats)
    preview = preview_rows(args.preview_anchors)
    lines = [
        "# Tiles: cost in bytes, decoding in parallel, by box, and the level-1 preview", "",
        f"Command: `{command_line('bench_tiles.py', argv)}`  ",
        f"Date: {datetime.date.today()}; torch {torch.__version__}, 2 threads, {platform.machine()}, "
        f"{os.cpu_count()} CPUs (shared); load {load_before} before, {load_average()} after.", "",
        "## Tiling cost (same settings with and without tiles)", "",
        "| scene | points | tile_points | tiles | bytes without tiles | bytes with tiles | cost | geometry bytes "
        "without | with | geometry cost | encode s without | encode s with |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|", *cost, *anchor_cost, "",
        f"## Decoding the {args.anchors:,}-anchor GG-Conv scene (tile_points {args.tile_points[0]:,})", "",
        f"Median of {args.repeats} decodes in this process, the cases alternated (decode_stream: parse, geometry, attributes with the "
        "GG-Conv context, hash check of every tile decoded). Ratio: to the tiled stream's 1-worker decode.", "",
        "| decode | tiles | anchors out | s | anchors/s | ratio |", "|---|---:|---:|---:|---:|---:|", *decode, "",
        "What the box decode reads, by tile side: the tiles the same box meets and the share of the anchors they "
        "hold (no decoding; a box decode's time follows that share).", "",
        "| tile side, voxels | tiles | anchors per tile | tiles the box meets | anchors in them |",
        "|---:|---:|---:|---:|---:|", *reach, "",
        "## The level-1 preview", "",
        "Renders of the preview against renders of the full decode (8 orbit views, 256x256, mean PSNR).", "",
        "| stream | anchors | full decode s | preview anchors | preview s | PSNR of the preview, dB |",
        "|---|---:|---:|---:|---:|---:|", *preview, ""]
    write_lines(Path(args.out), lines)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
