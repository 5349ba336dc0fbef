"""lghcc-view's page in a real browser (headless Debian Chromium driven by playwright): it draws
the decoded scene and its source, from the camera it says it has, as lghcc.render draws them on
the CPU, and the two panes keep one camera when the user drags.

Skips with the reason where playwright, Chromium or the built bundle (`make viewer-bundle`) is
missing; CI (.ci/run) installs all three.

Thresholds. The page and lghcc.render draw the same Gaussians by different rasterizers:
PlayCanvas cuts each splat at 2.83 sigma and renormalizes its falloff (exp(-d^2/2) - e^-4) /
(1 - e^-4), lghcc.render cuts at 3 sigma with the plain falloff; PlayCanvas sorts splats
globally by quantized camera depth, lghcc.render per 16 px tile by exact depth; the page
blends into an 8-bit framebuffer. Measured agreement (Chromium 156 / SwiftShader, black
background, first orbit view), browser screenshot against the CPU render of the same PLY:

    this test's scene, 160x160 (procedural, 400 anchors, preset low; both panes 3DGS exports):
        source 38.5 dB / SSIM 0.980, decoded 34.7 / 0.966; after the drag 38.7 / 0.981, 35.6 / 0.971
    procedural 3,000 anchors -> 15.7k Gaussians, 256x256:  41.0 dB, SSIM 0.991
    playbot decoded (2,087 anchors -> 8.2k Gaussians), 256x256:  31.2 dB, SSIM 0.961
    playbot source (8.4k Gaussians, SH degree 2), 256x192:  30.2 dB, SSIM 0.960
    donut source (45.6k Gaussians; thin sprinkles on the glaze, where depth order decides): 28.0 dB, 0.963

What a broken page would give on this test's scene (CPU render against a perturbed CPU render,
160x160, both panes alike): camera turned 1 degree 39.2 dB / 0.990, 2 degrees 33.5 / 0.965,
3 degrees 30.3 / 0.934; field of view +2% 33.8 / 0.971; shifted one pixel 36.6 / 0.982;
colours gamma-decoded and not re-encoded (this page's first version) 16.1 / 0.768; upside down
11.9 / 0.45; blank 10.8 / 0.53.

So the two rasterizers differ about as much as a 2-degree camera error: PSNR_MIN = 30 dB and
SSIM_MIN = 0.94 leave 4.7 dB / 0.026 of margin under the worst agreement measured here, and
fail every gross error (axes, gamma, a blank or unsorted pane, a pane that does not follow the
camera) and a camera off by 3 degrees or more; a smaller camera error is not detectable this
way (test_viewer.py checks that the page's camera numbers are the orbit camera's).
"""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from lghcc.viewer import page as page_mod
from lghcc.viewer.browser import ViewerSession, browser_status

OK, WHY = browser_status()
pytestmark = [pytest.mark.integration,  # Chromium
              pytest.mark.skipif(not OK, reason=WHY),
              pytest.mark.skipif(not page_mod.BUNDLE.is_file(),
                                 reason=f"the viewer bundle {page_mod.BUNDLE} is not built (make viewer-bundle)")]

SIZE = (160, 160)
PSNR_MIN = 30.0  # dB; see the module doc
SSIM_MIN = 0.94


@pytest.fixture(scope="module")
def view_page(tmp_path_factory):
    from lghcc.formats.procedural import make_procedural_scene
    from lghcc.formats.scaffold_io import write_scaffold
    from lghcc.encoder import cli as enc_cli
    from lghcc.viewer import cli as view_cli

    d = tmp_path_factory.mktemp("browser")
    write_scaffold(make_procedural_scene(400, seed=3, feature_dim=8, num_offsets=4), d / "src")
    assert enc_cli.main([str(d / "src"), "-o", str(d / "s.lghcc"), "-q", "--preset", "low"]) == 0
    assert view_cli.main([str(d / "s.lghcc"), "-o", str(d / "v.html"), "--source", str(d / "src"),
                          "--views", "1", "--psnr-size", "48x48", "-q"]) == 0
    return d / "v.html"


def _pane_scenes(html_path: Path):
    """The page's meta and, per pane, the CPU renderer of the exact PLY the page embeds."""
    import base64
    import tempfile

    from lghcc.formats.ply3dgs import read_3dgs_ply
    from lghcc.viewer.scenes import render_gaussians_fn

    text = html_path.read_text()
    meta = json.loads(re.search(r'<script id="lghcc-meta" type="application/json">(.*?)</script>', text).group(1))
    renders = {}
    for name in meta["panes"]:
        b64 = re.search(rf'<script id="lghcc-ply-{name}" type="application/octet-stream">([^<]*)</script>', text)
        with tempfile.TemporaryDirectory() as t:
            (Path(t) / "p.ply").write_bytes(base64.b64decode(b64.group(1)))
            renders[name] = render_gaussians_fn(read_3dgs_ply(Path(t) / "p.ply"))
    return meta, renders


def _cpu_camera(c: dict, meta: dict):
    """lghcc.render's camera for a page camera (meta's fov_x_deg, or camera()'s fovX)."""
    from lghcc.render.camera import Camera

    fov = c.get("fov_x_deg", c.get("fovX"))
    return Camera.look_at(c["eye"], c["target"], up=c["up"], width=SIZE[0], height=SIZE[1], fov_x_deg=fov,
                          near=meta["camera"]["near"], far=meta["camera"]["far"])


def _compare(shots: dict, renders: dict, cam, bg) -> dict:
    from lghcc.render.metrics import psnr, ssim

    out = {}
    for name, img in shots.items():
        ref = renders[name](cam, bg)
        out[name] = (psnr(img, ref), ssim(img, ref))
    return out


def test_first_frame_matches_the_cpu_render(view_page):
    meta, renders = _pane_scenes(view_page)
    bg = np.asarray(meta["background"], np.float32)
    with ViewerSession(view_page, *SIZE) as s:
        shots = s.images()
        requests = list(s.requests)
    assert set(shots) == {"source", "decoded"} and all(v.shape == (SIZE[1], SIZE[0], 3) for v in shots.values())
    # no network: the page loads itself and its scenes from blob: URLs of its own bytes
    assert all(r.startswith(("file:", "blob:", "data:")) for r in requests), requests
    scores = _compare(shots, renders, _cpu_camera(meta["camera"], meta), bg)
    print("browser vs CPU render, first frame:", {k: f"{p:.2f} dB, SSIM {q:.4f}" for k, (p, q) in scores.items()})
    for name, (p, q) in scores.items():
        assert p >= PSNR_MIN and q >= SSIM_MIN, (name, p, q)
        assert shots[name].max() > 0.2, f"{name}: the pane is (nearly) blank"


def test_panes_share_one_camera_when_dragged(view_page):
    meta, renders = _pane_scenes(view_page)
    bg = np.asarray(meta["background"], np.float32)
    with ViewerSession(view_page, *SIZE) as s:
        before = s.images()
        s.drag(60, -25)  # orbit with the mouse on the left pane
        cam = s.camera()
        after = s.images()
    assert np.linalg.norm(np.subtract(cam["eye"], meta["camera"]["eye"])) > 0.1, "the drag did not move the camera"
    assert all(np.abs(after[k] - before[k]).mean() > 0.005 for k in after), "a pane did not follow the drag"
    scores = _compare(after, renders, _cpu_camera(cam, meta), bg)
    print("browser vs CPU render after a drag:", {k: f"{p:.2f} dB, SSIM {q:.4f}" for k, (p, q) in scores.items()})
    for name, (p, q) in scores.items():
        assert p >= PSNR_MIN and q >= SSIM_MIN, (name, p, q)


def test_viewer_screenshot_tool(view_page, tmp_path):
    """tools/viewer_screenshot.py: the page at the window size asked, as a palette PNG, not blank."""
    import subprocess
    import sys

    from PIL import Image

    png = tmp_path / "shot.png"
    tool = Path(__file__).resolve().parents[1] / "tools" / "viewer_screenshot.py"
    r = subprocess.run([sys.executable, str(tool), str(view_page), str(png), "--window", "320x200", "--colors", "16"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    img = Image.open(png)
    assert img.size == (320, 200) and img.mode == "P"
    assert len(img.getcolors()) > 1
