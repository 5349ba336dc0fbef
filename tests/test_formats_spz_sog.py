"""SPZ and SOG: the published layouts byte by byte, round-trip error bounds, bad input, the
format registry, and interop with @playcanvas/splat-transform 3.7.0 (tools/node, `make
node-tools`; skipped without it)."""

import gzip
import io
import json
import math
import struct
import zipfile

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from scenes import splat_transform, splat_transform_or_skip

from lghcc import formats
from lghcc.common.errors import InputError
from lghcc.common.scene import GaussianScene
from lghcc.formats import detect_format, read_scene, register_format, write_scene
from lghcc.formats.ply3dgs import read_3dgs_ply, write_3dgs_ply
from lghcc.formats.sog import (decode_sog, encode_sog, inverse_log_transform, log_transform, morton_order,
                               palette_size, quantize_1d, texture_size)
from lghcc.formats.spz import axis_flips, decode_spz, encode_spz, flip_axes



def make_scene(rng, n, degree, pos_scale=1.0, rot_scale=1.0):
    k = (degree + 1) ** 2
    sh = rng.uniform(-1.2, 1.2, (n, k, 3))
    sh[:, 0] = rng.uniform(-4, 4, (n, 3))
    rot = rng.normal(size=(n, 4)) * rot_scale
    return GaussianScene(rng.uniform(-1, 1, (n, 3)).astype(np.float32) * np.float32(pos_scale), sh.astype(np.float32),
                         rng.uniform(-16, 16, n).astype(np.float32), rng.uniform(-12, 7, (n, 3)).astype(np.float32),
                         rot.astype(np.float32))


@st.composite
def gaussian_scenes(draw):
    """Scenes of 1-40 Gaussians, SH degree 0-3, values past every format's range, positions from
    1e-3 to 1e6 and quaternions of any norm."""
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    return make_scene(rng, draw(st.integers(1, 40)), draw(st.integers(0, 3)),
                      pos_scale=draw(st.sampled_from([1e-3, 1.0, 2047.0, 1e5, 1e6])),
                      rot_scale=draw(st.sampled_from([1e-20, 1.0, 1e20])))


def sigmoid(x):
    return 1 / (1 + np.exp(-np.asarray(x, np.float64)))


def unit_quats(q):
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quat_agreement(a, b):
    """|cos| of the angle between the rotations (1 = same)."""
    return np.abs((unit_quats(a) * unit_quats(b)).sum(axis=1))


def v4_streams(data):
    """(header fields, decompressed streams) of an SPZ v4 file, parsed by hand."""
    magic, version, n, degree, fb, flags, num, toc = struct.unpack_from("<4sIIBBBBI", data)
    assert data[20:32] == bytes(12)
    out, off = [], toc + 16 * num
    for i in range(num):
        csize, usize = struct.unpack_from("<QQ", data, toc + 16 * i)
        s = zstandard.ZstdDecompressor().decompress(data[off:off + csize])
        assert len(s) == usize
        out.append(s)
        off += csize
    assert off == len(data)
    return (magic, version, n, degree, fb, flags, num, toc), out


# --- SPZ: the layout ----------------------------------------------------------------------

def test_spz_v4_header_and_every_field_by_hand():
    q = np.array([[1, 0, 0, 0], [0.5, 0.5, -0.5, 0.5]], np.float32)  # (w, x, y, z)
    sh = np.zeros((2, 4, 3), np.float32)
    sh[0, 0] = [0.0, 1.0, -4.0]
    sh[1, 1:] = [[0.0, 0.5, -0.3], [0.999, -1.0, 0.03], [-2.0, 2.0, 0.0625]]
    scene = GaussianScene(np.array([[1.5, -0.25, 0], [2047.0, -2048.0, 1 / 8192]], np.float32), sh,
                          np.array([0.0, 30.0], np.float32), np.array([[-10, 0, -2.5], [6, -20, 5.9]], np.float32), q)
    (magic, version, n, degree, fb, flags, num, toc), s = v4_streams(encode_spz(scene))
    assert (magic, version, n, degree, fb, flags, num, toc) == (b"NGSP", 4, 2, 1, 12, 0, 6, 32)
    assert [len(x) for x in s] == [18, 2, 6, 6, 8, 18]
    # positions: 24-bit two's complement, 12 fraction bits; 1/8192 rounds half away from zero
    assert s[0] == bytes([0, 0x18, 0, 0, 0xFC, 0xFF, 0, 0, 0]) + bytes([0, 0xF0, 0x7F, 0, 0, 0x80, 1, 0, 0])
    assert s[1] == bytes([128, 255])  # round(255 sigmoid(0)) = round(127.5) = 128
    assert list(s[2][:3]) == [128, 166, 0]  # round(x 0.15 255 + 127.5), clamped
    assert list(s[3]) == [0, 160, 120, 255, 0, 254]  # round((x + 10) 16), clamped; 15.9 f32 * 16 = 254.4
    comp = struct.unpack("<2I", s[4])
    assert comp[0] == 3 << 30  # identity: w (index 3 of x, y, z, w) largest, the rest zero
    m = math.floor(511 * (0.5 / math.sqrt(0.5)) + 0.5)  # all |q| equal: x (first) is the largest
    assert comp[1] == (0 << 30) | ((512 | m) << 20) | (m << 10) | m  # y negative, then z, w
    # SH: round(128 x) + 128 to the centre of its 8-code bucket (5 bits); 0.999 -> 256 -> 255
    assert list(s[5][:9]) == [128] * 9
    assert list(s[5][9:]) == [128, 192, 88, 255, 0, 136, 0, 255, 136]


def test_spz_sh_buckets_of_higher_bands():
    sh = np.zeros((1, 9, 3), np.float32)
    sh[0, 4:] = [[0.1, -0.1, 0.06], [0.3, 1.0, -1.0], [0, 0, 0], [0.94, 0.93, -0.95], [0.5, 0.75, -0.5]]
    scene = GaussianScene(np.zeros((1, 3), np.float32), sh, np.zeros(1, np.float32), np.zeros((1, 3), np.float32),
                          np.array([[1, 0, 0, 0]], np.float32))
    _, s = v4_streams(encode_spz(scene))
    band2 = list(s[5][9:])  # 16-code buckets (4 bits)
    assert band2 == [144, 112, 144, 160, 255, 0, 128, 128, 128, 255, 240, 0, 192, 224, 64]


def test_spz_positions_beyond_2048_use_fewer_fraction_bits():
    rng = np.random.default_rng(0)
    scene = make_scene(rng, 3, 0)
    scene.means[0] = [5000.0, -3.0, 0.0]
    (_, _, _, _, fb, *_), s = v4_streams(encode_spz(scene))
    assert fb == 10  # 5000 * 2^10 < 2^23 <= 5000 * 2^11
    assert np.abs(decode_spz(encode_spz(scene)).means - scene.means).max() <= 2.0 ** -11
    scene.means[0, 0] = 2.0 ** 23
    with pytest.raises(InputError, match="24-bit fixed-point"):
        encode_spz(scene)


def _legacy(version, n, degree, fields, flags=0, tail=b""):
    return gzip.compress(struct.pack("<4sIIBBBB", b"NGSP", version, n, degree, 12, flags, 0) + b"".join(fields) + tail)


def test_spz_decodes_handmade_v2_bytes():
    pos = bytes([0, 0x10, 0, 0, 0, 0x80, 0xFF, 0xFF, 0xFF])  # 1.0, -2048, -1/4096
    data = _legacy(2, 1, 1, [pos, bytes([255]), bytes([0, 255, 128]), bytes([0, 16, 255]), bytes([255, 128, 0]),
                             bytes([128, 0, 255, 136, 120, 64, 192, 128, 1])])
    s = decode_spz(data)
    np.testing.assert_array_equal(s.means, np.float32([[1.0, -2048.0, -1 / 4096]]))
    np.testing.assert_allclose(s.opacity, [math.log((1 - 1e-6) / 1e-6)], rtol=1e-6)
    np.testing.assert_allclose(s.sh[0, 0], [-0.5 / 0.15, (1 - 0.5) / 0.15, (128 / 255 - 0.5) / 0.15], rtol=1e-6)
    np.testing.assert_array_equal(s.log_scales, [[-10.0, -9.0, 255 / 16 - 10]])
    xyz = np.array([255, 128, 0]) / 127.5 - 1
    np.testing.assert_allclose(s.rotations[0], [math.sqrt(max(0, 1 - (xyz ** 2).sum())), *xyz], atol=1e-7)
    np.testing.assert_array_equal(s.sh[0, 1:].reshape(-1), (np.array([128, 0, 255, 136, 120, 64, 192, 128, 1]) - 128) / 128)


def test_spz_decodes_handmade_v3_smallest_three():
    # z (index 2) largest; x = +511, y = -0 (sign bit only), w = -(255/511) of sqrt(1/2)
    comp = (2 << 30) | (511 << 20) | (512 << 10) | (512 | 255)
    data = _legacy(3, 1, 0, [bytes(9), bytes([128]), bytes(3), bytes(3), struct.pack("<I", comp)])
    s = decode_spz(data)
    x, w = math.sqrt(0.5), -math.sqrt(0.5) * 255 / 511
    np.testing.assert_allclose(s.rotations[0], [w, x, 0.0, math.sqrt(1 - x * x - w * w)], atol=1e-7)
    assert s.sh.shape == (1, 1, 3)


# splat-transform's test fixtures (playcanvas/splat-transform, test/fixtures/splat/minimal-v{2,3,4}.spz,
# MIT): v2 written byte by byte, v3 and v4 by the reference (@adobe/spz) from a 2 x 2 grid,
# log scale ln 0.1, opacity 0.9, colours (g + 1) / 3 per axis; v3/v4 with `from: RDF`, which the
# reference turns into RUB (y and z negated) without saying so in the file.
SPLAT_TRANSFORM_FIXTURES = {
    2: "1f8b0800000000000013f3730f0e606260606061606060e0606060f8ff9f014e421870360c3c7bf6ec596868c3aad086d0550dab56"
       "3554238106240000c9bdf6cb5c000000",
    3: "1f8b0800000000000003f3730f0e60666060600162061e20fef01fc4126080020198081278060499990dd3321b32a7354c9bd6508d"
       "0480d20790310027c3b78960000000",
    4: "4e4753500400000004000000000c000520000000000000000000000000000000250000000000000024000000000000000d000000"
       "00000000040000000000000015000000000000000c0000000000000011000000000000000c00000000000000140000000000000010"
       "0000000000000028b52ffd2024e50000b000f0ff00000000100000000000000000100000f0ff00010064d00428b52ffd2004210000"
       "e6e6e6e628b52ffd200c61000069698096698069968096968028b52ffd200c450000107b7b01001bc00228b52ffd20105d00002800"
       "0000c00001008cab05",
}


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_decodes_splat_transform_fixtures(version):
    s = decode_spz(bytes.fromhex(SPLAT_TRANSFORM_FIXTURES[version]))
    grid = np.float32([[-1, 0, -1], [0, 0, -1], [-1, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(s.means, grid if version == 2 else grid * np.float32([1, -1, -1]))
    np.testing.assert_allclose(s.opacity, math.log(230 / 25), rtol=1e-6)  # byte 230 = round(0.9 255)
    np.testing.assert_array_equal(s.log_scales, np.full((4, 3), 123 / 16 - 10, np.float32))  # round((ln 0.1 + 10) 16)
    dc = [85, 170] if version == 2 else [105, 150]  # v2 stores the colour itself, v3/v4 the SH DC of it
    codes = np.array([[dc[gx], dc[gz], 128] for gz in (0, 1) for gx in (0, 1)])
    np.testing.assert_allclose(s.sh[:, 0], (codes / 255 - 0.5) / 0.15, rtol=1e-6)
    want = [1, 0, 0, 0] if version > 2 else [math.sqrt(1 - 3 * (128 / 127.5 - 1) ** 2)] + [128 / 127.5 - 1] * 3
    np.testing.assert_allclose(s.rotations, np.tile(want, (4, 1)), atol=1e-7)


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_writes_each_version(version):
    scene = make_scene(np.random.default_rng(version), 7, 2)
    data = encode_spz(scene, version=version, antialiased=True)
    raw = data if version == 4 else gzip.decompress(data)
    assert raw[:4] == b"NGSP" and struct.unpack_from("<I", raw, 4)[0] == version and raw[14] & 1
    if version < 4:
        sizes = 7 * (9 + 1 + 3 + 3 + (4 if version == 3 else 3) + 24)
        assert len(raw) == 16 + sizes
    back = decode_spz(data)
    assert back.sh.shape == scene.sh.shape


# --- SPZ: round trip ----------------------------------------------------------------------

def _check_spz_bounds(scene, back, data, version):
    fb = (data if version == 4 else gzip.decompress(data))[13]
    assert np.abs(back.means.astype(np.float64) - scene.means).max() <= 2.0 ** -(fb + 1) * (1 + 1e-6)
    np.testing.assert_allclose(back.log_scales, np.clip(scene.log_scales, -10, 255 / 16 - 10), atol=1 / 32 + 1e-6)
    assert np.abs(sigmoid(back.opacity) - sigmoid(scene.opacity)).max() <= 0.5 / 255 + 1e-6
    lim = 0.5 / 0.15
    np.testing.assert_allclose(back.sh[:, 0], np.clip(scene.sh[:, 0], -lim, lim), atol=0.5 / (0.15 * 255) + 1e-5)
    rest = np.clip(scene.sh[:, 1:], -1, 127 / 128)
    np.testing.assert_allclose(back.sh[:, 1:4], rest[:, :3], atol=4.5 / 128 + 1e-7)
    np.testing.assert_allclose(back.sh[:, 4:], rest[:, 3:], atol=8.5 / 128 + 1e-7)
    # v3+: 9 bits + sign per small component; v2: 8-bit x, y, z with w derived (loose where w ~ 0)
    assert quat_agreement(back.rotations, scene.rotations).min() >= (0.99999 if version >= 3 else 0.99)


@settings(max_examples=60)
@given(gaussian_scenes(), st.sampled_from([2, 3, 4]))
def test_spz_round_trip_error_bounds(scene, version):
    data = encode_spz(scene, version=version)
    _check_spz_bounds(scene, decode_spz(data), data, version)


def test_spz_single_gaussian_round_trip():
    scene = make_scene(np.random.default_rng(1), 1, 3)
    data = encode_spz(scene)
    _check_spz_bounds(scene, decode_spz(data), data, 4)


# --- SPZ: coordinate-system extension -----------------------------------------------------

def sh_polynomials(d):
    """The 16 real SH basis functions of 3DGS up to constant factors (which a parity check does
    not need): band 1 y, z, x; band 2 xy, yz, 3z^2 - 1, xz, x^2 - y^2; band 3 ..."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([np.ones_like(x), y, z, x, x * y, y * z, 2 * z * z - x * x - y * y, x * z, x * x - y * y,
                     y * (3 * x * x - y * y), x * y * z, y * (4 * z * z - x * x - y * y),
                     z * (2 * z * z - 3 * x * x - 3 * y * y), x * (4 * z * z - x * x - y * y), z * (x * x - y * y),
                     x * (x * x - 3 * y * y)], axis=1)


def rotmat(q):
    w, x, y, z = unit_quats(q).T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)


def test_axis_flips_keep_colour_and_rotation():
    """Flipping axes maps each SH coefficient and each rotation consistently: the colour seen
    from direction d before equals the colour from the flipped d after, and the rotation
    matrix is conjugated by the flip."""
    rng = np.random.default_rng(3)
    scene = make_scene(rng, 5, 3)
    assert axis_flips(4).tolist() == [1, -1, -1]  # RUB -> RDF
    assert axis_flips(6).tolist() == [1, 1, 1] and axis_flips(1).tolist() == [-1, 1, -1]  # LDB
    for f in (axis_flips(4), np.array([-1.0, 1, 1]), np.array([-1.0, -1, 1])):
        out = flip_axes(scene, f)
        d = rng.normal(size=(5, 3))
        before = np.einsum("nk,nkc->nc", sh_polynomials(d), scene.sh.astype(np.float64))
        after = np.einsum("nk,nkc->nc", sh_polynomials(d * f), out.sh.astype(np.float64))
        np.testing.assert_allclose(before, after, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(out.means, scene.means * f.astype(np.float32))
        if np.prod(f) > 0:  # a proper rotation of the axes (an improper flip is not a rotation)
            np.testing.assert_allclose(rotmat(out.rotations), np.diag(f) @ rotmat(scene.rotations) @ np.diag(f),
                                       atol=1e-6)


def test_spz_coordinate_system_extension_is_honoured():
    scene = make_scene(np.random.default_rng(5), 4, 1)
    plain = encode_spz(scene)
    (_, _, n, degree, fb, _, num, _), _ = v4_streams(plain)
    ext = struct.pack("<III", 0xADBE0003, 4, 4)  # RUB
    other = struct.pack("<II", 0x12340001, 3) + b"abc"  # unknown: skipped
    header = struct.pack("<4sIIBBBBI12s", b"NGSP", 4, n, degree, fb, 2, num, 32 + len(other) + len(ext), bytes(12))
    data = header + other + ext + plain[32:]
    rub, raw = decode_spz(data), decode_spz(plain)
    np.testing.assert_array_equal(rub.means, raw.means * np.float32([1, -1, -1]))
    np.testing.assert_array_equal(rub.rotations, raw.rotations * np.float32([1, 1, -1, -1]))
    np.testing.assert_array_equal(rub.sh[:, 1:, :], raw.sh[:, 1:, :] * np.float32([-1, -1, 1])[None, :, None])
    rotated = header + other + struct.pack("<III", 0xADBE0003, 4, 12) + plain[32:]  # RFU: a 90-degree turn
    with pytest.raises(InputError, match="RFU"):
        decode_spz(rotated)


# --- SPZ: bad input -----------------------------------------------------------------------

def _spz_v4_sample():
    return encode_spz(make_scene(np.random.default_rng(9), 5, 1))


def _patch(data, offset, fmt, value):
    b = bytearray(data)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: b"", "not an SPZ file"),
    (lambda d: d[:20], "truncated"),
    (lambda d: d[:40], "truncated or corrupt: table of contents"),
    (lambda d: d[:-5], "truncated: stream 5"),
    (lambda d: d + b"x", "bytes after the last stream"),
    (lambda d: b"NGSQ" + d[4:], "not an SPZ file"),
    (lambda d: _patch(d, 4, "<I", 1), "version 1"),
    (lambda d: _patch(d, 4, "<I", 5), "unsupported SPZ version 5"),
    (lambda d: _patch(d, 4, "<I", 3), "must be gzip-compressed"),
    (lambda d: _patch(d, 8, "<I", 0), "no Gaussians"),
    (lambda d: _patch(d, 8, "<I", 2 ** 31), "impossible"),
    (lambda d: _patch(d, 8, "<I", 6), "stream 0 holds 45 bytes, 54 expected"),
    (lambda d: _patch(d, 12, "<B", 4), "SH degree 4"),
    (lambda d: _patch(d, 15, "<B", 5), "5 attribute streams, expected 6"),
    (lambda d: d[:128] + bytes(4) + d[132:], "corrupt zstd stream 0"),  # stream 0's frame magic
    (lambda d: _patch(_patch(d, 14, "<B", 2), 16, "<I", 36), "truncated extension record"),
])
def test_spz_bad_input_is_one_clear_line(tmp_path, mutate, message):
    path = tmp_path / "bad.spz"
    path.write_bytes(mutate(_spz_v4_sample()))
    with pytest.raises(InputError, match=message) as e:
        read_scene(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("data, message", [
    (gzip.compress(b"NGSP")[:-3], "truncated: the gzip stream ends inside"),
    (gzip.compress(b"ABCD" + bytes(12)), "does not hold an SPZ file"),
    (_legacy(3, 2, 0, [bytes(9)]), "truncated: the gzip stream ends after"),
    (_legacy(3, 1, 0, [bytes(20)])[:-12], "truncated"),
    (b"\x1f\x8b" + bytes(30), "corrupt gzip stream"),
    (_legacy(2, 1, 0, [bytes(19)], flags=2, tail=b"\x01\x00"), "truncated extension record"),
])
def test_spz_bad_legacy_input(data, message):
    with pytest.raises(InputError, match=message):
        decode_spz(data)


def test_spz_writer_refuses_bad_scenes(tmp_path):
    scene = make_scene(np.random.default_rng(0), 3, 0)
    scene.opacity[1] = np.nan
    with pytest.raises(InputError, match="opacity"):
        write_scene(scene, tmp_path / "x.spz")
    with pytest.raises(InputError, match="version must be"):
        encode_spz(make_scene(np.random.default_rng(0), 3, 0), version=5)
    assert list(tmp_path.iterdir()) == []


# --- SOG: the layout ----------------------------------------------------------------------

def _bundle(data):
    z = zipfile.ZipFile(io.BytesIO(data))
    meta = json.loads(z.read("meta.json"))
    px = {n: np.asarray(Image.open(io.BytesIO(z.read(n))).convert("RGBA")) for n in z.namelist() if n != "meta.json"}
    return z, meta, px


def test_sog_bundle_layout_by_hand():
    n = 17
    rng = np.random.default_rng(2)
    scene = make_scene(rng, n, 1)
    scene.rotations[0] = [1, 0, 0, 0]
    scene.rotations[1] = [-0.1, 0.2, -0.9, 0.3]
    scene.opacity[:2] = [0.0, -50.0]
    data = encode_sog(scene)
    z, meta, px = _bundle(data)
    assert z.namelist() == ["means_l.webp", "means_u.webp", "quats.webp", "scales.webp", "sh0.webp",
                            "shN_centroids.webp", "shN_labels.webp", "meta.json"]
    assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())
    assert data[-22:-18] == b"PK\x05\x06"  # the engine reads the end record at the very end
    assert (meta["version"], meta["count"]) == (2, n) and meta["asset"]["generator"].startswith("lghcc v")
    assert texture_size(n) == (8, 4) and all(p.shape == (4, 8, 4) for k, p in px.items() if "centroids" not in k)
    order = morton_order(scene.means)
    s = scene.subset(order)
    lm = log_transform(s.means.astype(np.float64))
    np.testing.assert_allclose(meta["means"]["mins"], lm.min(0))
    np.testing.assert_allclose(meta["means"]["maxs"], lm.max(0))
    q16 = (px["means_u.webp"].reshape(-1, 4)[:n, :3].astype(int) << 8) | px["means_l.webp"].reshape(-1, 4)[:n, :3]
    np.testing.assert_array_equal(q16, np.round(65535 * (lm - lm.min(0)) / (lm.max(0) - lm.min(0))))
    assert (px["means_l.webp"].reshape(-1, 4)[n:] == 0).all()  # padding
    quats = px["quats.webp"].reshape(-1, 4)
    i0, i1 = int(np.flatnonzero(order == 0)[0]), int(np.flatnonzero(order == 1)[0])
    assert list(quats[i0]) == [128, 128, 128, 252]  # w largest; 255 (0 + 1/2) rounds to even 128
    u = np.array([-0.1, 0.2, -0.9, 0.3]) / np.linalg.norm([-0.1, 0.2, -0.9, 0.3]) * -1  # y largest, made positive
    assert list(quats[i1]) == [*np.round(255 * (u[[0, 1, 3]] * math.sqrt(2) / 2 + 0.5)).astype(int), 254]
    sh0 = px["sh0.webp"].reshape(-1, 4)
    assert (sh0[i0, 3], sh0[i1, 3]) == (128, 0)
    book = np.float32(meta["sh0"]["codebook"])
    assert len(book) == 256 and (np.diff(book) >= 0).all()
    np.testing.assert_array_equal(np.abs(book[sh0[:n, :3]] - s.sh[:, 0].astype(np.float64)),
                                  np.abs(s.sh[:, 0, :, None].astype(np.float64) - book).min(-1))  # nearest entry
    assert meta["shN"]["bands"] == 1 and meta["shN"]["count"] == palette_size(n) == 16  # k-means: 17 -> 16
    assert px["shN_centroids.webp"].shape == (1, 192, 4)


def test_sog_palette_size_followssplat_transform_or_skip():
    assert [palette_size(n) for n in (1, 10, 1023, 1024, 31000, 65536, 300000)] == [1, 8, 512, 1024, 16384, 65536,
                                                                                    65536]


def test_morton_order_by_hand():
    # four corners of a square, listed out of Z order; then 300 points on one code refined
    p = np.array([[1, 1, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    assert morton_order(p).tolist() == [1, 2, 3, 0]
    same = np.zeros((300, 3), np.float32)
    same[:, 0] = np.linspace(0, 1e-4, 300)[::-1]  # one code at the scene's scale, ordered within it
    pts = np.concatenate([same, [[10, 10, 10]]]).astype(np.float32)
    assert morton_order(pts).tolist()[:300] == list(range(299, -1, -1))


def test_quantize_1d_is_the_nearest_entry_of_an_optimal_codebook():
    x = np.concatenate([np.zeros(500), np.linspace(-3, 3, 3000) ** 3]).astype(np.float32)
    book, (labels,) = quantize_1d([x])
    assert book.dtype == np.float32 and len(book) == 256 and (np.diff(book) >= 0).all()
    np.testing.assert_array_equal(np.abs(book[labels] - x), np.abs(x[:, None] - book).min(1))
    few, (lab,) = quantize_1d([np.float32([1, 2, 2, 3])])
    assert set(few.tolist()) == {1, 2, 3} and (few[lab] == [1, 2, 2, 3]).all()
    flat, (lab,) = quantize_1d([np.full(5, 0.25, np.float32)])
    assert (flat == np.float32(0.25)).all() and (lab == 0).all()


def _webp_bytes(pixels, fmt="WEBP"):
    buf = io.BytesIO()
    Image.fromarray(np.asarray(pixels, np.uint8), "RGBA").save(buf, fmt, lossless=True, exact=True)
    return buf.getvalue()


def _handmade_sog(tmp_path, meta, images, name="hand.sog"):
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as z:
        for k, v in images.items():
            z.writestr(k, v)
        if meta is not None:
            z.writestr("meta.json", json.dumps(meta) if not isinstance(meta, bytes) else meta)
    return path


def _two_gaussian_images(tag=(252, 253)):
    means_l = [[[0, 0, 0, 255], [255, 0, 255, 255]]]  # y: mins = maxs, stored as 0
    means_u = [[[0, 0, 0, 255], [255, 0, 255, 255]]]
    quats = [[[128, 128, 128, tag[0]], [200, 60, 128, tag[1]]]]
    scales = [[[0, 1, 255, 255], [3, 3, 3, 255]]]
    sh0 = [[[0, 1, 2, 255], [2, 1, 0, 0]]]
    labels = [[[1, 0, 0, 255], [0, 0, 0, 255]]]
    cent = np.zeros((1, 192, 4), np.uint8)
    cent[0, 3:6, :3] = [[1, 2, 3], [4, 5, 6], [7, 8, 9]]  # palette entry 1: 3 coefficients x RGB
    return {"means_l.webp": _webp_bytes(means_l), "means_u.webp": _webp_bytes(means_u),
            "quats.webp": _webp_bytes(quats), "scales.webp": _webp_bytes(scales), "sh0.webp": _webp_bytes(sh0),
            "shN_centroids.webp": _webp_bytes(cent), "shN_labels.webp": _webp_bytes(labels)}


def _v2_meta():
    return {"version": 2, "count": 2,
            "means": {"mins": [-1.0, 0.0, 0.5], "maxs": [1.0, 0.0, 2.0], "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"codebook": [-5.0, -4.0] + [0.0] * 253 + [1.0], "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"codebook": [0.5, 1.5, 2.5] + [3.0] * 253, "files": ["sh0.webp"]},
            "shN": {"count": 2, "bands": 1, "codebook": [i / 10 for i in range(256)],
                    "files": ["shN_centroids.webp", "shN_labels.webp"]}}


def test_sog_decodes_handmade_v2_bundle(tmp_path):
    s = read_scene(_handmade_sog(tmp_path, _v2_meta(), _two_gaussian_images()))
    np.testing.assert_allclose(s.means, np.float32([inverse_log_transform(np.array([-1.0, 0.0, 0.5])),
                                                    inverse_log_transform(np.array([1.0, 0.0, 2.0]))]), rtol=1e-6)
    a = (128 / 255 * 2 - 1) / math.sqrt(2)
    np.testing.assert_allclose(s.rotations[0], [math.sqrt(1 - 3 * a * a), a, a, a], rtol=1e-6)
    b = (np.array([200, 60, 128]) / 255 * 2 - 1) / math.sqrt(2)  # x largest: (w, y, z) = b
    np.testing.assert_allclose(s.rotations[1], [b[0], math.sqrt(1 - (b ** 2).sum()), b[1], b[2]], rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(s.log_scales, [[-5, -4, 1], [0, 0, 0]])
    np.testing.assert_array_equal(s.sh[:, 0], [[0.5, 1.5, 2.5], [2.5, 1.5, 0.5]])
    np.testing.assert_allclose(s.opacity, [math.log((1 - 1e-6) / 1e-6), -math.log((1 - 1e-6) / 1e-6)], rtol=1e-6)
    np.testing.assert_allclose(s.sh[0, 1:], np.float32([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.7, 0.8, 0.9]]))
    np.testing.assert_array_equal(s.sh[1, 1:], 0)  # palette entry 0: all codebook[0]


def test_sog_decodes_handmade_v1_meta_json(tmp_path):
    meta = {"means": {"shape": [2, 3], "mins": [-1.0, 0.0, 0.5], "maxs": [1.0, 0.0, 2.0],
                      "files": ["means_l.webp", "means_u.webp"]},
            "scales": {"mins": [-6.0, -6.0, -6.0], "maxs": [-1.0, -1.0, 4.0], "files": ["scales.webp"]},
            "quats": {"files": ["quats.webp"]},
            "sh0": {"mins": [-1.0, -1.0, -1.0, -3.0], "maxs": [1.0, 1.0, 1.0, 3.0], "files": ["sh0.webp"]},
            "shN": {"mins": -0.5, "maxs": 0.5, "files": ["shN_centroids.webp", "shN_labels.webp"]}}
    for k, v in _two_gaussian_images().items():
        (tmp_path / k).write_bytes(v)
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    assert detect_format(tmp_path / "meta.json").name == "sog"
    s = read_scene(tmp_path / "meta.json")
    np.testing.assert_allclose(s.log_scales[0], [-6, -6 + 5 / 255, 4], rtol=1e-6)
    np.testing.assert_allclose(s.sh[1, 0], [-1 + 2 * 2 / 255, -1 + 2 / 255, -1], rtol=1e-6)
    np.testing.assert_allclose(s.opacity, [3.0, -3.0], rtol=1e-6)  # V1 stores the logit linearly
    np.testing.assert_allclose(s.sh[0, 1, :], -0.5 + np.array([1, 2, 3]) / 255, rtol=1e-6)


# --- SOG: round trip ----------------------------------------------------------------------

def _nearest_entry_error(values, book):
    return np.abs(np.asarray(values, np.float64)[..., None] - np.float64(book)).min(-1)


@settings(max_examples=25)
@given(gaussian_scenes())
def test_sog_round_trip_error_bounds(scene):
    data = encode_sog(scene, palette=64)  # palette >= N: the SH keep one entry each
    _, meta, _ = _bundle(data)
    back = decode_sog(meta, lambda name: zipfile.ZipFile(io.BytesIO(data)).read(name), "t")
    s = scene.subset(morton_order(scene.means))
    lm = log_transform(s.means.astype(np.float64))
    step = (lm.max(0) - lm.min(0)) / 65535
    assert (np.abs(log_transform(back.means.astype(np.float64)) - lm) <= step / 2 + 1e-6 * (1 + np.abs(lm))).all()
    for got, want, key in ((back.log_scales, s.log_scales, "scales"), (back.sh[:, 0], s.sh[:, 0], "sh0")):
        np.testing.assert_allclose(np.abs(got - want), _nearest_entry_error(want, meta[key]["codebook"]), atol=1e-6)
    assert np.abs(sigmoid(back.opacity) - sigmoid(s.opacity)).max() <= 0.5 / 255 + 1e-6
    assert quat_agreement(back.rotations, s.rotations).min() >= 0.9999
    if scene.sh_degree:
        np.testing.assert_allclose(np.abs(back.sh[:, 1:] - s.sh[:, 1:]),
                                   _nearest_entry_error(s.sh[:, 1:], meta["shN"]["codebook"]), atol=1e-6)


def test_sog_palette_k_means_is_seeded_and_finds_clusters():
    rng = np.random.default_rng(4)
    scene = make_scene(rng, 1500, 2)
    centres = rng.uniform(-1, 1, (40, 8, 3))
    scene.sh[:, 1:] = (centres[rng.integers(0, 40, 1500)] + rng.normal(0, 0.01, (1500, 8, 3))).astype(np.float32)
    a = encode_sog(scene, palette=64)
    assert encode_sog(scene, palette=64) == a  # seeded: the same bytes
    _, meta, px = _bundle(a)
    assert meta["shN"]["count"] == 64 and px["shN_centroids.webp"].shape == (1, 512, 4)
    back = decode_sog(meta, lambda name: zipfile.ZipFile(io.BytesIO(a)).read(name), "t")
    err = back.sh[:, 1:] - scene.subset(morton_order(scene.means)).sh[:, 1:]
    assert np.sqrt((err ** 2).mean()) < 0.02  # 40 clusters of noise 0.01 in 64 entries, 8-bit codebook


# --- SOG: bad input -----------------------------------------------------------------------

@pytest.mark.parametrize("change, message", [
    (lambda m, im: (None, im), "no meta.json"),
    (lambda m, im: (b"{not json", im), "not valid JSON"),
    (lambda m, im: ({**m, "version": 3}, im), "unsupported SOG version 3"),
    (lambda m, im: ({**m, "count": 5}, im), "fewer than the 5"),
    (lambda m, im: ({**m, "count": 0}, im), "positive Gaussian count"),
    (lambda m, im: ({k: v for k, v in m.items() if k != "quats"}, im), "needs 'quats'"),
    (lambda m, im: (m, {k: v for k, v in im.items() if k != "sh0.webp"}), "has no sh0.webp"),
    (lambda m, im: (m, {**im, "sh0.webp": _webp_bytes(np.zeros((1, 2, 4)), "PNG")}), "sh0.webp is PNG"),
    (lambda m, im: (m, {**im, "scales.webp": b"RIFF\x00\x00"}), "not a readable WebP"),
    (lambda m, im: ({**m, "means": {**m["means"], "mins": [0, float("nan"), 0]}}, im), "NaN or Inf"),
    (lambda m, im: ({**m, "scales": {**m["scales"], "codebook": [1.0, 2.0]}}, im), "past the 2 entries"),
    (lambda m, im: ({**m, "shN": {**m["shN"], "count": 1}}, im), "palette index 1 past"),
    (lambda m, im: ({**m, "shN": {**m["shN"], "bands": 4}}, im), "'shN.bands' must be"),
    (lambda m, im: (m, _two_gaussian_images(tag=(252, 7))), "largest-component tag"),
])
def test_sog_bad_input_is_one_clear_line(tmp_path, change, message):
    meta, images = change(_v2_meta(), _two_gaussian_images())
    path = _handmade_sog(tmp_path, meta, images)
    with pytest.raises(InputError, match=message) as e:
        read_scene(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)


def test_sog_not_a_zip(tmp_path):
    (tmp_path / "x.sog").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(InputError, match="not a zip archive|corrupt zip"):
        read_scene(tmp_path / "x.sog")


# --- read_scene / write_scene -------------------------------------------------------------

def test_read_and_write_scene_by_extension_and_content(tmp_path):
    scene = make_scene(np.random.default_rng(8), 20, 1)
    for ext, name in ((".ply", "3dgs-ply"), (".spz", "spz"), (".sog", "sog")):
        write_scene(scene, tmp_path / f"s{ext}")
        assert detect_format(tmp_path / f"s{ext}").name == name
        assert read_scene(tmp_path / f"s{ext}").num_gaussians == 20
    np.testing.assert_array_equal(read_scene(tmp_path / "s.ply").sh, scene.sh)
    (tmp_path / "spz_named.ply").write_bytes((tmp_path / "s.spz").read_bytes())  # content wins
    assert detect_format(tmp_path / "spz_named.ply").name == "spz"
    (tmp_path / "legacy.bin").write_bytes(encode_spz(scene, version=3))
    assert detect_format(tmp_path / "legacy.bin").name == "spz"
    with pytest.raises(InputError, match="cannot tell the format"):
        write_scene(scene, tmp_path / "s.obj")
    with pytest.raises(InputError, match="no such file"):
        read_scene(tmp_path / "missing.spz")
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "cameras.json").write_text('{"frames": []}')
    for other in ("notes.txt", "cameras.json"):
        with pytest.raises(InputError, match=r"not a scene\b"):
            read_scene(tmp_path / other)
    with pytest.raises(InputError, match="folder"):
        read_scene(tmp_path)
    (tmp_path / "empty.spz").write_bytes(b"")  # no content to sniff: the extension's reader says why
    with pytest.raises(InputError, match="not an SPZ file"):
        read_scene(tmp_path / "empty.spz")


def test_a_failed_write_leaves_no_file(tmp_path):
    scene = make_scene(np.random.default_rng(8), 4, 0)
    scene.means[0, 0] = 1e7  # beyond SPZ's fixed point: refused while encoding
    with pytest.raises(InputError):
        write_scene(scene, tmp_path / "x.spz")
    write_scene(make_scene(np.random.default_rng(8), 4, 0), tmp_path / "y.spz")
    before = (tmp_path / "y.spz").read_bytes()
    with pytest.raises(InputError):
        write_scene(scene, tmp_path / "y.spz")
    assert (tmp_path / "y.spz").read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["y.spz"]


def test_another_reader_can_be_registered(tmp_path, monkeypatch):
    monkeypatch.setattr(formats, "_FORMATS", list(formats.scene_formats()))
    scene = make_scene(np.random.default_rng(0), 2, 0)
    register_format(formats.SceneFormat("folder", (), lambda p, head: (p / "scene.spz").is_file(),
                                        lambda p: read_scene(p / "scene.spz"), None), first=True)
    write_scene(scene, tmp_path / "scene.spz")
    assert detect_format(tmp_path).name == "folder"
    assert read_scene(tmp_path).num_gaussians == 2


# --- interop with splat-transform 3.7.0 ----------------------------------------------------

@pytest.fixture(scope="module")
def interop(tmp_path_factory):
    """One scene (SH degree 2, extreme values) through splat-transform and through us."""
    tool = splat_transform_or_skip()
    d = tmp_path_factory.mktemp("interop")
    scene = make_scene(np.random.default_rng(11), 700, 2, pos_scale=30.0)
    write_3dgs_ply(d / "scene.ply", scene)
    write_scene(scene, d / "ours.spz")
    write_scene(scene, d / "ours_v3.spz", version=3)
    write_scene(scene, d / "ours.sog")
    for src, dst in (("scene.ply", "st.spz"), ("scene.ply", "st.sog"), ("st.spz", "st_spz.ply"),
                     ("st.sog", "st_sog.ply"), ("ours.spz", "ours_spz.ply"), ("ours_v3.spz", "ours_v3_spz.ply"),
                     ("ours.sog", "ours_sog.ply")):
        splat_transform(tool, d / src, d / dst)
    return d, scene


def _assert_same_scene(a, b):
    for f in ("means", "sh", "opacity", "log_scales", "rotations"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-6, atol=1e-6, err_msg=f)


@pytest.mark.integration
@pytest.mark.parametrize("ours, theirs", [("ours.spz", "ours_spz.ply"), ("ours_v3.spz", "ours_v3_spz.ply"),
                                          ("ours.sog", "ours_sog.ply"), ("st.spz", "st_spz.ply"),
                                          ("st.sog", "st_sog.ply")])
def test_splat_transform_and_we_decode_alike(interop, ours, theirs):
    d, _ = interop
    _assert_same_scene(read_scene(d / ours), read_3dgs_ply(d / theirs))


@pytest.mark.integration
def test_our_spz_is_splat_transforms_spz(interop):
    """Same header and the same packed bytes in every stream (the zstd frames may differ with
    the library's version)."""
    d, _ = interop
    assert v4_streams((d / "ours.spz").read_bytes()) == v4_streams((d / "st.spz").read_bytes())


@pytest.mark.integration
def test_our_sog_images_match_splat_transforms(interop):
    """Same order and codebooks; means, quaternions and opacity round where splat-transform
    truncates (at most one code apart); the SH palettes are different k-means runs. Compared
    over the Gaussians' pixels: libwebp's default (splat-transform's) rewrites the colour of
    pixels whose alpha is 0 (padding, opacity 0); ours keeps it."""
    d, scene = interop
    n = scene.num_gaussians
    _, ours, po = _bundle((d / "ours.sog").read_bytes())
    _, theirs, pt = _bundle((d / "st.sog").read_bytes())
    po, pt = ({k: v.reshape(-1, 4)[:n].astype(int) for k, v in p.items() if "centroids" not in k} for p in (po, pt))
    assert ours["scales"]["codebook"] == theirs["scales"]["codebook"]
    assert ours["sh0"]["codebook"] == theirs["sh0"]["codebook"]
    np.testing.assert_allclose(ours["means"]["mins"], theirs["means"]["mins"], rtol=1e-12)
    np.testing.assert_array_equal(po["scales.webp"], pt["scales.webp"])
    seen = pt["sh0.webp"][:, 3] > 0
    np.testing.assert_array_equal(po["sh0.webp"][seen, :3], pt["sh0.webp"][seen, :3])
    q16 = [(p["means_u.webp"][:, :3] << 8) | p["means_l.webp"][:, :3] for p in (po, pt)]
    assert np.abs(q16[0] - q16[1]).max() <= 1
    assert np.abs(po["quats.webp"] - pt["quats.webp"]).max() <= 1
    assert np.abs(po["sh0.webp"][:, 3] - pt["sh0.webp"][:, 3]).max() <= 1
    assert (ours["shN"]["bands"], theirs["shN"]["bands"]) == (2, 2)


@pytest.mark.integration
@pytest.mark.data
def test_donut_spz_from_splat_transform_reads_as_its_ply(shared_data, tmp_path):
    tool = splat_transform_or_skip()
    donut = shared_data / "donut" / "donut.ply"
    if not donut.is_file():
        pytest.skip(f"{donut} not found")
    splat_transform(tool, donut, tmp_path / "donut.spz")
    splat_transform(tool, tmp_path / "donut.spz", tmp_path / "donut_spz.ply")
    _assert_same_scene(read_scene(tmp_path / "donut.spz"), read_3dgs_ply(tmp_path / "donut_spz.ply"))
    ours = encode_spz(read_scene(donut))
    assert v4_streams(ours) == v4_streams((tmp_path / "donut.spz").read_bytes())
