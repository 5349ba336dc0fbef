"""SH evaluation, the plain 3DGS PLY loader/writer, and transcoding 3DGS -> anchors."""

import math

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.formats.ply import write_ply
from lghcc.encoder import cli as enc_cli
from lghcc.encoder.transcode import TranscodeConfig, anchorize, transcode_3dgs
from lghcc.render.gaussians3dgs import Gaussians3DGS, is_3dgs_ply, load_3dgs_ply, write_3dgs_ply
from lghcc.render.sh import C0, C1, eval_sh, sh_basis, sh_degree_from_count, sh_to_rgb


def test_sh_basis_known_values():
    z = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    b = sh_basis(3, z)[0]
    want = np.zeros(16)
    want[0], want[2] = C0, C1
    want[6] = 0.31539156525252005 * 2  # C2[2] (2z^2 - x^2 - y^2)
    want[12] = 0.3731763325901154 * 2  # C3[3] z (2z^2 - 3x^2 - 3y^2)
    np.testing.assert_allclose(b.numpy(), want, atol=1e-15)
    x = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    bx = sh_basis(3, x)[0].numpy()
    assert bx[3] == pytest.approx(-C1) and bx[8] == pytest.approx(0.5462742152960396)
    assert bx[15] == pytest.approx(-0.5900435899266435)
    # Y_2^0 = sqrt(5 / 16 pi) (3 z^2 - 1): the closed form at an oblique direction
    v = torch.tensor([[0.48, -0.6, 0.64]], dtype=torch.float64)
    assert float(sh_basis(2, v)[0, 6]) == pytest.approx(math.sqrt(5 / (16 * math.pi)) * (3 * 0.64 ** 2 - 1))


def test_sh_basis_is_orthonormal_over_the_sphere():
    n = 20000
    i = np.arange(n) + 0.5
    zz = 1 - 2 * i / n
    r = np.sqrt(1 - zz * zz)
    phi = i * math.pi * (3 - math.sqrt(5))
    d = torch.tensor(np.stack([r * np.cos(phi), r * np.sin(phi), zz], 1))
    b = sh_basis(3, d)
    gram = (b.T @ b) * (4 * math.pi / n)
    np.testing.assert_allclose(gram.numpy(), np.eye(16), atol=2e-3)


def test_eval_sh_dc_and_degree_truncation():
    coeffs = torch.zeros(2, 9, 3, dtype=torch.float64)
    coeffs[:, 0] = torch.tensor([1.0, -1.0, 0.0])
    coeffs[:, 5] = 7.0  # ignored at degree 1
    dirs = torch.nn.functional.normalize(torch.randn(2, 3, dtype=torch.float64), dim=1)
    out = sh_to_rgb(1, coeffs, dirs)
    np.testing.assert_allclose(out.numpy(), [[0.5 + C0, max(0.0, 0.5 - C0), 0.5]] * 2, atol=1e-12)
    with pytest.raises(ValueError):
        eval_sh(3, coeffs, dirs)
    assert sh_degree_from_count(9) == 2
    with pytest.raises(ValueError):
        sh_degree_from_count(5)


def _columns(n=5, nrest=9, seed=0):
    rng = np.random.default_rng(seed)
    cols = {k: rng.normal(size=n).astype(np.float32) for k in
            ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3")}
    cols.update({f"f_rest_{i}": rng.normal(size=n).astype(np.float32) for i in range(nrest)})
    return cols


@pytest.mark.parametrize("missing", ["opacity", "f_dc_1", "rot_3", "scale_0", "z"])
def test_loader_names_file_and_missing_field(tmp_path, missing):
    cols = _columns()
    del cols[missing]
    p = tmp_path / "bad.ply"
    write_ply(p, cols)
    with pytest.raises(InputError) as e:
        load_3dgs_ply(p)
    assert str(p) in str(e.value) and f"'{missing}'" in str(e.value)


def test_loader_rejects_bad_sh_and_anchor_files(tmp_path):
    p = tmp_path / "rest.ply"
    write_ply(p, _columns(nrest=5))
    with pytest.raises(InputError, match="f_rest"):
        load_3dgs_ply(p)
    cols = _columns(nrest=9)
    del cols["f_rest_4"]
    cols["f_rest_9"] = cols["f_rest_0"]
    write_ply(p, cols)
    with pytest.raises(InputError, match="'f_rest_4'"):
        load_3dgs_ply(p)
    cols = _columns(nrest=0)
    cols["f_anchor_feat_0"] = cols["x"]
    write_ply(p, cols)
    assert not is_3dgs_ply(p)
    with pytest.raises(InputError, match="anchor"):
        load_3dgs_ply(p)
    cols = _columns(nrest=0)
    cols["opacity"][2] = np.nan
    write_ply(p, cols)
    with pytest.raises(InputError, match="'opacity'.*NaN"):
        load_3dgs_ply(p)


def test_write_and_load_keep_the_inria_layout(tmp_path):
    rng = np.random.default_rng(3)
    n = 7
    sh = rng.normal(size=(n, 9, 3)).astype(np.float32)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    p = tmp_path / "g.ply"
    write_3dgs_ply(p, rng.normal(size=(n, 3)), sh, rng.normal(size=n), rng.normal(size=(n, 3)), q)
    assert is_3dgs_ply(p)
    g = load_3dgs_ply(p)
    assert g.sh_degree == 2 and g.num_gaussians == n
    np.testing.assert_allclose(g.sh.numpy(), sh, atol=1e-6)
    np.testing.assert_allclose(g.quats.numpy(), q / np.linalg.norm(q, axis=1, keepdims=True), atol=1e-6)
    from lghcc.formats.ply import read_ply
    cols = read_ply(p)
    # channel-major f_rest: f_rest_{c (K-1) + i - 1} is coefficient i of channel c
    assert cols["f_rest_9"][4] == sh[4, 2, 1] and cols["f_rest_1"][0] == sh[0, 2, 0]


def synthetic_3dgs(n=400, seed=0, degree=1) -> Gaussians3DGS:
    """Gaussians on a bumpy shell with smooth colours (a small stand-in for a trained scene)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    means = d * (0.5 + 0.05 * np.sin(5 * d[:, :1]))
    k = (degree + 1) ** 2
    sh = np.zeros((n, k, 3))
    sh[:, 0] = (np.stack([d[:, 0], d[:, 1], -d[:, 2]], 1) * 0.4) / C0
    if degree:
        sh[:, 1:] = 0.1 * rng.normal(size=(n, k - 1, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return Gaussians3DGS(t(means), t(q), t(np.exp(rng.uniform(-3.6, -2.8, (n, 3)))),
                         t(rng.uniform(0.5, 0.95, n)), t(sh), degree, "synthetic")


def test_anchorize_assigns_each_gaussian_at_most_once():
    g = synthetic_3dgs(300)
    a = anchorize(g, TranscodeConfig(anchors=40, num_offsets=4))
    s = a["slot_gaussian"]
    used = s[s >= 0]
    assert len(np.unique(used)) == used.size == 300 - a["dropped"] - a["below_min_opacity"]
    assert 25 <= len(a["coords"]) <= 55
    # every assigned Gaussian lies within a voxel of its anchor
    pos = a["coords"] * a["voxel"] + a["origin"]
    ai = np.nonzero(s >= 0)[0]
    assert np.abs(g.means.numpy()[s[s >= 0]] - pos[ai]).max() <= a["voxel"] * 0.5 + 1e-5


def test_tiny_transcode_improves_over_its_initialization():
    torch.manual_seed(0)
    g = synthetic_3dgs(300)
    cfg = TranscodeConfig(anchors=50, feature_dim=8, num_offsets=8, views=4, test_views=2, resolution=32,
                          distill_steps=60, iterations=25, seed=0)
    r = transcode_3dgs(g, cfg)
    s = r.stats
    assert r.scene.num_anchors == s.anchors and r.scene.offset_mask is not None
    assert s.psnr_init_train > 12  # distillation alone already gives a recognizable scene
    assert s.psnr_final_train > s.psnr_init_train + 0.5, s
    assert np.isfinite(s.psnr_final)
    # a written checkpoint reads back on the same grid (voxel size inferred, no shift)
    import tempfile

    from lghcc.formats.scaffold_io import read_scaffold, write_scaffold
    with tempfile.TemporaryDirectory() as d:
        write_scaffold(r.scene, d)
        back = read_scaffold(d)
    np.testing.assert_allclose(back.positions(), r.scene.positions(), atol=1e-6)


def test_encoder_cli_transcodes_a_plain_3dgs_ply(tmp_path, capsys):
    g = synthetic_3dgs(150, degree=0)
    p = tmp_path / "plain.ply"
    lg = lambda a: np.log(a / (1 - a))  # noqa: E731
    write_3dgs_ply(p, g.means.numpy(), g.sh.numpy(), lg(g.opacities.numpy()), np.log(g.scales.numpy()),
                   g.quats.numpy())
    out = tmp_path / "t.lghcc"
    assert enc_cli.main([str(p), "-o", str(out), "--mode", "anchors", "--transcode-anchors", "30",
                         "--transcode-iterations", "2",
                         "--transcode-distill-steps", "5", "--transcode-views", "2", "--transcode-resolution", "16",
                         "--transcode-feature-dim", "4", "--transcode-offsets", "6"]) == 0
    err = capsys.readouterr()
    assert "plain 3DGS PLY" in err.err and "transcoding" in err.err and "held-out PSNR" in err.err
    assert "hash matches" in err.out and out.stat().st_size > 0
