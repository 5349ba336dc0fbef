"""The attribute-rate estimate used by rate-distortion training (encoder/anchors/rate_model.py)."""

import numpy as np
import torch

from lghcc.common.geometry import normative_order
from lghcc.common.hierarchy import build_hierarchy
from lghcc.formats.procedural import make_procedural_scene
from lghcc.encoder.stream.config import EncoderConfig
from lghcc.encoder.stream.encode import encode_scene
from lghcc.encoder.context.ggconv_train import GGConvTrainConfig
from lghcc.encoder.anchors.rate_model import AnchorRateModel, quantize_ste


def _scene_values(n=800, seed=3):
    scene = make_procedural_scene(n, seed=seed, feature_dim=6, num_offsets=2)
    values = np.concatenate([scene.features, scene.scalings, scene.offsets.reshape(scene.num_anchors, -1)], 1)
    return scene, values


def _model(scene, values, step=0.05, **kw):
    cfg = GGConvTrainConfig(ctx_channels=4, feat_hidden=8, head_hidden=8, **kw)
    return AnchorRateModel(scene.coords, np.full(values.shape[1], step), scene.feature_dim, 4, values, cfg)


def test_levels_are_the_codecs_hierarchy():
    scene, values = _scene_values()
    rm = _model(scene, values)
    order = normative_order(scene.coords)
    h = build_hierarchy(scene.coords[order], 4)
    assert np.array_equal(rm.l1.numpy(), order[h.level1_idx]) and np.array_equal(rm.l2.numpy(), order[h.level2_idx])
    assert rm.num_level1 + rm.num_level2 == scene.num_anchors


def test_level1_estimate_tracks_the_per_channel_prior_and_differentiates():
    """Level 1's estimate on rounded values is within 10% of what the codec's level-1 unit spends
    (per-channel prior, frozen tables); gradients reach every attribute."""
    scene, values = _scene_values(1500)
    rm = _model(scene, values)
    res = encode_scene(scene, EncoderConfig(hierarchy=True, feature_step=0.05, scaling_step=0.05, offset_step=0.05))
    coded = 8 * res.stats.levels[1].attribute_bytes
    with torch.no_grad():
        est = float(rm(torch.from_numpy(values), noise=False)["level1"])
    assert abs(est - coded) < 0.1 * coded, (est, coded)
    v = torch.from_numpy(values).requires_grad_()
    bits = rm(v, generator=torch.Generator().manual_seed(0))
    bits["total"].backward()
    assert torch.isfinite(v.grad).all() and (v.grad.abs().sum(1) > 0).all()
    assert float(bits["level2"].detach()) > 0


def test_training_the_twin_lowers_the_level2_estimate_on_a_smooth_scene():
    torch.manual_seed(0)  # the twin's initial weights come from torch's global generator: not from the test order
    scene, values = _scene_values(1500)
    for level in (1, 2):
        rm = _model(scene, values, neighbour_level=level)
        v = torch.from_numpy(values)
        with torch.no_grad():
            before = float(rm(v, noise=False)["level2"])
        opt = torch.optim.Adam(rm.parameters(), lr=3e-3)
        gen = torch.Generator().manual_seed(1)
        for _ in range(150):
            opt.zero_grad()
            rm(v, generator=gen)["total"].backward()
            opt.step()
        with torch.no_grad():
            after = float(rm(v, noise=False)["level2"])
        assert after < 0.97 * before, (level, before, after)


def test_quantize_ste_rounds_forward_and_passes_gradients():
    x = torch.tensor([0.012, -0.031, 0.5], requires_grad=True)
    y = quantize_ste(x, torch.tensor(0.02))
    assert torch.allclose(y, torch.tensor([0.02, -0.04, 0.5]))
    y.sum().backward()
    assert torch.equal(x.grad, torch.ones(3))


def test_one_anchor_and_an_empty_level2():
    scene, values = _scene_values(5)
    one = AnchorRateModel(scene.coords[:1], np.full(values.shape[1], 0.05), scene.feature_dim, 4, values[:1])
    assert one.twin is None and one.num_level2 == 0
    out = one(torch.from_numpy(values[:1]))
    assert float(out["level2"]) == 0 and torch.isfinite(out["total"])
