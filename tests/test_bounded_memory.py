"""The encoder's bounded-memory paths (issue 53) write the streams the whole-scene paths wrote, byte
for byte: uniform sensitivities as one broadcast row, RDOQ's rows chosen in blocks, the quantized
integers carried from RDOQ to the coding (quantize once). The hashes were those of the encoder
before these paths (commit 6865211), coded without the SH transform of format 1.6 (its presets' default
since): the pinned paths are the value-domain ones; with the transform, block sizes are checked against
each other (test_blocks_do_not_change_a_stream_with_the_sh_transform)."""

import dataclasses
import hashlib

import numpy as np
import pytest

from lghcc.common.scene import GaussianScene
from lghcc.encoder.gaussians import rdoq
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.stream.config import load_config
from lghcc.encoder.stream.level_coding import narrowest_integers

# (SH degree, tile_points) -> sha256 of the `fast` stream of _scene(3000, degree)
PINNED = {
    (3, 0): "9a70f1d078c9d9a77d3975ad712e67bcf66cf9a4d60648e61c859d732f856792",
    (3, 512): "b3cb3b07c19096afc2f47c1978a682512713615b70f356bd02654b10627337d6",
    (0, 0): "5af58cf27b12b0d43960a60da70fec5e7bea293d3ca4516238363c40b776caa9",
    (0, 512): "b6243fa53fbfd853f354f57f30f105910563c935d109718c7ee24aaefe76d01b",
}


def _scene(n: int, degree: int, seed: int = 53) -> GaussianScene:
    """Gaussians along a wandering curve (neighbours alike), colours with correlated channels."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2
    sh = rng.normal(size=(n, k, 1)) + 0.1 * rng.normal(size=(n, k, 3))
    sh[:, 1:] *= 0.2
    f = np.float32
    means = np.cumsum(rng.normal(0, 0.02, size=(n, 3)), axis=0)
    return GaussianScene(means.astype(f), sh.astype(f), rng.normal(0, 3, size=n).astype(f),
                         (-4 + 0.3 * rng.normal(size=(n, 3))).astype(f), rng.normal(size=(n, 4)).astype(f))


def _fast_stream(degree: int, tile_points: int, sh_transform: bool = False) -> bytes:
    cfg = dataclasses.replace(load_config("fast", kind="gaussians"), tile_points=tile_points, sh_transform=sh_transform)
    return encode_gaussian_scene(_scene(3000, degree), cfg).data


@pytest.mark.parametrize("degree,tile_points", sorted(PINNED))
def test_fast_streams_are_those_of_the_whole_scene_paths(degree, tile_points):
    assert hashlib.sha256(_fast_stream(degree, tile_points)).hexdigest() == PINNED[degree, tile_points]


# Round 2 (the neighbour coding's fits by histogram and by block, its residuals and levels when asked
# for, ideal bits summed by block): streams of other SH degrees, and of `low`'s coding tools without its
# renders (given sensitivities: RDOQ with step adjustment and the SH degree choice), hashed at a646e2b
MORE_PINNED = {
    ("fast", 2, 0): "122b8ee0793cdf6dd28c5b7d05a87504699d3db0c36678798e7655c2f91f3905",
    ("fast", 1, 512): "28d2a5d03ce7c86821cd065a79365c55c17ca88751762fb991b9ef24b8b6206b",
    ("low", 3, 0): "7e8a0453a71adceb51fac4e40d062b4f8120e1f30e80efb9bfad0cf60bf7ab1d",
    ("low", 3, 512): "8e507aef6847a004623c1c874d0435dec4a571d727f4392311309874b4de6d7a",
    ("low", 2, 0): "8788d7918b1430da73603c85a46cac8858bc655eec36dbb831347ad59a6cf9d0",
    ("low", 1, 512): "6370acdec86786aaab7e3f5eb78973e83ee05e68e14530f32e3aa24957c60541",
}


@pytest.mark.parametrize("preset,degree,tile_points", sorted(MORE_PINNED))
def test_more_streams_are_those_before_the_coding_by_block(preset, degree, tile_points):
    from lghcc.common.attributes import GaussianLayout

    if preset == "fast":
        assert hashlib.sha256(_fast_stream(degree, tile_points)).hexdigest() == MORE_PINNED[preset, degree, tile_points]
        return
    cfg = dataclasses.replace(load_config("low", kind="gaussians"), target_psnr=0, prune_share=0,
                              tile_points=tile_points, sh_transform=False)
    f = np.random.default_rng(7).gamma(0.5, 2.0, size=(3000, GaussianLayout(degree).num_channels))
    got = encode_gaussian_scene(_scene(3000, degree), cfg, sensitivity=f)
    assert got.stats.step_adjust_counts is not None and got.stats.sh_degree_counts is not None
    assert hashlib.sha256(got.data).hexdigest() == MORE_PINNED[preset, degree, tile_points]


def test_rdoq_blocks_do_not_change_the_stream(monkeypatch):
    """Within a LoD each row's choice depends on coarser LoDs only, and each row's step-adjustment
    costs are its own: any block size, the same stream (97 rows: many blocks per LoD, the last one
    partial; `low`'s tools: step adjustment and SH degrees)."""
    monkeypatch.setattr(rdoq, "RDOQ_BLOCK_ROWS", 97)
    assert hashlib.sha256(_fast_stream(3, 0)).hexdigest() == PINNED[3, 0]
    test_more_streams_are_those_before_the_coding_by_block("low", 3, 0)


def test_coding_blocks_do_not_change_the_stream(monkeypatch):
    """The neighbour coding's blocks of rows (each row's values its own, histograms' counts the same
    however cut, ideal bits summed along numpy's cuts): any block size, the same stream."""
    from lghcc.encoder.context import code_lengths
    from lghcc.encoder.stream import neighbour_coding, prediction

    for module in (neighbour_coding, prediction):
        monkeypatch.setattr(module, "CODING_BLOCK_ROWS", 97)
    monkeypatch.setattr(code_lengths, "SUM_BLOCK_VALUES", 1000)
    for tile_points in (0, 512):  # (with tiles, the neighbour-or-prior choice compares ideal bits)
        assert hashlib.sha256(_fast_stream(3, tile_points)).hexdigest() == PINNED[3, tile_points]
    test_more_streams_are_those_before_the_coding_by_block("low", 3, 0)


def test_uniform_sensitivities_are_one_broadcast_row():
    f = rdoq.uniform_sensitivity(10 ** 9, 56)  # SH 3: 448 GB stored
    assert f.shape == (10 ** 9, 56) and f.strides[0] == 0 and rdoq.uniform(f)
    rows = rdoq.take_rows(f, np.array([5, 7, 11]))
    assert rows.shape == (3, 56) and rows.strides[0] == 0 and (rows == 1).all()
    assert rdoq.take_rows(f, slice(10, 20)).shape == (10, 56)
    sub = rdoq.sh_degree_subset(f, 1)
    assert sub.shape == (10 ** 9, 20) and rdoq.uniform(sub)
    mu = rdoq.group_slopes(f[:1000], rdoq.channel_groups(3), 2.0)
    assert np.array_equal(mu, rdoq.group_slopes(np.ones((1000, 56)), rdoq.channel_groups(3), 2.0))
    stored = np.random.default_rng(0).random((6, 4))
    assert np.array_equal(rdoq.take_rows(stored, np.array([1, 3])), stored[[1, 3]])


@pytest.mark.parametrize("lo,hi,dtype", [(-5, 7, np.int16), (-40000, 3, np.int32), (0, 1 << 40, np.int64)])
def test_quantized_integers_take_the_narrowest_dtype(lo, hi, dtype):
    q = np.array([[lo, hi], [0, 1]], dtype=np.int64)
    got = narrowest_integers(q)
    assert got.dtype == dtype and np.array_equal(got, q)


def test_sh3_content_of_the_memory_scenes_is_playbots_and_deterministic():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    import scale_scenes

    scene, playbot = _scene(50, 0, seed=1), _scene(7, 2, seed=2)
    a, b = scale_scenes.with_sh3_content(scene, playbot), scale_scenes.with_sh3_content(scene, playbot, block=16)
    assert a.sh_degree == 3 and a.sh.tobytes() == b.sh.tobytes()  # deterministic, and the same by blocks
    assert np.array_equal(a.sh[:, 0], scene.sh[:, 0])
    # each Gaussian's bands 1-2 are those of playbot's nearest Gaussian (both in unit boxes, at the
    # Gaussian's position in its grid cell), band 3 half of the second nearest's coefficients 2-8
    m = playbot.means.astype(np.float64)
    unit = (m - (m.min(0) + m.max(0)) / 2) / (m.max(0) - m.min(0)).max()
    local = scene.means.astype(np.float64)
    local[:, [0, 2]] -= np.round(local[:, [0, 2]] / scale_scenes.CELL) * scale_scenes.CELL
    order = np.argsort(((local[:, None] - unit[None]) ** 2).sum(-1), axis=1, kind="stable")
    assert np.array_equal(a.sh[:, 1:9], playbot.sh[order[:, 0], 1:9])
    assert np.array_equal(a.sh[:, 9:16], np.float32(0.5) * playbot.sh[order[:, 1], 2:9])
    # a copy of playbot in a cell gets its own bands back
    copy = type(scene)((unit + [2 * scale_scenes.CELL, 0, scale_scenes.CELL]).astype(np.float32), playbot.sh[:, :1],
                       playbot.opacity, playbot.log_scales, playbot.rotations)
    assert np.array_equal(scale_scenes.with_sh3_content(copy, playbot).sh[:, 1:9], playbot.sh[:, 1:9])


@pytest.mark.parametrize("size", [1, 7, 129, 8193, 300_001, 3 * (1 << 18) + 13, 9 * (1 << 18) + 5])
def test_pairwise_total_is_numpys_sum_to_the_last_bit(size, monkeypatch):
    """The whole-scene ideal bits summed part by part are np.sum's (a neighbour-or-prior choice
    compares them: a different order could flip a near tie)."""
    from lghcc.encoder.context import code_lengths as sc

    x = np.random.default_rng(size).random(size) * 10.0 ** np.random.default_rng(1).uniform(-3, 3, size)
    monkeypatch.setattr(sc, "SUM_BLOCK_VALUES", 1 << 10)
    assert sc.pairwise_total(size, lambda lo, hi: x[lo:hi].copy()) == float(x.sum())
    rows = x[: size - size % 7].reshape(-1, 7)
    ends = 7 * np.arange(1, rows.shape[0] + 1)
    assert sc.row_blocked_total(ends, lambda a, b: rows[a:b].ravel()) == float(rows.sum())


def test_a_whole_scene_coding_is_freed_when_dropped_after_its_ideal_bits():
    """The neighbour coding whose ideal bits were summed goes as soon as it is dropped, without a
    garbage collection (a self-calling closure in the sum once held it, and its [N, M] arrays,
    through the tiles' stage: 750 MB at 1M Gaussians of SH 3)."""
    import gc
    import weakref

    from lghcc.encoder.stream.neighbour_coding import NeighbourCoding

    rng = np.random.default_rng(5)
    coords = np.unique(rng.integers(0, 50, (3000, 3)), axis=0)
    q = rng.integers(-20, 20, (coords.shape[0], 6))
    gc.disable()
    try:
        nc = NeighbourCoding(q, coords, 4, 6, 5, False, None)
        assert nc.ideal_bits() > 0
        alive = weakref.ref(nc)
        del nc
        assert alive() is None
    finally:
        gc.enable()


def test_ideal_bits_by_rows_are_the_whole_arrays():
    from lghcc.encoder.context.code_lengths import ideal_code_length_bits, ideal_code_length_bits_by_rows

    rng = np.random.default_rng(3)
    r = rng.integers(-40, 40, size=(20000, 30)) * rng.integers(1, 200, size=(20000, 30))
    lv = rng.integers(0, 64, size=r.shape).astype(np.uint8)
    coded = rng.random(r.shape) < 0.7
    assert ideal_code_length_bits_by_rows(lambda a, b: r[a:b], lambda a, b: lv[a:b], r.shape) == \
        ideal_code_length_bits(r, lv)
    assert ideal_code_length_bits_by_rows(lambda a, b: r[a:b], lambda a, b: lv[a:b], r.shape, coded) == \
        ideal_code_length_bits(r[coded], lv[coded])


def test_residual_histograms_give_each_groups_best_level_and_bits():
    """Gathered part by part, tabled and far residuals alike: best_level_and_bits of each group's all."""
    from lghcc.common.entropy.symbol_coder import best_level_and_bits, level_and_bits
    from lghcc.encoder.context.code_lengths import ResidualHistograms

    rng = np.random.default_rng(5)
    group, r = rng.integers(0, 4, size=9000), rng.integers(-300, 300, size=9000)
    r[::997] *= 40  # beyond the code-length table
    hist = ResidualHistograms(5)
    for lo in range(0, 9000, 2500):
        hist.add(group[lo:lo + 2500], r[lo:lo + 2500])
    for g in range(4):
        assert level_and_bits(hist.bits(g)) == best_level_and_bits(r[group == g])
    assert hist.bits(4) is None and hist.best_level(4) == 0


def test_the_searchs_grid_cache_changes_no_trial(monkeypatch):
    """The settings search keeps GRID_CACHE_KEYS (pruning share, position step) grids, not every one it
    tried: a grid made again is the same, so every trial (settings, error, bits) and the choice are those
    of keeping one (grids made again) or all of them (each made once). SH degree 1: the cache does not
    depend on the degree, and the search takes a quarter of an SH-3 scene's time."""
    from lghcc.encoder.gaussians import gaussian_rd
    from lghcc.encoder.gaussians.gaussian_fit import prepare_gaussians

    small = {"target_psnr": 35.0, "search_views": 2, "search_resolution": 32, "fit_views": 2, "fit_resolution": 32,
             "fit_iterations": 0, "search_reference_gaussians": 0, "resolve_px": 0.0, "step_adjust_max": 7,
             "landing_views": 0, "check_views": 0}
    scene = _scene(600, 1)
    cfg = dataclasses.replace(load_config("medium", kind="gaussians"), **small)
    real_make, real_eval = gaussian_rd.SettingsSearch._make_grid, gaussian_rd.SettingsSearch.evaluate

    def search(n: int):
        made, trials = [], []
        monkeypatch.setattr(gaussian_rd, "GRID_CACHE_KEYS", n)
        monkeypatch.setattr(gaussian_rd.SettingsSearch, "_make_grid",
                            lambda self, *k: made.append(k) or real_make(self, *k))
        monkeypatch.setattr(gaussian_rd.SettingsSearch, "evaluate",
                            lambda self, c: trials.append(real_eval(self, c)) or trials[-1])
        prepared = prepare_gaussians(scene, cfg)
        return prepared.cfg, [(t.cfg, t.mse, t.bits) for t in trials], made

    cfg_a, trials_a, made_a = search(gaussian_rd.GRID_CACHE_KEYS)
    assert len(trials_a) > 10
    for keys in (1, 1000):
        cfg_b, trials_b, made_b = search(keys)
        assert cfg_a == cfg_b and trials_a == trials_b, keys
        assert set(made_b) == set(made_a), keys  # the same grids tried
        if keys == 1:
            assert len(made_b) > len(set(made_b))  # one kept: some grid made again
        else:
            assert len(made_b) == len(set(made_b)) <= len(made_a)  # all kept: each grid made once


def test_blocks_do_not_change_a_stream_with_the_sh_transform(monkeypatch):
    """With the SH transform (format 1.6, the presets' default), RDOQ's and the coding's blocks of rows
    still change no byte: the stream at small blocks is the stream at the default ones, and it uses
    the transform (its sh_transform unit is in the stream)."""
    from lghcc.common.container import UnitType, read_container
    from lghcc.encoder.context import code_lengths
    from lghcc.encoder.stream import neighbour_coding, prediction

    whole = _fast_stream(3, 512, sh_transform=True)
    assert any(u.unit_type == UnitType.SH_TRANSFORM for u in read_container(whole).units)
    monkeypatch.setattr(rdoq, "RDOQ_BLOCK_ROWS", 97)
    for module in (neighbour_coding, prediction):
        monkeypatch.setattr(module, "CODING_BLOCK_ROWS", 97)
    monkeypatch.setattr(code_lengths, "SUM_BLOCK_VALUES", 1000)
    assert _fast_stream(3, 512, sh_transform=True) == whole

