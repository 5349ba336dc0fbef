"""Anchor scene -> plain 3DGS PLY export, and lghcc-dec's --render / --export-ply."""

import json

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.formats.procedural import make_procedural_scene
from lghcc.decoder import cli as dec_cli
from lghcc.encoder import cli as enc_cli
from lghcc.render.camera import Camera, ColmapCamera, ColmapImage, write_colmap_text
from lghcc.render.export import default_distance, export_3dgs, rotmat_to_quat
from lghcc.render.gaussians3dgs import load_3dgs_ply, render_3dgs
from lghcc.render.imageio import read_image, write_png
from lghcc.render.metrics import psnr
from lghcc.render.neural_gaussians import evaluate_anchors, generate_neural_gaussians
from lghcc.render.rasterizer import quat_to_rotmat, render_scene

ROUND_TRIP_PSNR_DB = 28.0  # measured 33-37 dB on this scene (SH degree 1, 16 directions)


def _views(scene, n=2, size=48):
    d, c = default_distance(scene), scene.positions().mean(0)
    out = []
    for e in [(1, 0, 0.5), (0, -1, 0.8), (-1, 0.3, 0.2)][:n]:
        e = np.array(e, float) / np.linalg.norm(e)
        out.append(Camera.look_at(c + e * d, c, width=size, height=size, fov_x_deg=50))
    return out


def test_evaluate_anchors_matches_generate_neural_gaussians():
    scene = make_procedural_scene(200, seed=2)
    cam = _views(scene, 1)[0]
    ng = generate_neural_gaussians(scene, cam, cull=False)
    n = scene.num_anchors
    p = torch.as_tensor(scene.positions())
    d = p - torch.as_tensor(cam.center, dtype=torch.float32)
    dist = torch.linalg.vector_norm(d, dim=1, keepdim=True)
    op, cov, col = evaluate_anchors(scene, torch.arange(n), d / dist, dist)
    assert torch.equal(op[ng.anchor_index, ng.offset_index], ng.opacities)
    torch.testing.assert_close(col[ng.anchor_index, ng.offset_index], ng.colors)
    assert int((op > 0).sum()) == ng.num_gaussians


def test_rotmat_to_quat_inverts_quat_to_rotmat():
    q = torch.nn.functional.normalize(torch.randn(50, 4, dtype=torch.float64), dim=1)
    back = rotmat_to_quat(quat_to_rotmat(q).numpy())
    np.testing.assert_allclose(np.abs((back * q.numpy()).sum(1)), 1.0, atol=1e-9)


def test_export_round_trip_renders_like_the_anchor_scene(tmp_path):
    scene = make_procedural_scene(300, seed=1)
    ex = export_3dgs(scene, tmp_path / "e.ply", sh_degree=1)
    g = load_3dgs_ply(tmp_path / "e.ply")
    assert g.sh_degree == 1 and g.num_gaussians == ex.num_gaussians > 0
    for cam in _views(scene):
        ref = render_scene(scene, cam).image.numpy()
        got = render_3dgs(g, cam).image.numpy()
        assert psnr(ref, got) > ROUND_TRIP_PSNR_DB


def test_export_skips_dead_and_never_visible_gaussians():
    scene = make_procedural_scene(100, seed=3)
    full = export_3dgs(scene, sh_degree=0, num_directions=8).num_gaussians
    scene.offset_mask = np.ones((scene.num_anchors, scene.num_offsets), bool)
    scene.offset_mask[:, 0] = False
    fewer = export_3dgs(scene, sh_degree=0, num_directions=8).num_gaussians
    assert fewer < full
    scene.mlps["opacity"].biases[-1][:] = -1e4  # tanh -> -1 everywhere
    with pytest.raises(InputError, match="nothing to export"):
        export_3dgs(scene)
    with pytest.raises(InputError, match="directions"):
        export_3dgs(scene, sh_degree=3, num_directions=9)


def test_decoder_cli_render_and_export(tmp_path, capsys):
    s = tmp_path / "p.lghcc"
    assert enc_cli.main(["--procedural", "300", "-o", str(s), "-q"]) == 0
    out = tmp_path / "views"
    assert dec_cli.main([str(s), "--render", "orbit:2", "--render-out", str(out), "--render-size", "40x32",
                         "--export-ply", str(tmp_path / "x.ply"), "--export-sh-degree", "2"]) == 0
    text = capsys.readouterr().out
    assert "rendered 2 views" in text and "3DGS PLY" in text
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) == 2 and read_image(pngs[0]).shape == (32, 40, 3)
    assert read_image(pngs[0]).max() > 0.05  # the scene is in view
    assert load_3dgs_ply(tmp_path / "x.ply").sh_degree == 2
    # COLMAP sparse folder and NeRF-synthetic transforms JSON
    sp = tmp_path / "sparse"
    write_colmap_text(sp, [ColmapCamera(1, "PINHOLE", 30, 20, np.array([25.0, 25.0, 15.0, 10.0]))],
                      [ColmapImage(1, np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, 3.0]), 1, "a.png")])
    assert dec_cli.main([str(s), "--render", str(sp), "--render-out", str(tmp_path / "c"), "-q"]) == 0
    assert read_image(tmp_path / "c" / "000_a.png").shape == (20, 30, 3)
    nd = tmp_path / "nerf"
    (nd / "test").mkdir(parents=True)
    write_png(nd / "test" / "r_0.png", np.zeros((16, 16, 4), np.float32))
    c2w = np.eye(4)
    c2w[2, 3] = 3.0
    (nd / "transforms_test.json").write_text(json.dumps(
        {"camera_angle_x": 0.8, "frames": [{"file_path": "./test/r_0", "transform_matrix": c2w.tolist()}]}))
    assert dec_cli.main([str(s), "--render", str(nd / "transforms_test.json"), "--render-out",
                         str(tmp_path / "n"), "-q"]) == 0
    assert len(list((tmp_path / "n").glob("*.png"))) == 1
    # errors: no output folder, bad spec
    assert dec_cli.main([str(s), "--render", "orbit:2", "-q"]) == 1
    assert "--render-out" in capsys.readouterr().err
    assert dec_cli.main([str(s), "--render", "nowhere:3", "--render-out", str(out), "-q"]) == 1


def test_compare_tool_writes_table_and_side_by_side(tmp_path):
    import importlib.util
    from pathlib import Path

    from lghcc.formats.scaffold_io import write_scaffold

    spec = importlib.util.spec_from_file_location("compare", Path(__file__).parents[1] / "tools" / "compare.py")
    compare = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(compare)
    write_scaffold(make_procedural_scene(300), tmp_path / "ref")
    s = tmp_path / "p.lghcc"
    assert enc_cli.main(["--procedural", "300", "-o", str(s), "-q"]) == 0
    md, png = tmp_path / "c.md", tmp_path / "c.png"
    assert compare.main([str(tmp_path / "ref"), str(s), "--views", "orbit:1", "--size", "32x24", "--out-md", str(md),
                         "--out-png", str(png), "--no-lpips"]) == 0
    row = [ln for ln in md.read_text().splitlines() if ln.startswith("| p.lghcc")][0]
    assert float(row.split("|")[5]) > 40 and "skipped" in row
    assert read_image(png).shape == (24, 96, 3)
