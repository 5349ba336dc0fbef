"""Fitting cross-channel prediction (informative; the prediction itself is normative,
``lghcc.common.attributes.ChannelPrediction``, spec clause 11.6).

The channels of a Gaussian are correlated: the R, G and B values of one SH coefficient
move together, and so do a Gaussian's three log scales. Each channel's deviation from its
mean is predicted from the deviations of the earlier channels of its group by least squares
on the quantized values; a prediction is kept only where it saves more bits (ideal code
lengths with the frozen tables) than its entries cost in the header.
"""

from __future__ import annotations

import numpy as np

from ...common.attributes import ChannelPrediction, CodingParams, GaussianLayout
from ...common.entropy.symbol_coder import best_level, code_lengths_bits
from ..context.code_lengths import ResidualHistograms
from ...common.units import CHANNEL_PREDICTION_SHIFT, MAX_CHANNEL_PREDICTION_WEIGHT
from .memory import CODING_BLOCK_ROWS

FIT_ROWS = 50_000  # rows sampled for the least-squares fit and the bit counts
ENTRY_COST_BITS = 24.0  # about ue(target) + ue(source) + se(weight)


def prediction_groups(layout: GaussianLayout) -> list[list[int]]:
    """Channels that may predict each other, earlier ones predicting later ones: the colours of
    each SH coefficient, the three log scales, the four rotation components."""
    groups = [[3 * i, 3 * i + 1, 3 * i + 2] for i in range(layout.sh_channels // 3)]
    groups.append(list(range(layout.scale_start, layout.rotation_start)))
    groups.append(list(range(layout.rotation_start, layout.num_channels)))
    return groups


def _bits(r: np.ndarray, level: np.ndarray | None) -> float:
    """Ideal bits of residuals r with per-value levels, or (None) with their best single level."""
    if level is None:
        level = np.full(r.shape, best_level(r), dtype=np.int64)
    return float(code_lengths_bits(r, level).sum())


def fit_rows(n: int, seed: int = 0) -> np.ndarray:
    """The rows (ascending) the prediction is fitted and costed on: every row up to FIT_ROWS, else
    FIT_ROWS of them drawn with ``seed``."""
    return np.arange(n) if n <= FIT_ROWS else np.sort(np.random.default_rng(seed).choice(n, FIT_ROWS, replace=False))


def fit_channel_prediction(q: np.ndarray, params: CodingParams, layout, live: np.ndarray,
                           seed: int = 0) -> tuple[ChannelPrediction, np.ndarray]:
    """-> (prediction, per-channel best level of the residuals after it: the prior's levels).
    ``params``: the means and levels the values are coded with (a per-channel prior has one row
    of levels, which the fit re-chooses; a context model's levels are kept)."""
    n, m = q.shape
    mean = np.broadcast_to(np.asarray(params.mean, np.int64), q.shape)
    per_value_levels = np.asarray(params.level).shape[0] != 1 or n == 1
    rows = fit_rows(n, seed)
    lv = np.broadcast_to(params.level, q.shape)[rows].astype(np.int64) if per_value_levels else None
    prediction = fit_sampled_prediction(q[rows] - mean[rows], lv, live[rows], layout, n)
    return prediction, levels_after(prediction, q, mean, live)


def levels_after(prediction: ChannelPrediction, q: np.ndarray, mean: np.ndarray, live: np.ndarray) -> np.ndarray:
    """Per channel: the best level of its live values' residuals after ``prediction`` (best_level of
    the column), from histograms gathered a block of rows at a time (peak memory: no [N, M] residuals)."""
    n, m = q.shape
    hist = ResidualHistograms(m)
    channel = np.arange(m)
    for lo in range(0, n, CODING_BLOCK_ROWS):
        block = slice(lo, lo + CODING_BLOCK_ROWS)
        r, ok = prediction.residuals(q[block], mean[block]), live[block]
        hist.add(np.broadcast_to(channel, r.shape)[ok], r[ok])
    return np.array([hist.best_level(c) for c in range(m)], dtype=np.int64)


def fit_sampled_prediction(d: np.ndarray, lv: np.ndarray | None, live: np.ndarray, layout,
                           n: int) -> ChannelPrediction:
    """The prediction fitted on the deviations from their means ``d`` (int64 [rows, M]) of the
    rows fit_rows(n) draws, ``lv`` their levels (None: each channel's best single level) and
    ``live`` the values coded: an entry is kept where its bits saved, scaled to the ``n`` rows,
    exceed its cost in the header."""
    targets, sources, weights = [], [], []
    for group in (prediction_groups(layout) if isinstance(layout, GaussianLayout) else []):
        for pos, c in enumerate(group[1:], start=1):
            src = group[:pos]
            ok = live[:, [c] + src].all(axis=1)
            if ok.sum() < 16:
                continue
            sub = d[:, [c] + src][ok]  # the target's and sources' deviations (not every channel's rows)
            y, xs = sub[:, 0], sub[:, 1:]
            if not np.abs(xs).any():
                continue
            w = np.linalg.lstsq(xs.astype(np.float64), y.astype(np.float64), rcond=None)[0]
            wi = np.clip(np.rint(w * (1 << CHANNEL_PREDICTION_SHIFT)), -MAX_CHANNEL_PREDICTION_WEIGHT,
                         MAX_CHANNEL_PREDICTION_WEIGHT).astype(np.int64)
            keep = wi != 0
            if not keep.any():
                continue
            pred = (xs[:, keep] @ wi[keep] + (1 << (CHANNEL_PREDICTION_SHIFT - 1))) >> CHANNEL_PREDICTION_SHIFT
            lc = None if lv is None else lv[ok, c]
            saved = _bits(y, lc) - _bits(y - pred, lc)
            if saved * n / d.shape[0] > ENTRY_COST_BITS * int(keep.sum()):
                for j, wj in zip(np.asarray(src)[keep], wi[keep]):
                    targets.append(c)
                    sources.append(int(j))
                    weights.append(int(wj))
    return ChannelPrediction(np.asarray(targets, np.int64), np.asarray(sources, np.int64),
                             np.asarray(weights, np.int64))
