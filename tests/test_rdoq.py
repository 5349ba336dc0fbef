"""Rate-distortion optimized quantization (encoder/gaussians/rdoq.py): the sensitivities against the exact
Jacobian, the choice's bounds and costs (property tests, hard cases), and the encoder coding
exactly the values it chose."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from lghcc.common.entropy.symbol_coder import best_level, code_lengths_bits
from lghcc.common.neighbour_prediction import neighbour_graph
from lghcc.common.scene import GaussianScene
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.stream.config import GaussianEncoderConfig
from lghcc.encoder.gaussians.gaussian_views import fit_cameras
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.gaussians import rdoq
from lghcc.encoder.gaussians.rdoq import (MAX_JUMP, ROTATION_NORMS, channel_groups, channel_steps, group_slopes, rd_quantize,
                                sensitivities, sh_degree_subset)
from lghcc.render.rasterizer import rasterize
from lghcc.render.sh import sh_to_rgb


def small_scene(rng, n, degree):
    f = np.float32
    return GaussianScene(rng.uniform(-1, 1, (n, 3)).astype(f), (0.3 * rng.normal(size=(n, (degree + 1) ** 2, 3))).astype(f),
                         rng.normal(1, 1, n).astype(f), np.log(rng.uniform(0.1, 0.4, (n, 3))).astype(f),
                         rng.normal(size=(n, 4)).astype(f))


def test_sensitivities_estimate_the_diagonal_of_jtj():
    """Averaged over many probes, the estimate approaches the exact sum over pixels of the squared
    derivatives (torch's Jacobian of the rendered image): within 15% where it matters."""
    rng = np.random.default_rng(0)
    scene = small_scene(rng, 6, 1)
    cam = fit_cameras(scene, 1, 12)
    est = sensitivities(scene, cam, probes=600)

    from lghcc.encoder.gaussians.gaussian_grid import canonical_rotations

    means = torch.tensor(scene.means)
    d = means - torch.as_tensor(cam[0].center, dtype=torch.float32)
    d = d / d.norm(dim=1, keepdim=True)
    n = scene.num_gaussians

    def image(flat):
        sh = flat[:, :12].reshape(n, 4, 3)
        op, ls, rot = flat[:, 12], flat[:, 13:16], flat[:, 16:]
        rot = rot / rot.norm(dim=1, keepdim=True)
        return rasterize(means, rot, torch.exp(ls), torch.sigmoid(op), sh_to_rgb(1, sh, d), cam[0],
                         background=torch.zeros(3)).image

    flat = torch.tensor(np.concatenate([scene.sh.reshape(n, -1), scene.opacity[:, None], scene.log_scales,
                                        canonical_rotations(scene.rotations)], 1), dtype=torch.float32)
    jac = torch.autograd.functional.jacobian(image, flat)  # [H, W, 3, N, M]
    exact = (jac.double() ** 2).sum(dim=(0, 1, 2)).numpy()
    assert est.shape == exact.shape == (n, 20)
    big = exact > 0.05 * exact.max()
    assert big.sum() >= 10
    np.testing.assert_allclose(est[big], exact[big], rtol=0.15)
    assert np.all(est[exact == 0] == 0)  # nothing where the pictures do not depend on the value


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 300), m=st.integers(1, 9), scale=st.sampled_from([0.3, 30.0, 3e6]),
       k=st.integers(1, 8), lods=st.integers(1, 6), mu=st.floats(0.01, 10), seed=st.integers(0, 2 ** 31))
def test_values_chosen_in_int32_are_those_chosen_in_int64(n, m, scale, k, lods, mu, seed):
    """RDOQ's values held in int32 (chosen_values_dtype: |x| < 2^26) are the int64 ones, also where
    rows have fewer neighbours than k (the spread's fill of a missing neighbour) and near the limit."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0, scale, (n, m))
    x[rng.uniform(size=x.shape) < 0.05] = np.sign(rng.normal()) * (rdoq.INT32_VALUE_LIMIT - 1)
    coords = np.unique(rng.integers(0, 40, (n, 3)), axis=0)
    x = x[:coords.shape[0]]
    f = rng.exponential(1.0, x.shape)
    graph = neighbour_graph(coords, lods, k)
    narrow = rd_quantize(x, f, np.full(x.shape[1], mu), coords, graph, 5)
    limit = rdoq.INT32_VALUE_LIMIT
    try:
        rdoq.INT32_VALUE_LIMIT = 0.0  # every value int64, as before the narrow dtype
        wide = rd_quantize(x, f, np.full(x.shape[1], mu), coords, graph, 5)
    finally:
        rdoq.INT32_VALUE_LIMIT = limit
    assert narrow.dtype == np.int32 and wide.dtype == np.int64
    np.testing.assert_array_equal(narrow, wide)


def test_values_beyond_the_int32_limit_are_chosen_in_int64():
    x = np.array([[0.2, -rdoq.INT32_VALUE_LIMIT], [1.0, 2.0]])
    assert rdoq.chosen_values_dtype(x) == np.int64
    assert rdoq.chosen_values_dtype(x[1:]) == np.int32
    assert rdoq.chosen_values_dtype(np.array([[np.nan]])) == np.int64  # (no comparison holds)


def _prior_costs(x, q, f, mu):
    mean = np.rint(np.median(np.rint(x), axis=0)).astype(np.int64)
    level = np.array([best_level(np.rint(x[:, c]).astype(np.int64) - mean[c]) for c in range(x.shape[1])])
    lv = np.broadcast_to(level, q.shape)
    return f * (x - q) ** 2 + mu * code_lengths_bits(q - mean, lv), mean


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 200), m=st.integers(1, 6), scale=st.sampled_from([0.3, 3.0, 1e6]),
       mu=st.floats(0, 10), zero_share=st.floats(0, 1), predict=st.booleans(), seed=st.integers(0, 2 ** 31))
def test_choice_stays_within_a_step_towards_the_prediction_and_never_costs_more(n, m, scale, mu, zero_share,
                                                                                predict, seed):
    """Every chosen value is the rounded one or up to MAX_JUMP steps towards the value its coding
    predicts, never away; with the per-channel prior (fixed means), each value's cost is at most
    the rounded value's; mu = 0 is plain rounding."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0, scale, (n, m)) + rng.normal(0, scale, m)
    f = rng.exponential(1.0, (n, m)) * (rng.uniform(size=(n, m)) >= zero_share)
    mus = np.full(m, mu)
    coords = rng.integers(0, 64, (n, 3))
    coords = np.unique(coords, axis=0)
    x, f = x[:coords.shape[0]], f[:coords.shape[0]]
    graph = neighbour_graph(coords, 4, 3) if predict else None
    q0 = np.rint(x).astype(np.int64)
    q = rd_quantize(x, f, mus, coords, graph, 5)
    assert q.dtype == rdoq.chosen_values_dtype(x) and q.shape == x.shape
    assert np.all(np.abs(q - q0) <= MAX_JUMP)
    np.testing.assert_array_equal(rd_quantize(x, f, np.zeros(m), coords, graph, 5), q0)
    if graph is None:
        chosen, mean = _prior_costs(x, q, f, mus)
        rounded, _ = _prior_costs(x, q0, f, mus)
        assert np.all(chosen <= rounded + 1e-9)
        assert np.all(np.abs(q - mean) <= np.abs(q0 - mean))


def test_values_the_pictures_do_not_show_go_to_their_prediction_and_cost_fewer_bits():
    rng = np.random.default_rng(3)
    n, m = 500, 4
    x = rng.normal(0, 3, (n, m))
    coords = np.unique(rng.integers(0, 1000, (n, 3)), axis=0)[:n]
    x = x[:coords.shape[0]]
    q0 = np.rint(x).astype(np.int64)
    q = rd_quantize(x, np.zeros_like(x), np.ones(m), coords, None, 5)
    mean = np.rint(np.median(q0, axis=0)).astype(np.int64)
    assert np.all(np.abs(q - mean) == np.maximum(np.abs(q0 - mean) - 1, 0))  # one step closer each
    sensitive = rd_quantize(x, np.full_like(x, 1e9), np.ones(m), coords, None, 5)
    np.testing.assert_array_equal(sensitive, q0)  # nothing worth its error


def test_hard_cases_one_point_constant_values_and_huge_magnitudes():
    coords = np.zeros((1, 3), np.int64)
    for x in (np.zeros((1, 3)), np.full((1, 3), 2.0 ** 40), np.array([[0.5, -0.5, 1e-300]])):
        q = rd_quantize(x, np.ones_like(x), np.ones(3), coords, None, 5)
        assert np.all(np.abs(q - np.rint(x)) <= 1)
    x = np.full((50, 2), 7.0)
    c = np.stack([np.arange(50), np.zeros(50), np.zeros(50)], 1).astype(np.int64)
    np.testing.assert_array_equal(rd_quantize(x, np.zeros_like(x), np.ones(2), c, neighbour_graph(c, 6, 6), 5), 7)
    empty = np.zeros((0, 3))
    assert rd_quantize(empty, empty, np.ones(3), np.zeros((0, 3), np.int64), None, 5).shape == (0, 3)


def _unit_quaternions(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return np.where(q[:, :1] < 0, -q, q)


SCALES, ROTATION = slice(0, 3), slice(3, 7)  # the orientation columns of the tests' [n, 7] rows


def _shapes(rng, n, step):
    """[n, 7] rows in steps: log scales around e^-3 (elongated ones too), unit quaternions."""
    return np.concatenate([rng.normal(-3, 1, (n, 3)) / step, _unit_quaternions(rng, n) / step], 1)


def _covariances(x, scale_step):
    from lghcc.render.rasterizer import quat_to_rotmat
    r = quat_to_rotmat(torch.from_numpy(x[:, ROTATION])).numpy()
    return np.einsum("nij,nj,nkj->nik", r, np.exp(2 * x[:, SCALES] * scale_step), r)


def test_axis_turns_are_the_24_turns_of_the_axes_and_keep_every_covariance():
    rng = np.random.default_rng(0)
    x = _shapes(rng, 64, 0.1)
    images = {tuple(np.round(m @ [1.0, 0, 0, 0], 9)) for m in rdoq.AXIS_TURNS}
    assert len(rdoq.AXIS_TURNS) == 24 and len({tuple(-np.array(g)) for g in images} | images) == 48
    np.testing.assert_array_equal(rdoq.AXIS_TURNS[0], np.eye(4))
    for m4, perm in zip(rdoq.AXIS_TURNS, rdoq.AXIS_TURN_PERMS):
        assert sorted(perm) == [0, 1, 2]
        np.testing.assert_allclose(m4 @ m4.T, np.eye(4), atol=1e-15)  # a length-keeping map of quaternions
        y = x.copy()
        y[:, SCALES], y[:, ROTATION] = x[:, SCALES][:, perm], -x[:, ROTATION] @ m4.T
        np.testing.assert_allclose(_covariances(y, 0.1), _covariances(x, 0.1), rtol=1e-9, atol=1e-18)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 150), step=st.sampled_from([0.005, 0.04, 0.3, 1.0, 3.0]), mu=st.floats(0, 100),
       zero_share=st.floats(0, 1), predict=st.booleans(), seed=st.integers(0, 2 ** 31))
def test_orientation_writes_the_same_gaussian_costs_no_more_and_never_a_zero_quaternion(n, step, mu, zero_share,
                                                                                        predict, seed):
    """Each Gaussian may be written 48 ways (+-q g with the scales permuted) and its rotation at any
    of ROTATION_NORMS' lengths (the decoder reads a direction): the way chosen is the same
    covariance; with the prior's fixed means it costs at most what the Gaussian's own way costs at
    its best length (scale bits + F (x - direction)^2 + mu bits); the coded quaternion is never
    zero, whatever the step; mu = 0 is plain rounding."""
    rng = np.random.default_rng(seed)
    x = _shapes(rng, n, step)
    f = rng.exponential(1.0, (n, 7)) * (rng.uniform(size=(n, 7)) >= zero_share)
    coords = np.unique(rng.integers(0, 64, (n, 3)), axis=0)
    x, f = x[:coords.shape[0]], f[:coords.shape[0]]
    graph = neighbour_graph(coords, 4, 3) if predict else None
    q = rd_quantize(x, f, np.full(7, mu), coords, graph, 5, (SCALES, ROTATION))
    assert q.shape == x.shape and np.all(q[:, ROTATION].any(axis=1))
    # the ways chosen, kept and given back, choose the same values
    ways = np.full(len(x), -1)
    np.testing.assert_array_equal(rd_quantize(x, f, np.full(7, mu), coords, graph, 5, (SCALES, ROTATION), ways), q)
    if mu > 0:
        assert ways.min() >= 0 and ways.max() < 48
    else:  # no rate term: plain rounding, no way chosen
        assert np.all(ways == -1)
    kept = ways.copy()
    np.testing.assert_array_equal(rd_quantize(x, f, np.full(7, mu), coords, graph, 5, (SCALES, ROTATION), ways), q)
    np.testing.assert_array_equal(ways, kept)
    plain = np.rint(x)
    plain[~plain[:, ROTATION].any(axis=1), 3] = 1
    np.testing.assert_array_equal(rd_quantize(x, f, np.zeros(7), coords, graph, 5, (SCALES, ROTATION)), plain)

    mean = np.rint(np.median(np.rint(x), axis=0)).astype(np.int64)
    level = np.broadcast_to([best_level(np.rint(x[:, c]).astype(np.int64) - mean[c]) for c in range(7)], x.shape)
    mean = np.broadcast_to(mean, x.shape)
    mus = np.full(7, mu)
    y, fy, rho, _ = rdoq._orientation(x, f, mean, level, mus, SCALES, ROTATION)
    assert set(np.unique(rho)) <= set(ROTATION_NORMS)
    np.testing.assert_allclose(np.linalg.norm(y[:, ROTATION], axis=1), rho * np.linalg.norm(x[:, ROTATION], axis=1))
    np.testing.assert_allclose(_covariances(y, step), _covariances(x, step), rtol=1e-9, atol=1e-300)
    if mu > 0:
        def cost(v, fv, vmean):  # the Gaussian's way v (unit length) at its best length, scales included
            s_bits = code_lengths_bits((np.rint(v[:, SCALES]) - vmean[:, SCALES]).astype(np.int64),
                                       level[:, SCALES]).sum(1)
            return mu * s_bits + rdoq._rotation_norms(v[:, ROTATION], fv[:, ROTATION], vmean[:, ROTATION],
                                                      level[:, ROTATION], mu)[1]
        unit = y.copy()
        unit[:, ROTATION] /= rho[:, None]
        assert np.all(cost(unit, fy * np.concatenate([np.ones((len(rho), 3)), (rho ** 2)[:, None].repeat(4, 1)], 1),
                           mean) <= cost(x, f, mean) * (1 + 1e-9) + 1e-9)


def _prior_bits(v):
    """Bits of integer rows [n, M] under a per-channel prior (median mean, best level)."""
    v = np.asarray(v).astype(np.int64)
    r = v - np.median(v, axis=0).astype(np.int64)
    return sum(code_lengths_bits(r[:, c], np.full(len(r), best_level(r[:, c]))).sum() for c in range(v.shape[1]))


def test_rotations_the_pictures_barely_show_are_coded_in_fewer_bits():
    rng = np.random.default_rng(5)
    n = 400
    x = _shapes(rng, n, 0.04)
    coords = np.unique(rng.integers(0, 1000, (n, 3)), axis=0)[:n]
    x = x[:coords.shape[0]]
    f = np.full(x.shape, 1e-3)
    q = rd_quantize(x, f, np.ones(7), coords, None, 5, (SCALES, ROTATION))
    # measured: 5,141 bits against 8,738 for the rounded rotations
    assert _prior_bits(q[:, ROTATION]) < 0.7 * _prior_bits(np.rint(x[:, ROTATION]))
    assert min(ROTATION_NORMS) > 0 and max(ROTATION_NORMS) == 1.0
    sensitive = rd_quantize(x, np.full(x.shape, 1e9), np.ones(7), coords, None, 5, (SCALES, ROTATION))

    # covariances as close as the rounding's (a shorter multiple of a rotation, such as (6, 10, 2, -3)
    # for (12, 20, 4, -6), gives the same one for fewer bits; another way of writing the Gaussian
    # rounds differently, chosen by F's diagonal, which leaves out the cross terms)
    def covariance_error(v):
        return np.abs(_covariances(v.astype(np.float64), 0.04) - _covariances(x, 0.04)).max(axis=(1, 2))
    assert covariance_error(sensitive).mean() <= 1.02 * covariance_error(np.rint(x)).mean()
    assert np.any(np.linalg.norm(sensitive[:, ROTATION], axis=1) < np.linalg.norm(np.rint(x[:, ROTATION]), axis=1))


def test_orientation_follows_the_prior_for_random_rotations_and_the_neighbours_for_aligned_ones():
    """Random orientations coded with the prior: fewer bits than each Gaussian's own way. Aligned
    ones (every Gaussian the same shape and turn, as on a surface) stay in the way their
    neighbours took: the bits do not grow."""
    rng = np.random.default_rng(7)
    n, step = 3000, 0.05
    coords = np.unique(rng.integers(0, 200, (n, 3)), axis=0)
    n = coords.shape[0]
    graph = neighbour_graph(coords, 4, 6)
    for aligned in (False, True):
        x = _shapes(rng, n, step)
        if aligned:
            x[:, SCALES] = np.array([-2.0, -3.0, -4.5]) / step + rng.normal(0, 0.3, (n, 3))
            q0 = np.array([0.2, 0.9, 0.3, -0.2])
            x[:, ROTATION] = (q0 / np.linalg.norm(q0) + rng.normal(0, 0.01, (n, 4))) / step
        f = np.full(x.shape, 20.0)
        mu = np.full(7, 0.5)
        own = rd_quantize(x, f, mu, coords, graph, 5, None)
        turned = rd_quantize(x, f, mu, coords, graph, 5, (SCALES, ROTATION))

        def bits(q):
            from lghcc.encoder.stream.neighbour_coding import NeighbourCoding
            nc = NeighbourCoding(q, coords, len(graph.rows), 1, 5, False, None, graph=graph)
            return sum(code_lengths_bits(nc.residuals[:, c], nc.levels[:, c]).sum() for c in range(7))
        assert bits(turned) <= (1.0 if aligned else 0.97) * bits(own), (aligned, bits(turned), bits(own))


def test_group_slopes_and_channel_maps():
    assert channel_groups(1).tolist() == [0, 0, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1, 4, 5, 5, 5, 6, 6, 6, 6]
    cfg = GaussianEncoderConfig(sh_dc_step=0.5, sh_band_steps=(0.25, 0.125, 1.0))
    steps = channel_steps(cfg, 2)
    assert steps.shape == (35,) and steps[0] == 0.5 and steps[3] == 0.25 and steps[12] == 0.125
    f = np.ones((4, 35))
    f[:, 27] = 8.0  # opacity
    mu = group_slopes(f, channel_groups(2), 2.0)
    assert mu[27] == pytest.approx(2 * 8 * np.log(2) / 6) and mu[0] == pytest.approx(2 * np.log(2) / 6)
    full = np.arange(2 * 56).reshape(2, 56)  # SH degree 3
    assert sh_degree_subset(full, 1).tolist()[0] == list(range(12)) + list(range(48, 56))
    zero = group_slopes(np.zeros((3, 20)), channel_groups(1), 1.0)
    assert np.all(zero == 0)  # a scene the views do not see: nothing to weigh, plain rounding


def _scene(n=400, degree=1, seed=5):
    rng = np.random.default_rng(seed)
    return small_scene(rng, n, degree)


@pytest.mark.parametrize("predict", [True, False])
def test_encoder_codes_the_chosen_values_exactly_and_spends_fewer_bytes(predict):
    scene = _scene()
    # steps of about half the values' spread, as the presets' searches choose
    cfg = GaussianEncoderConfig(neighbour_prediction=predict, position_step=0.3, sh_dc_step=0.15,
                                sh_band_steps=(0.15, 0.15, 0.15), opacity_step=0.5, scale_step=0.2,
                                rotation_step=0.25)
    plain = encode_gaussian_scene(scene, cfg)
    f = np.ones((scene.num_gaussians, 20))
    f[: scene.num_gaussians // 2] = 0.0  # half the Gaussians out of every picture
    chosen = encode_gaussian_scene(scene, cfg, sensitivity=f)
    # measured: 3,757 -> 3,509 bytes with neighbour prediction, 3,485 with the prior
    assert len(chosen.data) < 0.95 * len(plain.data), (len(plain.data), len(chosen.data))
    dec = decode_stream(chosen.data)
    assert dec.hash_checked
    # the decoded values are those the encoder reported, within one step of plain rounding
    steps = channel_steps(cfg, 1)
    # (the scales up to their order: RDOQ may turn a Gaussian's axes, encoder/gaussians/rdoq.py)
    a = np.concatenate([dec.scene.sh.reshape(len(dec.scene.sh), -1), np.sort(dec.scene.log_scales, 1)], 1)
    b = np.concatenate([plain.decoded.sh.reshape(len(a), -1), np.sort(plain.decoded.log_scales, 1)], 1)
    assert np.array_equal(dec.scene.sh, chosen.decoded.sh)
    diff = np.abs(a - b) / np.concatenate([steps[:12], steps[13:16]])
    assert diff.max() <= MAX_JUMP + 1e-3 and diff.max() > 0.5
    off = encode_gaussian_scene(scene, GaussianEncoderConfig(**{**cfg.__dict__, "rd_quantization": 0.0}),
                                sensitivity=f)
    assert off.data == plain.data  # 0: plain rounding, the same stream
    with pytest.raises(ValueError, match="rows"):
        encode_gaussian_scene(scene, cfg, sensitivity=f[:-1])


@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_a_bad_weight_is_refused_with_one_line_and_nothing_written(tmp_path, capsys, value):
    from lghcc.encoder import cli as enc_cli
    from lghcc.formats.ply3dgs import write_3dgs_ply

    src = tmp_path / "scene.ply"
    write_3dgs_ply(src, _scene(20))
    out = tmp_path / "scene.lghcc"
    assert enc_cli.main([str(src), "-o", str(out), "--rd-quantization", str(value)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rd_quantization" in err[0], err
    assert not out.exists()


def test_a_search_trial_does_not_depend_on_the_trials_before_it():
    """The settings search's trials choose RDOQ's ways afresh, as the coding does
    (tools/results/search_ways.md): a trial at coarse steps after one at fine steps measures what
    the same trial measures alone (with the ways kept from the first trial, as the search once did,
    it did not)."""
    from lghcc.encoder.gaussians.gaussian_rd import SettingsSearch, _attribute_groups, _scaled
    from lghcc.render.gaussians3dgs import gaussians_from_scene
    from lghcc.render.importance import gaussian_contributions

    scene = small_scene(np.random.default_rng(5), 300, 1)
    cams = fit_cameras(scene, 2, 32)
    g = gaussians_from_scene(scene)
    contrib = gaussian_contributions(g.means, g.quats, g.scales, g.opacities, cams)
    f = rdoq.sensitivities(scene, cams, probes=2)
    cfg = GaussianEncoderConfig(rd_quantization=1.0, step_adjust_max=0, search_views=2, search_resolution=32,
                                fit_views=2, fit_resolution=32)
    groups = _attribute_groups(scene)
    fine, coarse = _scaled(cfg, groups, 0.25), _scaled(cfg, groups, 4.0)

    def search():
        return SettingsSearch(scene, contrib, cfg, 0.0, 2, 32, f)

    alone = search().evaluate(coarse)
    s = search()
    s.evaluate(fine)
    after = s.evaluate(coarse)
    assert (after.mse, after.bits) == (alone.mse, alone.bits)
