"""The ancillary source_info unit (0x80, spec clause 7.3.10): written by lghcc-enc --mode anchors,
read by the decoder (lghcc-dec --export takes the source's SH degree from it), and nothing the
decoded scene depends on: unknown ancillary units are skipped, a malformed source_info ignored."""

import sys

import numpy as np
import pytest

from lghcc.common.container import AncillaryUnitType, DataUnit, UnitType, read_container, write_container
from lghcc.formats.procedural import make_procedural_scene
from lghcc.common.units import SourceInfo
from lghcc.decoder import cli as dec_cli
from lghcc.decoder.decode import decode_stream, organize_units
from lghcc.encoder.stream.config import load_config
from lghcc.encoder.stream.encode import encode_scene

SOURCE_INFO = AncillaryUnitType.SOURCE_INFO


@pytest.fixture(scope="module")
def plain():
    """A small anchor stream without ancillary units (its render MLPs included: exportable)."""
    scene = make_procedural_scene(60, seed=3, feature_dim=8, num_offsets=3)
    return scene, encode_scene(scene, load_config("low"))


def _with_units(data: bytes, extra: list[DataUnit], index: int = 1) -> bytes:
    units = read_container(data).units
    return write_container(units[:index] + extra + units[index:])


def test_source_info_syntax_and_reserved_trailing_bytes():
    for d in range(4):
        b = SourceInfo(source_sh_degree=d).to_bytes()
        assert b == bytes([d << 6])  # u(2), then zero alignment bits
        assert SourceInfo.from_payload(b).source_sh_degree == d
        assert SourceInfo.from_payload(b + b"later").source_sh_degree == d  # reserved bytes ignored
    with pytest.raises(Exception, match="ends while reading"):
        SourceInfo.from_payload(b"")
    with pytest.raises(Exception, match="alignment"):
        SourceInfo.from_payload(bytes([0x81]))


def test_encoder_writes_source_info_and_the_scene_does_not_depend_on_it(plain):
    scene, base = plain
    info = DataUnit(SOURCE_INFO, SourceInfo(source_sh_degree=3).to_bytes())
    res = encode_scene(scene, load_config("low"), ancillary=[info])
    units = read_container(res.data).units
    assert [u.unit_type for u in units[:2]] == [UnitType.SCENE_PARAMETER_SET, SOURCE_INFO]  # right after the sps
    assert res.scene_hash == base.scene_hash and len(res.data) == len(base.data) + 5 + 1 + 4
    assert res.breakdown.bytes_by_category["ancillary"] == 10
    dec = decode_stream(res.data, trace=True)
    assert dec.source_info == SourceInfo(source_sh_degree=3) and not dec.skipped_units and not dec.notes
    assert dec.stream_hash == base.scene_hash
    assert any(e.name == "source_info.source_sh_degree" and e.value == 3 for e in dec.trace)
    plain_dec = decode_stream(base.data)
    assert plain_dec.source_info is None
    np.testing.assert_array_equal(dec.scene.features, plain_dec.scene.features)
    with pytest.raises(ValueError, match="not an ancillary"):
        encode_scene(scene, load_config("low"), ancillary=[DataUnit(UnitType.GEOMETRY, b"")])


def test_unknown_ancillary_units_are_skipped_and_source_info_found_among_them(plain):
    _, base = plain
    data = _with_units(base.data, [DataUnit(0xC5, b"an extension"), DataUnit(0xFF, b""),
                                   DataUnit(SOURCE_INFO, SourceInfo(source_sh_degree=2).to_bytes()),
                                   DataUnit(0x81, b"\x00")], index=2)
    dec = decode_stream(data)
    assert dec.source_info.source_sh_degree == 2 and dec.stream_hash == base.scene_hash
    assert [s.split(" ")[0] for s in dec.skipped_units] == ["unknown_0xc5", "unknown_0xff", "unknown_0x81"]
    # without the list of known units (conformance/generate.py), every ancillary unit is skipped
    critical, skipped = organize_units(read_container(data))
    assert len(skipped) == 4 and all(not u.is_ancillary for u in critical)


@pytest.mark.parametrize("payload, why", [(b"", "cannot be parsed"), (bytes([0x41]), "cannot be parsed")])
def test_a_malformed_source_info_is_reported_and_ignored(plain, payload, why):
    _, base = plain
    dec = decode_stream(_with_units(base.data, [DataUnit(SOURCE_INFO, payload)]), trace=True)
    assert dec.source_info is None and dec.stream_hash == base.scene_hash
    assert len(dec.notes) == 1 and why in dec.notes[0]
    assert not any(e.name.startswith("source_info") for e in dec.trace)  # no half-parsed unit in the trace


def test_a_second_source_info_is_ignored(plain):
    _, base = plain
    units = [DataUnit(SOURCE_INFO, SourceInfo(source_sh_degree=d).to_bytes()) for d in (0, 3)]
    dec = decode_stream(_with_units(base.data, units))
    assert dec.source_info.source_sh_degree == 0 and "second source_info" in dec.notes[0]


def test_a_well_formed_source_info_after_a_malformed_first_one_is_ignored_too(plain):
    """A stream has at most one source_info unit (clause 7.3.10): a decoder uses the first and
    ignores every later one, even when the first is malformed (conformance stream c061)."""
    _, base = plain
    units = [DataUnit(SOURCE_INFO, b""), DataUnit(SOURCE_INFO, SourceInfo(source_sh_degree=3).to_bytes())]
    dec = decode_stream(_with_units(base.data, units))
    assert dec.source_info is None and dec.stream_hash == base.scene_hash
    assert len(dec.notes) == 2 and "cannot be parsed" in dec.notes[0] and "second source_info" in dec.notes[1]


def test_an_ancillary_unit_before_the_parameter_set_is_still_an_error(plain):
    _, base = plain
    from lghcc.common.errors import BitstreamError

    with pytest.raises(BitstreamError, match="precedes"):
        decode_stream(_with_units(base.data, [DataUnit(SOURCE_INFO, b"\x80")], index=0))


def test_export_takes_the_sh_degree_from_source_info(plain, tmp_path, capsys):
    from lghcc.formats.ply3dgs import read_3dgs_ply

    _, base = plain
    cases = {"info2": (_with_units(base.data, [DataUnit(SOURCE_INFO, SourceInfo(source_sh_degree=2).to_bytes())]), [],
                       2),
             "info2_asked0": (None, ["--export-sh-degree", "0"], 0),
             "unknown": (_with_units(base.data, [DataUnit(0xC0, b"\x80")]), [], 1),  # not source_info: default 1
             "bad": (_with_units(base.data, [DataUnit(SOURCE_INFO, b"")]), [], 1)}
    last = None
    for name, (data, extra, degree) in cases.items():
        data = data or last
        last = data
        stream = tmp_path / f"{name}.lghcc"
        stream.write_bytes(data)
        out = tmp_path / f"{name}.ply"
        assert dec_cli.main([str(stream), "--export", str(out), *extra]) == 0
        cap = capsys.readouterr()
        assert read_3dgs_ply(out).sh_degree == degree, name
        if name == "info2":
            assert "source_info" in cap.out and "SH degree 2" in cap.out
            assert "the source's degree (source_info)" in cap.out and "18 directions" in cap.out
        if name == "bad":
            assert "warning: source_info" in cap.err and "ignored" in cap.err


def test_decoder_package_does_not_import_the_encoder():
    import subprocess

    code = ("import sys, lghcc.decoder.cli, lghcc.decoder.decode; "
            "sys.exit(any(m.startswith('lghcc.encoder') for m in sys.modules))")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
