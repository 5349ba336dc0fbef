"""What the step-adjustment indices cost as symbols (format 1.2-1.4) and as flags (format 1.5, a
step_adjust_flags unit, clauses 7.3.16 and 11.8), on existing streams, at the same indices.

    python tools/bench_step_flags.py STREAM [STREAM ...] [--labels a,b,...]

Each stream (one with a step_adjust unit and its indices as symbols) is decoded by the reference
decoder; its indices, chunks and neighbour graphs are recorded, the flags' probabilities set from
the whole stream's flags (as the encoder sets them, encoder/stream/neighbour_coding.py), and every
chunk of indices coded again as flags. The values, geometry and everything else stay as they are,
so the decoded scene is the same and the difference in bytes is exact, but for the tile index's
ue(v) sizes (at most a byte per tile, not counted). Every flag chunk is decoded back and checked.
Prints a markdown table: bits per Gaussian of the indices as symbols and as flags (the unit
included), and the whole stream's bytes before and after.
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

import lghcc.common.neighbour_prediction as nbp  # noqa: E402
import lghcc.decoder.core as core  # noqa: E402  (the decoding process: the hooks go there)
import lghcc.decoder.decode as dec  # noqa: E402
from lghcc.common.sh_degree import decode_flag_chunk, encode_flag_chunk, neighbour_degrees  # noqa: E402
from lghcc.common.units import StepAdjustFlagsUnit  # noqa: E402
from lghcc.encoder.stream.neighbour_coding import flag_counts, flag_probabilities, unit_bytes  # noqa: E402


def recorded_tiles(data: bytes) -> tuple[list[dict], int]:
    """Per tile: {graph, header, adjust (int64 [n])}, decoding the stream once; and its Gaussians."""
    tiles: list[dict] = []
    graph_of, adjust_of, read_unit = nbp.neighbour_graph, nbp.decode_adjust_chunk, core.read_predicted_attribute_unit

    def graph(*a, **k):
        g = graph_of(*a, **k)
        tiles.append({"graph": g, "chunks": []})
        return g

    def adjust(piece, h, step_adjust, num_rows, i, *rest):
        if rest and rest[0] is not None:
            raise SystemExit("the stream's indices are flags already (a step_adjust_flags unit)")
        a = adjust_of(piece, h, step_adjust, num_rows, i, *rest)
        tiles[-1]["chunks"].append(a)
        return a

    def read(*a, **k):
        h = read_unit(*a, **k)
        tiles[-1]["header"] = h
        return h

    nbp.neighbour_graph, nbp.decode_adjust_chunk, core.read_predicted_attribute_unit = graph, adjust, read
    try:
        result = dec.decode_stream(data, jobs=1, verify_hash=True)
    finally:
        nbp.neighbour_graph, nbp.decode_adjust_chunk, core.read_predicted_attribute_unit = graph_of, adjust_of, read_unit
    if not tiles or not tiles[0]["chunks"]:
        raise SystemExit("the stream has no step-adjustment indices (no step_adjust unit)")
    for t in tiles:
        g, h = t["graph"], t["header"]
        adjust = np.zeros(sum(r.size for r in g.rows), np.int64)
        for (level, lo, hi), a in zip(nbp.chunk_segments(h, g), t["chunks"]):
            adjust[g.rows[level][lo:hi]] = a
        t["adjust"] = adjust
    return tiles, result.scene.num_gaussians


def as_flags(data: bytes) -> dict:
    """The stream's bytes and its indices' bytes as symbols and as flags (module doc)."""
    tiles, n = recorded_tiles(data)
    top = max(int(t["adjust"].max(initial=0)) for t in tiles)
    counts = sum(flag_counts(t["graph"], t["adjust"], top) for t in tiles)
    unit = StepAdjustFlagsUnit(max_step_adjust=top, step_flag_prob=flag_probabilities(counts))
    weights = nbp.step_flag_weights(unit)
    symbols = flags = header_delta = 0
    for t in tiles:
        g, h = t["graph"], t["header"]
        sizes = []
        for i, (level, lo, hi) in enumerate(nbp.chunk_segments(h, g)):
            rows = g.rows[level][lo:hi]
            nd = neighbour_degrees(nbp.chunk_neighbours(g, level, lo, hi), t["adjust"])
            chunk = encode_flag_chunk(t["adjust"][rows], nd, top, weights)
            if not np.array_equal(decode_flag_chunk(chunk, rows.size, nd, top, weights, f"chunk {i}"), t["adjust"][rows]):
                raise AssertionError(f"chunk {i}: the flags do not decode to the indices")
            sizes.append(len(chunk))
        h2 = copy.deepcopy(h)
        h2.adjust_chunk_size, h2.adjust_mean, h2.adjust_level = sizes, 0, 0
        symbols += sum(h.adjust_chunk_size)
        flags += sum(sizes)
        header_delta += len(h2.to_bytes()) - len(h.to_bytes())
    after = len(data) - symbols + flags + header_delta + unit_bytes(unit)
    return {"gaussians": n, "bytes": len(data), "symbols": symbols, "flags": flags + header_delta + unit_bytes(unit),
            "after": after}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("streams", nargs="+", type=Path)
    ap.add_argument("--labels", help="comma-separated row labels (default: the file names)")
    args = ap.parse_args(argv)
    labels = args.labels.split(",") if args.labels else [p.name for p in args.streams]
    if len(labels) != len(args.streams):
        ap.error("--labels needs one label per stream")
    print("| stream | Gaussians | bytes (1.4) | indices as symbols, bits/G | as flags (unit included), bits/G | "
          "bytes as 1.5 | change |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, path in zip(labels, args.streams):
        r = as_flags(path.read_bytes())
        g = r["gaussians"]
        print(f"| {label} | {g:,} | {r['bytes']:,} | {8 * r['symbols'] / g:.2f} | {8 * r['flags'] / g:.2f} | "
              f"{r['after']:,} | {100 * (r['after'] / r['bytes'] - 1):+.2f}% |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
