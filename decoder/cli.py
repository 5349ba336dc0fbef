"""lghcc-dec: decode a .lghcc file into the Scaffold-GS checkpoint layout."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lghcc.common.errors import HashMismatchError, LghccError
from lghcc.common.fileio import atomic_write_bytes

DESCRIPTION = """\
Decode an LG-HCC stream (.lghcc) into an anchor scene in the Scaffold-GS layout:
  OUT/point_cloud/iteration_0/point_cloud.ply   anchors
  OUT/point_cloud/iteration_0/checkpoint.pth    render MLPs
The decoder needs nothing but the stream. It checks the hash of the decoded scene
carried in the stream and prints the size of each part (header, geometry,
attributes, model) in bytes and bits per anchor.

examples:
  lghcc-dec demo.lghcc -o decoded/
  lghcc-dec demo.lghcc --trace demo.trace.txt      (no -o: check and report only)
"""


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lghcc-dec", description=DESCRIPTION,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("stream", help="the .lghcc file to decode")
    p.add_argument("-o", "--output", metavar="DIR", help="folder to write the decoded scene to")
    p.add_argument("--no-verify", action="store_true", help="do not check the decoded-scene hash")
    p.add_argument("--trace", metavar="FILE", help="write a bit trace: every syntax element with its position")
    p.add_argument("--threads", type=int, help="torch threads for inference (the output does not depend on it)")
    p.add_argument("--max-anchors", type=int, help="refuse streams declaring more anchors than this")
    p.add_argument("--print-hash", action="store_true",
                   help="print only the SHA-256 of the decoded scene (spec clause 11), computed from the output")
    p.add_argument("--json", metavar="FILE", help="also write the size breakdown as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv: list[str] | None = None) -> int:
    args = setup_args().parse_args(argv)
    from lghcc.common.scaffold_io import write_scaffold
    from lghcc.decoder.decode import decode_stream

    say = (lambda *a: None) if args.quiet else print
    try:
        if args.threads is not None:
            import torch
            torch.set_num_threads(max(1, args.threads))
        try:
            data = Path(args.stream).read_bytes()
        except OSError as e:
            raise LghccError(f"{args.stream}: cannot read ({e.strerror})") from None
        t0 = time.perf_counter()
        result = decode_stream(data, verify_hash=not args.no_verify, trace=bool(args.trace),
                               max_anchors=args.max_anchors, progress=not args.quiet and sys.stderr.isatty())
        t_dec = time.perf_counter() - t0
        if args.output:
            write_scaffold(result.scene, args.output)
        if args.trace:
            lines = [f"{e.bit_position:>10} {e.name:<60} {e.descriptor:<8} "
                     f"{e.value.hex() if isinstance(e.value, bytes) else e.value}" for e in result.trace]
            atomic_write_bytes(args.trace, ("\n".join(lines) + "\n").encode())
    except HashMismatchError as e:
        print(f"lghcc-dec: error: {e}", file=sys.stderr)
        return 3
    except LghccError as e:
        print(f"lghcc-dec: error: {args.stream}: {e}", file=sys.stderr)
        return 1
    s = result.scene
    if args.print_hash:
        from lghcc.common.hashing import scene_digest
        print(scene_digest(s).hex())
        return 0
    say(f"{args.stream}: {s.num_anchors:,} anchors, C={s.feature_dim}, K={s.num_offsets}, "
        f"{len(data):,} bytes, decoded in {t_dec:.2f} s ({s.num_anchors / max(t_dec, 1e-9):,.0f} anchors/s)")
    say(result.breakdown.table())
    for u in result.skipped_units:
        say(f"skipped ancillary unit {u}")
    say("decoded scene hash: " + ("matches the stream" if result.hash_checked else "not checked")
        + f" ({result.stream_hash.hex()})")
    if args.output:
        say(f"wrote {Path(args.output) / 'point_cloud' / 'iteration_0'}")
    if args.json:
        atomic_write_bytes(args.json, json.dumps({
            "stream": args.stream, "num_anchors": s.num_anchors, "bytes": len(data),
            "breakdown": result.breakdown.bytes_by_category, "decode_s": t_dec,
            "hash_checked": result.hash_checked, "scene_sha256": result.stream_hash.hex()}, indent=2).encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
