"""Scene file formats (informative): reading and writing the files 3DGS users exchange.

Every reader returns a validated ``lghcc.common.scene.GaussianScene`` (or raises InputError
naming the file and the problem); every writer writes atomically.

``read_scene(path)`` picks the reader by the file's content (its first bytes), the name's
extension deciding only where the content does not (an empty or truncated file is then
reported by the reader of its extension; a PLY that is none of the PLYs below, or a file
neither content nor extension places, is one error saying what was expected and what the file
holds); ``write_scene(scene, path)`` picks the writer by the extension. Formats: INRIA 3DGS
PLY (``.ply``), Niantic SPZ (``.spz``, v2-v4), PlayCanvas SOG (a ``.sog`` bundle; also read:
an unbundled ``meta.json`` with its images); read only: PlayCanvas compressed PLY
(``.compressed.ply``), streamed SOG (``lod-meta.json``, one level of detail: ``lod``),
antimatter15's ``.splat`` and ``.ksplat`` (the last two by extension: they have no header to
sniff); and the anchor scenes of Scaffold-GS / HAC (a model folder, an iteration folder, or an anchor PLY with
its render MLPs in ``checkpoint.pth`` beside it: an ``AnchorScene``). A folder in the 3DGS
layout (``point_cloud/iteration_<N>/point_cloud.ply``, as 3DGS and ``lghcc-dec`` write it)
reads as the plain 3DGS scene in it. ``write_scene`` writes an ``AnchorScene`` as a
Scaffold-GS model folder and a ``GaussianScene`` given a path without a scene extension as
a 3DGS model folder. Another format is added with ``register_format``.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..common.errors import InputError
from ..common.scene import AnchorScene, GaussianScene
from .compressed_ply import is_compressed_ply_header, read_compressed_ply
from .content import describe_content
from .ksplat import read_ksplat
from .ply3dgs import read_3dgs_ply, write_3dgs_ply
from .sog import read_sog, write_sog
from .splat import read_splat
from .spz import is_spz_bytes, read_spz, write_spz
from .streamed_sog import read_streamed_sog

Scene = AnchorScene | GaussianScene  # what read_scene returns

HEAD_BYTES = 4096  # what a format's sniff sees of a file (enough to inflate the start of a gzip stream)


@dataclass(frozen=True)
class SceneFormat:
    """A file format ``read_scene``/``write_scene`` know.

    ``sniff(path, head)`` is True when the content is this format (``head``: the file's first
    HEAD_BYTES bytes, b"" for a folder); ``suffixes`` (lower case, with the dot) name its files
    for writing and for files whose content no sniff claims. ``read(path, **options)`` or
    ``write(path, scene, **options)`` may be None for a read-only or write-only format;
    ``read_options`` names the options its reader takes (e.g. ``lod``)."""

    name: str
    suffixes: tuple[str, ...]
    sniff: Callable[[Path, bytes], bool]
    read: Callable[..., Scene] | None
    write: Callable[..., None] | None
    read_options: tuple[str, ...] = ()


def _is_sog(path: Path, head: bytes) -> bool:
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(path) as z:
                return "meta.json" in z.namelist()
        except (zipfile.BadZipFile, OSError):
            return False
    return _is_json(path, head) and b'"means"' in head


def _is_json(path: Path, head: bytes) -> bool:
    return path.name.lower().endswith(".json") and head.lstrip().startswith(b"{")


def _is_streamed_sog(path: Path, head: bytes) -> bool:
    return _is_json(path, head) and b'"lodLevels"' in head


def _ply_kind(path: Path, head: bytes) -> str | None:
    """Which PLY a file is by its header: 'anchors' (Scaffold-GS), 'compressed' (PlayCanvas),
    '3dgs' (INRIA), or None (not a PLY, or none of these)."""
    if not (path.is_file() and head.startswith(b"ply")):
        return None
    names = _ply_names(path)
    if "f_anchor_feat_0" in names:
        return "anchors"
    if is_compressed_ply_header(names):
        return "compressed"
    return "3dgs" if "f_dc_0" in names else None


def _write_ply(path: Path, scene: GaussianScene, comments: list[str] = ()) -> None:
    write_3dgs_ply(path, scene, comments)


def _located_ply(path: Path) -> Path | None:
    """The PLY a folder holds (Scaffold-GS/3DGS layout: highest iteration), None if none."""
    from .scaffold_io import locate_ply

    try:
        return locate_ply(path)
    except InputError:
        return None


def _ply_names(path: Path) -> list[str]:
    """The vertex properties of a PLY file ([] when its header cannot be read)."""
    from .ply3dgs import ply_property_names

    try:
        return ply_property_names(path, "vertex")
    except InputError:
        return []


def _is_anchor_scene(path: Path, head: bytes) -> bool:
    if path.is_dir():
        ply = _located_ply(path)
        return ply is not None and "f_anchor_feat_0" in _ply_names(ply)
    return _ply_kind(path, head) == "anchors"


def _read_anchor_scene(path: Path) -> AnchorScene:
    from .scaffold_io import read_scaffold

    return read_scaffold(path)


def _is_3dgs_folder(path: Path, head: bytes) -> bool:
    if not path.is_dir():
        return False
    ply = _located_ply(path)
    return ply is not None and "f_dc_0" in _ply_names(ply) and "f_anchor_feat_0" not in _ply_names(ply)


def _read_3dgs_folder(path: Path) -> GaussianScene:
    ply = _located_ply(path)
    if ply is None:
        raise InputError(f"{path}: no point_cloud.ply found")
    return read_3dgs_ply(ply)


def write_3dgs_folder(scene: GaussianScene, folder: str | os.PathLike, iteration: int = 0) -> Path:
    """``folder/point_cloud/iteration_<iteration>/point_cloud.ply`` (the layout of 3DGS); the PLY's path."""
    ply = Path(folder) / "point_cloud" / f"iteration_{iteration}" / "point_cloud.ply"
    ply.parent.mkdir(parents=True, exist_ok=True)
    write_3dgs_ply(ply, scene)
    return ply


_FORMATS: list[SceneFormat] = [
    # anchor scenes first: a Scaffold-GS anchor PLY also starts with "ply"
    SceneFormat("scaffold-gs", (), _is_anchor_scene, _read_anchor_scene, None),
    SceneFormat("3dgs-folder", (), _is_3dgs_folder, _read_3dgs_folder, None),
    SceneFormat("compressed-ply", (".compressed.ply",), lambda p, head: _ply_kind(p, head) == "compressed",
                read_compressed_ply, None),
    SceneFormat("3dgs-ply", (".ply",), lambda p, head: _ply_kind(p, head) == "3dgs", read_3dgs_ply, _write_ply),
    SceneFormat("spz", (".spz",), lambda p, head: is_spz_bytes(head), read_spz, write_spz),
    SceneFormat("sog", (".sog",), _is_sog, read_sog, write_sog),
    SceneFormat("streamed-sog", ("lod-meta.json",), _is_streamed_sog, read_streamed_sog, None, ("lod",)),
    # no header to sniff: known by the extension alone, as splat-transform knows them
    SceneFormat("splat", (".splat",), lambda p, head: False, read_splat, None),
    SceneFormat("ksplat", (".ksplat",), lambda p, head: False, read_ksplat, None),
]


def register_format(fmt: SceneFormat, first: bool = False) -> None:
    """Add a format; ``first`` puts it before the others, so that its sniff and its suffixes
    win (e.g. Scaffold-GS anchor PLYs before plain 3DGS PLYs)."""
    if first:
        _FORMATS.insert(0, fmt)
    else:
        _FORMATS.append(fmt)


def scene_formats() -> tuple[SceneFormat, ...]:
    """The known formats, in the order they are tried."""
    return tuple(_FORMATS)


def _suffix_matches(fmt: SceneFormat, path: Path) -> bool:
    return any(path.name.lower().endswith(s) for s in fmt.suffixes)


def detect_format(path: str | os.PathLike) -> SceneFormat:
    """The format ``read_scene`` would read ``path`` with; InputError when none fits."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    head = b""
    if p.is_file():
        try:
            with open(p, "rb") as f:
                head = f.read(HEAD_BYTES)
        except OSError as e:
            raise InputError(f"{p}: cannot read ({e.strerror})") from None
    readable = [f for f in _FORMATS if f.read is not None]
    claims = [f for f in readable if f.sniff(p, head)]
    # a PLY none claims is told as what it holds, not handed to the reader of its extension
    by_name = [f for f in claims or readable if _suffix_matches(f, p)] if claims or not head.startswith(b"ply") else []
    if by_name or claims:
        return (by_name or claims)[0]
    known = ", ".join(f.name + (f" ({' '.join(f.suffixes)})" if f.suffixes else "") for f in readable
                      if f.name != "scaffold-gs")
    raise InputError(f"{p}: not a scene this version reads: expected a 3DGS scene ({known}) or a Scaffold-GS model "
                     "(a model folder, an iteration folder or an anchor PLY with f_anchor_feat_*); found "
                     + describe_content(p, head))


def read_scene(path: str | os.PathLike, **options: Any) -> Scene:
    """Read a scene of any known format (``detect_format``): a validated GaussianScene, or an
    AnchorScene for a Scaffold-GS model (its MLPs from the checkpoint beside the PLY; a
    ``MissingMlpWarning`` when there is none). ``options`` (None values ignored) go to the
    reader: ``lod`` (streamed SOG: the level of detail; default, the level with the most Gaussians)."""
    p = Path(path)
    fmt = detect_format(p)
    given = {k: v for k, v in options.items() if v is not None}
    for k in given:
        if k not in fmt.read_options:
            takes = [f.name for f in _FORMATS if k in f.read_options]
            raise InputError(f"{p}: option {k!r} applies to {' and '.join(takes) or 'no format'}, this is {fmt.name}")
    return fmt.read(p, **given)


def write_scene(scene: Scene, path: str | os.PathLike, **options: Any) -> Path:
    """Write ``scene`` atomically (each file). A GaussianScene: in the format named by the
    extension of ``path`` (``.ply``, ``.spz``, ``.sog``; ``options`` go to that writer: SPZ
    ``version``, ``antialiased``; SOG ``iterations``, ``palette``, ``seed``; PLY ``comments``),
    or, for a path without one of these extensions, as a 3DGS model folder
    (``point_cloud/iteration_0/point_cloud.ply``). An AnchorScene: as a Scaffold-GS model
    folder (``point_cloud/iteration_0/point_cloud.ply`` and ``checkpoint.pth``).
    Returns the path written (the PLY for a folder)."""
    p = Path(path)
    if isinstance(scene, AnchorScene):
        from .scaffold_io import write_scaffold

        if any(p.name.lower().endswith(s) for f in _FORMATS for s in f.suffixes):
            raise InputError(f"{p}: an anchor scene is written as a Scaffold-GS model folder, not a {p.suffix} "
                             "file; convert it to Gaussians first (lghcc.to_gaussians) to write one")
        return write_scaffold(scene, p)
    if not isinstance(scene, GaussianScene):
        raise InputError(f"write_scene: expected an AnchorScene or a GaussianScene, got {type(scene).__name__}")
    if p.suffix == "" or p.is_dir():
        scene.validate(str(p))
        return write_3dgs_folder(scene, p)
    for f in _FORMATS:
        if f.write is not None and _suffix_matches(f, p):
            scene.validate(str(p))
            f.write(p, scene, **options)
            return p
    known = ", ".join(s for f in _FORMATS if f.write is not None for s in f.suffixes)
    raise InputError(f"{p}: cannot tell the format to write from the file name; use one of {known}")
