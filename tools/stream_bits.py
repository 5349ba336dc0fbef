#!/usr/bin/env python3
"""Where the bits of an explicit-Gaussian stream go: bits per Gaussian of each part, from the
stream alone (no encoder, no source scene).

The stream is decoded once (lghcc's decoder, one process) and every byte is charged to one part,
so that the parts add up to the file size:

- geometry: the geometry units;
- DC, SH rest, opacity, scales, rotation (the length index and x, y, z with a rotation_length
  unit, else w, x, y, z): the symbol chunks of the attribute units, each chunk's bytes shared
  among its channels in proportion to their ideal code lengths (common/entropy/symbol_coder.py
  code_lengths_bits of the residuals as decoded, at their scale levels); the "coder overhead"
  line says how far the chunks' bytes lie above those ideal lengths (the range coder's
  termination and the table precision), already inside the parts;
- step indices: the step-adjustment chunks (format 1.2), SH-degree flags: the SH-degree chunks
  (format 1.3), each its own bytes;
- attribute headers: what an attribute unit holds besides its chunks (per-channel priors, chunk
  sizes, cross-channel prediction);
- model: the units that parameterize the coding of every Gaussian (neighbour_prediction,
  step_adjust, step_adjust_flags, sh_degree, rotation_length, sh_transform, context and render models);
- headers: the container header, the parameter set, the decoded-scene hash, the tile index, every
  unit's framing (type, size, CRC) and ancillary units.

Bits per Gaussian divide by the stream's Gaussians (those coded, after pruning or merging) and,
with ``--source-gaussians``, also by the source's.

    python tools/stream_bits.py a.lghcc b.lghcc --labels "logo low,logo medium" --out table.md
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch: idle threads must not spin

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchutil import command_line, write_lines  # noqa: E402

import lghcc.common.attributes as attr  # noqa: E402
import lghcc.common.neighbour_prediction as nbp  # noqa: E402
from lghcc.common.container import UnitType, read_container  # noqa: E402
from lghcc.common.entropy.symbol_coder import code_lengths_bits  # noqa: E402
from lghcc.decoder.decode import decode_stream  # noqa: E402

CHANNEL_PARTS = ("DC", "SH rest", "opacity", "scales", "rotation")
PARTS = ("geometry", *CHANNEL_PARTS, "step indices", "SH-degree flags", "attribute headers", "model", "headers")
MODEL_UNITS = {UnitType.NEIGHBOUR_PREDICTION, UnitType.STEP_ADJUST, UnitType.STEP_ADJUST_FLAGS, UnitType.SH_DEGREE,
               UnitType.ROTATION_LENGTH, UnitType.SH_TRANSFORM,
               UnitType.CONTEXT_MODEL, UnitType.RENDER_MODEL}
DETAIL = ("SH band 1", "SH band 2", "SH band 3", "rotation length index or w", "rotation x", "rotation y", "rotation z")
HEADER_UNITS = {UnitType.SCENE_PARAMETER_SET, UnitType.GAUSSIAN_PARAMETER_SET, UnitType.DECODED_SCENE_HASH,
                UnitType.TILE_INDEX}


class _Recorder:
    """Wraps the decoder's symbol-chunk and side-chunk readers to record what each chunk costs."""

    def __init__(self):
        self.chunks: list[tuple[int, np.ndarray]] = []  # (bytes, ideal bits per channel [M])
        self.adjust_bytes = 0
        self.degree_bytes = 0

    def __enter__(self):
        self._residual, self._adjust, self._degrees = (attr.decode_residual_chunk, nbp.decode_adjust_chunk,
                                                       nbp.decode_degree_chunk)
        rec = self

        def residual_chunk(data, levels, live, what):
            r = rec._residual(data, levels, live, what)
            bits = code_lengths_bits(r, np.asarray(levels))
            if live is not None:
                bits = np.where(live, bits, 0.0)
            rec.chunks.append((len(data), bits.sum(axis=0)))
            return r

        def adjust_chunk(piece, *args):
            rec.adjust_bytes += len(piece)
            return rec._adjust(piece, *args)

        def degree_chunk(piece, *args):
            rec.degree_bytes += len(piece)
            return rec._degrees(piece, *args)

        attr.decode_residual_chunk, nbp.decode_adjust_chunk, nbp.decode_degree_chunk = (residual_chunk, adjust_chunk,
                                                                                          degree_chunk)
        return self

    def __exit__(self, *exc):
        attr.decode_residual_chunk, nbp.decode_adjust_chunk, nbp.decode_degree_chunk = (self._residual, self._adjust,
                                                                                          self._degrees)


def stream_parts(data: bytes) -> dict:
    """{'gaussians', 'sh_degree', 'bytes', 'parts': {part: bytes (float: the channel parts are
    shares)}, 'detail': {SH band b / rotation channel: bytes, inside the parts}, 'ideal_bytes' (the
    symbol chunks' ideal code lengths), 'symbol_bytes' (their bytes)}."""
    container = read_container(data)
    with _Recorder() as rec:
        result = decode_stream(data, jobs=1, exact_jobs=True)
    n = result.scene.num_gaussians
    sh_degree = result.scene.sh_degree
    parts = dict.fromkeys(PARTS, 0.0)
    parts["headers"] += len(data) - sum(u.size for u in container.units)  # the container header
    attribute_payload = 0
    for u in container.units:
        framing = u.size - len(u.payload)
        parts["headers"] += framing
        if u.is_ancillary or u.unit_type in HEADER_UNITS:
            parts["headers"] += len(u.payload)
        elif u.unit_type == UnitType.GEOMETRY:
            parts["geometry"] += len(u.payload)
        elif u.unit_type in MODEL_UNITS:
            parts["model"] += len(u.payload)
        elif u.unit_type == UnitType.ATTRIBUTE:
            attribute_payload += len(u.payload)
        else:
            parts["headers"] += len(u.payload)
    sh = 3 * (sh_degree + 1) ** 2
    columns = {"DC": slice(0, 3), "SH rest": slice(3, sh), "opacity": slice(sh, sh + 1),
               "scales": slice(sh + 1, sh + 4), "rotation": slice(sh + 4, sh + 8)}
    # the detail: each SH band of the SH rest, and each rotation channel (the first the length
    # index with a rotation_length unit)
    band = np.floor(np.sqrt(np.arange(sh) // 3)).astype(np.int64)
    detail_cols = {f"SH band {b}": np.nonzero(band == b)[0] for b in range(1, sh_degree + 1)}
    detail_cols.update({name: [sh + 4 + i] for i, name in enumerate(
        ("rotation length index" if _has(container, UnitType.ROTATION_LENGTH) else "rotation w",
         "rotation x", "rotation y", "rotation z"))})
    detail = dict.fromkeys(detail_cols, 0.0)
    symbol_bytes = ideal = 0.0
    for size, bits in rec.chunks:
        total = bits.sum()
        symbol_bytes += size
        ideal += total / 8
        for part, cols in columns.items():
            parts[part] += size * (bits[cols].sum() / total if total > 0 else 1 / 5)
        for name, cols in detail_cols.items():
            detail[name] += size * (bits[cols].sum() / total if total > 0 else 0.0)
    parts["step indices"] = rec.adjust_bytes
    parts["SH-degree flags"] = rec.degree_bytes
    parts["attribute headers"] = attribute_payload - symbol_bytes - rec.adjust_bytes - rec.degree_bytes
    assert abs(sum(parts.values()) - len(data)) < 1e-6 * len(data) + 1e-3, (sum(parts.values()), len(data))
    return {"gaussians": n, "sh_degree": sh_degree, "bytes": len(data), "parts": parts, "detail": detail,
            "ideal_bytes": ideal, "symbol_bytes": symbol_bytes}


def _has(container, unit_type: UnitType) -> bool:
    return any(not u.is_ancillary and u.unit_type == unit_type for u in container.units)


def table(rows: list[tuple[str, dict]], source_gaussians: list[int | None]) -> list[str]:
    head = "| stream | Gaussians coded | bytes | " + " | ".join(PARTS) + " | total | coder overhead |"
    lines = [head, "|---|---:|---:|" + "---:|" * (len(PARTS) + 2)]
    for (label, r), ns in zip(rows, source_gaussians):
        n = r["gaussians"]
        cells = [f"{8 * r['parts'][p] / n:.2f}" for p in PARTS]
        total = f"{8 * r['bytes'] / n:.2f}" + (f" ({8 * r['bytes'] / ns:.2f} per source Gaussian)" if ns else "")
        over = r["symbol_bytes"] / r["ideal_bytes"] - 1 if r["ideal_bytes"] else 0.0
        lines.append(f"| {label} | {n:,} | {r['bytes']:,} | " + " | ".join(cells) + f" | {total} | {over:+.2%} |")
    lines += ["", "Inside the SH rest and the rotation (bits per Gaussian):", "",
              "| stream | " + " | ".join(DETAIL) + " |", "|---|" + "---:|" * len(DETAIL)]
    for label, r in rows:
        d, n = r["detail"], r["gaussians"]
        rot_first = d.get("rotation length index", d.get("rotation w", 0.0))
        cells = [8 * (rot_first if k == "rotation length index or w" else d.get(k, 0.0)) / n for k in DETAIL]
        lines.append(f"| {label} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("streams", nargs="+", type=Path, help="explicit-Gaussian .lghcc streams")
    p.add_argument("--labels", default=None, help="comma-separated row labels (default: the file names)")
    p.add_argument("--source-gaussians", default=None,
                   help="comma-separated Gaussian counts of the sources (also bits per source Gaussian)")
    p.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    args = p.parse_args(argv)
    labels = args.labels.split(",") if args.labels else [s.name for s in args.streams]
    if len(labels) != len(args.streams):
        p.error("--labels: one label per stream")
    counts = [int(x) if x else None for x in args.source_gaussians.split(",")] if args.source_gaussians else \
        [None] * len(args.streams)
    if len(counts) != len(args.streams):
        p.error("--source-gaussians: one count per stream")
    rows = []
    for label, path in zip(labels, args.streams):
        r = stream_parts(path.read_bytes())
        rows.append((label, r))
        print(f"{label}: {r['bytes']:,} B, {r['gaussians']:,} Gaussians, SH {r['sh_degree']}, "
              f"{8 * r['bytes'] / r['gaussians']:.2f} bits per Gaussian", file=sys.stderr)
    lines = table(rows, counts)
    print("\n".join(lines))
    if args.out:
        write_lines(args.out, [f"Command: `{command_line('stream_bits.py', argv)}`", "", *lines])
    return 0


if __name__ == "__main__":
    sys.exit(main())
