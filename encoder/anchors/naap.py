"""Anchor pruning (informative, encoder side): Neighborhood-Aware Anchor Pruning (NAAP,
paper section 3.3) and, for comparison, the plain opacity-threshold pruning of Context-GS.

NAAP:
  1. graph: each anchor's K nearest neighbours within radius r (distances in voxels);
  2. w_ij = 1 / (|p_i - p_j| + eps);  Phi_i = (a_i + sum_j w_ij a_j) / (1 + sum_j w_ij);
     xi_i = (1 - lambda) a_i + lambda Phi_i,  where a_i is the anchor's accumulated opacity;
  3. anchors with xi_i < tau are pruned; each is associated with its nearest retained anchor;
  4. Theta_k = (1 - gamma) theta_k + gamma theta_r for offsets, scalings and opacity. When several
     pruned anchors share one target, theta_r is their mean (the paper states the pairwise rule).

Accumulated opacity comes from training statistics when the scene has them
(``scene.extra["opacity_accum"]``), else from the opacity MLP averaged over view
directions sampled on a sphere (``estimate_anchor_opacity``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ...common.errors import InputError
from ...common.scene import AnchorScene


@dataclass
class NaapConfig:
    k: int = 8
    radius_voxels: float | None = None  # None: 4 x the median nearest-neighbour distance
    eps: float = 1e-3  # in voxels
    lam: float = 0.5
    tau: float | None = None  # importance threshold; or
    keep_ratio: float | None = None  # keep this fraction of anchors (tau chosen as the quantile)
    gamma: float = 0.2


@dataclass
class PruneReport:
    method: str
    num_before: int
    num_after: int
    tau: float
    num_merged_targets: int = 0

    def __str__(self) -> str:
        return (f"{self.method}: {self.num_before:,} -> {self.num_after:,} anchors (tau={self.tau:.4g}"
                + (f", merged into {self.num_merged_targets:,} anchors)" if self.method == "naap" else ")"))


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def estimate_anchor_opacity(scene: AnchorScene, num_views: int = 16, batch: int = 65536) -> np.ndarray:
    """Mean over sampled views and over live offsets of the neural opacity max(0, MLP output)."""
    if "opacity_accum" in scene.extra:
        return np.asarray(scene.extra["opacity_accum"], dtype=np.float64).reshape(-1)
    mlp = scene.mlps.get("opacity")
    if mlp is None:
        raise InputError("NAAP needs anchor opacities: the scene has no opacity MLP and no training statistics")
    c = scene.feature_dim
    extra_in = mlp.in_dim - c
    if extra_in not in (0, 3, 4):
        raise InputError(f"opacity MLP input size {mlp.in_dim} does not match features ({c}) + view inputs")
    pos = scene.positions().astype(np.float64)
    dist = float(np.ptp(pos, axis=0).max()) or 1.0  # cameras at about one scene extent
    dirs = _fibonacci_sphere(num_views)
    live = np.ones((scene.num_anchors, scene.num_offsets)) if scene.offset_mask is None \
        else scene.offset_mask.astype(np.float64)
    out = np.zeros(scene.num_anchors)
    for lo in range(0, scene.num_anchors, batch):
        f = scene.features[lo:lo + batch].astype(np.float32)
        acc = np.zeros((f.shape[0], scene.num_offsets))
        for d in dirs:
            view = np.broadcast_to((-d).astype(np.float32), (f.shape[0], 3))
            inputs = [f, view, np.full((f.shape[0], 1), dist, np.float32)][: 1 + (extra_in >= 3) + (extra_in == 4)]
            acc += np.maximum(mlp(np.concatenate(inputs, axis=1)), 0)
        lv = live[lo:lo + batch]
        out[lo:lo + batch] = (acc / num_views * lv).sum(1) / np.maximum(lv.sum(1), 1)
    return out


def naap_importance(coords: np.ndarray, opacity: np.ndarray, k: int, radius: float, eps: float,
                    lam: float) -> np.ndarray:
    tree = cKDTree(coords.astype(np.float64))
    kk = min(k + 1, coords.shape[0])
    d, idx = tree.query(coords.astype(np.float64), k=kk, distance_upper_bound=radius)
    d, idx = d.reshape(len(coords), kk)[:, 1:], idx.reshape(len(coords), kk)[:, 1:]  # drop self
    valid = np.isfinite(d)
    w = np.where(valid, 1.0 / (np.where(valid, d, 0) + eps), 0.0)
    a_nb = opacity[np.where(valid, idx, 0)]
    phi = (opacity + (w * a_nb).sum(1)) / (1 + w.sum(1))
    return (1 - lam) * opacity + lam * phi


def _threshold(score: np.ndarray, tau: float | None, keep_ratio: float | None) -> float:
    if (tau is None) == (keep_ratio is None):
        raise InputError("give exactly one of a threshold tau or a keep ratio")
    if keep_ratio is not None:
        if not 0 < keep_ratio <= 1:
            raise InputError("keep ratio must be in (0, 1]")
        n_keep = max(1, int(round(keep_ratio * score.size)))
        return float(np.sort(score)[::-1][n_keep - 1])
    return float(tau)


def _keep_mask(score: np.ndarray, tau: float, keep_ratio: float | None) -> np.ndarray:
    if keep_ratio is None:
        keep = score >= tau
    else:  # exactly the requested count, ties broken by index (stable)
        n_keep = max(1, int(round(keep_ratio * score.size)))
        keep = np.zeros(score.size, bool)
        keep[np.argsort(-score, kind="stable")[:n_keep]] = True
    if not keep.any():
        keep[np.argmax(score)] = True
    return keep


def _subset(scene: AnchorScene, keep: np.ndarray) -> AnchorScene:
    return AnchorScene(coords=scene.coords[keep], voxel_size=scene.voxel_size, origin=scene.origin,
                       features=scene.features[keep], scalings=scene.scalings[keep], offsets=scene.offsets[keep],
                       offset_mask=None if scene.offset_mask is None else scene.offset_mask[keep],
                       mlps=scene.mlps, extra={k: v[keep] for k, v in scene.extra.items()})


@dataclass
class PrunePlan:
    """Which anchors stay (keep, bool [N]) and, for NAAP, the kept anchor each pruned one is
    merged into (targets [num pruned], an index into the kept anchors in their order)."""
    method: str
    keep: np.ndarray
    targets: np.ndarray | None
    tau: float

    def report(self) -> PruneReport:
        merged = 0 if self.targets is None else int(np.unique(self.targets).size)
        return PruneReport(self.method, int(self.keep.size), int(self.keep.sum()), self.tau, merged)

    def merge(self, values: np.ndarray, gamma: float) -> np.ndarray:
        """Weighted Attribute Transformation (paper eq. 11) of one attribute ([N, ...]): the kept
        rows, each target blended with the mean of the pruned anchors merged into it,
        Theta_k = (1 - gamma) theta_k + gamma theta_r. Without targets: the kept rows."""
        own = values[self.keep]
        if self.targets is None or not self.targets.size:
            return own.copy()
        theirs = values[~self.keep].astype(np.float64)
        counts = np.bincount(self.targets, minlength=own.shape[0]).astype(np.float64)
        acc = np.zeros((own.shape[0],) + theirs.shape[1:])
        np.add.at(acc, self.targets, theirs)
        hit = counts > 0
        mean = acc / np.maximum(counts, 1).reshape((-1,) + (1,) * (theirs.ndim - 1))
        out = own.astype(np.float64).copy()
        out[hit] = (1 - gamma) * out[hit] + gamma * mean[hit]
        return out.astype(values.dtype)


def opacity_plan(opacity: np.ndarray, tau: float | None = None, keep_ratio: float | None = None) -> PrunePlan:
    """Context-GS style: drop anchors whose accumulated opacity is below tau."""
    a = np.asarray(opacity, dtype=np.float64)
    t = _threshold(a, tau, keep_ratio)
    return PrunePlan("opacity", _keep_mask(a, t, keep_ratio), None, t)


def naap_plan(coords: np.ndarray, opacity: np.ndarray, cfg: NaapConfig) -> PrunePlan:
    """NAAP steps 1-3: importance over the k-NN graph, threshold, nearest kept neighbour of
    every pruned anchor."""
    a = np.asarray(opacity, dtype=np.float64)
    n = coords.shape[0]
    cf = coords.astype(np.float64)
    radius = cfg.radius_voxels
    if radius is None:
        radius = 4.0 * float(np.median(cKDTree(cf).query(cf, k=2)[0][:, 1])) if n > 1 else 1.0
    xi = naap_importance(coords, a, cfg.k, radius, cfg.eps, cfg.lam)
    tau = _threshold(xi, cfg.tau, cfg.keep_ratio)
    keep = _keep_mask(xi, tau, cfg.keep_ratio)
    targets = np.zeros(0, np.int64)
    if not keep.all():
        targets = cKDTree(cf[keep]).query(cf[~keep], k=1)[1].astype(np.int64)
    return PrunePlan("naap", keep, targets, tau)


def apply_plan(scene: AnchorScene, plan: PrunePlan, gamma: float, opacity: np.ndarray) -> AnchorScene:
    """The scene with the plan's anchors kept; with NAAP targets, offsets, scalings and the
    accumulated opacity (and a per-anchor opacity, if the scene has one) merged (eq. 11)."""
    out = _subset(scene, plan.keep)
    if plan.targets is not None and plan.targets.size:
        out.offsets = plan.merge(scene.offsets, gamma)
        out.scalings = plan.merge(scene.scalings, gamma)
        out.extra = dict(out.extra)
        out.extra["opacity_accum"] = plan.merge(np.asarray(opacity, dtype=np.float64), gamma)
        if "opacity" in scene.extra:
            out.extra["opacity"] = plan.merge(np.asarray(scene.extra["opacity"]), gamma)
    return out


def opacity_prune(scene: AnchorScene, tau: float | None = None, keep_ratio: float | None = None,
                  opacity: np.ndarray | None = None) -> tuple[AnchorScene, PruneReport]:
    """Context-GS style: drop anchors whose accumulated opacity is below tau."""
    a = estimate_anchor_opacity(scene) if opacity is None else opacity
    plan = opacity_plan(a, tau, keep_ratio)
    return _subset(scene, plan.keep), plan.report()


def naap_prune(scene: AnchorScene, cfg: NaapConfig, opacity: np.ndarray | None = None
               ) -> tuple[AnchorScene, PruneReport]:
    a = estimate_anchor_opacity(scene) if opacity is None else np.asarray(opacity, dtype=np.float64)
    plan = naap_plan(scene.coords, a, cfg)
    return apply_plan(scene, plan, cfg.gamma, a), plan.report()
