"""Tiles (format version 1, spec clauses 7.3.11, 13.2, 13.3): every tile decodes alone, the
output does not depend on how many processes decode it, a box selects exactly the tiles whose
cell meets it, the level-1 preview is each tile's level 1, and a scene too small for tiles pays
nothing for the tool. The faults of a tile index are conformance error streams (e125-e134)."""

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lghcc.common.container import UnitType, read_container
from lghcc.common.hashing import digest_of
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.tiles import Box, cell_bounds, cell_intersects_box, tile_cells
from lghcc.common.units import SceneParameterSet, TileIndex
from lghcc.decoder import decode as decode_mod
from lghcc.decoder import jobs as jobs_mod
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.stream.config import EncoderConfig
from lghcc.encoder.stream.encode import encode_scene
from lghcc.encoder.stream.tiling import choose_tile_scale

from scenes import random_scene


def _encode(scene, **cfg):
    return encode_scene(scene, EncoderConfig(**cfg))


def _index(data: bytes) -> tuple[SceneParameterSet, TileIndex | None]:
    units = read_container(data).units
    sps = SceneParameterSet.from_bytes(units[0].payload)
    iu = [u for u in units if u.unit_type == UnitType.TILE_INDEX]
    return sps, (TileIndex.from_bytes(iu[0].payload, num_points=sps.num_points) if iu else None)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(2, 300), spread=st.sampled_from([3, 20, 100, 10 ** 5]),
       tile_points=st.sampled_from([1, 5, 40]), hierarchy=st.booleans(), scale=st.sampled_from([1, 2, 4]))
def test_tiled_streams_round_trip_and_each_tile_holds_its_cell(seed, n, spread, tile_points, hierarchy, scale):
    """Any scene, any tile size: the decoder gives back the encoder's scene bit for bit; the
    tiles partition the points into cells in increasing order, each point in its tile's cell,
    and no coarse voxel is split between tiles."""
    scene = random_scene(np.random.default_rng(seed), n, spread=spread, mask=bool(seed % 2))
    res = _encode(scene, tile_points=tile_points, hierarchy=hierarchy, coarse_voxel_scale=scale)
    dec = decode_stream(res.data)
    assert dec.stream_hash == res.scene_hash == digest_of(dec.scene)
    assert np.array_equal(dec.scene.coords, res.decoded.coords)
    sps, index = _index(res.data)
    if index is None:
        assert res.stats.num_tiles == 1 and sps.tiles_enabled_flag == 0
        return
    assert index.num_tiles == res.stats.num_tiles >= 2
    size = sps.tile_size
    if sps.hierarchy_enabled_flag:
        assert size % sps.coarse_voxel_scale == 0
    start = 0
    for t, cell in enumerate(index.cells):
        count = index.tile_num_points_minus1[t] + 1
        pts = dec.scene.coords[start:start + count]
        assert (tile_cells(pts, size) == np.asarray(cell)).all()
        start += count
    assert start == dec.scene.num_anchors
    assert index.cells == sorted(set(index.cells))


def test_small_scenes_have_no_tiles_and_pay_nothing():
    """A scene under 2 x tile_points points is one tile: the stream is the untiled one, byte for byte."""
    scene = random_scene(np.random.default_rng(5), 200, spread=40)
    assert _encode(scene, tile_points=1000).data == _encode(scene, tile_points=0).data


def test_tile_size_is_chosen_from_the_points():
    """The side is a power of two of coarse voxels whose mean points per occupied tile is nearer
    the target (by ratio) than the mean of every other power of two that gives two tiles or more."""
    rng = np.random.default_rng(1)
    coords = rng.integers(0, 256, size=(40000, 3))

    def miss(scale, unit, target):
        occupied = len(np.unique(tile_cells(coords, scale * unit), axis=0))
        return abs(np.log2(len(coords) / occupied / target)) if occupied > 1 else np.inf

    for unit, target in ((1, 5000), (4, 5000), (1, 300), (2, 12000)):
        scale = choose_tile_scale(coords, unit, target)
        assert scale >= 1 and scale & (scale - 1) == 0
        assert all(miss(scale, unit, target) <= miss(1 << j, unit, target) for j in range(10))
    assert choose_tile_scale(coords, 1, 0) == 0 and choose_tile_scale(coords, 1, 30000) == 0


def brute_force_tile_scale(coords, unit, target):
    """choose_tile_scale by its definition: every power-of-two side's occupied cells counted anew."""
    best, best_err = 0, np.inf
    for j in range(21):
        occupied = len(np.unique(tile_cells(coords, (1 << j) * unit), axis=0))
        if occupied == 1:
            break
        err = abs(np.log2(len(coords) / occupied / target))
        if err < best_err:
            best, best_err = 1 << j, err
    return best


@pytest.mark.parametrize("seed", range(6))
def test_tile_size_of_negative_and_clustered_points_and_odd_units(seed):
    """The sides' cells derived from the side below (floor(floor(c / s) / 2) = floor(c / 2s)) count
    what counting each side anew counts: negative coordinates, clusters, coarse voxels of 3 and 5."""
    rng = np.random.default_rng(seed)
    centres = rng.integers(-5000, 5000, size=(7, 3))
    coords = centres[rng.integers(0, 7, 3000)] + rng.integers(-40, 40, size=(3000, 3)) * (seed + 1)
    for unit, target in ((1, 100), (3, 250), (5, 40)):
        assert choose_tile_scale(coords, unit, target) == brute_force_tile_scale(coords, unit, target)


@pytest.fixture(scope="module")
def tiled():
    scene = random_scene(np.random.default_rng(7), 3000, spread=60, mask=True)
    res = _encode(scene, tile_points=300, hierarchy=True, coarse_voxel_scale=4)
    return scene, res


def test_worker_processes_give_the_same_scene(tiled):
    _, res = tiled
    one = decode_stream(res.data)
    two = decode_stream(res.data, jobs=2, exact_jobs=True)
    assert one.num_tiles > 2 and one.stream_hash == two.stream_hash == res.scene_hash
    assert two.hash_checked and two.workers.workers == 2 and one.workers.workers == 1


def test_a_box_decodes_exactly_the_tiles_that_meet_it(tiled):
    _, res = tiled
    sps, index = _index(res.data)
    full = decode_stream(res.data).scene
    rng = np.random.default_rng(3)
    for _ in range(5):
        lo = rng.uniform(-0.7, 0.5, 3)
        box = Box(tuple(lo), tuple(lo + rng.uniform(0.01, 0.4, 3)))
        want = [t for t, c in enumerate(index.cells)
                if cell_intersects_box(c, sps.tile_size, sps.voxel_size, sps.origin, box)]
        got = decode_stream(res.data, box=box)
        assert got.tiles_decoded == len(want) and got.hash_checked
        starts = np.cumsum([0] + [x + 1 for x in index.tile_num_points_minus1])
        rows = np.concatenate([np.arange(starts[t], starts[t + 1]) for t in want]) if want else np.zeros(0, int)
        assert np.array_equal(got.scene.coords, full.coords[rows])
        assert np.array_equal(got.scene.features, full.features[rows])


def test_box_cells_in_world_coordinates():
    """A cell covers voxels lo..hi; in the world it spans lo * v + origin .. (hi + 1) * v + origin."""
    lo, hi = cell_bounds((1, -1, 0), 8)
    assert lo.tolist() == [8, -8, 0] and hi.tolist() == [15, -1, 7]
    inside = Box((0.85, -0.85, 0.05), (0.9, -0.8, 0.1))
    touching = Box((1.6, 0.0, 0.0), (2.0, 1.0, 1.0))
    away = Box((1.7, 0.0, 0.0), (2.0, 1.0, 1.0))
    assert cell_intersects_box((1, -1, 0), 8, 0.1, (0, 0, 0), inside)
    assert cell_intersects_box((1, -1, 0), 8, 0.1, (0, 0, 0), touching)
    assert not cell_intersects_box((1, -1, 0), 8, 0.1, (0, 0, 0), away)


def test_the_preview_is_each_tiles_level_1(tiled):
    _, res = tiled
    full = decode_stream(res.data).scene
    prev = decode_stream(res.data, max_level=1)
    assert prev.preview and not prev.hash_checked
    _, index = _index(res.data)
    starts = np.cumsum([0] + [x + 1 for x in index.tile_num_points_minus1])
    rows = np.concatenate([starts[t] + build_hierarchy(full.coords[starts[t]:starts[t + 1]], 4).level1_idx
                           for t in range(index.num_tiles)])
    assert np.array_equal(prev.scene.coords, full.coords[rows])
    assert np.array_equal(prev.scene.offsets, full.offsets[rows])


def test_tiles_cost_little_on_a_procedural_scene():
    """Tiling a 30k-anchor scene into ~8 tiles costs under 1% of its bytes (here it saves: each
    tile's prior fits its own part of the scene). Real scenes: tools/results/tiles.md."""
    from lghcc.formats.procedural import make_procedural_scene

    scene = make_procedural_scene(30000, seed=2)
    untiled = len(_encode(scene, tile_points=0).data)
    tiled_ = _encode(scene, tile_points=4000)
    assert tiled_.stats.num_tiles >= 4
    assert len(tiled_.data) <= 1.01 * untiled


def _die(args):
    os._exit(9)  # a worker killed: no result, no exception to pickle


def test_a_worker_that_dies_is_an_error_and_nothing_is_written(tiled, tmp_path, monkeypatch):
    """lghcc-dec --jobs 2 with a worker killed: a one-line error, exit status 1, no output folder."""
    from lghcc.decoder import cli

    _, res = tiled
    stream = tmp_path / "s.lghcc"
    stream.write_bytes(res.data)
    monkeypatch.setattr(decode_mod, "_decode_tile_job", _die)
    monkeypatch.setattr(jobs_mod, "WORKER_START_S", 0.0)  # workers that cost nothing always pay
    monkeypatch.setattr(jobs_mod, "TASK_S", 0.0)
    out = tmp_path / "out"
    assert cli.main([str(stream), "-o", str(out), "--jobs", "2", "-q"]) == 1
    assert not out.exists()


@pytest.mark.parametrize("argv, fragment", [
    (["--jobs", "0"], "--jobs: must be at least 1"),
    (["--box", "1,2,3"], "expected six numbers"),
    (["--box", "0,0,0,1,1,x"], "expected six numbers"),
    (["--box", "1,0,0,0,1,1"], "minimum is above its maximum on x"),
    (["--box", "0,0,0,1,1,inf"], "must be finite"),
    (["--level", "3"], "invalid choice"),
])
def test_bad_partial_decode_options_are_usage_errors(tiled, tmp_path, capsys, argv, fragment):
    from lghcc.decoder import cli

    stream = tmp_path / "s.lghcc"
    stream.write_bytes(tiled[1].data)
    with pytest.raises(SystemExit) as e:
        cli.main([str(stream), "-o", str(tmp_path / "o")] + argv)
    assert e.value.code == 2 and fragment in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_negative_box_corner_needs_no_equals_sign(tiled, tmp_path, capsys):
    from lghcc.decoder import cli

    stream = tmp_path / "s.lghcc"
    stream.write_bytes(tiled[1].data)
    assert cli.main([str(stream), "--box", "-0.5,-0.5,-0.5,-0.1,-0.1,-0.1"]) == 0
    assert "box: decoded" in capsys.readouterr().out


def test_a_box_that_meets_no_tile_decodes_to_the_empty_scene(tmp_path, capsys):
    """Clause 13.3: the empty scene (its hash is test.yaml's); lghcc-dec has nothing to write and says why."""
    import yaml

    from lghcc.conformance import STREAMS_DIR
    from lghcc.decoder import cli

    folder = STREAMS_DIR / "c086_step_adjust_tiles"
    part = next(p for p in yaml.safe_load((folder / "test.yaml").read_text())["partial_decodes"] if not p["tiles"])
    box = "--box=" + ",".join(repr(float(x)) for x in part["box"])
    assert cli.main([str(folder / "stream.lghcc"), box, "--print-hash"]) == 0
    assert capsys.readouterr().out.split()[-1] == part["decoded_sha256"]
    assert cli.main([str(folder / "stream.lghcc"), box, "-o", str(tmp_path / "x.ply")]) == 1
    assert "meets none of the stream's 8 tiles" in capsys.readouterr().err and not (tmp_path / "x.ply").exists()
