"""Small scene builders and hypothesis strategies shared by the tests."""

import numpy as np
from hypothesis import strategies as st

from lghcc.common.scene import AnchorScene, RenderMLP


def random_scene(rng: np.random.Generator, n: int, c: int = 4, k: int = 2, spread: int = 50,
                 value_scale: float = 1.0, mask: bool = False, with_mlps: bool = True) -> AnchorScene:
    coords = np.unique(rng.integers(-spread, spread + 1, size=(n * 2 + 4, 3)), axis=0)
    coords = coords[rng.permutation(len(coords))[:n]]
    n = len(coords)
    mlps = {}
    if with_mlps:
        mlps = {"opacity": RenderMLP([rng.normal(size=(c, c + 4)).astype(np.float32),
                                      rng.normal(size=(k, c)).astype(np.float32)],
                                     [rng.normal(size=c).astype(np.float32), np.zeros(k, np.float32)],
                                     ["relu", "tanh"])}
    return AnchorScene(
        coords=coords.astype(np.int64), voxel_size=0.01, origin=np.zeros(3, np.float32),
        features=(value_scale * rng.normal(size=(n, c))).astype(np.float32),
        scalings=rng.normal(size=(n, 6)).astype(np.float32),
        offsets=rng.normal(size=(n, k, 3)).astype(np.float32),
        offset_mask=(rng.random((n, k)) < 0.7) if mask else None, mlps=mlps)


@st.composite
def scenes(draw):
    """Small scenes spanning the hard cases: one anchor, far coordinates, constant and extreme values."""
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    n = draw(st.integers(1, 40))
    c = draw(st.integers(1, 6))
    k = draw(st.integers(1, 3))
    spread = draw(st.sampled_from([0, 1, 3, 1000, 10 ** 6, 2 ** 30]))
    scale = draw(st.sampled_from([0.0, 1e-3, 1.0, 1e3, 1e6]))
    s = random_scene(rng, n, c, k, spread=spread, value_scale=scale, mask=draw(st.booleans()),
                     with_mlps=draw(st.booleans()))
    s.voxel_size = draw(st.sampled_from([1e-30, 1e-6, 0.01, 1.0, 1e6, 1e30]))
    if draw(st.booleans()):
        s.features[:] = draw(st.sampled_from([0.0, 1.0, -7.5]))
    return s
