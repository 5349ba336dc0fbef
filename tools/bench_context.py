#!/usr/bin/env python3
"""Level-2 context models on procedural scenes: bits and time.

(a) For each size: attribute bits per anchor (level 1, level 2, all) and context-model bytes
    with the per-channel prior, the parent MLP ("vanilla EM") and GG-Conv, all through the
    real encoder (``encode_scene``, context_fallback off so the model is always used) and the
    real decoder (``decode_stream``, bit-exact round trip checked); encode time, context fit
    time and decode time. Level 1 always uses the per-channel prior (the paper's choice), so
    the model ratios are given for level 2 alone and for all attributes.
(b) "What accuracy costs in time": GG-Conv at context weight bits 8 / 16 and at K = 4, 8, 16
    neighbours on one size: level-2 bits, fit time, GG-Conv inference time (k-NN included)
    and decode time; a PNG plot when matplotlib is installed (``pip install -e .[tools]``).

    python tools/bench_context.py --sizes 10000 100000 --tradeoff-size 20000
"""

from __future__ import annotations

import argparse
import datetime
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

MODELS = ("per_channel", "parent_mlp", "ggconv")
NAMES = {"per_channel": "per-channel prior", "parent_mlp": "parent MLP", "ggconv": "GG-Conv"}


def _load() -> str:
    try:
        return " ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "n/a"


def run_one(scene, model: str, args, **over) -> dict:
    import numpy as np

    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.config import EncoderConfig
    from lghcc.encoder.encode import encode_scene

    kw = dict(hierarchy=True, coarse_voxel_scale=args.scale, context_model=model, context_fallback=False,
              context_float_steps=args.float_steps, context_qat_steps=args.qat_steps)
    kw.update(over)
    cfg = EncoderConfig(**kw)
    t0 = time.perf_counter()
    res = encode_scene(scene, cfg)
    t_enc = time.perf_counter() - t0
    st = res.stats
    n = scene.coords.shape[0]
    t0 = time.perf_counter()
    dec = decode_stream(res.data)
    t_dec = time.perf_counter() - t0
    assert np.array_equal(dec.scene.features, res.decoded.features), "decoder mismatch"
    l1, l2 = st.get("attribute_bytes_level1", 0), st.get("attribute_bytes_level2", 0)
    ctx = st["level2_bytes_with_context"] - l2 if model != "per_channel" else 0
    return {"n": n, "n2": None, "l1_bits": 8 * l1 / n, "l2_bits": 8 * l2 / n, "ctx_bytes": ctx,
            "all_bits": 8 * (l1 + l2 + ctx) / n, "enc_s": t_enc, "fit_s": st.get("time_context_fit_s", 0.0),
            "dec_s": t_dec}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000], help="anchor counts for table (a)")
    ap.add_argument("--scale", type=int, default=4, help="coarse voxel scale s (default 4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--float-steps", type=int, default=300, help="context fit: float steps (encoder default 300)")
    ap.add_argument("--qat-steps", type=int, default=150, help="context fit: QAT steps (encoder default 150)")
    ap.add_argument("--tradeoff-size", type=int, default=20000, help="anchors for table (b); 0 skips it")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--out", type=Path, default=ROOT / "tools" / "results" / "context.md")
    ap.add_argument("--plot", type=Path, default=None, help="PNG for table (b) (default: next to --out)")
    args = ap.parse_args(argv)

    import torch

    from lghcc.common.procedural import make_procedural_scene

    torch.set_num_threads(args.threads)
    cmd = "python tools/bench_context.py " + " ".join(sys.argv[1:] if argv is None else argv)
    lines = ["# Level-2 context models: bits and time", "",
             f"Command: `{cmd}`  ",
             f"Date: {datetime.date.today().isoformat()}; machine: {platform.machine()}, {args.threads} torch threads, "
             "shared 2-core VM (timings are noisy; the 1-minute load average is given beside each row). "
             f"Scenes: `make_procedural_scene(n, seed={args.seed})` (C=50, K=10, M=86 channels), coarse voxel "
             f"scale s={args.scale}, default steps, context fit {args.float_steps} float + {args.qat_steps} QAT steps, "
             "lambda 16, 16-bit weights, K=8 unless stated. Bytes are real coded bytes (encode_scene), "
             "decode is decode_stream on the stream (bit-exact round trip asserted). Level 1 is always "
             "coded with the per-channel prior; 'ratio L2' compares level-2 bits including the "
             "context-model unit, 'ratio all' all attribute bits.", ""]

    lines += ["## (a) Bits per anchor by context model", "",
              "| anchors | model | L1 bits/anchor | L2 bits/anchor | context model bytes | all attr bits/anchor "
              "| ratio L2 vs prior | ratio L2 vs parent MLP | ratio all vs prior | encode s | of which fit s "
              "| decode s | decode anchors/s | load |",
              "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for n in args.sizes:
        scene = make_procedural_scene(n, args.seed)
        rows = {}
        for model in MODELS:
            r = run_one(scene, model, args)
            r["load"] = _load()
            rows[model] = r
            print(n, model, r, flush=True)
        base, par = rows["per_channel"], rows["parent_mlp"]
        for model in MODELS:
            r = rows[model]
            l2c = r["l2_bits"] + 8 * r["ctx_bytes"] / r["n"]
            l2b = base["l2_bits"]
            l2p = par["l2_bits"] + 8 * par["ctx_bytes"] / par["n"]
            lines.append(f"| {r['n']:,} | {NAMES[model]} | {r['l1_bits']:.1f} | {r['l2_bits']:.1f} | "
                         f"{r['ctx_bytes']:,} | {r['all_bits']:.1f} | {l2c / l2b:.3f} | "
                         f"{(l2c / l2p) if model != 'per_channel' else float('nan'):.3f} | "
                         f"{r['all_bits'] / base['all_bits']:.3f} | {r['enc_s']:.1f} | {r['fit_s']:.1f} | "
                         f"{r['dec_s']:.2f} | {r['n'] / r['dec_s']:,.0f} | {r['load']} |")
        _write(args.out, lines)

    if args.tradeoff_size:
        n = args.tradeoff_size
        scene = make_procedural_scene(n, args.seed)
        lines += ["", f"## (b) What accuracy costs in time (GG-Conv, {n:,} anchors)", "",
                  "| setting | L2 bits/anchor (incl. model) | context model bytes | fit s | decode s | load |",
                  "|---|---:|---:|---:|---:|---|"]
        pts = []
        base = run_one(scene, "per_channel", args)
        lines.append(f"| per-channel prior | {base['l2_bits']:.1f} | 0 | 0.0 | {base['dec_s']:.2f} | {_load()} |")
        for label, over in (("weights 8 bit, K=8", dict(context_weight_bits=8)),
                            ("weights 16 bit, K=8", dict(context_weight_bits=16)),
                            ("weights 16 bit, K=4", dict(context_k=4)),
                            ("weights 16 bit, K=16", dict(context_k=16))):
            r = run_one(scene, "ggconv", args, **over)
            l2c = r["l2_bits"] + 8 * r["ctx_bytes"] / r["n"]
            pts.append((label, l2c, r["fit_s"], r["dec_s"] - base["dec_s"]))
            print(label, r, flush=True)
            lines.append(f"| {label} | {l2c:.1f} | {r['ctx_bytes']:,} | {r['fit_s']:.1f} | {r['dec_s']:.2f} | {_load()} |")
            _write(args.out, lines)
        lines += ["", "decode s includes the whole decoder; the per-channel row is the decoder without a "
                  "context model, so the difference is the k-NN plus GG-Conv inference."]
        plot = args.plot or args.out.with_suffix(".png")
        try:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            lines.append("(matplotlib not installed: no plot; `pip install -e .[tools]`)")
        else:
            fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
            for label, bits, fit, dec in pts:
                ax[0].scatter(fit, bits)
                ax[0].annotate(label, (fit, bits), fontsize=7)
                ax[1].scatter(dec, bits)
                ax[1].annotate(label, (dec, bits), fontsize=7)
            ax[0].set_xlabel("fit (encode) s")
            ax[1].set_xlabel("decode s over the prior's decode")
            ax[0].set_ylabel("level-2 bits/anchor")
            fig.suptitle(f"GG-Conv accuracy vs time, {n:,} anchors")
            fig.tight_layout()
            fig.savefig(plot, dpi=110)
            lines.append(f"![accuracy vs time]({plot.name})")
    _write(args.out, lines)
    print(f"wrote {args.out}")
    return 0


def _write(path: Path, lines: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
