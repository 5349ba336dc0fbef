"""Dataset layouts found by their files (render/datasets.py): NeRF-synthetic, COLMAP (bin and
txt), Mip-NeRF 360 (sparse/0 + images_N), LLFF (poses_bounds.npy, with or without its
sparse/0), on tiny fixtures made here: a procedural anchor scene rendered by our renderer from
known cameras, the models written by the project's own COLMAP writers. The strongest check:
the scene rendered from the cameras each layout gives back matches the images it was
rendered into (so intrinsics, axes and image matching are right)."""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import lghcc
from lghcc.common.errors import InputError
from lghcc.render.camera import Camera, ColmapCamera, ColmapImage, write_colmap_binary, write_colmap_text
from lghcc.render.datasets import detect_dataset, load_dataset, match_images
from lghcc.render.export import rotmat_to_quat
from lghcc.render.imageio import write_png

W, H = 40, 30  # not square: a swapped width/height shows
N_VIEWS = 10  # views 0 and 8 are the test views of the COLMAP/LLFF layouts
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def teacher():
    from lghcc.formats.procedural import make_procedural_scene

    return make_procedural_scene(200, seed=5)


def _cameras(scene, w=W, h=H, centred=False) -> list[Camera]:
    pts = scene.positions().astype(np.float64)
    c = (pts.min(0) + pts.max(0)) / 2
    r = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    cams = []
    for i in range(N_VIEWS):
        a = 2 * math.pi * i / N_VIEWS
        eye = c + r * np.array([math.cos(a), math.sin(a), 0.4 + 0.1 * (i % 3)])
        cam = Camera.look_at(eye, c, width=w, height=h, fov_x_deg=55.0, name=f"frame_{i:03d}.png", near=0.01)
        if not centred:  # a principal point off the centre, as real COLMAP cameras have
            cam = Camera(cam.world_to_camera, cam.fx, cam.fx * 1.02, w / 2 + 1.5, h / 2 - 1.0, w, h, near=0.01,
                         name=cam.name)
        cams.append(cam)
    return cams


_RENDERS: dict = {}  # the CPU renderer takes ~0.5 s a view here: each view is rendered once


def _render(scene, cam) -> np.ndarray:
    from lghcc.render.rasterizer import render_scene

    key = (id(scene), cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.world_to_camera.tobytes())
    if key not in _RENDERS:
        with torch.no_grad():
            _RENDERS[key] = render_scene(scene, cam, background=torch.zeros(3)).image.clamp(0, 1).numpy()
    return _RENDERS[key]


def _write_images(folder: Path, scene, cams, names=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i, cam in enumerate(cams):
        write_png(folder / (names[i] if names else cam.name), _render(scene, cam))


def _colmap_model(cams, scene):
    c0 = cams[0]
    ccam = ColmapCamera(1, "PINHOLE", c0.width, c0.height, np.array([c0.fx, c0.fy, c0.cx, c0.cy]))
    images = [ColmapImage(i + 1, rotmat_to_quat(c.rotation[None])[0], c.translation.copy(), 1, c.name)
              for i, c in enumerate(cams)]
    pts = scene.positions().astype(np.float64)[::4]
    return [ccam], images, pts


def make_colmap(root: Path, scene, binary: bool = True, scales=(), rename_scaled=False, poses_bounds=False):
    """images/ at W x H, images_N/ at W/N x H/N (cameras scaled), sparse/0 in bin or txt."""
    cams = _cameras(scene)
    cc, ims, pts = _colmap_model(cams, scene)
    (write_colmap_binary if binary else write_colmap_text)(root / "sparse" / "0", cc, ims, pts,
                                                          np.full((len(pts), 3), 128, np.uint8))
    _write_images(root / "images", scene, cams)
    for n in scales:
        small = [c.scaled(1.0 / n) for c in cams]
        names = [f"image{i:03d}.png" for i in range(len(cams))] if rename_scaled else None
        _write_images(root / f"images_{n}", scene, small, names)
    if poses_bounds:
        _write_poses_bounds(root, cams)
    return cams, pts


def _write_poses_bounds(root: Path, cams) -> None:
    rows = []
    for cam in cams:
        c2w = cam.camera_to_world
        pose = np.concatenate([np.stack([c2w[:3, 1], c2w[:3, 0], -c2w[:3, 2], c2w[:3, 3]], 1),
                               [[cam.height], [cam.width], [cam.fx]]], 1)
        rows.append(np.concatenate([pose.reshape(-1), [0.5, 20.0]]))
    np.save(root / "poses_bounds.npy", np.array(rows))


def _assert_same_cameras(got, want, scale=1.0):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        ws = w.scaled(scale) if scale != 1.0 else w
        assert (g.width, g.height) == (ws.width, ws.height), (g.name, w.name)
        np.testing.assert_allclose([g.fx, g.fy, g.cx, g.cy], [ws.fx, ws.fy, ws.cx, ws.cy], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(g.world_to_camera, w.world_to_camera, atol=1e-9)


def _self_psnr(scene, cams) -> float:
    """The scene against the images the cameras carry, rendered from those cameras."""
    return lghcc.evaluate(scene, None, cams).psnr


@pytest.mark.parametrize("binary", (True, False), ids=("bin", "txt"))
def test_colmap_bin_and_txt(tmp_path, teacher, binary):
    cams, pts = make_colmap(tmp_path, teacher, binary=binary)
    lay = detect_dataset(tmp_path)
    assert lay.kind == "colmap" and lay.sparse == tmp_path / "sparse" / "0" and lay.images == "images"
    ds = load_dataset(tmp_path, background="black")
    assert [c.name for c in ds.test] == [cams[0].name, cams[8].name] and len(ds.train) == 8
    _assert_same_cameras(ds.train + ds.test, [c for i, c in enumerate(cams) if i % 8] + cams[::8])
    np.testing.assert_allclose(ds.sfm_points, pts)
    assert _self_psnr(teacher, ds.test) > 50  # exactly the scene seen from these cameras (PNG rounding: ~59 dB)
    # the bare sparse folder: every view (lghcc-dec --render sparse/0)
    _assert_same_cameras(lghcc.load_cameras(tmp_path / "sparse" / "0"), cams)


def test_mipnerf360_layout_reads_images_n(tmp_path, teacher):
    """sparse/0 + images_2 + images_4 (the same names), and the poses_bounds.npy Mip-NeRF 360
    also ships (not needed: the sparse model wins, it was read first only for LLFF before)."""
    cams, pts = make_colmap(tmp_path, teacher, scales=(2, 4), poses_bounds=True)
    lay = detect_dataset(tmp_path, downscale=2)
    assert lay.kind == "colmap" and lay.images == "images_2" and lay.images_factor == 2
    assert "images_2, images_4" in lay.description
    ds = load_dataset(tmp_path, background="black", downscale=2)
    assert ds.train[0].image.shape == (H // 2, W // 2, 3)
    _assert_same_cameras(ds.test, cams[::8], scale=0.5)
    assert _self_psnr(teacher, ds.test) > 40  # the images_2 files themselves, not a resampling
    assert ds.sfm_points is not None and len(ds.sfm_points) == len(pts)
    # without images_N for the factor: images/ averaged down
    ds3 = load_dataset(tmp_path, background="black", downscale=3)
    assert ds3.layout.images == "images" and ds3.train[0].image.shape == (10, round(W / 3), 3)


def test_llff_with_sparse_uses_the_colmap_cameras_and_renamed_downscales(tmp_path, teacher):
    """An LLFF scene that kept sparse/0: its cameras (the same world frame as poses_bounds.npy),
    points for --init sfm, and images_2 renamed image000.png... matched in sorted order."""
    cams, _ = make_colmap(tmp_path, teacher, scales=(2,), rename_scaled=True, poses_bounds=True)
    ds = load_dataset(tmp_path, background="black", downscale=2)
    assert ds.kind == "colmap" and ds.sfm_points is not None
    assert _self_psnr(teacher, ds.test) > 40
    # LLFF's own poses (centred principal points) agree with the COLMAP ones in the world frame
    (tmp_path / "sparse" / "0" / "cameras.bin").rename(tmp_path / "cameras.bak")
    llff = load_dataset(tmp_path, background="black", downscale=2)
    assert llff.kind == "llff" and llff.sfm_points is None
    for a, b in zip(llff.test, ds.test):
        np.testing.assert_allclose(a.world_to_camera, b.world_to_camera, atol=1e-9)


def test_llff_cameras_for_rendering(tmp_path, teacher):
    cams = _cameras(teacher, centred=True)
    _write_images(tmp_path / "images", teacher, cams)
    _write_poses_bounds(tmp_path, cams)
    assert detect_dataset(tmp_path).kind == "llff"
    ds = load_dataset(tmp_path, background="black")
    assert _self_psnr(teacher, ds.test) > 50
    # the folder and the file itself are camera specs (lghcc-dec --render used to refuse LLFF)
    _assert_same_cameras(lghcc.load_cameras(tmp_path), cams[::8])
    _assert_same_cameras(lghcc.load_cameras(tmp_path / "poses_bounds.npy"), cams)


def test_nerf_synthetic_folder(tmp_path, teacher):
    cams = _cameras(teacher, centred=True)
    for split, sub in (("train", cams[:7]), ("test", cams[7:])):
        frames = [{"file_path": f"./{split}/{c.name[:-4]}", "transform_matrix": (c.camera_to_world @ GL_TO_CV).tolist()}
                  for c in sub]
        (tmp_path / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": cams[0].fov_x,
                                                                       "frames": frames}))
        _write_images(tmp_path / split, teacher, sub)
    assert detect_dataset(tmp_path).kind == "nerf_synthetic"
    ds = load_dataset(tmp_path, background="black")
    assert len(ds.test) == 3 and _self_psnr(teacher, ds.test) > 50
    _assert_same_cameras(lghcc.load_cameras(tmp_path), cams[7:])
    _assert_same_cameras(lghcc.load_cameras(tmp_path, split="train"), cams[:7])


def test_unknown_layouts_and_unmatched_images_are_named(tmp_path, teacher):
    with pytest.raises(InputError, match=r"transforms_train.json .* sparse/0 .* poses_bounds.npy"):
        detect_dataset(tmp_path)
    make_colmap(tmp_path, teacher)
    (tmp_path / "images" / "frame_003.png").unlink()
    with pytest.raises(InputError, match=r"images: 1 of the model's 10 images not found \(first: frame_003.png\)"):
        load_dataset(tmp_path)
    # a stem match: JPEG copies of PNG names
    folder = tmp_path / "jpg"
    folder.mkdir()
    (folder / "frame_001.jpg").write_bytes(b"")
    assert match_images(["frame_001.png"], folder) == {"frame_001.png": folder / "frame_001.jpg"}


def test_decoder_renders_and_evaluates_a_dataset_folder(tmp_path, teacher, capsys):
    """lghcc-dec --render <COLMAP dataset>: its test views, named after its images."""
    from lghcc.decoder import cli as dec

    make_colmap(tmp_path / "data", teacher, binary=False)
    stream = tmp_path / "s.lghcc"
    stream.write_bytes(lghcc.encode(teacher, preset="high"))
    assert dec.main([str(stream), "--render", str(tmp_path / "data"), "--render-out", str(tmp_path / "v"), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["000_frame_000.png", "001_frame_008.png"]
    ev = lghcc.evaluate(lghcc.decode(stream), None, str(tmp_path / "data"), background="black")
    assert ev.views == 2 and ev.psnr > 35


def test_train_init_sfm_on_a_mipnerf360_folder(tmp_path, teacher, capsys):
    """lghcc-train on sparse/0 + images_2 with --downscale 2 --init sfm: the anchors start from
    the model's points3D (it failed on an LLFF folder that had sparse/0/points3D.bin)."""
    from lghcc.encoder import train as train_cli
    from lghcc.encoder.training.config import TrainConfig
    from lghcc.encoder.training.data import init_points
    from lghcc.render.datasets import load_dataset

    _, pts = make_colmap(tmp_path / "data", teacher, scales=(2,), poses_bounds=True)
    argv = [str(tmp_path / "data"), "-o", str(tmp_path / "run"), "--iterations", "3", "--downscale", "2",
            "--init", "sfm", "--feature-dim", "4", "--num-offsets", "2", "--eval-interval", "3", "--threads", "1",
            "-q"]
    assert train_cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "finished at iteration 3" in out
    cfg = TrainConfig(data=str(tmp_path / "data"), downscale=2, init="sfm")
    ds = load_dataset(cfg.data, "white", 2)
    np.testing.assert_allclose(init_points(ds, cfg, np.random.default_rng(0)), pts)
    # a dataset without points3D: --init sfm says so
    shutil.rmtree(tmp_path / "data" / "sparse")
    ds = load_dataset(cfg.data, "white", 2)
    with pytest.raises(InputError, match=r"--init sfm\b.*points3D"):
        init_points(ds, cfg, np.random.default_rng(0))


@pytest.mark.data
def test_garden_cameras_and_points_as_a_colmap_model(tmp_path, shared_data):
    """The shared garden data (Mip-NeRF 360's SfM points and 3 cameras) written as a COLMAP
    text model: read back exactly, rendered from, and usable as SfM points."""
    npz = shared_data / "garden" / "test_garden.npz"
    if not npz.is_file():
        pytest.skip(f"{npz} not found")
    g = np.load(npz)
    w, h = int(g["width"]), int(g["height"])
    cams = [ColmapCamera(i + 1, "PINHOLE", w, h, np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]))
            for i, K in enumerate(g["Ks"])]
    ims = [ColmapImage(i + 1, rotmat_to_quat(v[None, :3, :3])[0], v[:3, 3].astype(np.float64), i + 1, f"{i:05d}.JPG")
           for i, v in enumerate(g["viewmats"])]
    pts = g["means3d"].astype(np.float64)[::50]
    write_colmap_text(tmp_path / "sparse" / "0", cams, ims, pts, g["colors"][::50])
    got = lghcc.load_cameras(tmp_path / "sparse" / "0")
    for cam, v, K in zip(got, g["viewmats"], g["Ks"]):
        np.testing.assert_allclose(cam.world_to_camera, v, atol=1e-5)
        np.testing.assert_allclose(cam.K, K, rtol=1e-6)
    ds = load_dataset(tmp_path, load_images=False)
    assert ds.kind == "colmap" and len(ds.sfm_points) == len(pts)
    # a Gaussian per point, rendered from the garden cameras: the points land in the images
    from lghcc.common.scene import GaussianScene

    n = len(pts)
    scene = GaussianScene(pts.astype(np.float32), np.full((n, 1, 3), 1.0, np.float32), np.full(n, 3.0, np.float32),
                          np.full((n, 3), -4.0, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)))
    imgs = lghcc.render_views(scene, [c.scaled(0.25) for c in got])
    assert all(img.mean() > 0.01 for img in imgs)
