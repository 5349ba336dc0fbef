"""How much of the pictures each Gaussian makes (informative; encoder decisions and tools).

The contribution of Gaussian i to a view is the sum over the view's pixels of its
compositing weight alpha_i T_i (its alpha at the pixel times the transmittance in front
of it): the fraction of the pixel's colour it supplies, accumulated per Gaussian during one
forward pass of the rasterizer that renders the scene (``compositing_weights``; it equals the
gradient of the summed image with respect to a per-Gaussian grey level, since the image is
linear in the colours, at a third of the cost of a forward and backward pass). Summed over a
set of views it is the "global significance" pruning criteria use (LightGaussian).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .camera import Camera
from .rasterizer import compositing_weights
from .view_threads import map_views


# Memory of one view's compositing weights per Gaussian: 763 MiB over the scene's at 1M in views of
# 667 px (render/view_threads.py VIEW_MEMORY_BUDGET: two at a time up to about 1.3M Gaussians).
CONTRIBUTION_VIEW_BYTES = 800.0
# and per region of a view (``view_contributions``' regions): its float64 sum and share
REGION_BYTES = 24.0


@dataclass
class Contributions:
    total: np.ndarray  # float64 [M]: sum over the views and pixels of alpha_i T_i
    # float64 [M]: the largest share of one view's sum (of one region's, with regions) that Gaussian i supplies
    view_share: np.ndarray | None


def view_contributions(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                       cameras: list[Camera], on_view=None, regions: int = 1) -> Contributions:
    """Each Gaussian's contribution to the pictures of ``cameras``, in all and to the view (with
    ``regions`` > 1: the region of a regions x regions grid of a view) it matters most to
    (activated parameters: unit quats (w, x, y, z), scales, opacities in [0, 1]). A Gaussian's
    share of a view is at most its largest share of the view's regions (the view's sum is the
    regions'), so the regions' shares bound the view's too. ``on_view()`` is called after each
    view. Two views at a time (render/view_threads.py), summed in the views' order."""
    total = torch.zeros(means.shape[0], dtype=torch.float64)
    view_share = torch.zeros(means.shape[0], dtype=torch.float64)
    views = map_views(lambda cam: compositing_weights(means, quats, scales, opacities, cam, regions=regions), cameras,
                      view_bytes=(CONTRIBUTION_VIEW_BYTES + REGION_BYTES * regions * regions) * means.shape[0])
    for weights in views:
        weights = weights.reshape(means.shape[0], -1)
        total += weights.sum(1) if regions > 1 else weights[:, 0]
        in_region = weights.sum(0)
        seen = in_region > 0
        if bool(seen.any()):
            torch.maximum(view_share, (weights[:, seen] / in_region[seen]).amax(1), out=view_share)
        if on_view is not None:
            on_view()
    return Contributions(total.numpy(), view_share.numpy())


def gaussian_contributions(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                           cameras: list[Camera], on_view=None) -> np.ndarray:
    """float64 [M]: sum over ``cameras`` and pixels of alpha_i T_i (``view_contributions``' total)."""
    return view_contributions(means, quats, scales, opacities, cameras, on_view).total
