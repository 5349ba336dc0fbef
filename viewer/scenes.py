"""What the viewer shows: a decoded stream or a source scene as an explicit 3DGS scene
(``GaussianScene``), and its 3DGS PLY bytes (informative).

A WebGL splat renderer draws plain 3DGS Gaussians, so every scene reaches the page as an INRIA
3DGS PLY. ``gaussians_of_decoded`` is the one place that turns a decoded stream into one: an
anchor stream's neural Gaussians are exported with ``lghcc.render.export.export_3dgs`` (a view-
independent approximation; the page shows how close it comes, ``export PSNR``), and a decoded
scene that already is a ``GaussianScene`` (the explicit-Gaussian stream mode) is taken as it is.

Sources (``--source``) are a plain 3DGS PLY (taken as it is) or a Scaffold-GS checkpoint
(exported like a decoded anchor scene). Each kind also has a CPU render function for the PSNR on
the page: the decoded scene is rendered as the decoder rebuilds it (neural Gaussians), not
through the export.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from lghcc.common.errors import InputError
from lghcc.common.scene import AnchorScene, GaussianScene


@dataclass
class ViewScene:
    """A scene as the viewer needs it: Gaussians for the page, a CPU renderer for the metrics,
    points to frame the cameras on, and a line saying what it is."""

    gaussians: GaussianScene
    render: Callable  # (Camera, background [3]) -> [H, W, 3] float numpy in [0, 1]
    positions: np.ndarray  # [N, 3] points the orbit cameras frame
    description: str
    export_stats: dict | None = None  # export_3dgs's stats when the Gaussians were exported


def _render_anchor_fn(scene: AnchorScene) -> Callable:
    from lghcc.render.neural_gaussians import SceneTensors
    from lghcc.render.rasterizer import render_scene

    st = SceneTensors.from_scene(scene)

    def render(cam, bg):
        with torch.no_grad():
            return render_scene(st, cam, background=bg, backend="torch").image.clamp(0, 1).numpy()
    return render


def render_gaussians_fn(scene: GaussianScene) -> Callable:
    """CPU render function of an explicit 3DGS scene (``render_3dgs``, SH colours per camera)."""
    from lghcc.render.gaussians3dgs import gaussians_from_scene, render_3dgs

    g = gaussians_from_scene(scene)

    def render(cam, bg):
        with torch.no_grad():
            return render_3dgs(g, cam, background=bg, backend="torch").image.clamp(0, 1).numpy()
    return render


def _visible_means(scene: GaussianScene) -> np.ndarray:
    """Means of the Gaussians with opacity >= 0.05 (sigmoid of the logit), as compare.py frames
    a 3DGS scene: faint floaters do not widen the orbit."""
    keep = scene.opacity >= np.log(0.05 / 0.95)
    return scene.means[keep] if keep.sum() >= 10 else scene.means


def _exported(scene: AnchorScene, sh_degree: int, num_directions: int) -> tuple[GaussianScene, dict]:
    from lghcc.render.export import export_3dgs

    ex = export_3dgs(scene, sh_degree=sh_degree, num_directions=num_directions)
    return GaussianScene(ex.means, ex.sh, ex.opacity_logits, ex.log_scales, ex.quats), ex.stats


def gaussians_of_decoded(decoded, *, sh_degree: int = 1, num_directions: int = 16) -> ViewScene:
    """A decoded stream's scene (``DecodeResult.scene``) as the viewer shows it.

    THE switch between stream modes: an anchor scene is exported to 3DGS Gaussians; a
    GaussianScene (explicit-Gaussian streams) is shown and rendered as decoded."""
    if isinstance(decoded, GaussianScene):
        return ViewScene(decoded, render_gaussians_fn(decoded), _visible_means(decoded),
                         f"{decoded.num_gaussians:,} Gaussians (explicit), SH degree {decoded.sh_degree}")
    if isinstance(decoded, AnchorScene):
        g, stats = _exported(decoded, sh_degree, num_directions)
        return ViewScene(g, _render_anchor_fn(decoded), decoded.positions(),
                         f"{decoded.num_anchors:,} anchors -> {g.num_gaussians:,} Gaussians "
                         f"(3DGS export, SH degree {sh_degree}, {num_directions} directions)", stats)
    raise TypeError(f"cannot show a decoded scene of type {type(decoded).__name__}")


def load_source(path: str | os.PathLike, *, sh_degree: int = 1, num_directions: int = 16) -> ViewScene:
    """``--source``: a plain 3DGS PLY, or a Scaffold-GS model folder / iteration folder / PLY.
    Raises InputError naming the file when it is neither."""
    from lghcc.formats.ply3dgs import is_3dgs_ply, read_3dgs_ply

    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if is_3dgs_ply(p):
        g = read_3dgs_ply(p)
        return ViewScene(g, render_gaussians_fn(g), _visible_means(g),
                         f"3DGS PLY, {g.num_gaussians:,} Gaussians, SH degree {g.sh_degree}")
    from lghcc.common.scaffold_io import read_scaffold

    scene = read_scaffold(p)
    g, stats = _exported(scene, sh_degree, num_directions)
    return ViewScene(g, _render_anchor_fn(scene), scene.positions(),
                     f"anchor scene, {scene.num_anchors:,} anchors -> {g.num_gaussians:,} Gaussians (3DGS export)",
                     stats)


def ply_bytes(scene: GaussianScene) -> bytes:
    """The scene as INRIA 3DGS PLY bytes, written by lghcc.formats.ply3dgs (the project's one
    3DGS writer) into a temporary folder."""
    from lghcc.formats.ply3dgs import write_3dgs_ply

    with tempfile.TemporaryDirectory(prefix="lghcc-view-") as d:
        f = Path(d) / "scene.ply"
        write_3dgs_ply(f, scene)
        return f.read_bytes()
