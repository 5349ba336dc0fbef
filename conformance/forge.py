"""Small, legal streams that make a decoder allocate a lot (issue 14): the test of the memory
bound that decoder/limits.py enforces.

``dense_zero_stream`` writes, without the encoder, a stream of a dense cube of side^3 anchors
with C features and K offsets whose attributes are all zero: the geometry of a full cube codes
in a few hundred bytes, and the one attribute chunk is empty, which decodes every value as bin 0
of its table (spec 10.6.4), i.e. residual -L_0, so a prior mean of L_0 makes every quantized
value 0. With side 128 (2^21 anchors) and C + 6 + 3K = 1024 channels the stream is about 2 kB,
within every level limit of spec clause 8 (N * M = 2^31), and its attribute array alone is
8 GiB of binary32. The decoded-scene hash is that of the all-zero scene (``exact_hash``: it
hashes the 8 GiB in row blocks, tens of seconds) or 32 zero bytes (the stream is then refused
for its hash, but only after decoding, which is what the memory bound prevents).
"""

from __future__ import annotations

import numpy as np

from ..common.container import DataUnit, UnitType, write_container
from ..common.entropy.tables import HALF_WIDTHS
from ..common.geometry import encode_geometry, normative_order
from ..common.units import AttributeUnitHeader, DecodedSceneHashUnit, SceneParameterSet


def dense_cube(side: int) -> np.ndarray:
    """int64 [side^3, 3]: every voxel of a cube, in the normative order."""
    ax = np.arange(side, dtype=np.int64)
    c = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    return c[normative_order(c)]


def zero_scene_digest(coords: np.ndarray, feature_dim: int, num_offsets: int) -> bytes:
    """The decoded-scene hash (spec clause 12) of anchors at ``coords`` whose attributes are all
    zero, voxel size 1, origin 0, no offset mask and no render model, without holding the
    attribute arrays (zero-stride views, hashed in row blocks by lghcc.common.hashing)."""
    from ..common.hashing import scene_digest
    from ..common.scene import AnchorScene

    n = coords.shape[0]
    zero = np.zeros(1, np.float32)
    scene = AnchorScene(coords=coords, voxel_size=1.0, origin=np.zeros(3, np.float32),
                        features=np.broadcast_to(zero, (n, feature_dim)), scalings=np.broadcast_to(zero, (n, 6)),
                        offsets=np.broadcast_to(zero, (n, num_offsets, 3)))
    return scene_digest(scene)


def dense_zero_stream(side: int = 128, feature_dim: int = 1015, num_offsets: int = 1, exact_hash: bool = False,
                      coords: np.ndarray | None = None) -> bytes:
    """A legal stream of side^3 anchors x (feature_dim + 6 + 3 num_offsets) channels, all zero
    (module docstring). ``coords``: the cube, when the caller has it already (dense_cube(side))."""
    coords = dense_cube(side) if coords is None else coords
    n = coords.shape[0]
    m = feature_dim + 6 + 3 * num_offsets
    sps = SceneParameterSet(num_anchors_minus1=n - 1, feature_dim_minus1=feature_dim - 1,
                            num_offsets_minus1=num_offsets - 1)
    level = 0  # bin 0 of level 0 is residual -L_0: a prior mean of L_0 decodes every value as q = 0
    h = AttributeUnitHeader(num_channels=m, num_offsets=num_offsets, num_rows=n, context_model_id=0,
                            prior_mean=[int(HALF_WIDTHS[level])] * m, prior_level=[level] * m,
                            rows_per_chunk_minus1=n - 1, chunk_size=[0])
    digest = zero_scene_digest(coords, feature_dim, num_offsets) if exact_hash else bytes(32)
    return write_container([
        DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes()),
        DataUnit(UnitType.GEOMETRY, encode_geometry(coords)),
        DataUnit(UnitType.ATTRIBUTE, h.to_bytes()),
        DataUnit(UnitType.DECODED_SCENE_HASH, DecodedSceneHashUnit(scene_hash=digest).to_bytes())])
