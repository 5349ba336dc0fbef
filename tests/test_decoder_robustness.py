"""The decoder given damaged or hostile input ends in the project's own error, quickly,
or in a valid decode; never another exception, a hang, or a huge allocation."""

import time
from datetime import timedelta

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from lghcc.common.container import DataUnit, UnitType, read_container, write_container
from lghcc.common.errors import BitstreamError, LghccError, UnsupportedStreamError
from lghcc.common.units import SceneParameterSet
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.stream.encode import EncoderConfig, encode_scene

from scenes import random_scene

STREAM = encode_scene(random_scene(np.random.default_rng(7), 60, mask=True), EncoderConfig(rows_per_chunk=16)).data
UNITS = read_container(STREAM).units
TIME_LIMIT_S = 5.0
# the same examples on every run (CI): no random seed, no example database
REPRODUCIBLE = dict(derandomize=True, database=None, deadline=timedelta(seconds=TIME_LIMIT_S))


def _decode_or_own_error(data: bytes) -> None:
    t0 = time.perf_counter()
    try:
        res = decode_stream(data)
        assert res.scene.num_anchors >= 1
    except LghccError as e:
        assert str(e)
    assert time.perf_counter() - t0 < TIME_LIMIT_S


def _rewrap(units) -> bytes:
    """Re-frame units with valid CRCs, so that damage reaches the payload parsers."""
    return write_container([DataUnit(u.unit_type, u.payload) for u in units])


@settings(max_examples=60, **REPRODUCIBLE)
@given(st.data())
def test_payload_mutations_with_valid_crcs(data):
    units = [DataUnit(u.unit_type, bytearray(u.payload)) for u in UNITS]
    target = data.draw(st.integers(0, len(units) - 1))
    payload = units[target].payload
    op = data.draw(st.sampled_from(["flip", "truncate", "insert", "delete", "extreme"]))
    if op == "flip" and payload:
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, len(payload) - 1))
            payload[i] ^= 1 << data.draw(st.integers(0, 7))
    elif op == "truncate":
        del payload[data.draw(st.integers(0, len(payload))):]
    elif op == "insert":
        i = data.draw(st.integers(0, len(payload)))
        payload[i:i] = data.draw(st.binary(min_size=1, max_size=8))
    elif op == "delete" and payload:
        i = data.draw(st.integers(0, len(payload) - 1))
        del payload[i:i + data.draw(st.integers(1, 8))]
    elif op == "extreme" and payload:
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i:i + 4] = data.draw(st.sampled_from([b"\x00\x00\x00\x00", b"\xff\xff\xff\xff", b"\x00\x00\x00\x01"]))
    units[target] = DataUnit(units[target].unit_type, bytes(payload))
    _decode_or_own_error(_rewrap(units))


@settings(max_examples=40, **REPRODUCIBLE)
@given(st.binary(max_size=400))
def test_random_bytes(blob):
    _decode_or_own_error(blob)
    _decode_or_own_error(STREAM[:8] + blob)


@settings(**REPRODUCIBLE)
@given(st.permutations(list(range(len(UNITS)))))
def test_shuffled_units(perm):
    shuffled = [UNITS[i] for i in perm]
    if perm == list(range(len(UNITS))):
        decode_stream(_rewrap(shuffled))
    else:
        with pytest.raises(BitstreamError):
            decode_stream(_rewrap(shuffled))


def test_truncation_at_every_unit_boundary_is_rejected():
    for cut in range(len(UNITS)):
        with pytest.raises(BitstreamError, match="has no"):
            decode_stream(_rewrap(UNITS[:cut]))


def test_unknown_critical_unit_stops_and_ancillary_unit_is_skipped():
    with pytest.raises(UnsupportedStreamError, match="0x42"):
        decode_stream(_rewrap(UNITS[:2] + [DataUnit(0x42, b"new tool")] + UNITS[2:]))
    res = decode_stream(_rewrap(UNITS[:2] + [DataUnit(0xC0, b"an extension")] + UNITS[2:]))
    assert res.skipped_units and "0xc0" in res.skipped_units[0]


def test_huge_declared_counts_fail_before_allocating():
    sps = SceneParameterSet.from_bytes(UNITS[0].payload)
    sps.num_anchors_minus1 = (1 << 24) - 1
    sps.feature_dim_minus1 = 1023
    units = [DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())] + UNITS[1:]
    t0 = time.perf_counter()
    with pytest.raises(BitstreamError, match="level limit"):
        decode_stream(_rewrap(units))
    assert time.perf_counter() - t0 < 1.0


def test_max_points_option():
    """A cap the caller sets is a resource limit, not a fault of the stream (exit status 4)."""
    from lghcc.common.errors import ResourceLimitError

    with pytest.raises(ResourceLimitError, match=r"maximum 10\b") as e:
        decode_stream(STREAM, max_points=10)
    assert not isinstance(e.value, BitstreamError)


def test_hash_mismatch_is_reported():
    from lghcc.common.errors import HashMismatchError
    units = list(UNITS)
    units[-1] = DataUnit(UnitType.DECODED_SCENE_HASH, units[-1].payload[:1] + bytes(32))
    with pytest.raises(HashMismatchError, match="does not match"):
        decode_stream(_rewrap(units))
    assert decode_stream(_rewrap(units), verify_hash=False).hash_checked is False


def test_a_step_that_overflows_binary32_is_rejected():
    sps = SceneParameterSet.from_bytes(UNITS[0].payload)
    sps.feature_step = 3.0e38  # any feature value of magnitude >= 2 steps overflows
    units = [DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())] + UNITS[1:]
    with pytest.raises(BitstreamError, match="overflows binary32"):
        decode_stream(_rewrap(units))
