#!/usr/bin/env python3
"""Level-2 context models on real and procedural anchor scenes: bits and time.

(a) For each scene: attribute bits per anchor (level 1, level 2 with and without the
    context-model unit, all) with the per-channel prior, the parent MLP ("vanilla EM",
    Context-GS style), GG-Conv over the paper's graph (neighbour_level 2: level-2 neighbours
    carrying their parents' attributes) and GG-Conv over level-1 neighbours (neighbour_level 1,
    the encoder's default); all through the real encoder (``encode_scene``, context_fallback
    off so the model is always used) and the real decoder (``decode_stream``, bit-exact round
    trip checked), same anchors, same quantization steps. Encode, fit and decode times.
(b) "What accuracy costs in time": GG-Conv at 8 and 16 weight bits, K = 4, 8, 16 neighbours
    and two model widths on one scene: level-2 bits, fit time, decode time; a PNG plot when
    matplotlib is installed (``pip install -e .[tools]``).

    python tools/bench_context.py --scene /work/scenes/lego100 --sizes 10000 100000 --tradeoff-scene procedural:20000

Scenes are read-only inputs: a Scaffold-GS folder (lghcc-train output, a transcoded 3DGS PLY)
or `procedural:N` (common/procedural.py, seed 0).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # shared machine: no spinning threads

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from benchutil import command_line, load_average, write_lines  # noqa: E402

MODELS = {  # label -> encoder options
    "per-channel prior": dict(context_model="per_channel"),
    "parent MLP": dict(context_model="parent_mlp"),
    "GG-Conv, level-2 graph (paper)": dict(context_model="ggconv", context_neighbour_level=2),
    "GG-Conv, level-1 neighbours": dict(context_model="ggconv", context_neighbour_level=1),
    # lghcc-enc's default on a rate-trained run: the level-1 fit and one started from the twin
    # lghcc-train saved beside the scene, the smaller kept (rows only for scenes with a twin)
    "GG-Conv, level-1 neighbours + training twin": dict(context_model="ggconv", context_neighbour_level=1, twin=True),
}


def load_scene(spec: str):
    """(scene, label, the context twin saved beside it or None)."""
    if spec.startswith("procedural:"):
        from lghcc.formats.procedural import make_procedural_scene
        return (make_procedural_scene(int(spec.split(":", 1)[1]), seed=0), f"procedural {int(spec.split(':')[1]):,}",
                None)
    from lghcc.formats.scaffold_io import read_scaffold
    from lghcc.encoder.context.ggconv_train import find_context_twin
    return read_scaffold(spec), Path(spec).name, find_context_twin(spec)


def decoded_error_sq_steps(scene, decoded, step: float) -> float:
    """Mean squared error of the decoded attributes (features, scalings, live offsets) against the
    source, in squared quantization steps: 1/12 for plain rounding; above it where a context
    model's step adjustment coarsened steps. It shows whether two rows quantized alike."""
    import numpy as np

    from lghcc.common.geometry import normative_order

    order = normative_order(scene.coords)  # the decoded scene's anchor order
    live = (np.ones(scene.offsets.shape[:2], bool) if scene.offset_mask is None
            else scene.offset_mask[order].astype(bool))
    pairs = [(scene.features[order], decoded.features), (scene.scalings[order], decoded.scalings),
             (scene.offsets[order][live], decoded.offsets[live])]
    sq = sum(float(((a.astype(np.float64) - b.astype(np.float64)) ** 2).sum()) for a, b in pairs)
    return sq / sum(a.size for a, _ in pairs) / step ** 2


def run_one(scene, args, twin=None, **over) -> dict:
    import numpy as np

    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.config import EncoderConfig
    from lghcc.encoder.stream.encode import encode_scene

    kw = dict(hierarchy=True, coarse_voxel_scale=args.scale, context_fallback=False, feature_step=args.step,
              scaling_step=args.step, offset_step=args.step)
    if args.float_steps is not None:
        kw["context_float_steps"] = args.float_steps
    if args.qat_steps is not None:
        kw["context_qat_steps"] = args.qat_steps
    kw.update(over)
    cfg = EncoderConfig(**kw)
    t0 = time.perf_counter()
    res = encode_scene(scene, cfg, context_twin=twin)
    t_enc = time.perf_counter() - t0
    st = res.stats
    t0 = time.perf_counter()
    dec = decode_stream(res.data)
    t_dec = time.perf_counter() - t0
    assert dec.stream_hash == res.scene_hash and np.array_equal(dec.scene.features, res.decoded.features)
    n = scene.num_anchors
    l1, l2 = (st.levels[level].attribute_bytes if level in st.levels else 0 for level in (1, 2))
    fit = st.context_fit
    ctx = fit.bytes_with_context - l2 if fit is not None and cfg.context_model != "per_channel" else 0
    return {"n": n, "n2": st.num_level2 or 0, "l1_bits": 8 * l1 / n, "l2_bits": 8 * l2 / n,
            "ctx_bytes": ctx, "all_bits": 8 * (l1 + l2 + ctx) / n, "enc_s": t_enc,
            "fit_s": fit.time_s if fit is not None else 0.0, "dec_s": t_dec, "load": load_average(),
            "base": (fit.parent_base or "-") if fit is not None and cfg.context_model != "per_channel" else "-",
            "err": decoded_error_sq_steps(scene, dec.scene, args.step)}


def plot_tradeoff(pts: list[tuple[str, float, float, float]], label: str, path: Path) -> str:
    """Table (b) as a PNG (bits against fit time and against extra decode time); returns the
    markdown line that shows it, or says why there is none."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "(matplotlib not installed: no plot; `pip install -e .[tools]`, then `--replot`)"
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for setting, bits, fit, dec in pts:
        ax[0].scatter(fit, bits)
        ax[0].annotate(setting, (fit, bits), fontsize=7)
        ax[1].scatter(dec, bits)
        ax[1].annotate(setting, (dec, bits), fontsize=7)
    ax[0].set_xlabel("fit (encode) s")
    ax[1].set_xlabel("decode s over the prior's decode")
    ax[0].set_ylabel("level-2 bits/anchor incl. model")
    fig.suptitle(f"GG-Conv accuracy vs time, {label}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return f"![accuracy vs time]({path.name})"


def replot(out: Path, plot: Path | None) -> int:
    """Redraw the plot of table (b) from the markdown table already in ``out``."""
    lines = out.read_text().split("\n")
    head = next((i for i, l in enumerate(lines) if l.startswith("## (b)")), None)
    if head is None:
        raise SystemExit(f"{out}: no table (b) to plot")
    label = lines[head].rsplit(", ", 1)[-1].rstrip(")")
    rows = [l.split("|")[1:-1] for l in lines[head:] if l.startswith("| ") and not l.startswith("| setting")]
    prior_dec = next(float(r[5]) for r in rows if r[0].strip() == "per-channel prior")
    pts = [(r[0].strip(), float(r[1]), float(r[4]), float(r[5]) - prior_dec) for r in rows
           if r[0].strip() != "per-channel prior"]
    line = plot_tradeoff(pts, label, plot or out.with_suffix(".png"))
    keep = [l for l in lines if not l.startswith("(matplotlib not installed") and not l.startswith("![accuracy")]
    while keep and not keep[-1]:
        keep.pop()
    write_lines(out, keep + [line])
    print(line)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", action="append", default=[], help="Scaffold-GS folder (repeatable)")
    ap.add_argument("--sizes", type=int, nargs="*", default=[10000, 100000], help="procedural anchor counts")
    ap.add_argument("--scale", type=int, default=4, help="coarse voxel scale s (default 4)")
    ap.add_argument("--step", type=float, default=0.02, help="quantization step of every attribute (default 0.02)")
    ap.add_argument("--float-steps", type=int, help="context fit: float steps (default: the encoder's)")
    ap.add_argument("--qat-steps", type=int, help="context fit: QAT steps (default: the encoder's)")
    ap.add_argument("--models", nargs="+", default=list(MODELS), help="subset of: " + "; ".join(MODELS))
    ap.add_argument("--tradeoff-scene", default="procedural:20000", help="scene of table (b)")
    ap.add_argument("--no-tradeoff", action="store_true", help="skip table (b)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "context.md")
    ap.add_argument("--append", action="store_true", help="append this run's tables to --out")
    ap.add_argument("--plot", type=Path, default=None, help="PNG for table (b) (default: next to --out)")
    ap.add_argument("--replot", action="store_true", help="only redraw the plot of table (b) already in --out")
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.out, args.plot)

    import torch

    from lghcc.encoder.stream.config import EncoderConfig

    torch.set_num_threads(args.threads)
    d = EncoderConfig()
    cmd = command_line("bench_context.py", argv)
    prev = args.out.read_text().rstrip("\n").split("\n") + [""] if args.append and args.out.exists() else []
    lines = prev + ([] if args.append else ["# Level-2 context models: bits and time", ""]) + [
             f"Command: `{cmd}`  ",
             f"Date: {datetime.date.today().isoformat()}; machine: {platform.machine()}, {args.threads} torch "
             "threads, shared 2-core VM (timings are noisy; the 1-minute load average is beside each row).  ",
             f"Every model codes the same anchors with the same steps ({args.step} for features, scalings and "
             f"offsets), coarse voxel scale s={args.scale}, K={d.context_k} neighbours, context-model size "
             "chosen by the encoder from the level-2 count (encoder/stream/config.py CONTEXT_MODEL_SIZES) unless stated; "
             f"fit {args.float_steps or d.context_float_steps} float + "
             f"{args.qat_steps if args.qat_steps is not None else d.context_qat_steps} QAT steps, lambda "
             f"{d.context_lambda}. Bytes are real coded bytes (encode_scene); decode is decode_stream on the "
             "stream (bit-exact round trip asserted). Level 1 is coded with the per-channel prior in every row "
             "(the paper's choice); 'L2+model' counts the context-model unit against level 2; 'decoded error': "
             "the mean squared error of the decoded attributes in squared steps (1/12 = 0.083 for plain "
             "rounding; larger where a context model coarsened steps), so rows with the same error quantized "
             "alike. "
             f"parent_base {d.context_parent_base!r}: the encoder fits the per-channel choice ('choose': the "
             "parent's value as the mean's base where it predicts a channel better than the channel's median) "
             "and the parent on every channel ('parent'), and keeps the smaller stream; 'parent_base kept' "
             "says which.", ""]
    lines += ["## (a) Bits per anchor by context model", "",
              "| scene | anchors | model | L1 bits/anchor | L2 bits/anchor | model bytes | L2+model bits/anchor "
              "| all attr bits/anchor | decoded error sq. steps | L2 vs prior | L2+model vs prior | L2 vs parent MLP | L2+model vs parent MLP "
              "| parent_base kept | encode s | of which fit s | decode s | decode anchors/s | load |",
              "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|"]
    scenes = list(args.scene) + [f"procedural:{n}" for n in args.sizes]
    for spec in scenes:
        scene, label, twin = load_scene(spec)
        rows = {}
        for model in args.models:
            opts = dict(MODELS[model])
            if opts.pop("twin", False):
                if twin is None:
                    continue
                opts["twin"] = twin
            rows[model] = r = run_one(scene, args, **opts)
            print(label, model, {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()}, flush=True)
        base, par = rows.get("per-channel prior"), rows.get("parent MLP")
        for model, r in rows.items():
            l2m = r["l2_bits"] + 8 * r["ctx_bytes"] / r["n"]

            def ratio(ref, with_model):
                if ref is None:
                    return "-"
                ref_bits = ref["l2_bits"] + (8 * ref["ctx_bytes"] / ref["n"] if with_model else 0)
                return f"{(l2m if with_model else r['l2_bits']) / ref_bits:.3f}"

            lines.append(f"| {label} | {r['n']:,} | {model} | {r['l1_bits']:.1f} | {r['l2_bits']:.1f} | "
                         f"{r['ctx_bytes']:,} | {l2m:.1f} | {r['all_bits']:.1f} | {r['err']:.4f} | {ratio(base, False)} | "
                         f"{ratio(base, True)} | {ratio(par, False)} | {ratio(par, True)} | {r['base']} | "
                         f"{r['enc_s']:.1f} | "
                         f"{r['fit_s']:.1f} | {r['dec_s']:.2f} | {r['n'] / r['dec_s']:,.0f} | {r['load']} |")
        write_lines(args.out, lines)

    if not args.no_tradeoff:
        scene, label, _ = load_scene(args.tradeoff_scene)
        lines += ["", f"## (b) What accuracy costs in time (GG-Conv, level-1 neighbours, {label})", "",
                  "One fit per setting (parent_base 'choose'); 'auto' would fit twice.", "",
                  "| setting | L2+model bits/anchor | L2 bits/anchor | model bytes | fit s | decode s | load |",
                  "|---|---:|---:|---:|---:|---:|---|"]
        pts = []
        base = run_one(scene, args, context_model="per_channel")
        lines.append(f"| per-channel prior | {base['l2_bits']:.1f} | {base['l2_bits']:.1f} | 0 | 0.0 | "
                     f"{base['dec_s']:.2f} | {base['load']} |")
        g = dict(context_model="ggconv", context_neighbour_level=1, context_parent_base="choose")
        big = dict(context_channels=32, context_feat_hidden=64, context_head_hidden=64)
        small = dict(context_channels=8, context_feat_hidden=16, context_head_hidden=16)
        for setting, over in (("size chosen by the encoder, K=8", {}),
                              ("Ch 32, hidden 64, weights 16 bit, K=8", dict(**big, context_weight_bits=16)),
                              ("Ch 32, hidden 64, weights 8 bit, K=8", dict(**big, context_weight_bits=8)),
                              ("Ch 32, hidden 64, weights 16 bit, K=4", dict(**big, context_weight_bits=16, context_k=4)),
                              ("Ch 32, hidden 64, weights 16 bit, K=16",
                               dict(**big, context_weight_bits=16, context_k=16)),
                              ("Ch 8, hidden 16, weights 8 bit, K=8", dict(**small, context_weight_bits=8))):
            r = run_one(scene, args, **g, **over)
            l2m = r["l2_bits"] + 8 * r["ctx_bytes"] / r["n"]
            pts.append((setting, l2m, r["fit_s"], r["dec_s"] - base["dec_s"]))
            print(setting, r, flush=True)
            lines.append(f"| {setting} | {l2m:.1f} | {r['l2_bits']:.1f} | {r['ctx_bytes']:,} | {r['fit_s']:.1f} | "
                         f"{r['dec_s']:.2f} | {r['load']} |")
            write_lines(args.out, lines)
        lines += ["", "decode s is the whole decoder; the per-channel row is the decoder without a context "
                  "model, so the difference is the k-NN plus GG-Conv inference."]
        plot = args.plot or args.out.with_suffix(".png")
        lines.append(plot_tradeoff(pts, label, plot))
    write_lines(args.out, lines)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
