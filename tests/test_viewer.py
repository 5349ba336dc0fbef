"""lghcc-view without a browser: the page it writes, its numbers, its refusals, and the
decoded-scene seam. The page's JavaScript bundle is replaced by a stub here (the real one is a
set-up artifact, `make viewer-bundle`; tests/test_viewer_browser.py runs it in Chromium)."""

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest

from lghcc.common.container import DataUnit, UnitType, read_container, write_container
from lghcc.formats.procedural import make_procedural_scene
from lghcc.formats.scaffold_io import write_scaffold
from lghcc.common.scene import GaussianScene
from lghcc.encoder import cli as enc_cli
from lghcc.viewer import cli as view_cli
from lghcc.viewer import page as page_mod
from lghcc.viewer.scenes import gaussians_of_decoded, ply_bytes

REPO = Path(__file__).resolve().parents[1]
STUB = "window.lghccViewer = {stub: true}; // a '</script>' inside the bundle must not end the element\n"


@pytest.fixture
def stub_bundle(tmp_path, monkeypatch):
    f = tmp_path / "bundle.js"
    f.write_text(STUB)
    monkeypatch.setattr(page_mod, "BUNDLE", f)
    return f


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    """A small anchor scene written as a Scaffold-GS folder, and its stream."""
    d = tmp_path_factory.mktemp("view")
    write_scaffold(make_procedural_scene(400, seed=3, feature_dim=8, num_offsets=4), d / "src")
    assert enc_cli.main([str(d / "src"), "-o", str(d / "s.lghcc"), "-q"]) == 0
    return d


def _embedded(page: str, pane: str) -> bytes:
    m = re.search(rf'<script id="lghcc-ply-{pane}" type="application/octet-stream">([^<]*)</script>', page)
    assert m, f"no {pane} pane in the page"
    return base64.b64decode(m.group(1))


def test_page_with_source_carries_both_scenes_and_the_numbers(small_scene, stub_bundle, tmp_path, capsys):
    out = tmp_path / "v.html"
    assert view_cli.main([str(small_scene / "s.lghcc"), "-o", str(out), "--source", str(small_scene / "src"),
                          "--views", "1", "--psnr-size", "48x48", "--note", "credit: nobody"]) == 0
    log = capsys.readouterr().out
    assert "PSNR vs source" in log and "export PSNR" in log and f"wrote {out}" in log
    page = out.read_text()
    nbytes = (small_scene / "s.lghcc").stat().st_size
    assert f"<b>{nbytes:,} bytes</b>" in page and "bits/anchor" in page and "bits/Gaussian" in page
    assert re.search(r"PSNR vs source <b>\d+\.\d\d dB</b>", page)
    assert "credit: nobody" in page and "hash ✓" in page
    # the decoded pane is exactly the anchor export of the decoded stream; the source pane is there too
    from lghcc.decoder.decode import decode_stream

    dec = decode_stream((small_scene / "s.lghcc").read_bytes()).scene
    assert _embedded(page, "decoded") == ply_bytes(gaussians_of_decoded(dec).gaussians)
    assert _embedded(page, "source")[:3] == b"ply"
    meta = json.loads(re.search(r'<script id="lghcc-meta" type="application/json">(.*?)</script>', page).group(1))
    assert meta["panes"] == ["source", "decoded"] and set(meta["camera"]) >= {"eye", "target", "up", "fov_x_deg"}
    # self-contained: nothing outside the bundle names a network address; the stub's "</script" is escaped
    assert not re.search(r"https?://|//cdn|<link|src=", page.replace(STUB.replace("</script", "<\\/script"), ""))
    assert "<\\/script>" in page


def test_page_without_source_says_so(small_scene, stub_bundle, tmp_path):
    out = tmp_path / "v.html"
    assert view_cli.main([str(small_scene / "s.lghcc"), "-o", str(out), "--no-psnr", "-q"]) == 0
    page = out.read_text()
    assert "PSNR not computed (--no-psnr)" in page and "lghcc-ply-source" not in page


def test_hash_mismatch_writes_no_page(small_scene, stub_bundle, tmp_path, capsys):
    units = read_container((small_scene / "s.lghcc").read_bytes()).units
    assert units[-1].unit_type == UnitType.DECODED_SCENE_HASH
    payload = bytearray(units[-1].payload)
    payload[-1] ^= 1
    bad = tmp_path / "bad.lghcc"
    bad.write_bytes(write_container([DataUnit(u.unit_type, u.payload) for u in units[:-1]]
                                    + [DataUnit(UnitType.DECODED_SCENE_HASH, bytes(payload))]))
    out = tmp_path / "v.html"
    assert view_cli.main([str(bad), "-o", str(out), "--no-psnr"]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(bad) in err and "does not match" in err and "no page written" in err
    assert not out.exists() and list(tmp_path.glob("*.tmp")) == []


def test_malformed_stream_is_an_invalid_stream(small_scene, stub_bundle, tmp_path, capsys):
    """The exit-status rule of every lghcc program (lghcc.app.cli_common): a malformed stream is 3, like a
    hash mismatch, with the stream's path in the one line."""
    bad = tmp_path / "cut.lghcc"
    bad.write_bytes((small_scene / "s.lghcc").read_bytes()[:-7])
    out = tmp_path / "v.html"
    assert view_cli.main([str(bad), "-o", str(out), "--no-psnr"]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("lghcc-view: error: ") and str(bad) in err
    assert not out.exists()


def test_missing_bundle_is_reported_before_any_work(small_scene, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(page_mod, "BUNDLE", tmp_path / "nowhere" / "lghcc-viewer.js")
    monkeypatch.setattr("lghcc.decoder.decode.decode_stream", lambda *a, **k: pytest.fail("decoded anyway"))
    assert view_cli.main([str(small_scene / "s.lghcc"), "-o", str(tmp_path / "v.html")]) == 1
    assert "make viewer-bundle" in capsys.readouterr().err


def test_bad_arguments_are_refused_before_any_work(small_scene, stub_bundle, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("lghcc.decoder.decode.decode_stream", lambda *a, **k: pytest.fail("decoded anyway"))
    s = str(small_scene / "s.lghcc")
    existing = tmp_path / "old.html"
    existing.write_text("keep")
    for argv, msg in ((["-o", s], "would overwrite the input stream"),
                      (["-o", str(existing)], "use -y (--overwrite)"),
                      (["-o", str(tmp_path / "v.html"), "--source", str(tmp_path / "none.ply")], "no such file"),
                      (["-o", str(tmp_path / "v.html"), "--up", "0,0,0"], "--up must be"),
                      (["-o", str(tmp_path / "v.html"), "--psnr-size", "big"], "--psnr-size must be WxH")):
        assert view_cli.main([s, *argv]) == 1, argv
        assert msg in capsys.readouterr().err, argv
    assert existing.read_text() == "keep"


def test_an_explicit_gaussian_scene_is_shown_as_decoded():
    """The seam for explicit-Gaussian streams: a GaussianScene is neither exported nor changed."""
    rng = np.random.default_rng(0)
    n = 50
    q = rng.normal(size=(n, 4)).astype(np.float32)
    g = GaussianScene(rng.normal(size=(n, 3)).astype(np.float32), rng.normal(size=(n, 4, 3)).astype(np.float32),
                      rng.normal(size=n).astype(np.float32), rng.normal(-3, 0.3, size=(n, 3)).astype(np.float32), q)
    v = gaussians_of_decoded(g)
    assert v.gaussians is g and v.export_stats is None and "explicit" in v.description
    from lghcc.render.views import orbit_cameras

    img = v.render(orbit_cameras(g.means, 1, width=24, height=24)[0], np.zeros(3, np.float32))
    assert img.shape == (24, 24, 3) and img.max() > 0
    with pytest.raises(TypeError, match="cannot show"):
        gaussians_of_decoded(object())


def test_page_camera_is_the_first_orbit_camera():
    """The page's camera (eye, target, up, horizontal fov: what viewer.mjs sets) is the camera
    lghcc.render's orbit_cameras makes, so CPU renders and the page see the same view."""
    from lghcc.render.camera import Camera

    pts = np.random.default_rng(1).normal(size=(500, 3)) * [1, 2, 0.5] + [3, -1, 2]
    for up in ([0, 0, 1.0], [0, -1.0, 0]):
        cam, c = view_cli.orbit_view(pts, np.array(up), width=120, height=80)
        again = Camera.look_at(c["eye"], c["target"], up=c["up"], width=120, height=80, fov_x_deg=c["fov_x_deg"],
                               near=c["near"], far=c["far"])
        np.testing.assert_allclose(again.world_to_camera, cam.world_to_camera, atol=1e-9)
        assert (again.fx, again.fy, again.cx, again.cy) == pytest.approx((cam.fx, cam.fy, cam.cx, cam.cy))


def test_engine_pin_is_the_one_the_page_names():
    pkg = json.loads((REPO / "tools" / "node" / "package.json").read_text())
    lock = json.loads((REPO / "tools" / "node" / "package-lock.json").read_text())
    assert pkg["dependencies"][page_mod.ENGINE_NAME] == page_mod.ENGINE_VERSION
    assert lock["packages"][f"node_modules/{page_mod.ENGINE_NAME}"]["version"] == page_mod.ENGINE_VERSION
    assert all(re.fullmatch(r"\d+\.\d+\.\d+", v) for v in pkg["dependencies"].values()), "pin exact versions"
