#!/usr/bin/env python3
"""Regenerate spec/syntax_tables.md from the code's syntax descriptions."""

import argparse
from pathlib import Path

from lghcc.common.spec_tables import syntax_tables_markdown

ROOT = Path(__file__).resolve().parents[1]

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default=str(ROOT / "spec" / "syntax_tables.md"))
    out = Path(ap.parse_args().out)
    out.write_text(syntax_tables_markdown())
    print(f"wrote {out}")
