"""Memory bounded before allocation (decoder/limits.py) and the GG-Conv extent limit (spec
clause 8): a small legal stream that needs 8 GiB is refused in well under a second with the
amount named; the plan is an upper bound of what decoding really allocates; a GG-Conv stream
beyond the extent limit is a stream error, not a ValueError."""

import os
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest

from lghcc.app.cli_common import EXIT_INVALID_STREAM, EXIT_RESOURCE_LIMIT
from lghcc.common.errors import BitstreamError, ResourceLimitError
from lghcc.conformance import runner
from lghcc.conformance.forge import dense_cube, dense_zero_stream
from lghcc.decoder import cli as dec_cli
from lghcc.decoder import limits
from lghcc.decoder.decode import decode_stream

STREAMS = runner.STREAMS_DIR


@pytest.fixture(scope="module")
def big_stream():
    """The issue's example: 2^21 anchors x 1024 channels (C 1015, K 1), all zero, about 2 kB."""
    return dense_zero_stream(128, 1015, 1, coords=dense_cube(128))


def test_the_8_gib_stream_is_legal_and_small(big_stream):
    from lghcc.common.container import read_container
    from lghcc.common.units import MAX_ATTRIBUTE_VALUES, SceneParameterSet

    sps = SceneParameterSet.from_bytes(read_container(big_stream).units[0].payload)
    m = sps.feature_dim + 6 + 3 * sps.num_offsets
    assert sps.num_points == 1 << 21 and m == 1024 and sps.num_points * m == MAX_ATTRIBUTE_VALUES
    assert len(big_stream) < 5000


def test_the_forged_stream_decodes_exactly_when_small():
    """The same construction at 8^3 anchors decodes to zeros under its exact hash."""
    res = decode_stream(dense_zero_stream(8, 10, 2, exact_hash=True))
    assert res.hash_checked and res.scene.num_anchors == 512
    assert not res.scene.features.any() and not res.scene.offsets.any()


def test_the_8_gib_stream_is_refused_fast_naming_the_amount(big_stream, tmp_path, capsys):
    t0 = time.perf_counter()
    with pytest.raises(ResourceLimitError) as e:
        decode_stream(big_stream)
    assert time.perf_counter() - t0 < 0.5
    msg = str(e.value)
    assert "needs about 8.7 GiB" in msg and "more than the allowed 4.0 GiB" in msg
    assert "2,097,152 anchors x 1,024 channels" in msg and "= 8.0 GiB" in msg
    path = tmp_path / "big.lghcc"
    path.write_bytes(big_stream)
    t0 = time.perf_counter()
    assert dec_cli.main([str(path), "-o", str(tmp_path / "out")]) == EXIT_RESOURCE_LIMIT
    assert time.perf_counter() - t0 < 1.0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "8.7 GiB" in err and not (tmp_path / "out").exists()
    with pytest.raises(ResourceLimitError, match="more than the allowed 8.0 GiB"):
        decode_stream(big_stream, max_memory=8 << 30)


def test_the_bound_is_a_keyword_of_decode_stream():
    data = (STREAMS / "c002_procedural_medium" / "stream.lghcc").read_bytes()
    need = limits.MemoryPlan  # the plan's own total, computed by a decode without a bound
    seen = []
    orig = need.check

    def record(self, p, s):
        seen.append(orig(self, p, s))
        return seen[-1]
    need.check = record
    try:
        decode_stream(data, max_memory=None)
    finally:
        need.check = orig
    worst = max(seen)
    decode_stream(data, max_memory=worst)  # exactly enough
    with pytest.raises(ResourceLimitError):
        decode_stream(data, max_memory=worst - 1)


def test_context_model_working_set_is_checked_before_level_2():
    """A bound between the first check (headers) and GG-Conv's working set: refused at the level-2
    unit, naming the context model's part, after level 1 and before the Ball k-NN runs."""
    data = (STREAMS / "c013_ggconv_context" / "stream.lghcc").read_bytes()
    seen = []
    orig = limits.MemoryPlan.check

    def record(self, p, s):
        seen.append((orig(self, p, s), [x.what for x in p]))
        return seen[-1][0]
    limits.MemoryPlan.check = record
    try:
        decode_stream(data, max_memory=None)
    finally:
        limits.MemoryPlan.check = orig
    first, last = seen[0][0], seen[-1][0]
    assert any("Ball k-NN" in w or "GG-Conv" in w for w in seen[-1][1]) and last > first
    with pytest.raises(ResourceLimitError, match=r"needs about \d"):
        decode_stream(data, max_memory=(first + last) // 2)


def _decode_peak(data: bytes) -> tuple[int, int]:
    """(the plan's largest total, tracemalloc's peak of the decode) in bytes."""
    seen = []
    orig = limits.MemoryPlan.check

    def record(self, p, s):
        seen.append(orig(self, p, s))
        return seen[-1]
    limits.MemoryPlan.check = record
    try:
        decode_stream(data, max_memory=None)  # imports, tables, models loaded before measuring
        seen.clear()
        tracemalloc.start()
        decode_stream(data, max_memory=None)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
        limits.MemoryPlan.check = orig
    return max(seen), peak


@pytest.mark.integration
def test_the_plan_bounds_what_numpy_allocates_for_every_suite_stream():
    for case in runner.load_cases():
        if case.expect != "decode":
            continue
        plan, peak = _decode_peak(case.stream.read_bytes())
        assert peak <= plan, (case.id, peak, plan)


@pytest.mark.integration
def test_the_plan_bounds_a_larger_scene_within_a_factor():
    """A 30,000-anchor scene with offset masks in chunks of 4096 rows: above the measured peak,
    and not absurdly so (the constants are measured, module docstring)."""
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.encoder.stream.encode import EncoderConfig, encode_scene

    data = encode_scene(make_procedural_scene(30000, seed=3, with_mask=True), EncoderConfig(rows_per_chunk=4096)).data
    plan, peak = _decode_peak(data)
    assert peak <= plan <= 3 * peak, (peak, plan)


MEASURE_RSS = """
import os, sys
os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
import torch
torch.set_num_threads(1)
from lghcc.conformance.fuzz import _reset_peak_rss, _status_kib
from lghcc.decoder import limits
from lghcc.decoder.decode import decode_stream
warm, target = (open(p, "rb").read() for p in sys.argv[1:3])
decode_stream(warm)  # torch, the tables and the model code loaded
seen = []
orig = limits.MemoryPlan.check
limits.MemoryPlan.check = lambda self, p, s: seen.append(orig(self, p, s)) or seen[-1]
base = _reset_peak_rss()
decode_stream(target, max_memory=None)
print((_status_kib("VmHWM") - base) * 1024, max(seen))
"""


@pytest.mark.integration
@pytest.mark.parametrize("sid", ["c013_ggconv_context", "c012_parent_mlp_context", "c003_offset_masks"])
def test_the_plan_bounds_the_resident_memory_of_a_fresh_decoder(sid):
    """Peak RSS growth of a fresh process (torch's allocations included), after a warm-up decode of
    another stream: below the plan."""
    warm = STREAMS / "c019_ggconv_minimal" / "stream.lghcc"
    out = subprocess.run([sys.executable, "-c", MEASURE_RSS, str(warm), str(STREAMS / sid / "stream.lghcc")],
                         capture_output=True, text=True, check=True, env=dict(os.environ, OMP_WAIT_POLICY="PASSIVE"))
    growth, plan = (int(x) for x in out.stdout.split())
    assert growth <= plan, (sid, growth, plan)


# --- the GG-Conv extent limit -------------------------------------------------------------------------

def test_ggconv_beyond_the_extent_limit_is_a_stream_error(capsys):
    """Issue 14's crash: a bare ValueError from common/knn.py; now the level limit of clause 8."""
    stream = STREAMS / "e018_ggconv_extent_limit" / "stream.lghcc"
    with pytest.raises(BitstreamError, match=r"extent 4294967295\b.*limit\b.*1753413056"):
        decode_stream(stream.read_bytes())
    assert dec_cli.main([str(stream)]) == EXIT_INVALID_STREAM
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_the_extent_check_is_exact_at_the_limit():
    from lghcc.common.context.models import check_ggconv_extent
    from lghcc.common.knn import MAX_EXTENT

    a = np.array([[0, 0, 0]], np.int64)
    check_ggconv_extent(a, np.array([[MAX_EXTENT, -5, 7]], np.int64))  # at the limit: allowed
    with pytest.raises(BitstreamError, match="extent 1753413057 exceeds"):
        check_ggconv_extent(a, np.array([[0, MAX_EXTENT + 1, 0]], np.int64))
    check_ggconv_extent(np.zeros((0, 3), np.int64))  # nothing to check


def test_the_encoder_keeps_the_prior_for_a_scene_beyond_the_extent():
    """The encoder never writes such a stream: GG-Conv is not fitted, level 2 keeps the prior."""
    from lghcc.encoder.stream.encode import EncoderConfig, encode_scene

    from scenes import random_scene

    scene = random_scene(np.random.default_rng(4), 80, c=2, k=1)
    scene.coords = np.unique(np.random.default_rng(4).integers(0, 6, (200, 3)), axis=0)[:80]
    scene.coords[0] = [-(1 << 31), 0, 0]
    scene.coords[1] = [(1 << 31) - 1, 0, 0]
    cfg = EncoderConfig(hierarchy=True, coarse_voxel_scale=2, context_model="ggconv", context_fallback=False,
                        context_float_steps=2, context_qat_steps=0)
    res = encode_scene(scene, cfg)
    assert "extent" in res.stats.context_fit.error
    assert res.stats.levels[2].context_model == "per-channel prior"
    assert decode_stream(res.data).hash_checked
