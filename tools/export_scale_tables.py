#!/usr/bin/env python3
"""Write the frozen scale tables as plain text (spec/tables/scale_tables.txt). Informative tool.

The level tables are normative data of the specification (spec/entropy.md, clause 10.2.1): one
line per scale level i = 0..63 holding the n_i = 2 L_i + 2 frequencies F_i[0 .. n_i - 1] (bins
r = -L_i .. L_i, then ESC) as decimal integers separated by one space, each line ended by one
LF, nothing else. This tool writes that file from common/entropy/scale_tables.npz, after the
loader has checked the archive against SCALE_TABLES_SHA256; ``--check`` compares instead of
writing (exit status 1 when the file differs). tests/test_scale_tables_text.py checks that
the file, with the escape class table of clause 10.2.1, serializes to SCALE_TABLES_SHA256.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "spec" / "tables" / "scale_tables.txt"


def table_text() -> str:
    from lghcc.common.entropy.tables import NUM_SCALE_LEVELS, TABLES  # verified against the digest on import

    lines = [" ".join(str(int(f)) for f in TABLES.level(i)) for i in range(NUM_SCALE_LEVELS)]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="compare with the committed file instead of writing it")
    args = ap.parse_args()
    text = table_text()
    if args.check:
        same = OUT.is_file() and OUT.read_bytes() == text.encode("ascii")
        print(f"{OUT}: {'matches' if same else 'DIFFERS from'} common/entropy/scale_tables.npz")
        return 0 if same else 1
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_bytes(text.encode("ascii"))
    print(f"wrote {OUT} ({OUT.stat().st_size:,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
