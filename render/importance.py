"""How much of the pictures each Gaussian makes (informative; encoder decisions and tools).

The contribution of Gaussian i to a view is the sum over the view's pixels of its
compositing weight alpha_i T_i (its alpha at the pixel times the transmittance in front
of it): the fraction of the pixel's colour it supplies. It is computed exactly, for every
Gaussian at once, as the gradient of the summed image with respect to a per-Gaussian grey
level of 1 (the image is linear in the colours, d image / d c_i = sum alpha_i T_i).
Summed over a set of views it is the "global significance" pruning criteria use
(LightGaussian), computed by the same rasterizer that renders the scene.
"""

from __future__ import annotations

import numpy as np
import torch

from lghcc.render.camera import Camera
from lghcc.render.rasterizer import rasterize


def gaussian_contributions(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                           cameras: list[Camera], on_view=None) -> np.ndarray:
    """float64 [M]: sum over ``cameras`` and pixels of alpha_i T_i (activated parameters:
    unit quats (w, x, y, z), scales, opacities in [0, 1]). ``on_view()`` is called after each view."""
    total = torch.zeros(means.shape[0], dtype=torch.float64)
    m, q, s, o = (t.detach() for t in (means, quats, scales, opacities))
    for cam in cameras:
        grey = torch.ones(m.shape[0], 1, dtype=torch.float32, requires_grad=True)
        rasterize(m, q, s, o, grey, cam).image.sum().backward()
        total += grey.grad[:, 0].double()
        if on_view is not None:
            on_view()
    return total.numpy()
