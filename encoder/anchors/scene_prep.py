"""Preparing an input scene for coding (informative)."""

from __future__ import annotations

import numpy as np

from ...common.scene import AnchorScene


def merge_duplicate_anchors(scene: AnchorScene) -> tuple[AnchorScene, int]:
    """Anchors that share a voxel become one: attributes averaged, offset masks OR-ed.
    Returns the merged scene and how many anchors were merged away."""
    uniq, inverse, counts = np.unique(scene.coords, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if uniq.shape[0] == scene.num_anchors:
        return scene, 0

    def mean(a: np.ndarray) -> np.ndarray:
        out = np.zeros((uniq.shape[0],) + a.shape[1:], dtype=np.float64)
        np.add.at(out, inverse, a.astype(np.float64))
        return (out / counts.reshape((-1,) + (1,) * (a.ndim - 1))).astype(np.float32)

    mask = None
    if scene.offset_mask is not None:
        mask = np.zeros((uniq.shape[0], scene.num_offsets), dtype=bool)
        np.logical_or.at(mask, inverse, scene.offset_mask.astype(bool))
    merged = AnchorScene(coords=uniq.astype(np.int64), voxel_size=scene.voxel_size, origin=scene.origin,
                         features=mean(scene.features), scalings=mean(scene.scalings),
                         offsets=mean(scene.offsets), offset_mask=mask, mlps=scene.mlps,
                         extra={k: mean(v) for k, v in scene.extra.items()})
    return merged, scene.num_anchors - uniq.shape[0]
