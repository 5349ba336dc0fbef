#!/usr/bin/env python3
"""What the encoder's choices cost in bytes and PSNR, for the JavaScript decoder's speed (issue 54 item 4).

Encodes one explicit-Gaussian scene at a preset (default fast: no renders, so that each variant is
a few seconds to minutes) with each variant's settings over it, writes each stream, and measures
its decoded scene's PSNR against the source on an orbit of ``--views`` cameras of ``--size`` px
(tools/bench_real.py's orbit: render/views.py orbit_cameras, 20 degrees up, black background; the
same cameras for every variant). One variant, ``steps:F``, multiplies every quantization step and
the position step by F: with the base's it gives the local slope (dB per doubling of the bytes) by
which every other variant's bytes are moved to the base's PSNR ("bytes at equal PSNR").

    OMP_WAIT_POLICY=PASSIVE python tools/bench_web_choices.py SCENE --out DIR \\
        --variant base --variant steps:1.15 --variant no_np:neighbour_prediction=false ...

SCENE: a name of tools/bench_real.py (playcanvas-logo, playbot-lod3, donut, playbot-lod4), scale-N
(tools/scale_scenes.py's scene of N Gaussians: scale-1000000 is the pool target's 1M scene), or any
input lghcc-enc reads (a PLY, SPZ, a streamed SOG lod-meta.json) with ``@UP`` for its up axis
(default: detected as bench_real does). A variant: ``NAME`` (the preset as it is), ``NAME:key=value,
key=value`` (GaussianEncoderConfig fields over the preset: true/false, integers, numbers, strings) or
``steps:F``. Prints one JSON line per variant {variant, bytes, psnr, gaussians, encode_s, stream} and
a last line with the slope and each variant's bytes at the base's PSNR (the first variant is the base).
The streams go to DIR/SCENE_VARIANT.lghcc for tools/bench_js_spz.mjs.
"""
import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real  # noqa: E402

STEP_FIELDS = ("sh_dc_step", "opacity_step", "scale_step", "rotation_step", "position_step")


def parse_value(text: str):
    """A YAML-like scalar: true/false, an integer, a number, else the string."""
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def variant_config(spec: str, base):
    """``spec`` (NAME, NAME:key=value,..., or steps:F) over the preset's config -> (name, config)."""
    name, _, rest = spec.partition(":")
    if name == "steps":
        f = float(rest)
        scaled = {k: getattr(base, k) * f for k in STEP_FIELDS}
        scaled["sh_band_steps"] = tuple(s * f for s in base.sh_band_steps)
        return f"steps{f:g}", dataclasses.replace(base, **scaled)
    fields = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq or not hasattr(base, key):
            raise SystemExit(f"variant {spec!r}: {item!r} is not key=value of a GaussianEncoderConfig field")
        fields[key] = parse_value(value)
    return name, dataclasses.replace(base, **fields)


def load_scene(spec: str, data_root: Path):
    """(label, GaussianScene, up axis) of a bench_real scene name or a path[@UP]."""
    from lghcc.formats import read_scene

    path_text, _, up = spec.partition("@")
    if path_text.startswith("scale-"):  # tools/scale_scenes.py's scene of that many Gaussians (e.g. the 1M stream's)
        import scale_scenes

        n = int(path_text.removeprefix("scale-"))
        return path_text, scale_scenes.build_scene(n, scale_scenes.load_sources(data_root))[0], up or "-y"
    if path_text in bench_real.SCENES:
        rel, rec_up, _ = bench_real.SCENES[path_text]
        return path_text, read_scene(data_root / rel), up or rec_up
    scene = read_scene(path_text)
    label = Path(path_text).parent.name if Path(path_text).name == "lod-meta.json" else Path(path_text).stem
    return label, scene, up or bench_real.detect_up(scene.means, scene.opacity)[0]


def psnr_against(source_images: list, scene, cams) -> float:
    from lghcc.encoder.gaussians.gaussian_rd import whole_scene_renders

    mse = [float(((a.clamp(0, 1) - b.clamp(0, 1)) ** 2).double().mean())
           for a, b in zip(whole_scene_renders(scene, cams), source_images)]
    return -10 * math.log10(max(sum(mse) / len(mse), 1e-12))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="a bench_real scene name or an input path, optionally @UP")
    ap.add_argument("--variant", action="append", required=True,
                    help="NAME, NAME:key=value,... or steps:F (repeatable; the first is the base)")
    ap.add_argument("--preset", default="fast", help="the preset the variants change (default fast)")
    ap.add_argument("--out", required=True, help="folder for the streams")
    ap.add_argument("--views", type=int, default=12, help="orbit cameras for the PSNR (default 12)")
    ap.add_argument("--size", type=int, default=256, help="their size in px, square (default 256)")
    ap.add_argument("--no-psnr", action="store_true", help="streams and bytes only (no renders: a large scene "
                    "meant for decode timings)")
    ap.add_argument("--data-root", default=str(bench_real.default_data_root()),
                    help="where the named scenes lie (default ../shared/data)")
    args = ap.parse_args(argv)

    from lghcc.encoder.gaussians.gaussian_rd import whole_scene_renders
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene, without_invisible
    from lghcc.encoder.stream.config import load_config

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    label, scene, up = load_scene(args.scene, Path(args.data_root))
    cams = bench_real.orbit(scene.means, args.views, args.size, up)
    source_images = None if args.no_psnr else whole_scene_renders(scene, cams)
    base_cfg = load_config(args.preset, kind="gaussians")
    rows = []
    for spec in args.variant:
        name, cfg = variant_config(spec, base_cfg)
        t0 = time.perf_counter()
        kept, _ = without_invisible(scene, cfg)
        res = encode_gaussian_scene(kept, cfg)
        seconds = time.perf_counter() - t0
        path = out / f"{label}_{name}.lghcc"
        path.write_bytes(res.data)
        row = {"variant": name, "spec": spec, "bytes": len(res.data), "psnr": None if args.no_psnr else psnr_against(source_images, res.decoded, cams),
               "gaussians": res.decoded.num_gaussians, "encode_s": round(seconds, 1), "stream": str(path),
               "load": os.getloadavg()[0]}
        rows.append(row)
        print(json.dumps(row), flush=True)
    print(json.dumps(equal_psnr(rows)), flush=True)
    return 0


def equal_psnr(rows: list[dict]) -> dict:
    """Each row's bytes moved to the first row's PSNR along the slope of the base and its steps:F
    row (dB per doubling of the bytes), where there is one."""
    base = rows[0]
    scaled = [r for r in rows if r["variant"].startswith("steps")]
    if base["psnr"] is None or not scaled or scaled[0]["bytes"] == base["bytes"]:
        return {"slope_db_per_doubling": None}
    s = scaled[0]
    slope = (base["psnr"] - s["psnr"]) / math.log2(base["bytes"] / s["bytes"])
    if slope <= 0:  # the PSNR did not follow the steps: too few or too small views to measure by
        return {"slope_db_per_doubling": round(slope, 3), "bytes_at_base_psnr": None,
                "note": "the PSNR did not fall with the bytes: measure on more or larger views (--views, --size)"}
    eq = {r["variant"]: round(r["bytes"] * 2 ** ((base["psnr"] - r["psnr"]) / slope)) for r in rows}
    rel = {k: round(100 * (v / base["bytes"] - 1), 2) for k, v in eq.items()}
    return {"slope_db_per_doubling": round(slope, 3), "bytes_at_base_psnr": eq, "percent_vs_base": rel}


if __name__ == "__main__":
    sys.exit(main())
