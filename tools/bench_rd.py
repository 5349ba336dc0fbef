"""Rate-distortion curve in coded bytes: scenes trained under the rate term (lghcc-train
--rate-lambda) coded by encoder presets, against the test views of their data.

For each training run and each preset: the stream's bytes (its geometry, attribute and model
units), bits per anchor, encode and decode time, and the decoded scene's test PSNR/SSIM on the
run's test views; the run's own (uncompressed) test PSNR beside it. One row per (run, preset),
and a PNG plot of test PSNR against bytes, one line per (training length, preset), when
matplotlib is installed (``pip install -e .[tools]``).

    python tools/bench_rd.py /work/scenes/lego100_rd0 /work/scenes/lego100_rd0.05 \\
        --data /work/shared/data/lego/lego_100 --presets medium lghcc-medium

Each run folder is read-only input (lghcc-train output: its config.yaml gives lambda, its last
checkpoint is the scene); results go to tools/results/rd.md (--append adds a section).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: no spinning OpenMP threads

import argparse
import datetime
import sys
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, load_average, write_lines  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_info(run: Path) -> tuple[float, int]:
    """(rate lambda, trained iterations) of an lghcc-train output folder."""
    cfg = yaml.safe_load((run / "config.yaml").read_text()) or {}
    iters = [int(p.name.split("_")[-1]) for p in (run / "point_cloud").glob("iteration_*")]
    if not iters:
        raise SystemExit(f"{run}: no point_cloud/iteration_* checkpoint: not an lghcc-train output")
    return float(cfg.get("rate_lambda") or 0.0), max(iters)


def plot_rd(rows: list[dict], path: Path) -> str:
    """Test PSNR against stream bytes; returns the markdown line that shows the PNG (or says why
    there is none)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "(matplotlib not installed: no plot; `pip install -e .[tools]`)"
    fig, ax = plt.subplots(figsize=(6.5, 4))
    for key in sorted({(r["iterations"], r["preset"]) for r in rows}):
        pts = sorted((r["bytes"], r["psnr"], r["lambda"]) for r in rows if (r["iterations"], r["preset"]) == key)
        ax.plot([p[0] / 1e3 for p in pts], [p[1] for p in pts], "o-", label=f"{key[1]}, {key[0]:,} iterations")
        for b, p, lam in pts:
            ax.annotate(f"{lam:g}", (b / 1e3, p), textcoords="offset points", xytext=(3, 3), fontsize=7)
    ax.set_xlabel("stream kB")
    ax.set_ylabel("test PSNR dB")
    ax.set_title("rate-distortion: training lambda (labels) x preset")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return f"![rate-distortion]({path.name})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="lghcc-train output folders")
    ap.add_argument("--data", required=True, help="the dataset the runs were trained on (its test views)")
    ap.add_argument("--background", default="white", help="background of --data (default white)")
    ap.add_argument("--presets", nargs="+", default=["medium", "lghcc-medium"], help="encoder presets")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tools" / "results" / "rd.md"))
    ap.add_argument("--append", action="store_true", help="add a section to --out instead of replacing it")
    args = ap.parse_args(argv)

    import torch

    from lghcc.formats.scaffold_io import read_scaffold
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.config import load_config
    from lghcc.encoder.stream.encode import encode_scene
    from lghcc.encoder.context.ggconv_train import find_context_twin
    from lghcc.encoder.training.evaluation import evaluate_scene
    from lghcc.render.datasets import load_dataset

    torch.set_num_threads(args.threads)
    test = load_dataset(args.data, args.background).test
    rows = []
    for run in map(Path, args.runs):
        lam, iters = run_info(run)
        scene = read_scaffold(run)
        twin = find_context_twin(run)  # as lghcc-enc does: the GG-Conv fit also starts from the training's twin
        own = evaluate_scene(scene, test, args.background)
        for name in args.presets:
            t0 = time.perf_counter()
            res = encode_scene(scene, load_config(name), context_twin=twin)
            t_enc = time.perf_counter() - t0
            t0 = time.perf_counter()
            dec = decode_stream(res.data)
            t_dec = time.perf_counter() - t0
            ev = evaluate_scene(dec.scene, test, args.background)
            parts = res.breakdown.bytes_by_category
            rows.append(dict(run=run.name, preset=name, twin=getattr(res.stats.context_fit, "parent_base", None) == "twin", bytes=len(res.data), anchors=scene.num_anchors,
                             geom=parts["geometry"], attr=parts["attributes"], model=parts["model"], enc=t_enc, dec=t_dec, psnr=ev["psnr"],
                             ssim=ev["ssim"], own=own["psnr"], iterations=iters, **{"lambda": lam}))
            r = rows[-1]
            print(f"{run.name} (lambda {lam:g}, {iters} it) {name}: {r['bytes']:,} B, test PSNR {r['psnr']:.3f} dB "
                  f"(uncompressed {r['own']:.3f}), enc {t_enc:.1f} s, dec {t_dec:.2f} s", flush=True)
    out = Path(args.out)
    lines = [] if args.append else ["# Rate-distortion in coded bytes (training lambda x encoder preset)", ""]
    lines += [f"## {Path(args.data).name}, {datetime.date.today()}", "",
              f"Command: `{command_line('bench_rd.py', argv)}`  ",
              f"{args.threads} torch threads; shared 2-core VM, load {load_average()} at the end (timings are noisy). "
              f"Test PSNR/SSIM: the decoded scene on the {len(test)} test views; 'uncompressed': the trained "
              "scene itself. geometry / attributes / models: bytes of those units (models: the render MLPs and "
              "the context model), framing included. twin: the GG-Conv model kept is the fit started from the "
              "training's context twin (context_twin.pt beside the scene).", "",
              "| run | lambda | iterations | anchors | preset | twin | bytes | bits/anchor | geometry | attributes | models "
              "| test PSNR dB | test SSIM | uncompressed PSNR dB | encode s | decode s |",
              "|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['run']} | {r['lambda']:g} | {r['iterations']:,} | {r['anchors']:,} | {r['preset']} | {'yes' if r['twin'] else '-'} | "
              f"{r['bytes']:,} | {8 * r['bytes'] / r['anchors']:.1f} | {r['geom']:,} | {r['attr']:,} | {r['model']:,} | "
              f"{r['psnr']:.3f} | {r['ssim']:.4f} | {r['own']:.3f} | {r['enc']:.1f} | {r['dec']:.2f} |" for r in rows]
    lines += ["", plot_rd(rows, out.with_suffix(".png"))]
    prev = out.read_text().rstrip("\n").split("\n") + [""] if args.append and out.exists() else []
    write_lines(out, prev + lines)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
