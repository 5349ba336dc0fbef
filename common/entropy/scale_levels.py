"""The 64 scale levels and the layout of the frozen scale tables (spec/entropy.md, clause 10.2).

What both the table generator (tools/gen_scale_tables.py) and the loader (tables.py) follow;
this module reads no file, so the generator can import it before the tables exist.

Level i has the nominal standard deviation sigma_i = 0.11 * (512 / 0.11) ^ (i / 63)
quantization steps (informative: it explains where the tables came from; decoding uses
only the frozen integer tables).
"""

from __future__ import annotations

import math

import numpy as np

SCALE_LEVEL_BITS = 6  # a scale level is coded as u(6)
NUM_SCALE_LEVELS = 1 << SCALE_LEVEL_BITS  # 64
NUM_ESCAPE_CLASSES = 63  # class k = bit length of m = |r| - L - 1 < 2^62
TABLES_MAGIC = b"LGHCC scale tables v1\n"

SIGMA_MIN, SIGMA_MAX = 0.11, 512.0  # sigma_0 and sigma_63, in quantization steps


def sigma_of_level(level) -> np.ndarray:
    """sigma_i = SIGMA_MIN * (SIGMA_MAX / SIGMA_MIN) ^ (i / 63), float64 (informative)."""
    return SIGMA_MIN * (SIGMA_MAX / SIGMA_MIN) ** (np.asarray(level, dtype=np.float64) / (NUM_SCALE_LEVELS - 1))


# The same rule in the log domain, ln sigma_i = LOG_SIGMA_MIN + i LOG_SIGMA_STEP, for the
# encoder's differentiable rate estimates (encoder/context/ggconv_train.py, encoder/anchors/rate_model.py).
LOG_SIGMA_MIN = math.log(SIGMA_MIN)
LOG_SIGMA_STEP = math.log(SIGMA_MAX / SIGMA_MIN) / (NUM_SCALE_LEVELS - 1)


def canonical_bytes(half_widths: np.ndarray, freqs: np.ndarray, class_freqs: np.ndarray) -> bytes:
    """The serialization the tables' SHA-256 is taken of: TABLES_MAGIC, then little-endian
    uint32 words: 64, L_0..L_63, every level's frequencies (level 0 first, bins in order
    r = -L..L, ESC), 63, the class frequencies."""
    words = np.concatenate([[np.asarray(half_widths).size], half_widths, freqs,
                            [np.asarray(class_freqs).size], class_freqs])
    return TABLES_MAGIC + np.asarray(words, dtype=np.int64).astype("<u4").tobytes()
