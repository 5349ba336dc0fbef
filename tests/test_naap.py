"""NAAP and opacity pruning (encoder side)."""

import numpy as np
import pytest

from lghcc.common.errors import InputError
from lghcc.formats.procedural import make_procedural_scene
from lghcc.encoder.anchors.naap import (NaapConfig, estimate_anchor_opacity, naap_importance, naap_prune,
                                opacity_prune)

from scenes import random_scene


def test_importance_matches_the_paper_formula():
    coords = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0]])
    a = np.array([0.1, 0.8, 0.4])
    xi = naap_importance(coords, a, k=8, radius=10, eps=0.0, lam=0.5)
    w = np.array([1.0, 0.5])  # anchor 0: distance 1 and 2
    phi0 = (0.1 + w @ a[1:]) / (1 + w.sum())
    assert xi[0] == pytest.approx(0.5 * 0.1 + 0.5 * phi0)


def test_low_opacity_anchor_in_a_salient_cluster_survives_naap_not_opacity_pruning():
    g = np.stack(np.meshgrid(*[np.arange(3)] * 3, indexing="ij"), -1).reshape(-1, 3)
    far = np.array([[50, 50, 50], [60, 50, 50]])
    coords = np.concatenate([g, far])
    scene = random_scene(np.random.default_rng(0), 1)
    n = len(coords)
    scene.coords = coords
    scene.features = np.zeros((n, 4), np.float32)
    scene.scalings = np.zeros((n, 6), np.float32)
    scene.offsets = np.zeros((n, 2, 3), np.float32)
    a = np.full(n, 0.9)
    a[13] = 0.2          # the cluster's centre: low own opacity
    a[-2:] = 0.3         # isolated anchors with mediocre opacity
    keep = n - 2
    _, rep_o = opacity_prune(scene, keep_ratio=keep / n, opacity=a)
    kept_n, rep_n = naap_prune(scene, NaapConfig(keep_ratio=keep / n, lam=0.9), opacity=a)
    assert rep_o.num_after == rep_n.num_after == keep
    assert any((kept_n.coords == [1, 1, 1]).all(1))      # NAAP keeps the centre ...
    assert not any((kept_n.coords == [60, 50, 50]).all(1))  # ... and merges away an isolated one


def test_merge_rule():
    scene = random_scene(np.random.default_rng(1), 1)
    scene.coords = np.array([[0, 0, 0], [1, 0, 0]])
    scene.features = np.zeros((2, 4), np.float32)
    scene.scalings = np.array([[1.0] * 6, [3.0] * 6], np.float32)
    scene.offsets = np.array([np.ones((2, 3)), 5 * np.ones((2, 3))], np.float32)
    out, rep = naap_prune(scene, NaapConfig(tau=0.5, gamma=0.25, lam=0.0), opacity=np.array([0.9, 0.1]))
    assert rep.num_after == 1
    assert out.scalings[0, 0] == pytest.approx(0.75 * 1 + 0.25 * 3)
    assert out.offsets[0, 0, 0] == pytest.approx(0.75 * 1 + 0.25 * 5)
    assert out.extra["opacity_accum"][0] == pytest.approx(0.75 * 0.9 + 0.25 * 0.1)


def test_degenerate_inputs_stay_finite():
    scene = random_scene(np.random.default_rng(2), 1)
    out, rep = naap_prune(scene, NaapConfig(keep_ratio=0.5), opacity=np.array([0.3]))
    assert rep.num_after == 1
    scene = random_scene(np.random.default_rng(2), 30)
    out, rep = naap_prune(scene, NaapConfig(tau=0.5, radius_voxels=1e-9), opacity=np.full(30, 0.5))
    assert rep.num_after == 30  # equal importance at the threshold: nothing pruned
    out, rep = naap_prune(scene, NaapConfig(tau=10.0), opacity=np.zeros(30))
    assert rep.num_after == 1 and np.isfinite(out.offsets).all()
    with pytest.raises(InputError):
        naap_prune(scene, NaapConfig(tau=0.1, keep_ratio=0.5), opacity=np.zeros(30))


def test_opacity_from_the_mlp():
    scene = make_procedural_scene(400, seed=0, feature_dim=8, num_offsets=3)
    a = estimate_anchor_opacity(scene, num_views=4)
    assert a.shape == (scene.num_anchors,) and np.all((a >= 0) & (a <= 1))
    assert a.std() > 0
    scene.mlps = {}
    with pytest.raises(InputError, match="no opacity MLP"):
        estimate_anchor_opacity(scene)


@pytest.mark.parametrize("method", ["naap", "opacity"])
def test_encoder_prunes_before_coding(method):
    """lghcc-enc's pruning option: the stream holds the kept anchors, decoded bit-exactly."""
    from lghcc.decoder.decode import decode_stream
    from lghcc.encoder.stream.config import EncoderConfig
    from lghcc.encoder.stream.encode import encode_scene

    scene = make_procedural_scene(600, seed=1, feature_dim=8, num_offsets=3)
    full = encode_scene(scene, EncoderConfig())
    res = encode_scene(scene, EncoderConfig(pruning=method, prune_keep_ratio=0.5))
    n = scene.num_anchors
    assert res.decoded.num_anchors == round(0.5 * n) and res.stats.anchors_before_pruning == n
    assert len(res.data) < 0.7 * len(full.data)
    dec = decode_stream(res.data)
    assert dec.stream_hash == res.scene_hash and dec.scene.num_anchors == res.decoded.num_anchors
    # every kept anchor is one of the input's
    kept = {tuple(c) for c in dec.scene.coords.tolist()}
    assert kept <= {tuple(c) for c in scene.coords.tolist()}


def test_encoder_pruning_options_are_checked():
    from lghcc.encoder.stream.config import EncoderConfig

    with pytest.raises(InputError, match="exactly one"):
        EncoderConfig(pruning="naap").validate()
    with pytest.raises(InputError, match="exactly one"):
        EncoderConfig(pruning="naap", prune_keep_ratio=0.5, prune_tau=0.1).validate()
    with pytest.raises(InputError, match="keep_ratio"):
        EncoderConfig(pruning="opacity", prune_keep_ratio=1.5).validate()
    with pytest.raises(InputError, match="pruning must be"):
        EncoderConfig(pruning="random").validate()
