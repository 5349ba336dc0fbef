"""lghcc-enc / lghcc-dec as a user runs them (main(argv), no subprocess)."""

from pathlib import Path

import numpy as np
import pytest

from lghcc.common.scaffold_io import read_scaffold, write_scaffold
from lghcc.decoder import cli as dec_cli
from lghcc.encoder import cli as enc_cli

from scenes import random_scene


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
    assert "use --force" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"
    assert enc_cli.main(["--procedural", "100", "-o", str(out), "--force", "-q"]) == 0
    assert out.read_bytes()[:4] == b"LGHC"


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
    assert dec_cli.main([str(bad), "-o", str(tmp_path / "d")]) == 1
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
