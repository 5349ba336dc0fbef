"""The container: a header, then typed data units with length and CRC-32 (spec clause 6).

    stream       = container_header data_unit*
    data_unit    = unit_header payload unit_crc32

Unit types below 0x80 are critical: a decoder that does not know one must stop.
Types 0x80..0xFF are ancillary: a decoder that does not know one skips it.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from enum import IntEnum

from .bitio import BitReader, BitWriter
from .errors import BitstreamError, UnsupportedStreamError
from .syntax import SyntaxStructure, SyntaxVisitor

MAGIC = 0x4C474843  # "LGHC"
VERSION_MAJOR = 1
VERSION_MINOR = 6  # this decoder's version: 1.6
BASE_VERSION_MINOR = 1  # the version of a stream that uses no tool of a later minor version (clause 6.2)
ANCILLARY_UNIT_TYPE_MIN = 0x80
UNIT_HEADER_BYTES = 5
UNIT_CRC_BYTES = 4


class Profile(IntEnum):
    MAIN = 1  # the only profile of versions 0.1 and 0.2


class UnitType(IntEnum):
    SCENE_PARAMETER_SET = 0x01
    RENDER_MODEL = 0x02
    GEOMETRY = 0x03
    ATTRIBUTE = 0x04
    CONTEXT_MODEL = 0x05
    DECODED_SCENE_HASH = 0x06
    GAUSSIAN_PARAMETER_SET = 0x07  # version 0.2: an explicit-Gaussian scene (in place of the scene parameter set)
    TILE_INDEX = 0x08  # version 1: where each tile's units are, its grid cell and point count (clause 7.3.11)
    NEIGHBOUR_PREDICTION = 0x09  # version 1.1: LoD coding of Gaussian attributes from their neighbours (7.3.12)
    STEP_ADJUST = 0x0A  # version 1.2: a step-adjustment index per Gaussian (7.3.13)
    SH_DEGREE = 0x0B  # version 1.3: an SH degree per Gaussian (7.3.14)
    ROTATION_LENGTH = 0x0C  # version 1.4: rotations as a length index and x, y, z, w implied (7.3.15)
    STEP_ADJUST_FLAGS = 0x0D  # version 1.5: the step-adjustment indices as flags (7.3.16)
    SH_TRANSFORM = 0x0E  # version 1.6: the SH rest as transform coefficients of an integer matrix (7.3.17)


class AncillaryUnitType(IntEnum):
    """Ancillary unit types this document defines (clause 6.3): informative; the decoding
    process never depends on them and a decoder that does not know one skips it."""
    SOURCE_INFO = 0x80  # source_info (clause 7.3.10): what the encoder's input scene was


@dataclass
class ContainerHeader(SyntaxStructure):
    syntax_name = "container_header"
    clause = "6.2"
    magic: int = MAGIC
    version_major: int = VERSION_MAJOR
    version_minor: int = BASE_VERSION_MINOR
    profile_idc: int = int(Profile.MAIN)
    reserved_zero_8bits: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(32, self, "magic")
        v.u(8, self, "version_major")
        v.u(8, self, "version_minor")
        v.u(8, self, "profile_idc")
        v.u(8, self, "reserved_zero_8bits")


@dataclass
class UnitHeader(SyntaxStructure):
    syntax_name = "data_unit_header"
    clause = "6.3"
    unit_type: int = 0
    unit_payload_size: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(8, self, "unit_type", lo=1)
        v.u(32, self, "unit_payload_size")


@dataclass
class DataUnit:
    unit_type: int
    payload: bytes
    offset: int = 0  # byte offset of the unit header in the stream (reading only)

    @property
    def size(self) -> int:
        return UNIT_HEADER_BYTES + len(self.payload) + UNIT_CRC_BYTES

    @property
    def is_ancillary(self) -> bool:
        return self.unit_type >= ANCILLARY_UNIT_TYPE_MIN

    @property
    def type_name(self) -> str:
        for kind in (UnitType, AncillaryUnitType):
            if self.unit_type in kind._value2member_map_:
                return kind(self.unit_type).name.lower()
        return f"unknown_0x{self.unit_type:02x}"


CONTAINER_HEADER_BYTES = 8


# A stream's version_minor is the lowest whose tools it uses (clause 6.2): a stream without a
# step_adjust unit is a version 1.1 stream, which a decoder of version 1.1 decodes (and one
# without an sh_degree unit a version 1.2 stream at most).
FIRST_MINOR_OF_UNIT: dict[int, int] = {UnitType.STEP_ADJUST: 2, UnitType.SH_DEGREE: 3, UnitType.ROTATION_LENGTH: 4,
                       UnitType.STEP_ADJUST_FLAGS: 5, UnitType.SH_TRANSFORM: 6}


def version_minor_of(units: list[DataUnit]) -> int:
    return max([BASE_VERSION_MINOR] + [FIRST_MINOR_OF_UNIT.get(u.unit_type, 0) for u in units])


def write_container(units: list[DataUnit], header: ContainerHeader | None = None) -> bytes:
    w = BitWriter()
    (header or ContainerHeader(version_minor=version_minor_of(units))).write_to(w)
    for unit in units:
        start = len(w.getvalue())
        UnitHeader(unit.unit_type, len(unit.payload)).write_to(w)
        w.bytes(unit.payload, "unit_payload")
        crc = zlib.crc32(w.getvalue()[start:])
        w.u(32, crc, "unit_crc32")
    return w.getvalue()


@dataclass
class Container:
    header: ContainerHeader
    units: list[DataUnit] = field(default_factory=list)


def read_container(data: bytes) -> Container:
    """Split a stream into units, checking magic, version, profile, lengths and CRCs."""
    if len(data) < CONTAINER_HEADER_BYTES:
        raise BitstreamError(f"not an LG-HCC stream: {len(data)} bytes is shorter than the container header", condition="E1")
    r = BitReader(data, "container")
    header = ContainerHeader.parse(r)
    if header.magic != MAGIC:
        raise BitstreamError("not an LG-HCC stream: the magic number is not 'LGHC'", condition="E2")
    if header.version_major != VERSION_MAJOR:
        raise UnsupportedStreamError(
            f"stream version {header.version_major}.{header.version_minor} is not supported "
            f"(this decoder reads version {VERSION_MAJOR}.x"
            + ("; version 0 streams were written by lghcc before the tiled format: re-encode the scene)"
               if header.version_major == 0 else ")"), condition="E3")
    if header.profile_idc not in Profile._value2member_map_:
        raise UnsupportedStreamError(f"profile_idc {header.profile_idc} is not supported", condition="E4")
    if header.reserved_zero_8bits != 0:
        raise BitstreamError("container_header.reserved_zero_8bits is not zero", condition="E5")
    units: list[DataUnit] = []
    pos = CONTAINER_HEADER_BYTES
    while pos < len(data):
        if len(data) - pos < UNIT_HEADER_BYTES + UNIT_CRC_BYTES:
            raise BitstreamError(f"stream ends inside the header of data unit {len(units)} at byte {pos}", condition="E6")
        uh = UnitHeader.parse(BitReader(data[pos:pos + UNIT_HEADER_BYTES], f"data unit {len(units)} header"))
        end = pos + UNIT_HEADER_BYTES + uh.unit_payload_size
        if end + UNIT_CRC_BYTES > len(data):
            raise BitstreamError(
                f"data unit {len(units)} (type 0x{uh.unit_type:02x}) declares {uh.unit_payload_size} payload "
                f"bytes but the stream ends {len(data) - pos - UNIT_HEADER_BYTES - UNIT_CRC_BYTES} bytes later", condition="E8")
        stored = int.from_bytes(data[end:end + UNIT_CRC_BYTES], "big")
        if zlib.crc32(data[pos:end]) != stored:
            raise BitstreamError(f"data unit {len(units)} (type 0x{uh.unit_type:02x}) at byte {pos} fails its "
                                 "CRC-32 check: the stream is corrupted", condition="E9")
        units.append(DataUnit(uh.unit_type, bytes(data[pos + UNIT_HEADER_BYTES:end]), pos))
        pos = end + UNIT_CRC_BYTES
    return Container(header, units)
