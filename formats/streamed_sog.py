"""PlayCanvas streamed SOG (``lod-meta.json``, how SuperSplat and splat-transform publish large
scenes): read one level of detail as a scene. Read only.

Layout as @playcanvas/splat-transform 3.7.0 writes and reads it (``writeLodSource``,
``parseLodMeta``, ``collectFilesByLod`` and ``readLodSource`` in ``dist/index.mjs``):
``lod-meta.json`` holds ``lodLevels``, optionally ``version`` (1) and ``counts`` (Gaussians per
level), ``filenames`` (SOG units, unbundled ``meta.json`` files beside it, e.g.
``0_0/meta.json``) and a ``tree`` of nodes whose ``lods`` map a level to ``{file, offset,
count}``. Each unit holds Gaussians of one level only; a level is the units it references, in
file order, each decoded whole (formats/sog.py). Level 0 is the full scene by splat-transform's
convention (``-l 0``); the default here is the level with the most Gaussians. The units are read
one at a time into the scene's arrays, so the memory needed beyond the scene is one unit.
Not read (as splat-transform does not): the ``environment`` unit and the ``errors`` tables.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..common.errors import InputError
from ..common.scene import GaussianScene
from .sog import read_sog

LOD_META_VERSION = 1


def _is_count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def parse_lod_meta(path: Path) -> dict:
    """The checked JSON of a ``lod-meta.json`` (InputError naming the file and the field)."""
    try:
        meta = json.loads(path.read_bytes())
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: not a JSON object")
    if meta.get("version", LOD_META_VERSION) != LOD_META_VERSION:
        raise InputError(f"{path}: unsupported lod-meta.json version {meta['version']!r}; version 1 is read")
    levels = meta.get("lodLevels")
    if not _is_count(levels) or levels == 0:
        raise InputError(f"{path}: 'lodLevels' must be a positive integer, got {levels!r}")
    counts = meta.get("counts")
    if counts is not None and not (isinstance(counts, list) and len(counts) == levels and all(map(_is_count, counts))):
        raise InputError(f"{path}: 'counts' must be {levels} Gaussian counts")
    names = meta.get("filenames")
    if not (isinstance(names, list) and all(isinstance(f, str) for f in names)):
        raise InputError(f"{path}: 'filenames' must be a list of file names")
    if not isinstance(meta.get("tree"), dict):
        raise InputError(f"{path}: 'tree' must be a JSON object")
    return meta


def _valid_reference(meta: dict, level: str, ref) -> bool:
    return (level.isdigit() and int(level) < meta["lodLevels"] and isinstance(ref, dict)
            and _is_count(ref.get("file")) and ref["file"] < len(meta["filenames"])
            and _is_count(ref.get("offset")) and _is_count(ref.get("count")))


def units_by_level(meta: dict, path: Path) -> dict[int, dict[int, int]]:
    """{level: {file index: Gaussians of that level in it}} from the tree's nodes."""
    units: dict[int, dict[int, int]] = {}
    stack = [meta["tree"]]
    while stack:
        node = stack.pop()
        children = node.get("children", []) if isinstance(node, dict) else None
        if not isinstance(children, list) or not isinstance(node.get("lods", {}), dict):
            raise InputError(f"{path}: a tree node is not an object with 'lods' and a list of 'children'")
        for level, ref in node.get("lods", {}).items():
            if not _valid_reference(meta, level, ref):
                raise InputError(f"{path}: tree reference {level!r}: {ref!r} names no level, file and count")
            files = units.setdefault(int(level), {})
            files[ref["file"]] = files.get(ref["file"], 0) + ref["count"]
        stack.extend(children)
    totals = [sum(units.get(level, {}).values()) for level in range(meta["lodLevels"])]
    if meta.get("counts") is not None and totals != meta["counts"]:
        raise InputError(f"{path}: the tree holds {totals} Gaussians per level, 'counts' says {meta['counts']}")
    return units


def chosen_level(totals: list[int], lod: int | None, path: Path) -> int:
    """``lod`` (negative: from the coarsest end, as splat-transform's -L), or the level with the
    most Gaussians."""
    levels = ", ".join(f"{i} ({t:,} Gaussians)" for i, t in enumerate(totals))
    if lod is None:
        lod = int(np.argmax(totals))
    elif not -len(totals) <= lod < len(totals):
        raise InputError(f"{path}: no level of detail {lod}; the levels: {levels}")
    lod %= len(totals)
    if totals[lod] == 0:
        raise InputError(f"{path}: level of detail {lod} holds no Gaussians; the levels: {levels}")
    return lod


def _copy_unit(out: dict, unit: GaussianScene, start: int) -> None:
    end = start + unit.num_gaussians
    if unit.sh.shape[1] > out["sh"].shape[1]:  # a unit of a higher SH degree: the others' extra bands are 0
        out["sh"] = np.pad(out["sh"], ((0, 0), (0, unit.sh.shape[1] - out["sh"].shape[1]), (0, 0)))
    for field in ("means", "opacity", "log_scales", "rotations"):
        out[field][start:end] = getattr(unit, field)
    out["sh"][start:end, : unit.sh.shape[1]] = unit.sh


def read_streamed_sog(path: str | os.PathLike, lod: int | None = None) -> GaussianScene:
    """Read level of detail ``lod`` (None: the level with the most Gaussians) of a streamed SOG
    into a validated GaussianScene, its units in file order."""
    p = Path(path)
    meta = parse_lod_meta(p)
    units = units_by_level(meta, p)
    totals = [sum(units.get(level, {}).values()) for level in range(meta["lodLevels"])]
    level = chosen_level(totals, lod, p)
    n, start, out = totals[level], 0, None
    for file, count in sorted(units[level].items()):
        unit_path = p.parent / meta["filenames"][file]
        unit = read_sog(unit_path)
        if unit.num_gaussians != count:
            raise InputError(f"{unit_path}: {unit.num_gaussians} Gaussians, {p} gives it {count} of level {level}")
        if out is None:
            out = {"means": np.empty((n, 3), np.float32), "opacity": np.empty(n, np.float32),
                   "log_scales": np.empty((n, 3), np.float32), "rotations": np.empty((n, 4), np.float32),
                   "sh": np.zeros((n, unit.sh.shape[1], 3), np.float32)}
        _copy_unit(out, unit, start)
        start += count
    return GaussianScene(out["means"], out["sh"], out["opacity"], out["log_scales"], out["rotations"]).validate(str(p))
