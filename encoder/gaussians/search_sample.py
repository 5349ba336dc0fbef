"""The part of a large explicit-Gaussian scene the settings search measures (informative).

The settings search (encoder/gaussians/gaussian_rd.py) renders and codes every trial: its cost grows with
the scene. Above ``search_sample_gaussians`` it measures a sample instead, and the chosen settings
are applied to the whole scene (encoder/gaussians/gaussian_fit.py, ``search_for_settings``). What the
settings trade is local: the grid step against the Gaussians' sizes, the neighbour prediction
between nearby Gaussians, RDOQ per Gaussian. So the sample is made of whole cells of space, which
keep each neighbourhood's density and structure as it is (Gaussians drawn one by one would thin
every neighbourhood, and the grid and the neighbour prediction would code them differently):

1. the scene's bounding cube is cut into 2^L cells per side, L the smallest level at which the
   occupied cells hold at most ``search_sample_gaussians / SAMPLE_CELLS`` Gaussians on average;
2. the occupied cells are walked in Morton (Z) order, which keeps nearby cells together, and
   taken by error diffusion on their counts: each cell adds rate x its count to a running quota
   (rate = sample size / N) and is taken when the quota reaches half its count, which the cell
   then uses up. The sample spreads evenly along the curve, so over the whole scene, and holds
   about the sample size.

The choice depends on the positions only: the same scene gives the same sample.
"""

from __future__ import annotations

import numpy as np

# Cells a sample is made of, about: enough that it spreads over the scene, few enough that each
# cell holds whole neighbourhoods (at 100,000 sampled Gaussians, about 3,000 a cell).
SAMPLE_CELLS = 32
MAX_LEVEL = 20


def morton_keys(cells: np.ndarray) -> np.ndarray:
    """int64 [N]: the Morton (Z-order) key of integer cell coordinates [N, 3] below 2^21."""
    key = np.zeros(cells.shape[0], dtype=np.int64)
    c = cells.astype(np.int64)
    for b in range(21):
        for axis in range(3):
            key |= ((c[:, axis] >> b) & 1) << (3 * b + axis)
    return key


def _cells_at(means: np.ndarray, lo: np.ndarray, side: float, level: int) -> tuple[np.ndarray, np.ndarray]:
    """(the occupied cells' Morton keys in order and each Gaussian's index into them) at 2^level
    cells per side of the cube of ``side`` from ``lo``."""
    k = 1 << level
    cells = np.clip(np.floor((means - lo) / side * k), 0, k - 1).astype(np.int64)
    keys, inverse = np.unique(morton_keys(cells), return_inverse=True)
    return keys, inverse.reshape(-1)


def spatial_cells(means: np.ndarray, mean_count: float) -> np.ndarray:
    """int64 [N]: each Gaussian's cell (index in Morton order) at the coarsest level whose occupied
    cells hold at most ``mean_count`` Gaussians on average (MAX_LEVEL at most)."""
    m = np.asarray(means, dtype=np.float64)
    lo = m.min(axis=0)
    side = max(float((m.max(axis=0) - lo).max()), 1e-30) * (1 + 1e-9)
    for level in range(MAX_LEVEL + 1):
        keys, inverse = _cells_at(m, lo, side, level)
        if m.shape[0] / keys.shape[0] <= mean_count:
            break
    return inverse


def diffuse_cells(counts: np.ndarray, rate: float) -> np.ndarray:
    """bool [C]: the cells taken by error diffusion on ``counts`` (module doc, step 2)."""
    taken = np.zeros(counts.shape[0], dtype=bool)
    quota = 0.0
    for j, c in enumerate(counts.tolist()):
        quota += rate * c
        if quota >= c / 2:
            taken[j] = True
            quota -= c
    return taken


def search_sample(means: np.ndarray, size: int) -> np.ndarray | None:
    """bool [N]: the Gaussians the settings search measures on a scene whose positions are
    ``means`` (module doc), or None where it measures them all: ``size`` 0, a scene of at most
    ``size`` Gaussians, or one whose Gaussians no cell separates."""
    n = means.shape[0]
    if size <= 0 or n <= size:
        return None
    cell = spatial_cells(means, max(size / SAMPLE_CELLS, 1.0))
    counts = np.bincount(cell)
    taken = diffuse_cells(counts, size / n)
    if not taken.any() or taken.all():
        return None
    return taken[cell]
