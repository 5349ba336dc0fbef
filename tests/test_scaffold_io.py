"""The Scaffold-GS checkpoint layout: write, read, variants, errors."""

import re

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.common.hashing import scene_digest
from lghcc.formats.ply import read_ply, read_ply_comments, write_ply
from lghcc.formats.procedural import make_procedural_scene
from lghcc.formats.scaffold_io import (MissingMlpWarning, infer_voxel_size, read_cfg_args, read_scaffold,
                                      write_scaffold)

from scenes import scaffold_gs_positions, write_scaffold_gs_model


def test_round_trip_exact(tmp_path):
    scene = make_procedural_scene(500, seed=3, feature_dim=50, num_offsets=10, with_mask=True)
    folder = write_scaffold(scene, tmp_path)
    back = read_scaffold(tmp_path)
    assert folder.name == "iteration_0"
    assert np.array_equal(back.coords, scene.coords)
    assert back.voxel_size == pytest.approx(scene.voxel_size, rel=1e-6)
    for name in ("features", "scalings", "offsets"):
        assert np.array_equal(getattr(back, name), getattr(scene, name)), name
    assert np.array_equal(back.offset_mask, scene.offset_mask)
    for role in ("opacity", "cov", "color"):
        assert back.mlps[role].activations == scene.mlps[role].activations
        for a, b in zip(back.mlps[role].weights, scene.mlps[role].weights):
            assert np.array_equal(a, b)


def test_offsets_are_stored_transposed(tmp_path):
    scene = make_procedural_scene(50, seed=0, feature_dim=4, num_offsets=3)
    write_scaffold(scene, tmp_path)
    cols = read_ply(tmp_path / "point_cloud" / "iteration_0" / "point_cloud.ply")
    # f_offset index = axis * K + k
    assert np.array_equal(cols["f_offset_4"], scene.offsets[:, 1, 1])
    assert np.array_equal(cols["f_offset_2"], scene.offsets[:, 2, 0])


def test_hac_variant_mask_logits_and_names(tmp_path):
    scene = make_procedural_scene(80, seed=0, feature_dim=4, num_offsets=2)
    folder = write_scaffold(scene, tmp_path)
    cols = read_ply(folder / "point_cloud.ply")
    logits = np.where(np.arange(80) % 3 == 0, -10.0, 3.0).astype(np.float32)
    cols["f_mask_0"] = logits
    cols["f_mask_1"] = -logits
    write_ply(folder / "point_cloud.ply", cols)
    sd = torch.load(folder / "checkpoint.pth", weights_only=True)
    torch.save({"mlp_opacity": sd["opacity_mlp"], "mlp_color": sd["color_mlp"]}, folder / "checkpoint.pth")
    back = read_scaffold(folder / "point_cloud.ply")
    assert np.array_equal(back.offset_mask[:, 0], np.arange(80) % 3 != 0)
    assert set(back.mlps) == {"opacity", "color"}


def test_voxel_size_inference_and_off_grid_input():
    rng = np.random.default_rng(0)
    coords = rng.integers(-1000, 1000, size=(500, 3))
    assert infer_voxel_size(coords * 0.013) == pytest.approx(0.013, rel=2.0 ** -24)  # the float32 the scene codes
    with pytest.raises(InputError, match="not on a regular grid"):
        infer_voxel_size(rng.normal(size=(500, 3)))


def test_plain_3dgs_ply_is_explained(tmp_path):
    write_ply(tmp_path / "g.ply", {k: np.zeros(4, np.float32) for k in ("x", "y", "z", "f_dc_0", "opacity")})
    with pytest.raises(InputError, match="not a Scaffold-GS anchor file"):
        read_scaffold(tmp_path / "g.ply")


def test_truncated_and_garbage_ply(tmp_path):
    scene = make_procedural_scene(50, seed=0, feature_dim=4, num_offsets=2)
    folder = write_scaffold(scene, tmp_path)
    ply = folder / "point_cloud.ply"
    ply.write_bytes(ply.read_bytes()[:-10])
    with pytest.raises(InputError, match="truncated"):
        read_scaffold(ply)
    (tmp_path / "junk.ply").write_bytes(b"not a ply at all")
    with pytest.raises(InputError, match="not a PLY file"):
        read_scaffold(tmp_path / "junk.ply")
    with pytest.raises(InputError, match="no point_cloud.ply"):
        read_scaffold(tmp_path / "nothing_here")


def test_checkpoints_pth_is_accepted_and_missing_mlps_warn(tmp_path):
    scene = make_procedural_scene(60, seed=1, feature_dim=4, num_offsets=2)
    folder = write_scaffold(scene, tmp_path)
    (folder / "checkpoint.pth").rename(folder / "checkpoints.pth")
    back = read_scaffold(tmp_path)
    assert set(back.mlps) == {"opacity", "cov", "color"}
    assert np.array_equal(back.mlps["cov"].weights[1], scene.mlps["cov"].weights[1])
    (folder / "checkpoints.pth").unlink()
    with pytest.warns(MissingMlpWarning, match=f"{folder}: no render-MLP file recognised"):
        assert read_scaffold(tmp_path).mlps == {}
    torch.save({"something_else": {}}, folder / "checkpoint.pth")
    with pytest.warns(MissingMlpWarning, match=r"checkpoint.pth\b.*render MLP"):
        assert read_scaffold(tmp_path).mlps == {}


def test_write_scaffold_removes_stale_mlp_files(tmp_path):
    with_mlps = make_procedural_scene(40, seed=0, feature_dim=4, num_offsets=2)
    folder = write_scaffold(with_mlps, tmp_path)
    for name in ("checkpoints.pth", "opacity_mlp.pt", "cov_mlp.pt", "color_mlp.pt"):
        (folder / name).write_bytes(b"stale")
    (folder / "notes.txt").write_bytes(b"not ours")
    write_scaffold(with_mlps, tmp_path)
    assert sorted(p.name for p in folder.iterdir()) == ["checkpoint.pth", "notes.txt", "point_cloud.ply"]
    without = make_procedural_scene(30, seed=1, feature_dim=4, num_offsets=2)
    without.mlps = {}
    write_scaffold(without, tmp_path)
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "point_cloud.ply"]
    with pytest.warns(MissingMlpWarning):
        back = read_scaffold(tmp_path)
    assert back.num_anchors == without.num_anchors and back.mlps == {}


def test_voxel_size_and_origin_survive_the_float32_positions(tmp_path):
    scene = make_procedural_scene(400, seed=2, feature_dim=4, num_offsets=2)
    scene.voxel_size = 0.06557438
    scene.origin = np.array([0.1, -2.5, 1e3], np.float32)
    folder = write_scaffold(scene, tmp_path)
    back = read_scaffold(tmp_path)
    assert back.voxel_size == float(np.float32(scene.voxel_size))
    assert back.origin.tobytes() == scene.origin.tobytes()
    assert np.array_equal(back.coords, scene.coords)
    assert scene_digest(back) == scene_digest(scene)
    # Other tools ignore comment lines; the values are exact hex floats.
    comments = read_ply_comments(folder / "point_cloud.ply")
    assert comments[0] == f"lghcc voxel_size {float(np.float32(0.06557438)).hex()}"
    assert comments[1].startswith("lghcc origin ")
    # An explicit voxel size still wins; a file without the comments falls back to inference.
    assert read_scaffold(tmp_path, voxel_size=2 * back.voxel_size).voxel_size == 2 * back.voxel_size
    cols = read_ply(folder / "point_cloud.ply")
    write_ply(folder / "point_cloud.ply", cols)
    assert read_ply_comments(folder / "point_cloud.ply") == []
    # Far from the origin the float32 positions no longer pin the grid down: inference fails.
    with pytest.raises(InputError, match="not on a regular grid"):
        read_scaffold(tmp_path)
    again = read_scaffold(tmp_path, voxel_size=back.voxel_size, origin=scene.origin)
    assert np.array_equal(again.coords, scene.coords)


def test_read_scaffold_validates_with_the_path(tmp_path):
    scene = make_procedural_scene(50, seed=0, feature_dim=4, num_offsets=2)
    folder = write_scaffold(scene, tmp_path)
    ply = folder / "point_cloud.ply"
    cols = read_ply(ply)
    for column, value, message in (("f_anchor_feat_2", np.nan, "features contain NaN or Inf"),
                                   ("scale_4", np.inf, "scalings contain NaN or Inf"),
                                   ("f_offset_1", -np.inf, "offsets contain NaN or Inf")):
        cols[column] = cols[column].copy()
        good = cols[column][7]
        cols[column][7] = value
        write_ply(ply, cols)
        with pytest.raises(InputError, match=f"^{re.escape(str(ply))}: {message}"):
            read_scaffold(tmp_path)
        cols[column][7] = good
    write_ply(ply, cols)
    for bad in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(InputError, match=r"voxel size\b.*positive finite"):
            read_scaffold(tmp_path, voxel_size=bad)
    # Anchors sharing a voxel are left for the encoder to reject or merge (--merge-duplicates).
    cols = read_ply(ply)
    for c in ("x", "y", "z"):
        cols[c][1] = cols[c][0]
    write_ply(ply, cols)
    assert read_scaffold(tmp_path).num_anchors == scene.num_anchors


def test_write_ply_in_blocks_matches_a_single_copy(tmp_path, monkeypatch):
    from lghcc.formats import ply as ply_mod

    rng = np.random.default_rng(0)
    cols = {"x": rng.normal(size=1000).astype(np.float32), "flag": rng.random(1000) < 0.5,
            "d": rng.normal(size=1000)}  # bool and float64 columns are stored as float32
    monkeypatch.setattr(ply_mod, "WRITE_BLOCK_ROWS", 7)  # 143 blocks, the last one partial
    write_ply(tmp_path / "a.ply", cols, comments=["hello world"])
    raw = (tmp_path / "a.ply").read_bytes()
    body = np.stack([cols["x"], cols["flag"].astype(np.float32), cols["d"].astype(np.float32)], 1).astype("<f4")
    assert raw.endswith(body.tobytes())
    assert raw.startswith(b"ply\nformat binary_little_endian 1.0\ncomment hello world\nelement vertex 1000\n")
    back = read_ply(tmp_path / "a.ply")
    assert np.array_equal(back["x"], cols["x"]) and np.array_equal(back["flag"], cols["flag"].astype(np.float32))
    write_ply(tmp_path / "empty.ply", {"x": np.zeros(0, np.float32)})
    assert len(read_ply(tmp_path / "empty.ply")["x"]) == 0
    with pytest.raises(ValueError, match="rows"):
        write_ply(tmp_path / "b.ply", {"x": np.zeros(3), "y": np.zeros(4)})
    with pytest.raises(ValueError, match="one line"):
        write_ply(tmp_path / "b.ply", {"x": np.zeros(3)}, comments=["two\nlines"])


def test_written_files_get_the_umask_mode(tmp_path):
    import os
    import stat

    old = os.umask(0o002)
    try:
        folder = write_scaffold(make_procedural_scene(20, seed=0, feature_dim=4, num_offsets=2), tmp_path)
    finally:
        os.umask(old)
    for f in (folder / "point_cloud.ply", folder / "checkpoint.pth"):
        assert stat.S_IMODE(f.stat().st_mode) == 0o664
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]  # no temporary files left


def _anchor_grid(seed: int, voxel: float, extent: float) -> np.ndarray:
    """A voxelized surface patch near the origin and anchors scattered to +-extent metres."""
    rng = np.random.default_rng(seed)
    kmax = int(extent / voxel)
    patch = np.unique(rng.integers(-5, 6, size=(150, 3)), axis=0)
    return np.vstack([patch, rng.integers(-kmax, kmax + 1, size=(100, 3)), [[kmax, -kmax, kmax]]])


@pytest.mark.filterwarnings("ignore:`torch.jit.load` is deprecated:DeprecationWarning")
def test_a_model_in_scaffold_gs_layout(tmp_path, monkeypatch):
    """cfg_args, point_cloud/iteration_<N>/point_cloud.ply with no lghcc header comments, the MLPs
    as traced modules: the voxel size is cfg_args', every voxel index and MLP comes back."""
    k = _anchor_grid(0, 0.001, 30.0)
    write_scaffold_gs_model(tmp_path / "m", k, 0.001, iteration=7000, cfg_args=False)  # an older iteration
    folder = write_scaffold_gs_model(tmp_path / "m", k, 0.001, iteration=30000, feat_dim=32, n_offsets=10)
    said = []
    scene = read_scaffold(tmp_path / "m", log=said.append)
    assert said == [f"{folder / 'point_cloud.ply'}: voxel size 0.001 from {tmp_path / 'm' / 'cfg_args'}"]
    assert scene.voxel_size == 0.001 and np.array_equal(scene.coords, k)
    assert np.array_equal(scene.positions(), scaffold_gs_positions(k, 0.001))  # the very float32 positions
    assert (scene.feature_dim, scene.num_offsets) == (32, 10)
    traced = torch.jit.load(str(folder / "color_mlp.pt")).state_dict()
    assert np.array_equal(scene.mlps["color"].weights[1], traced["2.weight"].numpy())
    assert scene.mlps["color"].activations == ["relu", "sigmoid"] and scene.mlps["cov"].activations[-1] == "none"
    monkeypatch.chdir(folder.parent)  # a relative path from inside the model folder finds its cfg_args too
    said.clear()
    read_scaffold(folder.name, log=said.append)
    assert said == [f"{folder.name}/point_cloud.ply: voxel size 0.001 from {tmp_path / 'm' / 'cfg_args'}"]
    # the 'unite' mode: checkpoints.pth beside the PLY
    unite = write_scaffold_gs_model(tmp_path / "u", k, 0.001, mlps="unite")
    assert set(read_scaffold(unite / "point_cloud.ply").mlps) == {"opacity", "cov", "color"}


@pytest.mark.parametrize("voxel", [0.0005, 0.001, 0.004, 0.05])
@pytest.mark.parametrize("stated", [True, False])
def test_scaffold_gs_grids_to_200_m_with_and_without_cfg_args(tmp_path, voxel, stated):
    k = _anchor_grid(1, voxel, 200.0)
    write_scaffold_gs_model(tmp_path, k, voxel, cfg_args=stated, mlps="unite")
    said = []
    scene = read_scaffold(tmp_path, log=said.append)
    assert np.array_equal(scene.coords, k)
    assert np.float32(scene.voxel_size) == np.float32(voxel)
    assert ("from " if stated else "inferred from the anchor grid") in said[0]


def test_cfg_args_is_parsed_never_evaluated(tmp_path):
    cfg = tmp_path / "cfg_args"
    cfg.write_text("Namespace(voxel_size=0.004, source_path='a, b (c)=d', lod=[1, 2], eval=True, "
                   "device=torch.device('cuda'), hook=__import__('os').system('touch " + str(tmp_path / "x") + "'))")
    assert read_cfg_args(cfg) == {"voxel_size": 0.004, "source_path": "a, b (c)=d", "lod": [1, 2], "eval": True}
    assert not (tmp_path / "x").exists()
    for text, message in (("voxel_size=0.001", "unreadable"), ("Namespace(voxel_size=", "unreadable"),
                          ("os.system('ls')", "not a printed argparse Namespace"), ("[1, 2]", "not a printed")):
        cfg.write_text(text)
        with pytest.raises(InputError, match=f"^{re.escape(str(cfg))}: {message}"):
            read_cfg_args(cfg)


def test_what_cfg_args_cannot_say_is_inferred_and_what_it_says_is_checked(tmp_path):
    k = _anchor_grid(2, 0.004, 20.0)
    folder = write_scaffold_gs_model(tmp_path, k, 0.004, mlps="unite")
    cfg = tmp_path / "cfg_args"
    text = cfg.read_text()
    for stated, note in (("0.0", "states no positive voxel_size (voxel_size=0.0)"),  # Scaffold-GS: chosen from the points
                         ("'auto'", "states no positive voxel_size (voxel_size='auto')")):
        cfg.write_text(text.replace("voxel_size=0.004", f"voxel_size={stated}"))
        said = []
        assert np.array_equal(read_scaffold(tmp_path, log=said.append).coords, k)
        assert said[0].endswith(f"voxel size 0.004 inferred from the anchor grid ({cfg} {note})")
    cfg.write_text("Namespace(voxel_size=0.004")
    said = []
    assert np.array_equal(read_scaffold(tmp_path, log=said.append).coords, k)
    assert f"inferred from the anchor grid ({cfg}: unreadable" in said[0]
    # a stated voxel size that the anchors are not on is an error naming both files
    cfg.write_text(text.replace("voxel_size=0.004", "voxel_size=0.003"))
    with pytest.raises(InputError, match=f"^{re.escape(str(cfg))}: voxel_size=0.003, but the anchor positions of "
                                         f"{re.escape(str(folder / 'point_cloud.ply'))} are not on a grid"):
        read_scaffold(tmp_path)
    # --voxel-size and lghcc's own header comment come first
    said = []
    assert read_scaffold(tmp_path, voxel_size=0.004, log=said.append).voxel_size == 0.004
    assert said[0].endswith("voxel size 0.004 as given (--voxel-size)")
    scene = read_scaffold(tmp_path, voxel_size=0.004)
    write_scaffold(scene, tmp_path, iteration=30000)
    said = []
    assert read_scaffold(tmp_path, log=said.append).voxel_size == float(np.float32(0.004))
    assert said[0].endswith("voxel size 0.004 from lghcc's header comment in the PLY")
