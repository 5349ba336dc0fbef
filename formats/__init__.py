"""Scene file formats (informative): reading and writing the files 3DGS users exchange.

Every reader returns a validated ``lghcc.common.scene.GaussianScene`` (or raises InputError
naming the file and the problem); every writer writes atomically.

``read_scene(path)`` picks the reader by the file's content (its first bytes), the name's
extension deciding only where the content does not (an empty or truncated file is then
reported by the reader of its extension); ``write_scene(scene, path)`` picks the writer by
the extension. Formats: INRIA 3DGS PLY (``.ply``), Niantic SPZ (``.spz``, v2-v4), PlayCanvas
SOG (a ``.sog`` bundle; also read: an unbundled ``meta.json`` with its images). Another format (a folder layout, a codec stream) is
added with ``register_format``.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from lghcc.common.errors import InputError
from lghcc.common.scene import GaussianScene
from lghcc.formats.ply3dgs import read_3dgs_ply, write_3dgs_ply
from lghcc.formats.sog import read_sog, write_sog
from lghcc.formats.spz import is_spz_bytes, read_spz, write_spz

HEAD_BYTES = 4096  # what a format's sniff sees of a file (enough to inflate the start of a gzip stream)


@dataclass(frozen=True)
class SceneFormat:
    """A file format ``read_scene``/``write_scene`` know.

    ``sniff(path, head)`` is True when the content is this format (``head``: the file's first
    HEAD_BYTES bytes, b"" for a folder); ``suffixes`` (lower case, with the dot) name its files
    for writing and for files whose content no sniff claims. ``read(path)`` or
    ``write(path, scene, **options)`` may be None for a read-only or write-only format."""

    name: str
    suffixes: tuple[str, ...]
    sniff: Callable[[Path, bytes], bool]
    read: Callable[[Path], GaussianScene] | None
    write: Callable[..., None] | None


def _is_sog(path: Path, head: bytes) -> bool:
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(path) as z:
                return "meta.json" in z.namelist()
        except (zipfile.BadZipFile, OSError):
            return False
    return path.name.lower().endswith(".json") and head.lstrip().startswith(b"{") and b'"means"' in head


def _write_ply(path: Path, scene: GaussianScene, comments: list[str] = ()) -> None:
    write_3dgs_ply(path, scene, comments)


_FORMATS: list[SceneFormat] = [
    SceneFormat("3dgs-ply", (".ply",), lambda p, head: head.startswith(b"ply"), read_3dgs_ply, _write_ply),
    SceneFormat("spz", (".spz",), lambda p, head: is_spz_bytes(head), read_spz, write_spz),
    SceneFormat("sog", (".sog",), _is_sog, read_sog, write_sog),
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
    by_name = [f for f in claims or readable if _suffix_matches(f, p)]
    if by_name or claims:
        return (by_name or claims)[0]
    kind = "folder" if p.is_dir() else f"file starting with {head[:8]!r}"
    known = ", ".join(f"{f.name} ({' '.join(f.suffixes)})" for f in readable)
    raise InputError(f"{p}: not a scene this version reads ({kind}); formats: {known}")


def read_scene(path: str | os.PathLike) -> GaussianScene:
    """Read a scene file of any known format (``detect_format``) into a validated GaussianScene."""
    p = Path(path)
    return detect_format(p).read(p)


def write_scene(scene: GaussianScene, path: str | os.PathLike, **options: Any) -> None:
    """Write ``scene`` atomically in the format named by the extension of ``path`` (``.ply``,
    ``.spz``, ``.sog``); ``options`` go to that writer (SPZ: ``version``, ``antialiased``; SOG:
    ``iterations``, ``palette``, ``seed``; PLY: ``comments``)."""
    p = Path(path)
    for f in _FORMATS:
        if f.write is not None and _suffix_matches(f, p):
            scene.validate(str(p))
            f.write(p, scene, **options)
            return
    known = ", ".join(s for f in _FORMATS if f.write is not None for s in f.suffixes)
    raise InputError(f"{p}: cannot tell the format to write from the file name; use one of {known}")
