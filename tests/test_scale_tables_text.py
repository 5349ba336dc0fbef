"""spec/tables/scale_tables.txt: the normative level tables as plain data (spec/entropy.md, clause
10.2.1). An implementer reads them from the spec alone: the file's 64 lines, with the half widths
and the escape class table printed in clause 10.2.1, serialize canonically (clause 10.2.2) to
SCALE_TABLES_SHA256, and they are the tables of common/entropy/scale_tables.npz."""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from lghcc.common.entropy.tables import (NUM_ESCAPE_CLASSES, NUM_SCALE_LEVELS, SCALE_TABLES_SHA256, TABLES,
                                         TOTAL_FREQUENCY, canonical_bytes)

ROOT = Path(__file__).resolve().parents[1]
TABLE_FILE = ROOT / "spec" / "tables" / "scale_tables.txt"
ENTROPY_MD = ROOT / "spec" / "entropy.md"


def _read_table_file() -> list[list[int]]:
    data = TABLE_FILE.read_bytes()
    text = data.decode("ascii")  # plain ASCII, nothing else
    assert text.endswith("\n") and "\r" not in text
    lines = text[:-1].split("\n")
    assert len(lines) == NUM_SCALE_LEVELS
    for line in lines:  # decimal integers separated by one space, no sign, no leading zeros
        assert re.fullmatch(r"[1-9][0-9]*( [1-9][0-9]*)*", line), line[:80]
    return [[int(x) for x in line.split(" ")] for line in lines]


def _spec_lists() -> tuple[list[int], list[int]]:
    """The half widths L_0..L_63 and the escape class table C[0..62] as printed in clause 10.2.1."""
    text = ENTROPY_MD.read_text()
    clause = text[text.index("### 10.2.1"):text.index("### 10.2.2")]
    blocks = re.findall(r"\n\n((?:    [0-9, ]+\n)+)", clause)
    assert len(blocks) == 2, "clause 10.2.1 prints two indented lists: L_i, then C[k]"
    lists = [[int(x) for x in re.findall(r"[0-9]+", b)] for b in blocks]
    return lists[0], lists[1]


def test_scale_table_file_serializes_to_the_spec_digest():
    levels = _read_table_file()
    half_widths, class_freqs = _spec_lists()
    assert len(half_widths) == NUM_SCALE_LEVELS and len(class_freqs) == NUM_ESCAPE_CLASSES
    for i, f in enumerate(levels):
        assert len(f) == 2 * half_widths[i] + 2, f"level {i}: {len(f)} frequencies for L = {half_widths[i]}"
        assert sum(f) == TOTAL_FREQUENCY and min(f) >= 1
    assert sum(class_freqs) == TOTAL_FREQUENCY
    freqs = np.concatenate([np.asarray(f, dtype=np.int64) for f in levels])
    digest = hashlib.sha256(canonical_bytes(np.asarray(half_widths), freqs, np.asarray(class_freqs))).hexdigest()
    assert digest == SCALE_TABLES_SHA256
    assert SCALE_TABLES_SHA256 in ENTROPY_MD.read_text()


def test_scale_table_file_equals_the_npz_tables():
    levels = _read_table_file()
    for i, f in enumerate(levels):
        assert np.array_equal(np.asarray(f, dtype=np.int64), TABLES.level(i)), f"level {i}"
    half_widths, class_freqs = _spec_lists()
    assert np.array_equal(TABLES.half_widths, half_widths)
    assert np.array_equal(TABLES.escape_class_freqs, class_freqs)


def test_scale_table_file_digest_is_in_the_spec_and_the_tool_reproduces_it():
    file_digest = hashlib.sha256(TABLE_FILE.read_bytes()).hexdigest()
    assert file_digest in ENTROPY_MD.read_text()
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "export_scale_tables.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
