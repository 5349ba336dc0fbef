"""--device for lghcc-train and the transcoder (lghcc-enc on a 3DGS PLY): one seam,
lghcc.render.rasterizer.select_device, on the CPU. Without CUDA, --device cuda is refused
clearly and before any work; with a usable backend (faked here: gsplat's rasterizer replaced
by the CPU one), training and transcoding rasterize through it. No GPU is measured here."""

import numpy as np
import pytest
import torch

from lghcc.common.errors import InputError
from lghcc.render import rasterizer as R


@pytest.fixture
def no_cuda(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


@pytest.fixture
def fake_gpu(monkeypatch):
    """A machine where --device cuda is usable, with gsplat's rasterizer counted and replaced by
    the CPU rasterizer (same arguments, same result type)."""
    calls = []

    def fake_gsplat(*a, **k):
        calls.append(a[5])  # the camera
        for unused in ("sigma_cutoff", "chunk_elements"):
            k.pop(unused, None)
        return R.rasterize(*a, **k)

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(R, "gsplat_available", lambda: True)
    monkeypatch.setattr(R, "rasterize_gsplat", fake_gsplat)
    return calls


def test_select_device(no_cuda):
    assert R.select_device("cpu") == "torch" and R.rasterize_with("torch") is R.rasterize
    with pytest.raises(InputError, match=r"^no CUDA device\b.*--device cpu"):
        R.select_device("cuda")
    with pytest.raises(InputError, match="unknown device 'tpu'"):
        R.select_device("tpu")


def test_cuda_without_gsplat_names_what_is_missing(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(R, "gsplat_available", lambda: False)
    with pytest.raises(InputError, match=r"--device cuda\b.*gsplat\b.*gsplat"):
        R.select_device("cuda")


def test_train_refuses_cuda_before_loading_data(no_cuda, tmp_path, capsys):
    from lghcc.encoder import train as train_cli

    rc = train_cli.main([str(tmp_path / "no_such_images"), "-o", str(tmp_path / "run"), "--device", "cuda"])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("lghcc-train: error:") and "CUDA" in err and err.count("\n") == 1
    assert not (tmp_path / "run").exists()


def test_encoder_refuses_cuda_before_transcoding(no_cuda, tmp_path, capsys):
    from lghcc.encoder import cli as enc_cli

    ply = tmp_path / "x.ply"
    ply.write_text("not read")
    assert enc_cli.main([str(ply), "-o", str(tmp_path / "x.lghcc"), "--device", "cuda"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("lghcc-enc: error:") and "CUDA" in err and not (tmp_path / "x.lghcc").exists()


def test_training_rasterizes_through_the_seam(fake_gpu, tmp_path):
    from test_train import make_dataset, tiny_config

    from lghcc.encoder.training.loop import train

    data = make_dataset(tmp_path / "d", n_train=3, n_test=1)
    res = train(tiny_config(data, iterations=3, device="cuda"), tmp_path / "run", progress=False,
                log=lambda *a: None)
    assert res.iteration == 3 and len(fake_gpu) >= 3  # every training step (evaluation renders on the CPU)
    assert "device: cuda" in (tmp_path / "run" / "config.yaml").read_text()


def test_transcoding_rasterizes_through_the_seam(fake_gpu):
    from test_transcode import synthetic_3dgs

    from lghcc.encoder.anchors.transcode import TranscodeConfig, transcode_3dgs

    cfg = TranscodeConfig(anchors=20, feature_dim=4, num_offsets=4, views=2, test_views=1, resolution=16,
                          distill_steps=2, iterations=3, device="cuda")
    r = transcode_3dgs(synthetic_3dgs(80), cfg)
    # the source's targets (2 + 1 views) and the 3 fitting iterations; the held-out evaluation stays on the CPU
    assert len(fake_gpu) == 3 + 3 and np.isfinite(r.stats.psnr_final)
