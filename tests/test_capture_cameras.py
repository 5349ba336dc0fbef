"""The cameras a 3DGS capture comes with: the INRIA trainer's cameras.json, nerfstudio /
instant-ngp transforms.json, COLMAP models, the one entry point over them, finding cameras.json
beside a trained scene, and lghcc-dec --render's spec reading them."""

import json
import logging
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lghcc.common.errors import InputError
from lghcc.render.camera import (Camera, ColmapCamera, ColmapImage, find_capture_cameras, load_capture_cameras,
                                 load_colmap, load_inria_cameras, load_transforms_cameras, qvec_to_rotmat,
                                 write_colmap_binary, write_colmap_text)
from lghcc.render.imageio import write_png
from lghcc.render.views import cameras_from_spec

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _cameras() -> list[Camera]:
    return [Camera.look_at([3.0, -4.0, 1.5], [0, 0, 0], width=64, height=48, fov_x_deg=60, name="a"),
            Camera.look_at([-2.0, 1.0, 5.0], [0.5, 0, 0], width=80, height=80, fov_x_deg=40, name="b"),
            Camera.look_at([0.0, 7.0, -1.0], [0, 0, 0.3], width=33, height=17, fov_x_deg=90, name="c")]


def _focal2fov(focal, pixels):
    return 2 * math.atan(pixels / (2 * focal))


def _fov2focal(fov, pixels):
    return pixels / (2 * math.tan(fov / 2))


def _camera_to_json(id_, cam: Camera) -> dict:
    """INRIA gaussian-splatting's utils/camera_utils.py camera_to_JSON, line for line, with its
    Camera's R (the world-to-camera rotation transposed), T and FovX/FovY."""
    R, T = cam.world_to_camera[:3, :3].T, cam.world_to_camera[:3, 3]
    fov_x, fov_y = _focal2fov(cam.fx, cam.width), _focal2fov(cam.fy, cam.height)
    Rt = np.zeros((4, 4))
    Rt[:3, :3] = R.transpose()
    Rt[:3, 3] = T
    Rt[3, 3] = 1.0
    W2C = np.linalg.inv(Rt)
    pos = W2C[:3, 3]
    rot = W2C[:3, :3]
    return {"id": id_, "img_name": cam.name, "width": cam.width, "height": cam.height, "position": pos.tolist(),
            "rotation": [x.tolist() for x in rot], "fy": _fov2focal(fov_y, cam.height),
            "fx": _fov2focal(fov_x, cam.width)}


def _write_inria(path, cams):
    path.write_text(json.dumps([_camera_to_json(i, c) for i, c in enumerate(cams)]))
    return path


def _assert_same(got: list[Camera], want: list[Camera], tol=1e-9):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g.world_to_camera, w.world_to_camera, rtol=0, atol=tol)
        for k in ("fx", "fy", "cx", "cy"):
            assert getattr(g, k) == pytest.approx(getattr(w, k), rel=tol, abs=tol), k
        assert (g.width, g.height, g.name) == (w.width, w.height, w.name)


# --- INRIA cameras.json ------------------------------------------------------------------------

def test_inria_cameras_round_trip_and_project_alike(tmp_path):
    cams = _cameras()
    back = load_inria_cameras(_write_inria(tmp_path / "cameras.json", cams))
    _assert_same(back, cams)
    points = np.array([[0.1, 0.2, 0.3], [1.0, -0.5, 0.2]])
    for g, w in zip(back, cams):
        np.testing.assert_allclose(g.project(points)[0], w.project(points)[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(g.center, w.center, atol=1e-12)


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       centre=st.lists(st.floats(-100, 100), min_size=3, max_size=3),
       size=st.tuples(st.integers(1, 4096), st.integers(1, 4096)),
       focal=st.tuples(st.floats(1.0, 1e4), st.floats(1.0, 1e4)))
def test_inria_cameras_round_trip_any_pose_and_intrinsics(tmp_path, q, centre, size, focal):
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = qvec_to_rotmat(np.array(q)), centre
    w, h = size
    cam = Camera.from_camera_to_world(c2w, focal[0], focal[1], w / 2, h / 2, w, h, name="view")
    (back,) = load_inria_cameras(_write_inria(tmp_path / "cameras.json", [cam]))
    _assert_same([back], [cam])


@pytest.mark.parametrize("edit, match", [
    (lambda e: e.pop("fx"), "camera 1: missing 'fx'"),
    (lambda e: e.pop("rotation"), "camera 1: missing 'rotation'"),
    (lambda e: e["position"].__setitem__(0, float("nan")), "camera 1 position is not a finite 3-vector"),
    (lambda e: e.__setitem__("fy", float("nan")), "camera 1: 'fy' must be a positive number"),
    (lambda e: e.__setitem__("width", 0), "camera 1: 'width' must be a positive integer"),
    (lambda e: e.__setitem__("height", 7.5), "camera 1: 'height' must be a positive integer"),
    (lambda e: e.__setitem__("rotation", [[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "camera 1: .*not orthonormal"),
    (lambda e: e.__setitem__("rotation", [[1, 0], [0, 1]]), "camera 1 rotation is not a finite 3x3 matrix"),
    (lambda e: e.__setitem__("img_name", 7), "camera 1: 'img_name' must be a string"),
])
def test_inria_cameras_errors_name_the_file_and_entry(tmp_path, edit, match):
    entries = [_camera_to_json(i, c) for i, c in enumerate(_cameras())]
    edit(entries[1])
    jp = tmp_path / "cameras.json"
    jp.write_text(json.dumps(entries))  # NaN is written as JSON's NaN, as json.dump does
    with pytest.raises(InputError, match="cameras.json" + r"\b.*" + match):
        load_inria_cameras(jp)


def test_inria_cameras_file_errors(tmp_path):
    jp = tmp_path / "cameras.json"
    with pytest.raises(InputError, match="cameras.json: file not found"):
        load_inria_cameras(jp)
    jp.write_text('{"frames": []}')
    with pytest.raises(InputError, match=r"cameras.json\b.*JSON list"):
        load_inria_cameras(jp)
    jp.write_text("[1, 2")
    with pytest.raises(InputError, match="cameras.json: not valid JSON"):
        load_inria_cameras(jp)
    jp.write_text("[7]")
    with pytest.raises(InputError, match=r"cameras.json\b.*camera 0\b.*object"):
        load_inria_cameras(jp)


# --- transforms.json -----------------------------------------------------------------------------

def _frames(cams, **per_frame) -> list[dict]:
    return [{"file_path": f"images/{c.name}", "transform_matrix": (c.camera_to_world @ GL_TO_CV).tolist(),
             **per_frame.get(c.name, {})} for c in cams]


def test_transforms_top_level_pixel_intrinsics(tmp_path):
    """No images: the file's w x h, fl_x/fl_y/cx/cy in its pixels, OpenGL poses converted."""
    cam = Camera.from_camera_to_world(_cameras()[0].camera_to_world, 50.0, 52.0, 30.5, 20.25, 64, 48, name="a")
    jp = tmp_path / "capture.json"  # any file name
    jp.write_text(json.dumps({"fl_x": 50.0, "fl_y": 52.0, "cx": 30.5, "cy": 20.25, "w": 64, "h": 48,
                              "camera_model": "OPENCV", "frames": _frames([cam])}))
    got = load_transforms_cameras(jp)
    _assert_same(got, [cam])
    assert got[0].image is None and got[0].distortion == ()


def test_transforms_per_frame_intrinsics_override_the_files(tmp_path):
    cams = _cameras()
    own = {"b": {"fl_x": 70.0, "fl_y": 71.0, "cx": 39.0, "cy": 41.0, "w": 80, "h": 80}}
    jp = tmp_path / "transforms.json"
    jp.write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48, "frames": _frames(cams[:2], **own)}))
    a, b = load_transforms_cameras(jp)
    assert (a.fx, a.fy, a.cx, a.cy, a.width, a.height) == (40.0, 40.0, 32.0, 24.0, 64, 48)
    assert (b.fx, b.fy, b.cx, b.cy, b.width, b.height) == (70.0, 71.0, 39.0, 41.0, 80, 80)
    np.testing.assert_allclose(b.world_to_camera, cams[1].world_to_camera, atol=1e-12)
    jp.write_text(json.dumps({"frames": _frames(cams[:2], **own)}))  # only frame b has a focal length
    with pytest.raises(InputError, match=r"transforms.json\b.*frame 0\b.*'camera_angle_x'.*'fl_x'"):
        load_transforms_cameras(jp)
    jp.write_text(json.dumps({"fl_x": 40.0, "frames": _frames(cams[:1], a={"w": 64})}))
    with pytest.raises(InputError, match=r"transforms.json: frame 0: 'w' and 'h' must be given together"):
        load_transforms_cameras(jp)
    jp.write_text(json.dumps({"fl_x": 40.0, "w": 8, "h": 8, "frames": _frames(cams[:1], a={"fl_y": -1})}))
    with pytest.raises(InputError, match=r"transforms.json: frame 0: 'fl_y' must be a positive number"):
        load_transforms_cameras(jp)


def test_transforms_camera_angle_and_size_from_the_image(tmp_path):
    cams = _cameras()
    jp = tmp_path / "transforms.json"
    jp.write_text(json.dumps({"camera_angle_x": 0.9, "w": 64, "h": 48, "frames": _frames(cams[:1])}))
    (c,) = load_transforms_cameras(jp)
    assert c.fx == pytest.approx(32 / math.tan(0.45)) and c.fy == c.fx and (c.cx, c.cy) == (32.0, 24.0)
    # no w/h: the size of the image the frame names (NeRF-synthetic style, extension left off)
    (tmp_path / "images").mkdir()
    write_png(tmp_path / "images" / "a.png", np.zeros((10, 20, 3), np.float32))
    frames = _frames(cams[:1])
    frames[0]["file_path"] = "images/a"
    jp.write_text(json.dumps({"camera_angle_x": 0.9, "frames": frames}))
    (c,) = load_transforms_cameras(jp)
    assert (c.width, c.height, c.cx, c.cy, c.name) == (20, 10, 10.0, 5.0, "a")
    assert c.fx == pytest.approx(10 / math.tan(0.45))
    frames[0]["file_path"] = "images/missing.png"
    jp.write_text(json.dumps({"camera_angle_x": 0.9, "frames": frames}))
    with pytest.raises(InputError, match=r"transforms.json\b.*frame 0\b.*'w'.*'h'"):
        load_transforms_cameras(jp)


def test_transforms_distortion_kept_and_warned_non_pinhole_refused(tmp_path, caplog):
    cams = _cameras()[:1]
    jp = tmp_path / "transforms.json"
    jp.write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48, "k1": 0.1, "p2": -0.01, "camera_model": "OPENCV",
                              "frames": _frames(cams)}))
    with caplog.at_level(logging.WARNING):
        (c,) = load_transforms_cameras(jp)
    assert c.distortion == (0.1, 0.0, 0.0, -0.01, 0.0, 0.0)
    assert "distortion ignored" in caplog.text
    jp.write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48, "frames": _frames(cams, a={"camera_model":
                                                                                         "OPENCV_FISHEYE"})}))
    with pytest.raises(InputError, match=r"transforms.json\b.*frame 0\b.*'OPENCV_FISHEYE'"):
        load_transforms_cameras(jp)


# --- COLMAP and the one entry point ------------------------------------------------------------

def _colmap_model():
    rng = np.random.default_rng(3)
    cams = [ColmapCamera(1, "PINHOLE", 64, 48, np.array([50.0, 51.0, 31.0, 23.5])),
            ColmapCamera(2, "SIMPLE_PINHOLE", 40, 40, np.array([35.0, 20.0, 20.0]))]
    images = [ColmapImage(i + 1, rng.normal(size=4), rng.normal(size=3), 1 + i % 2, f"img_{i}.jpg")
              for i in range(5)]
    return cams, images


@pytest.mark.parametrize("writer", [write_colmap_binary, write_colmap_text])
def test_capture_cameras_of_a_colmap_model_and_a_dataset_folder(tmp_path, writer):
    writer(tmp_path / "scene" / "sparse" / "0", *_colmap_model())
    want, _ = load_colmap(tmp_path / "scene" / "sparse" / "0")
    assert len(want) == 5 and want[0].name == "img_0.jpg"
    _assert_same(load_capture_cameras(tmp_path / "scene" / "sparse" / "0"), want, tol=0)
    _assert_same(load_capture_cameras(tmp_path / "scene"), want, tol=0)
    (c,) = [c for c in want if c.name == "img_1.jpg"]
    assert (c.fx, c.fy, c.cx, c.cy, c.width) == (35.0, 35.0, 20.0, 20.0, 40)


def test_capture_cameras_of_every_file_and_folder_kind(tmp_path):
    cams = _cameras()
    model = tmp_path / "model"
    model.mkdir()
    _write_inria(model / "cameras.json", cams)
    _assert_same(load_capture_cameras(model / "cameras.json"), cams)
    _assert_same(load_capture_cameras(model), cams)
    ns = tmp_path / "ns"
    ns.mkdir()
    (ns / "transforms.json").write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48, "frames": _frames(cams)}))
    assert [c.name for c in load_capture_cameras(ns)] == ["a", "b", "c"]
    assert len(load_capture_cameras(ns / "transforms.json")) == 3
    blender = tmp_path / "blender"  # NeRF-synthetic: train and test views
    blender.mkdir()
    for split, sub in (("train", cams[:2]), ("val", cams[:1]), ("test", cams[2:])):
        (blender / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.8, "w": 64, "h": 48,
                                                                      "frames": _frames(sub)}))
    assert [c.name for c in load_capture_cameras(blender)] == ["a", "b", "c"]
    assert [c.name for c in load_capture_cameras(blender / "transforms_test.json")] == ["c"]


def test_capture_cameras_errors_name_what_was_given(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(InputError, match=r"notes.txt\b.*INRIA cameras.json"):
        load_capture_cameras(tmp_path / "notes.txt")
    with pytest.raises(InputError, match=r"missing.json: not found"):
        load_capture_cameras(tmp_path / "missing.json")
    (tmp_path / "other.json").write_text('{"camera": 1}')
    with pytest.raises(InputError, match=r"other.json\b.*list of cameras"):
        load_capture_cameras(tmp_path / "other.json")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty\b.*no cameras"):
        load_capture_cameras(tmp_path / "empty")
    (tmp_path / "cameras.json").write_text("[]")
    with pytest.raises(InputError, match=r"cameras.json: no cameras"):
        load_capture_cameras(tmp_path / "cameras.json")
    both = tmp_path / "both"
    write_colmap_text(both / "sparse" / "0", *_colmap_model())
    (both / "transforms.json").write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48, "frames": []}))
    with pytest.raises(InputError, match=r"both\b.*transforms.json.*COLMAP"):
        load_capture_cameras(both)


# --- finding cameras.json beside a trained scene ---------------------------------------------------

def test_find_capture_cameras(tmp_path):
    model = tmp_path / "output" / "garden"
    ply = model / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    ply.parent.mkdir(parents=True)
    ply.write_bytes(b"ply\n")
    assert find_capture_cameras(ply) is None
    assert find_capture_cameras(model) is None
    (model / "cameras.json").write_text("[]")
    assert find_capture_cameras(ply) == model / "cameras.json"
    assert find_capture_cameras(model) == model / "cameras.json"
    beside = tmp_path / "beside" / "scene.ply"
    beside.parent.mkdir()
    beside.write_bytes(b"ply\n")
    assert find_capture_cameras(beside) is None
    (tmp_path / "beside" / "cameras.json").write_text("[]")
    assert find_capture_cameras(beside) == tmp_path / "beside" / "cameras.json"
    up = tmp_path / "up" / "exports" / "scene.spz"
    up.parent.mkdir(parents=True)
    (tmp_path / "up" / "cameras.json").write_text("[]")
    assert find_capture_cameras(up) == tmp_path / "up" / "cameras.json"
    deep = tmp_path / "deep" / "a" / "b" / "scene.ply"  # two folders above the scene's, not the INRIA layout
    deep.parent.mkdir(parents=True)
    (tmp_path / "deep" / "cameras.json").write_text("[]")
    assert find_capture_cameras(deep) is None


# --- lghcc-dec --render's spec -----------------------------------------------------------------------

def test_render_spec_reads_capture_cameras(tmp_path):
    cams = _cameras()
    model = tmp_path / "model"
    model.mkdir()
    _write_inria(model / "cameras.json", cams)
    (tmp_path / "transforms.json").write_text(json.dumps({"fl_x": 40.0, "w": 64, "h": 48,
                                                          "frames": _frames(cams[:2])}))
    pos = np.zeros((1, 3))
    _assert_same(cameras_from_spec(str(model / "cameras.json"), pos), cams)
    _assert_same(cameras_from_spec(str(model), pos), cams)
    assert len(cameras_from_spec(str(tmp_path / "transforms.json"), pos)) == 2
    half = cameras_from_spec(str(model / "cameras.json"), pos, scale=0.5)
    assert (half[0].width, half[0].height) == (32, 24)
    (tmp_path / "other.json").write_text('{"camera": 1}')
    with pytest.raises(InputError, match="other.json"):
        cameras_from_spec(str(tmp_path / "other.json"), pos)
    with pytest.raises(InputError, match="cameras.json \\(INRIA\\)"):
        cameras_from_spec(str(tmp_path / "nowhere"), pos)
