"""tools/bench_step_flags.py (the indices of a 1.2-1.4 stream as 1.5's flags),
tools/position_precision_bound.py (the octree levels a point is alone in) and tools/bench_sh_coding.py
(candidate codings of the SH rest, on a tiny synthetic scene)."""

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from bench_step_flags import as_flags  # noqa: E402
from position_precision_bound import levels_alone  # noqa: E402

STREAMS = ROOT / "conformance" / "streams"


@pytest.mark.parametrize("name", ["c085_step_adjust", "c086_step_adjust_tiles"])
def test_step_flags_of_a_symbol_stream_are_exact_and_smaller(name):
    """c085/c086 hold the indices as symbols; as flags the stream's bytes follow from the chunks
    exactly (each decoded back inside as_flags) and the indices cost less."""
    data = (STREAMS / name / "stream.lghcc").read_bytes()
    r = as_flags(data)
    assert r["bytes"] == len(data)
    assert r["after"] == r["bytes"] - r["symbols"] + r["flags"]
    assert 0 < r["flags"] < r["symbols"]


def test_a_flag_stream_is_refused():
    with pytest.raises(SystemExit, match="flags already"):
        as_flags((STREAMS / "c107_step_adjust_flags" / "stream.lghcc").read_bytes())


def test_levels_alone_in_a_small_octree():
    """Depth 3 (coordinates < 8): (0,0,0) and (1,0,0) share their nodes down to the last level, so
    each is alone only below it (0 levels); (7,7,7) parts from them at the root, alone for 2 levels."""
    coords = np.array([[0, 0, 0], [1, 0, 0], [7, 7, 7]])
    alone, depth = levels_alone(coords)
    assert depth == 3
    assert alone.tolist() == [0, 0, 2]
    one, _ = levels_alone(np.array([[0, 0, 0], [4, 4, 4]]))
    assert one.tolist() == [2, 2]


def test_sh_coding_bench_on_a_tiny_scene():
    """tools/bench_sh_coding.py on 400 synthetic Gaussians of SH degree 1: RAHT keeps the values'
    energy (orthonormal, so its rounding errors are the values'), every row has bits, and the
    transforms are coded at today's distortion."""
    from bench_sh_coding import measure_level, raht, sh_scene_on_grid, table_lines

    rng = np.random.default_rng(0)
    coords = np.unique(rng.integers(0, 64, size=(500, 3)), axis=0)[:400]
    dc = rng.normal(0, 0.5, size=(400, 1, 3))
    rest = 0.3 * dc * rng.normal(1, 0.2, size=(400, 3, 3)) + rng.normal(0, 0.05, size=(400, 3, 3))
    sc = sh_scene_on_grid("tiny", coords, np.concatenate([dc, rest], axis=1))
    h, _, root = raht(sc.rest, sc.coords)
    assert h.shape[0] == sc.n - 1
    assert np.isclose((h ** 2).sum() + (root ** 2).sum(), (sc.rest ** 2).sum())
    r = measure_level(sc, "test", 0.05, [0.1], [0.8, 1.0, 1.25, 1.6], hidden=4, train_rows=400, train_steps=5)
    assert all(np.isfinite(v) and v > 0 for v in r.bits.values())
    assert all(abs(e / r.error - 1) < 0.05 for e in r.errors.values())
    assert "| tiny | test" in table_lines([r])[2]
