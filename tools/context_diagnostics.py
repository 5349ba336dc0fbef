"""How much a scene's level-2 attributes can be predicted from their context (informative).

The numbers behind the findings of tools/results/context.md, for each scene:

* parent vs median: the attribute channels (live entries of the level-2 anchors, in
  quantization steps) whose parent's value is a worse mean than the channel's median, by mean
  absolute residual (what the encoder's parent_base "choose" rule tests);
* neighbour R^2: the share of the level-2 feature variance that a ridge regression on the
  features of the anchor's K nearest level-1 anchors explains on held-out anchors (half the
  anchors fit, a quarter chooses the ridge weight, a quarter is scored; variance-weighted over
  the feature channels). Near 0: the
  neighbours carry little that a context model could use.

    python tools/context_diagnostics.py /work/scenes/lego100_rd0 /work/scenes/donut --step 0.02
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def diagnose(path: str, step: float, scale: int, k: int) -> dict:
    from scipy.spatial import cKDTree

    from lghcc.common.geometry import normative_order
    from lghcc.common.hierarchy import build_hierarchy
    from lghcc.formats.scaffold_io import read_scaffold

    s = read_scaffold(path)
    order = normative_order(s.coords)
    coords = s.coords[order]
    n = len(order)
    values = np.concatenate([s.features[order], s.scalings[order], s.offsets[order].reshape(n, -1)], 1) / step
    live = np.ones_like(values, dtype=bool)
    if s.offset_mask is not None:  # dead offsets are not coded
        live[:, s.feature_dim + 6:] = np.repeat(s.offset_mask[order].astype(bool), 3, axis=1)
    h = build_hierarchy(coords, scale)
    t = np.where(live[h.level2_idx], values[h.level2_idx], np.nan)
    par = values[h.parent_anchor_of_level2]
    med = np.nanmedian(t, 0)
    worse = int((np.nanmean(np.abs(t - par), 0) > np.nanmean(np.abs(t - med), 0)).sum())

    c = s.feature_dim
    x1, y = values[h.level1_idx, :c], values[h.level2_idx, :c]
    kk = min(k, len(h.level1_idx))
    _, nb = cKDTree(coords[h.level1_idx].astype(np.float64)).query(coords[h.level2_idx].astype(np.float64), k=kk)
    x = x1[nb.reshape(len(y), kk)].reshape(len(y), -1)
    # half the anchors fit, a quarter chooses the ridge weight, the last quarter is scored
    idx = np.random.default_rng(0).permutation(len(y))
    fit, val, test = np.split(idx, [len(y) // 2, 3 * len(y) // 4])
    mu, sd = x[fit].mean(0), x[fit].std(0) + 1e-9
    xs = np.concatenate([(x - mu) / sd, np.ones((len(y), 1))], 1)

    def explained(rows, w):
        resid = y[rows] - xs[rows] @ w
        return 1.0 - float((resid ** 2).sum()) / float(((y[rows] - y[fit].mean(0)) ** 2).sum())

    gram, rhs = xs[fit].T @ xs[fit], xs[fit].T @ y[fit]
    fits = [np.linalg.solve(gram + lam * len(fit) * np.eye(xs.shape[1]), rhs) for lam in 10.0 ** np.arange(-3, 4)]
    r2 = explained(test, max(fits, key=lambda w: explained(val, w)))
    return {"scene": path, "level2": len(h.level2_idx), "channels": values.shape[1], "parent_worse": worse,
            "neighbour_r2": r2}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="Scaffold-GS folders")
    ap.add_argument("--step", type=float, default=0.02, help="quantization step (default 0.02, preset medium)")
    ap.add_argument("--scale", type=int, default=4, help="coarse voxel scale s (default 4)")
    ap.add_argument("-k", type=int, default=8, help="level-1 neighbours of the regression (default 8)")
    args = ap.parse_args(argv)
    print("| scene | level-2 anchors | channels where the parent is a worse mean than the median "
          f"| feature variance explained by {args.k} level-1 neighbours (held out) |")
    print("|---|---:|---:|---:|")
    for path in args.scenes:
        d = diagnose(path, args.step, args.scale, args.k)
        print(f"| {d['scene']} | {d['level2']:,} | {d['parent_worse']} of {d['channels']} | {d['neighbour_r2']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
