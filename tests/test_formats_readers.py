"""The readers of compressed PLY, streamed SOG (lod-meta.json), .splat and .ksplat: value for
value as the pinned splat-transform reads the same small files, made in the test (skipped
without Node: `make node-tools`); their errors; opacity logits of +-inf read as opacity 1 and 0
with one warning; and the one error for a path that is no scene, which names what was expected
and what was found (issue 57: never a preset message for the wrong kind of scene)."""

import importlib.util
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from scenes import splat_transform, splat_transform_or_skip

from lghcc.common.errors import InputError
from lghcc.common.scene import GaussianScene
from lghcc.encoder import cli as enc_cli
from lghcc.formats import detect_format, read_scene, streamed_sog, write_scene
from lghcc.formats.opacity import LARGEST_OPACITY_LOGIT, InfiniteOpacityWarning
from lghcc.formats.ply import read_ply, write_ply
from lghcc.formats.ply3dgs import read_3dgs_ply, write_3dgs_ply

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_readers", ROOT / "tools" / "check_readers.py")
check_readers = importlib.util.module_from_spec(_spec)
sys.modules["check_readers"] = check_readers
_spec.loader.exec_module(check_readers)

FIELDS = ("means", "sh", "opacity", "log_scales", "rotations")


def make_scene(n: int, degree: int, seed: int = 0) -> GaussianScene:
    """Opacities from far below 1/255 to far above 254/255 (alpha 0 and 255 in 8 bits)."""
    rng = np.random.default_rng(seed)
    sh = rng.uniform(-1.2, 1.2, (n, (degree + 1) ** 2, 3))
    sh[:, 0] = rng.uniform(-2, 2, (n, 3))
    return GaussianScene(rng.normal(size=(n, 3)).astype(np.float32) * 3, sh.astype(np.float32),
                         rng.uniform(-12, 12, n).astype(np.float32), rng.uniform(-6, 0, (n, 3)).astype(np.float32),
                         rng.normal(size=(n, 4)).astype(np.float32))


def assert_same(ours: GaussianScene, theirs: GaussianScene) -> None:
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(ours, f), getattr(theirs, f), err_msg=f)


def theirs(tool, path: Path, *select) -> GaussianScene:
    """The scene splat-transform reads from ``path``, through the PLY it writes (its +-inf
    opacity logits read as lghcc reads them)."""
    ply = path.with_name(path.name + "".join(map(str, select)) + ".st.ply")
    splat_transform(tool, path, *select, ply)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InfiniteOpacityWarning)
        return read_3dgs_ply(ply)


# --- against splat-transform -------------------------------------------------------------

@pytest.mark.integration
@pytest.mark.parametrize("degree", [0, 2])
def test_compressed_ply_reads_as_splat_transform_reads_it(tmp_path, degree):
    tool = splat_transform_or_skip()
    write_3dgs_ply(tmp_path / "s.ply", make_scene(700, degree))  # 3 chunks of 256
    splat_transform(tool, tmp_path / "s.ply", tmp_path / "s.compressed.ply")
    assert detect_format(tmp_path / "s.compressed.ply").name == "compressed-ply"
    ours = read_scene(tmp_path / "s.compressed.ply")
    assert ours.num_gaussians == 700 and ours.sh_degree == degree
    assert_same(ours, theirs(tool, tmp_path / "s.compressed.ply"))
    # splat-transform's own reading gives alpha 255 and 0 as +-inf; ours the finite logits
    raw = read_ply(tmp_path / "s.compressed.ply.st.ply")["opacity"]
    assert np.isinf(raw).any()
    np.testing.assert_array_equal(ours.opacity[np.isinf(raw)], np.sign(raw[np.isinf(raw)]) *
                                  np.float32(LARGEST_OPACITY_LOGIT))


@pytest.mark.integration
def test_streamed_sog_reads_each_level_as_splat_transform_does(tmp_path, monkeypatch):
    tool = splat_transform_or_skip()
    write_3dgs_ply(tmp_path / "fine.ply", make_scene(2500, 1, seed=1))
    write_3dgs_ply(tmp_path / "coarse.ply", make_scene(600, 1, seed=2))
    lod = tmp_path / "scene" / "lod-meta.json"
    splat_transform(tool, "--lod-chunk-count", "1", tmp_path / "fine.ply", "-l", "0", tmp_path / "coarse.ply",
                    "-l", "1", lod)
    meta = json.loads(lod.read_text())
    assert sum(name.startswith("0_") for name in meta["filenames"]) > 1  # level 0 in several units
    assert detect_format(lod).name == "streamed-sog"
    for level in (0, 1):
        assert_same(read_scene(lod, lod=level), theirs(tool, lod, "-L", level))
    assert read_scene(lod).num_gaussians == 2500  # default: the level with the most Gaussians
    opened = []
    monkeypatch.setattr(streamed_sog, "read_sog", lambda p: opened.append(p.parent.name) or read_scene(p))
    assert read_scene(lod, lod=-1).num_gaussians == 600  # negative: from the coarsest end
    assert opened and all(name.startswith("1_") for name in opened)  # only the chosen level's units are read


@pytest.mark.integration
def test_splat_reads_as_splat_transform_reads_it(tmp_path):
    tool = splat_transform_or_skip()
    (tmp_path / "s.splat").write_bytes(check_readers.splat_bytes(make_scene(300, 0)))
    ours = read_scene(tmp_path / "s.splat")
    assert detect_format(tmp_path / "s.splat").name == "splat" and ours.num_gaussians == 300
    assert_same(ours, theirs(tool, tmp_path / "s.splat"))


@pytest.mark.integration
@pytest.mark.parametrize("mode, degree", [(0, 0), (0, 2), (1, 1), (1, 3), (2, 2)])
def test_ksplat_reads_as_splat_transform_reads_it(tmp_path, mode, degree):
    """Two sections; in modes 1 and 2 full and partial buckets."""
    tool = splat_transform_or_skip()
    path = tmp_path / "s.ksplat"
    path.write_bytes(check_readers.ksplat_bytes(make_scene(900, degree), mode, capacity=64))
    ours = read_scene(path)
    assert ours.num_gaussians == 900 and ours.sh_degree == degree
    assert_same(ours, theirs(tool, path))


# --- without Node ----------------------------------------------------------------------------

def _streamed(tmp_path: Path, counts=(300, 80, 40)) -> Path:
    """A streamed SOG written here: level 0 in units 0 and 1, level 1 in unit 2 (SOG units by
    lghcc's writer, the tree by hand)."""
    folder = tmp_path / "streamed"
    names = ["0_0.sog", "0_1.sog", "1_0.sog"]
    for i, (name, n) in enumerate(zip(names, counts)):
        scene = make_scene(n, 1, seed=i)
        scene.opacity[:] = 3.0  # all drawn: none is dropped by the presets that drop what no rasterizer draws
        write_scene(scene, folder / name)
    tree = {"children": [{"lods": {"0": {"file": 0, "offset": 0, "count": counts[0]}}},
                         {"lods": {"0": {"file": 1, "offset": 0, "count": counts[1]},
                                   "1": {"file": 2, "offset": 0, "count": counts[2]}}}]}
    meta = {"version": 1, "lodLevels": 2, "counts": [counts[0] + counts[1], counts[2]], "filenames": names,
            "tree": tree}
    (folder / "lod-meta.json").write_text(json.dumps(meta))
    return folder / "lod-meta.json"


def test_streamed_sog_levels_units_and_errors(tmp_path):
    lod = _streamed(tmp_path)
    units = [read_scene(lod.parent / n) for n in json.loads(lod.read_text())["filenames"]]
    fine = read_scene(lod)
    assert fine.num_gaussians == 380
    np.testing.assert_array_equal(fine.means, np.concatenate([units[0].means, units[1].means]))
    assert_same(read_scene(lod, lod=1), units[2])
    with pytest.raises(InputError, match=r"level of detail 2\b.*0 \(380 Gaussians\), 1 \(40"):
        read_scene(lod, lod=2)
    with pytest.raises(InputError, match="option 'lod' applies to streamed-sog, this is sog"):
        read_scene(lod.parent / "1_0.sog", lod=0)
    meta = json.loads(lod.read_text())
    meta["counts"] = [1, 40]
    lod.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"\[380, 40\].*'counts'.*\[1, 40\]"):
        read_scene(lod)
    del meta["counts"]
    meta["tree"]["children"][0]["lods"]["0"]["count"] = 299
    lod.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"0_0.sog\b.*300 Gaussians\b.*299\b.*level 0"):
        read_scene(lod)
    (lod.parent / "0_0.sog").unlink()
    with pytest.raises(InputError, match="0_0.sog"):
        read_scene(lod)


@pytest.mark.parametrize("name, data, message", [
    ("s.splat", b"\0" * 33, "33 bytes: a .splat file is a positive multiple of 32 bytes"),
    ("s.splat", b"", "0 bytes: a .splat file"),
    ("s.ksplat", b"\0\1" + b"\0" * 100, "shorter than the .ksplat header"),
    ("s.ksplat", b"\1\0" + b"\0" * 5000, "version 1.0"),
    ("s.ksplat", b"\0\1" + b"\0" * 18 + b"\3\0" + b"\0" * 5000, "compression mode 3"),
])
def test_malformed_splat_and_ksplat_name_the_problem(tmp_path, name, data, message):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(InputError, match=message):
        read_scene(tmp_path / name)


def test_a_truncated_ksplat_is_an_error(tmp_path):
    data = check_readers.ksplat_bytes(make_scene(100, 1), 1)
    (tmp_path / "s.ksplat").write_bytes(data[:-10])
    with pytest.raises(InputError, match="truncated"):
        read_scene(tmp_path / "s.ksplat")


# --- +-inf opacity logits (issue 57) ------------------------------------------------------

def _ply_with_opacities(path: Path, values) -> Path:
    scene = make_scene(60, 1)
    write_3dgs_ply(path, scene)
    cols = read_ply(path)
    cols["opacity"][: len(values)] = values
    write_ply(path, cols)
    return path


def test_infinite_opacity_logits_read_as_opacity_1_and_0_with_one_warning(tmp_path):
    ply = _ply_with_opacities(tmp_path / "inf.ply", [np.inf, -np.inf, np.inf])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = read_scene(ply)
    assert [str(w.message) for w in caught] == [
        f"{ply}: 2 opacity logits of +inf and 1 of -inf read as opacity 1 and 0 (logits +-13.82, as alpha 255 "
        "and 0 decode)"]
    top = np.float32(LARGEST_OPACITY_LOGIT)
    assert list(scene.opacity[:3]) == [top, -top, top]
    _ply_with_opacities(ply, [np.inf, np.nan])
    with pytest.raises(InputError, match="'opacity' contains NaN or Inf"):
        read_scene(ply)


def test_lghcc_enc_codes_infinite_opacities_with_one_warning_line(tmp_path, capsys):
    ply = _ply_with_opacities(tmp_path / "inf.ply", [np.inf, -np.inf])
    assert enc_cli.main([str(ply), "--preset", "fast", "-o", str(tmp_path / "s.lghcc"), "-q"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"lghcc-enc: warning: {ply}: 1 opacity logits of +inf and 1 of -inf read as opacity 1 and 0 "
                   "(logits +-13.82, as alpha 255 and 0 decode)"]


# --- what is no scene (issue 57) -----------------------------------------------------------

def _not_scenes(tmp_path: Path) -> list[tuple[Path, str]]:
    (tmp_path / "cameras.json").write_text('{"frames": [], "camera_angle_x": 0.7}')
    (tmp_path / "published").mkdir()
    (tmp_path / "published" / "lod-meta.json").write_text("{}")
    write_ply(tmp_path / "points.ply", {k: np.zeros(3, np.float32) for k in ("x", "y", "z", "red", "green", "blue")})
    (tmp_path / "notes.txt").write_text("hello")
    return [(tmp_path / "cameras.json", "found a JSON object with keys frames, camera_angle_x"),
            (tmp_path / "published", "found a folder holding lod-meta.json (give that file itself)"),
            (tmp_path / "points.ply", "found a PLY file whose vertex properties are x, y, z, red, green, blue"),
            (tmp_path / "notes.txt", "found a file starting with b'hello'")]


def test_what_is_no_scene_is_named_with_what_was_expected(tmp_path):
    for path, found in _not_scenes(tmp_path):
        with pytest.raises(InputError) as e:
            read_scene(path)
        assert "expected a 3DGS scene (" in str(e.value) and "or a Scaffold-GS model" in str(e.value)
        assert found in str(e.value)


@pytest.mark.parametrize("preset", ["fast", "lghcc-medium", "medium"])
def test_lghcc_enc_says_what_it_saw_not_a_preset_message(tmp_path, capsys, preset):
    """`lghcc-enc x --preset fast` once answered a JSON file with 'unknown preset ... for anchors'."""
    for path, found in _not_scenes(tmp_path):
        assert enc_cli.main([str(path), "--preset", preset, "-o", str(tmp_path / "s.lghcc")]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not a scene" in err[0] and "3DGS scene" in err[0], err
        assert found in err[0] and "preset" not in err[0]
        assert not (tmp_path / "s.lghcc").exists()


def test_lghcc_enc_reads_a_streamed_sog_level(tmp_path, capsys):
    lod = _streamed(tmp_path)
    out = tmp_path / "s.lghcc"
    assert enc_cli.main([str(lod), "--lod", "1", "--preset", "fast", "-o", str(out), "-q"]) == 0
    from lghcc.decoder.decode import decode_stream

    assert decode_stream(out.read_bytes()).scene.num_gaussians == 40
    assert enc_cli.main([str(lod.parent / "0_0.sog"), "--lod", "1", "--preset", "fast", "-o",
                         str(tmp_path / "t.lghcc")]) == 1
    err = capsys.readouterr().err
    assert "'lod'" in err and "streamed-sog" in err
