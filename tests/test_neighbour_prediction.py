"""Neighbour prediction (format 1.1, clause 11.7): the LoD rule, the neighbour graph against brute
force, the integer mean and activity buckets, bit-exact round trips (with tiles, worker
processes, cross-channel prediction, every parameter range), hard cases, and the encoder's
choice (the tool costs a scene it does not help nothing)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.container import UnitType, read_container
from lghcc.common.neighbour_prediction import (lod_coding_params, lod_of_rows, lod_rows,
                                               neighbour_graph)
from lghcc.common.units import lod_sizes_of
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.stream.config import GaussianEncoderConfig
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.formats.procedural import smooth_gaussian_scene as _smooth_scene
from reference_impl import squared_distances
from test_gaussians import assert_same, random_gaussians


@given(st.integers(0, 5000), st.integers(1, 16))
def test_lod_rule_and_sizes(n, lods):
    lod = lod_of_rows(n, lods)
    for i in range(min(n, 300)):
        tz = (i & -i).bit_length() - 1 if i else 10 ** 9
        assert lod[i] == max(0, lods - 1 - tz)
    assert lod_sizes_of(n, lods) == [int(r.size) for r in lod_rows(n, lods)]
    assert sum(lod_sizes_of(n, lods)) == n


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 120), st.integers(1, 6), st.integers(1, 9), st.integers(0, 2 ** 31), st.sampled_from([2, 4, 1000]))
def test_neighbour_graph_is_the_k_nearest_coarser_rows_with_ties_to_the_lower_row(n, lods, k, seed, span):
    rng = np.random.default_rng(seed)
    coords = np.unique(rng.integers(0, span, size=(n, 3)), axis=0)  # small spans: many equal distances
    rng.shuffle(coords)
    g = neighbour_graph(coords, lods, k)
    lod = lod_of_rows(coords.shape[0], lods)
    for level in range(1, lods):
        coarser = np.nonzero(lod < level)[0]
        for row, nb in zip(g.rows[level], g.neighbours[level]):
            d2 = squared_distances(coords[coarser], coords[row])
            expect = coarser[np.lexsort((coarser, d2))][:k]
            got = nb[nb >= 0]
            assert got.tolist() == expect.tolist()
            assert (nb[len(got):] == -1).all()


@given(st.lists(st.lists(st.integers(-2 ** 40, 2 ** 40), min_size=3, max_size=3), min_size=1, max_size=8),
       st.integers(1, 16))
def test_mean_and_activity_bucket_are_exact_integers(values, buckets):
    nb = np.asarray(values, dtype=np.int64)  # the neighbours' q, 3 channels
    q = np.vstack([nb, np.zeros((1, 3), np.int64)])
    neighbours = np.arange(nb.shape[0])[None, :]
    table = np.arange(3 * buckets, dtype=np.int64).reshape(3, buckets) % 64
    flags = np.array([True, False, True])
    prior = np.array([5, -7, 9], dtype=np.int64)
    p = lod_coding_params(q, neighbours, table, buckets, flags, prior)
    n = len(values)
    for c in range(3):
        col = [v[c] for v in values]
        mean = (sum(col) + n // 2) // n if flags[c] else int(prior[c])  # Python ints: floor division
        assert p.mean[0, c] == mean
        bucket = min((max(col) - min(col)).bit_length(), buckets - 1)
        assert p.level[0, c] == table[c, bucket]


def _uses_tool(data: bytes) -> bool:
    return any(u.unit_type == UnitType.NEIGHBOUR_PREDICTION for u in read_container(data).units)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 400), st.integers(0, 3), st.integers(1, 16), st.integers(1, 32), st.integers(1, 16),
       st.booleans(), st.sampled_from([1, 7, 65536]), st.integers(0, 2 ** 31))
def test_round_trip_with_neighbour_prediction_is_bit_exact(n, degree, lods, k, buckets, predict, rows_per_chunk, seed):
    rng = np.random.default_rng(seed)
    scene = _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(rng, n, degree)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", prediction_lods=lods, prediction_neighbours=k,
                                prediction_buckets=buckets, channel_prediction=predict, rows_per_chunk=rows_per_chunk)
    res = encode_gaussian_scene(scene, cfg)
    assert _uses_tool(res.data) and res.stats.neighbour_prediction
    dec = decode_stream(res.data)
    assert dec.hash_checked
    assert_same(dec.scene, res.decoded)
    assert dec.scene.num_gaussians == n


def test_smooth_scene_codes_smaller_and_a_noise_scene_pays_nothing():
    smooth = _smooth_scene(3000, 1)
    on = encode_gaussian_scene(smooth, GaussianEncoderConfig())
    off = encode_gaussian_scene(smooth, GaussianEncoderConfig(neighbour_prediction=False))
    assert on.stats.neighbour_prediction and _uses_tool(on.data)
    assert len(on.data) < 0.9 * len(off.data)
    assert_same(decode_stream(on.data).scene, decode_stream(off.data).scene)  # lossless: same values
    # attributes without spatial structure: the encoder keeps the per-channel prior, at no cost
    noise = random_gaussians(np.random.default_rng(3), 3000, 0)
    auto = encode_gaussian_scene(noise, GaussianEncoderConfig())
    never = encode_gaussian_scene(noise, GaussianEncoderConfig(neighbour_prediction=False))
    if not auto.stats.neighbour_prediction:
        assert auto.data == never.data and not _uses_tool(auto.data)
    else:
        assert len(auto.data) < len(never.data)


def test_tiles_share_the_unit_and_workers_give_the_same_output():
    scene = _smooth_scene(6000, 0, seed=5)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", tile_points=1000)
    res = encode_gaussian_scene(scene, cfg)
    assert res.stats.num_tiles > 1 and _uses_tool(res.data)
    assert sum(u.unit_type == UnitType.NEIGHBOUR_PREDICTION for u in read_container(res.data).units) == 1
    one = decode_stream(res.data)
    two = decode_stream(res.data, jobs=2, exact_jobs=True)
    assert one.hash_checked and two.hash_checked
    assert_same(one.scene, two.scene)
    assert_same(one.scene, res.decoded)


@pytest.mark.parametrize("case", ["one", "two", "collinear", "constant", "extreme", "far_apart"])
def test_hard_cases_round_trip(case):
    rng = np.random.default_rng(7)
    n = {"one": 1, "two": 2}.get(case, 200)
    scene = random_gaussians(rng, n, 2)
    if case == "collinear":
        scene.means[:, 1:] = 0
    if case == "constant":  # every neighbour agrees: activity 0, bucket 0 everywhere
        scene.sh[:] = 0.25
        scene.opacity[:] = 1.0
        scene.log_scales[:] = -3
        scene.rotations[:] = (1, 0, 0, 0)
    if case == "extreme":  # values many steps from zero
        scene.sh[:, 0] *= 1e6
        scene.opacity[:] = rng.choice([-8.0, 8.0], n)
    if case == "far_apart":  # a few clusters far apart: neighbours across the empty space
        scene.means[:] += rng.choice([-1e4, 0, 1e4], size=(n, 1)).astype(np.float32)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", prediction_buckets=16, prediction_neighbours=32)
    res = encode_gaussian_scene(scene, cfg)
    dec = decode_stream(res.data)
    assert dec.hash_checked and _uses_tool(res.data)
    assert_same(dec.scene, res.decoded)
    assert np.isfinite(dec.scene.sh).all()


def test_hierarchy_scenes_do_not_use_it_and_bad_options_are_named():
    scene = _smooth_scene(500, 0)
    res = encode_gaussian_scene(scene, GaussianEncoderConfig(hierarchy=True, neighbour_prediction="always"))
    assert not _uses_tool(res.data)
    for bad in ({"prediction_lods": 0}, {"prediction_neighbours": 33}, {"prediction_buckets": 17},
                {"neighbour_prediction": "sometimes"}):
        with pytest.raises(Exception, match=next(iter(bad))):
            dataclasses.replace(GaussianEncoderConfig(), **bad).validate()


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 60), st.integers(1, 6), st.integers(1, 9), st.integers(0, 2 ** 31), st.booleans(),
       st.integers(1, 7))
def test_lod_coding_params_in_blocks_are_those_of_the_whole_lod(rows, k, m, seed, with_adjust, block):
    import lghcc.common.neighbour_prediction as npd
    rng = np.random.default_rng(seed)
    q = rng.integers(-(1 << 20), 1 << 20, size=(rows + 5, m))
    neighbours = rng.integers(-1, rows + 5, size=(rows, k))
    neighbours[:, 0] = rng.integers(0, rows + 5, size=rows)  # at least one neighbour per row
    table = rng.integers(0, 64, size=(m, 5))
    flags = rng.random(m) < 0.7
    prior = rng.integers(-50, 50, size=m)
    adjust = rng.integers(0, 8, size=rows + 5) if with_adjust else None
    row_adjust = rng.integers(0, 8, size=rows) if with_adjust else None
    whole = lod_coding_params(q, neighbours, table, 5, flags, prior, adjust, row_adjust)
    saved = npd.LOD_BLOCK_ROWS
    try:
        npd.LOD_BLOCK_ROWS = block
        blocks = lod_coding_params(q, neighbours, table, 5, flags, prior, adjust, row_adjust)
    finally:
        npd.LOD_BLOCK_ROWS = saved
    assert np.array_equal(blocks.mean, whole.mean) and np.array_equal(blocks.level, whole.level)
