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

from ..common.errors import InputError
from ..common.scene import AnchorScene, GaussianScene


@dataclass
class ViewScene:
    """A scene as the viewer needs it: Gaussians for the page, a CPU renderer for the metrics,
    points to frame the cameras on, and a line saying what it is."""

    gaussians: GaussianScene
    render: Callable  # (Camera, background [3]) -> [H, W, 3] float numpy in [0, 1]
    positions: np.ndarray  # [N, 3] points the orbit cameras frame
    description: str
    export_stats: dict | None = None  # export_3dgs's stats when the Gaussians were exported


def render_gaussians_fn(scene: GaussianScene) -> Callable:
    """CPU render function (camera, background) of an explicit 3DGS scene (lghcc.render.scenes)."""
    from ..render.scenes import render_fn

    return render_fn(scene)


def _render_anchor_fn(scene: AnchorScene) -> Callable:
    from ..render.scenes import render_fn

    return render_fn(scene)


def _visible_means(scene: GaussianScene) -> np.ndarray:
    from ..render.scenes import framing_points

    return framing_points(scene)


def _exported(scene: AnchorScene, sh_degree: int, num_directions: int) -> tuple[GaussianScene, dict]:
    from ..render.export import export_3dgs

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
    """``--source``: a plain 3DGS scene (any format lghcc.formats reads), or a Scaffold-GS model folder /
    iteration folder / PLY (lghcc.formats.read_scene).
    Raises InputError naming the file when it is neither."""
    from ..formats import detect_format, read_scene

    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    scene = read_scene(p)
    if isinstance(scene, GaussianScene):
        kind = {"3dgs-ply": "3DGS PLY", "spz": "SPZ", "sog": "SOG", "compressed-ply": "compressed PLY",
                "streamed-sog": "streamed SOG", "splat": ".splat", "ksplat": ".ksplat"}.get(detect_format(p).name,
                                                                                        "3DGS scene")
        return ViewScene(scene, render_gaussians_fn(scene), _visible_means(scene),
                         f"{kind}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}")
    g, stats = _exported(scene, sh_degree, num_directions)
    return ViewScene(g, _render_anchor_fn(scene), scene.positions(),
                     f"anchor scene, {scene.num_anchors:,} anchors -> {g.num_gaussians:,} Gaussians (3DGS export)",
                     stats)


def ply_bytes(scene: GaussianScene) -> bytes:
    """The scene as INRIA 3DGS PLY bytes, written by lghcc.formats.ply3dgs (the project's one
    3DGS writer) into a temporary folder."""
    from ..formats.ply3dgs import write_3dgs_ply

    with tempfile.TemporaryDirectory(prefix="lghcc-view-") as d:
        f = Path(d) / "scene.ply"
        write_3dgs_ply(f, scene)
        return f.read_bytes()
