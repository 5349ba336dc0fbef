"""lghcc: reference codec for LG-HCC compression of 3D Gaussian Splatting scenes.

As a library::

    import lghcc

    scene = lghcc.read_scene("scene.ply")             # 3DGS PLY, SPZ, SOG, Scaffold-GS model
    data = lghcc.encode(scene, preset="medium")       # bytes of one .lghcc stream
    decoded = lghcc.decode(data)                      # hash-checked
    lghcc.write_scene(decoded, "decoded.spz")
    print(lghcc.evaluate(decoded, scene, "orbit:8"))  # PSNR / SSIM against the source

Functions (api.py): ``read_scene``, ``write_scene``, ``encode``, ``decode``,
``load_cameras``, ``load_dataset``, ``render_views``, ``evaluate``, ``to_gaussians``.
Types: ``AnchorScene``, ``GaussianScene``, ``Camera``, ``Evaluation``; errors:
``LghccError`` and its subclasses. ``import lghcc`` is light (no torch, no encoder); each
function loads what it needs.

Layout: the repository root is the package ``lghcc``, so a folder path is an import path
(common/geometry.py is lghcc.common.geometry) and every import inside the package is relative,
resolvable from a plain checkout (docs/architecture.md):
  common/      normative: syntax, bitstream, geometry, entropy coding, context models (spec/)
  decoder/     normative decoding process, lghcc-dec (imports common/, never the encoder)
  encoder/     informative: quantization choices, model fitting, lghcc-enc, lghcc-train
  render/      informative: neural Gaussians, rasterizer, metrics, datasets
  formats/     informative: scene files (3DGS PLY, SPZ, SOG, Scaffold-GS) and the procedural scene
  app/         informative: command-line arguments, exit statuses, atomic files, progress, reports
  conformance/ conformance streams, their runner, mutation list and fuzzer
  viewer/, batch/  lghcc-view and lghcc-batch
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

# Imported as the package (always, except: pytest imports the __init__.py of the folder it collects
# from, here the repository root, as a lone module when the checkout's folder name is not an
# identifier, e.g. lghcc-main; that import has no package to import from and nothing to set up).
if __package__:
    from .api import (decode, encode, evaluate, load_cameras, load_dataset, read_scene, render_views,
                      to_gaussians, write_scene)
    from .common.errors import BitstreamError, HashMismatchError, InputError, LghccError

__version__ = "0.1.0"

if TYPE_CHECKING:
    from .common.scene import AnchorScene, GaussianScene
    from .render.camera import Camera
    from .render.scenes import Evaluation

_LAZY = {
    "AnchorScene": "lghcc.common.scene",
    "GaussianScene": "lghcc.common.scene",
    "Camera": "lghcc.render.camera",
    "Evaluation": "lghcc.render.scenes",
}

__all__ = [
    "__version__", "read_scene", "write_scene", "encode", "decode", "load_cameras", "load_dataset", "render_views",
    "evaluate", "to_gaussians", "AnchorScene", "GaussianScene", "Camera", "Evaluation",
    "LghccError", "InputError", "BitstreamError", "HashMismatchError",
]


def __getattr__(name: str) -> Any:  # the types, imported when first asked for (numpy, not at import lghcc)
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lghcc' has no attribute {name!r}")
