"""Geometry coding (common/geometry.py): exact round trips on hard cases, the normative order,
the header syntax, integer probabilities, malformed payloads, and compression on real data."""

from __future__ import annotations

import hashlib
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.bitio import BitReader
from lghcc.common.errors import BitstreamError
from lghcc.common.geometry import (COORD_MAX, COORD_MIN, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS, IDCM_OFF,
                                   GeometryHeader, binary_frequency, decode_geometry, encode_geometry,
                                   normative_order)


def roundtrip(coords, **kw) -> bytes:
    c = np.asarray(coords, dtype=np.int64)
    payload = encode_geometry(c, **kw)
    out = decode_geometry(payload, c.shape[0])
    assert out.dtype == np.int64 and out.shape == c.shape
    np.testing.assert_array_equal(out, c[normative_order(c)])
    return payload


def reference_order(coords: np.ndarray) -> np.ndarray:
    """Morton order written out with Python integers, bit by bit (x most significant)."""
    off = coords - coords.min(axis=0)
    depth = max(int(v).bit_length() for v in off.ravel())

    def key(p):
        k = 0
        for b in range(depth - 1, -1, -1):
            for a in range(3):
                k = (k << 1) | ((int(p[a]) >> b) & 1)
        return k

    return np.array(sorted(range(len(coords)), key=lambda i: key(off[i])), dtype=np.int64)


def surface(n_side: int, seed: int = 0) -> np.ndarray:
    """Voxels of a sphere shell and a plane, densely sampled."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(40 * n_side * n_side, 3))
    s = d / np.linalg.norm(d, axis=1, keepdims=True) * (0.4 * n_side) + n_side / 2
    x, y = rng.uniform(0, n_side, (2, 20 * n_side * n_side))
    p = np.concatenate([s, np.stack([x, y, 0.1 * n_side + 0.05 * x], axis=1)])
    return np.unique(np.floor(p).astype(np.int64), axis=0)


# --- hard cases --------------------------------------------------------------------------------

CUBE16 = np.stack(np.meshgrid(*[np.arange(16)] * 3, indexing="ij"), -1).reshape(-1, 3)


@pytest.mark.parametrize("coords", [
    [[0, 0, 0]],
    [[-7, 12, 3]],
    [[COORD_MIN, COORD_MIN, COORD_MIN]],
    [[COORD_MAX, COORD_MAX, COORD_MAX]],
    [[5, 6, 7], [5, 6, 8]],
    [[0, 0, 0], [1, 1, 1]],
    [[-10**9, 0, 0], [10**9, 0, 0]],
    [[-10**9, -10**9, -10**9], [10**9, 10**9, 10**9]],
    [[COORD_MIN, COORD_MIN, COORD_MIN], [COORD_MAX, COORD_MAX, COORD_MAX]],
    [[COORD_MIN, COORD_MAX, 0], [COORD_MAX, COORD_MIN, 0], [0, 0, COORD_MIN]],
], ids=lambda c: f"{len(c)}pts")
@pytest.mark.parametrize("mode", [IDCM_OFF, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS])
def test_small_and_extreme(coords, mode):
    roundtrip(coords, idcm_mode=mode)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_all_equal_but_one_axis(axis):
    c = np.full((300, 3), 17, dtype=np.int64)
    c[:, axis] = np.arange(-150, 150) * 7
    payload = roundtrip(c)
    h = GeometryHeader.parse(BitReader(payload))
    assert [d for a, d in enumerate(h.geom_bit_depth) if a != axis] == [0, 0]


def test_dense_cube_is_nearly_free():
    payload = roundtrip(CUBE16)
    assert 8 * len(payload) / len(CUBE16) < 0.5


def test_random_sparse_points():
    rng = np.random.default_rng(1)
    c = np.unique(rng.integers(-10**6, 10**6, (2000, 3)), axis=0)
    payload = roundtrip(c)
    # entropy of a random 2000-subset of a (2e6)^3 cube: about log2(8e18 / 2000) + 1.44 = 53.3 bits
    assert 8 * len(payload) / len(c) < 58


def test_huge_random_points():
    rng = np.random.default_rng(2)
    c = np.unique(rng.integers(COORD_MIN, COORD_MAX, (500, 3), endpoint=True), axis=0)
    for mode in (IDCM_OFF, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS):
        roundtrip(c, idcm_mode=mode)


def test_points_on_planes():
    rng = np.random.default_rng(3)
    uv = np.unique(rng.integers(0, 200, (8000, 2)), axis=0)
    for normal in range(3):
        c = np.insert(uv, normal, 42, axis=1)
        payload = roundtrip(c)
        assert 8 * len(payload) / len(c) < 4.5  # 18% of the cells of a plane: ideal 3.76 bits
    tilted = np.unique(np.stack([uv[:, 0], uv[:, 1], (uv[:, 0] + 2 * uv[:, 1]) // 3], axis=1), axis=0)
    roundtrip(tilted)


def test_surface_compresses_well():
    c = surface(64)
    payload = roundtrip(c)
    assert 8 * len(payload) / len(c) < 2.0


def test_input_order_does_not_matter():
    c = surface(32)
    perm = np.random.default_rng(4).permutation(len(c))
    assert encode_geometry(c) == encode_geometry(c[perm])


def test_frozen_payload():
    """The coded format is normative: a change of these bytes is a change of the spec."""
    rng = np.random.default_rng(5)
    c = np.concatenate([surface(40), np.unique(rng.integers(-500, 500, (50, 3)), axis=0)])
    c = np.unique(c, axis=0)
    payload = roundtrip(c)
    assert len(payload) == FROZEN_SIZE
    assert hashlib.sha256(payload).hexdigest() == FROZEN_SHA256


FROZEN_SIZE = 1234
FROZEN_SHA256 = "b6007a10ce79a67af0da2903850a1e55af8424fcd5bad1d53827ccc70b920d40"


coord = st.integers(COORD_MIN, COORD_MAX)


@st.composite
def point_sets(draw):
    n = draw(st.integers(1, 60))
    scale = draw(st.sampled_from([1, 3, 100, 10**5, 2**31]))
    base = draw(st.lists(st.integers(-scale, scale - 1), min_size=3 * n, max_size=3 * n))
    shift = draw(st.tuples(coord, coord, coord))
    c = np.array(base, dtype=np.int64).reshape(n, 3) + np.array(shift, dtype=np.int64)
    c = np.clip(c, COORD_MIN, COORD_MAX)
    return np.unique(c, axis=0)


@settings(max_examples=60, deadline=None)
@given(point_sets(), st.sampled_from([IDCM_OFF, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS]))
def test_roundtrip_property(c, mode):
    roundtrip(c, idcm_mode=mode)


# --- the normative order -----------------------------------------------------------------------

@settings(max_examples=40, deadline=None)
@given(point_sets())
def test_normative_order_is_morton(c):
    order = normative_order(c)
    assert order.dtype == np.int64
    np.testing.assert_array_equal(order, reference_order(c))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(*[st.integers(0, (1 << 21) - 1)] * 3), min_size=1, max_size=40),
       st.integers(0, 2), st.sampled_from([-1, 1]))
def test_morton_step_is_the_key_of_the_neighbour(points, axis, delta):
    """The dilated-arithmetic step (the face neighbours' keys) equals the Morton key of the
    stepped coordinates, up to the edges of the 21-bit grid, where carries would leave the axis."""
    from lghcc.common.geometry import _morton21, _morton_step

    q = np.array(points, dtype=np.int64)
    moved = q.copy()
    moved[:, axis] += delta
    inside = (moved[:, axis] >= 0) & (moved[:, axis] < 1 << 21)
    got = _morton_step(_morton21(q)[inside], axis, delta)
    np.testing.assert_array_equal(got, _morton21(moved[inside]))


@settings(max_examples=40, deadline=None)
@given(point_sets(), st.sampled_from([IDCM_OFF, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS]))
def test_face_neighbours_from_the_parents_equal_the_search(c, mode):
    """The decoder and the encoder carry each node's face neighbours from its parent's
    (_NodeState.nb: _child_neighbours, _kept_neighbours after direct nodes leave); at every depth
    of both they equal the search among the depth's nodes (_face_neighbours), and the round trip
    holds. Deep boxes (beyond 21 bits per axis) take the search's other key."""
    from lghcc.common import geometry as G

    seen = []
    real = G._code_occupancy

    def checked(io, st_, q, depth, remaining, bit_depth, occ_true, nb):
        np.testing.assert_array_equal(nb, G._face_neighbours(q, depth))
        seen.append(depth)
        return real(io, st_, q, depth, remaining, bit_depth, occ_true, nb)

    G._code_occupancy = checked
    try:
        roundtrip(c, idcm_mode=mode)
    finally:
        G._code_occupancy = real
    # without direct coding every set of 2+ points codes some occupancy; with it (IDCM) the root's
    # points may all be coded directly before any occupancy is (e.g. (0, 0, 0) and (0, 0, 2))
    assert seen or c.shape[0] == 1 or mode != IDCM_OFF


def test_normative_order_deep_bounding_box():
    c = np.array([[COORD_MAX, 0, 0], [COORD_MIN, 5, 0], [0, COORD_MAX, COORD_MIN], [1, 1, 1]], dtype=np.int64)
    np.testing.assert_array_equal(normative_order(c), reference_order(c))


# --- header, probabilities ---------------------------------------------------------------------

def test_header_syntax_table_and_roundtrip():
    table = GeometryHeader.syntax_table()
    for name in ("geom_bbox_min_sign_flag", "geom_bbox_min_abs", "geom_bit_depth", "geom_idcm_mode"):
        assert name in table
    h = GeometryHeader.for_min([COORD_MIN, 0, 77], [32, 0, 7], IDCM_NO_NEIGHBOURS)
    data = h.to_bytes()
    back = GeometryHeader.from_bytes(data)
    assert back.bbox_min == [COORD_MIN, 0, 77]
    assert back.geom_bit_depth == [32, 0, 7] and back.geom_idcm_mode == IDCM_NO_NEIGHBOURS
    assert (h.bit_size() + 7) // 8 == len(data)


def test_binary_frequency_is_integer_kt():
    counts = np.array([[0, 0], [3, 1], [0, 10**6], [10**6, 0], [5, 5]])
    f = binary_frequency(counts)
    assert f.dtype == np.int64
    assert f.tolist() == [1 << 23, (3 << 24) // 10, min((2 * 10**6 + 1 << 24) // (2 * 10**6 + 2), (1 << 24) - 1),
                          max((1 << 24) // (2 * 10**6 + 2), 1), 1 << 23]
    assert f.min() >= 1 and f.max() <= (1 << 24) - 1


# --- invalid input -----------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [
    np.zeros((0, 3), dtype=np.int64),
    np.zeros((3, 2), dtype=np.int64),
    np.zeros((2, 3), dtype=np.int64),  # duplicates
    np.array([[0, 0, 2**31]]),
    np.array([[0, 0, -2**31 - 1]]),
    np.array([[0.5, 0, 0]]),
])
def test_invalid_input_raises_value_error(bad):
    with pytest.raises(ValueError):
        encode_geometry(bad)


# --- malformed payloads ------------------------------------------------------------------------

def _decode_or_error(payload: bytes, n: int) -> None:
    t0 = time.perf_counter()
    try:
        out = decode_geometry(payload, n)
    except BitstreamError as e:
        assert str(e)
    else:
        assert out.shape == (n, 3) and out.dtype == np.int64
        assert len(np.unique(out, axis=0)) == n
    assert time.perf_counter() - t0 < 5.0


@pytest.fixture(scope="module")
def sample():
    c = np.unique(np.concatenate([surface(24), np.array([[-10**6, 3, 9], [10**6, -4, 2]])]), axis=0)
    return c, encode_geometry(c)


def test_truncated_payloads(sample):
    c, payload = sample
    for cut in list(range(0, 24)) + list(range(24, len(payload), max(1, len(payload) // 40))):
        with pytest.raises(BitstreamError):
            decode_geometry(payload[:cut], len(c))


def test_wrong_num_anchors(sample):
    c, payload = sample
    for n in (0, -1, 1, len(c) - 1, len(c) + 1, 2 * len(c)):
        with pytest.raises(BitstreamError):
            decode_geometry(payload, n)


def test_bit_flips(sample):
    c, payload = sample
    rng = np.random.default_rng(6)
    for pos in rng.choice(8 * len(payload), 60, replace=False):
        b = bytearray(payload)
        b[pos // 8] ^= 1 << (pos % 8)
        _decode_or_error(bytes(b), len(c))


def test_random_bytes():
    rng = np.random.default_rng(7)
    for i in range(40):
        data = rng.integers(0, 256, int(rng.integers(0, 200)), dtype=np.uint8).tobytes()
        _decode_or_error(data, int(rng.integers(1, 3000)))


def test_header_only_edge_cases():
    # a 1-anchor payload has no coded data; trailing words are an error
    payload = encode_geometry(np.array([[4, 5, 6]]))
    assert decode_geometry(payload, 1).tolist() == [[4, 5, 6]]
    with pytest.raises(BitstreamError):
        decode_geometry(payload + b"\0\0\0\x01", 1)
    with pytest.raises(BitstreamError):
        decode_geometry(payload, 2)  # zero bit depth holds one point only


# --- real data ---------------------------------------------------------------------------------

def _voxelize(xyz: np.ndarray, bits: int) -> np.ndarray:
    lo = xyz.min(axis=0)
    side = float((xyz.max(axis=0) - lo).max())
    return np.unique(np.floor((xyz - lo) / side * ((1 << bits) - 1) + 0.5).astype(np.int64), axis=0)


@pytest.mark.data
def test_garden_and_donut_beat_gpcc(shared_data):
    garden = shared_data / "garden" / "test_garden.npz"
    donut = shared_data / "donut" / "donut.ply"
    if not garden.exists() or not donut.exists():
        pytest.skip("garden or donut data missing")
    g = _voxelize(np.load(garden)["means3d"].astype(np.float64), 12)
    from lghcc.formats.ply import read_ply

    v = read_ply(donut)
    d = _voxelize(np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64), 12)
    for coords, gpcc in ((g, 12.0), (d, 18.0)):
        payload = roundtrip(coords)
        assert 8 * len(payload) / len(coords) <= gpcc


@pytest.mark.slow
def test_million_anchors_fast():
    c = surface(700)
    assert len(c) > 900_000
    t0 = time.perf_counter()
    payload = encode_geometry(c)
    t1 = time.perf_counter()
    out = decode_geometry(payload, len(c))
    t2 = time.perf_counter()
    np.testing.assert_array_equal(out, c[normative_order(c)])
    assert t1 - t0 < 20 and t2 - t1 < 20


def test_spec_holds_the_generated_header_table():
    from pathlib import Path

    spec = (Path(__file__).resolve().parents[1] / "spec" / "geometry.md").read_text()
    assert GeometryHeader.syntax_table() in spec
