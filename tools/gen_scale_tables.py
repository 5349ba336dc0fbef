#!/usr/bin/env python3
"""Generate the frozen scale tables (common/entropy/scale_tables.npz). Informative tool.

Run ONCE; the output is a normative constant. Float math is used here only; the
decoder never recomputes anything from it. Regenerating must reproduce the SHA-256
``SCALE_TABLES_SHA256`` in common/entropy/tables.py (checked with ``--check``);
a different result means the float environment differs and the stored file wins.

Construction (spec/entropy.md, clause "Scale tables"):

* level i in [0, 64): sigma_i = 0.11 * (512 / 0.11) ** (i / 63) quantization steps;
* half width L_i = clip(ceil(8 * sigma_i), 4, 4096); bins r = -L_i..L_i, then ESC;
* p(r) = Phi((r + 1/2) / sigma_i) - Phi((r - 1/2) / sigma_i), p(ESC) = 2 * Q((L_i + 1/2) / sigma_i)
  (computed with upper-tail functions for accuracy and mirrored, so exactly symmetric);
* frequencies f = 1 + floor(p * (2^24 - n)) (n = 2 L_i + 2 bins); the remaining units go in
  pairs (r, -r) to the pairs with the largest fractional parts, an odd unit to r = 0;
* escape magnitude classes k = 0..62 with p(k) proportional to (3/4)^k, quantized the same way
  (each >= 1, remainder to the largest fractional parts, ties to the smaller k).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import math
import sys
from pathlib import Path

import numpy as np
from scipy.special import ndtr

from lghcc.common.entropy.range_coder import TOTAL_FREQUENCY as TOTAL
from lghcc.common.entropy.scale_levels import NUM_ESCAPE_CLASSES, NUM_SCALE_LEVELS, canonical_bytes, sigma_of_level

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "common" / "entropy" / "scale_tables.npz"

COVERAGE_SIGMAS = 8.0
MIN_HALF_WIDTH, MAX_HALF_WIDTH = 4, 4096
ESCAPE_CLASS_RATIO = 0.75


def sigmas() -> np.ndarray:
    return sigma_of_level(np.arange(NUM_SCALE_LEVELS))


def upper_tail(x: np.ndarray) -> np.ndarray:
    """Q(x) = 1 - Phi(x), accurate for large x."""
    return ndtr(-x)


def level_table(sigma: float) -> np.ndarray:
    L = int(min(max(math.ceil(COVERAGE_SIGMAS * sigma), MIN_HALF_WIDTH), MAX_HALF_WIDTH))
    n = 2 * L + 2
    r = np.arange(0, L + 1, dtype=np.float64)
    # p(r) for r >= 0, as a difference of upper tails (p(0) = 1 - 2 Q(1/2 sigma))
    p_pos = upper_tail((r - 0.5) / sigma) - upper_tail((r + 0.5) / sigma)
    p_pos[0] = 1.0 - 2.0 * upper_tail(0.5 / sigma)
    p_esc = 2.0 * upper_tail((L + 0.5) / sigma)
    spare = TOTAL - n
    scaled_pos = p_pos * spare
    scaled_esc = p_esc * spare
    f_pos = 1 + np.floor(scaled_pos).astype(np.int64)
    f_esc = 1 + int(math.floor(scaled_esc))
    frac = scaled_pos - np.floor(scaled_pos)
    left = TOTAL - (f_pos[0] + 2 * int(f_pos[1:].sum()) + f_esc)
    assert 0 <= left < n + 2, left
    # pairs (r, -r), r >= 1, with the largest fractional parts get one unit each (stable: ties
    # go to the smaller |r|); an odd unit goes to r = 0
    order = np.argsort(-frac[1:], kind="stable") + 1
    npairs = left // 2
    f_pos[order[:npairs]] += 1
    f_pos[0] += left - 2 * npairs
    f = np.concatenate([f_pos[:0:-1], f_pos, [f_esc]]).astype(np.int64)
    assert f.size == n and int(f.sum()) == TOTAL and int(f.min()) >= 1
    return f


def escape_class_table() -> np.ndarray:
    k = np.arange(NUM_ESCAPE_CLASSES, dtype=np.float64)
    p = ESCAPE_CLASS_RATIO ** k
    p /= p.sum()
    spare = TOTAL - NUM_ESCAPE_CLASSES
    scaled = p * spare
    f = 1 + np.floor(scaled).astype(np.int64)
    left = TOTAL - int(f.sum())
    order = np.argsort(-(scaled - np.floor(scaled)), kind="stable")
    f[order[:left]] += 1
    assert int(f.sum()) == TOTAL and int(f.min()) >= 1
    return f


def build() -> dict[str, np.ndarray]:
    tables = [level_table(s) for s in sigmas()]
    half_widths = np.array([(t.size - 2) // 2 for t in tables], dtype=np.int32)
    offsets = np.concatenate([[0], np.cumsum([t.size for t in tables])]).astype(np.int64)
    return {
        "half_widths": half_widths,
        "offsets": offsets,
        "freqs": np.concatenate(tables).astype(np.int32),
        "escape_class_freqs": escape_class_table().astype(np.int32),
        "sigmas": sigmas(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--check", action="store_true",
                    help="only compare a fresh generation with the stored file (exit 1 if they differ)")
    args = ap.parse_args()
    t = build()
    digest = hashlib.sha256(canonical_bytes(t["half_widths"], t["freqs"], t["escape_class_freqs"])).hexdigest()
    if args.check:
        with np.load(args.out) as z:
            stored = hashlib.sha256(canonical_bytes(z["half_widths"], z["freqs"],
                                                    z["escape_class_freqs"])).hexdigest()
        print(f"generated {digest}\nstored    {stored}")
        return 0 if digest == stored else 1
    buf = io.BytesIO()
    np.savez_compressed(buf, **t)
    Path(args.out).write_bytes(buf.getvalue())
    print(f"wrote {args.out}: {len(buf.getvalue())} bytes, {t['freqs'].size} frequencies")
    print(f"SCALE_TABLES_SHA256 = \"{digest}\"")
    return 0


if __name__ == "__main__":
    sys.exit(main())
