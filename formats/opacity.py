"""Opacity as the formats store it: 8-bit alpha, and the logit a GaussianScene holds.

Every 8-bit format read here (SPZ, SOG, compressed PLY, .splat, .ksplat) decodes alpha a as
the logit of a / 255 clamped to [ALPHA_EPS, 1 - ALPHA_EPS], as splat-transform's SOG, .splat
and .ksplat readers do: alpha 0 and 255 (opacity 0 and 1) become the finite logits
-+LARGEST_OPACITY_LOGIT (about 13.8), whose sigmoid differs from 0 or 1 by 1e-6, far below
the 1/255 of the code. A PLY converted from an 8-bit format by splat-transform can hold those
opacities as logits of -inf and +inf instead (its compressed-PLY reader does not clamp);
``finite_opacity_logits`` reads them as the same finite logits, with one warning.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..common.errors import InputWarning

ALPHA_EPS = 1e-6
LARGEST_OPACITY_LOGIT = math.log((1 - ALPHA_EPS) / ALPHA_EPS)


class InfiniteOpacityWarning(InputWarning):
    """Opacity logits of +-inf were read as opacity 1 or 0 (finite logits)."""


def alpha_logits(alpha: np.ndarray) -> np.ndarray:
    """The opacity logits (float64) of 8-bit alphas 0..255 (any integer or float array)."""
    a = np.clip(np.asarray(alpha, np.float64) / 255.0, ALPHA_EPS, 1 - ALPHA_EPS)
    return np.log(a / (1 - a))


def finite_opacity_logits(logits: np.ndarray, what: str) -> np.ndarray:
    """``logits`` with +-inf replaced by +-LARGEST_OPACITY_LOGIT (one InfiniteOpacityWarning
    counting them); with NaN among them they are returned as they are, for the scene's
    validation to refuse (no warning for a file that is not read)."""
    logits = np.asarray(logits)
    infinite = np.isinf(logits)
    if not infinite.any() or np.isnan(logits).any():
        return logits
    up = int((infinite & (logits > 0)).sum())
    down = int(infinite.sum()) - up
    warnings.warn(f"{what}: {up:,} opacity logits of +inf and {down:,} of -inf read as opacity 1 and 0 "
                  f"(logits +-{LARGEST_OPACITY_LOGIT:.4g}, as alpha 255 and 0 decode)", InfiniteOpacityWarning,
                  stacklevel=2)
    return np.where(infinite, np.sign(logits) * LARGEST_OPACITY_LOGIT, logits).astype(logits.dtype)
