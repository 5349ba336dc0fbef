"""Cameras, loaders (NeRF-synthetic, LLFF, COLMAP text/binary), PNG I/O, loader errors."""

import json
import math
import struct

import numpy as np
import pytest

from lghcc.common.errors import InputError
from lghcc.render.camera import (Camera, ColmapCamera, ColmapImage, load_colmap, load_llff, load_nerf_synthetic,
                                 qvec_to_rotmat, read_colmap_model, write_colmap_binary, write_colmap_text)
from lghcc.render.imageio import read_image, write_png


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


# --- Camera --------------------------------------------------------------------------------

def test_camera_projects_and_looks_where_told():
    cam = Camera.look_at([0, -4, 0], [0, 0, 0], up=[0, 0, 1], width=101, height=81, fov_x_deg=60)
    np.testing.assert_allclose(cam.center, [0, -4, 0], atol=1e-12)
    np.testing.assert_allclose(cam.forward, [0, 1, 0], atol=1e-12)
    uv, z = cam.project(np.array([[0.0, 0, 0], [0.0, 0, 1.0], [1.0, 0, 0]]))
    np.testing.assert_allclose(uv[0], [50.5, 40.5])
    assert z[0] == pytest.approx(4.0)
    assert uv[1, 1] < 40.5  # world up is image up (y down)
    assert uv[2, 0] > 50.5  # world +x is to the right seen from -y
    assert cam.fov_x == pytest.approx(math.radians(60))
    d, dist = cam.view_directions(np.array([[0.0, 0, 0]]))
    np.testing.assert_allclose(d[0], [0, 1, 0], atol=1e-12)
    assert dist[0] == pytest.approx(4.0)
    big = cam.scaled(2)
    assert (big.width, big.height) == (202, 162) and big.fx == pytest.approx(2 * cam.fx)


def test_camera_rejects_bad_values():
    with pytest.raises(InputError):
        Camera(np.eye(4), -1, 1, 0, 0, 10, 10)
    with pytest.raises(InputError):
        Camera(np.eye(4), 1, 1, 0, 0, 0, 10)
    with pytest.raises(InputError):
        Camera(np.full((4, 4), np.nan), 1, 1, 0, 0, 10, 10)
    with pytest.raises(InputError, match="orthonormal"):
        Camera.from_camera_to_world(np.eye(4) * 2, 1, 1, 0, 0, 10, 10)


# --- PNG -------------------------------------------------------------------------------------

def test_png_write_read_round_trip(tmp_path):
    img = np.random.default_rng(1).random((5, 6, 3)).astype(np.float32)
    write_png(tmp_path / "x.png", img)
    back = read_image(tmp_path / "x.png")
    assert back.shape == (5, 6, 3)
    assert np.abs(back - img).max() <= 0.5 / 255 + 1e-6


def test_image_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_bytes(b"not a png at all")
    with pytest.raises(InputError, match="bad.png"):
        read_image(tmp_path / "bad.png")


# --- NeRF-synthetic ------------------------------------------------------------------------------

def _write_nerf(root, n=3, size=(8, 6), missing=None):
    (root / "test").mkdir(parents=True)
    frames = []
    for i in range(n):
        c2w = np.eye(4)
        c2w[:3, :3] = _rot_y(0.3 * i)
        c2w[:3, 3] = [0.1 * i, 0.2, 4.0]
        frames.append({"file_path": f"./test/r_{i}", "transform_matrix": c2w.tolist()})
        if i != missing:
            img = np.zeros((size[1], size[0], 4), np.float32)
            img[..., 0] = 1.0
            img[..., 3] = np.linspace(0, 1, size[0])[None, :]
            write_png(root / "test" / f"r_{i}.png", img)
    (root / "transforms_test.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": frames}))


def test_nerf_loader_converts_opengl_poses_and_composites(tmp_path):
    _write_nerf(tmp_path)
    white = load_nerf_synthetic(tmp_path, "test", background="white")
    black = load_nerf_synthetic(tmp_path, "test", background="black")
    assert len(white) == 3
    cam = white[0]
    assert (cam.width, cam.height) == (8, 6)
    assert cam.fx == pytest.approx(4 / math.tan(0.4)) and cam.cx == 4 and cam.cy == 3
    # OpenGL camera at (0, 0.2, 4) looking down -z: OpenCV forward is world -z, image down is world -y
    np.testing.assert_allclose(cam.center, [0, 0.2, 4.0], atol=1e-12)
    np.testing.assert_allclose(cam.forward, [0, 0, -1], atol=1e-12)
    uv, z = cam.project(np.array([[0.0, 0.2, 0.0], [0.0, 1.2, 0.0]]))
    np.testing.assert_allclose(uv[0], [4, 3], atol=1e-9)
    assert z[0] == pytest.approx(4.0) and uv[1, 1] < 3
    a = np.linspace(0, 1, 8)[None, :]
    np.testing.assert_allclose(white[0].image[..., 1], np.broadcast_to(1 - a, (6, 8)), atol=1 / 255)
    np.testing.assert_allclose(black[0].image[..., 1], 0, atol=1e-7)
    np.testing.assert_allclose(black[0].image[..., 0], np.broadcast_to(a, (6, 8)), atol=1 / 255)
    no_img = load_nerf_synthetic(tmp_path, "test", load_images=False)
    assert no_img[2].image is None and no_img[2].width == 8


def test_nerf_loader_errors(tmp_path):
    with pytest.raises(InputError, match=r"transforms_test.json\b.*not found"):
        load_nerf_synthetic(tmp_path)
    _write_nerf(tmp_path, missing=1)
    with pytest.raises(InputError, match="r_1"):
        load_nerf_synthetic(tmp_path)
    with pytest.raises(InputError, match="background"):
        load_nerf_synthetic(tmp_path, background="grey", max_frames=1)
    (tmp_path / "transforms_test.json").write_text('{"frames": []}')
    with pytest.raises(InputError, match="camera_angle_x"):
        load_nerf_synthetic(tmp_path)
    (tmp_path / "transforms_test.json").write_text('{"camera_angle_x": 0.5, "frames": [{"file_path": "./test/r_0", '
                                                     '"transform_matrix": [[1, 0], [0, 1]]}]}')
    with pytest.raises(InputError, match="4x4"):
        load_nerf_synthetic(tmp_path)


@pytest.mark.parametrize("field, value, match", [
    ("camera_angle_x", 0, "'camera_angle_x' must be an angle"),
    ("camera_angle_x", "abc", "'camera_angle_x' must be an angle in radians.*'abc'"),
    ("camera_angle_x", None, "'camera_angle_x' must be an angle.*None"),
    ("camera_angle_x", [1], r"'camera_angle_x' must be an angle.*\[1\]"),
    ("camera_angle_x", 4.0, "'camera_angle_x' must be an angle"),
    ("camera_angle_y", -0.5, "'camera_angle_y' must be an angle"),
    ("fl_x", 0, "'fl_x' must be a positive number"),
    ("fl_y", "7", "'fl_y' must be a positive number"),
    ("cx", float("nan"), "'cx' must be a finite number"),
    ("w", 7.5, "'w' must be a positive integer"),
    ("h", True, "'h' must be a positive integer"),
])
@pytest.mark.parametrize("load_images", [True, False])
def test_nerf_loader_rejects_bad_intrinsics_naming_file_and_field(tmp_path, field, value, match, load_images):
    _write_nerf(tmp_path)
    jp = tmp_path / "transforms_test.json"
    meta = json.loads(jp.read_text())
    meta.update({"w": 8, "h": 6} if field in ("w", "h") else {})
    meta[field] = value
    jp.write_text(json.dumps(meta))
    with pytest.raises(InputError, match="transforms_test.json: " + match):
        load_nerf_synthetic(tmp_path, load_images=load_images)


@pytest.mark.parametrize("load_images", [True, False])
def test_nerf_loader_rejects_bad_frames_naming_file_and_field(tmp_path, load_images):
    _write_nerf(tmp_path)
    jp = tmp_path / "transforms_test.json"
    meta = json.loads(jp.read_text())
    for bad in (17, None, "", ["./test/r_0"]):
        meta["frames"][1]["file_path"] = bad
        jp.write_text(json.dumps(meta))
        with pytest.raises(InputError, match=r"transforms_test.json\b.*frame 1\b.*'file_path'"):
            load_nerf_synthetic(tmp_path, load_images=load_images)
    meta["frames"][1]["file_path"] = "./test/r_1"
    meta["frames"][1]["transform_matrix"] = "abc"
    jp.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"transforms_test.json\b.*frame 1\b.*transform_matrix"):
        load_nerf_synthetic(tmp_path, load_images=load_images)
    meta["frames"][1]["transform_matrix"] = [[1, 0, 0, "x"]] * 4
    jp.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"transforms_test.json\b.*frame 1\b.*transform_matrix"):
        load_nerf_synthetic(tmp_path, load_images=load_images)


@pytest.mark.parametrize("load_images", [True, False])
def test_nerf_loader_scales_intrinsics_given_for_another_size(tmp_path, load_images):
    """w/h = 16x12 with fl_x for 16 px, but 8x6 images: fx, fy, cx, cy are halved. Training
    (load_images) and rendering views (header only) build the same cameras."""
    _write_nerf(tmp_path)
    jp = tmp_path / "transforms_test.json"
    meta = json.loads(jp.read_text())
    del meta["camera_angle_x"]
    meta.update({"w": 16, "h": 12, "fl_x": 20.0, "fl_y": 22.0, "cx": 8.5, "cy": 6.5})
    jp.write_text(json.dumps(meta))
    cams = load_nerf_synthetic(tmp_path, load_images=load_images)
    c = cams[0]
    assert (c.width, c.height) == (8, 6)
    assert (c.fx, c.fy, c.cx, c.cy) == pytest.approx((10.0, 11.0, 4.25, 3.25))
    # angle-based: the focal length follows the image width; cx in pixels of w is scaled
    del meta["fl_x"], meta["fl_y"]
    meta["camera_angle_x"] = 0.8
    jp.write_text(json.dumps(meta))
    c = load_nerf_synthetic(tmp_path, load_images=load_images)[0]
    assert c.fx == pytest.approx(4 / math.tan(0.4)) and c.cx == pytest.approx(4.25)
    # another aspect ratio: a clear error naming the image
    meta.update({"w": 16, "h": 16})
    jp.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"transforms_test.json\b.*frame 0\b.*r_0.png\b.*8x6.*w=16, h=16"):
        load_nerf_synthetic(tmp_path, load_images=load_images)
    # without w/h, a principal point outside the image means intrinsics for another size
    del meta["w"], meta["h"]
    meta.update({"fl_x": 20.0, "cx": 8.5, "cy": 6.5})
    jp.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"\(8.5, 6.5\).*8x6.*r_0.png"):
        load_nerf_synthetic(tmp_path, load_images=load_images)


def test_render_views_and_training_cameras_agree(tmp_path):
    """lghcc-dec --render / tools/compare.py views (cameras_from_spec) are the cameras the
    trainer uses, also when the file's w/h and fl_x are for larger images."""
    from lghcc.render.views import cameras_from_spec

    _write_nerf(tmp_path)
    jp = tmp_path / "transforms_test.json"
    meta = json.loads(jp.read_text())
    meta.update({"w": 800, "h": 600, "fl_x": 900.0})
    del meta["camera_angle_x"]
    jp.write_text(json.dumps(meta))
    train = load_nerf_synthetic(tmp_path, "test", load_images=True)
    for views in (cameras_from_spec(str(jp), np.zeros((1, 3))), cameras_from_spec(str(tmp_path), np.zeros((1, 3)))):
        assert len(views) == len(train)
        for v, t in zip(views, train):
            assert (v.width, v.height, v.fx, v.fy, v.cx, v.cy) == (t.width, t.height, t.fx, t.fy, t.cx, t.cy) \
                == (8, 6, 9.0, 9.0, 4.0, 3.0)
            np.testing.assert_array_equal(v.world_to_camera, t.world_to_camera)


@pytest.mark.data
def test_lego_loader(shared_data):
    root = shared_data / "lego" / "lego_100"
    if not (root / "transforms_test.json").is_file():
        pytest.skip(f"lego not found at {root}")
    cams = load_nerf_synthetic(root, "test", background="white", max_frames=4)
    assert len(cams) == 4
    for c in cams:
        assert c.image.shape == (100, 100, 3) and c.image.dtype == np.float32
        assert 0 <= c.image.min() and c.image.max() <= 1
        assert c.image[0, 0].tolist() == [1.0, 1.0, 1.0]  # corner: white background
        assert np.linalg.norm(c.center) == pytest.approx(4.03, abs=0.05)  # NeRF-synthetic orbit radius
        _, z = c.project(np.zeros((1, 3)))  # the object at the origin is in front of every camera
        assert z[0] > 3.5
    assert cams[0].fx == pytest.approx(50 / math.tan(0.6911112070083618 / 2))
    all_test = load_nerf_synthetic(root, "test", load_images=False)
    assert len(all_test) == 200


@pytest.mark.data
def test_lego_with_intrinsics_for_800px(shared_data, tmp_path):
    """lego_100's images with a camera file written for the 800x800 originals (w, h, fl_x):
    the intrinsics are scaled to the 100 px images, the same cameras as camera_angle_x gives."""
    root = shared_data / "lego" / "lego_100"
    if not (root / "transforms_test.json").is_file():
        pytest.skip(f"lego not found at {root}")
    meta = json.loads((root / "transforms_test.json").read_text())
    ref = load_nerf_synthetic(root, "test", max_frames=3)
    f800 = 400 / math.tan(meta["camera_angle_x"] / 2)
    meta.update({"w": 800, "h": 800, "fl_x": f800, "fl_y": f800, "cx": 400.0, "cy": 400.0})
    del meta["camera_angle_x"]
    (tmp_path / "test").symlink_to(root / "test")
    (tmp_path / "transforms_test.json").write_text(json.dumps(meta))
    for load_images in (True, False):
        cams = load_nerf_synthetic(tmp_path, "test", max_frames=3, load_images=load_images)
        for c, r in zip(cams, ref):
            assert (c.width, c.height) == (100, 100)
            assert (c.fx, c.fy, c.cx, c.cy) == pytest.approx((r.fx, r.fy, 50.0, 50.0), rel=1e-12)


# --- COLMAP ---------------------------------------------------------------------------------

def _colmap_fixture():
    cams = [ColmapCamera(1, "PINHOLE", 64, 48, np.array([50.0, 52.0, 32.0, 24.0])),
            ColmapCamera(2, "SIMPLE_RADIAL", 32, 24, np.array([30.0, 16.0, 12.0, 0.01])),
            ColmapCamera(3, "SIMPLE_PINHOLE", 20, 10, np.array([15.0, 10.0, 5.0]))]
    q = np.array([0.9, 0.1, -0.2, 0.3])
    q /= np.linalg.norm(q)
    imgs = [ColmapImage(1, q, np.array([0.1, 0.2, 3.0]), 1, "b.png"),
            ColmapImage(7, np.array([1.0, 0, 0, 0]), np.array([0.0, 0, 2.0]), 2, "a.png"),
            ColmapImage(3, np.array([0.0, 1.0, 0, 0]), np.array([0.0, 0, 5.0]), 3, "c.png")]
    xyz = np.random.default_rng(0).normal(size=(5, 3))
    rgb = np.random.default_rng(1).integers(0, 256, size=(5, 3)).astype(np.uint8)
    return cams, imgs, xyz, rgb


@pytest.mark.parametrize("writer", [write_colmap_text, write_colmap_binary])
def test_colmap_loader(tmp_path, writer):
    cams, imgs, xyz, rgb = _colmap_fixture()
    writer(tmp_path, cams, imgs, xyz, rgb)
    out, model = load_colmap(tmp_path)
    assert [c.name for c in out] == ["a.png", "b.png", "c.png"]
    b = out[1]
    assert (b.fx, b.fy, b.cx, b.cy, b.width, b.height) == (50.0, 52.0, 32.0, 24.0, 64, 48)
    np.testing.assert_allclose(b.rotation, qvec_to_rotmat(imgs[0].qvec), atol=1e-12)
    np.testing.assert_allclose(b.translation, [0.1, 0.2, 3.0])
    assert out[0].fx == out[0].fy == 30.0 and out[0].distortion == (0.01,)
    assert out[2].fx == out[2].fy == 15.0 and out[2].cx == 10.0
    np.testing.assert_allclose(model.points_xyz, xyz)
    np.testing.assert_array_equal(model.points_rgb, rgb)
    np.testing.assert_allclose(qvec_to_rotmat(imgs[0].qvec) @ qvec_to_rotmat(imgs[0].qvec).T, np.eye(3), atol=1e-12)


def test_colmap_text_and_binary_agree(tmp_path):
    cams, imgs, xyz, rgb = _colmap_fixture()
    write_colmap_text(tmp_path / "t", cams, imgs, xyz, rgb)
    write_colmap_binary(tmp_path / "b", cams, imgs, xyz, rgb)
    a, _ = load_colmap(tmp_path / "t")
    b, _ = load_colmap(tmp_path / "b")
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.world_to_camera, y.world_to_camera)
        assert (x.fx, x.fy, x.cx, x.cy, x.width, x.height, x.name) == (y.fx, y.fy, y.cx, y.cy, y.width, y.height, y.name)


def test_colmap_text_with_points2d_lines(tmp_path):
    (tmp_path / "cameras.txt").write_text("# c\n1 PINHOLE 10 8 9 9 5 4\n")
    (tmp_path / "images.txt").write_text(
        "# Image list with two lines of data per image:\n"
        "1 1 0 0 0 0 0 1 1 one.png\n2.5 3.0 -1 4.0 5.0 12\n"
        "2 1 0 0 0 0 0 2 1 two.png\n\n")
    (tmp_path / "points3D.txt").write_text("1 0.5 0.5 0.5 10 20 30 0.1 1 0 2 0\n")
    cams, model = load_colmap(tmp_path)
    assert [c.name for c in cams] == ["one.png", "two.png"]
    assert model.points_xyz.shape == (1, 3) and model.points_rgb.tolist() == [[10, 20, 30]]


def test_colmap_loads_images(tmp_path):
    cams, imgs, _, _ = _colmap_fixture()
    write_colmap_text(tmp_path / "sparse", cams[:1], imgs[:1])
    (tmp_path / "images").mkdir()
    write_png(tmp_path / "images" / "b.png", np.full((24, 32, 3), 0.5, np.float32))  # half size
    out, _ = load_colmap(tmp_path / "sparse", tmp_path / "images", load_images=True)
    assert out[0].image.shape == (24, 32, 3) and out[0].fx == pytest.approx(25.0) and out[0].width == 32
    with pytest.raises(InputError, match="b.png"):
        load_colmap(tmp_path / "sparse", tmp_path / "nowhere", load_images=True)


def test_colmap_errors(tmp_path):
    cams, imgs, xyz, rgb = _colmap_fixture()
    with pytest.raises(InputError, match="not found"):
        load_colmap(tmp_path / "nope")
    d = tmp_path / "m"
    write_colmap_binary(d, cams, imgs, xyz, rgb)
    # inconsistent: an image refers to a camera that does not exist
    write_colmap_binary(d, cams[:1], imgs, xyz, rgb)
    with pytest.raises(InputError, match="refers to camera 2"):
        load_colmap(d)
    # truncated binary
    write_colmap_binary(d, cams, imgs, xyz, rgb)
    data = (d / "images.bin").read_bytes()
    (d / "images.bin").write_bytes(data[:-5])
    with pytest.raises(InputError, match="images.bin: truncated"):
        read_colmap_model(d)
    # unsupported model
    fish = [ColmapCamera(1, "OPENCV_FISHEYE", 10, 10, np.ones(8))]
    write_colmap_text(tmp_path / "f", fish, imgs[:1])
    with pytest.raises(InputError, match="OPENCV_FISHEYE"):
        load_colmap(tmp_path / "f")
    # wrong parameter count and unknown model names
    (tmp_path / "f" / "cameras.txt").write_text("1 PINHOLE 10 10 5 5 5\n")
    with pytest.raises(InputError, match=r"cameras.txt\b.*camera 1 \(PINHOLE\).* 3 .* 4"):
        load_colmap(tmp_path / "f")
    (tmp_path / "f" / "cameras.txt").write_text("1 WEIRD 10 10 5 5 5\n")
    with pytest.raises(InputError, match="unknown model 'WEIRD'"):
        load_colmap(tmp_path / "f")
    (tmp_path / "f" / "cameras.bin").write_bytes(struct.pack("<QiiQQ", 1, 1, 99, 10, 10))
    with pytest.raises(InputError, match="unknown model id 99"):
        load_colmap(tmp_path / "f")


# --- LLFF ----------------------------------------------------------------------------------------

def _write_llff(root, n=3, hw=(12, 16), f=20.0, img_hw=(6, 8), n_images=None):
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(n):
        c2w_cv = np.eye(4)
        c2w_cv[:3, :3] = _rot_y(0.2 * i)
        c2w_cv[:3, 3] = [i, 0.5, -3.0]
        right, down, fwd = c2w_cv[:3, 0], c2w_cv[:3, 1], c2w_cv[:3, 2]
        m = np.stack([down, right, -fwd, c2w_cv[:3, 3], np.array([hw[0], hw[1], f])], axis=1)  # LLFF layout
        rows.append(np.concatenate([m.reshape(-1), [1.0, 10.0]]))
    np.save(root / "poses_bounds.npy", np.array(rows))
    (root / "images").mkdir(exist_ok=True)
    for i in range(n if n_images is None else n_images):
        write_png(root / "images" / f"{i:03d}.png", np.full((*img_hw, 3), 0.25 * (i % 4), np.float32))


def test_llff_loader(tmp_path):
    _write_llff(tmp_path)
    cams = load_llff(tmp_path)
    assert len(cams) == 3
    c = cams[1]
    assert (c.width, c.height) == (8, 6) and c.fx == pytest.approx(10.0)  # images are half the pose size
    np.testing.assert_allclose(c.center, [1, 0.5, -3.0], atol=1e-12)
    np.testing.assert_allclose(c.rotation.T[:, 2], _rot_y(0.2)[:, 2], atol=1e-12)  # forward column
    assert c.near == pytest.approx(0.9) and c.image.shape == (6, 8, 3)
    assert cams[1].image[0, 0, 0] == pytest.approx(0.25, abs=1 / 255)


@pytest.mark.parametrize("loader", ["llff", "colmap"])
def test_llff_and_colmap_composite_rgba_on_the_given_background(tmp_path, loader):
    """Transparent pixels take the caller's background (they were always black)."""
    rgba = np.zeros((6, 8, 4), np.float32)
    rgba[..., 0] = 1.0
    rgba[:, :4, 3] = 1.0  # left half opaque red, right half transparent
    if loader == "llff":
        _write_llff(tmp_path, n=1)
        write_png(tmp_path / "images" / "000.png", rgba)
        load = lambda bg: load_llff(tmp_path, background=bg)  # noqa: E731
    else:
        write_colmap_text(tmp_path / "sparse", [ColmapCamera(1, "PINHOLE", 8, 6, np.array([8.0, 8.0, 4.0, 3.0]))],
                          [ColmapImage(1, np.array([1.0, 0, 0, 0]), np.zeros(3), 1, "a.png")])
        (tmp_path / "images").mkdir()
        write_png(tmp_path / "images" / "a.png", rgba)
        load = lambda bg: load_colmap(tmp_path / "sparse", tmp_path / "images", load_images=True,  # noqa: E731
                                      background=bg)[0]
    for bg, want in (("white", [1, 1, 1]), ("black", [0, 0, 0]), ((0.2, 0.4, 0.6), [0.2, 0.4, 0.6])):
        img = load(bg)[0].image
        assert img.shape == (6, 8, 3)
        np.testing.assert_allclose(img[:, 4:], np.broadcast_to(np.float32(want), (6, 4, 3)), atol=1e-6)
        np.testing.assert_allclose(img[:, :4], np.broadcast_to(np.float32([1, 0, 0]), (6, 4, 3)), atol=1e-6)


def test_llff_errors(tmp_path):
    with pytest.raises(InputError, match=r"poses_bounds.npy\b.*not found"):
        load_llff(tmp_path)
    _write_llff(tmp_path / "a", n_images=2)
    with pytest.raises(InputError, match="3 poses but 2 images"):
        load_llff(tmp_path / "a")
    _write_llff(tmp_path / "b", img_hw=(6, 12))
    with pytest.raises(InputError, match="not a scaled copy"):
        load_llff(tmp_path / "b")
    (tmp_path / "c").mkdir()
    np.save(tmp_path / "c" / "poses_bounds.npy", np.zeros((3, 15)))
    with pytest.raises(InputError, match=r"\[N, 17\]"):
        load_llff(tmp_path / "c")


def test_write_png_is_atomic(tmp_path, monkeypatch):
    """A failed write leaves the previous PNG as it was and no temporary file (Pillow writes
    into a temporary file that replaces the target only when complete)."""
    from PIL import Image

    target = tmp_path / "view.png"
    old = np.full((4, 5, 3), 0.25, np.float32)
    write_png(target, old)
    before = target.read_bytes()

    def failing_save(self, fp, format=None, **kw):
        fp.write(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", failing_save)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.zeros((4, 5, 3), np.float32))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.png"]
    monkeypatch.undo()
    assert np.allclose(read_image(target), np.round(old * 255) / 255)
