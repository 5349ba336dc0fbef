"""The library API (api.py): what `import lghcc` gives, without the programs."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lghcc
from lghcc.formats.scaffold_io import write_scaffold

from scenes import random_scene

ROOT = Path(__file__).resolve().parents[1]


def _gaussians(n=300, seed=0):
    from lghcc.common.scene import GaussianScene

    rng = np.random.default_rng(seed)
    return GaussianScene(rng.normal(0, 1, (n, 3)).astype(np.float32), rng.normal(0, 0.5, (n, 4, 3)).astype(np.float32),
                         rng.normal(1, 1, n).astype(np.float32), rng.normal(-3, 0.3, (n, 3)).astype(np.float32),
                         rng.normal(size=(n, 4)).astype(np.float32))


def test_import_is_light_and_decode_never_loads_the_encoder():
    code = ("import sys, lghcc; before = sorted(m for m in ('torch', 'lghcc.encoder') if m in sys.modules); "
            "s = lghcc.decode(sys.argv[1]); "
            "print(before, type(s).__name__, sorted(m for m in sys.modules if m.startswith('lghcc.encoder')))")
    stream = ROOT / "conformance" / "streams" / "c002_procedural_medium" / "stream.lghcc"
    out = subprocess.run([sys.executable, "-c", code, str(stream)], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[] AnchorScene []"


@pytest.mark.integration
def test_three_lines_from_gaussians_to_a_stream_and_back(tmp_path):
    scene = _gaussians()
    data = lghcc.encode(scene, preset="high", rd_lambda=0, fit_iterations=0)
    back = lghcc.decode(data)
    assert isinstance(data, bytes) and data[:4] == b"LGHC"
    assert isinstance(back, lghcc.GaussianScene) and 0.9 * scene.num_gaussians < back.num_gaussians <= 300
    # a path: read_scene picks the format; decode also takes a path
    lghcc.write_scene(scene, tmp_path / "s.spz")
    assert lghcc.encode(tmp_path / "s.spz", preset="low", rd_lambda=0, fit_iterations=0)[:4] == b"LGHC"
    (tmp_path / "s.lghcc").write_bytes(data)
    assert lghcc.decode(tmp_path / "s.lghcc").num_gaussians == back.num_gaussians
    ev = lghcc.evaluate(back, scene, "orbit:2", size=(48, 32))
    assert ev.views == 2 and ev.psnr > 25 and 0 < ev.ssim <= 1


def test_anchor_scenes_read_write_and_render(tmp_path):
    from lghcc.formats.procedural import make_procedural_scene

    scene = make_procedural_scene(300, seed=2)
    decoded = lghcc.decode(lghcc.encode(scene, preset="high"))
    assert isinstance(decoded, lghcc.AnchorScene) and decoded.num_anchors == scene.num_anchors
    ply_folder = lghcc.write_scene(decoded, tmp_path / "model")
    assert (ply_folder / "point_cloud.ply").is_file() and (ply_folder / "checkpoint.pth").is_file()
    again = lghcc.read_scene(tmp_path / "model")  # a Scaffold-GS folder, by its content
    assert isinstance(again, lghcc.AnchorScene)
    assert isinstance(lghcc.read_scene(ply_folder / "point_cloud.ply"), lghcc.AnchorScene)  # the anchor PLY itself
    imgs = lghcc.render_views(again, "orbit:2", size=(32, 24))
    assert len(imgs) == 2 and imgs[0].shape == (24, 32, 3) and imgs[0].dtype == np.float32
    g = lghcc.to_gaussians(again)
    assert isinstance(g, lghcc.GaussianScene) and g.sh_degree == 1
    lghcc.write_scene(g, tmp_path / "g.ply")
    # a Gaussian scene written to a folder: the 3DGS layout, read back as Gaussians
    lghcc.write_scene(g, tmp_path / "gfolder")
    assert (tmp_path / "gfolder" / "point_cloud" / "iteration_0" / "point_cloud.ply").is_file()
    assert lghcc.read_scene(tmp_path / "gfolder").num_gaussians == g.num_gaussians
    with pytest.raises(lghcc.InputError, match="Scaffold-GS model folder"):
        lghcc.write_scene(again, tmp_path / "a.spz")


def test_errors_are_lghcc_errors(tmp_path):
    with pytest.raises(lghcc.InputError, match="no such file"):
        lghcc.read_scene(tmp_path / "missing.ply")
    with pytest.raises(lghcc.BitstreamError):
        lghcc.decode(b"LGHC\x00\x01")
    with pytest.raises(lghcc.InputError, match="unknown preset"):
        lghcc.encode(_gaussians(20), preset="nope")
    with pytest.raises(lghcc.LghccError):
        lghcc.encode(_gaussians(20), no_such_option=1)
    write_scaffold(random_scene(np.random.default_rng(4), 25, with_mlps=False), tmp_path / "m")
    with pytest.warns(UserWarning, match="no render-MLP file"):
        bare = lghcc.read_scene(tmp_path / "m")
    with pytest.raises(lghcc.InputError, match="has no render MLPs"):
        lghcc.encode(bare)
    assert lghcc.decode(lghcc.encode(bare, allow_missing_mlps=True)).mlps == {}
    with pytest.raises(lghcc.InputError, match="cannot be rendered"):
        lghcc.render_views(bare)


def test_typed_package():
    assert (ROOT / "py.typed").is_file()
    import inspect

    for name in ("read_scene", "write_scene", "encode", "decode", "load_cameras", "load_dataset", "render_views",
                 "evaluate", "to_gaussians"):
        fn = getattr(lghcc, name)
        sig = inspect.signature(fn)
        assert fn.__doc__ and sig.return_annotation is not inspect.Signature.empty, name
        assert all(p.annotation is not inspect.Parameter.empty for p in sig.parameters.values()
                   if p.kind is not p.VAR_KEYWORD), name
    assert set(lghcc.__all__) <= set(dir(lghcc)) | {"AnchorScene", "GaussianScene", "Camera", "Evaluation"}
