"""Where GG-Conv decoding time goes, and its floor on this machine (informative).

For the procedural scene at each size (common/procedural.py, seed 0, coarse voxel scale 4) and
each neighbour level, a GG-Conv model of the size the encoder gives that many level-2 anchors
(encoder/stream/config.py CONTEXT_MODEL_SIZES) with random integer weights (the time does not depend
on the values) and the encoder's radius rule; the decoder's own code path
(``GGConvEvaluator``) is timed in its parts:

* k-NN: the canonical Ball k-NN graph (common/knn.py), also with the candidate generator's
  former setting (initial_extra 8 for every query), same process, same graph asserted;
* init: the evaluator's per-level-1 terms and the geometry tables;
* rows: the coding parameters of every level-2 anchor;
* GEMM floor: the three float64 matrix products the rows cannot avoid (the feature MLP's
  second layer on every edge, the head's two layers on every anchor, less the head input
  folded per level-1 anchor), timed alone on the same shapes: what exact float64 arithmetic
  costs on these cores whatever the surrounding code does;
* with ``--blocks``: the rows again with each of those block sizes (rows evaluated at once;
  the result does not depend on it), the sizes alternated over ``--repeats`` rounds in this
  process, median of each, in a second table.

    python tools/bench_ggconv.py --sizes 100000 1000000 --threads 2
    python tools/bench_ggconv.py --sizes 100000 1000000 --threads 1 --blocks 128 512 1024 4096 \
        --out tools/results/ggconv_blocks.md

Results: tools/results/ggconv.md (table and command).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads
import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def random_model(rng: np.random.Generator, num_features: int, m: int, n2: int, coords2, coords1, level: int):
    from lghcc.common.context.ggconv import GGConvParams
    from lghcc.common.intnn import IntLinear, IntMLP
    from lghcc.encoder.stream.config import EncoderConfig, context_model_size
    from lghcc.encoder.context.ggconv_train import default_radius_sq

    ch, fh, hh, bits = context_model_size(EncoderConfig(), n2)

    def lin(i, o, relu):
        w = min(300, (1 << (bits - 1)) - 1)
        return IntLinear(rng.integers(-w, w, (o, i)), rng.integers(-5000, 5000, o), 12, relu, bits)

    radius_sq = default_radius_sq(coords2, 8, coords1 if level == 1 else None)
    return GGConvParams(num_features, 8, radius_sq, rng.integers(-3000, 3000, (5, 5, 5, ch)), 14,
                        IntMLP([lin(num_features + 3, fh, True), lin(fh, ch, False)]),
                        IntMLP([lin(ch + 4 + m, hh, True), lin(hh, 3 * m, False)]), level)


def gemm_floor(params, n2: int, num_edges: int, block: int = 1 << 12) -> tuple[float, float]:
    """(seconds, GFLOP) of the unavoidable float64 products over n2 rows in blocks."""
    fh = params.feat_mlp.layers[0].fan_out
    ch, hh, m3 = params.context_channels, params.head_mlp.layers[0].fan_out, params.head_mlp.out_dim
    k = num_edges / max(n2, 1)
    shapes = [(round(block * k), fh, ch), (block, ch + 4, hh), (block, hh, m3)]
    mats = [(torch.rand(r, i, dtype=torch.float64), torch.rand(i, o, dtype=torch.float64),
             torch.rand(o, dtype=torch.float64)) for r, i, o in shapes]
    t = time.perf_counter()
    for _ in range(0, n2, block):
        for x, w, b in mats:
            torch.addmm(b, x, w)
    secs = time.perf_counter() - t
    flop = 2 * sum(r * i * o for r, i, o in shapes) * (n2 / block)
    return secs, flop / 1e9


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000], help="procedural anchor counts")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--blocks", type=int, nargs="*", default=[],
                    help="also time the rows with each of these block sizes (default: none)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of the --blocks timings (median)")
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "ggconv.md"))
    args = ap.parse_args(argv)

    from lghcc.common.context.ggconv import GGConvEvaluator, block_rows, level2_graph
    from lghcc.common.geometry import normative_order
    from lghcc.common.hierarchy import build_hierarchy
    from lghcc.common.knn import ball_knn
    from lghcc.formats.procedural import make_procedural_scene

    torch.set_num_threads(args.threads)
    ball_knn(np.zeros((2, 3), np.int64), 1, 1)  # first use: scipy's import is not the graph's time
    rows, block_lines = [], []
    for n in args.sizes:
        scene = make_procedural_scene(n, seed=0)
        c = scene.coords[normative_order(scene.coords)]
        hier = build_hierarchy(c, 4)
        c1, c2 = c[hier.level1_idx], c[hier.level2_idx]
        m = scene.features.shape[1] + 6 + 3 * scene.offsets.shape[1]
        rng = np.random.default_rng(0)
        x1 = rng.integers(-200, 200, (hier.num_level1, m))
        for level in (1, 2):
            p = random_model(rng, scene.features.shape[1], m, hier.num_level2, c2, c1, level)
            if not rows:  # first use of the kernels (thread pool, BLAS) is not the evaluator's time
                GGConvEvaluator(p, c2[:500], hier.parent_of_level2[:500], c1, x1, 4).rows(0, 500)
            t = time.perf_counter()
            graph = level2_graph(p, c2, c1)
            t_knn = time.perf_counter() - t
            t = time.perf_counter()
            old = ball_knn(c2, p.k, p.radius_sq, initial_extra=8) if level == 2 else \
                ball_knn(c1, p.k, p.radius_sq, query=c2, initial_extra=8)
            t_knn8 = time.perf_counter() - t
            assert all(np.array_equal(a, b) for a, b in zip(graph, old))
            t = time.perf_counter()
            ev = GGConvEvaluator(p, c2, hier.parent_of_level2, c1, x1, 4, graph)
            t_init = time.perf_counter() - t
            t = time.perf_counter()
            ev.rows(0, ev.num_rows)
            t_rows = time.perf_counter() - t
            g_s, g_flop = gemm_floor(p, hier.num_level2, int(graph[1].sum()))
            total = t_knn + t_init + t_rows
            rows.append((n, hier.num_level2, level, p.radius_sq, f"{p.context_channels}/{p.feat_mlp.layers[0].fan_out}/"
                         f"{p.head_mlp.layers[0].fan_out}", t_knn, t_knn8, t_init, t_rows, total,
                         hier.num_level2 / total, g_s, g_flop, g_flop / g_s))
            print(" ".join(str(x) if not isinstance(x, float) else f"{x:.2f}" for x in rows[-1]), flush=True)
            times: dict[int, list[float]] = {b: [] for b in args.blocks}
            for _ in range(args.repeats if args.blocks else 0):
                for b in args.blocks:
                    t = time.perf_counter()
                    ev.rows(0, ev.num_rows, b)
                    times[b].append(time.perf_counter() - t)
            for b, ts in times.items():
                mark = " (default)" if b == block_rows() else ""
                block_lines.append(f"| {n:,} | {level} | {b}{mark} | {float(np.median(ts)):.2f} | "
                                   f"{' / '.join(f'{x:.2f}' for x in ts)} |")
                print(block_lines[-1], flush=True)
    lines = ["# GG-Conv decoding time: where it goes", "",
             f"Command: `{command_line('bench_ggconv.py', argv)}`  ",
             f"Date: {datetime.date.today()}; {args.threads} torch threads; shared 2-core VM, load {load_average()} "
             "at the end (timings are noisy). Procedural scene (seed 0), coarse voxel scale 4, K = 8, random "
             "integer weights at the encoder's model size (Ch / feature hidden / head hidden) and radius rule. "
             "k-NN (initial_extra 8): the graph with the candidate generator's former setting, same graph. "
             "GEMM floor: the three float64 products alone, same shapes and blocks.", "",
             "| anchors | level-2 | neighbour level | radius^2 | model | k-NN s | k-NN s (initial_extra 8) | init s "
             "| rows s | total s | level-2 anchors/s | GEMM floor s | GFLOP | GFLOP/s |",
             "|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r[0]:,} | {r[1]:,} | {r[2]} | {r[3]} | {r[4]} | {r[5]:.2f} | {r[6]:.2f} | {r[7]:.2f} | "
              f"{r[8]:.2f} | {r[9]:.2f} | {r[10]:,.0f} | {r[11]:.2f} | {r[12]:.1f} | {r[13]:.1f} |" for r in rows]
    if block_lines:
        lines += ["", f"Rows by block size (rows evaluated at once; {args.threads} torch threads; the sizes "
                  f"alternated over {args.repeats} rounds, median):", "",
                  "| anchors | neighbour level | block rows | rows s | each round, s |", "|---:|---:|---:|---:|---|",
                  *block_lines]
    write_lines(Path(args.out), lines)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
