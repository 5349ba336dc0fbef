"""The frozen scale tables (normative constants; spec/entropy.md, clause "Scale tables").

64 scale levels; level i is an integer frequency table over residuals r in [-L_i, L_i]
followed by one escape bin (ESC), total 2^24, every frequency >= 1. Escaped magnitudes
are coded with one more frozen table over 63 magnitude classes. The tables were generated
once by tools/gen_scale_tables.py and are stored in scale_tables.npz; this module loads
them and checks the SHA-256 of their canonical serialization, so a damaged or edited file
can never silently change the code.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from .range_coder import PRECISION_BITS, TOTAL_FREQUENCY  # noqa: F401 (re-exported)
from .scale_levels import (NUM_ESCAPE_CLASSES, NUM_SCALE_LEVELS, TABLES_MAGIC,  # noqa: F401 (re-exported)
                           canonical_bytes, sigma_of_level)

MAX_ABS_RESIDUAL = (1 << 62) - 1  # every |r| <= this can be coded; larger values are rejected
SCALE_TABLES_SHA256 = "d190e032e31f5d4f0aaca7804206cdad1b718a0fbd79e00c1f458764b3da9d87"
TABLES_PATH = Path(__file__).with_name("scale_tables.npz")

#: Nominal standard deviation of each level, in quantization steps (informative).
SCALE_SIGMAS = sigma_of_level(np.arange(NUM_SCALE_LEVELS))


class ScaleTables:
    """The loaded, verified tables. Arrays are read-only."""

    def __init__(self, half_widths: np.ndarray, freqs: np.ndarray, class_freqs: np.ndarray) -> None:
        self.half_widths = np.asarray(half_widths, dtype=np.int64)           # L_i, [64]
        self.sizes = 2 * self.half_widths + 2                                 # bins per level (incl. ESC)
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)]).astype(np.int64)  # [65]
        self.freqs = np.asarray(freqs, dtype=np.int64)                        # all levels concatenated
        self.escape_class_freqs = np.asarray(class_freqs, dtype=np.int64)     # [63]
        for a in (self.half_widths, self.sizes, self.offsets, self.freqs, self.escape_class_freqs):
            a.setflags(write=False)

    def level(self, i: int) -> np.ndarray:
        """Frequencies of level i: bins r = -L_i..L_i (index r + L_i), then ESC (index 2 L_i + 1)."""
        return self.freqs[self.offsets[i]:self.offsets[i + 1]]


def load_tables(path: Path | str = TABLES_PATH, expected_sha256: str = SCALE_TABLES_SHA256) -> ScaleTables:
    try:
        with np.load(path) as z:
            half_widths, freqs, class_freqs = z["half_widths"], z["freqs"], z["escape_class_freqs"]
            offsets = z["offsets"]
    except (OSError, KeyError, ValueError) as e:
        raise RuntimeError(f"cannot read the frozen scale tables {path}: {e}") from None
    digest = hashlib.sha256(canonical_bytes(half_widths, freqs, class_freqs)).hexdigest()
    if digest != expected_sha256:
        raise RuntimeError(f"frozen scale tables {path} are damaged: SHA-256 {digest}, "
                           f"expected {expected_sha256}")
    t = ScaleTables(half_widths, freqs, class_freqs)
    # structural checks (the digest already pins the values; these guard the layout)
    if (t.half_widths.size != NUM_SCALE_LEVELS or t.escape_class_freqs.size != NUM_ESCAPE_CLASSES
            or t.offsets[-1] != t.freqs.size or not np.array_equal(np.asarray(offsets), t.offsets)):
        raise RuntimeError(f"frozen scale tables {path} have an unexpected layout")
    return t


TABLES = load_tables()
HALF_WIDTHS = TABLES.half_widths
