"""The loss of lghcc-train: the image term (by default 0.8 L1 + 0.2 (1 - SSIM) + 0.01 x mean
volume of the neural Gaussians, Scaffold-GS) and, in the rate-distortion phase, the rate term (LG-HCC eq.
12: lambda x the estimated bits per attribute value, encoder/anchors/rate_model.py) with its rate model."""

from __future__ import annotations

import numpy as np
import torch

from .config import TrainConfig


def image_loss(img: torch.Tensor, gt: torch.Tensor, scales: torch.Tensor, cfg: TrainConfig) -> torch.Tensor:
    """(1 - lambda_dssim) L1 + lambda_dssim (1 - SSIM) of the rendered image against the ground
    truth, plus lambda_volume x the mean volume (product of the scales) of the neural Gaussians."""
    from ...render.metrics import ssim_torch

    l1 = (img - gt).abs().mean()
    loss = (1 - cfg.lambda_dssim) * l1 + cfg.lambda_dssim * (1 - ssim_torch(img, gt))
    if cfg.lambda_volume:
        loss = loss + cfg.lambda_volume * scales.prod(dim=1).mean()
    return loss


class RateTerm:
    """The rate-distortion phase of a ``Trainer`` (training/loop.py): its rate model (built once
    the anchor set is final) and the rate term of the loss."""

    def build_rate_model(self, scales=None, twin_size: tuple[int, int, int] | None = None) -> None:
        """The rate model of the current anchors; twin_size (Ch, feature hidden, head hidden): the
        twin's size on resume (None: the encoder's size rule for this many level-2 anchors)."""
        from ...common.geometry import normative_order
        from ...common.hierarchy import build_hierarchy
        from ..stream.config import EncoderConfig, context_model_size
        from ..context.ggconv_train import GGConvTrainConfig
        from ..anchors.rate_model import AnchorRateModel

        cfg = self.cfg
        m = cfg.feature_dim + 6 + 3 * cfg.num_offsets
        coords = self.coords.numpy()
        # the model the encoder will fit for this many level-2 anchors (its size rule), so the scene is
        # trained for a rate that coder can reach
        n2 = build_hierarchy(coords[normative_order(coords)], cfg.rate_voxel_scale).num_level2
        ch, feat_hidden, head_hidden = twin_size or context_model_size(EncoderConfig(), n2)[:3]
        twin = GGConvTrainConfig(neighbour_level=cfg.rate_neighbour_level, ctx_channels=ch, feat_hidden=feat_hidden,
                                 head_hidden=head_hidden, seed=cfg.seed)
        self.rate_model = AnchorRateModel(coords, np.full(m, cfg.rate_step), cfg.feature_dim,
                                          cfg.rate_voxel_scale, self.attribute_values().detach().numpy(), twin)
        if scales is not None and self.rate_model.twin is not None:  # resume: the saved input scales
            self.rate_model.twin.feat_q, self.rate_model.twin.head_q_raw = scales
        self.rate_opt = torch.optim.Adam(self.rate_model.parameters(), lr=cfg.rate_lr)

    def rate_scales(self):
        t = self.rate_model.twin
        return None if t is None else (t.feat_q, t.head_q_raw)

    def add_rate_term(self, loss: torch.Tensor) -> torch.Tensor:
        """``loss`` plus rate_lambda x the estimated bits per attribute value (in the rate phase)."""
        cfg = self.cfg
        if self.rate_model is not None:
            bits = self.rate_model(self.attribute_values(), generator=self.gen)["total"]
            self.rate_bits = float(bits.detach()) / self.num_anchors
            loss = loss + cfg.rate_lambda * bits.float() / (self.num_anchors * self.rate_model.num_attrs)
        return loss

    @torch.no_grad()
    def rate_estimate(self) -> float:
        """Estimated attribute bits per anchor of the rounded attributes (no noise)."""
        return float(self.rate_model(self.attribute_values(), noise=False)["total"]) / self.num_anchors
