"""Smoke runs of the maintained tools in tools/ that no other test runs (tools/README.md names the
test or Makefile target of each tool): each on a tiny input, in seconds, writing under tmp_path
rather than tools/results/. They check that a tool runs to its end on today's code and writes its
table with one row per case asked, not what its numbers are (integration tier: the tools start
several Python and Node processes)."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lghcc.app.cli_common import EXIT_OK, EXIT_RESOURCE_LIMIT

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.integration


def _tool(name: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    r = subprocess.run([sys.executable, str(ROOT / "tools" / name), *args], capture_output=True, text=True,
                       env=env, cwd=cwd, timeout=600)
    assert r.returncode == EXIT_OK, f"{name} {' '.join(args)} exited {r.returncode}:\n{r.stderr[-3000:]}"
    return r


def _rows(text: str, first_cell: str) -> list[list[str]]:
    """The markdown table rows of ``text`` whose first cell is ``first_cell``, as lists of cells."""
    rows = [[c.strip() for c in ln.strip().strip("|").split("|")] for ln in text.splitlines() if ln.startswith("|")]
    return [r for r in rows if r[0] == first_cell]


def test_bench_codec(tmp_path):
    out = tmp_path / "codec.md"
    _tool("bench_codec.py", "--sizes", "300", "--threads", "1", "--out", str(out), cwd=tmp_path)
    (row,) = _rows(out.read_text(), "300")
    assert int(row[1].replace(",", "")) > 0  # bytes
    assert float(row[8]) > 0  # decode_stream peak RSS MB


def test_bench_decode_with_calibration(tmp_path):
    out = tmp_path / "decode.md"
    _tool("bench_decode.py", "--kinds", "low", "gaussians-medium", "--sizes", "1000", "--repeats", "1",
          "--calibrate", "--cache", str(tmp_path / "cache"), "--out", str(out), cwd=tmp_path)
    text = out.read_text()
    for kind in ("low", "gaussians-medium"):
        decoded = [r for r in _rows(text, kind) if r[1] == "1,000" and r[5] == "1,000"]
        assert len(decoded) == 3, text  # --jobs 1, 2 workers forced, --jobs auto (--level 1 is refused)
    # --calibrate: the worker start and one row per stream, timed
    assert "Worker start (fork" in text
    assert len(_rows(text, "low, 1,000")) == 1 and len(_rows(text, "gaussians-medium, 1,000")) == 1


def test_bench_presets(tmp_path):
    out = tmp_path / "presets.md"
    _tool("bench_presets.py", "--procedural", "300", "--presets", "low", "--views", "1", "--size", "32",
          "--out", str(out), cwd=tmp_path)
    (row,) = _rows(out.read_text(), "low")
    assert int(row[1].replace(",", "")) > 0 and float(row[5]) > 20  # bytes; render PSNR dB


def test_bench_speed(tmp_path, shared_data):
    out = tmp_path / "speed.md"
    _tool("bench_speed.py", "--scene", str(shared_data / "donut" / "donut.ply"), "--gaussians", "300",
          "--presets", "fast,low", "--out", str(out), cwd=tmp_path)
    text = out.read_text()
    fast, low = _rows(text, "fast"), _rows(text, "low")
    assert len(fast) == 1 and len(low) == 1
    assert int(low[0][4]) > 0  # the settings search ran trials at low (none at fast)


def test_bench_render(tmp_path, shared_data):
    out = tmp_path / "render.md"
    _tool("bench_render.py", "--sizes", "1000", "--size", "64", "--repeat", "1", "--anchors", "300", "--views", "1",
          "--lego", str(shared_data / "lego" / "lego_100"), "--out", str(out), cwd=tmp_path)
    text = out.read_text()
    (raster,) = _rows(text, "1,000")
    assert raster[-1] == "yes"  # gradients finite
    assert len(_rows(text, "lego test cameras")) == 4 and len(_rows(text, "close-ups (25% distance)")) == 4


def test_forge_stream_is_refused_by_the_memory_bound(tmp_path):
    """The issue-14 stream (2^21 anchors x 1024 channels, 8 GiB of attributes in about 2 kB) is
    refused by lghcc-dec's memory bound; a small forged stream with its exact hash decodes."""
    from lghcc.decoder import cli as dec_cli

    _tool("forge_stream.py", "-o", str(tmp_path / "big.lghcc"), cwd=tmp_path)
    assert (tmp_path / "big.lghcc").stat().st_size < 4096
    assert dec_cli.main([str(tmp_path / "big.lghcc"), "-o", str(tmp_path / "big"), "-q"]) == EXIT_RESOURCE_LIMIT
    _tool("forge_stream.py", "-o", str(tmp_path / "small.lghcc"), "--side", "4", "--feature-dim", "10",
          "--exact-hash", cwd=tmp_path)
    report = tmp_path / "small.json"
    assert dec_cli.main([str(tmp_path / "small.lghcc"), "-o", str(tmp_path / "small"), "-q",
                         "--json", str(report)]) == EXIT_OK
    got = json.loads(report.read_text())
    assert got["num_anchors"] == 4 ** 3 and got["hash_checked"] is True


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not on the PATH")
def test_bench_js_decoder(tmp_path):
    stream = ROOT / "conformance" / "streams" / "c085_step_adjust" / "stream.lghcc"
    r = _tool("bench_js_decoder.py", "--stream", str(stream), "--repeat", "1", "--out", str(tmp_path / "js"),
              cwd=tmp_path)
    (row,) = _rows(r.stdout, "stream.lghcc")
    assert int(row[1]) > 0 and int(row[2]) == stream.stat().st_size  # Gaussians, bytes
    assert float(row[3]) > 0  # Node seconds


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not on the PATH")
def test_bench_js_stream(tmp_path):
    stream = ROOT / "conformance" / "streams" / "c078_neighbour_prediction_tiles" / "stream.lghcc"
    out = tmp_path / "js_stream.md"
    _tool("bench_js_stream.py", str(stream), "--rate", "50", "--repeat", "1", "--out", str(out), cwd=tmp_path)
    rows = _rows(out.read_text(), "stream.lghcc")
    assert [r[2] for r in rows] == ["Node decode(url), whole", "Node stream(url, {camera})"]
    assert all(int(r[1].replace(",", "")) == stream.stat().st_size for r in rows)  # bytes


def _sh_ply(tmp_path: Path, n: int = 400, degree: int = 2) -> Path:
    """A tiny 3DGS PLY with an SH rest whose colour channels are correlated (the SH transform pays)."""
    import numpy as np

    from lghcc.common.scene import GaussianScene
    from lghcc.formats.ply3dgs import write_3dgs_ply

    rng = np.random.default_rng(5)
    base = rng.normal(size=(n, (degree + 1) ** 2, 1)) * 0.3
    sh = (base * np.array([1.0, 0.8, 0.6]) + rng.normal(size=(n, (degree + 1) ** 2, 3)) * 0.02).astype(np.float32)
    scene = GaussianScene(rng.normal(size=(n, 3)).astype(np.float32), sh, rng.normal(1.0, 1.0, n).astype(np.float32),
                          (np.full((n, 3), -2.5) + rng.normal(0, 0.3, (n, 3))).astype(np.float32),
                          rng.normal(size=(n, 4)).astype(np.float32))
    path = tmp_path / "sh.ply"
    write_3dgs_ply(path, scene)
    return path


def _encode(ply: Path, out: Path, *args: str) -> Path:
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    r = subprocess.run([sys.executable, "-m", "lghcc.encoder.cli", str(ply), "-o", str(out), "-y", "-q", *args],
                       capture_output=True, text=True, env=env, timeout=600)
    assert r.returncode == EXIT_OK, r.stderr[-3000:]
    return out


def test_sh_rest_error_and_trace_encoder_memory(tmp_path):
    ply = _sh_ply(tmp_path)
    trace = _tool("trace_encoder_memory.py", str(ply), "-o", str(tmp_path / "a.lghcc"), "-y", "--preset", "fast",
                  cwd=tmp_path)
    assert "peak" in trace.stdout.lower() and (tmp_path / "a.lghcc").stat().st_size > 0
    other = _encode(ply, tmp_path / "b.lghcc", "--preset", "low")
    r = _tool("sh_rest_error.py", str(ply), str(tmp_path / "a.lghcc"), str(other), cwd=tmp_path)
    rows = [ln for ln in r.stdout.splitlines() if ln.startswith("|") and ".lghcc" in ln]
    assert len(rows) == 2, r.stdout


def test_bench_sh_transform(tmp_path):
    out = tmp_path / "sh_transform.md"
    _tool("bench_sh_transform.py", str(_sh_ply(tmp_path)), "--presets", "low", "--factors", "1", "--threads", "1",
          "--out", str(out), cwd=tmp_path)
    text = out.read_text()
    assert len(_rows(text, "low")) == 3, text  # without and with at x 1, and with at the PSNR of without


@pytest.mark.skipif(shutil.which("node") is None, reason="node (Node.js) is not on the PATH")
def test_bench_js_pair(tmp_path):
    streams = ROOT / "conformance" / "streams"
    a, b = (streams / s / "stream.lghcc" for s in ("c032_gaussians_sh0", "c113_sh_transform"))
    r = subprocess.run(["node", str(ROOT / "tools" / "bench_js_pair.mjs"), str(a), str(b), "--rounds", "1"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["gaussiansA"] > 0 and result["gaussiansB"] > 0 and result["ratio"] > 0


@pytest.mark.skipif(shutil.which("node") is None, reason="node (Node.js) is not on the PATH")
@pytest.mark.skipif(not (ROOT / "tools" / "node" / "node_modules" / "@playcanvas" / "splat-transform").is_dir(),
                    reason="splat-transform is not installed in tools/node (make node-tools)")
def test_bench_js_spz(tmp_path):
    """The JavaScript decoder beside splat-transform's SPZ reader: a conformance stream and the SPZ of
    its decoded scene (lghcc's SPZ writer), both decoded whole, the same Gaussians counted."""
    from lghcc.decoder.decode import decode_stream
    from lghcc.formats.spz import write_spz

    stream = ROOT / "conformance" / "streams" / "c033_gaussians_sh3_prediction" / "stream.lghcc"
    scene = decode_stream(stream.read_bytes()).scene
    write_spz(tmp_path / "scene.spz", scene)
    other = ROOT / "conformance" / "streams" / "c032_gaussians_sh0" / "stream.lghcc"  # --also: another stream
    r = subprocess.run(["node", str(ROOT / "tools" / "bench_js_spz.mjs"), str(stream), str(tmp_path / "scene.spz"),
                        "--rounds", "1", "--also", str(other)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["lghcc"]["gaussians"] == result["spz"]["gaussians"] == scene.num_gaussians
    assert result["ratio"] > 0
    also = result["also"][str(other)]
    assert also["gaussians"] == decode_stream(other.read_bytes()).scene.num_gaussians
    assert also["bytes"] == other.stat().st_size and also["speedup"] > 0 and also["ratio"] > 0


@pytest.mark.skipif(shutil.which("node") is None, reason="node (Node.js) is not on the PATH")
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="bench_js_memory.mjs reads /proc (Linux)")
@pytest.mark.skipif(not (ROOT / "tools" / "node" / "node_modules" / "@playcanvas" / "splat-transform").is_dir(),
                    reason="splat-transform is not installed in tools/node (make node-tools)")
def test_bench_js_memory(tmp_path):
    """A decode's peak memory against its arrays, lghcc in one thread and with helpers and SPZ's reader: every
    measurement counts the scene's Gaussians, its arrays' bytes are 4 per value, and the peak covers them."""
    from lghcc.decoder.decode import decode_stream
    from lghcc.formats.spz import write_spz

    stream = ROOT / "conformance" / "streams" / "c033_gaussians_sh3_prediction" / "stream.lghcc"
    scene = decode_stream(stream.read_bytes()).scene
    write_spz(tmp_path / "scene.spz", scene)
    r = subprocess.run(["node", str(ROOT / "tools" / "bench_js_memory.mjs"), str(stream), str(tmp_path / "scene.spz"),
                        "--workers", "0,2", "--json"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [json.loads(ln) for ln in r.stdout.strip().splitlines()]
    assert [(row["kind"], row["workers"]) for row in rows] == [("lghcc", 0), ("lghcc", 2), ("spz", 0)]
    values = 3 + 3 + 4 + 1 + 3 * (scene.sh_degree + 1) ** 2  # positions, scales, rotations, opacity, SH
    for row in rows:
        assert row["count"] == scene.num_gaussians
        assert row["arraysBytes"] == 4 * values * scene.num_gaussians
        assert row["peak"] >= row["rssBefore"] > 0 and row["decodePeak"] == row["peak"] - row["rssBefore"]
    bad = subprocess.run(["node", str(ROOT / "tools" / "bench_js_memory.mjs"), str(stream), "--workers", "x"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--workers" in bad.stderr


def test_bench_web_choices(tmp_path, shared_data):
    """A scene at fast with variants of its settings: one stream and row each, the base's PSNR found
    again by its variant with the same settings, and bytes at equal PSNR from the steps' slope."""
    r = _tool("bench_web_choices.py", "playbot-lod4", "--out", str(tmp_path), "--data-root", str(shared_data),
              "--views", "4", "--size", "128", "--variant", "base", "--variant", "steps:1.3",
              "--variant", "no_np:neighbour_prediction=false", "--variant", "same:rows_per_chunk=65536", cwd=tmp_path)
    *rows, summary = [json.loads(ln) for ln in r.stdout.strip().splitlines()]
    assert [row["variant"] for row in rows] == ["base", "steps1.3", "no_np", "same"]
    for row in rows:
        assert Path(row["stream"]).stat().st_size == row["bytes"] > 0 and row["gaussians"] > 0
    assert rows[3]["bytes"] == rows[0]["bytes"] and rows[3]["psnr"] == rows[0]["psnr"]
    assert rows[1]["bytes"] < rows[0]["bytes"] and summary["slope_db_per_doubling"] > 0
    assert summary["bytes_at_base_psnr"]["base"] == rows[0]["bytes"]


def test_decode_stages(tmp_path):
    stream = ROOT / "conformance" / "streams" / "c092_sh_degree_tiles" / "stream.lghcc"
    r = _tool("decode_stages.py", str(stream), "--work", str(tmp_path), cwd=tmp_path)
    rows = [line for line in r.stdout.splitlines() if line.startswith("| ") and "CPU s" not in line]
    labels = {line.split(" | ")[0][2:] for line in rows}
    assert {"geometry", "k-NN graph", "neighbour means and buckets", "PLY write"} <= labels, r.stdout
    shares = [float(line.split(" | ")[2].rstrip("%")) for line in rows]
    assert abs(sum(shares) - 100) < 1.0, r.stdout  # the stages and the rest make up the whole
    assert (tmp_path / "decode_stages.ply").stat().st_size > 0
