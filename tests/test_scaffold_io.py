"""The Scaffold-GS checkpoint layout: write, read, variants, errors."""

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.common.ply import read_ply, write_ply
from lghcc.common.procedural import make_procedural_scene
from lghcc.common.scaffold_io import infer_voxel_size, read_scaffold, write_scaffold


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
    assert infer_voxel_size(coords * 0.013) == pytest.approx(0.013, rel=1e-9)
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
