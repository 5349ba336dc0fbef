"""tools/bench_real.py: up axis and orbit, the SPZ envelope and equal-PSNR interpolation, the
results file (sections, --append, --replot), the lghcc rows through the installed CLIs, and
the splat-transform round trip (skipped when node or the pinned package is absent:
`make node-tools`)."""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lghcc.common.scene import GaussianScene
from lghcc.formats.opacity import LARGEST_OPACITY_LOGIT
from lghcc.formats.ply3dgs import write_3dgs_ply

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("bench_real", ROOT / "tools" / "bench_real.py")
br = importlib.util.module_from_spec(_spec)
sys.modules["bench_real"] = br
_spec.loader.exec_module(br)

FAST = ["--views", "2", "--size", "32", "--importance-views", "3", "--importance-size", "24", "--threads", "1"]


def tiny_scene(n: int = 300, degree: int = 1, flat: int = 2, seed: int = 0) -> GaussianScene:
    """n Gaussians in a slab thin along axis ``flat``."""
    rng = np.random.default_rng(seed)
    squash = np.ones(3, np.float32)
    squash[flat] = 0.25
    means = rng.normal(size=(n, 3)).astype(np.float32) * squash
    sh = (rng.normal(size=(n, (degree + 1) ** 2, 3)) * 0.3).astype(np.float32)
    return GaussianScene(means, sh, rng.normal(1.0, 1.0, n).astype(np.float32),
                         (np.full((n, 3), -2.5) + rng.normal(0, 0.3, (n, 3))).astype(np.float32),
                         rng.normal(size=(n, 4)).astype(np.float32))


@pytest.fixture
def tiny_ply(tmp_path) -> Path:
    p = tmp_path / "tiny.ply"
    write_3dgs_ply(p, tiny_scene())
    return p


# --- up axis and orbit ----------------------------------------------------------------------

@pytest.mark.parametrize("flat, expect", [(0, "x"), (1, "-y"), (2, "z")])
def test_detect_up_takes_the_thinnest_axis_with_the_conventional_sign(flat, expect):
    s = tiny_scene(2000, 0, flat)
    up, why = br.detect_up(s.means, s.opacity)
    assert up == expect and why.startswith("detected: thinnest along " + "xyz"[flat])


def test_detect_up_ignores_transparent_gaussians():
    s = tiny_scene(2000, 0, flat=2)
    rng = np.random.default_rng(1)
    far = rng.normal(size=(3000, 3)) * np.array([5.0, 5.0, 50.0])  # a transparent haze tall along z
    means = np.concatenate([s.means, far]).astype(np.float32)
    opacity = np.concatenate([s.opacity, np.full(3000, -20.0)]).astype(np.float32)
    assert br.detect_up(means, opacity)[0] == "z"
    assert br.detect_up(means)[0] != "z"


@pytest.mark.parametrize("up", ["x", "y", "z", "-x", "-y", "-z"])
def test_orbit_keeps_the_up_axis_up(up):
    s = tiny_scene(500, 0)
    u = np.array(br.parse_up(up))
    cams = br.orbit(s.means, 6, 40, up, elevation=20.0)
    lo, hi = np.quantile(s.means, 0.01, axis=0), np.quantile(s.means, 0.99, axis=0)
    centre, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    for c in cams:
        d = c.center - centre
        assert math.isclose(float(d @ u) / np.linalg.norm(d), math.sin(math.radians(20)), abs_tol=1e-6)
        (p_centre, p_above), _ = c.project(np.stack([centre, centre + 0.5 * r * u]))
        assert p_above[1] < p_centre[1] - 1  # above in the image (rows grow downwards)
    assert br.parse_up("+z") == br.parse_up("Z") == (0.0, 0.0, 1.0)
    with pytest.raises(ValueError):
        br.parse_up("up")


def test_scene_specs(tmp_path):
    s = br.resolve_scene("donut", tmp_path, None)
    assert (s.slug, s.up, s.up_source, s.path) == ("donut", "z", "recorded", tmp_path / "donut/donut.ply")
    assert br.resolve_scene("donut@-x", tmp_path, None).up == "-x"
    assert br.resolve_scene("playcanvas-logo", tmp_path, "+x").up == "x"
    p = br.resolve_scene("some/dir/my scene.ply@-y", tmp_path, None)
    assert (p.slug, p.up, p.up_source, p.path) == ("my-scene", "-y", "given", Path("some/dir/my scene.ply"))
    assert br.resolve_scene("a.ply", tmp_path, None).up is None  # detected when the scene is read
    lab = br.resolve_scene("lego-trained=runs/x/point_cloud.ply@z", tmp_path, None)
    assert (lab.slug, lab.path, lab.up) == ("lego-trained", Path("runs/x/point_cloud.ply"), "z")


# --- equal PSNR -----------------------------------------------------------------------------

points = st.lists(st.tuples(st.integers(1000, 10 ** 7), st.floats(20, 70)), min_size=1, max_size=30)


@given(points)
def test_envelope_is_monotone_and_undominated(pts):
    env = br.envelope(pts)
    assert env and all(b0 < b1 and p0 < p1 for (b0, p0), (b1, p1) in zip(env, env[1:]))
    for b, p in pts:  # every point is matched or beaten by an envelope point
        assert any(eb <= b and ep >= p for eb, ep in env)
    for eb, ep in env:  # no envelope point is beaten by a measured one
        assert not any((b <= eb and p > ep) or (b < eb and p >= ep) for b, p in pts)


@given(points, st.floats(10, 80))
def test_bytes_at_psnr(pts, q):
    env = br.envelope(pts)
    for b, p in env:  # exact at the measured points
        assert br.bytes_at_psnr(env, p) == (pytest.approx(b, rel=1e-12), "interpolated")
    got, where = br.bytes_at_psnr(env, q)
    if q > env[-1][1]:
        assert (got, where) == (None, "above")
    elif q < env[0][1]:
        assert (got, where) == (env[0][0], "below")
    else:
        assert where == "interpolated"
        i = next(i for i, (_, p) in enumerate(env) if p >= q)
        assert env[max(i - 1, 0)][0] * (1 - 1e-12) <= got <= env[i][0] * (1 + 1e-12)
        lower = br.bytes_at_psnr(env, max(env[0][1], q - 0.5))[0]
        assert lower <= got * (1 + 1e-12)  # more PSNR never costs fewer bytes


def test_interpolation_is_linear_in_log_bytes():
    env = br.envelope([(1000, 30.0), (4000, 40.0), (3000, 35.0), (5000, 39.0)])  # (5000, 39) is dominated
    assert env == [(1000, 30.0), (3000, 35.0), (4000, 40.0)]
    assert br.bytes_at_psnr(env, 32.5)[0] == pytest.approx(math.sqrt(1000 * 3000))
    assert br.equal_psnr_cell(1500, 35.0, env, 4000) == "0.50 (SPZ 3,000 B)"
    assert br.equal_psnr_cell(2000, 45.0, env, 4000) == "0.50 vs full SPZ (above SPZ's best, 40.00 dB)"
    assert br.equal_psnr_cell(600, 25.0, env, 4000) == ">= 0.60 (below SPZ's lowest, 30.00 dB)"
    assert br.equal_psnr_cell(600, 25.0, [], None) == "n/a (no SPZ curve)"


# --- the results file -----------------------------------------------------------------------

def _rows():
    R = br.Row
    main = [R("source PLY", "SH 1", 31829, 300, math.inf, 1.0, 1),
            R("SPZ", "full", 6543, 300, 54.0, 0.9998, 1, 0.6, 0.4),
            R("SOG", "full", 24828, 300, 46.5, 0.999, 1, 4.4, 0.4),
            R("lghcc", "low", 3500, 2400, 33.0, 0.97, 1, 70.0, 3.0),
            R("lghcc", "high", 0, 0, math.nan, math.nan, note="lghcc-enc failed (exit 1)")]
    curve = [R("SPZ curve", "full", 6543, 300, 54.0, 0.9998, 1),
             R("SPZ curve", "importance 60%", 4120, 180, 33.2, 0.98, 1),
             R("SPZ curve", "decimate 60%", 4068, 180, 29.1, 0.93, 1),
             R("SPZ curve", "full", 4994, 300, 31.3, 0.96, 0)]
    return main, curve


def test_section_round_trip_and_equal_psnr_column():
    main, curve = _rows()
    lines = br.scene_section("tiny (300 Gaussians, SH degree 1)", ["Command: `x`"], 300, main, curve,
                             "![PSNR against bytes](real_tiny.png)", ["Data credit: someone."])
    text = "\n".join(lines)
    assert "| lghcc | low | 3,500 | 93.33 | 2,400 | 33.00 | 0.9700 | 70.0 | 3.0 | 0.85 (SPZ 4,117 B) |" in text
    assert "| SOG | full | 24,828 |" in text and "| 4.48 (SPZ 5,538 B) |" in text
    assert "| lghcc | high | 0 | 0.00 | 0 | n/a | n/a | - | - | lghcc-enc failed (exit 1) |" in text
    assert "| full | 0 | 300 | 4,994 | 133.17 | 31.30 | 0.9600 |  |" in text  # under the envelope
    assert "| decimate 60% | 1 | 180 | 4,068 | 108.48 | 29.10 | 0.9300 | yes |" in text  # the cheapest
    assert "| importance 60% | 1 | 180 | 4,120 | 109.87 | 33.20 | 0.9800 | yes |" in text
    d = br.parse_section(lines)
    assert d["plot"] == "real_tiny.png" and d["title"].startswith("tiny")
    assert [(r.codec, r.setting, r.bytes, r.gaussians) for r in d["main"]] == \
           [(r.codec, r.setting, r.bytes, r.gaussians) for r in main]
    assert d["main"][3].psnr == 33.0 and math.isnan(d["main"][4].psnr)
    assert sorted((r.setting, r.sh_degree, r.bytes, r.psnr) for r in d["curve"]) == \
           sorted((r.setting, r.sh_degree, r.bytes, r.psnr) for r in curve)


def test_results_file_append_and_replot_without_node(tiny_ply, tmp_path, capsys):
    """--no-splat-transform and no lghcc rows: the file is written, the missing rows are named;
    --append replaces the scene run and keeps the others; --replot redraws from the tables."""
    out, work = tmp_path / "res" / "real.md", tmp_path / "work"
    other = tmp_path / "other.ply"
    write_3dgs_ply(other, tiny_scene(200, 0, flat=1, seed=3))
    base = [*FAST, "--presets", "none", "--no-splat-transform", "--work", str(work), "--out", str(out)]
    assert br.main([str(tiny_ply), str(other), *base]) == 0
    text = out.read_text()
    assert text.startswith("# Real 3DGS scenes") and text.count("\n## ") == 2
    assert "## tiny (300 Gaussians, SH degree 1)" in text and "## other (200 Gaussians, SH degree 0)" in text
    assert "up z (detected: thinnest along z" in text and "up -y (detected: thinnest along y" in text
    assert "Not measured (--no-splat-transform): SPZ; SOG; compressed PLY; SPZ SH 1 importance 90%" in text
    assert f"Command: `python tools/bench_real.py {tiny_ply} {other}" in text
    assert (work.glob("tiny-*/r*/source_renders.npy")).__next__().exists()
    assert br.main([f"{tiny_ply}@x", *base, "--append"]) == 0
    text2 = out.read_text()
    assert text2.count("\n## ") == 2 and text2.index("## tiny") < text2.index("## other")
    assert "up x (given on the command line)" in text2
    assert text2.split("## other")[1] == text.split("## other")[1]
    capsys.readouterr()
    assert br.main(["--replot", "--out", str(out)]) == 0
    assert out.read_text().split("## other")[1] == text.split("## other")[1]


def test_missing_splat_transform_is_one_line_and_exit_3(tiny_ply, tmp_path, monkeypatch, capsys):
    node_dir = tmp_path / "node"
    node_dir.mkdir()
    (node_dir / "package.json").write_text('{"dependencies": {"@playcanvas/splat-transform": "3.7.0"}}')
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    assert br.splat_transform_status(node_dir)[1].startswith("node is not on the PATH")
    monkeypatch.undo()
    if br.shutil.which("node"):
        assert "is not installed in" in br.splat_transform_status(node_dir)[1]
        assert "make node-tools" in br.splat_transform_status(node_dir)[1]
    monkeypatch.setattr(br, "splat_transform_status", lambda: (None, "node is not on the PATH: ..."))
    capsys.readouterr()
    assert br.main([str(tiny_ply), *FAST, "--presets", "none", "--work", str(tmp_path / "w"),
                    "--out", str(tmp_path / "r.md")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["bench_real: error: node is not on the PATH: ..."] and not (tmp_path / "r.md").exists()


def test_infinite_opacity_logits_are_read_as_opacity_1_or_0(tiny_ply, tmp_path):
    """splat-transform writes compressed PLY's 8-bit opacities 0 and 1 back as logits -inf / +inf."""
    from lghcc.formats.ply import read_ply, write_ply

    cols = read_ply(tiny_ply)
    cols["opacity"][:3] = [np.inf, -np.inf, np.inf]
    bad = tmp_path / "inf.ply"
    write_ply(bad, cols)
    s, note = br.read_back_ply(bad)
    assert note.startswith("2 opacity logits of +inf and 1 of -inf read as opacity 1 and 0")
    top = np.float32(LARGEST_OPACITY_LOGIT)
    assert list(s.opacity[:3]) == [top, -top, top] and s.num_gaussians == 300
    assert br.read_back_ply(tiny_ply)[1] == ""
    cols["opacity"][0] = np.nan
    write_ply(bad, cols)
    with pytest.raises(br_input_error()):
        br.read_back_ply(bad)


def br_input_error():
    from lghcc.common.errors import InputError
    return InputError


def test_presets_from_the_encoder_help():
    help_ = "usage: lghcc-enc [--preset {high,lghcc-high,lghcc-low,lghcc-medium,low,medium}]\n"
    assert br.listed_presets(help_) == ["high", "lghcc-high", "lghcc-low", "lghcc-medium", "low", "medium"]
    assert br.default_presets(help_) == ["high", "low", "medium"]
    enc, _ = br.lghcc_commands()
    assert set(br.default_presets(br.help_text(enc))) >= {"low", "medium", "high"}


@pytest.mark.slow  # two subprocesses that import torch: ~10 s
def test_lghcc_row_through_the_clis(tiny_ply, tmp_path):
    """lghcc-enc / lghcc-dec of this venv, a very short transcode: the row has the stream's bytes
    and the decoded scene exported at the source's SH degree."""
    out = tmp_path / "r.md"
    enc_args = ("--transcode-iterations 0 --transcode-distill-steps 2 --transcode-views 2 "
                "--transcode-resolution 16 --transcode-anchors 40 --no-verify -q")
    assert br.main([str(tiny_ply), *FAST, "--presets", "low", "--no-splat-transform", "--enc-args", enc_args,
                    "--dec-args", "-q --export-directions 4", "--work", str(tmp_path / "w"), "--out", str(out)]) == 0
    row = next(l for l in out.read_text().splitlines() if l.startswith("| lghcc | low |"))
    c = [x.strip() for x in row.strip("|").split("|")]
    stream = next((tmp_path / "w").glob("tiny-*/r*/files/lghcc-low.lghcc"))
    assert int(c[2].replace(",", "")) == stream.stat().st_size > 0
    assert int(c[4].replace(",", "")) > 0 and 0 < float(c[5]) < 100 and float(c[7]) > 0 and float(c[8]) > 0
    assert c[9].startswith("n/a (no SPZ curve)")


# --- splat-transform ------------------------------------------------------------------------

def _splat_transform_or_skip():
    prefix, why = br.splat_transform_status()
    if prefix is None:
        pytest.skip(why)
    return prefix


@pytest.mark.integration
def test_splat_transform_round_trip(tiny_ply, tmp_path):
    """SPZ, SOG and compressed PLY written and read back with the pinned splat-transform, and the
    SPZ curve (pruned, decimated, fewer SH bands), on a 300-Gaussian scene."""
    _splat_transform_or_skip()
    out, work = tmp_path / "r.md", tmp_path / "w"
    args = [str(tiny_ply), *FAST, "--presets", "none", "--spz-keep", "60", "--spz-reducers", "prune,decimate-adaptive",
            "--work", str(work), "--out", str(out)]
    assert br.main(args) == 0
    d = br.parse_section(br.split_sections(out.read_text())[1][0])
    rows = {r.codec: r for r in d["main"]}
    assert set(rows) == {"source PLY", "SPZ", "SOG", "compressed PLY"}
    for name in ("SPZ", "SOG", "compressed PLY"):
        assert rows[name].gaussians == 300 and rows[name].psnr > 35 and rows[name].bytes < rows["source PLY"].bytes
    curve = {(r.setting, r.sh_degree): r for r in d["curve"]}
    assert set(curve) == {(s, d) for s in ("full", "importance 60%", "decimate-adaptive 60%") for d in (0, 1)}
    assert curve["importance 60%", 1].gaussians == 180 and curve["full", 1].bytes == rows["SPZ"].bytes
    assert curve["full", 0].bytes < curve["full", 1].bytes
    # a second run takes every splat-transform row from the cache, even without splat-transform
    text = out.read_text()
    assert br.main([*args, "--no-splat-transform"]) == 0
    strip = lambda t: [l for l in t.splitlines() if not l.startswith(("Command:", "Date:"))]  # noqa: E731
    assert strip(out.read_text()) == strip(text)


def test_the_report_says_which_views_the_spz_importance_ranks_on():
    """Fibonacci sphere by default; with --cameras the evaluation's own views, which the report calls
    an oracle; --importance-cameras others (a capture's), named."""
    ns = argparse.Namespace(importance_views=24, importance_size=256, cameras=None, importance_cameras=None)
    assert br.importance_text(ns) == "24 Fibonacci-sphere views (not the orbit)"
    ns.cameras = "eval.json"
    assert "oracle" in br.importance_text(ns)
    ns.importance_cameras = "capture.json"
    assert br.importance_text(ns).startswith("the cameras of `capture.json` at 256 px")
