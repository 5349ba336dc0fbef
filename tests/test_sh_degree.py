"""Per-Gaussian SH degree (format 1.3, clauses 7.3.14 and 11.9): the flags' contexts against the
rule written out row by row, the flag chunks' round trip, cross-channel prediction over coded
channels, round trips through the encoder and decoder (tiles, step adjustment, chunking), the hard
cases and the errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.attributes import ChannelPrediction, GaussianLayout
from lghcc.common.container import UnitType, read_container
from lghcc.common.errors import BitstreamError
from lghcc.common.sh_degree import (coded_channels, decode_degree_chunk, encode_degree_chunk, flag_contexts,
                                    neighbour_degrees)
from lghcc.common.units import NUM_DEGREE_CONTEXTS, ShDegreeUnit
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.stream.config import GaussianEncoderConfig
from test_gaussians import assert_same, random_gaussians
from test_neighbour_prediction import _smooth_scene
from test_step_adjust import _sensitivity


def _context_by_rule(band: int, nbr_degrees: list[int]) -> int:
    """Clause 11.9's context of one row, written out: n valid neighbours, m of them with the band."""
    valid = [x for x in nbr_degrees if x >= 0]
    n, m = len(valid), sum(x >= band for x in valid)
    return 1 if m == 0 else 5 if m == n else 2 + (3 * m) // n


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3), st.integers(1, 8), st.integers(0, 2 ** 31))
def test_contexts_follow_the_rule_row_by_row(d, k, seed):
    rng = np.random.default_rng(seed)
    n_rows, n_all = 40, 60
    degrees = rng.integers(0, d + 1, n_all)
    neighbours = rng.integers(0, n_all, (n_rows, k))
    neighbours[:, 1:][rng.random((n_rows, k - 1)) < 0.3] = -1  # fewer than k found: -1 at the end
    neighbours = -np.sort(-neighbours, axis=1)
    nd = neighbour_degrees(neighbours, degrees)
    rows = np.arange(n_rows)
    for band in range(1, d + 1):
        want = [_context_by_rule(band, [degrees[j] if j >= 0 else -1 for j in neighbours[r]]) for r in rows]
        assert flag_contexts(band, nd, rows).tolist() == want
    assert flag_contexts(1, None, rows).tolist() == [0] * n_rows  # LoD 0


def _unit(d: int, rng) -> ShDegreeUnit:
    return ShDegreeUnit(sh_degree=d, degree_flag_prob=rng.integers(0, 4096, d * NUM_DEGREE_CONTEXTS).tolist())


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 3), st.integers(0, 120), st.booleans(), st.integers(0, 2 ** 31))
def test_degree_chunk_round_trip(d, n, lod0, seed):
    rng = np.random.default_rng(seed)
    degrees_all = rng.integers(0, d + 1, n + 50)
    row_degrees = degrees_all[:n]
    nd = None if lod0 else neighbour_degrees(rng.integers(-1, 50, (n, 4)) + n * 0, degrees_all[n:])
    unit = _unit(d, rng)
    data = encode_degree_chunk(row_degrees, nd, unit)
    assert decode_degree_chunk(data, n, nd, unit, "t").tolist() == row_degrees.tolist()
    if d == 0 or n == 0:
        assert data == b""  # no flag: an empty chunk


def test_an_empty_chunk_decodes_every_flag_as_zero():
    unit = ShDegreeUnit(sh_degree=3, degree_flag_prob=[4095] * 18)  # even where flag 1 is all but certain
    assert decode_degree_chunk(b"", 7, None, unit, "t").tolist() == [0] * 7


def test_words_left_over_are_rejected():
    rng = np.random.default_rng(1)
    unit = _unit(2, rng)
    data = encode_degree_chunk(np.array([0, 1, 2, 2, 1]), None, unit)
    with pytest.raises(BitstreamError, match="data left over"):
        decode_degree_chunk(data + bytes(8), 5, None, unit, "SH-degree chunk 0")


def test_coded_channels_layout():
    layout = GaussianLayout(2)  # S = 9: SH channels 0..26, then 8
    coded = coded_channels(layout.sh_channels, layout.num_channels, np.array([0, 1, 2]))
    assert coded.sum(axis=1).tolist() == [3 + 8, 12 + 8, 27 + 8]
    assert coded[0, :3].all() and not coded[0, 3:27].any() and coded[0, 27:].all()
    assert coded[1, :12].all() and not coded[1, 12:27].any()


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.integers(2, 12), st.integers(0, 2 ** 31))
def test_prediction_over_coded_channels_round_trips(rows, m, seed):
    """Any predictions, any coded channels: the residuals of the coded values decode back to q, the
    others to 0, whatever their means and the predictions that target them."""
    rng = np.random.default_rng(seed)
    coded = rng.random((rows, m)) < 0.6
    q = rng.integers(-50, 50, (rows, m)) * coded
    mean = rng.integers(-20, 20, (rows, m))
    pairs = sorted({(int(t), int(s)) for t, s in rng.integers(0, m, (8, 2)) if s < t})
    t = np.array([p[0] for p in pairs], np.int64)
    pred = ChannelPrediction(t, np.array([p[1] for p in pairs], np.int64), rng.integers(-400, 400, t.size))
    r = pred.residuals(q, mean, coded)
    r_coded_only = np.where(coded, r, rng.integers(-9, 9, r.shape))  # uncoded residuals are never read
    assert np.array_equal(pred.reconstruct(r_coded_only * coded, mean, "t", coded), q)


def _scene(n: int, degree: int, seed: int):
    return _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(np.random.default_rng(seed), n, degree)


def _decoded_degrees(scene) -> np.ndarray:
    """The highest band with a non-zero coefficient of each decoded Gaussian (a lower bound of D)."""
    d = scene.sh_degree
    out = np.zeros(scene.num_gaussians, np.int64)
    for b in range(1, d + 1):
        out[np.abs(scene.sh[:, b * b:(b + 1) ** 2]).sum(axis=(1, 2)) > 0] = b
    return out


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 250), st.integers(0, 3), st.booleans(), st.sampled_from([0, 60]), st.sampled_from([7, 65536]),
       st.booleans(), st.integers(0, 2 ** 31))
def test_round_trip_with_sh_degrees_is_bit_exact(n, degree, predict, tile_points, rows_per_chunk, adjust, seed):
    rng = np.random.default_rng(seed)
    scene = _scene(n, degree, seed)
    degrees = rng.integers(0, degree + 1, n)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", channel_prediction=predict, tile_points=tile_points,
                                rows_per_chunk=rows_per_chunk, step_adjust_max=7 if adjust else 0)
    res = encode_gaussian_scene(scene, cfg, sensitivity=_sensitivity(scene, rng) if adjust else None,
                                sh_degrees=degrees)
    dec = decode_stream(res.data, jobs=2 if tile_points and seed % 3 == 0 else 1, exact_jobs=True)
    assert dec.hash_checked
    assert_same(dec.scene, res.decoded)
    container = read_container(res.data)
    flags = any(u.unit_type == UnitType.STEP_ADJUST_FLAGS for u in container.units)
    assert container.header.version_minor == (5 if flags else 3)
    assert sum(u.unit_type == UnitType.SH_DEGREE for u in container.units) == 1
    # every coefficient of a band above a Gaussian's degree decodes to +0.0 (no -0.0): sorted by
    # degree, the decoded degrees are never above the given ones
    assert np.all(np.sort(_decoded_degrees(dec.scene)) <= np.sort(degrees))
    assert not np.signbit(dec.scene.sh[dec.scene.sh == 0]).any()
    assert res.stats.sh_degree_counts == np.bincount(degrees, minlength=degree + 1).tolist()


def test_every_degree_full_decodes_as_without_the_tool():
    """D = d everywhere codes every value as without the unit: the same decoded scene, a 1.3 stream
    a few flag bytes larger; without degrees the stream has no unit and is version 1.1."""
    scene = _smooth_scene(600, 2, seed=3)
    cfg = GaussianEncoderConfig(neighbour_prediction="always")
    off = encode_gaussian_scene(scene, cfg)
    full = encode_gaussian_scene(scene, cfg, sh_degrees=np.full(600, 2))
    assert full.scene_hash == off.scene_hash
    assert read_container(off.data).header.version_minor == 1
    assert not any(u.unit_type == UnitType.SH_DEGREE for u in read_container(off.data).units)
    assert read_container(full.data).header.version_minor == 3
    assert len(off.data) < len(full.data) < len(off.data) + 200  # 2 flags per row, all nearly certain


@pytest.mark.parametrize("case", ["every_degree_zero", "one_gaussian", "empty_lod", "degree_zero_scene"])
def test_hard_cases_round_trip(case):
    n = {"every_degree_zero": 400, "one_gaussian": 1, "empty_lod": 3, "degree_zero_scene": 300}[case]
    degree = 0 if case == "degree_zero_scene" else 3
    scene = _smooth_scene(n, degree, seed=5)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", prediction_lods=4 if case == "empty_lod" else 6)
    res = encode_gaussian_scene(scene, cfg, sh_degrees=np.zeros(n, np.int64))
    dec = decode_stream(res.data)
    assert dec.hash_checked and dec.scene.num_gaussians == n
    assert_same(dec.scene, res.decoded)
    assert not dec.scene.sh[:, 1:].any()  # every SH-rest coefficient +0.0
    if case == "every_degree_zero":  # the SH rest costs nothing: far below the stream with every band
        assert len(res.data) < 0.7 * len(encode_gaussian_scene(scene, cfg).data)
    if case == "degree_zero_scene":
        unit = [u for u in read_container(res.data).units if u.unit_type == UnitType.SH_DEGREE][0]
        assert unit.payload == b"" and not res.stats.sh_degree_coded_bits  # no flag: empty chunks


def test_bad_degrees_are_refused():
    scene = _smooth_scene(50, 1, seed=2)
    cfg = GaussianEncoderConfig(neighbour_prediction="always")
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        encode_gaussian_scene(scene, cfg, sh_degrees=np.full(50, 2))
    with pytest.raises(ValueError, match="50 Gaussians"):
        encode_gaussian_scene(scene, cfg, sh_degrees=np.zeros(49, np.int64))
    with pytest.raises(ValueError, match="integer"):
        encode_gaussian_scene(scene, cfg, sh_degrees=np.zeros(50))
    with pytest.raises(ValueError, match="need neighbour prediction"):
        encode_gaussian_scene(scene, dataclasses.replace(cfg, neighbour_prediction=False),
                              sh_degrees=np.zeros(50, np.int64))


def test_a_truncated_unit_and_a_repeated_unit_are_rejected():
    scene = _smooth_scene(80, 1, seed=7)
    res = encode_gaussian_scene(scene, GaussianEncoderConfig(neighbour_prediction="always"),
                                sh_degrees=np.arange(80) % 2)
    from lghcc.common.container import DataUnit, write_container

    units = [DataUnit(u.unit_type, u.payload) for u in read_container(res.data).units]
    k = [i for i, u in enumerate(units) if u.unit_type == UnitType.SH_DEGREE][0]
    cut = units[:k] + [DataUnit(UnitType.SH_DEGREE, units[k].payload[:-1])] + units[k + 1:]
    with pytest.raises(BitstreamError, match=r"sh_degree unit ends"):
        decode_stream(write_container(cut))
    with pytest.raises(BitstreamError, match="out of order or repeated"):
        decode_stream(write_container(units[:k + 1] + units[k:]))
