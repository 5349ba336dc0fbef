import numpy as np
import torch

from lghcc.render.camera import Camera
from lghcc.render.importance import gaussian_contributions
from lghcc.render.rasterizer import rasterize


def _gaussians(n, seed=0):
    rng = np.random.default_rng(seed)
    means = torch.tensor(rng.normal(size=(n, 3)) * 0.3, dtype=torch.float32)
    quats = torch.tensor(rng.normal(size=(n, 4)), dtype=torch.float32)
    quats = quats / quats.norm(dim=1, keepdim=True)
    scales = torch.tensor(rng.uniform(0.03, 0.2, size=(n, 3)), dtype=torch.float32)
    op = torch.tensor(rng.uniform(0.05, 0.99, size=n), dtype=torch.float32)
    return means, quats, scales, op


def test_contributions_add_up_to_the_rendered_alpha():
    g = _gaussians(60)
    cams = [Camera.look_at((0, -4, 0), (0, 0, 0), width=40, height=32),
            Camera.look_at((3, 0, 2), (0, 0, 0), width=24, height=24)]
    c = gaussian_contributions(*g, cams)
    alpha = sum(rasterize(*g, torch.zeros(60, 1), cam).alpha.double().sum().item() for cam in cams)
    assert c.shape == (60,) and (c >= 0).all()
    np.testing.assert_allclose(c.sum(), alpha, rtol=1e-5)


def test_a_hidden_or_transparent_gaussian_contributes_nothing():
    means, quats, scales, op = _gaussians(3)
    means[:] = torch.tensor([[0.0, 0, 0], [0, 2.0, 0], [0, 0, 0]])  # 1 behind 0 (seen from -y), 2 transparent
    scales[:] = 0.3
    scales[0] = 1.0  # wide enough to hide Gaussian 1 entirely
    op[:] = torch.tensor([0.99, 0.99, 0.0])
    cam = Camera.look_at((0, -4, 0), (0, 0, 0), width=16, height=16)
    c = gaussian_contributions(means, quats, scales, op, [cam])
    assert c[0] > 1 and c[1] < 0.05 * c[0] and c[2] == 0


def test_region_weights_equal_the_gradient_of_each_region_of_the_image():
    """compositing_weights(regions=2): per Gaussian, d(sum of each quarter of the image) / d(grey
    level), the quarters being whole tiles (4 px: 12 x 10 tiles, split 6 | 6 and 5 | 5), and their
    sum the whole picture's weights."""
    from lghcc.render.rasterizer import compositing_weights

    g = _gaussians(80, seed=3)
    cam = Camera.look_at((1, -4, 1), (0, 0, 0), width=48, height=40)
    regions = compositing_weights(*g, cam, regions=2, tile_size=4)
    assert regions.shape == (80, 4)
    for r, (rows, cols) in enumerate([(slice(0, 20), slice(0, 24)), (slice(0, 20), slice(24, 48)),
                                      (slice(20, 40), slice(0, 24)), (slice(20, 40), slice(24, 48))]):
        grey = torch.ones(80, 1, requires_grad=True)
        rasterize(*g, grey, cam, tile_size=4).image[rows, cols].sum().backward()
        np.testing.assert_allclose(regions[:, r].numpy(), grey.grad[:, 0].double().numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(regions.sum(1).numpy(), compositing_weights(*g, cam, tile_size=4).numpy(), rtol=1e-12)
    assert (regions > 0).sum() > 80  # Gaussians spanning several regions share out among them


def test_forward_weights_equal_the_gradient_of_the_image():
    """compositing_weights (one forward pass) = d(sum of the image) / d(grey level of each Gaussian)."""
    from lghcc.render.rasterizer import compositing_weights

    g = _gaussians(80, seed=3)
    cam = Camera.look_at((1, -4, 1), (0, 0, 0), width=48, height=40)
    grey = torch.ones(80, 1, requires_grad=True)
    rasterize(*g, grey, cam).image.sum().backward()
    np.testing.assert_allclose(compositing_weights(*g, cam).numpy(), grey.grad[:, 0].double().numpy(),
                               rtol=1e-5, atol=1e-6)
