"""Merging instead of dropping (informative): the Gaussians the pruning removes are merged into
their nearest kept neighbour with the moments of the group kept, as LG-HCC's NAAP merges
low-importance anchors into salient ones (``prune_mode: merge``; ``drop`` removes them).

Each pruned Gaussian i goes to its nearest kept Gaussian k (Euclidean distance of the means)
when they are within MERGE_REACH x (largest scale of i + largest scale of k), and is dropped
otherwise. A kept Gaussian k with its merged ones G = {k} + {i -> k} becomes:

- weight w_j: the Gaussian's contribution to the pictures (render/importance.py, what the
  pruning ranks by: the sum over views and pixels of alpha T), so each Gaussian moves the group
  as much as the views see of it. Opacity x footprint (alpha (s1 s2 s3)^(2/3)) or opacity x
  volume (alpha s1 s2 s3) give a hidden Gaussian the weight of a visible one: on playbot lod4
  at the low preset's steps with 3% of the contribution pruned (no fit, tools/results/merging.md), the
  footprint weights gave 34.68 dB against the contributions' 35.02 dB (drop: 34.48), volume
  weights 34.45 dB;
- mean mu = sum w_j mu_j / W (W = sum w_j);
- covariance Sigma = sum w_j (Sigma_j + (mu_j - mu)(mu_j - mu)^T) / W, written as scales and a
  rotation by its eigendecomposition in float64 (eigenvalues floored at MIN_EIGEN_RATIO of the
  largest, so a flat or degenerate group stays a valid Gaussian; a near-isotropic one takes any
  orthonormal eigenvectors, which render the same);
- SH (DC and rest) the w-weighted mean;
- opacity: the kept Gaussian's. The group's coverage 1 - prod(1 - a_j) (capped at the coded
  limit) made the merged Gaussians too opaque where the pruned ones lay behind or beside them
  (34.18 against 34.68 dB in the case above; the group's mass a_j area_j spread over the merged
  footprint 34.50 against 35.02 dB).

A group whose weights are all zero (Gaussians no view sees) leaves k as it was. Kept Gaussians
that nothing merges into are returned bit for bit.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ...common.scene import GaussianScene
from .gaussian_views import prune_by_contribution, prune_by_view_share

# A pruned Gaussian merges into a kept one within this many times the sum of their largest scales.
# On playbot lod4 at low's steps with 10% of the contribution pruned (no fit), 0.5 / 1 / 2 gave
# 30.21 / 30.94 / 31.26 dB (drop 29.39); on the donut at 3% 0.5 / 1 gave 43.14 / 43.29 dB (drop
# 42.26); a wider reach moves more kept Gaussians further (tools/results/merging.md).
MERGE_REACH = 1.0
# Eigenvalues of a merged covariance are at least this share of its largest one.
MIN_EIGEN_RATIO = 1e-8


def merge_targets(scene: GaussianScene, keep: np.ndarray) -> np.ndarray:
    """int64 [N]: for each pruned Gaussian (``~keep``), the index (into the scene) of the kept
    Gaussian it merges into, -1 where none is within reach; -1 for the kept ones."""
    target = np.full(scene.num_gaussians, -1, dtype=np.int64)
    kept, pruned = np.flatnonzero(keep), np.flatnonzero(~keep)
    if kept.size == 0 or pruned.size == 0:
        return target
    m = scene.means.astype(np.float64)
    dist, j = cKDTree(m[kept]).query(m[pruned], k=1)
    reach = np.exp(scene.log_scales.astype(np.float64)).max(axis=1)
    close = dist <= MERGE_REACH * (reach[pruned] + reach[kept[j]])
    target[pruned[close]] = kept[j[close]]
    return target


def rotation_matrices(scene: GaussianScene) -> np.ndarray:
    """float64 [N, 3, 3]: each Gaussian's rotation."""
    q = scene.rotations.astype(np.float64)
    return Rotation.from_quat(np.concatenate([q[:, 1:], q[:, :1]], axis=1)).as_matrix()


def covariances(scene: GaussianScene) -> np.ndarray:
    """float64 [N, 3, 3]: R S^2 R^T of each Gaussian."""
    r = rotation_matrices(scene)
    s2 = np.exp(2 * scene.log_scales.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", r, s2, r)


_PERMUTATIONS = np.array(list(itertools.permutations(range(3))))


def _aligned(lam: np.ndarray, vec: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenpairs reordered and signed to lie closest to ``frame``'s axes (the kept Gaussian's
    rotation matrices): the same covariance, written as its neighbours' values are, so the
    neighbour prediction of scales and rotations keeps working (eigh's ascending order and
    arbitrary signs cost the donut 8.5% more attribute bits at 3% merged)."""
    dots = np.einsum("nji,njk->nik", frame, vec)  # [n, frame axis, eigenvector]
    score = np.abs(dots)[:, np.arange(3)[None, :], _PERMUTATIONS].sum(axis=2)  # [n, 6]
    perm = _PERMUTATIONS[score.argmax(axis=1)]
    rows = np.arange(vec.shape[0])[:, None]
    vec, lam, dots = vec[rows[:, None], np.arange(3)[None, :, None], perm[:, None, :]], lam[rows, perm], \
        dots[rows, np.arange(3)[None, :], perm]
    vec = vec * np.where(dots < 0, -1.0, 1.0)[:, None, :]
    weakest = np.abs(dots).argmin(axis=1)
    flip = np.where(np.linalg.det(vec) < 0, -1.0, 1.0)  # a proper rotation: turn the least aligned axis
    vec[np.arange(vec.shape[0]), :, weakest] *= flip[:, None]
    return lam, vec


def scales_and_rotations(cov: np.ndarray, frame: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric positive semi-definite [M, 3, 3] (float64) -> (log scales [M, 3], unit quaternions
    [M, 4] (w, x, y, z), w >= 0), eigenvalues floored at MIN_EIGEN_RATIO of the largest; with
    ``frame`` ([M, 3, 3] rotation matrices) the axes closest to its (``_aligned``)."""
    lam, vec = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    top = np.maximum(lam[:, -1:], np.finfo(np.float64).tiny)
    lam = np.maximum(lam, top * MIN_EIGEN_RATIO)
    vec[:, :, 2] *= np.sign(np.linalg.det(vec))[:, None]  # a proper rotation
    if frame is not None:
        lam, vec = _aligned(lam, vec, frame)
    q = Rotation.from_matrix(vec).as_quat()  # (x, y, z, w)
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    q = np.where(q[:, :1] < 0, -q, q)
    return 0.5 * np.log(lam), q


def _group_sums(target: np.ndarray, w: np.ndarray, x: np.ndarray, n: int) -> np.ndarray:
    """Per group (indexed by ``target``; -1 counts nowhere): sum of w_j x_j."""
    out = np.zeros((n,) + x.shape[1:], np.float64)
    on = target >= 0
    np.add.at(out, target[on], w[on].reshape((-1,) + (1,) * (x.ndim - 1)) * x[on])
    return out


def merged_moments(scene: GaussianScene, group: np.ndarray, w: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(W, mean, covariance) per group: ``group`` [N] the index of each Gaussian's group (-1: in
    none; a group's index is its kept Gaussian's), ``w`` its weight. The means are taken relative
    to the group's kept Gaussian, so a scene far from the origin loses no digits."""
    n = scene.num_gaussians
    m = scene.means.astype(np.float64)
    anchor = np.where(group >= 0, group, np.arange(n))
    d = m - m[anchor]  # relative to the kept Gaussian of the group
    total = _group_sums(group, w, np.ones(n), n)
    safe = np.where(total > 0, total, 1.0)
    delta = _group_sums(group, w, d, n) / safe[:, None]
    second = _group_sums(group, w, covariances(scene) + np.einsum("ni,nj->nij", d, d), n) / safe[:, None, None]
    cov = second - np.einsum("ni,nj->nij", delta, delta)
    return total, m + delta, cov


def merge_pruned(scene: GaussianScene, keep: np.ndarray, weights: np.ndarray,
                 target: np.ndarray | None = None) -> GaussianScene:
    """The kept Gaussians (in scene order) with the pruned ones merged into them, ``weights`` [N]
    each Gaussian's (its contribution; module doc); ``target``: ``merge_targets(scene, keep)``
    where the caller has it. A scene on a grid comes back off it where a mean moved."""
    keep = np.asarray(keep, dtype=bool)
    target = merge_targets(scene, keep) if target is None else target
    group = np.where(keep, np.arange(scene.num_gaussians), target)
    w = np.asarray(weights, np.float64)
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    total, mean, cov = merged_moments(scene, group, w)
    changed = np.zeros(scene.num_gaussians, dtype=bool)
    changed[target[target >= 0]] = True
    changed &= total > 0
    if not changed.any():
        return scene.subset(keep)
    out = GaussianScene(*(getattr(scene, f).copy() for f in ("means", "sh", "opacity", "log_scales", "rotations")))
    _write_merged(scene, out, group, w, total, mean, cov, changed)
    return out.subset(keep)


def _write_merged(scene: GaussianScene, out: GaussianScene, group: np.ndarray, w: np.ndarray, total: np.ndarray,
                  mean: np.ndarray, cov: np.ndarray, changed: np.ndarray) -> None:
    """Writes the merged groups' values into ``out`` (rows ``changed``)."""
    c = np.flatnonzero(changed)
    log_scales, quats = scales_and_rotations(cov[c], rotation_matrices(scene.subset(c)))
    sh = _group_sums(group, w, scene.sh.astype(np.float64), scene.num_gaussians)[c] / total[c, None, None]
    out.means[c] = mean[c]
    out.log_scales[c] = log_scales
    out.rotations[c] = quats
    out.sh[c] = sh


def merged_weights(contrib: np.ndarray, keep: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The contribution of each kept Gaussian with those merged into it added (scene order of the kept)."""
    total = np.asarray(contrib, np.float64).copy()
    on = target >= 0
    np.add.at(total, target[on], total[on])
    return total[keep].astype(np.asarray(contrib).dtype)


def pruned_scene(scene: GaussianScene, contrib: np.ndarray, share: float, mode: str,
                 view_share: np.ndarray | None = None) -> tuple[np.ndarray, GaussianScene, np.ndarray]:
    """Pruning by contribution (``prune_by_contribution``: by each Gaussian's largest share of one
    view where ``view_share`` is given, so that no view loses more than ``share``), the pruned
    Gaussians dropped (``mode`` "drop") or merged into their kept neighbours ("merge") -> (which
    Gaussians were kept, the kept scene, their contributions: under merge with those merged into
    each added)."""
    keep = prune_by_contribution(contrib, share) if view_share is None else prune_by_view_share(view_share, share)
    if mode != "merge" or keep.all():
        return keep, scene.subset(keep), contrib[keep]
    target = merge_targets(scene, keep)
    return keep, merge_pruned(scene, keep, contrib, target), merged_weights(contrib, keep, target)
