"""Rotations as a length index and x, y, z (format 1.4, clauses 7.3.15 and 11.10): the implied w
against the rule written out value by value, round trips through the encoder and decoder (neighbour
prediction, the per-channel prior, tiles, step adjustment, SH degrees, RDOQ), streams without the
tool unchanged, and the errors."""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.attributes import ROTATION_LENGTH_SQ, GaussianLayout, implied_w, reconstruct_rotations
from lghcc.common.container import DataUnit, UnitType, read_container, write_container
from lghcc.common.errors import BitstreamError
from lghcc.common.units import MAX_ROTATION_LENGTH_INDEX, RotationLengthUnit
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.stream.config import GaussianEncoderConfig
from test_gaussians import assert_same, random_gaussians
from test_neighbour_prediction import _smooth_scene
from test_step_adjust import _sensitivity


def _f32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _w_by_rule(k: int, x: float, y: float, z: float) -> float:
    """Clause 11.10 written out with Python floats (binary64): float32(sqrt(max(0, 2^-k - ((x*x + y*y) + z*z))))."""
    t = 2.0 ** -k - ((x * x + y * y) + z * z)
    return _f32(math.sqrt(max(0.0, t)))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, MAX_ROTATION_LENGTH_INDEX),
                          *[st.floats(-2, 2, width=32, allow_subnormal=True)] * 3), min_size=1, max_size=20))
def test_implied_w_follows_the_rule(rows):
    k = np.array([r[0] for r in rows], np.int64)
    xyz = np.array([r[1:] for r in rows], np.float32)
    got = implied_w(k, xyz)
    assert got.dtype == np.float32
    for i, (kk, x, y, z) in enumerate(rows):
        assert got[i].tobytes() == np.float32(_w_by_rule(kk, x, y, z)).tobytes()


def test_squared_lengths_are_exact_powers_of_two():
    assert ROTATION_LENGTH_SQ[0] == 1.0 and len(ROTATION_LENGTH_SQ) == MAX_ROTATION_LENGTH_INDEX + 1
    assert all(math.frexp(v)[0] == 0.5 for v in ROTATION_LENGTH_SQ)


def test_implied_w_is_zero_beyond_the_length_and_one_on_the_axis():
    w = implied_w(np.array([0, 2, 0]), np.array([[0, 0, 0], [0.6, 0, 0], [1, 0, 0]], np.float32))
    assert w.tolist() == [1.0, 0.0, 0.0] and not np.signbit(w).any()


def test_index_outside_the_unit_s_range_is_rejected():
    layout = GaussianLayout(0, 3)
    q = np.zeros((2, layout.num_channels), np.int64)
    values = np.zeros(q.shape, np.float32)
    q[1, layout.rotation_start] = 4
    with pytest.raises(BitstreamError, match="rotation length index"):
        reconstruct_rotations(q, values, layout, "test")
    q[1, layout.rotation_start] = -1
    with pytest.raises(BitstreamError, match="rotation length index"):
        reconstruct_rotations(q, values, layout, "test")
    q[1, layout.rotation_start] = 3
    reconstruct_rotations(q, values, layout, "test")
    assert values[:, layout.rotation_start].tolist() == [1.0, _f32(2 ** -1.5)]


def _cfg(prediction: str, tile_points: int, adjust: bool, rows_per_chunk: int = 65536, **kw) -> GaussianEncoderConfig:
    return GaussianEncoderConfig(neighbour_prediction=prediction, tile_points=tile_points, rows_per_chunk=rows_per_chunk,
                                 step_adjust_max=7 if adjust else 0, rotation_length=True, **kw)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 250), st.integers(0, 2), st.sampled_from(["always", False]), st.sampled_from([0, 60]),
       st.booleans(), st.booleans(), st.integers(0, 2 ** 31))
def test_round_trip_with_rotation_lengths_is_bit_exact(n, degree, prediction, tile_points, adjust, rdoq, seed):
    rng = np.random.default_rng(seed)
    scene = _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(rng, n, degree)
    cfg = _cfg(prediction, tile_points, adjust and prediction == "always", rows_per_chunk=7 if seed % 3 else 65536)
    res = encode_gaussian_scene(scene, cfg, sensitivity=_sensitivity(scene, rng) if rdoq or adjust else None)
    dec = decode_stream(res.data, jobs=2 if tile_points and seed % 3 == 0 else 1, exact_jobs=True)
    assert dec.hash_checked
    assert_same(dec.scene, res.decoded)
    container = read_container(res.data)
    flags = any(u.unit_type == UnitType.STEP_ADJUST_FLAGS for u in container.units)
    assert container.header.version_minor == (5 if flags else 4)
    units = [u for u in container.units if u.unit_type == UnitType.ROTATION_LENGTH]
    assert len(units) == 1
    # every decoded rotation has w >= 0 and a length of about 2^(-k/2) <= 1 (never a zero quaternion)
    rot = dec.scene.rotations.astype(np.float64)
    assert (rot[:, 0] >= 0).all()
    length = np.linalg.norm(rot, axis=1)
    assert (length > 0).all() and (length <= 1 + 1e-6 + 2 * np.abs(rot[:, 1:]).max(initial=0)).all()


def _covariances(rotations: np.ndarray, log_scales: np.ndarray) -> np.ndarray:
    from lghcc.render.rasterizer import quat_to_rotmat
    import torch

    rot = rotations.astype(np.float64) / np.linalg.norm(rotations.astype(np.float64), axis=1, keepdims=True)
    r = quat_to_rotmat(torch.from_numpy(rot)).numpy()
    return np.einsum("nij,nj,nkj->nik", r, np.exp(2 * log_scales.astype(np.float64)), r)


def test_rdoq_choices_decode_as_close_as_four_components():
    """The covariances the encoder writes with the tool are as near the source's as without it
    (the same Gaussian up to the sign and the 24 axis turns, which permute the scales)."""
    scene = _smooth_scene(300, 1, 3)
    src = _covariances(scene.rotations, scene.log_scales)
    errors = []
    for on in (False, True):  # fine scales, so that the rotations' error shows
        cfg = GaussianEncoderConfig(neighbour_prediction="always", rotation_step=0.02, scale_step=0.001,
                                    rotation_length=on)
        res = encode_gaussian_scene(scene, cfg, sensitivity=_sensitivity(scene, np.random.default_rng(3), spread=0.5))
        dec = decode_stream(res.data).scene  # in normative order: matched to the source by position
        near = np.argmin(((dec.means[:, None, :] - scene.means[None, :, :]) ** 2).sum(axis=2), axis=0)
        got = _covariances(dec.rotations[near], dec.log_scales[near])
        errors.append(np.median(np.linalg.norm(src - got, axis=(1, 2)) / np.linalg.norm(src, axis=(1, 2))))
    assert errors[0] < 0.05 and errors[1] < 1.1 * errors[0]


def test_streams_without_the_tool_are_unchanged():
    scene = _smooth_scene(120, 1, 5)
    rng = np.random.default_rng(5)
    f = _sensitivity(scene, rng)
    base = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=7, step_adjust_flags=False)
    off = encode_gaussian_scene(scene, base, sensitivity=f).data
    assert all(u.unit_type != UnitType.ROTATION_LENGTH for u in read_container(off).units)
    assert read_container(off).header.version_minor == 2
    on = encode_gaussian_scene(scene, dataclasses.replace(base, rotation_length=True), sensitivity=f).data
    assert len(on) != len(off)


def _with_units(data: bytes, edit) -> bytes:
    c = read_container(data)
    return write_container(edit(list(c.units)), c.header)


def test_unit_errors_are_rejected():
    scene = random_gaussians(np.random.default_rng(1), 40, 0)
    data = encode_gaussian_scene(scene, _cfg("always", 0, False)).data
    assert decode_stream(data).hash_checked
    k = next(i for i, u in enumerate(read_container(data).units) if u.unit_type == UnitType.ROTATION_LENGTH)

    def twice(units):
        return units[:k + 1] + [units[k]] + units[k + 1:]

    def trailing(units):
        units[k] = DataUnit(UnitType.ROTATION_LENGTH, units[k].payload + b"\0")
        return units

    def truncated(units):
        units[k] = DataUnit(UnitType.ROTATION_LENGTH, b"")
        return units

    def first(units):  # before the gaussian_parameter_set's neighbour_prediction unit
        return [units[0], units[k]] + units[1:k] + units[k + 1:]

    for edit in (twice, trailing, truncated, first):
        with pytest.raises(BitstreamError):
            decode_stream(_with_units(data, edit), verify_hash=False)


def test_index_above_the_unit_s_maximum_is_rejected(monkeypatch):
    from lghcc.encoder.gaussians import rdoq

    monkeypatch.setattr(rdoq, "LENGTH_INDICES", (0, 1, 2, 3))  # the presets give every Gaussian k = 0
    rng = np.random.default_rng(7)
    scene = random_gaussians(rng, 200, 0)  # rotations the neighbours do not predict
    f = _sensitivity(scene, rng)
    f[::2, -4:] *= 1e-6  # rotations the pictures barely see: RDOQ gives them shorter lengths
    data = encode_gaussian_scene(scene, _cfg("always", 0, False), sensitivity=f).data
    c = read_container(data)
    k = next(i for i, u in enumerate(c.units) if u.unit_type == UnitType.ROTATION_LENGTH)
    top = RotationLengthUnit.from_bytes(c.units[k].payload).max_rotation_length_index
    assert top > 0
    units = list(c.units)
    units[k] = DataUnit(UnitType.ROTATION_LENGTH, RotationLengthUnit(max_rotation_length_index=top - 1).to_bytes())
    with pytest.raises(BitstreamError, match="rotation length index"):
        decode_stream(write_container(units, c.header), verify_hash=False)
