"""What a file or folder that no scene reader claims looks like, in words, for the one error
that says what was expected and what was found (formats.detect_format)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from ..common.errors import InputError

SHOWN_NAMES = 8  # how many keys, properties or entries a description lists
JSON_READ_LIMIT = 1 << 20  # a JSON file is parsed for its keys only up to this size


def _listed(names: list[str]) -> str:
    more = f", ... ({len(names)} in all)" if len(names) > SHOWN_NAMES else ""
    return ", ".join(names[:SHOWN_NAMES]) + more


def _folder(path: Path) -> str:
    for name in ("lod-meta.json", "meta.json"):
        if (path / name).is_file():
            return f"a folder holding {name} (give that file itself)"
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in path.iterdir())
    return ("a folder without point_cloud/iteration_<N>/point_cloud.ply"
            + (f" (holding {_listed(names)})" if names else " (empty)"))


def _ply(path: Path) -> str:
    from .ply3dgs import ply_property_names

    try:
        names = ply_property_names(path, "vertex")
    except InputError as e:
        return f"a PLY file whose header cannot be read ({e})"
    return (f"a PLY file whose vertex properties are {_listed(names) or 'none'} (neither f_dc_* of a 3DGS PLY, "
            "packed_* of a compressed PLY nor f_anchor_feat_* of a Scaffold-GS anchor PLY)")


def _json(path: Path) -> str:
    try:
        if path.stat().st_size > JSON_READ_LIMIT:
            return "a JSON file"
        data = json.loads(path.read_bytes())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return "a file that starts like JSON but does not parse as JSON"
    if isinstance(data, dict):
        return f"a JSON object with keys {_listed(list(data)) or 'none'} (no 'means' of SOG, no 'lodLevels' " \
               "of streamed SOG)"
    return f"a JSON {type(data).__name__}"


def _zip(path: Path) -> str:
    try:
        with zipfile.ZipFile(path) as z:
            return f"a zip archive without meta.json (entries: {_listed(z.namelist()) or 'none'})"
    except (zipfile.BadZipFile, OSError):
        return "a file that starts like a zip archive but cannot be opened as one"


def describe_content(path: Path, head: bytes) -> str:
    """``path`` in words: a folder and what it holds, the kind of file and what it holds (a PLY's
    properties, a JSON object's keys, a zip's entries), or its first bytes."""
    if path.is_dir():
        return _folder(path)
    if not head:
        return "an empty file"
    if head.startswith(b"ply"):
        return _ply(path)
    if head.lstrip().startswith((b"{", b"[")):
        return _json(path)
    if head.startswith(b"PK\x03\x04"):
        return _zip(path)
    if head.startswith(b"\x1f\x8b"):
        return "a gzip stream that is not SPZ"
    return f"a file starting with {head[:8]!r}"
