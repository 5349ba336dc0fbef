"""Merging instead of dropping (encoder/gaussians/merging.py): the moments the merge keeps, its
degenerate cases, and an encode with ``prune_mode: merge`` that decodes to what it coded."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from lghcc.common.errors import InputError
from lghcc.common.scene import GaussianScene
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians.merging import covariances, merge_pruned, merge_targets, pruned_scene
from lghcc.encoder.stream.config import GaussianEncoderConfig


def _scene(means, log_scales, opacity, rotations=None, sh=None) -> GaussianScene:
    n = len(means)
    f = lambda a: np.asarray(a, np.float32)  # noqa: E731
    rot = np.tile([1.0, 0, 0, 0], (n, 1)) if rotations is None else rotations
    sh = np.arange(n * 4 * 3, dtype=np.float32).reshape(n, 4, 3) / 10 if sh is None else sh
    return GaussianScene(f(means), f(sh), f(opacity), f(log_scales), f(rot))



def _pairs(rng: np.random.Generator, offset: np.ndarray, log_scales: np.ndarray, opacity: np.ndarray):
    """Two Gaussians far from the origin (the moments must lose no digits there)."""
    return _scene(np.stack([np.zeros(3), offset]) + 1000.0, log_scales, opacity, rng.normal(size=(2, 4)))


_finite = st.floats(-3, 3, allow_nan=False)
_weight = st.floats(1e-6, 1e3)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 31), offset=st.lists(_finite, min_size=3, max_size=3),
       scales=st.lists(st.floats(-4, 1), min_size=6, max_size=6), w=st.lists(_weight, min_size=2, max_size=2))
def test_a_merged_pair_keeps_the_weighted_mean_and_covariance(seed, offset, scales, w):
    rng = np.random.default_rng(seed)
    scene = _pairs(rng, 0.1 * np.asarray(offset), np.reshape(scales, (2, 3)), np.asarray([0.5, -1.0]))
    keep = np.array([True, False])
    assume(merge_targets(scene, keep)[1] == 0)  # else dropped (test_out_of_reach_is_dropped...)
    w = np.asarray(w)
    out = merge_pruned(scene, keep, w)
    m = scene.means.astype(np.float64)
    mu = (w[:, None] * m).sum(0) / w.sum()
    d = m - mu
    cov = (w[:, None, None] * (covariances(scene) + np.einsum("ni,nj->nij", d, d))).sum(0) / w.sum()
    merged = covariances(out)[0]
    np.testing.assert_allclose(out.means[0], mu, rtol=0, atol=1e-4 * (1 + np.abs(d).max()))
    np.testing.assert_allclose(merged, cov, rtol=1e-4, atol=1e-5 * np.abs(cov).max())
    assert np.allclose(merged, merged.T) and np.linalg.eigvalsh(merged).min() > 0
    sh = (w[:, None, None] * scene.sh).sum(0) / w.sum()
    np.testing.assert_allclose(out.sh[0], sh, rtol=1e-5, atol=1e-5)
    assert out.opacity[0] == scene.opacity[0]  # the kept Gaussian's (merging.py: the coverage measured worse)


def test_identical_positions_merge_to_the_weighted_covariance_in_place():
    scene = _scene(np.ones((3, 3)), [[-1, -2, -3], [-3, -2, -1], [-2, -2, -2]], [1.0, -1.0, 0.0])
    w = np.array([1.0, 2.0, 3.0])
    out = merge_pruned(scene, np.array([True, False, False]), w)
    assert out.num_gaussians == 1
    np.testing.assert_allclose(out.means[0], 1.0, atol=1e-6)
    cov = (w[:, None, None] * covariances(scene)).sum(0) / w.sum()
    np.testing.assert_allclose(covariances(out)[0], cov, rtol=1e-4)


def test_zero_weight_merges_nothing_in():
    scene = _scene([[0, 0, 0], [0.05, 0, 0]], np.full((2, 3), -2.0), [1.0, -20.0])
    keep = np.array([True, False])
    for w in ([2.0, 0.0], [2.0, np.nan], [2.0, -1.0]):  # no view sees it (NaN, negative: none either)
        out = merge_pruned(scene, keep, np.array(w))
        np.testing.assert_allclose(out.means[0], 0.0, atol=1e-7)
        np.testing.assert_allclose(covariances(out)[0], covariances(scene)[0], rtol=1e-5)
        assert np.isfinite(out.sh).all()
    same = merge_pruned(scene, keep, np.zeros(2))  # all weights zero: kept as it was
    for f in ("means", "sh", "opacity", "log_scales", "rotations"):
        assert np.array_equal(getattr(same, f), getattr(scene, f)[:1])


@pytest.mark.parametrize("log_scale", [-30.0, 30.0])
def test_huge_and_tiny_scales_stay_finite_and_positive_definite(log_scale):
    scene = _scene([[0, 0, 0], [1e-20, 0, 0]], [[log_scale, log_scale, log_scale - 8], [log_scale] * 3], [0.0, 0.0])
    out = merge_pruned(scene, np.array([True, False]), np.array([1.0, 0.5]))
    for a in (out.means, out.log_scales, out.rotations, out.opacity, out.sh):
        assert np.isfinite(a).all()
    lam = np.linalg.eigvalsh(covariances(out)[0].astype(np.float64))
    assert lam.min() > 0


def test_nothing_to_merge_returns_the_kept_gaussians_as_they_were():
    rng = np.random.default_rng(0)
    scene = _scene(rng.normal(size=(5, 3)), np.full((5, 3), -3.0), rng.normal(size=5), rng.normal(size=(5, 4)))
    for keep in (np.ones(5, bool), np.array([True, False, True, False, True])):
        far = _scene(scene.means * 1000, scene.log_scales, scene.opacity, scene.rotations)  # out of reach
        out = merge_pruned(far, keep, np.ones(5))
        for f in ("means", "sh", "opacity", "log_scales", "rotations"):
            assert np.array_equal(getattr(out, f), getattr(far, f)[keep])
    single = scene.subset(np.array([0]))
    assert np.array_equal(merge_pruned(single, np.array([True]), np.ones(1)).means, single.means)


def test_out_of_reach_is_dropped_and_in_reach_goes_to_the_nearest_kept():
    scene = _scene([[0, 0, 0], [0.1, 0, 0], [5, 0, 0], [1.0, 0, 0]], np.full((4, 3), np.log(0.1)), np.zeros(4))
    target = merge_targets(scene, np.array([True, False, False, True]))
    assert target.tolist() == [-1, 0, -1, -1]  # 0.1 from 0 (reach 0.2); 4 from the nearest: dropped


def test_pruned_scene_adds_the_merged_contributions():
    scene = _scene([[0, 0, 0], [0.1, 0, 0], [1.0, 0, 0]], np.full((3, 3), np.log(0.1)), np.zeros(3))
    contrib = np.array([5.0, 0.5, 4.0])
    keep, kept, weights = pruned_scene(scene, contrib, 0.06, "merge")
    assert keep.tolist() == [True, False, True] and weights.tolist() == [5.5, 4.0]
    assert kept.means[0, 0] == pytest.approx(0.1 * 0.5 / 5.5)  # moved by the pruned one's share
    keep, kept, weights = pruned_scene(scene, contrib, 0.06, "drop")
    assert weights.tolist() == [5.0, 4.0] and kept.means[0, 0] == 0


def test_prune_mode_is_checked():
    with pytest.raises(InputError, match="prune_mode"):
        GaussianEncoderConfig(prune_mode="fuse").validate()


def test_an_encode_with_merging_decodes_to_what_it_coded():
    from lghcc.encoder.gaussians.gaussian_fit import prepare_gaussians
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
    from test_gaussians import assert_same, random_gaussians

    scene = random_gaussians(np.random.default_rng(4), 300, 1, correlated=True)
    scene.log_scales[:] = np.log(0.08)
    base = dict(fit_iterations=0, fit_views=6, fit_resolution=32, position_step=0.5, prune_share=0.05)
    merged = prepare_gaussians(scene, GaussianEncoderConfig(**base, prune_mode="merge"))
    dropped = prepare_gaussians(scene, GaussianEncoderConfig(**base, prune_mode="drop"))
    assert merged.stats.gaussians_pruned == dropped.stats.gaussians_pruned > 0
    assert merged.scene.num_gaussians == dropped.scene.num_gaussians
    assert not np.array_equal(merged.scene.log_scales, dropped.scene.log_scales)
    res = encode_gaussian_scene(merged.scene, merged.cfg)
    assert_same(decode_stream(res.data).scene, res.decoded)


def test_a_covariance_is_written_on_the_axes_of_the_frame_it_came_from():
    from scipy.spatial.transform import Rotation

    from lghcc.encoder.gaussians.merging import scales_and_rotations

    rng = np.random.default_rng(0)
    r = Rotation.random(50, random_state=1).as_matrix()
    s = np.exp(rng.normal(size=(50, 3)))
    cov = np.einsum("nij,nj,nkj->nik", r, s ** 2, r)
    log_scales, q = scales_and_rotations(cov, r)
    np.testing.assert_allclose(np.exp(log_scales), s, rtol=1e-9)  # not eigh's ascending order
    back = Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()
    np.testing.assert_allclose(back, r, atol=1e-9)
    unaligned, _ = scales_and_rotations(cov)
    assert (np.diff(unaligned, axis=1) >= 0).all()
