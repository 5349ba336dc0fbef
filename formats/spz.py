"""Niantic SPZ (``.spz``): read versions 2, 3 and 4, write version 4 (or 2 and 3 on request).

Layout as the reference implementation defines it: nianticlabs/spz, ``src/cc/load-spz.cc``,
``src/cc/load-spz.h``, ``src/cc/splat-utils.h`` and ``README.md`` at commit
21715c3b7a609ea6fb7c69b8ae42181a12b59f22 (2026-07-10; LATEST_SPZ_HEADER_VERSION = 4). It is
also what @playcanvas/splat-transform 3.7.0 writes (through @adobe/spz 0.2.3, the reference
compiled to WASM) and reads (its own ``readSpz``).

Containers:

- v2, v3: one gzip stream holding a 16-byte header (u32 magic 0x5053474E "NGSP", u32
  version, u32 numPoints, u8 shDegree, u8 fractionalBits, u8 flags, u8 reserved) and then the
  attributes one after the other: positions, alphas, colors, scales, rotations, SH.
- v4: not gzip. A 32-byte plaintext header (magic, version, numPoints, shDegree,
  fractionalBits, flags, u8 numStreams, u32 tocByteOffset, 12 reserved bytes), optional
  extension records up to tocByteOffset, a table of contents of numStreams x (u64
  compressedSize, u64 uncompressedSize), then one zstd frame per attribute in the order above;
  the SH stream is left out when it is empty (degree 0: 5 streams, else 6). The reference
  compresses with zstd level 12; so does this writer.

Attributes, per Gaussian (all little-endian, attribute-major):

- positions: 3 x 24-bit signed fixed point with ``fractionalBits`` fraction bits;
- alphas: u8 = round(sigmoid(opacity) * 255);
- colors: u8 = round(f_dc * 0.15 * 255 + 127.5) (0.15 is the reference's ``colorScale``);
- scales: u8 = round((log scale + 10) * 16);
- rotations: v2 three u8 (x, y, z of the unit quaternion with w >= 0, (q + 1) * 127.5);
  v3 and later "smallest three": one u32 with the index of the largest |component| (x, y, z,
  w order) in bits 30-31 and the other three, in order, as sign bit + 9-bit magnitude
  (|q| / sqrt(1/2) * 511) in bits 20-29, 10-19 and 0-9, for the quaternion whose largest
  component is positive;
- SH: (degree + 1)^2 - 1 coefficients x 3 channels (channel fastest), u8 = q + 128 with
  q = round(128 x), then rounded to the centre of a bucket of 2^(8 - bits) codes: 5 bits for
  band 1, 4 for the higher bands (the reference's defaults; a reader needs no bits).

The writer rounds exactly as the reference does (C ``std::round``, binary32 arithmetic), so
our files decode to the same values as its files; it chooses ``fractionalBits`` = 12 like the
reference unless a position needs the range, then the largest that fits (the reference keeps 12
and its positions wrap past +-2048; readers take the bits from the header).

Coordinates: stored as given, without conversion, i.e. in the PLY's own axes. The reference's
README calls RUB the default, but its ``ply_to_spz`` and its library defaults (``from`` and
``to`` = UNSPECIFIED) convert nothing, and splat-transform 3.7.0 writes and reads the same way,
so a PLY -> SPZ -> PLY trip through any of them keeps the axes. A file that declares its axes
with the ``SPZ_ADOBE_coordinate_system`` extension (type 0xADBE0003) is converted from them to
RDF (PLY's axes) by flipping axes, as the reference's ``coordinateConverter`` does; the rotated
family (systems 9-16, a 90-degree turn) is refused.

Decoding follows the reference except where it would produce infinities: alpha bytes 0 and 255
decode to the logit of 1e-6 and 1 - 1e-6 (as splat-transform; the reference gives -inf and
+inf). Values are computed in binary64 and rounded once to binary32. Not kept: the
``antialiased`` flag (the scene has no field for it; ``write_spz`` can set it), extension data
other than the coordinate system, and SH degree 4 (refused: the scene holds degrees 0-3).
"""

from __future__ import annotations

import gzip
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import zstandard

from ..common.errors import InputError
from ..app.fileio import atomic_write_bytes
from ..common.scene import SH_DEGREE_MAX, GaussianScene, sh_coeffs_per_channel
from .opacity import alpha_logits

SPZ_MAGIC = 0x5053474E  # "NGSP" in file order
SPZ_VERSION_LATEST = 4
SPZ_VERSIONS_READ = (2, 3, 4)
FLAG_ANTIALIASED = 0x1
FLAG_HAS_EXTENSIONS = 0x2
LEGACY_HEADER = struct.Struct("<IIIBBBB")  # magic, version, numPoints, shDegree, fractionalBits, flags, reserved
HEADER_V4 = struct.Struct("<IIIBBBBI12s")  # ... flags, numStreams, tocByteOffset, reserved[12]
TOC_ENTRY = struct.Struct("<QQ")  # compressedSize, uncompressedSize
ZSTD_LEVEL = 12  # the reference's compressZstd
COLOR_SCALE = np.float32(0.15)
FRACTIONAL_BITS = 12
SH1_BITS, SH_REST_BITS = 5, 4
MIN_BYTES_PER_POINT = 9  # the reference's bound on numPoints: the positions stream alone ...
MAX_COMPRESSION_RATIO = 1024  # ... compressed at most this much
MAX_LEGACY_EXTENSION_BYTES = 1 << 20
EXT_COORDINATE_SYSTEM = 0xADBE0003
COORDINATE_SYSTEMS = ("UNSPECIFIED", "LDB", "RDB", "LUB", "RUB", "LDF", "RDF", "LUF", "RUF",
                      "LFD", "RFD", "LFU", "RFU", "LBD", "RBD", "LBU", "RBU")
RDF = 6


def is_spz_bytes(head: bytes) -> bool:
    """True when ``head`` (the first bytes of a file) starts like an SPZ file: "NGSP" (v4) or
    gzip whose first member inflates to "NGSP" (v2, v3)."""
    if head[:4] == b"NGSP":
        return True
    if head[:2] != b"\x1f\x8b":
        return False
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, 4)[:4] == b"NGSP"
    except zlib.error:
        return False


# --- quantization, exactly as load-spz.cc packs ------------------------------------------

def _round(x: np.ndarray) -> np.ndarray:
    """C ``std::round`` (halves away from zero) of binary32 values, exact: in binary64,
    x + 0.5 does not round for the magnitudes that reach here."""
    x = np.asarray(x, np.float64)
    return np.trunc(x + np.copysign(0.5, x))


def _to_u8(x: np.ndarray) -> np.ndarray:
    """The reference's ``toUint8``: clamp(round(x), 0, 255)."""
    return np.clip(_round(x), 0, 255).astype(np.uint8)


def _quantize_sh(x: np.ndarray, bits: int) -> np.ndarray:
    """The reference's ``quantizeSH``: q = round(128 x) + 128, moved to the centre of its
    bucket of 2^(8 - bits) codes, then clamped (so the top bucket's centre 256 becomes 255)."""
    bucket = 1 << (8 - bits)
    q = _round(np.clip(np.asarray(x, np.float32) * np.float32(128), -1e6, 1e6)).astype(np.int64) + 128
    q = (q + bucket // 2) // bucket * bucket  # floor and C's truncation agree after the clamp
    return np.clip(q, 0, 255).astype(np.uint8)


def _fractional_bits(means: np.ndarray, what: str) -> int:
    """12 (the reference's choice) unless a coordinate needs more integer bits."""
    hi, lo = np.float32(means.max(initial=0.0)), np.float32(means.min(initial=0.0))
    for fb in range(FRACTIONAL_BITS, -1, -1):
        scale = np.float32(1 << fb)
        if _round(hi * scale) <= (1 << 23) - 1 and _round(lo * scale) >= -(1 << 23):
            return fb
    raise InputError(f"{what}: a position coordinate ({float(lo):g} .. {float(hi):g}) exceeds SPZ's 24-bit "
                     f"fixed-point range (-{1 << 23} .. {(1 << 23) - 1})")


def _pack_positions(means: np.ndarray, fb: int) -> bytes:
    fixed = _round(means.astype(np.float32) * np.float32(1 << fb)).astype(np.int32).reshape(-1)
    b = fixed.astype("<i4").view(np.uint8).reshape(-1, 4)[:, :3]
    return b.tobytes()


def _normalized_xyzw(rotations: np.ndarray) -> np.ndarray:
    """Scene quaternions (w, x, y, z) -> unit (x, y, z, w) in binary32, with the reference's
    operations (q / sqrt(((x x + y y) + z z) + w w)). Each quaternion is first divided by a power
    of two near its largest |component|: exact, so the result is the same bits, but no square
    overflows or underflows."""
    q = rotations.astype(np.float32)[:, [1, 2, 3, 0]]
    _, e = np.frexp(np.abs(q).max(axis=1))
    q = np.ldexp(q, -e[:, None]).astype(np.float32)
    sq = q * q
    norm = np.sqrt(((sq[:, 0] + sq[:, 1]) + sq[:, 2]) + sq[:, 3])
    return (q / norm[:, None]).astype(np.float32)


def _pack_rotations_smallest_three(rotations: np.ndarray) -> bytes:
    q = _normalized_xyzw(rotations)
    largest = np.argmax(np.abs(q), axis=1)  # first maximum, as the reference's strict '>' scan
    negate = np.take_along_axis(q, largest[:, None], 1)[:, 0] < 0
    comp = largest.astype(np.uint32)
    scale = np.float32((1 << 9) - 1)
    sqrt1_2 = np.float32(0.707106781186547524401)
    for i in range(4):
        use = largest != i
        negbit = ((q[:, i] < 0) ^ negate).astype(np.uint32)
        mag = np.floor(scale * (np.abs(q[:, i]) / sqrt1_2) + np.float32(0.5)).astype(np.uint32)
        comp = np.where(use, (comp << 10) | (negbit << 9) | mag, comp)
    return comp.astype("<u4").tobytes()


def _pack_rotations_first_three(rotations: np.ndarray) -> bytes:
    q = _normalized_xyzw(rotations)
    q = q * np.where(q[:, 3] < 0, np.float32(-127.5), np.float32(127.5))[:, None] + np.float32(127.5)
    return _to_u8(q[:, :3]).tobytes()


def _pack_attributes(scene: GaussianScene, version: int = SPZ_VERSION_LATEST) -> tuple[int, list[bytes]]:
    """(fractionalBits, [positions, alphas, colors, scales, rotations, sh]) as the reference's
    ``packGaussians`` lays them out for ``version``."""
    what = "SPZ writer"
    fb = _fractional_bits(scene.means, what)
    op = scene.opacity.astype(np.float32)
    with np.errstate(over="ignore"):
        alpha = np.float32(1) / (np.float32(1) + np.exp(-op))
    colors = scene.sh[:, 0].astype(np.float32) * (COLOR_SCALE * np.float32(255)) + np.float32(0.5 * 255)
    scales = (scene.log_scales.astype(np.float32) + np.float32(10)) * np.float32(16)
    rest = scene.sh[:, 1:].astype(np.float32)  # [N, K - 1, 3]: coefficient-major, channel fastest
    sh = np.concatenate([_quantize_sh(rest[:, :3], SH1_BITS), _quantize_sh(rest[:, 3:], SH_REST_BITS)], axis=1)
    rotations = (_pack_rotations_smallest_three if version >= 3 else _pack_rotations_first_three)(scene.rotations)
    return fb, [_pack_positions(scene.means, fb), _to_u8(alpha * np.float32(255)).tobytes(),
                _to_u8(colors).tobytes(), _to_u8(scales).tobytes(), rotations, sh.tobytes()]


def encode_spz(scene: GaussianScene, version: int = SPZ_VERSION_LATEST, antialiased: bool = False) -> bytes:
    """The SPZ file for ``scene`` (validated first): version 4 by default (zstd streams),
    2 or 3 for older readers (gzip)."""
    if version not in SPZ_VERSIONS_READ:
        raise InputError(f"SPZ writer: version must be one of {SPZ_VERSIONS_READ}, got {version}")
    scene.validate("SPZ writer")
    n, degree = scene.num_gaussians, scene.sh_degree
    if n > (1 << 31) - 1:
        raise InputError(f"SPZ writer: {n} Gaussians exceed the format's 2^31 - 1")
    fb, streams = _pack_attributes(scene, version)
    flags = FLAG_ANTIALIASED if antialiased else 0
    if version < 4:
        header = LEGACY_HEADER.pack(SPZ_MAGIC, version, n, degree, fb, flags, 0)
        # the reference's compressGzipped: default level, no name and mtime 0 in the gzip header
        return gzip.compress(header + b"".join(streams), compresslevel=6, mtime=0)
    streams = [s for s in streams if s]
    cctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    chunks = [cctx.compress(s) for s in streams]
    header = HEADER_V4.pack(SPZ_MAGIC, version, n, degree, fb, flags, len(chunks), HEADER_V4.size, bytes(12))
    toc = b"".join(TOC_ENTRY.pack(len(c), len(s)) for c, s in zip(chunks, streams))
    return header + toc + b"".join(chunks)


def write_spz(path: str | os.PathLike, scene: GaussianScene, version: int = SPZ_VERSION_LATEST,
              antialiased: bool = False) -> None:
    """Write ``scene`` as an SPZ file, atomically (see ``encode_spz``)."""
    atomic_write_bytes(path, encode_spz(scene, version, antialiased))


# --- decoding -----------------------------------------------------------------------------

def _stream_sizes(n: int, degree: int, version: int) -> list[int]:
    """Bytes of positions, alphas, colors, scales, rotations and SH for n Gaussians."""
    return [9 * n, n, 3 * n, 3 * n, (4 if version >= 3 else 3) * n, 3 * (sh_coeffs_per_channel(degree) - 1) * n]


def _parse_extensions(block: bytes, what: str) -> int:
    """The coordinate system declared by SPZ_ADOBE_coordinate_system in a block of extension
    records (u32 type, u32 byteLength, payload), or RDF (no conversion) when none is."""
    system, pos = RDF, 0
    while pos < len(block):
        if pos + 8 > len(block):
            raise InputError(f"{what}: truncated extension record at byte {pos} of the extension block")
        kind, length = struct.unpack_from("<II", block, pos)
        if pos + 8 + length > len(block):
            raise InputError(f"{what}: extension 0x{kind:08X} claims {length} bytes, more than the block holds")
        if kind == EXT_COORDINATE_SYSTEM:
            if length < 4:
                raise InputError(f"{what}: SPZ_ADOBE_coordinate_system extension has {length} payload bytes, needs 4")
            value = struct.unpack_from("<I", block, pos + 8)[0]
            if value >= len(COORDINATE_SYSTEMS):
                raise InputError(f"{what}: SPZ_ADOBE_coordinate_system names unknown coordinate system {value}")
            system = value or COORDINATE_SYSTEMS.index("RUB")  # the reference resolves UNSPECIFIED to RUB
        pos += 8 + length
    return system


def axis_flips(system: int) -> np.ndarray:
    """(sx, sy, sz) in {-1, 1}: the flips that take coordinates in ``system`` (one of the
    standard family, 1-8) to RDF, as the reference's ``axesMatch``."""
    a, b = system - 1, RDF - 1
    return np.array([1.0 if ((a >> k) & 1) == ((b >> k) & 1) else -1.0 for k in range(3)])


def flip_axes(scene: GaussianScene, flips: np.ndarray) -> GaussianScene:
    """The scene with its axes flipped by ``flips`` = (sx, sy, sz): positions, quaternion vector
    part (x by sy sz, y by sx sz, z by sx sy) and each SH coefficient by the parity of its basis
    function (the reference's flipP, flipQ and flipSh)."""
    x, y, z = (float(v) for v in flips)
    sh_signs = [1.0, y, z, x, x * y, y * z, 1.0, x * z, 1.0, y, x * y * z, y, z, x, z, x]
    k = scene.sh.shape[1]
    rot = scene.rotations * np.array([1.0, y * z, x * z, x * y], np.float32)
    return GaussianScene((scene.means * np.asarray(flips, np.float32)).astype(np.float32),
                         (scene.sh * np.array(sh_signs[:k], np.float32)[None, :, None]).astype(np.float32),
                         scene.opacity, scene.log_scales, rot.astype(np.float32))


def _unpack(n: int, degree: int, fb: int, version: int, streams: list[bytes]) -> GaussianScene:
    pos_b = np.frombuffer(streams[0], np.uint8).reshape(n * 3, 3).astype(np.int32)
    fixed = pos_b[:, 0] | (pos_b[:, 1] << 8) | (pos_b[:, 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    means = (fixed.astype(np.float64) * 2.0 ** -fb).reshape(n, 3)
    opacity = alpha_logits(np.frombuffer(streams[1], np.uint8))
    color = (np.frombuffer(streams[2], np.uint8).reshape(n, 3) / 255.0 - 0.5) / 0.15
    log_scales = np.frombuffer(streams[3], np.uint8).reshape(n, 3) / 16.0 - 10.0
    if version >= 3:
        comp = np.frombuffer(streams[4], "<u4").astype(np.int64)
        largest = comp >> 30
        q = np.zeros((n, 4))  # x, y, z, w
        for i in range(3, -1, -1):  # the last packed component sits in the lowest bits
            use = largest != i
            v = np.sqrt(0.5) * (comp & 511) / 511.0
            q[:, i] = np.where(use, np.where((comp >> 9) & 1, -v, v), 0.0)
            comp = np.where(use, comp >> 10, comp)
        rest = np.maximum(0.0, 1.0 - (q * q).sum(axis=1))
        q[np.arange(n), largest] = np.sqrt(rest)
    else:
        xyz = np.frombuffer(streams[4], np.uint8).reshape(n, 3) / 127.5 - 1.0
        q = np.concatenate([xyz, np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(axis=1)))[:, None]], axis=1)
    k = sh_coeffs_per_channel(degree)
    sh = np.zeros((n, k, 3))
    sh[:, 0] = color
    if k > 1:
        sh[:, 1:] = (np.frombuffer(streams[5], np.uint8).reshape(n, k - 1, 3).astype(np.float64) - 128) / 128
    f32 = np.float32
    return GaussianScene(means.astype(f32), sh.astype(f32), opacity.astype(f32), log_scales.astype(f32),
                         q[:, [3, 0, 1, 2]].astype(f32))


def _check_counts(n: int, degree: int, max_points: int, what: str) -> None:
    if n == 0:
        raise InputError(f"{what}: the file holds no Gaussians (numPoints = 0)")
    if n > min(max_points, (1 << 31) - 1):
        raise InputError(f"{what}: numPoints {n} is impossible for the file's size (truncated or corrupt header)")
    if degree > SH_DEGREE_MAX:
        raise InputError(f"{what}: SH degree {degree} is not supported (degrees 0-{SH_DEGREE_MAX}; SPZ degree 4 "
                         "has no place in a 3DGS scene)")


def _check_version(version: int, what: str) -> None:
    if version not in SPZ_VERSIONS_READ:
        note = " (v1, float16 positions, was never released)" if version == 1 else ""
        raise InputError(f"{what}: unsupported SPZ version {version}{note}; versions {SPZ_VERSIONS_READ[0]}-"
                         f"{SPZ_VERSIONS_READ[-1]} are read")


def _decode_v4(data: bytes, what: str) -> tuple[int, int, int, int, int, list[bytes], int]:
    if len(data) < HEADER_V4.size:
        raise InputError(f"{what}: truncated: {len(data)} bytes, an SPZ v4 header needs {HEADER_V4.size}")
    _, version, n, degree, fb, flags, num_streams, toc, _ = HEADER_V4.unpack_from(data)
    _check_version(version, what)
    if version < 4:
        raise InputError(f"{what}: SPZ version {version} must be gzip-compressed, but the file starts with a "
                         "plain 'NGSP' header")
    _check_counts(n, degree, len(data) * MAX_COMPRESSION_RATIO // MIN_BYTES_PER_POINT, what)
    sizes = [s for s in _stream_sizes(n, degree, version) if s]
    if num_streams != len(sizes):
        raise InputError(f"{what}: {num_streams} attribute streams, expected {len(sizes)} for SH degree {degree}")
    if toc < HEADER_V4.size or toc + TOC_ENTRY.size * num_streams > len(data):
        raise InputError(f"{what}: truncated or corrupt: table of contents at byte {toc} does not fit in "
                         f"{len(data)} bytes")
    system = _parse_extensions(data[HEADER_V4.size:toc], what) if flags & FLAG_HAS_EXTENSIONS else RDF
    offset = toc + TOC_ENTRY.size * num_streams
    streams = []
    dctx = zstandard.ZstdDecompressor()
    for i, expected in enumerate(sizes):
        csize, usize = TOC_ENTRY.unpack_from(data, toc + TOC_ENTRY.size * i)
        if usize != expected:
            raise InputError(f"{what}: stream {i} holds {usize} bytes, {expected} expected for {n} Gaussians")
        if csize > len(data) - offset:
            raise InputError(f"{what}: truncated: stream {i} ends at byte {offset + csize}, the file has {len(data)}")
        try:
            s = dctx.decompress(data[offset:offset + csize], max_output_size=expected)
        except zstandard.ZstdError as e:
            raise InputError(f"{what}: corrupt zstd stream {i}: {e}") from None
        if len(s) != expected:
            raise InputError(f"{what}: stream {i} decompresses to {len(s)} bytes, {expected} expected")
        streams.append(s)
        offset += csize
    if offset != len(data):
        raise InputError(f"{what}: {len(data) - offset} bytes after the last stream (corrupt table of contents)")
    streams += [b""] * (6 - len(streams))
    return version, n, degree, fb, flags, streams, system


def _decode_legacy(data: bytes, what: str) -> tuple[int, int, int, int, int, list[bytes], int]:
    """Inflate the header, then no more than the attributes it announces (and up to
    MAX_LEGACY_EXTENSION_BYTES of extension records after them): a corrupt count cannot make
    the reader allocate more than the file describes."""
    inflater = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        payload = inflater.decompress(data, LEGACY_HEADER.size)
        if len(payload) < LEGACY_HEADER.size:
            raise InputError(f"{what}: truncated: the gzip stream ends inside the {LEGACY_HEADER.size}-byte header")
        magic, version, n, degree, fb, flags, _ = LEGACY_HEADER.unpack_from(payload)
        if magic != SPZ_MAGIC:
            raise InputError(f"{what}: the gzip stream does not hold an SPZ file (magic 0x{magic:08X}, "
                             "expected 'NGSP')")
        _check_version(version, what)
        _check_counts(n, degree, len(data) * MAX_COMPRESSION_RATIO // MIN_BYTES_PER_POINT, what)
        sizes = _stream_sizes(n, degree, version)
        end = LEGACY_HEADER.size + sum(sizes)
        payload += inflater.decompress(inflater.unconsumed_tail, end + MAX_LEGACY_EXTENSION_BYTES - len(payload))
    except zlib.error as e:
        raise InputError(f"{what}: corrupt gzip stream ({e})") from None
    if len(payload) < end or not (inflater.eof or inflater.unconsumed_tail):
        raise InputError(f"{what}: truncated: the gzip stream ends after {len(payload)} of the {end} bytes that "
                         f"{n} Gaussians of SH degree {degree} need")
    system = RDF
    if flags & FLAG_HAS_EXTENSIONS:
        if not inflater.eof:
            raise InputError(f"{what}: more than {MAX_LEGACY_EXTENSION_BYTES} bytes of extension records")
        system = _parse_extensions(payload[end:], what)
    streams, pos = [], LEGACY_HEADER.size
    for s in sizes:
        streams.append(payload[pos:pos + s])
        pos += s
    return version, n, degree, fb, flags, streams, system


def decode_spz(data: bytes, what: str = "SPZ data") -> GaussianScene:
    """The validated scene in an SPZ file's bytes; InputError naming ``what`` and the problem."""
    if data[:4] == b"NGSP":
        version, n, degree, fb, flags, streams, system = _decode_v4(data, what)
    elif data[:2] == b"\x1f\x8b":
        version, n, degree, fb, flags, streams, system = _decode_legacy(data, what)
    else:
        raise InputError(f"{what}: not an SPZ file (starts with {data[:4]!r}, expected 'NGSP' or gzip)")
    scene = _unpack(n, degree, fb, version, streams)
    if system != RDF:
        if system > 8:
            raise InputError(f"{what}: stored in the {COORDINATE_SYSTEMS[system]} coordinate system "
                             "(SPZ_ADOBE_coordinate_system), a 90-degree rotation of PLY's axes that is not supported")
        scene = flip_axes(scene, axis_flips(system))
    return scene.validate(what)


def read_spz(path: str | os.PathLike) -> GaussianScene:
    """Read an SPZ file (v2, v3 or v4) into a validated GaussianScene."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise InputError(f"{p}: cannot read ({e.strerror})") from None
    return decode_spz(data, str(p))
