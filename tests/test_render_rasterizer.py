"""The CPU rasterizer: closed-form image, agreement with the plain definition, gradients,
hard cases."""

import functools
import math

import numpy as np
import pytest
import torch

from lghcc.render.camera import Camera
from lghcc.render.rasterizer import (ALPHA_MAX, composite_reference, compositing_weights, project_gaussians, rasterize,
                                     rasterize_gsplat, gsplat_available)

F64 = torch.float64


def _head_on_camera(w=40, h=30, f=50.0):
    return Camera(np.eye(4), f, f, w / 2, h / 2, w, h, near=0.01, far=100.0)


def _random_gaussians(m, seed=0, dtype=F64, spread=0.5, scale=(0.02, 0.22), opac=(0.1, 0.9)):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(m, 3, generator=g, dtype=dtype) * spread
    quats = torch.randn(m, 4, generator=g, dtype=dtype)
    scales = torch.rand(m, 3, generator=g, dtype=dtype) * (scale[1] - scale[0]) + scale[0]
    op = torch.rand(m, generator=g, dtype=dtype) * (opac[1] - opac[0]) + opac[0]
    col = torch.rand(m, 3, generator=g, dtype=dtype)
    return [means, quats, scales, op, col]


def _reference(means, quats, scales, op, col, cam, bg, sigma_cutoff=3.0):
    """The definition: every Gaussian over every pixel, one at a time in depth order."""
    proj = project_gaussians(means, quats, scales, cam)
    o = op.detach()
    thr = torch.minimum(torch.log(255 * o.clamp_min(1e-30)), torch.tensor(0.5 * sigma_cutoff ** 2, dtype=F64))
    thr = torch.where(proj.valid & (o * 255 >= 1), thr, torch.tensor(-1.0, dtype=F64))
    order = torch.argsort(proj.depths.detach(), stable=True)
    order = order[proj.valid[order]]
    feats = torch.cat([col, torch.ones(len(op), 1, dtype=col.dtype)], 1)
    acc = composite_reference(proj.means2d[order], proj.conics[order], op[order], feats[order], thr[order],
                              cam.width, cam.height)
    return acc[..., :3] + (1 - acc[..., 3:]) * bg, acc[..., 3]


def test_isotropic_gaussian_head_on_matches_closed_form():
    cam = _head_on_camera(41, 31)  # odd sizes: the principal point is a pixel centre
    z, sigma, o = 4.0, 0.1, 0.8
    color, bg = torch.tensor([[0.9, 0.2, 0.1]]), torch.tensor([0.1, 0.3, 0.5])
    r = rasterize(torch.tensor([[0.0, 0.0, z]]), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), sigma),
                  torch.tensor([o]), color, cam, background=bg)
    s2 = (cam.fx * sigma / z) ** 2 + 0.3  # EWA variance in px^2, with the 0.3 px^2 dilation
    ys, xs = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    power = 0.5 * ((xs - cam.cx) ** 2 + (ys - cam.cy) ** 2) / s2
    alpha = np.minimum(ALPHA_MAX, o * np.exp(-power))
    alpha[power > min(4.5, math.log(255 * o))] = 0.0
    want = alpha[..., None] * color.numpy() + (1 - alpha[..., None]) * bg.numpy()
    np.testing.assert_allclose(r.image.numpy(), want, atol=2e-5)
    np.testing.assert_allclose(r.alpha.numpy(), alpha, atol=2e-5)
    assert r.alpha.max() == pytest.approx(o, abs=1e-4)  # the centre pixel sits on the mean
    # the footprint is the 3-sigma disc: nothing outside it
    assert (r.alpha.numpy()[power > 4.5] == 0).all() and (r.alpha.numpy()[power < 4.4] > 0).all()


def test_opaque_gaussian_clamps_alpha_and_terminates():
    cam = _head_on_camera(16, 16)
    # 6 identical opaque layers: alpha 0.99 each; T after 2 layers = 1e-4 -> the second would
    # bring T below... 0.01^2 = 1e-4 is not < 1e-4, so 2 are drawn, the third stops it.
    m = 6
    means = torch.tensor([[0.0, 0.0, 2.0 + 0.1 * i] for i in range(m)], dtype=F64)
    col = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]] * 2, dtype=F64)
    r = rasterize(means, torch.tensor([[1.0, 0, 0, 0]] * m, dtype=F64), torch.full((m, 3), 1.0, dtype=F64),
                  torch.ones(m, dtype=F64), col, cam, background=torch.tensor([1.0, 1.0, 1.0], dtype=F64))
    centre = r.image[8, 8]
    t1 = 1 - 0.99
    want = torch.tensor([0.99, t1 * 0.99, 0.0], dtype=F64) + (1 - (0.99 + t1 * 0.99))
    # the 1e-4 test is on T after the Gaussian: 0.01 * 0.01 = 1e-4 passes (not < 1e-4)
    torch.testing.assert_close(centre, want, atol=1e-12, rtol=0)


@pytest.mark.parametrize("tile_size,chunk", [(16, 1 << 21), (8, 64 * 16), (4, 16 * 40)])
def test_tiled_path_matches_definition_forward_and_backward(tile_size, chunk):
    cam = Camera.look_at([0.2, -3, 0.5], [0, 0, 0], width=37, height=29, fov_x_deg=50)
    params = [p.requires_grad_() for p in _random_gaussians(80, seed=1, scale=(0.1, 0.5), opac=(0.5, 1.0))]
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=F64)
    r = rasterize(*params, cam, background=bg, tile_size=tile_size, chunk_elements=chunk)
    img, alpha = _reference(*params, cam, bg)
    torch.testing.assert_close(r.image, img, atol=1e-12, rtol=0)
    torch.testing.assert_close(r.alpha, alpha, atol=1e-12, rtol=0)
    w = torch.randn(img.shape, generator=torch.Generator().manual_seed(3), dtype=F64)
    g1 = torch.autograd.grad((r.image * w).sum() + 0.5 * r.alpha.sum(), params)
    g2 = torch.autograd.grad((img * w).sum() + 0.5 * alpha.sum(), params)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colors"), g1, g2):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-9, msg=name)
        assert b.abs().sum() > 0, name


def test_gradients_match_finite_differences():
    cam = Camera.look_at([0.1, -2.5, 0.3], [0, 0, 0], width=18, height=14, fov_x_deg=45)
    params = [p.requires_grad_() for p in _random_gaussians(5, seed=7, spread=0.25, scale=(0.15, 0.3),
                                                           opac=(0.3, 0.8))]
    bg = torch.tensor([0.3, 0.6, 0.9], dtype=F64)

    def f(*ps):
        r = rasterize(*ps, cam, background=bg, tile_size=8, render_depth=True)
        return r.image, r.alpha, r.depth

    assert torch.autograd.gradcheck(f, params, eps=1e-6, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_image_does_not_depend_on_tile_size_float32():
    cam = Camera.look_at([0, -3, 0.5], [0, 0, 0], width=50, height=41, fov_x_deg=50)
    params = _random_gaussians(300, seed=2, dtype=torch.float32, scale=(0.01, 0.2))
    imgs = [rasterize(*params, cam, tile_size=t).image for t in (16, 8, 32, 4, None)]
    for im in imgs[1:]:
        torch.testing.assert_close(im, imgs[0], atol=2e-5, rtol=0)


@pytest.mark.parametrize("opac", [(0.05, 0.3), (0.6, 1.0)])
def test_long_tiles_composited_in_parts_keep_every_bit(monkeypatch, opac):
    """Batches of long tiles are composited in parts along depth, dropping the tiles whose
    transmittance ran out or whose Gaussians did (``_batch_weights_in_parts``): the image, the
    alpha, the compositing weights and the gradients have the bits of the one pass over each whole
    batch, with faint Gaussians (few tiles used up) and near-opaque ones (most)."""
    from lghcc.render import rasterizer as R

    cam = Camera.look_at([0, -3, 0.5], [0, 0, 0], width=24, height=20, fov_x_deg=50)
    params = _random_gaussians(3000, seed=5, dtype=torch.float32, spread=0.3, scale=(0.01, 0.3), opac=opac)
    bg = torch.tensor([0.2, 0.3, 0.4])

    def run():
        ps = [p.clone().requires_grad_() for p in params]
        r = rasterize(*ps, cam, background=bg, tile_size=4)
        grads = torch.autograd.grad((r.image ** 2).sum() + r.alpha.sum(), ps)
        return [r.image, r.alpha, compositing_weights(*params[:4], cam, tile_size=4), *grads], r.stats

    parted, stats = run()
    assert stats["tile_pairs"] / (6 * 5) >= 2 * R.PART_GAUSSIANS  # the tiles are long enough to be parted
    monkeypatch.setattr(R, "PART_GAUSSIANS", 10 ** 9)  # every batch in one pass
    whole, _ = run()
    for name, a, b in zip(("image", "alpha", "weights", "means", "quats", "scales", "opacities", "colors"),
                          parted, whole):
        assert torch.equal(a, b), name


def test_gaussians_that_cannot_reach_the_image_are_culled_before_the_projection(monkeypatch):
    """A narrow view of a wide cloud: the Gaussians whose footprint cannot reach the image are
    culled before the projection (``_may_reach_image``), large ones just off the edge that reach
    into it are not; image, alpha, depth, gradients, compositing weights and the counts have the
    bits of projecting them all."""
    from lghcc.render import rasterizer as R

    cam = Camera.look_at([0, -3, 0.2], [0, 0, 0], width=30, height=22, fov_x_deg=12)
    params = _random_gaussians(4000, seed=6, dtype=torch.float32, spread=1.0, scale=(0.005, 0.25), opac=(0.2, 0.95))

    def run():
        ps = [p.clone().requires_grad_() for p in params]
        r = R.rasterize(*ps, cam, background=torch.tensor([0.1, 0.2, 0.3]), render_depth=True)
        grads = torch.autograd.grad((r.image ** 2).sum() + r.alpha.sum() + 1e-3 * r.depth.sum(), ps)
        return [r.image, r.alpha, r.depth, R.compositing_weights(*params[:4], cam), *grads], r.stats

    rows = R._may_reach_image(params[0], params[2], cam, 3.0, 0.3, None)
    assert rows is not None and 0 < rows.numel() < 0.5 * params[0].shape[0]
    culled, stats = run()
    monkeypatch.setattr(R, "_may_reach_image", lambda *a: None)
    every, stats_every = run()
    assert stats == stats_every and stats["rasterized"] > rows.numel() / 4
    for name, a, b in zip(("image", "alpha", "depth", "weights", "means", "quats", "scales", "opacities", "colors"),
                          culled, every):
        assert torch.equal(a, b), name


@pytest.mark.parametrize("scale,expected", [((0.0005, 0.001), 4), ((0.5, 0.8), 16)])
def test_the_tile_size_follows_the_footprints(scale, expected):
    """Footprints of a pixel or two get 4-pixel tiles (a 16-pixel tile would compute 256 pixels
    for each); footprints wider than the image get 16-pixel tiles (fewer pairs); the chosen
    tiles draw the same image as fixed ones."""
    cam = Camera.look_at([0, -3, 0.5], [0, 0, 0], width=96, height=80, fov_x_deg=50)
    params = _random_gaussians(400, seed=4, dtype=torch.float32, scale=scale)
    auto = rasterize(*params, cam)
    assert auto.stats["tile_size"] == expected
    torch.testing.assert_close(auto.image, rasterize(*params, cam, tile_size=16).image, atol=2e-5, rtol=0)
    weights = compositing_weights(*params[:4], cam)
    torch.testing.assert_close(weights, compositing_weights(*params[:4], cam, tile_size=8), atol=1e-4, rtol=1e-4)


def test_depth_is_alpha_weighted_camera_depth():
    cam = _head_on_camera()
    r = rasterize(torch.tensor([[0.0, 0, 3.0]]), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.1),
                  torch.tensor([0.5]), torch.ones(1, 3), cam, render_depth=True)
    torch.testing.assert_close(r.depth, 3.0 * r.alpha)


def _hard_case_gaussians(dtype):
    rows = [  # mean, scale, opacity
        ([0.0, 0.0, -1.0], [0.1] * 3, 0.8),  # behind the camera
        ([0.0, 0.0, 0.0], [0.1] * 3, 0.8),  # at the camera centre
        ([0.0, 0.0, 0.005], [0.1] * 3, 0.8),  # in front, but nearer than the near plane
        ([0.05, 0.0, 2.0], [1e-8] * 3, 0.9),  # near-zero scale
        ([0.0, 0.1, 3.0], [1e4] * 3, 0.5),  # huge scale
        ([0.0, 0.0, 0.5], [10.0] * 3, 0.3),  # the camera is inside it
        ([0.1, 0.1, 2.0], [1e4, 1e-8, 1e-8], 0.7),  # huge and tiny axes at once
        ([0.0, -0.1, 2.5], [0.2] * 3, 0.0),  # opacity exactly 0
        ([0.0, 0.05, 2.2], [0.2] * 3, 1.0),  # opacity exactly 1
        ([1e6, 1e6, 1.0], [0.1] * 3, 0.9),  # far off-screen
        ([0.0, 0.0, 1e-3], [1e3] * 3, 1.0),  # huge, just in front of the centre
    ]
    m = len(rows)
    means = torch.tensor([r[0] for r in rows], dtype=dtype)
    scales = torch.tensor([r[1] for r in rows], dtype=dtype)
    op = torch.tensor([r[2] for r in rows], dtype=dtype)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * (m - 1) + [[0.0, 0.0, 0.0, 0.0]], dtype=dtype)  # one zero quat
    col = torch.rand(m, 3, generator=torch.Generator().manual_seed(0), dtype=dtype)
    return [means, quats, scales, op, col]


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_hard_cases_stay_finite(dtype):
    cam = _head_on_camera(48, 40)
    params = [p.requires_grad_() for p in _hard_case_gaussians(dtype)]
    r = rasterize(*params, cam, background=torch.tensor([0.5, 0.5, 0.5]), render_depth=True)
    for t in (r.image, r.alpha, r.depth):
        assert torch.isfinite(t).all()
    assert (r.alpha >= 0).all() and (r.alpha <= 1).all()
    (r.image.sum() + r.alpha.sum() + r.depth.sum()).backward()
    for p in params:
        assert torch.isfinite(p.grad).all()
    # each case on its own
    for i in range(len(params[0])):
        sub = [p.detach()[i:i + 1].clone().requires_grad_() for p in params]
        ri = rasterize(*sub, cam)
        assert torch.isfinite(ri.image).all() and torch.isfinite(ri.alpha).all()
        (ri.image.sum() + ri.alpha.sum()).backward()
        assert all(torch.isfinite(p.grad).all() for p in sub)


def test_hard_cases_drawn_or_not():
    cam = _head_on_camera(48, 40)
    means, quats, scales, op, col = _hard_case_gaussians(torch.float32)
    proj = project_gaussians(means, quats, scales, cam)
    assert proj.valid.tolist()[:3] == [False, False, False]  # behind, at the centre, before near
    assert torch.isfinite(proj.conics).all() and torch.isfinite(proj.means2d).all()
    # opacity 0 draws nothing, opacity 1 is clamped to 0.99
    r0 = rasterize(means[7:8], quats[7:8], scales[7:8], op[7:8], col[7:8], cam)
    assert r0.alpha.abs().max() == 0 and r0.stats["rasterized"] == 0
    r1 = rasterize(means[8:9], quats[8:9], scales[8:9], op[8:9], col[8:9], cam)
    assert r1.alpha.max() == pytest.approx(ALPHA_MAX, abs=1e-6)
    # near-zero scale: the dilation leaves a 0.3 px^2 blob, about one pixel
    r2 = rasterize(means[3:4], quats[3:4], scales[3:4], op[3:4], col[3:4], cam)
    assert 0 < int((r2.alpha > 0).sum()) <= 16
    # camera inside a huge Gaussian: it covers the whole image
    r3 = rasterize(means[5:6], quats[5:6], scales[5:6], op[5:6], col[5:6], cam)
    assert (r3.alpha > 0.25).all()


def test_zero_gaussians_give_background():
    cam = _head_on_camera(20, 10)
    e = [torch.zeros(0, 3, requires_grad=True), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0),
         torch.zeros(0, 3, requires_grad=True)]
    r = rasterize(*e, cam, background=torch.tensor([0.1, 0.2, 0.3]))
    assert r.image.shape == (10, 20, 3) and r.stats["tile_pairs"] == 0
    torch.testing.assert_close(r.image, torch.tensor([0.1, 0.2, 0.3]).expand(10, 20, 3))
    r.image.sum().backward()
    assert e[0].grad.shape == (0, 3)


def test_bad_shapes_are_rejected():
    cam = _head_on_camera()
    p = _random_gaussians(3, dtype=torch.float32)
    with pytest.raises(ValueError):
        rasterize(p[0], p[1][:2], p[2], p[3], p[4], cam)
    with pytest.raises(ValueError):
        rasterize(*p, cam, background=torch.zeros(4))


def test_gsplat_backend_is_guarded():
    if gsplat_available():
        pytest.skip("gsplat and CUDA present: the guard is not exercised")
    p = _random_gaussians(3, dtype=torch.float32)
    with pytest.raises(RuntimeError, match="gsplat|CUDA"):
        rasterize_gsplat(*p, _head_on_camera())


@pytest.mark.slow
def test_speed_100k_gaussians_800px():
    """The design target: 100k Gaussians at 800x800 forward in under 2 s (2 cores)."""
    import time
    cam = Camera.look_at([0, -4.0, 1.0], [0, 0, 0.3], width=800, height=800, fov_x_deg=40)
    g = torch.Generator().manual_seed(0)
    d = torch.randn(100_000, 3, generator=g)
    means = d / d.norm(dim=1, keepdim=True) * torch.tensor([0.65, 1.1, 0.6]) + torch.tensor([0, 0, 0.35])
    scales = torch.rand(100_000, 3, generator=g) * 0.008 + 0.004
    args = [means, torch.randn(100_000, 4, generator=g), scales, torch.rand(100_000, generator=g),
            torch.rand(100_000, 3, generator=g)]
    rasterize(*args, cam)
    t = time.perf_counter()
    rasterize(*args, cam)
    assert time.perf_counter() - t < 2.0


def test_jacobian_clamp_matches_3dgs_and_gsplat():
    """x/z is clamped to the image edge + 0.3 tan(fov_x / 2) (1.3x the half field of view for a
    centred principal point) in the EWA Jacobian, as 3DGS and gsplat do."""
    cam = _head_on_camera(40, 30, 50.0)  # tan(fov_x / 2) = 0.4, limit 0.52
    z, sigma = 2.0, 0.1
    for xz in (0.3, 2.0, -2.0):  # inside the limit, beyond it on either side
        proj = project_gaussians(torch.tensor([[xz * z, 0.0, z]], dtype=F64), torch.tensor([[1.0, 0, 0, 0]], dtype=F64),
                                 torch.full((1, 3), sigma, dtype=F64), cam)
        t = max(-0.52, min(0.52, xz))
        want = sigma ** 2 * (cam.fx / z) ** 2 * (1 + t * t) + 0.3  # J = f/z [1, 0, -t]
        assert float(proj.cov2d[0, 0]) == pytest.approx(want, rel=1e-12)


def test_backend_selection(monkeypatch):
    import lghcc.render.rasterizer as R

    for avail, want in ((False, "torch"), (True, "gsplat")):
        monkeypatch.setattr(R, "gsplat_available", lambda a=avail: a)
        assert R.select_backend("auto") == want
        assert R.select_backend("torch") == "torch"
    monkeypatch.setattr(R, "gsplat_available", lambda: False)
    with pytest.raises(RuntimeError, match="lghcc\\[gsplat\\].*CUDA"):
        R.select_backend("gsplat")
    with pytest.raises(ValueError, match="unknown backend 'cuda'"):
        R.select_backend("cuda")


def test_auto_backend_without_cuda_is_the_cpu_path():
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.render.rasterizer import render_scene

    if gsplat_available():
        pytest.skip("gsplat and CUDA present: auto selects gsplat (see test_gsplat_matches_cpu_rasterizer)")
    scene = make_procedural_scene(num_anchors=200, seed=1)
    cam = Camera.look_at([0.0, -3.0, 1.0], [0, 0, 0], width=32, height=24, fov_x_deg=50)
    a = render_scene(scene, cam, background=[1.0, 1.0, 1.0])
    b = render_scene(scene, cam, background=[1.0, 1.0, 1.0], backend="torch")
    assert a.stats["backend"] == "torch" and a.image.device.type == "cpu"
    torch.testing.assert_close(a.image, b.image, rtol=0, atol=0)


# --- gsplat against the CPU rasterizer --------------------------------------------------------
# Stated agreement (float32 gsplat vs this module), per scene, image and alpha:
#   footprints made equal (sigma_cutoff = GSPLAT_SIGMA_CUTOFF, sqrt(2 ln 255) = 3.33):
#       max |difference| <= GSPLAT_MAX_ABS (0.02, ~5/255) and PSNR >= GSPLAT_MIN_PSNR (50 dB);
#   the CPU default sigma_cutoff = 3: max |difference| <= 0.06 and PSNR >= 40 dB
#       (pixels between 3 and 3.33 sigma lack alpha <= 0.011 per Gaussian).
# Opacities stay <= 0.95 so the alpha clamps (0.99 here, 0.999 in gsplat) never act. Bounds
# derived from the known differences (a rounding at the alpha >= 1/255 threshold moves a
# pixel by <= 1/255); not yet measured: no GPU was available when this test was written.
GSPLAT_MAX_ABS, GSPLAT_MIN_PSNR = 0.02, 50.0


def _gsplat_scene(kind: str, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    m = {"isotropic": 300, "anisotropic": 300, "overlapping": 80, "off_screen": 120}[kind]
    means = torch.randn(m, 3, generator=g) * torch.tensor([0.6, 0.45, 0.3]) + torch.tensor([0.0, 0.0, 3.0])
    quats = torch.randn(m, 4, generator=g)
    scales = torch.rand(m, 3, generator=g) * 0.08 + 0.01
    op = torch.rand(m, generator=g) * 0.85 + 0.1  # [0.1, 0.95]
    col = torch.rand(m, 3, generator=g)
    if kind == "isotropic":
        scales = scales[:, :1].repeat(1, 3)
    elif kind == "anisotropic":  # needles and discs, random orientations: catches quaternion order
        scales = scales * torch.tensor([12.0, 1.0, 0.2])
    elif kind == "overlapping":  # a stack along the view axis: depth order and early termination
        means = torch.randn(m, 3, generator=g) * 0.05 + torch.tensor([0.0, 0.0, 2.0])
        means[:, 2] += torch.linspace(0, 2, m)
        scales = torch.rand(m, 3, generator=g) * 0.15 + 0.1
        op = torch.rand(m, generator=g) * 0.35 + 0.6
    elif kind == "off_screen":  # centres beyond the left/right edges and the Jacobian clamp (x/z > 0.69)
        side = torch.where(torch.rand(m, generator=g) < 0.5, -1.0, 1.0)
        xz = 0.45 + torch.rand(m, generator=g) * 0.8
        means[:, 0] = side * xz * means[:, 2]
        scales = torch.rand(m, 3, generator=g) * 0.4 + 0.1
    return [means, quats, scales, op, col]


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return math.inf if mse == 0 else 10 * math.log10(1.0 / mse)


@pytest.mark.skipif(not gsplat_available(), reason="needs gsplat (pip install 'lghcc[gsplat]') and a CUDA GPU")
@pytest.mark.parametrize("kind", ["isotropic", "anisotropic", "overlapping", "off_screen"])
def test_gsplat_matches_cpu_rasterizer(kind):
    from lghcc.render.rasterizer import GSPLAT_SIGMA_CUTOFF

    cam = Camera(np.eye(4), 60.0, 60.0, 32.0, 24.0, 64, 48, near=0.1, far=100.0)  # tan(fov_x / 2) = 0.53
    bg = torch.tensor([0.2, 0.5, 0.8])
    params = _gsplat_scene(kind)
    for cutoff, max_abs, min_psnr in ((GSPLAT_SIGMA_CUTOFF, GSPLAT_MAX_ABS, GSPLAT_MIN_PSNR), (3.0, 0.06, 40.0)):
        ref = rasterize(*params, cam, background=bg, render_depth=True, sigma_cutoff=cutoff)
        got = rasterize_gsplat(*params, cam, background=bg, render_depth=True)
        assert got.image.device.type == "cpu" and got.image.dtype == torch.float32  # the caller's device and dtype
        assert got.image.shape == ref.image.shape and got.alpha.shape == ref.alpha.shape
        assert ref.alpha.max() > 0.5  # the scene is in view
        for a, b in ((got.image, ref.image), (got.alpha, ref.alpha)):
            assert float((a - b).abs().max()) <= max_abs, (kind, cutoff, float((a - b).abs().max()))
            assert _psnr(a, b) >= min_psnr, (kind, cutoff, _psnr(a, b))
        if cutoff == GSPLAT_SIGMA_CUTOFF:  # alpha-weighted depth, relative to the depth range
            assert float((got.depth - ref.depth).abs().max()) <= max_abs * float(params[0][:, 2].max())
    # gradients: colour gradients are the compositing weights summed over pixels
    w = torch.rand(48, 64, 3, generator=torch.Generator().manual_seed(1))
    grads = []
    for fn in (functools.partial(rasterize, sigma_cutoff=GSPLAT_SIGMA_CUTOFF), rasterize_gsplat):
        p = [t.clone().requires_grad_() for t in params]
        (fn(*p, cam, background=bg).image * w).sum().backward()
        assert all(torch.isfinite(t.grad).all() for t in p)
        grads.append(p[4].grad)
    torch.testing.assert_close(grads[1], grads[0], rtol=0.02, atol=0.05)
    # inputs on the GPU: results stay there
    cuda = [t.cuda() for t in params]
    r = rasterize_gsplat(*cuda, cam, background=bg.cuda())
    assert r.image.is_cuda
    torch.testing.assert_close(r.image.cpu(), rasterize_gsplat(*params, cam, background=bg).image)


@pytest.mark.skipif(not gsplat_available(), reason="needs gsplat (pip install 'lghcc[gsplat]') and a CUDA GPU")
def test_auto_backend_with_cuda_uses_gsplat_and_returns_cpu_images():
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.render.rasterizer import GSPLAT_SIGMA_CUTOFF, render_scene

    scene = make_procedural_scene(num_anchors=300, seed=2)
    cam = Camera.look_at([0.0, -3.0, 1.0], [0, 0, 0], width=64, height=48, fov_x_deg=50)
    a = render_scene(scene, cam, background=[1.0, 1.0, 1.0])
    b = render_scene(scene, cam, background=[1.0, 1.0, 1.0], backend="torch", sigma_cutoff=GSPLAT_SIGMA_CUTOFF)
    assert a.stats["backend"] == "gsplat" and a.image.device.type == "cpu"
    assert _psnr(a.image, b.image) >= 40.0  # neural Gaussians may reach opacity 1 (alpha clamp 0.999 vs 0.99)
