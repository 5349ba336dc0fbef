"""The report of a sweep: one markdown table of every cell, results.json, and per scene a
rate-distortion plot (coded bytes against PSNR; one line per lambda, points in preset order).

The plots need matplotlib (``pip install 'lghcc[tools]'``); without it the table says that
they were skipped and why, and the run is otherwise the same."""

from __future__ import annotations

import datetime
import json
import shlex
import sys
from pathlib import Path

from .sweep import Sweep
from ..app.fileio import atomic_output, atomic_write_bytes


def _fmt(rec: dict, key: str, spec: str) -> str:
    v = rec.get(key)
    return format(v, spec) if isinstance(v, (int, float)) else "—"


def rd_plots(sweep: Sweep, records: list[dict]) -> tuple[list[Path], str | None]:
    """One PNG per scene with at least one finished cell; (paths, why none when skipped)."""
    try:
        import matplotlib  # pyright: ignore[reportMissingImports] (optional: lghcc[tools])

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # pyright: ignore[reportMissingImports] (optional: lghcc[tools])
    except ImportError:
        return [], "matplotlib is not installed (pip install 'lghcc[tools]')"
    paths = []
    order = {p: i for i, p in enumerate(sweep.presets)}
    for scene in sweep.scenes:
        ok = [r for r in records if r["scene"] == scene and r["status"] == "ok"]
        if not ok:
            continue
        fig, ax = plt.subplots(figsize=(5.5, 4), dpi=110)
        for lam in sorted({r["lambda"] for r in ok}, key=lambda x: -1 if x is None else x):
            pts = sorted((r for r in ok if r["lambda"] == lam), key=lambda r: (r["bytes"], order[r["preset"]]))
            ax.plot([r["bytes"] / 1000 for r in pts], [r["psnr"] for r in pts], "o-",
                    label="presets" if lam is None else f"lambda {lam:g}")
            for r in pts:
                ax.annotate(r["preset"], (r["bytes"] / 1000, r["psnr"]), textcoords="offset points", xytext=(4, 4),
                            fontsize=7)
        ax.set_xlabel("coded size (kB)")
        ax.set_ylabel("PSNR against the source renders (dB)")
        ev = sweep.evaluation
        ax.set_title(f"{scene}: {ev.views} orbit views, {ev.width}x{ev.height}", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = sweep.output / f"rd_{scene}.png"
        with atomic_output(path) as f:
            fig.savefig(f, format="png")
        plt.close(fig)
        paths.append(path)
    return paths, None


def write_report(sweep: Sweep, records: list[dict], argv: list[str] | None = None) -> Path:
    """results.md and results.json in the output folder; returns the markdown's path."""
    sweep.output.mkdir(parents=True, exist_ok=True)
    plots, why_not = rd_plots(sweep, records)
    ev = sweep.evaluation
    cmd = "lghcc-batch " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    failed = [r for r in records if r["status"] != "ok"]
    lines = [f"# Sweep {sweep.file.name}", "",
             f"Command: `{cmd}`. Date: {datetime.date.today().isoformat()}.",
             f"Evaluation: PSNR/SSIM of the decoded scene against the source rendered from the same {ev.views} "
             f"orbit views ({ev.width}x{ev.height}, {ev.background} background) by lghcc.render on the CPU; the "
             "source of a 3DGS PLY is the PLY itself (the PSNR includes transcoding), of a trained scene the "
             "trained model. Bytes are the whole stream; times are one cell's on the host named in "
             "cells/<cell>.json.", "",
             "| scene | lambda | preset | bytes | anchors | bits/anchor | PSNR dB | SSIM | encode s | decode s | "
             "status |", "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in records:
        lam = "—" if r["lambda"] is None else f"{r['lambda']:g}"
        if r["status"] == "ok":
            lines.append(f"| {r['scene']} | {lam} | {r['preset']} | {r['bytes']:,} | {r['num_anchors']:,} | "
                         f"{_fmt(r, 'bits_per_anchor', '.1f')} | {_fmt(r, 'psnr', '.2f')} | {_fmt(r, 'ssim', '.4f')} | "
                         f"{_fmt(r, 'encode_s', '.1f')} | {_fmt(r, 'decode_s', '.2f')} | ok |")
        else:
            lines.append(f"| {r['scene']} | {lam} | {r['preset']} | | | | | | | | **failed** |")
    lines.append("")
    if failed:
        lines += [f"{len(failed)} of {len(records)} cells failed (their errors; the full tracebacks are in "
                  "cells/<cell>.json; a rerun retries them):", ""]
        lines += [f"- {r['cell']}: {r['error']}" for r in failed]
        lines.append("")
    if plots:
        lines += ["Rate-distortion plots: " + ", ".join(f"[{p.name}]({p.name})" for p in plots) + "."]
    elif why_not:
        lines += [f"Rate-distortion plots skipped: {why_not}."]
    md = sweep.output / "results.md"
    atomic_write_bytes(md, ("\n".join(lines) + "\n").encode())
    atomic_write_bytes(sweep.output / "results.json", (json.dumps(
        [{k: v for k, v in r.items() if k != "traceback"} for r in records], indent=2) + "\n").encode())
    return md
