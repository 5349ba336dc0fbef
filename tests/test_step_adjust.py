"""Step adjustment (format 1.2, clauses 7.3.13 and 11.8): the fixed-point means and buckets against
exact integer arithmetic (and against version 1.1's with every index 0), bit-exact round trips
with tiles and cross-channel prediction, the version a stream declares, the encoder's choice of
indices, and the hard cases."""

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.attributes import STEP_ADJUST_FACTORS, CodingParams, GaussianLayout
from lghcc.common.geometry import normative_order
from lghcc.common.container import UnitType, read_container
from lghcc.common.neighbour_prediction import (ADJUST_FIXED_POINT, ADJUST_LEVEL_SHIFT, adjusted_prior,
                                               lod_coding_params, neighbour_graph, prior_level_in_steps)
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.cli import step_adjust_summary
from lghcc.encoder.stream.config import GaussianEncoderConfig
from lghcc.encoder.gaussians.gaussian_grid import coded_values
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.gaussians.rdoq import channel_groups, channel_steps, group_slopes, step_adjust_choice
from test_gaussians import assert_same, random_gaussians
from test_neighbour_prediction import _smooth_scene


def test_fixed_point_factors_and_level_shifts_are_the_rounded_rules():
    a = np.arange(8)
    assert ADJUST_FIXED_POINT.tolist() == [round(4096 * 2 ** (i / 4)) for i in a]
    assert ADJUST_LEVEL_SHIFT.tolist() == [round(i / 4 * 63 / np.log2(512 / 0.11)) for i in a]
    assert np.allclose(STEP_ADJUST_FACTORS, 2.0 ** (a / 4), rtol=1e-7)


@given(st.lists(st.tuples(st.lists(st.integers(-2 ** 40, 2 ** 40), min_size=3, max_size=3), st.integers(0, 7)),
                min_size=1, max_size=32),
       st.integers(0, 7), st.integers(1, 16))
def test_adjusted_mean_and_bucket_are_exact_integers(neighbours, own, buckets):
    """Clause 11.8 with Python's unbounded integers as the reference: 32 neighbours at +-2^40 with
    the largest factor stay within int64."""
    q = np.array([v for v, _ in neighbours] + [[0, 0, 0]], dtype=np.int64)
    adjust = np.array([a for _, a in neighbours] + [own], dtype=np.int64)
    nb = np.arange(len(neighbours))[None, :]
    table = np.arange(3 * buckets, dtype=np.int64).reshape(3, buckets) % 64
    flags = np.array([True, False, True])
    prior = np.array([5, -7, 2 ** 31 - 1], dtype=np.int64)
    p = lod_coding_params(q, nb, table, buckets, flags, prior, adjust, adjust[-1:])
    fp = [round(4096 * 2 ** (i / 4)) for i in range(8)]
    f, n = fp[own], len(neighbours)
    for c in range(3):
        v = [x[c] * fp[a] for x, a in neighbours]
        mean = (sum(v) + (n * f) // 2) // (n * f) if flags[c] else (int(prior[c]) * 4096 + f // 2) // f
        assert p.mean[0, c] == mean
        bucket = min(((max(v) - min(v)) // f).bit_length(), buckets - 1)
        assert p.level[0, c] == table[c, bucket]


@given(st.lists(st.lists(st.integers(-2 ** 40, 2 ** 40), min_size=2, max_size=2), min_size=1, max_size=12),
       st.integers(1, 16))
def test_index_zero_everywhere_is_version_1_1(values, buckets):
    q = np.vstack([np.asarray(values, np.int64), np.zeros((1, 2), np.int64)])
    nb = np.arange(len(values))[None, :]
    table = np.arange(2 * buckets, dtype=np.int64).reshape(2, buckets) % 64
    flags, prior = np.array([True, False]), np.array([3, -4], np.int64)
    plain = lod_coding_params(q, nb, table, buckets, flags, prior)
    zero = lod_coding_params(q, nb, table, buckets, flags, prior, np.zeros(len(q), np.int64), np.zeros(1, np.int64))
    assert np.array_equal(plain.mean, zero.mean) and np.array_equal(plain.level, zero.level)


def test_adjusted_prior_rounds_the_mean_and_lowers_the_level():
    prior = CodingParams(np.array([[100, -101, 0, 7]]), np.array([[20, 5, 0, 63]]))
    p = adjusted_prior(prior, np.arange(8))
    for a in range(8):
        f = round(4096 * 2 ** (a / 4))
        assert p.mean[a].tolist() == [(m * 4096 + f // 2) // f for m in (100, -101, 0, 7)]
        assert p.level[a].tolist() == [max(0, lv - int(ADJUST_LEVEL_SHIFT[a])) for lv in (20, 5, 0, 63)]


def _sensitivity(scene, rng, spread: float = 4.0) -> np.ndarray:
    """Per Gaussian a visibility over ``spread`` decades, times a level per channel."""
    m = GaussianLayout(scene.sh_degree).num_channels
    return (10.0 ** (-spread * rng.random(scene.num_gaussians)))[:, None] * 10.0 ** rng.uniform(2, 4, m)[None, :]


def _tool(data: bytes) -> bool:
    return any(u.unit_type == UnitType.STEP_ADJUST for u in read_container(data).units)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(2, 300), st.integers(0, 3), st.integers(1, 7), st.booleans(), st.sampled_from([0, 60]),
       st.sampled_from([5, 65536]), st.integers(0, 2 ** 31))
def test_round_trip_with_step_adjustment_is_bit_exact(n, degree, top, predict, tile_points, rows_per_chunk, seed):
    rng = np.random.default_rng(seed)
    scene = _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(rng, n, degree)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=top, channel_prediction=predict,
                                tile_points=tile_points, rows_per_chunk=rows_per_chunk)
    res = encode_gaussian_scene(scene, cfg, sensitivity=_sensitivity(scene, rng))
    dec = decode_stream(res.data, jobs=2 if tile_points and seed % 3 == 0 else 1, exact_jobs=True)
    assert dec.hash_checked
    assert_same(dec.scene, res.decoded)
    header = read_container(res.data).header
    flags = any(u.unit_type == UnitType.STEP_ADJUST_FLAGS for u in read_container(res.data).units)
    assert header.version_minor == (5 if flags else 2 if _tool(res.data) else 1)
    # what lghcc-enc reports of the tool: every Gaussian counted once, the index chunks' bytes
    counts, bits = res.stats.step_adjust_counts, res.stats.step_adjust_coded_bits
    if _tool(res.data):
        assert sum(counts) == res.decoded.num_gaussians and len(counts) <= top + 1 and counts[-1] > 0
        assert bits % 8 == 0 and 0 < bits < 8 * len(res.data)
    else:
        assert counts is None and bits is None


def test_invisible_gaussians_take_the_coarsest_steps_and_visible_ones_keep_theirs():
    scene = _smooth_scene(3000, 1, seed=4)
    rng = np.random.default_rng(4)
    f = _sensitivity(scene, rng)
    f[:1000] = 0.0  # the pictures do not show these at all
    f[1000:1100] = 100 * f.max(axis=0)  # and these very well
    cfg = GaussianEncoderConfig(neighbour_prediction="always", channel_prediction=False)
    on = encode_gaussian_scene(scene, dataclasses.replace(cfg, step_adjust_max=7), sensitivity=f)
    off = encode_gaussian_scene(scene, cfg, sensitivity=f)
    assert _tool(on.data) and not _tool(off.data)
    assert len(on.data) < 0.9 * len(off.data)
    assert decode_stream(on.data).hash_checked
    line = step_adjust_summary(on.stats, on.decoded.num_gaussians)  # lghcc-enc's report of the tool
    assert f"indices {on.stats.step_adjust_coded_bits // 8:,} bytes" in line
    assert f"7: {on.stats.step_adjust_counts[7]:,}" in line and on.stats.step_adjust_counts[7] > 0
    # the choice itself, on the values in steps as the coding sees them
    x = coded_values(scene) / channel_steps(cfg, 1)
    coords = np.rint(scene.means / 0.01).astype(np.int64)
    order = normative_order(coords)
    graph = neighbour_graph(coords[order], cfg.prediction_lods, cfg.prediction_neighbours)
    mu = group_slopes(f, channel_groups(1), 1.0)
    a = np.empty(3000, np.int64)
    a[order] = step_adjust_choice(x[order], f[order], mu, coords[order], graph, cfg.prediction_buckets, 7)
    # the visible ones mostly keep their steps (a coarser one wins where its rounding happens to land
    # near the values)
    assert (a[1000:1100] == 0).mean() > 0.5 and a[1000:1100].mean() < 1
    assert (a[:1000] > 0).mean() > 0.95  # the fewest bits, wherever they are (ties go to the finer step)
    assert a[:1000].mean() > a[1100:].mean() > a[1000:1100].mean()


def test_every_index_zero_costs_nothing_and_writes_a_version_1_1_stream(monkeypatch):
    """Where the choice gives every Gaussian index 0, no unit is written: the same bytes as without
    the tool, a version 1.1 stream."""
    import lghcc.encoder.gaussians.rdoq as rdoq

    scene = _smooth_scene(1500, 0, seed=6)
    f = _sensitivity(scene, np.random.default_rng(6))
    cfg = GaussianEncoderConfig(neighbour_prediction="always")
    monkeypatch.setattr(rdoq, "step_adjust_choice", lambda x, *a: np.zeros(x.shape[0], np.int64))
    on = encode_gaussian_scene(scene, dataclasses.replace(cfg, step_adjust_max=7), sensitivity=f)
    off = encode_gaussian_scene(scene, cfg, sensitivity=f)
    assert on.data == off.data and not _tool(on.data)
    assert read_container(on.data).header.version_minor == 1


@pytest.mark.parametrize("flags", [True, False])  # the indices as flags (format 1.5) where they pay, or as symbols
@pytest.mark.parametrize("case", ["one_gaussian", "all_invisible", "two_far_apart", "all_at_the_coarsest"])
def test_hard_cases_round_trip(case, flags):
    rng = np.random.default_rng(9)
    n = {"one_gaussian": 1, "all_invisible": 200, "two_far_apart": 2, "all_at_the_coarsest": 300}[case]
    scene = random_gaussians(rng, n, 1)
    if case == "two_far_apart":
        scene.means[1] = scene.means[0] + np.float32(1e4)
    f = np.zeros((n, 20)) if case == "all_invisible" else _sensitivity(scene, rng)
    if case == "all_at_the_coarsest":
        f *= 1e-12  # barely seen: every Gaussian takes the coarsest step
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=7, step_adjust_flags=flags)
    res = encode_gaussian_scene(scene, cfg, sensitivity=f)
    dec = decode_stream(res.data)
    assert dec.hash_checked and dec.scene.num_gaussians == n
    assert_same(dec.scene, res.decoded)
    assert np.isfinite(dec.scene.sh).all() and np.isfinite(dec.scene.rotations).all()
    if case == "all_invisible":  # no sensitivity anywhere gives no slope to weigh bits by: plain rounding
        assert not _tool(res.data)


def test_a_value_beyond_2_40_steps_is_refused_before_rdoq():
    """Found by the scene fuzzer (issue 35): with a sensitivity and step adjustment, a value 1e20 steps
    from zero reached RDOQ's cast to int64 (ValueError: residual -2^63 ...); it is the InputError of
    any Gaussian value beyond 2^40 steps."""
    from lghcc.common.errors import InputError
    from lghcc.common.scene import GaussianScene
    from lghcc.encoder.stream.config import load_config

    g = np.random.default_rng(1)
    c = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    sh = g.normal(size=(64, 16, 3)).astype(np.float32)
    sh[7, 0, 0] = 5e18
    scene = GaussianScene.on_grid(c, 0.01, [0, 0, 0], sh, g.normal(size=64).astype(np.float32),
                                  g.uniform(-5, 0, (64, 3)).astype(np.float32), g.normal(size=(64, 4)).astype(np.float32))
    cfg = load_config("medium", overrides={"neighbour_prediction": True, "step_adjust_max": 3}, kind="gaussians")
    with pytest.raises(InputError, match=r"2\^40 steps"):
        encode_gaussian_scene(scene, cfg, sensitivity=np.ones((64, 56)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.sampled_from([1, 2, 7, 129, 3000, 20000]), scale=st.sampled_from([0.0, 0.4, 3.0, 200.0, 1e7]),
       share=st.floats(0.0, 1.0), seed=st.integers(0, 2 ** 16))
def test_best_prior_level_is_the_least_of_every_levels_bits(n, scale, share, seed):
    """The prior level of LoD 0's residuals with step adjustment: the least of the 64 levels' summed code
    lengths, each row's level lowered by its index's shift; made several levels per call (the blocks cut
    small here too), the same sums to the last bit as one level at a time, ties to the lower level."""
    from lghcc.common.entropy.scale_levels import NUM_SCALE_LEVELS
    from lghcc.common.entropy.symbol_coder import code_lengths_bits
    from lghcc.encoder.stream import neighbour_coding
    rng = np.random.default_rng(seed)
    r = np.rint(rng.standard_normal(n) * scale * np.where(rng.random(n) < 0.05, 50.0, 1.0)).astype(np.int64)
    adjust = rng.integers(0, 8, n) * (rng.random(n) < share)
    costs = [float(code_lengths_bits(r, prior_level_in_steps(lv, adjust)).sum()) for lv in range(NUM_SCALE_LEVELS)]
    expected = int(np.argmin(costs)) if adjust.any() else neighbour_coding.best_level(r)
    assert neighbour_coding.best_prior_level(r, adjust) == expected
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(neighbour_coding, "PRIOR_LEVEL_VALUES", 5 * n)  # 5 levels a call, the last 4
        assert neighbour_coding.best_prior_level(r, adjust) == expected
