"""The encoder's per-Gaussian SH degree (format 1.3, clause 11.9; encoder/gaussians/rdoq.py
sh_degree_choice): the degree of least cost, the bands the views do not see dropped, the ones
they see kept, no tool where it does not pay, the config switch, and the hard cases."""

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.attributes import GaussianLayout
from lghcc.common.container import UnitType, read_container
from lghcc.common.errors import InputError
from lghcc.common.geometry import normative_order
from lghcc.common.neighbour_prediction import neighbour_graph
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians import rdoq
from lghcc.encoder.gaussians.gaussian_grid import coded_values
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.gaussians.rdoq import (_degree_costs, channel_groups, channel_steps, group_slopes, rd_quantize,
                                          sh_degree_choice)
from lghcc.encoder.stream.config import GaussianEncoderConfig, load_config
from test_gaussians import random_gaussians
from test_neighbour_prediction import _smooth_scene
from test_step_adjust import _sensitivity


def _tool(data: bytes) -> bool:
    return any(u.unit_type == UnitType.SH_DEGREE for u in read_container(data).units)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 3), st.integers(1, 20), st.integers(0, 2 ** 31))
def test_the_chosen_degree_never_costs_more_than_keeping_every_band(d, n, seed):
    rng = np.random.default_rng(seed)
    gains = rng.normal(0, 10, (n, d)) * (rng.random((n, d)) < 0.8)
    flags = rng.uniform(0.001, 12, (n, d, 2))
    costs = _degree_costs(gains, flags)
    # the cost of degree D: the gains of the bands above it, the ones of bands 1 .. D, a zero after
    for D in range(d + 1):
        want = gains[:, D:].sum(axis=1) + flags[:, :D, 1].sum(axis=1) + (flags[:, D, 0] if D < d else 0)
        assert np.allclose(costs[:, D], want)
    chosen = np.argmin(costs, axis=1)
    assert (costs[np.arange(n), chosen] <= costs[:, d]).all()


def _choice(scene, f, cfg, q=None):
    """sh_degree_choice on the scene's RDOQ'd values (scene order), as the encoder runs it."""
    layout = GaussianLayout(scene.sh_degree)
    x = coded_values(scene) / channel_steps(cfg, scene.sh_degree)
    coords = np.rint(scene.means / 0.01).astype(np.int64)
    order = normative_order(coords)
    graph = neighbour_graph(coords[order], cfg.prediction_lods, cfg.prediction_neighbours)
    mu = group_slopes(f, channel_groups(scene.sh_degree), 1.0)
    if q is None:
        q = rd_quantize(x[order], f[order], mu, coords[order], graph, cfg.prediction_buckets)
    else:
        q = q[order]
    d = np.empty(scene.num_gaussians, np.int64)
    d[order] = sh_degree_choice(x[order], q, f[order], mu, coords[order], graph, cfg.prediction_buckets, layout)
    return d


def test_unseen_sh_rest_is_dropped_and_well_seen_kept():
    scene = _smooth_scene(2000, 2, seed=3)
    rng = np.random.default_rng(3)
    f = _sensitivity(scene, rng, spread=1.0)
    f[:600, 3:27] = 0.0  # the views see no view-dependent colour of these
    f[600:700, 3:27] *= 1e4  # and that of these very well, which have some
    scene.sh[600:700, 1:] = rng.normal(0, 1, scene.sh[600:700, 1:].shape).astype(np.float32)
    cfg = GaussianEncoderConfig(neighbour_prediction="always")
    d = _choice(scene, f, cfg)
    assert (d[:600] == 0).all()
    assert (d[600:700] == 2).all()
    assert d.min() >= 0 and d.max() <= 2


@pytest.mark.parametrize("case", ["all_zero_sh_rest", "zero_sensitivity", "one_gaussian"])
def test_hard_cases_of_the_choice(case):
    n = 1 if case == "one_gaussian" else 500
    scene = _smooth_scene(n, 2, seed=5) if n > 1 else random_gaussians(np.random.default_rng(5), 1, 2)
    f = _sensitivity(scene, np.random.default_rng(5))
    if case == "all_zero_sh_rest":
        scene.sh[:, 1:] = 0.0
    if case == "zero_sensitivity":
        f[:] = 0.0
    cfg = GaussianEncoderConfig(neighbour_prediction="always")
    x = coded_values(scene) / channel_steps(cfg, 2)
    d = _choice(scene, f, cfg, q=np.rint(x).astype(np.int64))
    assert d.shape == (n,) and d.dtype == np.int64 and ((d >= 0) & (d <= 2)).all()
    if case != "one_gaussian":  # nothing to lose by dropping: no band kept (zero F: no slope, no error)
        assert (d == 0).all()


def test_sh_degree_zero_keeps_degree_zero():
    scene = _smooth_scene(300, 0, seed=2)
    f = _sensitivity(scene, np.random.default_rng(2))
    assert (_choice(scene, f, GaussianEncoderConfig(neighbour_prediction="always")) == 0).all()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 400), st.integers(0, 3), st.sampled_from([0, 7]), st.sampled_from([0, 80]),
       st.integers(0, 2 ** 31))
def test_encoder_round_trip_with_the_choice(n, degree, top, tile_points, seed):
    rng = np.random.default_rng(seed)
    scene = _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(rng, n, degree)
    f = _sensitivity(scene, rng, spread=6.0)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=top, tile_points=tile_points,
                                sh_degree_choice=True)
    res = encode_gaussian_scene(scene, cfg, sensitivity=f)
    dec = decode_stream(res.data)
    assert dec.hash_checked
    minor = read_container(res.data).header.version_minor
    if any(u.unit_type == UnitType.STEP_ADJUST_FLAGS for u in read_container(res.data).units):
        assert top and minor == 5  # the step-adjustment indices as flags (version 1.5)
    else:
        assert minor == 3 if _tool(res.data) else minor in ((1, 2) if top else (1,))
    counts = res.stats.sh_degree_counts
    if _tool(res.data):
        assert degree > 0 and sum(counts) == dec.scene.num_gaussians and counts[-1] < dec.scene.num_gaussians
        # the bands above each Gaussian's degree decode to 0: as many Gaussians have a zero band 2 (1)
        # as have degree < 2 (< 1), at least
        for b in range(1, degree + 1):
            band = dec.scene.sh[:, b * b:(b + 1) ** 2]
            assert (~band.any(axis=(1, 2))).sum() >= sum(counts[:b])
    else:
        assert counts is None


def test_the_tool_pays_where_views_do_not_see_the_sh_rest_and_costs_nothing_where_they_do():
    scene = _smooth_scene(1500, 2, seed=8)
    f = _sensitivity(scene, np.random.default_rng(8), spread=1.0)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=7)
    on_cfg = dataclasses.replace(cfg, sh_degree_choice=True)
    seen, unseen = f.copy(), f.copy()
    seen[:, 3:27] *= 1e6
    unseen[:, 3:27] = 0.0
    off = encode_gaussian_scene(scene, cfg, sensitivity=unseen)
    on = encode_gaussian_scene(scene, on_cfg, sensitivity=unseen)
    assert _tool(on.data) and len(on.data) < 0.8 * len(off.data)
    assert on.stats.sh_degree_counts[0] == 1500 and not on.decoded.sh[:, 1:].any()
    # every Gaussian keeps every band: no unit, the bytes of the stream without the tool
    assert encode_gaussian_scene(scene, on_cfg, sensitivity=seen).data == \
        encode_gaussian_scene(scene, cfg, sensitivity=seen).data


def test_the_switch_is_validated_and_on_where_it_paid():
    with pytest.raises(InputError, match="sh_degree_choice"):
        GaussianEncoderConfig(sh_degree_choice="yes").validate()
    # on at low, where it paid through the whole encoder; off where it did not, and in fast (no
    # renders, no sensitivities) (tools/results/sh_degree.md)
    assert load_config("low", kind="gaussians").sh_degree_choice is True
    for preset in ("medium", "high", "fast"):
        assert load_config(preset, kind="gaussians").sh_degree_choice is False
    assert rdoq.DEGREE_ROUNDS >= 1 and rdoq.DEGREE_DISTORTION_WEIGHT > 0
