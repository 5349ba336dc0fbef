"""Rendering and comparing whole scenes (informative): one implementation for the library
(``lghcc.render_views``, ``lghcc.evaluate``, ``lghcc.to_gaussians``) and the programs
(``lghcc-dec --render``/``--export``, ``lghcc-train --evaluate``).

Either kind of scene renders: an ``AnchorScene`` through its render MLPs (neural Gaussians),
a ``GaussianScene`` through its SH colours. Cameras are a list of ``Camera`` or a spec that
``cameras_from_spec`` reads (``orbit:N``, a dataset folder of any layout, a transforms
JSON, a COLMAP sparse folder, ``poses_bounds.npy``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..common.errors import InputError
from ..common.scene import AnchorScene, GaussianScene
from .camera import Camera

MLP_ROLES = ("opacity", "cov", "color")


def scene_points(scene: AnchorScene | GaussianScene) -> np.ndarray:
    """The scene's points [N, 3] float64 (Gaussian means or anchor positions)."""
    if isinstance(scene, GaussianScene):
        return np.asarray(scene.means, np.float64)
    if isinstance(scene, AnchorScene):
        return np.asarray(scene.positions(), np.float64)
    raise InputError(f"expected an AnchorScene or a GaussianScene, got {type(scene).__name__}")


def check_renderable(scene: AnchorScene | GaussianScene) -> None:
    """InputError for an anchor scene without its render MLPs (nothing defines its colours)."""
    if isinstance(scene, AnchorScene):
        missing = [r for r in MLP_ROLES if r not in scene.mlps]
        if missing:
            raise InputError(f"the anchor scene has no {', '.join(missing)} MLP: it cannot be rendered or exported "
                             "(its stream was coded without render MLPs)")


def resolve_cameras(cameras: str | Sequence[Camera], scene: AnchorScene | GaussianScene | None = None, *,
                    size: tuple[int, int] = (256, 256), scale: float = 1.0, split: str = "test") -> list[Camera]:
    """A list of cameras from a list (as it is) or a spec (``cameras_from_spec``; ``orbit:N``
    circles ``scene``, ``size`` = (width, height))."""
    if isinstance(cameras, str) or hasattr(cameras, "__fspath__"):
        from .views import cameras_from_spec

        pts = scene_points(scene) if scene is not None else np.zeros((1, 3))
        return cameras_from_spec(str(cameras), pts, width=size[0], height=size[1], scale=scale, split=split)
    cams = list(cameras)
    if not cams or not all(isinstance(c, Camera) for c in cams):
        raise InputError("cameras: expected a non-empty list of lghcc Camera objects or a camera spec string")
    return cams


def framing_points(scene: AnchorScene | GaussianScene) -> np.ndarray:
    """The points orbit cameras frame: anchor positions, or the means of the Gaussians with
    opacity >= 0.05 (faint floaters do not widen the orbit; all of them when fewer than 10)."""
    if isinstance(scene, GaussianScene):
        keep = scene.opacity >= np.log(0.05 / 0.95)
        return np.asarray(scene.means[keep] if keep.sum() >= 10 else scene.means, np.float64)
    return scene_points(scene)


def render_fn(scene: AnchorScene | GaussianScene, backend: str = "torch") -> Callable[[Camera, Any], np.ndarray]:
    """A function (camera, background) -> image [H, W, 3] float32 in [0, 1] for ``scene``
    (background: 'black', 'white', 3 numbers or a tensor). ``backend``: 'torch' (the CPU
    reference rasterizer; the default, so numbers match on every machine), 'gsplat' or 'auto'."""
    import torch

    from .imageio import background_color

    check_renderable(scene)
    if isinstance(scene, GaussianScene):
        from .gaussians3dgs import gaussians_from_scene, render_3dgs

        g = gaussians_from_scene(scene)
        draw = lambda cam, bg: render_3dgs(g, cam, background=bg, backend=backend)  # noqa: E731
    else:
        from .neural_gaussians import SceneTensors
        from .rasterizer import render_scene

        st = SceneTensors.from_scene(scene)
        draw = lambda cam, bg: render_scene(st, cam, background=bg, backend=backend)  # noqa: E731

    def render(cam: Camera, background: Any = "black") -> np.ndarray:
        bg = background if isinstance(background, torch.Tensor) else torch.as_tensor(
            np.asarray(background_color(background), np.float32).reshape(3))
        with torch.no_grad():
            return draw(cam, bg).image.clamp(0, 1).float().cpu().numpy()
    return render


def renderer(scene: AnchorScene | GaussianScene, background: Any = "black",
             backend: str = "torch") -> Callable[[Camera], np.ndarray]:
    """``render_fn`` with the background fixed: camera -> image."""
    fn = render_fn(scene, backend)
    return lambda cam: fn(cam, background)


def render_views(scene: AnchorScene | GaussianScene, cameras: str | Sequence[Camera], *, background: Any = "black",
                 size: tuple[int, int] = (256, 256), backend: str = "torch") -> list[np.ndarray]:
    """Images [H, W, 3] float32 in [0, 1] of ``scene`` from ``cameras`` (module doc)."""
    draw = renderer(scene, background, backend)
    return [draw(c) for c in resolve_cameras(cameras, scene, size=size)]


@dataclass
class Evaluation:
    """Mean PSNR (dB) and SSIM over the views, and the values of each view."""

    psnr: float
    ssim: float
    views: int
    psnr_views: list[float] = field(default_factory=list)
    ssim_views: list[float] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"psnr": self.psnr, "ssim": self.ssim, "views": self.views, "psnr_views": self.psnr_views,
                "ssim_views": self.ssim_views}


def evaluate(scene: AnchorScene | GaussianScene, reference: AnchorScene | GaussianScene | None = None,
             cameras: str | Sequence[Camera] = "orbit:8", *, background: Any = "black",
             size: tuple[int, int] = (256, 256), backend: str = "torch") -> Evaluation:
    """PSNR/SSIM of ``scene`` rendered from ``cameras`` against ``reference`` rendered from the
    same cameras, or (``reference`` None) against the cameras' own images (a dataset's test
    views: ``cameras`` a dataset folder, whose images are then loaded, or Cameras with
    ``image``). ``orbit:N`` circles the reference (else the scene)."""
    from .metrics import psnr, ssim

    if reference is None and isinstance(cameras, str) and not cameras.strip().startswith("orbit:"):
        from .datasets import load_dataset

        cams = load_dataset(cameras, background=background).test
    else:
        cams = resolve_cameras(cameras, reference if reference is not None else scene, size=size)
    if reference is None:
        if any(c.image is None for c in cams):
            raise InputError("evaluate: the cameras carry no images; give a reference scene or a dataset folder")
        targets = (c.image for c in cams)
    else:
        ref_draw = renderer(reference, background, backend)
        targets = (ref_draw(c) for c in cams)
    draw = renderer(scene, background, backend)
    ps, ss = [], []
    for cam, target in zip(cams, targets):
        img = draw(cam)
        ps.append(float(psnr(img, target)))
        ss.append(float(ssim(img, target)))
    return Evaluation(float(np.mean(ps)), float(np.mean(ss)), len(ps), ps, ss)


def to_gaussians(scene: AnchorScene | GaussianScene, sh_degree: int | None = None, *, directions: int = 16,
                 distance: float | None = None) -> GaussianScene:
    """A plain 3DGS scene for viewers and other formats. A GaussianScene as it is (at most
    ``sh_degree``); an AnchorScene's neural Gaussians with SH colours of degree ``sh_degree``
    (default 1) fitted to its colour MLP over ``directions`` view directions at ``distance``
    (render/export.py)."""
    if isinstance(scene, GaussianScene):
        return scene if sh_degree is None else scene.with_sh_degree(sh_degree)
    check_renderable(scene)
    from .export import export_3dgs

    ex = export_3dgs(scene, None, sh_degree=1 if sh_degree is None else sh_degree, num_directions=directions,
                     distance=distance)
    return GaussianScene(ex.means.astype(np.float32), ex.sh.astype(np.float32), ex.opacity_logits.astype(np.float32),
                         ex.log_scales.astype(np.float32), ex.quats.astype(np.float32))
