"""Test-view quality of lghcc-train's scenes: mean PSNR / SSIM rendered with the CPU reference
renderer (reported metrics do not depend on the machine), of a scene or of a model folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ...render.datasets import load_dataset, parse_background


@torch.no_grad()
def render_image(scene, cam, background) -> np.ndarray:
    """Render ``scene`` (AnchorScene or SceneTensors) for ``cam``; [H, W, 3] float64 clipped to [0, 1]."""
    from ...render.rasterizer import render_scene

    bg = torch.as_tensor(np.asarray(background, np.float32).reshape(3))
    # the CPU reference renderer, as in training: reported metrics do not depend on the machine
    return render_scene(scene, cam, background=bg, backend="torch").image.clamp(0, 1).double().numpy()


def evaluate_model(model: str | Path, data: str | Path, background: str = "white", downscale: int = 1,
                   images: str | None = None, voxel_size: float | None = None) -> dict:
    """Test-view PSNR / SSIM of a Scaffold-GS model (e.g. a decoded .lghcc) on a dataset."""
    from ...formats.scaffold_io import read_scaffold

    scene = read_scaffold(model, voxel_size=voxel_size)
    ds = load_dataset(data, background, downscale, images)
    return {"model": str(model), **evaluate_scene(scene, ds.test, background)}


def evaluate_scene(scene, cams: list, background: str = "white") -> dict:
    """Mean PSNR / SSIM of ``scene`` (an AnchorScene) against the images of ``cams``
    (lghcc.render.scenes.evaluate: the CPU reference renderer)."""
    from ...render.scenes import evaluate

    ev = evaluate(scene, None, cams, background=parse_background(background), backend="torch")
    return {"psnr": ev.psnr, "ssim": ev.ssim, "views": ev.views, "anchors": scene.num_anchors}
