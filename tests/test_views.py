"""Where the explicit-Gaussian encoder looks from (issue 52): the object / inside decision, the views
of each kind, the capture's cameras, pruning bounded per view, and the check on held-back views."""

import json
import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.scene import GaussianScene
from lghcc.encoder.gaussians.free_space import OccupancyGrid, watched_from
from lghcc.encoder.gaussians.gaussian_views import (CHECK_VIEWS, LANDING_VIEWS, ORBIT, SceneViews, cropped, prune_by_view_share,
                                                    resolving_views, scene_views)
from lghcc.formats.procedural import (ROOM_PARTS, make_room_scene, room_inside_cameras, room_scene_parts,
                                      smooth_gaussian_scene)
from lghcc.render.camera import Camera


def _box_shell(lo, hi, n: int, rng) -> np.ndarray:
    """n points on each of the six faces of the box [lo, hi]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    faces = []
    for axis in range(3):
        for side in (lo, hi):
            p = rng.uniform(lo, hi, (n, 3))
            p[:, axis] = side[axis]
            faces.append(p)
    return np.concatenate(faces)


def _points_scene(points: np.ndarray, log_scale: float = -4.0) -> GaussianScene:
    n = points.shape[0]
    return GaussianScene(points.astype(np.float32), np.zeros((n, 1, 3), np.float32), np.full(n, 3.0, np.float32),
                         np.full((n, 3), log_scale, np.float32), np.tile(np.float32([1, 0, 0, 0]), (n, 1)))


def test_a_room_is_watched_from_inside_and_its_viewpoints_are_in_its_free_space():
    scene = make_room_scene(20_000)
    found = watched_from(scene)
    assert found.kind == "inside", found.reason
    lo, hi = np.quantile(scene.means, 0.01, axis=0), np.quantile(scene.means, 0.99, axis=0)
    assert found.eyes.shape == (3, 3)
    assert np.all((found.eyes > lo) & (found.eyes < hi))
    # no content right at a viewpoint: each is at least a few cells from the nearest Gaussian
    grid = OccupancyGrid.of(scene.means.astype(np.float64))
    nearest = np.min(np.linalg.norm(scene.means[None, :, :] - found.eyes[:, None, :], axis=2), axis=1)
    assert np.all(nearest > 2 * grid.cell)


def test_objects_are_watched_from_around_them():
    rng = np.random.default_rng(0)
    assert watched_from(smooth_gaussian_scene(3000, 0)).kind == "orbit"
    d = rng.normal(size=(6000, 3))
    ball = _points_scene(d / np.linalg.norm(d, axis=1, keepdims=True))  # a thin closed shell: a small cavity
    solid = _points_scene(rng.uniform(-1, 1, (6000, 3)))
    assert watched_from(solid).kind == "orbit"
    # a closed sphere's inside is a third of its box, enclosed: geometry alone cannot tell it from a
    # room; the decision is inside or both, never a silent orbit that prunes what is seen inside
    assert watched_from(ball).kind in ("inside", "both")


@pytest.mark.parametrize("points", [np.zeros((50, 3)), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]] * 20)])
def test_degenerate_scenes_are_objects(points):
    """A scene of one point, or on a line: no free space, an orbit, no error."""
    assert watched_from(_points_scene(points)).kind == "orbit"


def test_the_orbit_kind_gives_the_views_the_encoder_always_gave():
    scene = smooth_gaussian_scene(2000, 1)
    a, b = ORBIT.cameras(scene, 6, 64, 0.1), resolving_views(scene, 6, 64, 0.1)
    assert [c.name for c in a] == [c.name for c in b]
    assert all(np.array_equal(x.world_to_camera, y.world_to_camera) and x.fx == y.fx for x, y in zip(a, b))


def test_inside_views_look_outward_from_the_viewpoints_as_a_standing_viewer_does():
    scene = make_room_scene(20_000)
    views = scene_views(scene, "inside")
    cams = views.whole_views(scene, 12, 64)
    assert len(cams) == 12 and all(c.width == c.height == 64 for c in cams)
    eyes = {tuple(np.round(c.center, 6)) for c in cams}
    assert eyes == {tuple(np.round(e, 6)) for e in views.eyes}
    forward = np.array([c.forward for c in cams])
    assert np.abs(forward.mean(axis=0)).max() < 0.2  # spread around the viewpoints
    assert np.all(np.abs(forward[:, 2]) <= np.sin(np.radians(35)) + 1e-9)  # within 35 degrees of the horizon
    assert all(abs(np.degrees(c.fov_x) - 90) < 1e-6 for c in cams)
    held = views.held(CHECK_VIEWS).whole_views(scene, 12, 64) + views.held(LANDING_VIEWS).whole_views(scene, 12, 64)
    assert not any(np.allclose(h.world_to_camera, c.world_to_camera) for h in held for c in cams)


def test_both_splits_the_views_between_the_kinds():
    scene = make_room_scene(20_000)
    both = scene_views(scene, "both")
    cams = both.whole_views(scene, 7, 32)
    assert len(cams) == 7 and sum(c.name.startswith("fit_") for c in cams) == 4


def _capture(n: int) -> list[Camera]:
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [Camera.look_at((3 * np.cos(a), 3 * np.sin(a), 1.0), (0, 0, 0), width=320, height=180, fov_x_deg=60,
                           name=f"cap{i}") for i, a in enumerate(angles)]


def test_the_capture_cameras_are_used_as_a_spread_subset_at_the_views_pixel_count():
    scene = smooth_gaussian_scene(2000, 0)
    views = scene_views(scene, "auto", _capture(40))
    assert views.kind == "capture"
    cams = views.whole_views(scene, 8, 100)
    assert len(cams) == 8 and all(abs(c.width * c.height - 100 * 100) < 300 for c in cams)
    assert all(abs(c.width / c.height - 320 / 180) < 0.02 for c in cams)
    centres = np.array([c.center for c in cams])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.eye(8) * 99
    assert gaps.min() > 0.5  # spread round the circle (neighbours are 0.47 apart)
    check = {c.name for c in views.held(CHECK_VIEWS).whole_views(scene, 8, 100)}
    landing = {c.name for c in views.held(LANDING_VIEWS).whole_views(scene, 8, 100)}
    assert len(check) == len(landing) == 8 and check.isdisjoint(landing)
    assert (check | landing).isdisjoint({c.name for c in views.whole_views(scene, 24, 100)})


def test_a_crop_shows_the_window_of_its_view_magnified():
    cam = Camera.look_at((0, -4, 0), (0, 0, 0), width=80, height=60, fov_x_deg=60)
    crop = cropped(cam, 4.0, (20.0, 45.0), "c")
    points = np.array([[0.3, 0.2, -0.4], [-1.0, 0.5, 0.1]])
    (uv, _), (uv2, _) = cam.project(points), crop.project(points)
    np.testing.assert_allclose(uv2, 4.0 * (uv - [20.0, 45.0]) + [40.0, 30.0], atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(1, 4), st.integers(2, 60), st.floats(0.0, 0.5), st.integers(0, 2 ** 31))
def test_pruning_by_largest_region_share_bounds_what_every_view_and_region_loses(views, regions, n, share, seed):
    """Pruned by each Gaussian's largest share of one region of one view (render/importance.py),
    no region of any view, and so no view, loses more than ``share`` of its contribution, however
    the Gaussians are spread over the views and regions."""
    rng = np.random.default_rng(seed)
    w = rng.exponential(size=(views, regions, n)) * (rng.random((views, regions, n)) < 0.5)  # many seen by few
    w[:, :, 0] += 1e-3  # every region sees something
    region_share = (w / w.sum(axis=2, keepdims=True)).max(axis=(0, 1))
    keep = prune_by_view_share(region_share, share)
    lost_in_region = w[:, :, ~keep].sum(axis=2) / w.sum(axis=2)
    lost_in_view = w[:, :, ~keep].sum(axis=(1, 2)) / w.sum(axis=(1, 2))
    assert np.all(lost_in_region <= share + 1e-12) and np.all(lost_in_view <= share + 1e-12) and keep.any()


def test_inside_views_keep_what_the_orbit_prunes_in_a_room():
    """The room's furniture is hidden from the orbit: pruned by orbit contributions it goes (all but
    14% at 1% of any view, 48 px views of 12k Gaussians); measured from inside, per region of a view
    as the encoder prunes there, what the views show of it stays (74%: the rest is hidden behind or
    under furniture), and a quarter of the outside of the walls, which the inside views barely
    show, goes instead."""
    from lghcc.encoder.gaussians.gaussian_fit import measure_contributions, pruning_regions
    from lghcc.render.gaussians3dgs import gaussians_from_scene

    scene, parts = room_scene_parts(12_000, 0, 0)
    furniture = parts == ROOM_PARTS.index("furniture")
    g = gaussians_from_scene(scene)
    kept = {}
    for kind in ("orbit", "inside"):
        views = scene_views(scene, kind)
        c = measure_contributions(g, views.contribution_cameras(scene, 12, 48, 0.0), False, pruning_regions(views))
        kept[kind] = prune_by_view_share(c.view_share, 0.01)
    exterior = parts == ROOM_PARTS.index("exterior")
    assert kept["orbit"][furniture].mean() < 0.25 and kept["inside"][furniture].mean() > 0.5
    assert kept["orbit"][exterior].all() and kept["inside"][exterior].mean() < 0.75


@pytest.mark.integration
def test_lghcc_enc_uses_the_cameras_of_an_inria_training_output(tmp_path):
    """A PLY in the INRIA layout: lghcc-enc finds <model>/cameras.json, says so, measures from those
    cameras and checks the stream on others of them; --no-cameras and --views place views itself."""
    from lghcc.encoder.cli import main
    from lghcc.formats import write_scene

    model = tmp_path / "model"
    ply = model / "point_cloud" / "iteration_7000" / "point_cloud.ply"
    ply.parent.mkdir(parents=True)
    scene = make_room_scene(3000)
    write_scene(scene, ply)
    _write_inria_cameras(model / "cameras.json", room_inside_cameras(n=20, size=64))
    report = tmp_path / "r.json"
    args = [str(ply), "-o", str(tmp_path / "s.lghcc"), "--preset", "low", "--json", str(report), "-q",
            "--config", str(_small_config(tmp_path))]
    assert main(args) == 0
    stats = json.loads(report.read_text())["stats"]
    assert stats["prepare_views"] == "capture" and stats["prepare_gaussians_in"] == 3000
    assert stats["prepare_held_back_views"] == 4 and stats["prepare_held_back_psnr"] > 20
    assert main(args + ["-y", "--views", "orbit"]) == 0
    assert json.loads(report.read_text())["stats"]["prepare_views"] == "orbit"
    assert main(args + ["-y", "--cameras", str(model), "--views", "inside"]) == 2  # contradicting options
    assert main(args + ["-y", "--cameras", str(tmp_path / "none.json")]) == 1


def _write_inria_cameras(path, cams):
    """``cams`` as the cameras.json a 3DGS training output holds (centre, camera-to-world rotation)."""
    path.write_text(json.dumps([{"id": i, "img_name": c.name, "width": c.width, "height": c.height,
                                 "position": c.center.tolist(), "rotation": c.camera_to_world[:3, :3].tolist(),
                                 "fx": c.fx, "fy": c.fy} for i, c in enumerate(cams)]))
    return path


def _small_config(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text("fit_views: 16\nfit_resolution: 32\nsearch_views: 4\nsearch_resolution: 32\n"
                    "search_reference_gaussians: 0\ncheck_views: 4\ncheck_resolution: 32\nfit_iterations: 0\n"
                    "landing_views: 4\nlanding_resolution: 32\n")
    return path


def test_bench_views_decides_the_built_scenes(tmp_path):
    """tools/bench_views.py on the built scenes whose answer is known."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / "bench_views.py"
    spec = importlib.util.spec_from_file_location("bench_views", path)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    out = tmp_path / "views.md"
    assert tool.main(["--scenes", "room,solid-cube", "--out", str(out)]) == 0
    rows = [line for line in out.read_text().splitlines() if line.startswith("| room") or line.startswith("| solid")]
    assert "**inside**" in rows[0] and "**orbit**" in rows[1]


@pytest.mark.integration
def test_the_landing_moves_the_steps_onto_the_target_on_its_own_views():
    """With a target, the prepared scene's steps are moved onto it on the landing views (larger
    than the search's, none of the search's or the check's), in the place of the trim."""
    from lghcc.encoder.gaussians.gaussian_fit import prepare_gaussians
    from lghcc.encoder.stream.config import GaussianEncoderConfig

    scene = smooth_gaussian_scene(1500, 1, seed=3)
    base = dict(target_psnr=38.0, search_views=2, search_resolution=32, fit_views=4, fit_resolution=32,
                fit_iterations=3, search_reference_gaussians=0, resolve_px=0.0, landing_resolution=64,
                landing_views=3)
    landed = prepare_gaussians(scene, GaussianEncoderConfig(**base))
    assert landed.stats.landing_trials >= 1 and landed.stats.time_trim_s is None
    legacy = prepare_gaussians(scene, GaussianEncoderConfig(**{**base, "landing_views": 0}))
    assert legacy.stats.landing_trials is None and legacy.stats.time_trim_s is not None
    assert landed.cfg.search_views == 2 and landed.cfg.search_resolution == 32  # the search's plan kept


@pytest.mark.integration
def test_lghcc_encode_takes_the_capture_cameras(tmp_path):
    """lghcc.encode(..., cameras=PATH): the room measured from its cameras keeps what they see; from
    the orbit (views="orbit") the inside is pruned away, and the stream is a fraction of the size."""
    import lghcc

    scene = make_room_scene(2000)
    path = _write_inria_cameras(tmp_path / "cameras.json", room_inside_cameras(n=12, size=64))
    small = dict(fit_views=8, fit_resolution=32, search_views=2, search_resolution=32, search_reference_gaussians=0,
                 check_views=2, check_resolution=32, landing_views=2, landing_resolution=32, fit_iterations=0)
    inside = lghcc.decode(lghcc.encode(scene, "low", cameras=path, **small))
    around = lghcc.decode(lghcc.encode(scene, "low", views="orbit", **small))
    assert inside.num_gaussians > 2 * around.num_gaussians


def test_a_turned_camera_keeps_its_centre_and_looks_beside_the_capture():
    from lghcc.encoder.gaussians.gaussian_views import TURN_PITCH_DEG, TURN_YAW_DEG, turned

    cam = _capture(4)[1]
    for j in range(20):
        t = turned(cam, j, "t")
        np.testing.assert_allclose(t.center, cam.center, atol=1e-9)
        angle = np.degrees(np.arccos(np.clip(t.forward @ cam.forward, -1, 1)))
        assert 0 < angle <= np.hypot(TURN_YAW_DEG, TURN_PITCH_DEG) + 1e-6
        np.testing.assert_allclose(t.rotation @ t.rotation.T, np.eye(3), atol=1e-12)
