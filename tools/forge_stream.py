#!/usr/bin/env python3
"""Write a small legal stream that needs a lot of memory to decode (issue 14): a dense cube of
side^3 anchors, all attributes zero, C + 6 + 3K channels (lghcc.conformance.forge).

    python tools/forge_stream.py -o big.lghcc                       # 2^21 anchors x 1024 channels: 8 GiB
    python tools/forge_stream.py -o big.lghcc --exact-hash          # with the decoded scene's real hash
    lghcc-dec big.lghcc; echo $?                                    # refused: exit status 4, amount named

The default is the issue's example: 128^3 = 2^21 anchors, C = 1015, K = 1 (M = 1024), within the
level limits (N * M = 2^31), about 2 kB, whose attribute array alone is 8 GiB. Without
--exact-hash the stream carries 32 zero bytes as its hash (hashing 8 GiB takes tens of seconds);
the memory bound refuses it before that matters.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", required=True, help="the .lghcc file to write")
    ap.add_argument("--side", type=int, default=128, help="anchors per side of the cube (default 128: 2^21 anchors)")
    ap.add_argument("--feature-dim", type=int, default=1015, help="C (default 1015)")
    ap.add_argument("--offsets", type=int, default=1, help="K (default 1)")
    ap.add_argument("--exact-hash", action="store_true", help="carry the real decoded-scene hash (slow)")
    args = ap.parse_args(argv)
    from lghcc.app.fileio import atomic_write_bytes
    from lghcc.conformance.forge import dense_zero_stream

    t0 = time.perf_counter()
    data = dense_zero_stream(args.side, args.feature_dim, args.offsets, exact_hash=args.exact_hash)
    atomic_write_bytes(args.output, data)
    n, m = args.side ** 3, args.feature_dim + 6 + 3 * args.offsets
    print(f"{args.output}: {len(data):,} bytes, {n:,} anchors x {m:,} channels (attribute array "
          f"{4 * n * m / 2**30:.2f} GiB), hash {'exact' if args.exact_hash else 'zero'}, "
          f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
