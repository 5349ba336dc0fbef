"""The procedural room (formats/procedural.py make_room_scene, room_inside_cameras): a closed room
watched from inside, whose inside views are known; and tools/make_room.py, which writes it."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from lghcc.formats import read_scene
from lghcc.formats.procedural import (EYE_HEIGHT, ROOM_HI, ROOM_LO, ROOM_PARTS, WALL_THICKNESS, furniture_contains,
                                      make_room_scene, room_contains, room_inside_cameras, room_scene_parts)
from lghcc.render.metrics import psnr
from lghcc.render.scenes import render_views
from lghcc.render.views import orbit_cameras

TOOLS = Path(__file__).resolve().parents[1] / "tools"
FIELDS = ("means", "sh", "opacity", "log_scales", "rotations")
FURNITURE, EXTERIOR = ROOM_PARTS.index("furniture"), ROOM_PARTS.index("exterior")


def _rotmats(q: np.ndarray) -> np.ndarray:
    """[N, 3, 3] rotation matrices of (w, x, y, z) quaternions."""
    q = q.astype(np.float64) / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


@pytest.fixture(scope="module")
def room():
    """(scene, parts) of 30,000 Gaussians, SH 0: what the rendering tests look at."""
    return room_scene_parts(30_000, 0, 0)


@pytest.mark.parametrize("n", [100, 2_001, 60_000])
def test_exactly_n_gaussians_and_the_same_for_the_same_seed(n):
    a, pa = room_scene_parts(n, 1, seed=7)
    b, pb = room_scene_parts(n, 1, seed=7)
    assert a.num_gaussians == n and pa.shape == (n,)
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == np.float32 and x.tobytes() == y.tobytes(), f
    assert pa.tobytes() == pb.tobytes()
    c = make_room_scene(n, 1, seed=8)
    assert c.num_gaussians == n
    assert not np.array_equal(a.means, c.means) and not np.array_equal(a.sh, c.sh)
    assert np.array_equal(make_room_scene(n, 1, seed=7).means, a.means)


def test_too_few_gaussians_refused():
    with pytest.raises(ValueError):
        make_room_scene(99)


@pytest.mark.parametrize("degree", [0, 3])
def test_validates_with_small_smooth_view_dependence(degree):
    scene = make_room_scene(20_000, degree, seed=1)
    assert scene.validate() is scene
    assert scene.sh.shape == (20_000, (degree + 1) ** 2, 3) and scene.sh_degree == degree
    if degree:  # a few percent of the DC, and smooth: nearest neighbours have nearly the same bands
        rest, dc = np.abs(scene.sh[:, 1:]), np.abs(scene.sh[:, 0])
        assert 0.005 * dc.mean() < rest.mean() < 0.05 * dc.mean() and rest.max() < 0.5
        from scipy.spatial import cKDTree

        _, nn = cKDTree(scene.means).query(scene.means, k=2)
        a, b = scene.sh[:, 1:].reshape(-1), scene.sh[nn[:, 1], 1:].reshape(-1)
        assert np.corrcoef(a, b)[0, 1] > 0.9
    colour = 0.5 + 0.28209479 * scene.sh[:, 0]
    assert colour.min() > 0 and colour.max() < 1
    assert np.median(scene.opacity) > 3 and scene.opacity.min() >= 2.5 and scene.opacity.max() <= 5.5


def test_every_mean_inside_the_room_or_on_its_outer_walls():
    scene, part = room_scene_parts(60_000, 0)
    m = scene.means.astype(np.float64)
    inner = part != EXTERIOR
    assert room_contains(m[inner], margin=-1e-5).all()
    lo, hi = np.array(ROOM_LO) - [WALL_THICKNESS, WALL_THICKNESS, 0], np.array(ROOM_HI) + WALL_THICKNESS
    ext = m[~inner]
    assert 0 < ext.shape[0] < 0.1 * scene.num_gaussians
    assert ((ext >= lo - 1e-5) & (ext <= hi + 1e-5)).all()
    near = lambda a, b: np.isclose(a, b, rtol=0, atol=1e-5)  # noqa: E731
    on_face = (near(ext[:, 0], lo[0]) | near(ext[:, 0], hi[0]) | near(ext[:, 1], lo[1]) | near(ext[:, 1], hi[1])
               | near(ext[:, 2], hi[2]))  # the four outer walls and the roof
    assert on_face.all()
    assert not room_contains(ext, margin=-1e-3).any()
    assert furniture_contains(m[part == FURNITURE], margin=1e-5).all()
    assert not furniture_contains(m[part < FURNITURE], margin=-1e-3).any()
    counts = np.bincount(part, minlength=len(ROOM_PARTS))
    assert (counts > 0).all() and counts[ROOM_PARTS.index("walls")] > counts[FURNITURE]


def test_flat_gaussians_lie_in_their_surfaces():
    """Scale index 2 is the thinnest (10x), and the rotation turns it to the surface's normal."""
    scene, part = room_scene_parts(60_000, 0)
    s = np.exp(scene.log_scales.astype(np.float64))
    assert (s[:, 2] * 5 < s[:, :2].min(axis=1)).all()
    tangent = s[part != EXTERIOR, :2]
    assert 0.01 < np.median(tangent) < 0.05  # a few centimetres at 60k
    normal = _rotmats(scene.rotations)[:, :, 2]
    m = scene.means
    floor_ceiling = part <= ROOM_PARTS.index("ceiling")
    assert (np.abs(normal[floor_ceiling, 2]) > 0.999).all()
    walls = part == ROOM_PARTS.index("walls")
    on_x = np.isclose(np.abs(m[:, 0]), ROOM_HI[0]) & walls
    on_y = np.isclose(np.abs(m[:, 1]), ROOM_HI[1]) & walls & ~on_x
    assert (on_x | on_y)[walls].all()
    assert (np.abs(normal[on_x, 0]) > 0.999).all() and (np.abs(normal[on_y, 1]) > 0.999).all()


def test_inside_cameras_stand_in_the_room_clear_of_furniture():
    cams = room_inside_cameras()
    assert len(cams) == 18
    centres = np.array([c.center for c in cams])
    assert room_contains(centres, margin=0.5).all()
    assert not furniture_contains(centres, margin=0.3).any()
    feet = centres * [1, 1, 0] + [0, 0, 0.05]  # where the viewer stands: not on or in furniture
    assert not furniture_contains(feet, margin=0.3).any()
    assert np.allclose(centres[:, 2], EYE_HEIGHT, atol=0.15)
    forward = np.array([c.forward for c in cams])
    pitch = np.degrees(np.arcsin(forward[:, 2]))
    assert np.abs(pitch).max() <= 35 + 1e-9 and pitch.min() < -10 and pitch.max() > 10
    yaw = np.sort(np.degrees(np.arctan2(forward[:, 1], forward[:, 0])) % 360)
    assert np.diff(np.r_[yaw, yaw[0] + 360]).max() < 45  # all around the circle
    for c in cams:
        assert (c.width, c.height) == (256, 256) and c.near == 0.05
        assert np.isclose(np.degrees(c.fov_x), 90) and abs(c.camera_to_world[2, 0]) < 1e-12  # no roll
    again = room_inside_cameras(None, 18, seed=0)
    assert all(np.array_equal(a.world_to_camera, b.world_to_camera) for a, b in zip(cams, again))
    other = room_inside_cameras(None, 18, seed=1)
    assert not np.allclose(centres, [c.center for c in other])
    small = room_inside_cameras(make_room_scene(500), 4, size=32, fov_deg=70)
    assert len(small) == 4 and small[0].width == 32 and np.isclose(np.degrees(small[0].fov_x), 70)


def test_inside_views_see_the_room_all_around(room):
    scene, _ = room
    images = render_views(scene, room_inside_cameras(None, 9, size=64), background="black")
    for im in images:
        assert im.shape == (64, 64, 3)
        assert (im.max(axis=2) < 0.05).mean() < 0.02  # no background shows
        assert im.std() > 0.03  # not a blank wall: texture, corners, furniture
    white = render_views(scene, room_inside_cameras(None, 9, size=64), background="white")
    alpha = 1 - np.mean([(w - b).mean() for w, b in zip(white, images)])
    assert alpha > 0.99


def test_orbit_sees_a_closed_box_and_the_inside_views_see_the_furniture(room):
    """Without its furniture the room is the same from outside (the walls hide it) and plainly
    different from inside."""
    scene, part = room
    empty = scene.subset(part != FURNITURE)
    orbit = orbit_cameras(scene.means, 4, width=64, height=64)
    full_o, empty_o = np.stack(render_views(scene, orbit)), np.stack(render_views(empty, orbit))
    assert psnr(full_o, empty_o) > 40
    assert (full_o.max(axis=3) > 0.2).mean() > 0.3  # the box fills a good part of the views
    inside = room_inside_cameras(None, 18, size=64)
    full_i, empty_i = np.stack(render_views(scene, inside)), np.stack(render_views(empty, inside))
    assert psnr(full_i, empty_i) < 25


def test_the_exterior_does_not_show_inside(room):
    """The shell outside is drawn over no inside view (module doc of EXTERIOR_SPACING)."""
    scene, part = room
    inside = room_inside_cameras(None, 9, size=64)
    with_shell = np.stack(render_views(scene, inside))
    without = np.stack(render_views(scene.subset(part != EXTERIOR), inside))
    assert psnr(with_shell, without) > 45


def test_make_room_tool_writes_the_scene_and_its_cameras(tmp_path):
    sys.path.insert(0, str(TOOLS))
    try:
        import make_room
    finally:
        sys.path.remove(str(TOOLS))
    out = tmp_path / "room" / "room.ply"
    assert make_room.main(["-o", str(out), "--gaussians", "2000", "--sh-degree", "1", "--seed", "3",
                           "--cameras", "5", "--size", "64"]) == 0
    scene = read_scene(out)
    want = make_room_scene(2000, 1, seed=3)
    assert scene.num_gaussians == 2000 and scene.sh_degree == 1
    assert np.array_equal(scene.means, want.means) and np.array_equal(scene.sh, want.sh)
    entries = json.loads((out.parent / "cameras.json").read_text())
    cams = room_inside_cameras(None, 5, size=64, seed=3)
    assert len(entries) == 5
    for i, (e, c) in enumerate(zip(entries, cams)):
        assert set(e) == {"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"}
        assert e["id"] == i and e["img_name"] == c.name and (e["width"], e["height"]) == (64, 64)
        assert e["fx"] == e["fy"] == pytest.approx(32.0)
        r = np.array(e["rotation"])
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1)
        assert np.allclose(e["position"], c.center) and np.allclose(r[:, 2], c.forward)
        assert r[2, 1] < 0  # camera y (down in the image) points down in the world


def test_make_room_tool_writes_a_model_folder(tmp_path):
    sys.path.insert(0, str(TOOLS))
    try:
        import make_room
    finally:
        sys.path.remove(str(TOOLS))
    out = tmp_path / "model"
    assert make_room.main(["-o", str(out), "--gaussians", "300", "--cameras", "2"]) == 0
    assert read_scene(out / "point_cloud" / "iteration_0" / "point_cloud.ply").num_gaussians == 300
    assert len(json.loads((out / "cameras.json").read_text())) == 2
