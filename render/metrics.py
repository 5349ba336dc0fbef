"""Image quality metrics (informative): PSNR, SSIM as in the 3DGS evaluation, LPIPS when
available.

Images are [H, W, C] or [N, H, W, C] tensors/arrays with values in [0, 1].

SSIM follows 3DGS ``utils/loss_utils.ssim`` (itself pytorch-ssim): 11x11 Gaussian window
with sigma 1.5, per channel, zero padding of 5 ("same" size), C1 = 0.01^2, C2 = 0.03^2,
mean over the whole map. ``padding='valid'`` gives the scikit-image style instead
(no padding, only full windows).
"""

from __future__ import annotations

import logging
import math
import os

import numpy as np
import torch
import torch.nn.functional as F

log = logging.getLogger(__name__)


def _nchw(x, dtype=None) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x)
    if not t.is_floating_point():
        raise ValueError("images must be float arrays in [0, 1]")
    if dtype is not None:
        t = t.to(dtype)
    if t.ndim == 3:
        t = t[None]
    if t.ndim != 4:
        raise ValueError(f"images must be [H, W, C] or [N, H, W, C], got {list(t.shape)}")
    return t.permute(0, 3, 1, 2)


def mse(a, b) -> float:
    x, y = _nchw(a, torch.float64), _nchw(b, torch.float64)
    if x.shape != y.shape:
        raise ValueError(f"image shapes differ: {list(x.shape)} vs {list(y.shape)}")
    return float(((x - y) ** 2).mean())


def psnr(a, b, max_value: float = 1.0) -> float:
    """10 log10(max^2 / MSE) over all pixels and channels (inf for identical images)."""
    m = mse(a, b)
    return math.inf if m == 0 else 10.0 * math.log10(max_value ** 2 / m)


def psnr_torch(a: torch.Tensor, b: torch.Tensor, max_value: float = 1.0) -> torch.Tensor:
    """Differentiable PSNR of two tensors of the same shape."""
    return 10.0 * torch.log10(max_value ** 2 / ((a - b) ** 2).mean().clamp_min(1e-20))


def gaussian_window(size: int = 11, sigma: float = 1.5, dtype=torch.float64) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).to(dtype)


def ssim_torch(a: torch.Tensor, b: torch.Tensor, window_size: int = 11, sigma: float = 1.5,
               padding: str = "same") -> torch.Tensor:
    """Differentiable SSIM of [H, W, C] or [N, H, W, C] tensors (mean over everything)."""
    x, y = _nchw(a), _nchw(b)
    if x.shape != y.shape:
        raise ValueError(f"image shapes differ: {list(x.shape)} vs {list(y.shape)}")
    ch = x.shape[1]
    win = gaussian_window(window_size, sigma, x.dtype).expand(ch, 1, window_size, window_size).contiguous()
    pad = window_size // 2 if padding == "same" else 0
    if padding not in ("same", "valid"):
        raise ValueError("padding must be 'same' (3DGS) or 'valid'")
    conv = lambda t: F.conv2d(t, win, padding=pad, groups=ch)  # noqa: E731
    mu1, mu2 = conv(x), conv(y)
    s11 = conv(x * x) - mu1 * mu1
    s22 = conv(y * y) - mu2 * mu2
    s12 = conv(x * y) - mu1 * mu2
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    m = ((2 * mu1 * mu2 + c1) * (2 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s11 + s22 + c2))
    return m.mean()


def ssim(a, b, window_size: int = 11, sigma: float = 1.5, padding: str = "same") -> float:
    """SSIM as a float, computed in float64."""
    return float(ssim_torch(_nchw(a, torch.float64).permute(0, 2, 3, 1), _nchw(b, torch.float64).permute(0, 2, 3, 1),
                            window_size, sigma, padding))


_LPIPS_CACHE: dict = {}
_BACKBONE_FILES = {"alex": "alexnet-owt-7be5be79.pth", "vgg": "vgg16-397923af.pth", "squeeze": "squeezenet1_1-b8a52dc0.pth"}


def lpips_status(net: str = "vgg") -> tuple[bool, str]:
    """(available, reason): LPIPS needs the ``lpips`` package, its linear-layer weights and the
    backbone's ImageNet weights in the torch hub cache; nothing is downloaded."""
    try:
        import lpips  # type: ignore
    except ImportError:
        return False, "the lpips package is not installed (pip install lpips)"
    lin = os.path.join(os.path.dirname(lpips.__file__), "weights", "v0.1", f"{net}.pth")
    if not os.path.isfile(lin):
        return False, f"LPIPS linear weights not found at {lin}"
    hub = os.path.join(torch.hub.get_dir(), "checkpoints", _BACKBONE_FILES.get(net, ""))
    if not os.path.isfile(hub):
        return False, f"the {net} backbone weights are not in the torch hub cache ({hub}); they would be downloaded"
    return True, "ok"


def lpips(a, b, net: str = "vgg") -> float | None:
    """LPIPS distance, or None (with a logged message) when the package or its weights are
    not present locally. 3DGS reports LPIPS with net='vgg'."""
    ok, why = lpips_status(net)
    if not ok:
        log.warning("LPIPS skipped: %s", why)
        return None
    import lpips as _lp  # type: ignore

    if net not in _LPIPS_CACHE:
        _LPIPS_CACHE[net] = _lp.LPIPS(net=net, verbose=False).eval()
    x, y = _nchw(a, torch.float32), _nchw(b, torch.float32)
    with torch.no_grad():
        return float(_LPIPS_CACHE[net](x * 2 - 1, y * 2 - 1).mean())
