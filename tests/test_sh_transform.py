"""The SH rest as transform coefficients (format 1.6, clauses 7.3.17 and 11.11): the integer inverse
against the rule written out with Python integers, the unit's syntax, the encoder's KLT and its
coefficient sensitivities, round trips through the encoder and decoder (neighbour prediction, the
per-channel prior, tiles, step adjustment, SH degrees), streams without the tool unchanged, and the
errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.attributes import GaussianLayout, ShTransform, inverse_sh_transform
from lghcc.common.container import DataUnit, UnitType, read_container, write_container
from lghcc.common.errors import BitstreamError, HashMismatchError
from lghcc.common.units import MAX_PREDICTED_MAGNITUDE, ShTransformUnit
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians import sh_transform as sht
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.stream.config import GaussianEncoderConfig
from test_gaussians import assert_same, random_gaussians
from test_step_adjust import _sensitivity


def _by_rule(t: list[int], matrix: list[int], n: int, shift: int) -> list[int]:
    """Clause 11.11 with Python integers: (sum_k T[j][k] t_k + floor(2^R / 2)) >> R."""
    return [(sum(matrix[j * n + k] * t[k] for k in range(n)) + ((1 << shift) >> 1)) >> shift for j in range(n)]


@st.composite
def transforms(draw):
    d = draw(st.integers(1, 3))
    n = 3 * (d + 1) ** 2 - 3
    # up to 45 x 45 entries: drawn from a seed (hypothesis draws them one by one a hundred times slower),
    # uniform over the 16-bit range with a drawn share of them at the extremes and 0, 1, -1
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    special = np.array([-(1 << 15), (1 << 15) - 1, 0, 1, -1])
    matrix = rng.integers(-(1 << 15), 1 << 15, size=n * n)
    at = rng.random(n * n) < draw(st.sampled_from([0.0, 0.2, 0.5, 1.0]))
    matrix[at] = rng.choice(special, size=int(at.sum()))
    matrix = [int(v) for v in matrix]
    shift = draw(st.integers(0, 31))
    big = 1 << 40
    coeff = st.one_of(st.integers(-1000, 1000), st.integers(-big, big), st.sampled_from([-big, big, 0]))
    rows = draw(st.lists(st.lists(coeff, min_size=n, max_size=n), min_size=1, max_size=4))
    return d, n, matrix, shift, rows


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(transforms())
def test_inverse_follows_the_rule_in_integers(case):
    d, n, matrix, shift, rows = case
    layout = dataclasses.replace(GaussianLayout(d), sh_transform=ShTransform(shift, tuple(matrix)))
    q = np.zeros((len(rows), layout.num_channels), np.int64)
    q[:, 3:3 + n] = rows
    q[:, 0], q[:, -1] = 7, -5  # the DC and the other channels pass unchanged
    expected = [_by_rule(r, matrix, n, shift) for r in rows]
    if any(abs(v) > MAX_PREDICTED_MAGNITUDE for row in expected for v in row):
        with pytest.raises(BitstreamError, match="inverse transform exceeds the limit"):
            inverse_sh_transform(q, layout, "test")
        return
    out = inverse_sh_transform(q, layout, "test")
    assert out[:, 3:3 + n].tolist() == expected
    assert (out[:, 0] == 7).all() and (out[:, -1] == -5).all() and out[:, 3 + n:-1].tolist() == q[:, 3 + n:-1].tolist()


def test_rounding_shift_floors_ties_up_and_negative_sums():
    layout = dataclasses.replace(GaussianLayout(1), sh_transform=ShTransform(1, tuple(np.eye(9, dtype=int).ravel())))
    q = np.zeros((1, layout.num_channels), np.int64)
    q[0, 3:12] = [1, -1, 3, -3, 0, 2, -2, 5, -5]  # halves: ties towards plus infinity
    assert inverse_sh_transform(q, layout, "t")[0, 3:12].tolist() == [1, 0, 2, -1, 0, 1, -1, 3, -2]


def test_without_a_transform_q_is_returned_as_is():
    q = np.arange(2 * 35, dtype=np.int64).reshape(2, 35)
    assert inverse_sh_transform(q, GaussianLayout(2), "t") is q


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 3), st.integers(0, 31), st.integers(1, 16), st.integers(0, 2 ** 31))
def test_unit_round_trip_and_entry_offset(d, shift, bits, seed):
    n = 3 * (d + 1) ** 2 - 3
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 1 << bits, size=n * n).tolist()
    unit = ShTransformUnit(sh_degree=d, sh_transform_shift=shift, sh_transform_bits_minus1=bits - 1,
                           sh_transform_coeff=raw)
    data = unit.to_bytes()
    assert len(data) == (9 + bits * n * n + 7) // 8
    back = ShTransformUnit.from_bytes(data, sh_degree=d)
    assert back.sh_transform_coeff == raw and back.sh_transform_shift == shift
    t = ShTransform.from_unit(back)
    assert list(t.matrix) == [c - (1 << (bits - 1)) for c in raw]
    again = t.to_unit(d)  # the fewest bits that hold the entries
    assert ShTransform.from_unit(ShTransformUnit.from_bytes(again.to_bytes(), sh_degree=d)) == t
    assert again.sh_transform_bits_minus1 <= bits - 1


def test_unit_faults():
    unit = ShTransformUnit(sh_degree=1, sh_transform_shift=3, sh_transform_bits_minus1=3, sh_transform_coeff=[5] * 81)
    data = unit.to_bytes()
    with pytest.raises(BitstreamError, match="unexpected trailing bytes"):
        ShTransformUnit.from_bytes(data + b"\0", sh_degree=1)
    with pytest.raises(BitstreamError):
        ShTransformUnit.from_bytes(data[:-1], sh_degree=1)
    assert ShTransformUnit.from_bytes(bytes(2), sh_degree=0).sh_transform_coeff == []


def test_klt_is_orthonormal_by_decreasing_variance():
    rng = np.random.default_rng(3)
    u = rng.normal(size=(4000, 24)) @ rng.normal(size=(24, 24))
    a = sht.fit_klt(u)
    assert np.allclose(a.T @ a, np.eye(24), atol=1e-9)
    var = (u @ a).var(axis=0)
    assert (np.diff(var) <= 1e-9 * var[0]).all()
    t = sht.integer_transform(a)
    assert max(abs(x) for x in t.matrix) <= sht.ENTRY_LIMIT
    assert np.allclose(sht.forward(u[:5], t) @ sht.value_matrix(t).T, u[:5])  # B^-1 then B


def test_klt_is_the_same_whatever_the_layout_of_its_input():
    """The search fits the KLT to a column slice of its values (x[:, rest]); a contiguous copy, or the
    columns of a Fortran-order array, give the same integer transform."""
    rng = np.random.default_rng(11)
    wide = (rng.normal(size=(5000, 24)) @ rng.normal(size=(24, 24))) * rng.uniform(0.1, 30, 24)
    x = np.concatenate([rng.normal(size=(5000, 3)), wide, rng.normal(size=(5000, 8))], axis=1)
    t = sht.integer_transform(sht.fit_klt(x[:, 3:27]))
    assert t == sht.integer_transform(sht.fit_klt(np.ascontiguousarray(x[:, 3:27])))
    assert t == sht.integer_transform(sht.fit_klt(np.asfortranarray(x)[:, 3:27]))
    a = sht.fit_klt(x[:, 3:27])
    c = np.cov(x[:, 3:27], rowvar=False)  # the eigenvectors of the covariance, by decreasing variance
    assert np.allclose(c @ a, a * np.diag(a.T @ c @ a), atol=1e-9 * np.abs(c).max())


@settings(max_examples=25, deadline=None)
@given(n=st.integers(0, 700), width=st.sampled_from([9, 24, 45]), fit_rows=st.integers(2, 400),
       mode=st.sampled_from([True, "always"]), scale=st.sampled_from([0.3, 4.0, 1e5]), seed=st.integers(0, 2 ** 31))
def test_the_transform_of_the_values_is_the_one_of_the_sh_rest_made_whole(n, width, fit_rows, mode, scale, seed):
    """chosen_transform_of_values (the SH rest divided by its band steps a block or a column at a time,
    the fit on its sampled rows) chooses the transform chosen_transform chooses from u made whole, and
    its coefficients are one solve's of every row."""
    rng = np.random.default_rng(seed)
    mix = rng.normal(size=(width, width)) * (rng.uniform(size=(width, width)) < 0.3) + np.eye(width)
    values = np.concatenate([rng.normal(size=(n, 3)), (rng.normal(size=(n, width)) @ mix) * scale,
                             rng.normal(size=(n, 8))], axis=1)
    band_steps = rng.uniform(0.05, 2.0, width)
    rest, degree = slice(3, 3 + width), {9: 1, 24: 2, 45: 3}[width]
    old_fit = sht.FIT_ROWS
    try:
        sht.FIT_ROWS = fit_rows  # (the fit's sample taken from the values as from u)
        transform, coefficients = sht.chosen_transform_of_values(values, rest, band_steps, mode, degree)
        u = values[:, rest] / band_steps
        assert transform == sht.chosen_transform(u, mode, degree)
    finally:
        sht.FIT_ROWS = old_fit
    if transform is None:
        assert coefficients is None
        return
    whole = np.linalg.solve(sht.value_matrix(transform), u.T).T
    assert np.array_equal(coefficients.view(np.int64), whole.view(np.int64))  # every bit


@pytest.mark.parametrize("n", [2 * (1 << 16) - 1, 2 * (1 << 16) + 3, 3 * (1 << 16) + 12345])
def test_forward_by_blocks_is_one_solve_to_the_last_bit(n):
    """forward's blocks (solve_blocks: none narrower than FORWARD_BLOCK_ROWS, the rest in the last) give
    every coefficient the bits of one solve of every row."""
    blocks = list(sht.solve_blocks(n))
    assert blocks[0].start == 0 and blocks[-1].stop == n and all(a.stop == b.start for a, b in zip(blocks, blocks[1:]))
    assert all(b.stop - b.start >= sht.FORWARD_BLOCK_ROWS for b in blocks)
    rng = np.random.default_rng(n)
    u = rng.normal(size=(n, 45)) @ (np.eye(45) + 0.3 * rng.normal(size=(45, 45)))
    t = sht.integer_transform(sht.fit_klt(u))
    whole = np.linalg.solve(sht.value_matrix(t), u.T).T
    assert np.array_equal(sht.forward(u, t).view(np.int64), whole.view(np.int64))


def test_klt_of_degenerate_inputs():
    for u in (np.zeros((1, 9)), np.zeros((50, 9)), np.ones((50, 9))):
        a = sht.fit_klt(u)
        assert np.allclose(a.T @ a, np.eye(9), atol=1e-9)


def test_coefficient_sensitivity_is_the_diagonal_of_bt_f_b():
    rng = np.random.default_rng(5)
    t = sht.integer_transform(sht.fit_klt(rng.normal(size=(300, 9)) @ rng.normal(size=(9, 9))))
    f = rng.random((4, 9)) * 10
    steps = rng.random(9) + 0.1
    got = sht.coefficient_sensitivity(f, steps, t)
    b = sht.value_matrix(t) * steps[:, None]
    for i in range(4):
        assert np.allclose(got[i], np.diag(b.T @ np.diag(f[i]) @ b))
    # the expected picture error of independent unit coefficient errors
    e = rng.choice([-0.5, 0.5], size=(20000, 9))
    err = ((e @ b.T) ** 2 * f[0]).sum(axis=1).mean()
    assert err == pytest.approx((got[0] * 0.25).sum(), rel=0.05)


def _transform_unit(data: bytes):
    return [u for u in read_container(data).units if u.unit_type == UnitType.SH_TRANSFORM]


@pytest.mark.parametrize("degree,extra", [
    (1, {"neighbour_prediction": False}),
    (2, {}),
    (3, {"step_adjust_max": 7, "sh_degree_choice": True, "rotation_length": True, "tile_points": 500}),
])
def test_round_trip_through_encoder_and_decoder(degree, extra):
    rng = np.random.default_rng(10 + degree)
    scene = random_gaussians(rng, 1200, degree, correlated=True)
    cfg = dataclasses.replace(GaussianEncoderConfig(), sh_transform="always", **extra).validate()
    r = encode_gaussian_scene(scene, cfg, sensitivity=_sensitivity(scene, rng))
    assert len(_transform_unit(r.data)) == 1 and r.stats.sh_transform
    assert read_container(r.data).header.version_minor == 6
    d = decode_stream(r.data)
    assert_same(d.scene, r.decoded)


def _sh_rest_error(decoded, scene) -> float:
    """Mean squared error of the decoded SH rest against the source's, each decoded Gaussian matched to
    the source Gaussian nearest its position (the decoded scene is in normative order)."""
    d2 = ((decoded.means[:, None, :].astype(np.float64) - scene.means[None, :, :]) ** 2).sum(axis=2)
    src = scene.sh[np.argmin(d2, axis=1)]
    return float(np.square(decoded.sh[:, 1:].astype(np.float64) - src[:, 1:]).mean())


def _latent_scene(rng, n: int, degree: int):
    """An SH rest of few latent factors mixed into every coefficient and colour (as in real captures:
    tools/results/sh_coding.md), which pairwise cross-channel prediction takes only in part."""
    scene = random_gaussians(rng, n, degree)
    rest = 3 * (degree + 1) ** 2 - 3
    z = rng.normal(size=(n, 3)) @ rng.normal(size=(3, rest)) * 0.15 + 0.01 * rng.normal(size=(n, rest))
    scene.sh[:, 1:] = z.reshape(n, -1, 3).astype(np.float32)
    return scene


def test_transform_codes_a_correlated_sh_rest_in_fewer_bits():
    rng = np.random.default_rng(21)
    scene = _latent_scene(rng, 2000, 2)
    out = {}
    for on in (False, True):
        r = encode_gaussian_scene(scene, dataclasses.replace(GaussianEncoderConfig(), sh_transform=on))
        out[on] = (len(r.data), _sh_rest_error(decode_stream(r.data).scene, scene), len(_transform_unit(r.data)))
    assert out[True][2] == 1 and out[False][2] == 0
    assert out[True][0] < 0.95 * out[False][0]
    # about the distortion of rounding each value at its band step (plain rounding: the step^2 / 12 of both)
    assert out[True][1] < 1.2 * out[False][1]


def test_scenes_without_sh_rest_or_gain_are_coded_as_before():
    rng = np.random.default_rng(30)
    for scene in (random_gaussians(rng, 500, 0), random_gaussians(rng, 40, 1)):
        off = encode_gaussian_scene(scene, dataclasses.replace(GaussianEncoderConfig(), sh_transform=False)).data
        on = encode_gaussian_scene(scene, dataclasses.replace(GaussianEncoderConfig(), sh_transform=True)).data
        assert on == off and not _transform_unit(on)


def test_degrees_keep_the_leading_coefficients():
    rng = np.random.default_rng(40)
    scene = random_gaussians(rng, 600, 2, correlated=True)
    degrees = rng.integers(0, 3, size=600)
    cfg = dataclasses.replace(GaussianEncoderConfig(), sh_transform="always").validate()
    r = encode_gaussian_scene(scene, cfg, sh_degrees=degrees)
    d = decode_stream(r.data)
    assert_same(d.scene, r.decoded)
    d2 = ((d.scene.means[:, None, :].astype(np.float64) - scene.means[None, :, :]) ** 2).sum(axis=2)
    own = degrees[np.argmin(d2, axis=1)]  # each decoded Gaussian's degree (normative order)
    assert (d.scene.sh[own == 0, 1:] == 0).all()  # no coefficient: every SH-rest value +0.0
    assert np.abs(d.scene.sh[own == 1, 4:]).max() > 0  # band 2 from the 9 leading coefficients


def _with_units(data: bytes, edit) -> bytes:
    units = [DataUnit(u.unit_type, u.payload) for u in read_container(data).units]
    edit(units)
    return write_container(units)


def test_errors():
    rng = np.random.default_rng(50)
    scene = random_gaussians(rng, 300, 1, correlated=True)
    cfg = dataclasses.replace(GaussianEncoderConfig(), sh_transform="always", rotation_length=True,
                              neighbour_prediction="always").validate()
    data = encode_gaussian_scene(scene, cfg).data
    types = [u.unit_type for u in read_container(data).units]
    j = types.index(UnitType.SH_TRANSFORM)
    assert types[j - 1] == UnitType.ROTATION_LENGTH
    twice = _with_units(data, lambda u: u.insert(j, u[j]))
    swapped = _with_units(data, lambda u: u.__setitem__(slice(j - 1, j + 1), [u[j], u[j - 1]]))
    for bad in (twice, swapped):
        with pytest.raises(BitstreamError, match="out of order"):
            decode_stream(bad)
    unit = ShTransformUnit.from_bytes(read_container(data).units[j].payload, sh_degree=1)
    huge = dataclasses.replace(unit, sh_transform_shift=0, sh_transform_bits_minus1=15,
                               sh_transform_coeff=[(1 << 15) - 1] * 81)
    other = _with_units(data, lambda u: u.__setitem__(j, DataUnit(UnitType.SH_TRANSFORM, huge.to_bytes())))
    with pytest.raises(HashMismatchError):  # another matrix, other values: the hash tells
        decode_stream(other)
    assert decode_stream(other, verify_hash=False).scene.sh[:, 1:].any()


def test_the_fit_rounds_and_prices_the_coefficients_the_stream_codes():
    """The rate-aware fit (encoder/gaussians/gaussian_fit.py) simulates the coding: with the transform,
    its quantized SH rest is B round(B^-1 u) in band steps (u the values in band steps), what the
    decoder's inverse gives within its 2^-GUARD_BITS grid, and the integers it prices are the
    coefficients; with an identity basis, exactly the values' own rounding."""
    from lghcc.encoder.gaussians.gaussian_fit import _Fit, sh_transform_basis

    rng = np.random.default_rng(50)
    scene = _latent_scene(rng, 400, 2)
    cfg = dataclasses.replace(GaussianEncoderConfig(), sh_transform="always").validate()
    basis = sh_transform_basis(scene, cfg)
    assert basis is not None and basis.shape == (24, 24)
    assert sh_transform_basis(scene, dataclasses.replace(cfg, sh_transform=False)) is None
    assert sh_transform_basis(random_gaussians(rng, 50, 0), cfg) is None
    steps = np.repeat(np.asarray(cfg.sh_band_steps)[np.floor(np.sqrt(np.arange(1, 9))).astype(int) - 1], 3)
    u = scene.sh[:, 1:].reshape(400, -1).astype(np.float64) / steps
    t = np.rint(np.linalg.solve(basis, u.T).T)

    fit = _Fit(scene, cfg, sh_basis=basis)
    sh, *_ = fit.quantized()
    got = sh[:, 1:].detach().numpy().reshape(400, -1).astype(np.float64) / steps
    assert np.abs(got - t @ basis.T).max() < 1e-3
    coded = fit.values_in_steps(*fit.quantized())[1].detach().numpy()
    assert np.abs(coded - t).max() < 1e-3 and np.abs(coded - np.rint(coded)).max() < 1e-3
    # the straight-through gradient reaches every SH-rest value
    sh[:, 1:].sum().backward()
    assert fit.sh_rest.grad is not None and bool((fit.sh_rest.grad != 0).all())

    plain, identity = _Fit(scene, cfg), _Fit(scene, cfg, sh_basis=np.eye(24))
    assert torch_equal(plain.quantized()[0], identity.quantized()[0])


def torch_equal(a, b) -> bool:
    return bool((a.detach() == b.detach()).all())


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 300), st.integers(1, 45), st.integers(0, 2 ** 31), st.integers(1, 40), st.integers(1, 15))
def test_exact_matmul_is_the_integer_product_on_both_sides_of_2_53(rows, n, seed, a_bits, b_bits):
    from lghcc.common.attributes import exact_matmul
    rng = np.random.default_rng(seed)
    a = rng.integers(-(1 << a_bits), (1 << a_bits) + 1, size=(rows, n))
    b = rng.integers(-(1 << b_bits), (1 << b_bits) + 1, size=(n, n))
    assert exact_matmul(a, b).tolist() == (a @ b).tolist()  # numpy's int64 product: exact below 2^63


def test_exact_matmul_at_the_float64_edge():
    from lghcc.common.attributes import exact_matmul
    # |a| * column sum = 2^53 - 1: the float64 product, every partial sum exact; one more: the int64 path
    for top in ((1 << 53) - 1, 1 << 53, (1 << 53) + 1):
        a = np.array([[top, -top, 5]] * 130, np.int64)  # over a block of 128 rows
        b = np.array([[1, 0], [0, 1], [0, 0]], np.int64)  # column sums 1
        assert exact_matmul(a, b).tolist() == (a @ b).tolist()
    assert exact_matmul(np.zeros((0, 3), np.int64), np.ones((3, 3), np.int64)).shape == (0, 3)
