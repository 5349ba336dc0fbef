"""Decoder options that must pay (issue 38): --jobs auto hands tiles to workers only where the
cost model says it pays and --jobs N is an upper bound; a box decode does no work for the tiles
it does not select; --level 1 on a stream without the hierarchy is refused; the render MLPs are
written as a checkpoint torch reads, without importing torch. Timings: tools/bench_decode.py."""

import io

import numpy as np
import pytest

from lghcc.app.cli_common import EXIT_USAGE
from lghcc.common.errors import UsageError
from lghcc.common.tiles import Box
from lghcc.decoder import cli
from lghcc.decoder import core as decode_core
from lghcc.decoder.decode import decode_stream, parse_stream, selected_tiles, worker_plan
from lghcc.decoder.jobs import VALUE_S, makespan, plan_workers, tile_seconds
from lghcc.encoder.stream.config import EncoderConfig
from lghcc.encoder.stream.encode import encode_scene

from scenes import random_scene


@pytest.fixture(scope="module")
def flat():
    """A tiled stream without the hierarchy (the default anchor presets' tools)."""
    scene = random_scene(np.random.default_rng(5), 2000, spread=60, mask=True)
    return encode_scene(scene, EncoderConfig(tile_points=250))


def test_small_or_cheap_tiles_stay_in_one_process():
    cheap = [tile_seconds(2000, 86, "per-channel prior")] * 8  # 16k points of the medium preset
    assert plan_workers(cheap, 2, "auto").workers == 1
    assert plan_workers([tile_seconds(300, 86, "GG-Conv")] * 8, 2, "auto").workers == 1  # small tiles
    assert plan_workers([5.0], 2, "auto").workers == 1  # one tile: nothing to share


def test_costly_tiles_go_to_workers_and_the_bound_holds():
    costly = [tile_seconds(12_000, 86, "GG-Conv")] * 90  # the 1M-anchor GG-Conv stream of tiles.md
    assert plan_workers(costly, 2, "auto").workers == 2
    assert plan_workers(costly, 1, "--jobs 1").workers == 1
    for bound in (2, 3, 4):
        plan = plan_workers(costly, bound, f"--jobs {bound}")
        assert 2 <= plan.workers <= bound and f"{plan.workers} worker processes" in plan.reason
    assert plan_workers(costly[:3], 8, "auto").workers <= 3  # never more workers than tiles


def test_the_decision_follows_the_coding_tool():
    """The same tiles pay in workers with GG-Conv sooner than with the per-channel prior."""
    assert min(VALUE_S["GG-Conv"], VALUE_S["neighbour prediction"]) > VALUE_S["per-channel prior"]
    n = next(n for n in range(1000, 200_000, 1000) if plan_workers([tile_seconds(n, 86, "GG-Conv")] * 8, 2,
                                                                   "auto").workers == 2)
    assert plan_workers([tile_seconds(n, 86, "per-channel prior")] * 8, 2, "auto").workers == 1


def test_makespan_deals_the_largest_first():
    assert makespan([2, 3, 2, 3, 2], 2) == 7  # 3+2+2 | 3+2: the pool's order, not the best split (6)
    assert makespan([1.0] * 4, 1) == 4.0 and makespan([5.0, 1.0], 4) == 5.0


def test_auto_decodes_a_small_stream_in_one_process_and_says_why(flat, tmp_path, capsys):
    res = decode_stream(flat.data, jobs=None)
    assert res.num_tiles > 2 and res.workers.workers == 1 and "1 process" in res.workers.reason
    stream = tmp_path / "s.lghcc"
    stream.write_bytes(flat.data)
    assert cli.main([str(stream)]) == 0
    assert "workers: 1 process" in capsys.readouterr().out


def test_an_explicit_job_count_is_an_upper_bound(flat, monkeypatch):
    s = parse_stream(flat.data)
    sel = selected_tiles(s.tiles, s.ps, None)
    monkeypatch.setattr("lghcc.decoder.jobs.WORKER_START_S", 0.0)  # workers that cost nothing: as many as allowed
    monkeypatch.setattr("lghcc.decoder.jobs.TASK_S", 0.0)
    for jobs in (1, 2, 3):
        plan = worker_plan(s.tiles, sel, s.ps, s.layout, s.context_model, jobs=jobs)
        assert plan.workers == min(jobs, len(sel))
    res = decode_stream(flat.data, jobs=2)
    assert res.workers.workers == 2 and res.stream_hash == flat.scene_hash


def test_a_box_decodes_no_tile_it_does_not_select(flat, monkeypatch):
    full = decode_stream(flat.data)
    geometry, tiles = [], []
    real_geometry, real_tile = decode_core.decode_geometry, decode_core.decode_tile
    monkeypatch.setattr(decode_core, "decode_geometry", lambda p, n, e=None: geometry.append(n) or real_geometry(p, n, e))
    monkeypatch.setattr(decode_core, "decode_tile", lambda tile, t, *a, **k: tiles.append(t) or real_tile(tile, t, *a,
                                                                                                          **k))
    pts = full.scene.positions()
    lo = pts.min(axis=0)
    box = Box(tuple(lo), tuple(lo + 0.01))
    part = decode_stream(flat.data, box=box, jobs=1)
    assert 1 <= part.tiles_decoded < part.num_tiles
    assert len(tiles) == len(geometry) == part.tiles_decoded
    assert sum(geometry) == part.scene.num_anchors < full.scene.num_anchors


def test_level_1_without_the_hierarchy_is_refused(flat, tmp_path, capsys):
    with pytest.raises(UsageError, match="no level-1 preview"):
        decode_stream(flat.data, max_level=1)
    stream = tmp_path / "s.lghcc"
    stream.write_bytes(flat.data)
    out = tmp_path / "out"
    assert cli.main([str(stream), "-o", str(out), "--level", "1"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "without the hierarchy" in err and not out.exists()


def test_help_says_what_the_tile_options_do_by_stream_kind(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for fragment in ("--jobs auto", "GG-Conv", "has no preview", "exit status 2", "any kind of stream"):
        assert fragment in text


def test_the_checkpoint_is_what_torch_reads_and_writes():
    import torch

    from lghcc.formats.torch_checkpoint import checkpoint_bytes

    rng = np.random.default_rng(1)
    state = {"mlp_opacity": {"0.weight": rng.normal(size=(32, 36)).astype(np.float32),
                             "0.bias": rng.normal(size=32).astype(np.float32)},
             "mlp_color": {"2.weight": rng.normal(size=(30, 32)), "2.bias": np.arange(3, dtype=np.int64)}}
    got = torch.load(io.BytesIO(checkpoint_bytes(state)), weights_only=True)
    ref = io.BytesIO()
    torch.save({n: {k: torch.from_numpy(a) for k, a in sd.items()} for n, sd in state.items()}, ref)
    want = torch.load(io.BytesIO(ref.getvalue()), weights_only=True)
    assert got.keys() == want.keys()
    for n in state:
        for k in state[n]:
            assert got[n][k].dtype == want[n][k].dtype and torch.equal(got[n][k], want[n][k])
    with pytest.raises(ValueError, match="dtype"):
        checkpoint_bytes({"m": {"w": np.zeros(2, np.complex64)}})


def test_writing_a_decoded_anchor_scene_does_not_import_torch(tmp_path):
    import subprocess
    import sys

    from lghcc.formats.procedural import make_procedural_scene

    stream = tmp_path / "s.lghcc"
    stream.write_bytes(encode_scene(make_procedural_scene(300, seed=1), EncoderConfig()).data)
    code = ("import sys; from lghcc.decoder.cli import main; rc = main([sys.argv[1], '-o', sys.argv[2], '-q']); "
            "assert rc == 0; assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code, str(stream), str(tmp_path / "out")], check=True)
    from lghcc.formats import read_scene
    from lghcc.common.hashing import digest_of

    assert digest_of(read_scene(str(tmp_path / "out"))) == decode_stream(stream.read_bytes()).stream_hash


def test_exporting_a_decoded_3dgs_stream_does_not_import_torch(tmp_path):
    """--export-ply of an explicit-Gaussian stream needs no renderer: render/ (and with it torch,
    seconds and ~180 MiB) stays unimported, and the PLY holds the decoded scene."""
    import subprocess
    import sys

    from lghcc.common.hashing import gaussian_scene_digest
    from lghcc.common.scene import GaussianScene
    from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
    from lghcc.encoder.stream.config import GaussianEncoderConfig
    from lghcc.formats.ply3dgs import read_3dgs_ply

    rng, f = np.random.default_rng(3), np.float32
    n = 500
    scene = GaussianScene(rng.uniform(-1, 1, (n, 3)).astype(f), rng.normal(size=(n, 1, 3)).astype(f),
                          rng.normal(0, 3, n).astype(f), (-4 + rng.normal(size=(n, 3))).astype(f),
                          rng.normal(size=(n, 4)).astype(f))
    stream = tmp_path / "g.lghcc"
    stream.write_bytes(encode_gaussian_scene(scene, GaussianEncoderConfig()).data)
    out = tmp_path / "g.ply"
    code = ("import sys; from lghcc.decoder.cli import main; rc = main([sys.argv[1], '--export-ply', sys.argv[2], "
            "'-q']); assert rc == 0; assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code, str(stream), str(out)], check=True)
    decoded = decode_stream(stream.read_bytes()).scene
    back = read_3dgs_ply(out)
    assert back.num_gaussians == n
    np.testing.assert_array_equal(back.means, decoded.means)
    np.testing.assert_array_equal(back.sh, decoded.sh)
    np.testing.assert_array_equal(back.opacity, decoded.opacity)
    assert gaussian_scene_digest(decoded) == decode_stream(stream.read_bytes()).stream_hash
