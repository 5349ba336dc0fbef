"""lghcc-batch: the sweep file's checks, the per-cell work, resuming, failures, the report; on
a local Ray instance (skipped without ray) and serially (--local, no Ray)."""

import json
import socket
import time
from pathlib import Path

import pytest

from lghcc.batch import cli as batch_cli
from lghcc.batch.runner import check_reachable, ClusterError, parse_address
from lghcc.batch.sweep import SweepError, load_sweep

SMALL = "evaluation: {views: 2, size: 48x48}\n"


def _sweep(tmp_path: Path, body: str, name: str = "sweep.yaml") -> Path:
    f = tmp_path / name
    f.write_text(body)
    return f


def _records(out: Path) -> dict:
    return {r["cell"]: r for r in json.loads((out / "results.json").read_text())}


def _broken_ply(tmp_path: Path) -> Path:
    """Exists (so the sweep file is accepted) but cannot be read: its cells fail when run."""
    p = tmp_path / "broken.ply"
    p.write_text("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nend_header\n")
    return p


# --- the sweep file -----------------------------------------------------------------------------

@pytest.mark.parametrize("body, message", [
    ("scenes: [{name: a, procedural: 10}]\npresetz: [low]\n", "unknown key 'presetz'"),
    ("scenes: [{name: a, procedural: 10, sede: 1}]\n", "unknown key 'scenes[0].sede'"),
    ("scenes: [{name: a, procedural: 10}]\nevaluation: {view: 3}\n", "unknown key 'evaluation.view'"),
    ("scenes: [{name: a, procedural: 10}]\nencoder: {feature_stepp: 0.1}\n", "unknown key 'encoder.feature_stepp'"),
    ("scenes: [{name: a, procedural: 10}]\npresets: [ultra]\n", "unknown preset 'ultra'"),
    ("scenes: [{name: a, procedural: 10}]\nlambdas: [0.01]\n", "no scene is trained"),
    ("scenes: [{name: a, procedural: 10}, {name: a, procedural: 20}]\n", "'a' is used twice"),
    ("scenes: [{name: 'a/b', procedural: 10}]\n", "name must be"),
    ("scenes: [{name: a, procedural: 10, path: x.ply}]\n", "exactly one of path, procedural, train"),
    ("scenes: [{name: a, train: imgs, train_options: {data: x}}]\n", "unknown key 'scenes[0].train_options.data'"),
    ("scenes: []\n", "scenes must be a non-empty list"),
    ("scenes: [{name: a, procedural: 10}]\nencoder: {feature_step: -1}\n", "feature_step must be a positive"),
    ("", "the sweep file is empty"),
    ("scenes: [\n", "not valid YAML"),
])
def test_bad_sweep_files_are_refused_before_any_work(tmp_path, capsys, body, message):
    (tmp_path / "imgs").mkdir()
    f = _sweep(tmp_path, body)
    assert batch_cli.main([str(f), "--local"]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "sweep_results").exists()


def test_missing_scenes_are_all_named(tmp_path, capsys):
    f = _sweep(tmp_path, "scenes:\n  - {name: a, path: nowhere/a.ply}\n  - {name: b, procedural: 10}\n"
                         "  - {name: c, train: no_images}\n")
    assert batch_cli.main([str(f)]) == 1  # no Ray needed to say so: checked before it starts
    err = capsys.readouterr().err
    assert "2 scenes not found" in err and "a: " in err and "nowhere/a.ply" in err and "no_images" in err


def test_paths_are_relative_to_the_sweep_file(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "s.ply").write_text("x")
    sw = load_sweep(_sweep(tmp_path / "sub", "scenes: [{name: s, path: s.ply, up: '0,-1,0'}]\noutput: out\n"))
    assert sw.scenes["s"].path == str((tmp_path / "sub" / "s.ply").resolve()) and sw.scenes["s"].up == (0, -1, 0)
    assert sw.output == (tmp_path / "sub" / "out").resolve() or sw.output == tmp_path / "sub" / "out"
    with pytest.raises(SweepError, match="up must be three numbers"):
        load_sweep(_sweep(tmp_path, "scenes: [{name: s, procedural: 5, up: [0, 0]}]\n"))


# --- running: serially (--local) ---------------------------------------------------------------

def test_local_run_resumes_and_survives_a_failed_cell(tmp_path, capsys):
    _broken_ply(tmp_path)
    f = _sweep(tmp_path, "scenes:\n  - {name: a, procedural: 120, seed: 1}\n  - {name: bad, path: broken.ply}\n"
                         "presets: [low, high]\n" + SMALL)
    out = tmp_path / "sweep_results"
    assert batch_cli.main([str(f), "--local"]) == 2  # a failed cell: non-zero, after all others ran
    io = capsys.readouterr()
    assert "[1/4]" in io.out and "[4/4]" in io.out and "bad__low: FAILED" in io.out
    assert "2 of 4" in io.err and "bad__low, bad__high" in io.err
    rec = _records(out)
    assert rec["a__low"]["status"] == rec["a__high"]["status"] == "ok"
    assert rec["a__high"]["bytes"] > rec["a__low"]["bytes"] and rec["a__high"]["psnr"] > rec["a__low"]["psnr"] > 20
    assert (out / "streams" / "a__low.lghcc").stat().st_size == rec["a__low"]["bytes"]
    assert rec["bad__low"]["status"] == "failed" and "truncated" in rec["bad__low"]["error"]
    md = (out / "results.md").read_text()
    assert "| a | — | low |" in md and "**failed**" in md and "- bad__high: preparing bad failed" in md
    assert "Rate-distortion plots" in md  # a plot, or the reason there is none
    # resume: the finished cells are not run again; the failed ones are retried (and fail again)
    mtime = (out / "streams" / "a__low.lghcc").stat().st_mtime_ns
    assert batch_cli.main([str(f), "--local"]) == 2
    assert "2 already done, 2 to run" in capsys.readouterr().out
    assert (out / "streams" / "a__low.lghcc").stat().st_mtime_ns == mtime
    # with the broken scene fixed (here: removed) the sweep finishes; nothing is redone
    f.write_text("scenes:\n  - {name: a, procedural: 120, seed: 1}\npresets: [low, high]\n" + SMALL)
    assert batch_cli.main([str(f), "--local"]) == 0
    assert "2 already done, 0 to run" in capsys.readouterr().out
    # other evaluation settings: other results, so the cells run again
    f.write_text("scenes:\n  - {name: a, procedural: 120, seed: 1}\npresets: [low]\n"
                 "evaluation: {views: 1, size: 32x32}\n")
    assert batch_cli.main([str(f), "--local", "-q"]) == 0
    assert _records(out)["a__low"]["psnr_views"].__len__() == 1


def test_trained_scenes_run_once_per_lambda(tmp_path, capsys):
    from test_train import make_dataset

    make_dataset(tmp_path / "imgs", n_train=4, n_test=1)
    f = _sweep(tmp_path, "scenes:\n  - name: t\n    train: imgs\n    train_options: {iterations: 10, feature_dim: 8, "
                         "num_offsets: 3, init_points: 200, eval_interval: 1000, checkpoint_interval: 1000, "
                         "stats_from: 2, densify_from: 4, densify_until: 6, densify_interval: 2, rate_from: 7}\n"
                         "lambdas: [0, 0.01]\npresets: [low, medium]\n" + SMALL)
    assert batch_cli.main([str(f), "--local"]) == 0
    text = capsys.readouterr().out
    assert text.count("prepared t__lam") == 2  # trained once per lambda, not per preset
    rec = _records(tmp_path / "sweep_results")
    assert set(rec) == {"t__lam0__low", "t__lam0__medium", "t__lam0.01__low", "t__lam0.01__medium"}
    assert all(r["status"] == "ok" for r in rec.values())
    assert (tmp_path / "sweep_results" / "prepared" / "t__lam0.01.tar").is_file()


def test_dry_run_lists_the_cells(tmp_path, capsys):
    f = _sweep(tmp_path, "scenes: [{name: a, procedural: 10}]\npresets: [low, medium]\n")
    assert batch_cli.main([str(f), "--dry-run"]) == 0
    assert capsys.readouterr().out.split("\n")[:2] == ["a__low: to run", "a__medium: to run"]
    assert not (tmp_path / "sweep_results").exists()


# --- the cluster's address ---------------------------------------------------------------------

def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_an_unreachable_cluster_is_named_before_any_work(tmp_path, capsys):
    f = _sweep(tmp_path, "scenes: [{name: a, procedural: 10}]\n")
    addr = f"127.0.0.1:{_closed_port()}"
    t0 = time.perf_counter()
    assert batch_cli.main([str(f), "--address", addr, "--connect-timeout", "3"]) == 1
    err = capsys.readouterr().err
    assert "Ray cluster" in err and addr in err and err.count("\n") == 1
    assert time.perf_counter() - t0 < 10 and not (tmp_path / "sweep_results").exists()


def test_addresses():
    assert parse_address("10.0.0.5:6379") == ("10.0.0.5", 6379)
    assert parse_address("ray://head.local:10001") == ("head.local", 10001)
    assert parse_address("auto") is None
    for bad in ("10.0.0.5", "host:port", ":6379", "h:70000"):
        with pytest.raises(ClusterError, match="expected host:port"):
            parse_address(bad)
    with pytest.raises(ClusterError, match=r"Ray cluster\b"):
        check_reachable(f"127.0.0.1:{_closed_port()}", 2.0)


# --- on Ray ------------------------------------------------------------------------------------

@pytest.mark.integration
def test_sweep_on_local_ray(tmp_path, capsys):
    """Two small scenes x two presets and a broken scene on a local Ray instance (2 CPUs):
    the cells run as Ray tasks, the broken scene's cells fail without losing the others."""
    pytest.importorskip("ray", reason="ray is not installed (pip install 'lghcc[batch]')")
    _broken_ply(tmp_path)
    f = _sweep(tmp_path, "scenes:\n  - {name: a, procedural: 120, seed: 1}\n  - {name: b, procedural: 150, seed: 2}\n"
                         "  - {name: bad, path: broken.ply}\npresets: [low, high]\n" + SMALL)
    t0 = time.perf_counter()
    assert batch_cli.main([str(f), "--num-cpus", "2"]) == 2
    elapsed = time.perf_counter() - t0
    out = capsys.readouterr().out
    assert "Ray: local, 2 CPUs" in out and "[6/6]" in out
    rec = _records(tmp_path / "sweep_results")
    ok = {k for k, r in rec.items() if r["status"] == "ok"}
    assert ok == {"a__low", "a__high", "b__low", "b__high"}
    assert {r["pid"] for k, r in rec.items() if k in ok} - {__import__("os").getpid()}, "ran in this process"
    assert rec["bad__high"]["error"].startswith("preparing bad failed")
    print(f"lghcc-batch on local Ray: {elapsed:.1f} s")
