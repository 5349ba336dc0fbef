"""tools/stream_bits.py: every byte of a stream charged to one part, each side chunk to its own."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from stream_bits import CHANNEL_PARTS, stream_parts, table  # noqa: E402

STREAMS = ROOT / "conformance" / "streams"


@pytest.mark.parametrize("name", ["c093_sh_degree_step_adjust", "c100_rotation_length"])
def test_parts_add_up_to_the_file(name):
    data = (STREAMS / name / "stream.lghcc").read_bytes()
    r = stream_parts(data)
    assert sum(r["parts"].values()) == pytest.approx(len(data))
    assert all(r["parts"][p] > 0 for p in ("geometry", *CHANNEL_PARTS, "headers", "model"))
    # the symbol chunks cost at least their ideal code lengths, and little more
    assert r["ideal_bytes"] <= r["symbol_bytes"] <= 1.01 * r["ideal_bytes"] + 16
    # the detail splits the SH rest and the rotation, no more
    bands = sum(v for k, v in r["detail"].items() if k.startswith("SH band"))
    rotation = sum(v for k, v in r["detail"].items() if k.startswith("rotation"))
    assert bands == pytest.approx(r["parts"]["SH rest"])
    assert rotation == pytest.approx(r["parts"]["rotation"])
    if name == "c093_sh_degree_step_adjust":  # step adjustment and SH degrees, w coded
        assert r["parts"]["step indices"] > 0 and r["parts"]["SH-degree flags"] > 0
        assert "rotation w" in r["detail"]
    else:  # a rotation_length unit, no sh_degree unit
        assert r["parts"]["SH-degree flags"] == 0
        assert "rotation length index" in r["detail"]
    lines = table([(name, r)], [None])
    assert lines[2].startswith(f"| {name} | {r['gaussians']:,} | {len(data):,} |")
