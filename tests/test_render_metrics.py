"""PSNR, SSIM (3DGS evaluation convention), LPIPS availability."""

import logging
import math

import numpy as np
import pytest
import torch
from scipy.ndimage import correlate

from lghcc.render import metrics


def _ssim_numpy(a, b):
    """SSIM written out independently: 11x11 Gaussian (sigma 1.5), zero padding, per channel."""
    x = np.arange(11) - 5
    g = np.exp(-x ** 2 / 4.5)
    g /= g.sum()
    win = np.outer(g, g)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    maps = []
    for ch in range(a.shape[2]):
        f = lambda t: correlate(t, win, mode="constant", cval=0.0)  # noqa: E731
        x1, y1 = a[..., ch].astype(np.float64), b[..., ch].astype(np.float64)
        mu1, mu2 = f(x1), f(y1)
        s11, s22, s12 = f(x1 * x1) - mu1 ** 2, f(y1 * y1) - mu2 ** 2, f(x1 * y1) - mu1 * mu2
        maps.append(((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 ** 2 + mu2 ** 2 + c1) * (s11 + s22 + c2)))
    return float(np.mean(maps))


def test_psnr_known_values():
    a = np.zeros((4, 5, 3), np.float32)
    b = a + 0.1
    assert metrics.psnr(a, b) == pytest.approx(20.0, abs=1e-5)
    assert metrics.psnr(a, a) == math.inf
    assert float(metrics.psnr_torch(torch.zeros(2, 2, 3), torch.full((2, 2, 3), 0.01))) == pytest.approx(40.0, abs=1e-4)


def test_ssim_matches_independent_implementation():
    rng = np.random.default_rng(0)
    a = rng.random((37, 29, 3)).astype(np.float32)
    b = np.clip(a + 0.1 * rng.normal(size=a.shape), 0, 1).astype(np.float32)
    assert metrics.ssim(a, b) == pytest.approx(_ssim_numpy(a, b), abs=1e-10)
    assert metrics.ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert metrics.ssim(a, b) < metrics.ssim(a, np.clip(a + 0.01, 0, 1))
    valid = metrics.ssim(a, b, padding="valid")
    assert 0 < valid < 1 and valid != metrics.ssim(a, b)


def test_ssim_is_differentiable():
    a = torch.rand(16, 16, 3, dtype=torch.float64)
    b = torch.rand(16, 16, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda y: metrics.ssim_torch(a, y), (b,), fast_mode=True)


def test_shape_mismatch():
    with pytest.raises(ValueError):
        metrics.psnr(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))


def test_lpips_is_none_with_a_message_when_unavailable(caplog):
    ok, why = metrics.lpips_status()
    if ok:
        pytest.skip("LPIPS and its weights are present here")
    with caplog.at_level(logging.WARNING):
        assert metrics.lpips(np.zeros((8, 8, 3), np.float32), np.zeros((8, 8, 3), np.float32)) is None
    assert "LPIPS skipped" in caplog.text and why in caplog.text
