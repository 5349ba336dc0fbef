"""lghcc as a library: the functions ``import lghcc`` gives (see the package doc).

Every function imports what it needs when called: ``import lghcc`` loads neither torch nor
the encoder, and ``lghcc.decode`` never imports the encoder (the decoder is separable).
Errors a caller can cause raise ``lghcc.LghccError`` (``InputError`` for a bad scene, file
or option; ``BitstreamError`` for a bad stream; ``HashMismatchError`` when a decoded scene
does not match the stream's hash) with a message naming what is wrong.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence, Union

if TYPE_CHECKING:
    import numpy as np

    from .common.scene import AnchorScene, GaussianScene
    from .render.camera import Camera
    from .render.datasets import Dataset
    from .render.scenes import Evaluation

    Scene = Union[AnchorScene, GaussianScene]

PathLike = Union[str, "os.PathLike[str]"]


def read_scene(path: PathLike, **options: Any) -> "Scene":
    """Read a scene, its format found by content, then extension: a 3DGS PLY, SPZ (v2-v4), SOG
    (``.sog`` or ``meta.json``), PlayCanvas compressed PLY, streamed SOG (``lod-meta.json``: one
    level of detail, ``lod=N``; default the level with the most Gaussians), ``.splat``,
    ``.ksplat``, a 3DGS model folder (``point_cloud/iteration_N/``) -> ``GaussianScene``; a
    Scaffold-GS / HAC model (folder, iteration folder or anchor PLY, render MLPs from
    ``checkpoint.pth`` beside it) -> ``AnchorScene``. Anything else: one InputError naming what
    was expected and what the path holds."""
    from .formats import read_scene as _read

    return _read(path, **options)


def write_scene(scene: "Scene", path: PathLike, **options: Any) -> Path:
    """Write a scene (each file atomically; an existing file is replaced): a GaussianScene by
    the extension of ``path`` (``.ply``, ``.spz``, ``.sog``; a path without one: a 3DGS model
    folder); an AnchorScene as a Scaffold-GS model folder. Returns the path written."""
    from .formats import write_scene as _write

    return _write(scene, path, **options)


def encode(scene: "Scene | PathLike", preset: str = "medium", *, config: PathLike | None = None,
           verify: bool = True, progress: bool = False, allow_missing_mlps: bool = False,
           cameras: "PathLike | Sequence[Camera] | None" = None, **options: Any) -> bytes:
    """Encode a scene (or the scene a path names, ``read_scene``) into one .lghcc stream.

    ``preset``: ``low``, ``medium``, ``high`` (both kinds of scene), ``fast`` and ``web``
    (Gaussian scenes, no renders; ``web`` decodes faster in JavaScript) or ``lghcc-low``,
    ``lghcc-medium``, ``lghcc-high`` (anchor scenes; they fit a context model: minutes).
    ``config``: a YAML file of encoder options; ``options``: more of them (e.g.
    ``feature_step=0.01`` for anchor scenes, ``rd_lambda=0.5`` or ``sh_degree=1`` for Gaussian
    scenes; encoder/stream/config.py lists them). ``verify`` decodes the stream again and checks its
    hash. An anchor scene without render MLPs is refused unless ``allow_missing_mlps``.
    ``cameras``: a Gaussian scene's capture cameras (a path ``load_capture_cameras`` reads, or
    Camera objects), where its render-based choices look from; None: ``views`` (an option:
    ``"auto"``, ``"orbit"``, ``"inside"``, ``"both"``) places them."""
    from .encoder import api as enc

    if isinstance(scene, (str, os.PathLike)):
        scene = read_scene(scene)
    if isinstance(cameras, (str, os.PathLike)):
        from .render.camera import load_capture_cameras

        cameras = load_capture_cameras(cameras)
    cfg = enc.encoder_config(scene, preset, config, options)
    result, _ = enc.encode(scene, cfg, progress=progress, verify=verify, allow_missing_mlps=allow_missing_mlps,
                           cameras=None if cameras is None else list(cameras))
    return result.data


def decode(data: bytes | bytearray | memoryview | PathLike, *, verify: bool = True, jobs: int = 1,
           box: tuple[float, float, float, float, float, float] | None = None, level: int = 2) -> "Scene":
    """Decode a .lghcc stream (its bytes, or a path to it) into the scene it carries: a
    GaussianScene (a stream coded from Gaussians) or an AnchorScene. ``verify`` checks the
    decoded scene against the hash in the stream (HashMismatchError when they differ; per tile
    in a tiled stream). ``jobs``: worker processes for the tiles (the result does not depend on
    it). ``box`` (x0, y0, z0, x1, y1, z1, world coordinates): only the tiles whose cell meets it.
    ``level`` 1: the level-1 preview (not hash-checked)."""
    from .common.errors import InputError
    from .decoder.decode import decode_stream

    if isinstance(data, (str, os.PathLike)):
        try:
            data = Path(data).read_bytes()
        except OSError as e:
            raise InputError(f"{data}: cannot read ({e.strerror})") from None
    from .common.tiles import Box

    if box is not None:
        if len(box) != 6 or any(lo > hi for lo, hi in zip(box[:3], box[3:])):
            raise InputError(f"box: expected (x0, y0, z0, x1, y1, z1) with x0 <= x1, y0 <= y1, z0 <= z1, got {box!r}")
        box = Box(tuple(map(float, box[:3])), tuple(map(float, box[3:])))
    if level not in (1, 2):
        raise InputError(f"level: 1 (the preview) or 2 (everything), got {level!r}")
    if jobs < 1:
        raise InputError(f"jobs: at least 1, got {jobs!r}")
    return decode_stream(bytes(data), verify_hash=verify, jobs=jobs, box=box, max_level=level).scene


def load_cameras(spec: "str | PathLike", scene: "Scene | None" = None, *, size: tuple[int, int] = (256, 256),
                 scale: float = 1.0, split: str = "test") -> "list[Camera]":
    """Cameras from ``orbit:N`` (N views circling ``scene``, ``size`` = (width, height)) or from
    a dataset: a folder of any layout (NeRF-synthetic, COLMAP bin/txt, Mip-NeRF 360, LLFF;
    its ``split``: test, train or all), a ``transforms_<split>.json``, a COLMAP sparse folder,
    a ``poses_bounds.npy``. File cameras are scaled by ``scale``."""
    from .render.scenes import resolve_cameras

    return resolve_cameras(str(spec), scene, size=size, scale=scale, split=split)


def load_dataset(path: PathLike, *, downscale: int = 1, background: Any = "white", images: str | None = None,
                 load_images: bool = True) -> "Dataset":
    """The posed images of a dataset folder, its layout found by its files: ``.kind``,
    ``.train`` and ``.test`` (lists of Camera with ``.image``), ``.sfm_points`` (COLMAP
    points3D, or None). ``downscale`` N reads ``images_N/`` when present."""
    from .render.datasets import load_dataset as _load

    return _load(path, background, downscale, images, load_images=load_images)


def render_views(scene: "Scene", cameras: "str | Sequence[Camera]" = "orbit:8", *, background: Any = "black",
                 size: tuple[int, int] = (256, 256)) -> "list[np.ndarray]":
    """Images (float32 [H, W, 3] in [0, 1]) of either kind of scene, rendered on the CPU from
    ``cameras``: a list of Camera or a spec as ``load_cameras`` takes."""
    from .render.scenes import render_views as _render

    return _render(scene, cameras, background=background, size=size)


def evaluate(scene: "Scene", reference: "Scene | None" = None, cameras: "str | Sequence[Camera]" = "orbit:8", *,
             background: Any = "black", size: tuple[int, int] = (256, 256)) -> "Evaluation":
    """PSNR (dB) and SSIM of ``scene`` against ``reference`` (another scene, rendered from the
    same cameras), or, with no reference, against a dataset's test images (``cameras`` a
    dataset folder, or Cameras carrying images). -> Evaluation(psnr, ssim, views, per view)."""
    from .render.scenes import evaluate as _evaluate

    return _evaluate(scene, reference, cameras, background=background, size=size)


def to_gaussians(scene: "Scene", sh_degree: int | None = None, *, directions: int = 16) -> "GaussianScene":
    """A plain 3DGS scene (for viewers, ``write_scene`` to .ply/.spz/.sog): a GaussianScene as
    it is (at most ``sh_degree``); an AnchorScene's neural Gaussians with SH colours (degree 1
    by default) fitted to its colour MLP over ``directions`` view directions."""
    from .render.scenes import to_gaussians as _to

    return _to(scene, sh_degree, directions=directions)
