"""Posed-image datasets (informative): which layout a folder is, by its files, and its views.

Layouts:

* **NeRF-synthetic**: ``transforms_train.json`` (and ``transforms_test.json``; without it
  every 8th training view is a test view), images as the frames name them.
* **COLMAP**: a sparse model in ``sparse/0/`` or ``sparse/`` (``cameras``, ``images``,
  ``points3D`` as ``.bin`` or ``.txt``) and the images in ``images/``. **Mip-NeRF 360** is this
  layout with downscaled copies in ``images_2/``, ``images_4/``, ``images_8/``, and so is an
  **LLFF** scene that kept its ``sparse/0`` (LLFF's ``poses_bounds.npy`` was computed from
  it, in the same world frame): whenever a sparse model is there, the cameras come from it
  (exact intrinsics) and its points3D are the SfM points (``lghcc-train --init sfm``).
* **LLFF** without a sparse model: ``poses_bounds.npy`` and ``images/`` (or ``images_N/``).

Test views: NeRF-synthetic's test split; for the others every 8th view (sorted by image
name), the rest train (the convention of Mip-NeRF 360 and 3DGS).

Downscaling: ``downscale=N`` reads ``images_N/`` when the folder has it (the images as the
dataset ships them; Mip-NeRF 360's, LLFF's), else ``images/`` averaged down by N. Images in
``images_N/`` may keep the sparse model's names (Mip-NeRF 360) or be renamed (LLFF's
``image000.png``): they are matched by name, then by stem, then in sorted order.
"""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..common.errors import InputError
from .camera import Camera, load_colmap, load_llff, load_nerf_synthetic, sparse_folder
from .imageio import background_color

_IMAGE_EXTS = (".png", ".jpg", ".jpeg")
TEST_EVERY = 8


@dataclass
class DatasetLayout:
    """What ``detect_dataset`` found: ``kind`` (nerf_synthetic, colmap, llff), the folder, the
    sparse model (COLMAP kinds), the image folder to read and the downscale factor its images
    already have (images_4: 4), and a description for messages."""

    kind: str
    root: Path
    sparse: Path | None
    images: str
    images_factor: int
    description: str


@dataclass
class Dataset:
    kind: str  # nerf_synthetic | llff | colmap
    train: list  # list[Camera] (with images when loaded)
    test: list
    sfm_points: np.ndarray | None = None
    layout: DatasetLayout | None = None


def parse_background(spec: Any) -> np.ndarray:
    """'white', 'black', 'r,g,b' (numbers in [0, 1]) or 3 numbers -> float32 [3]."""
    if isinstance(spec, str) and "," in spec:
        try:
            spec = tuple(float(v) for v in spec.split(","))
        except ValueError:
            raise InputError(f"background must be 'white', 'black' or r,g,b, got {spec!r}") from None
    return background_color(spec)


def downscaled_folders(root: Path) -> dict[int, str]:
    """{N: 'images_N'} for the downscaled image folders a dataset has."""
    out = {}
    if root.is_dir():
        for d in root.iterdir():
            m = re.fullmatch(r"images_(\d+)", d.name)
            if m and d.is_dir() and int(m.group(1)) >= 1:
                out[int(m.group(1))] = d.name
    return out


def detect_dataset(data: str | os.PathLike, images: str | None = None, downscale: int = 1) -> DatasetLayout:
    """The layout of a dataset folder (module doc); InputError naming what is missing."""
    root = Path(data)
    if not root.exists():
        raise InputError(f"{root}: data folder not found")
    if not root.is_dir():
        raise InputError(f"{root}: not a folder (give the folder holding transforms_train.json, sparse/0 or "
                         "poses_bounds.npy)")
    if downscale < 1:
        raise InputError(f"--downscale must be a positive integer, got {downscale}")
    if (root / "transforms_train.json").is_file():
        return DatasetLayout("nerf_synthetic", root, None, images or "", 1, "NeRF-synthetic (transforms_*.json)")
    sparse = sparse_folder(root)
    llff = (root / "poses_bounds.npy").is_file()
    if sparse is None and not llff:
        raise InputError(f"{root}: no transforms_train.json (NeRF-synthetic), sparse/0 (COLMAP, Mip-NeRF 360) or "
                         "poses_bounds.npy (LLFF) found")
    factor = 1
    if images is None:
        scaled = downscaled_folders(root)
        if downscale > 1 and downscale in scaled:
            images, factor = scaled[downscale], downscale
        else:
            images = "images"
    else:
        m = re.fullmatch(r"images_(\d+)", Path(images).name)
        factor = int(m.group(1)) if m else 1
    extra = sorted(downscaled_folders(root))
    if sparse is not None:
        what = "COLMAP " + ("sparse/0" if sparse.name == "0" else "sparse" if sparse.name == "sparse" else "model")
        if extra:
            what += " + " + ", ".join(f"images_{n}" for n in extra) + " (Mip-NeRF 360 / LLFF layout)"
        if llff:
            what += "; poses_bounds.npy not needed"
        return DatasetLayout("colmap", root, sparse, images, factor, what)
    return DatasetLayout("llff", root, None, images, factor, "LLFF (poses_bounds.npy)")


def match_images(names: list[str], folder: Path) -> dict[str, Path]:
    """Image files of ``folder`` for the sparse model's image ``names``: by name, else by stem
    (another extension), else in sorted order when the counts agree (LLFF's renamed
    downscales). InputError when they cannot be matched."""
    if not folder.is_dir():
        raise InputError(f"{folder}: image folder not found")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXTS)
    by_name = {p.name: p for p in files}
    by_stem: dict[str, Path] = {}
    for p in files:
        by_stem.setdefault(p.stem, p)
    out = {}
    for n in names:
        p = folder / n
        if p.is_file():
            out[n] = p
        elif Path(n).name in by_name:
            out[n] = by_name[Path(n).name]
        elif Path(n).stem in by_stem:
            out[n] = by_stem[Path(n).stem]
    if len(out) == len(names):
        return out
    if len(files) == len(names):  # renamed copies (LLFF images_N: image000.png ...): sorted order
        return dict(zip(sorted(names), files))
    missing = [n for n in names if n not in out]
    raise InputError(f"{folder}: {len(missing)} of the model's {len(names)} images not found (first: {missing[0]}), "
                     f"and it holds {len(files)} images, so they cannot be matched in order either")


def _downscale(cams: list, factor: int) -> list:
    if factor == 1:
        return cams
    import torch
    import torch.nn.functional as F

    out = []
    for c in cams:
        s = c.scaled(1.0 / factor)
        if c.image is None:
            out.append(s)
            continue
        img = torch.from_numpy(np.ascontiguousarray(c.image)).permute(2, 0, 1)[None]
        small = F.interpolate(img, size=(s.height, s.width), mode="area")[0].permute(1, 2, 0).numpy()
        out.append(dataclasses.replace(s, image=np.ascontiguousarray(small, dtype=np.float32)))
    return out


def _check_sizes(cams: list, what: str) -> None:
    for c in cams:
        if c.image is not None and c.image.shape[:2] != (c.height, c.width):
            raise InputError(f"{what}: image {c.name!r} does not match its camera size {c.width}x{c.height}")
    first = cams[0] if cams else None
    for c in cams:
        if (c.width, c.height) != (first.width, first.height):
            raise InputError(f"{what}: image {c.name!r} is {c.width}x{c.height} but {first.name!r} (the first view) is "
                             f"{first.width}x{first.height}: the images have different sizes; all views must share one size")


def split_views(cams: list) -> tuple[list, list]:
    """(train, test): every TEST_EVERY-th view (0, 8, 16, ...) tests."""
    return [c for i, c in enumerate(cams) if i % TEST_EVERY], cams[::TEST_EVERY]


def load_dataset(data: str | os.PathLike, background: Any = "white", downscale: int = 1, images: str | None = None,
                 load_images: bool = True) -> Dataset:
    """The views of a dataset folder (module doc); raises InputError naming the file for
    every problem. Without ``load_images`` the cameras have no images (sizes from the files'
    headers or the model), for rendering."""
    lay = detect_dataset(data, images, downscale)
    root = lay.root
    bg = parse_background(background)
    sfm = None
    if lay.kind == "nerf_synthetic":
        train = load_nerf_synthetic(root, "train", background=bg, load_images=load_images)
        if (root / "transforms_test.json").is_file():
            test = load_nerf_synthetic(root, "test", background=bg, load_images=load_images)
        else:
            test = train[::TEST_EVERY]
        _check_sizes(train, str(root / "transforms_train.json"))
        if (root / "transforms_test.json").is_file():
            _check_sizes(test, str(root / "transforms_test.json"))
        resample = downscale
    else:
        if lay.kind == "colmap":
            from .camera import read_colmap_model

            model = read_colmap_model(lay.sparse)
            paths = None
            if load_images:
                paths = match_images([im.name for im in model.images.values()], root / lay.images)
            cams, model = load_colmap(lay.sparse, root / lay.images, load_images=load_images, background=bg,
                                      image_paths=paths, model=model)
            sfm = model.points_xyz if len(model.points_xyz) else None
            where = str(lay.sparse)
        else:
            cams = load_llff(root, images_dir=lay.images, load_images=load_images, background=bg)
            where = str(root / "poses_bounds.npy")
        if not load_images and lay.images_factor > 1:  # the size of the images in images_N
            cams = [c.scaled(1.0 / lay.images_factor) for c in cams]
        _check_sizes(cams, where)
        train, test = split_views(cams)
        resample = max(1, round(downscale / lay.images_factor)) if downscale > 1 else 1
    if not train:
        raise InputError(f"{root}: no training views")
    if not test:
        raise InputError(f"{root}: no test views")
    return Dataset(lay.kind, _downscale(train, resample), _downscale(test, resample), sfm, lay)


def dataset_cameras(data: str | os.PathLike, split: str = "test", images: str | None = None) -> list[Camera]:
    """Cameras (no images) of a dataset folder's ``split``: test, train or all."""
    ds = load_dataset(data, "black", 1, images, load_images=False)
    if split == "test":
        return ds.test
    if split == "train":
        return ds.train
    if split == "all":
        return ds.train + ds.test if ds.kind == "nerf_synthetic" else sorted(ds.train + ds.test, key=lambda c: c.name)
    raise InputError(f"split must be test, train or all, got {split!r}")
