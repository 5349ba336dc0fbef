"""The decoded-scene hash (spec clause 12): SHA-256 over a canonical serialization of
everything the decoder outputs, so that a decoder can prove it rebuilt the scene the
encoder meant, bit for bit (as video codecs carry a decoded picture hash).

Serialization of an explicit-Gaussian scene (``gaussian_scene_digest``), little-endian:
  b"LGHC-gaussians-v1", num_gaussians, sh_degree (int64 each)
  voxel_size (float32), origin (3 x float32)
  coords [N,3] int64, in normative order
  sh [N,S,3], opacity [N], log scales [N,3], rotations [N,4] (float32)

Serialization of an anchor scene, all little-endian, in this order:
  b"LGHC-scene-v1", num_anchors, feature_dim, num_offsets (int64 each)
  voxel_size (float32), origin (3 x float32)
  coords [N,3] int64, in normative order
  features [N,C], scalings [N,6], offsets [N,K,3] (float32)
  offset_mask [N,K] as uint8 when present, else nothing; a presence byte precedes it
  per render MLP in role order (opacity, cov, color, feature_bank) when present:
    role index (int64), number of layers (int64), then per layer: activation index (int64),
    weight [out,in] float32, bias [out] float32
"""

from __future__ import annotations

import hashlib

import numpy as np

from .scene import ACTIVATIONS, MLP_ROLES, AnchorScene, GaussianScene


HASH_BLOCK_ROWS = 1 << 16


def _i64(*values: int) -> bytes:
    return np.asarray(values, dtype="<i8").tobytes()


def _update_rows(h, arr: np.ndarray) -> None:
    for lo in range(0, arr.shape[0], HASH_BLOCK_ROWS):  # row blocks: no full-size copies
        h.update(np.ascontiguousarray(arr[lo:lo + HASH_BLOCK_ROWS], dtype="<f4").data)


def gaussian_scene_digest(scene: GaussianScene) -> bytes:
    """SHA-256 of a decoded explicit-Gaussian scene (on its grid)."""
    if scene.coords is None:
        raise ValueError("the hash covers a scene on its coding grid (coords, voxel size, origin)")
    h = hashlib.sha256()
    h.update(b"LGHC-gaussians-v1")
    h.update(_i64(scene.num_gaussians, scene.sh_degree))
    h.update(np.asarray([scene.voxel_size], dtype="<f4").tobytes())
    h.update(np.asarray(scene.origin, dtype="<f4").tobytes())
    h.update(np.ascontiguousarray(scene.coords, dtype="<i8").data)
    for arr in (scene.sh, scene.opacity, scene.log_scales, scene.rotations):
        _update_rows(h, arr)
    return h.digest()


def digest_of(scene: AnchorScene | GaussianScene) -> bytes:
    """The decoded-scene hash of either kind of scene."""
    return gaussian_scene_digest(scene) if isinstance(scene, GaussianScene) else scene_digest(scene)


def scene_digest(scene: AnchorScene) -> bytes:
    h = hashlib.sha256()
    h.update(b"LGHC-scene-v1")
    h.update(_i64(scene.num_anchors, scene.feature_dim, scene.num_offsets))
    h.update(np.asarray([scene.voxel_size], dtype="<f4").tobytes())
    h.update(np.asarray(scene.origin, dtype="<f4").tobytes())
    h.update(np.ascontiguousarray(scene.coords, dtype="<i8").data)
    for arr in (scene.features, scene.scalings, scene.offsets):
        for lo in range(0, arr.shape[0], HASH_BLOCK_ROWS):  # row blocks: no full-size copies
            h.update(np.ascontiguousarray(arr[lo:lo + HASH_BLOCK_ROWS], dtype="<f4").data)
    if scene.offset_mask is None:
        h.update(b"\x00")
    else:
        h.update(b"\x01")
        h.update(np.ascontiguousarray(scene.offset_mask, dtype=np.uint8).tobytes())
    for role_idx, role in enumerate(MLP_ROLES):
        mlp = scene.mlps.get(role)
        if mlp is None:
            continue
        h.update(_i64(role_idx, len(mlp.weights)))
        for w, b, a in zip(mlp.weights, mlp.biases, mlp.activations):
            h.update(_i64(ACTIVATIONS.index(a)))
            h.update(np.ascontiguousarray(w, dtype="<f4").tobytes())
            h.update(np.ascontiguousarray(b, dtype="<f4").tobytes())
    return h.digest()
