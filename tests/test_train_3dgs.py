"""Plain-3DGS baseline trainer: on a tiny NeRF-synthetic folder rendered by our own renderer
(test_train.make_dataset), a few dozen iterations lower the loss and raise the training PSNR,
densification keeps parameters and Adam state in step, and the CLI writes a readable 3DGS PLY."""

import json

import numpy as np
import torch
from test_train import make_dataset

from lghcc.encoder.training import train_3dgs as G
from lghcc.render.datasets import load_dataset
from lghcc.render.gaussians3dgs import load_3dgs_ply


def _trainer(data, **kw):
    torch.set_num_threads(1)
    cfg = G.Config3DGS(data=str(data), init_points=300, threads=1, seed=1, **kw)
    return G.Trainer3DGS(cfg, load_dataset(data))


def test_training_lowers_the_loss(tmp_path):
    data = make_dataset(tmp_path / "tiny", n_train=6, n_test=2)
    tr = _trainer(data, iterations=60, densify_from=10 ** 6)
    before = tr.evaluate(tr.ds.train)["psnr"]
    losses = [tr.step() for _ in range(60)]
    after = tr.evaluate(tr.ds.train)["psnr"]
    assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:10]), losses
    assert after > before + 1.0, (before, after)


def test_densify_and_prune_keep_optimizer_in_step(tmp_path):
    data = make_dataset(tmp_path / "tiny", n_train=4, n_test=1)
    tr = _trainer(data, iterations=20, densify_grad_threshold=0.0, densify_from=2, densify_interval=4,
                  min_opacity=0.0)
    n0 = tr.num_gaussians
    for _ in range(8):
        tr.step()
    assert tr.num_gaussians > n0  # every drawn Gaussian was cloned or split
    n = tr.num_gaussians
    for g in tr.opt.param_groups:
        p = g["params"][0]
        assert p is tr.params[g["name"]] and p.shape[0] == n
        st = tr.opt.state.get(p)
        if st:
            assert st["exp_avg"].shape == p.shape
    tr.cfg.min_opacity = 2.0  # prunes everything but never all: nothing
    tr.densify_and_prune()
    assert tr.num_gaussians > 0
    tr.step()


def test_cli_writes_ply_and_metrics(tmp_path):
    data = make_dataset(tmp_path / "tiny", n_train=4, n_test=2)
    out = tmp_path / "out"
    rc = G.main([str(data), "-o", str(out), "--iterations", "12", "--threads", "1", "--init-points", "200",
                 "--densify-from", "4", "--densify-interval", "4"])
    assert rc == 0
    g = load_3dgs_ply(out / "point_cloud.ply")
    m = json.loads((out / "metrics.json").read_text())
    assert g.num_gaussians == m["gaussians"] > 0 and g.sh_degree == 0
    assert m["views"] == 2 and np.isfinite(m["psnr"]) and 0 < m["ssim"] <= 1
    assert G.main([str(tmp_path / "missing"), "-o", str(out)]) == 1
