"""Anchors -> neural Gaussians (Scaffold-GS semantics), culling, masks, gradients."""

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.formats.procedural import make_procedural_scene
from lghcc.common.scene import AnchorScene, RenderMLP
from lghcc.render.camera import Camera
from lghcc.render.neural_gaussians import SceneTensors, TorchMLP, generate_neural_gaussians
from lghcc.render.rasterizer import render_scene

F64 = torch.float64


def _mlp(rng, dims, final, scale=1.0):
    ws = [(scale * rng.normal(size=(o, i)) / np.sqrt(i)).astype(np.float32) for i, o in zip(dims[:-1], dims[1:])]
    bs = [(0.1 * rng.normal(size=o)).astype(np.float32) for o in dims[1:]]
    return RenderMLP(ws, bs, ["relu"] * (len(ws) - 1) + [final])


def _scene(n=30, c=8, k=3, seed=0, extra_in=4, mask=False, bank=False, log_scale=-2.5):
    rng = np.random.default_rng(seed)
    coords = np.unique(rng.integers(-20, 21, size=(n * 3, 3)), axis=0)[:n]
    n = len(coords)
    mlps = {"opacity": _mlp(rng, [c + extra_in, c, k], "tanh"), "cov": _mlp(rng, [c + extra_in, c, 7 * k], "none"),
            "color": _mlp(rng, [c + extra_in, c, 3 * k], "sigmoid")}
    if bank:
        mlps["feature_bank"] = _mlp(rng, [4, c, 3], "none")
    return AnchorScene(coords=coords.astype(np.int64), voxel_size=0.05, origin=np.array([0.1, -0.2, 0.3], np.float32),
                       features=rng.normal(size=(n, c)).astype(np.float32),
                       scalings=(log_scale + 0.3 * rng.normal(size=(n, 6))).astype(np.float32),
                       offsets=rng.normal(size=(n, k, 3)).astype(np.float32),
                       offset_mask=(rng.random((n, k)) < 0.6) if mask else None, mlps=mlps)


def _reference(scene: AnchorScene, cam: Camera):
    """Scaffold-GS generate_neural_gaussians, written out in numpy, no culling."""
    p = scene.positions().astype(np.float64)
    f = scene.features.astype(np.float64)
    d = p - cam.center
    dist = np.linalg.norm(d, axis=1, keepdims=True)
    v = d / dist
    c, k = scene.feature_dim, scene.num_offsets
    if "feature_bank" in scene.mlps:
        z = scene.mlps["feature_bank"](np.concatenate([v, dist], 1))
        wb = np.exp(z - z.max(1, keepdims=True))
        wb /= wb.sum(1, keepdims=True)
        f = np.tile(f[:, ::4], 4) * wb[:, :1] + np.tile(f[:, ::2], 2) * wb[:, 1:2] + f * wb[:, 2:]

    def run(role):
        m = scene.mlps[role]
        x = np.concatenate([f, v, dist] if m.in_dim == c + 4 else [f, v], 1)
        return m(x)

    op, cov, col = run("opacity"), run("cov").reshape(-1, k, 7), run("color").reshape(-1, k, 3)
    live = np.ones((len(p), k), bool) if scene.offset_mask is None else scene.offset_mask
    ai, ki = np.nonzero((op > 0) & live)
    s = np.exp(scene.scalings.astype(np.float64))
    means = p[ai] + scene.offsets[ai, ki] * s[ai, :3]
    scales = s[ai, 3:] / (1 + np.exp(-cov[ai, ki, :3]))
    q = cov[ai, ki, 3:]
    return dict(means=means, scales=scales, quats=q / np.linalg.norm(q, axis=1, keepdims=True),
                opacities=op[ai, ki], colors=col[ai, ki], anchor=ai, offset=ki)


@pytest.mark.parametrize("extra_in,mask,bank", [(4, False, False), (3, False, False), (4, True, False),
                                                (4, False, True), (3, True, True)])
def test_matches_scaffold_gs_reference(extra_in, mask, bank):
    scene = _scene(extra_in=extra_in, mask=mask, bank=bank)
    cam = Camera.look_at([2.0, -3.0, 1.5], [0.0, 0.0, 0.0], width=64, height=48)
    ng = generate_neural_gaussians(SceneTensors.from_scene(scene, F64), cam, cull=False)
    ref = _reference(scene, cam)
    assert ng.num_gaussians == len(ref["anchor"]) > 0
    np.testing.assert_array_equal(ng.anchor_index.numpy(), ref["anchor"])
    np.testing.assert_array_equal(ng.offset_index.numpy(), ref["offset"])
    for name, t in (("means", ng.means), ("scales", ng.scales), ("quats", ng.quats), ("opacities", ng.opacities),
                    ("colors", ng.colors)):
        np.testing.assert_allclose(t.detach().numpy(), ref[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert (ng.opacities > 0).all()


def test_frustum_culling_runs_mlps_only_on_anchors_in_view():
    # tiny anchors (log scale -12): the bounding spheres are points, so "in view" is the
    # anchor centre projecting into the image widened by the margin
    scene = _scene(n=400, log_scale=-12.0)
    st = SceneTensors.from_scene(scene)
    cam = Camera.look_at([0.3, -1.5, 0.3], [0.4, 0.0, 0.3], width=60, height=40, fov_x_deg=40)
    seen = []
    st.mlps["opacity"].register_forward_hook(lambda m, i, o: seen.append(i[0].shape[0]) and None)
    ng = generate_neural_gaussians(st, cam, margin=0.1)
    uv, z = cam.project(scene.positions())
    inside = ((z > cam.near) & (uv[:, 0] >= -6) & (uv[:, 0] <= 66) & (uv[:, 1] >= -4) & (uv[:, 1] <= 44))
    assert 0 < inside.sum() < 0.5 * len(z)
    assert seen == [int(inside.sum())] == [ng.stats["anchors_in_view"]]
    assert set(ng.anchor_index.tolist()) <= set(np.nonzero(inside)[0].tolist())


def test_culling_does_not_change_the_image():
    scene = make_procedural_scene(3000, seed=1)
    st = SceneTensors.from_scene(scene)
    cam = Camera.look_at([0.55, -0.6, 0.4], [0.55, 0.0, 0.1], width=64, height=48, fov_x_deg=40)
    a = render_scene(st, cam, background=[1.0, 1.0, 1.0])
    b = render_scene(st, cam, cull=False, background=[1.0, 1.0, 1.0])
    assert a.stats["ng_anchors_in_view"] < 0.7 * b.stats["ng_anchors_in_view"]
    assert a.stats["ng_gaussians"] < b.stats["ng_gaussians"]
    torch.testing.assert_close(a.image, b.image, atol=1e-5, rtol=0)


def test_masked_offsets_are_never_built():
    scene = _scene(n=60, mask=True)
    scene.offset_mask[:10] = False  # anchors with no live offset: no MLP runs on them
    st = SceneTensors.from_scene(scene)
    seen = {}
    for role in ("opacity", "cov", "color"):
        st.mlps[role].register_forward_hook(lambda m, i, o, r=role: seen.update({r: i[0].shape[0]}) and None)
    cam = Camera.look_at([2.0, -3.0, 1.5], [0.0, 0.0, 0.0], width=64, height=48)
    ng = generate_neural_gaussians(st, cam, cull=False)
    live = scene.offset_mask[ng.anchor_index.numpy(), ng.offset_index.numpy()]
    assert live.all() and ng.num_gaussians > 0
    n_live = int(scene.offset_mask.any(axis=1).sum())
    assert n_live < 50
    assert seen["opacity"] == n_live == ng.stats["anchors_run"]
    assert seen["cov"] == seen["color"] == ng.stats["anchors_with_gaussians"] <= n_live
    assert not (ng.anchor_index < 10).any()


def test_gradients_reach_anchor_attributes_and_mlps():
    scene = _scene(n=6, c=4, k=2, seed=3, log_scale=-1.0)
    cam = Camera.look_at([0.2, -1.8, 0.5], [0.0, 0.0, 0.0], width=16, height=12, fov_x_deg=60)
    base = SceneTensors.from_scene(scene, F64)
    w = torch.randn(12, 16, 3, generator=torch.Generator().manual_seed(0), dtype=F64)

    def loss_of(pos, feat, scal, offs):
        st = SceneTensors(pos, feat, scal, offs, dict(base.mlps.items()))
        return (render_scene(st, cam, dtype=F64, tile_size=8).image * w).sum()

    args = [base.positions.clone().requires_grad_(), base.features.clone().requires_grad_(),
            base.scalings.clone().requires_grad_(), base.offsets.clone().requires_grad_()]
    assert torch.autograd.gradcheck(loss_of, args, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)
    # MLP weights: autograd against central differences on a few entries
    st = SceneTensors.from_scene(scene, F64, requires_grad=True)
    loss = (render_scene(st, cam, dtype=F64, tile_size=8).image * w).sum()
    loss.backward()
    for role in ("opacity", "cov", "color"):
        weight = st.mlps[role].layers[0].weight
        assert weight.grad is not None and weight.grad.abs().sum() > 0, role
        for (i, j) in ((0, 0), (1, 2)):
            with torch.no_grad():
                weight[i, j] += 1e-6
                lp = (render_scene(st, cam, dtype=F64, tile_size=8).image * w).sum()
                weight[i, j] -= 2e-6
                lm = (render_scene(st, cam, dtype=F64, tile_size=8).image * w).sum()
                weight[i, j] += 1e-6
            assert float(weight.grad[i, j]) == pytest.approx(float(lp - lm) / 2e-6, rel=1e-4, abs=1e-6), role


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_hard_case_huge_anchor_scalings_stay_finite(dtype):
    """Anchor log-scalings >= 89 overflow exp in float32; they are clamped (at 80) before exp, as
    the culling radii are, so the image and every gradient stay finite."""
    scene = _scene(n=20, c=8, k=3, seed=1, log_scale=-1.0)
    scene.scalings[:3] = 89.0  # offsets and Gaussian scales overflow
    scene.scalings[3:6, :3] = 95.0  # offsets only
    scene.scalings[6:8, 3:] = 200.0  # Gaussian scales only
    scene.scalings[8] = -200.0  # underflow to zero
    cam = Camera.look_at([0.2, -1.8, 0.5], [0.0, 0.0, 0.0], width=24, height=16, fov_x_deg=60)
    for cull in (True, False):
        st = SceneTensors.from_scene(scene, dtype, requires_grad=True)
        r = render_scene(st, cam, cull=cull, dtype=dtype, background=[0.5, 0.5, 0.5])
        assert torch.isfinite(r.image).all() and torch.isfinite(r.alpha).all()
        assert r.stats["ng_gaussians"] > 0 and r.stats["rasterized"] > 0
        (r.image * torch.linspace(0.5, 1.5, 3, dtype=dtype)).sum().backward()
        grads = {n: p.grad for n, p in st.named_parameters() if p.grad is not None}
        assert {"positions", "features", "scalings", "offsets"} <= set(grads)
        for name, g in grads.items():
            assert torch.isfinite(g).all(), (cull, name)


def test_mlp_shape_errors():
    scene = _scene(c=8, k=3)
    bad = dict(scene.mlps)
    bad["color"] = _mlp(np.random.default_rng(0), [8 + 5, 8, 9], "sigmoid")  # appearance embedding
    scene.mlps = bad
    with pytest.raises(InputError, match="color MLP takes 13 inputs"):
        SceneTensors.from_scene(scene)
    scene.mlps = {k: v for k, v in bad.items() if k != "cov"}
    with pytest.raises(InputError, match="no cov MLP"):
        SceneTensors.from_scene(scene)


def test_torch_mlp_round_trip():
    m = _mlp(np.random.default_rng(1), [7, 5, 4], "tanh")
    t = TorchMLP.from_render_mlp(m)
    x = np.random.default_rng(2).normal(size=(10, 7)).astype(np.float32)
    np.testing.assert_allclose(t(torch.from_numpy(x)).detach().numpy(), m(x), rtol=1e-5, atol=1e-6)
    back = t.to_render_mlp()
    for a, b in zip(back.weights, m.weights):
        np.testing.assert_array_equal(a, b)
