"""lghcc-enc / lghcc-dec as a user runs them (main(argv), no subprocess)."""

from pathlib import Path

import numpy as np
import pytest

from lghcc.formats.scaffold_io import read_scaffold, write_scaffold
from lghcc.decoder import cli as dec_cli
from lghcc.encoder import cli as enc_cli

from scenes import random_scene, scaffold_gs_positions, write_scaffold_gs_model


def test_procedural_demo_round_trip(tmp_path, capsys):
    out = tmp_path / "demo.lghcc"
    assert enc_cli.main(["--procedural", "1500", "-o", str(out), "--json", str(tmp_path / "e.json"),
                         "--report-ideal"]) == 0
    text = capsys.readouterr().out
    assert "geometry" in text and "attributes" in text and "hash matches" in text
    assert "over the model's ideal" in text
    assert dec_cli.main([str(out), "-o", str(tmp_path / "dec"), "--trace", str(tmp_path / "t.txt")]) == 0
    text = capsys.readouterr().out
    assert "matches the stream" in text and "bits/anchor" in text
    scene = read_scaffold(tmp_path / "dec")
    assert scene.num_anchors > 1000
    trace = (tmp_path / "t.txt").read_text()
    assert "scene_parameter_set.num_anchors_minus1" in trace


def test_scaffold_folder_in_and_out(tmp_path, capsys):
    scene = random_scene(np.random.default_rng(1), 300, c=8, k=3, mask=True)
    write_scaffold(scene, tmp_path / "model")
    out = tmp_path / "s.lghcc"
    assert enc_cli.main([str(tmp_path / "model"), "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert dec_cli.main([str(out), "-o", str(tmp_path / "dec"), "-q"]) == 0
    back = read_scaffold(tmp_path / "dec")
    assert back.num_anchors == 300 and back.offset_mask is not None


def test_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "x.lghcc"
    out.write_bytes(b"keep me")
    assert enc_cli.main(["--procedural", "100", "-o", str(out)]) == 1
    assert "exists; use -y (--overwrite)" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"
    assert enc_cli.main(["--procedural", "100", "-o", str(out), "-n"]) == 1  # -n: the default, said explicitly
    assert out.read_bytes() == b"keep me"
    for flag in ("-y", "--overwrite", "-f", "--force"):  # -f/--force: the older spelling, kept
        out.write_bytes(b"keep me")
        assert enc_cli.main(["--procedural", "100", "-o", str(out), flag, "-q"]) == 0
        assert out.read_bytes()[:4] == b"LGHC"
    with pytest.raises(SystemExit):  # -y and -n contradict each other: a usage error
        enc_cli.main(["--procedural", "100", "-o", str(out), "-y", "-n"])


def test_input_is_never_overwritten(tmp_path, capsys):
    scene = random_scene(np.random.default_rng(1), 20)
    folder = write_scaffold(scene, tmp_path / "m")
    ply = folder / "point_cloud.ply"
    before = ply.read_bytes()
    assert enc_cli.main([str(ply), "-o", str(ply), "--force"]) == 1
    assert "overwrite the input" in capsys.readouterr().err
    assert ply.read_bytes() == before


def test_clear_errors(tmp_path, capsys):
    assert enc_cli.main([str(tmp_path / "missing"), "-o", str(tmp_path / "o.lghcc")]) == 1
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.lghcc"
    bad.write_bytes(b"LGHC\x00\x01\x01\x00" + b"\x01\x00\x00\x00\x10" + b"\x00" * 3)
    assert dec_cli.main([str(bad), "-o", str(tmp_path / "d")]) == 3  # invalid stream (lghcc.app.cli_common)
    err = capsys.readouterr().err
    assert "bad.lghcc" in err and "Traceback" not in err
    assert not (tmp_path / "d").exists()


def test_unknown_preset_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit) as e:
        enc_cli.main(["--procedural", "100", "-o", str(tmp_path / "a"), "--preset", "nope"])
    assert e.value.code == 2


def test_help_explains(capsys):
    for main in (enc_cli.main, dec_cli.main):
        with pytest.raises(SystemExit):
            main(["--help"])
        text = capsys.readouterr().out
        assert "examples:" in text and "Scaffold-GS" in text


# --- outputs: clean errors, never over the input, never mixing two scenes ------------------------------

@pytest.fixture(scope="module")
def small_stream(tmp_path_factory):
    d = tmp_path_factory.mktemp("stream")
    out = d / "s.lghcc"
    assert enc_cli.main(["--procedural", "200", "-o", str(out), "-q"]) == 0
    return out


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def test_unwritable_outputs_are_one_line_errors(tmp_path, capsys, small_stream):
    afile = tmp_path / "afile"
    afile.write_bytes(b"x")
    adir = tmp_path / "adir"
    adir.mkdir()
    cases = [
        (dec_cli.main, [str(small_stream), "-o", str(afile)], f"cannot write {afile} (it exists and is not a folder)"),
        (dec_cli.main, [str(small_stream), "--render", "orbit:1", "--render-out", str(afile)],
         f"cannot write {afile} (it exists and is not a folder)"),
        (dec_cli.main, [str(small_stream), "--json", str(afile / "x.json")], f"cannot write {afile / 'x.json'}"),
        (dec_cli.main, [str(small_stream), "--trace", str(adir)], f"cannot write {adir} (it is a folder)"),
        (enc_cli.main, ["--procedural", "100", "-o", str(adir), "-f"], f"cannot write {adir} (it is a folder)"),
        (enc_cli.main, ["--procedural", "100", "-o", str(afile / "x.lghcc")], f"cannot write {afile / 'x.lghcc'}"),
        (enc_cli.main, ["--procedural", "100", "-o", str(tmp_path / "ok.lghcc"), "--json", str(adir)],
         f"cannot write {adir} (it is a folder)"),
    ]
    for main, argv, message in cases:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and err.count("\n") == 1, (argv, err)
    assert afile.read_bytes() == b"x" and list(adir.iterdir()) == []
    assert not (tmp_path / "ok.lghcc").exists()  # nothing is written when one output cannot be


def test_write_failing_late_is_a_clean_error(tmp_path, capsys, small_stream, monkeypatch):
    # A failure only the write itself finds (disk full, a path that vanished) is reported the same way.
    import errno

    from lghcc.app import fileio

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(fileio.tempfile, "mkstemp", full)
    monkeypatch.setattr(fileio, "check_writable_file", lambda *a, **k: None)
    assert dec_cli.main([str(small_stream), "-q", "-o", str(tmp_path / "dec")]) == 1
    assert f"cannot write {tmp_path / 'dec'} (No space left on device)" in capsys.readouterr().err
    assert dec_cli.main([str(small_stream), "-q", "--json", str(tmp_path / "d.json")]) == 1
    assert f"cannot write {tmp_path / 'd.json'} (No space left on device)" in capsys.readouterr().err
    assert enc_cli.main(["--procedural", "100", "-q", "-o", str(tmp_path / "e.lghcc")]) == 1
    assert f"cannot write {tmp_path / 'e.lghcc'} (No space left on device)" in capsys.readouterr().err


def test_error_messages_name_the_path_once(tmp_path, capsys):
    missing = tmp_path / "nope.lghcc"
    assert dec_cli.main([str(missing)]) == 1
    err = capsys.readouterr().err
    assert err == f"lghcc-dec: error: {missing}: cannot read (No such file or directory)\n"


@pytest.mark.parametrize("value", ["nan", "0", "-1", "inf", "abc"])
def test_bad_render_scale_and_voxel_size_are_usage_errors(value, capsys, tmp_path, small_stream):
    with pytest.raises(SystemExit) as e:
        dec_cli.main([str(small_stream), "--render", "orbit:1", "--render-out", str(tmp_path / "v"),
                      "--render-scale", value])
    assert e.value.code == 2
    assert "--render-scale" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        enc_cli.main(["--procedural", "100", "-o", str(tmp_path / "x.lghcc"), "--voxel-size", value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--voxel-size" in err and ("positive finite" in err or "expected a number" in err)
    assert "RuntimeWarning" not in err and not (tmp_path / "v").exists()


def test_no_output_may_overwrite_the_input(tmp_path, capsys, small_stream):
    stream = _copy(small_stream, tmp_path / "c.lghcc")
    before = stream.read_bytes()
    link = tmp_path / "link.lghcc"
    link.symlink_to(stream)
    for argv in (["--json", str(stream)], ["--trace", str(stream)], ["--export-ply", str(stream)],
                 ["--json", str(tmp_path / "." / "c.lghcc")], ["--trace", str(link)], ["-o", str(stream)]):
        assert dec_cli.main([str(stream), "-q"] + argv) == 1, argv
        err = capsys.readouterr().err
        assert "overwrite" in err and "input stream" in err
    assert dec_cli.main([str(stream), "-q", "--json", str(tmp_path / "a"), "--trace", str(tmp_path / "a")]) == 1
    assert "are the same file" in capsys.readouterr().err
    assert stream.read_bytes() == before
    # The encoder: --json against the input (a PLY, or the PLY inside a model folder) and against -o.
    folder = write_scaffold(random_scene(np.random.default_rng(1), 20), tmp_path / "m")
    ply = folder / "point_cloud.ply"
    ply_bytes = ply.read_bytes()
    for argv in ([str(ply), "-o", str(tmp_path / "o.lghcc"), "--json", str(ply)],
                 [str(tmp_path / "m"), "-o", str(tmp_path / "o.lghcc"), "--json", str(ply)],
                 [str(tmp_path / "m"), "-o", str(ply), "-f"]):
        assert enc_cli.main(argv) == 1, argv
        assert "would overwrite the input" in capsys.readouterr().err
    assert enc_cli.main(["--procedural", "100", "-o", str(tmp_path / "o.lghcc"), "--json",
                         str(tmp_path / "o.lghcc")]) == 1
    assert "are the same file" in capsys.readouterr().err
    assert ply.read_bytes() == ply_bytes and not (tmp_path / "o.lghcc").exists()


def test_decoding_into_a_used_folder_needs_force_and_never_mixes_scenes(tmp_path, capsys):
    with_mlps = random_scene(np.random.default_rng(2), 30, with_mlps=True)
    without = random_scene(np.random.default_rng(3), 40, with_mlps=False)
    for name, scene in (("a", with_mlps), ("b", without)):
        from lghcc.encoder.stream.encode import encode_scene
        (tmp_path / f"{name}.lghcc").write_bytes(encode_scene(scene).data)
    out = tmp_path / "dec"
    assert dec_cli.main([str(tmp_path / "a.lghcc"), "-o", str(out), "-q"]) == 0
    it = out / "point_cloud" / "iteration_0"
    assert (it / "checkpoint.pth").is_file()
    assert dec_cli.main([str(tmp_path / "b.lghcc"), "-o", str(out), "-q"]) == 1
    assert "-y (--overwrite)" in capsys.readouterr().err
    assert dec_cli.main([str(tmp_path / "b.lghcc"), "-o", str(out), "-q", "-y"]) == 0
    assert not (it / "checkpoint.pth").exists()  # the first scene's MLPs are gone
    with pytest.warns(UserWarning, match="no render-MLP file recognised"):
        back = read_scaffold(out)
    assert back.num_anchors == 40 and back.mlps == {}
    # An empty existing folder needs no --force.
    (tmp_path / "empty").mkdir()
    assert dec_cli.main([str(tmp_path / "a.lghcc"), "-o", str(tmp_path / "empty"), "-q"]) == 0


def test_encoder_refuses_a_folder_without_mlps_unless_asked(tmp_path, capsys):
    """Its decoded scene could be neither rendered nor exported: refused (exit 1, nothing
    written) with a message saying why and what to do; --allow-no-mlps codes it anyway."""
    folder = write_scaffold(random_scene(np.random.default_rng(4), 25, with_mlps=False), tmp_path / "m")
    assert enc_cli.main([str(tmp_path / "m"), "-o", str(tmp_path / "x.lghcc"), "-q"]) == 1
    err = capsys.readouterr().err
    warning, error = err.strip().splitlines()
    assert warning.startswith(f"lghcc-enc: warning: {folder}:") and "render-MLP" in warning
    assert error.startswith("lghcc-enc: error:") and "render MLPs" in error and "--allow-no-mlps" in error
    assert not (tmp_path / "x.lghcc").exists()
    assert enc_cli.main([str(tmp_path / "m"), "-o", str(tmp_path / "x.lghcc"), "-q", "--allow-no-mlps"]) == 0
    # its decoded scene: rendering and export say why they cannot, before writing anything
    assert dec_cli.main([str(tmp_path / "x.lghcc"), "--render", "orbit:1", "--render-out", str(tmp_path / "v")]) == 1
    err = capsys.readouterr().err
    assert "opacity, cov, color MLP" in err and "rendered" in err
    assert dec_cli.main([str(tmp_path / "x.lghcc"), "--export", str(tmp_path / "x.ply")]) == 1
    assert "exported" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


def test_decode_then_reencode_gives_the_same_scene(tmp_path, capsys):
    import json

    first, again = tmp_path / "a.lghcc", tmp_path / "b.lghcc"
    assert enc_cli.main(["--procedural", "2500", "--seed", "3", "-o", str(first), "--json", str(tmp_path / "a.json"),
                         "-q"]) == 0
    assert dec_cli.main([str(first), "-o", str(tmp_path / "dec"), "-q"]) == 0
    ply = tmp_path / "dec" / "point_cloud" / "iteration_0" / "point_cloud.ply"
    assert b"comment lghcc voxel_size " in ply.read_bytes()[:400]
    assert enc_cli.main([str(tmp_path / "dec"), "-o", str(again), "--json", str(tmp_path / "b.json"), "-q"]) == 0
    h1 = json.loads((tmp_path / "a.json").read_text())["scene_sha256"]
    h2 = json.loads((tmp_path / "b.json").read_text())["scene_sha256"]
    assert h1 == h2
    # Without the header comment (origin 0) the voxel size inferred from the float32 positions is the
    # float32 the scene multiplies by: the same bits.
    from lghcc.formats.scaffold_io import infer_voxel_size
    scene = read_scaffold(tmp_path / "dec")
    assert infer_voxel_size(scene.positions().astype(np.float64)) == scene.voxel_size


def test_same_stream_whether_the_voxel_size_is_stated_inferred_or_given(tmp_path, capsys):
    """A model as Scaffold-GS writes it (voxel size 0.001, float32 positions, no lghcc header
    comments) codes to the same stream whether its voxel size comes from its cfg_args, from
    --voxel-size or from the anchor grid; the log says which, and the geometry comes back exactly."""
    rng = np.random.default_rng(0)
    k = np.vstack([np.unique(rng.integers(-6, 7, size=(400, 3)), axis=0), [[200_000, -150_000, 3_000]]])
    write_scaffold_gs_model(tmp_path / "m", k, 0.001, mlps="unite")
    ply = tmp_path / "m" / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    streams = {}
    for how, extra, said in (
            ("cfg_args", [], f"{ply}: voxel size 0.001 from {tmp_path / 'm' / 'cfg_args'}"),
            ("given", ["--voxel-size", "0.001"], f"{ply}: voxel size 0.001 as given (--voxel-size)"),
            ("inferred", [], f"{ply}: voxel size 0.001 inferred from the anchor grid (no cfg_args in the model folder)")):
        if how == "inferred":
            (tmp_path / "m" / "cfg_args").unlink()
        out = tmp_path / f"{how}.lghcc"
        assert enc_cli.main([str(tmp_path / "m"), "-o", str(out), "--preset", "low", *extra]) == 0
        assert said in capsys.readouterr().err
        streams[how] = out.read_bytes()
    assert streams["cfg_args"] == streams["given"] == streams["inferred"]
    assert dec_cli.main([str(tmp_path / "inferred.lghcc"), "-o", str(tmp_path / "dec"), "-q"]) == 0
    back = read_scaffold(tmp_path / "dec").positions()
    assert np.array_equal(np.unique(back, axis=0), np.unique(scaffold_gs_positions(k, 0.001), axis=0))


def test_hash_mismatch_prints_both_full_digests_and_the_stream(tmp_path, capsys, small_stream):
    import zlib

    data = bytearray(small_stream.read_bytes())
    unit = slice(len(data) - (5 + 33 + 4), len(data) - 4)  # the decoded_scene_hash unit, without its CRC
    assert data[unit.start] == 0x06
    data[-5] ^= 0x01  # last byte of scene_hash
    data[-4:] = zlib.crc32(bytes(data[unit])).to_bytes(4, "big")
    bad = tmp_path / "bad.lghcc"
    bad.write_bytes(bytes(data))
    assert dec_cli.main([str(bad)]) == 3  # invalid stream: a hash mismatch is one (lghcc.app.cli_common)
    err = capsys.readouterr().err
    import re
    digests = re.findall(r"\b[0-9a-f]{64}\b", err)
    assert len(digests) == 2 and digests[0] != digests[1] and digests[0][:62] == digests[1][:62]
    assert str(bad) in err


def test_outputs_get_the_umask_mode(tmp_path, small_stream):
    import os
    import stat

    old = os.umask(0o027)
    try:
        assert dec_cli.main([str(small_stream), "-q", "-o", str(tmp_path / "d"), "--json", str(tmp_path / "d.json")]) == 0
        assert enc_cli.main(["--procedural", "50", "-q", "-o", str(tmp_path / "e.lghcc")]) == 0
    finally:
        os.umask(old)
    for f in (tmp_path / "d.json", tmp_path / "e.lghcc", tmp_path / "d" / "point_cloud" / "iteration_0" / "point_cloud.ply",
              tmp_path / "d" / "point_cloud" / "iteration_0" / "checkpoint.pth"):
        assert stat.S_IMODE(f.stat().st_mode) == 0o640, f


def test_procedural_progress_bar_does_not_change_the_scene(capsys, monkeypatch):
    monkeypatch.setenv("LGHCC_PROGRESS_INTERVAL", "0")  # stderr is no terminal here: log lines, each update
    from lghcc.common.hashing import scene_digest
    from lghcc.formats.procedural import make_procedural_scene

    quiet = make_procedural_scene(3000, seed=7, with_mask=True)
    shown = make_procedural_scene(3000, seed=7, with_mask=True, progress=True)
    assert scene_digest(quiet) == scene_digest(shown)
    assert np.array_equal(quiet.offset_mask, shown.offset_mask)
    assert "procedural scene" in capsys.readouterr().err
