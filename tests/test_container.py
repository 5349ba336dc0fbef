"""The container: framing, CRC, unknown units, truncation."""

import zlib

import pytest
from hypothesis import given, strategies as st

from lghcc.common.container import DataUnit, read_container, write_container
from lghcc.common.errors import BitstreamError, UnsupportedStreamError

units_strategy = st.lists(st.builds(DataUnit, st.integers(1, 255), st.binary(max_size=300)), max_size=8)


@given(units_strategy)
def test_round_trip(units):
    data = write_container(units)
    back = read_container(data)
    assert [(u.unit_type, u.payload) for u in back.units] == [(u.unit_type, u.payload) for u in units]
    assert sum(u.size for u in back.units) + 8 == len(data)


@given(units_strategy.filter(lambda u: u), st.data())
def test_any_truncation_or_bit_flip_is_detected(units, data):
    stream = write_container(units)
    cut = data.draw(st.integers(0, len(stream) - 1))
    boundaries, pos = {8}, 8
    for u in units:
        pos += 5 + len(u.payload) + 4
        boundaries.add(pos)
    if cut in boundaries:  # a whole number of units: valid, shorter (the decoder misses required units)
        assert len(read_container(stream[:cut]).units) < len(units)
    else:
        with pytest.raises(BitstreamError):
            read_container(stream[:cut])
    pos = data.draw(st.integers(8, len(stream) - 1))
    bit = data.draw(st.integers(0, 7))
    flipped = bytearray(stream)
    flipped[pos] ^= 1 << bit
    with pytest.raises(BitstreamError):
        read_container(bytes(flipped))


def test_wrong_magic_version_profile():
    good = write_container([])
    with pytest.raises(BitstreamError, match="magic"):
        read_container(b"XXXX" + good[4:])
    with pytest.raises(UnsupportedStreamError, match="version 7"):
        read_container(good[:4] + b"\x07" + good[5:])
    with pytest.raises(UnsupportedStreamError, match="profile"):
        read_container(good[:6] + b"\x09" + good[7:])
    with pytest.raises(BitstreamError, match="shorter"):
        read_container(b"LG")


def test_length_field_larger_than_stream_is_named():
    data = bytearray(write_container([DataUnit(3, b"abc")]))
    data[9:13] = (2 ** 32 - 1).to_bytes(4, "big")
    with pytest.raises(BitstreamError, match=r"4294967295 payload bytes"):
        read_container(bytes(data))


def test_crc_covers_header_and_payload():
    data = write_container([DataUnit(3, b"payload")])
    crc = int.from_bytes(data[-4:], "big")
    assert crc == zlib.crc32(data[8:-4])
