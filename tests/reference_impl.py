"""Test-only reference implementations: slow, plain versions of normative operations of
common/, which the tests compare the reference decoder against (not part of the codec)."""

from __future__ import annotations

import numpy as np

from lghcc.common.context.parent_mlp import ParentMlpEvaluator, ParentMlpParams
from lghcc.common.knn import _prepare


def rshift_round_np(x: np.ndarray, shift: int) -> np.ndarray:
    """numpy twin of common/intnn.py ``rshift_round`` (int64): (x + 2^(shift-1)) >> shift."""
    if shift < 0 or shift > 62:
        raise ValueError(f"shift must be in [0, 62], got {shift}")
    if shift == 0:
        return x
    return (x + np.int64(1 << (shift - 1))) >> np.int64(shift)


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Exact int64 squared distances between broadcastable [..., 3] int64 arrays (caller
    guarantees the extent bound of common/knn.py)."""
    d = a - b
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    return x * x + y * y + z * z


def ball_knn_bruteforce(coords, k: int, radius_sq: int, query=None,
                        exclude_self: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """O(N M) reference of common/knn.py ``ball_knn`` (same contract)."""
    c, q, self_mode, _, idx_out, valid_out = _prepare(coords, query, k)
    n, m = c.shape[0], q.shape[0]
    for r in range(m):
        if n == 0:
            break
        d2 = squared_distances(c, q[r][None, :])
        ok = d2 <= radius_sq
        if exclude_self:
            if self_mode:
                ok[r] = False
            else:
                ok &= d2 != 0
        j = np.nonzero(ok)[0]
        j = j[np.lexsort((j, d2[j]))][:k]
        idx_out[r, :j.size] = j
        valid_out[r, :j.size] = True
    return idx_out, valid_out


def parent_mlp_coding_params(params: ParentMlpParams, coords2: np.ndarray, parent: np.ndarray, attrs1: np.ndarray,
                             voxel_scale: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All level-2 rows at once through common/context/parent_mlp.py's evaluator: coords2 int
    [N2, 3], parent int [N2] (indices into level 1), attrs1 int [N1, M] the decoded level-1
    attributes. Returns mean (int32), level (int8), step_adjust (int8), each [N2, M]."""
    ev = ParentMlpEvaluator(params, coords2, parent, attrs1, voxel_scale)
    return ev.rows(0, ev.num_rows)
