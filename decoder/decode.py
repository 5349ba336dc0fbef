"""The decoding process (spec clause 13): bitstream in, scene out, nothing else needed.

Critical data units come in the order (clause 6.3)
    scene_parameter_set, [render_model], geometry, [context_model], attribute x (1 or 2), decoded_scene_hash
for an anchor scene, or (version 0.2)
    gaussian_parameter_set, geometry, [context_model], attribute x (1 or 2), decoded_scene_hash
for an explicit-Gaussian scene, with two attribute units (level 1, then level 2) when the
hierarchy is enabled. Ancillary units (type >= 0x80) may appear anywhere after the parameter
set. This decoder knows one, source_info (0x80, clause 7.3.10), and returns what it says
(``DecodeResult.source_info``: the source scene's SH degree, which lghcc-dec --export uses);
it skips the others. The decoded scene and its hash never depend on an ancillary unit: a
source_info this decoder cannot parse, or a second one, is reported (``notes``) and ignored.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from ..app.progress import progress_bar

from ..common import attributes as attr
from ..common.container import AncillaryUnitType, Container, DataUnit, UnitType, read_container
from ..common.errors import BitstreamError, HashMismatchError, ResourceLimitError, UnsupportedStreamError
from ..common.context.models import describe_context_model, level2_coding_params, read_context_model
from ..common.geometry import decode_geometry
from ..common.hashing import digest_of
from ..common.hierarchy import Hierarchy, build_hierarchy
from ..common.render_model import read_render_model_unit
from ..app.report import SizeBreakdown, breakdown_of
from ..common.scene import AnchorScene, GaussianScene
from ..common.syntax import TraceEntry
from ..common.units import (LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_ATTRIBUTE_VALUES, DecodedSceneHashUnit,
                            GaussianParameterSet, SceneParameterSet, SourceInfo)
from .limits import DEFAULT_MAX_MEMORY, MemoryPlan

_LETTER = {UnitType.SCENE_PARAMETER_SET: "S", UnitType.GAUSSIAN_PARAMETER_SET: "P", UnitType.RENDER_MODEL: "R",
           UnitType.GEOMETRY: "G", UnitType.CONTEXT_MODEL: "C", UnitType.ATTRIBUTE: "A",
           UnitType.DECODED_SCENE_HASH: "H"}
# an anchor scene, or (version 0.2) an explicit-Gaussian scene, which has no render model
_UNIT_ORDER = re.compile(r"SR?GC?A{1,2}H|PGC?A{1,2}H")


@dataclass
class DecodeResult:
    scene: AnchorScene | GaussianScene
    breakdown: SizeBreakdown
    hash_checked: bool
    stream_hash: bytes
    skipped_units: list[str] = field(default_factory=list)
    trace: list[TraceEntry] | None = None
    tools: list[str] = field(default_factory=list)  # the coding tools the stream uses, in words
    # the source_info unit (clause 7.3.10), when the stream has one this decoder could parse
    source_info: SourceInfo | None = None
    notes: list[str] = field(default_factory=list)  # ancillary units reported and ignored, in words


_KNOWN_ANCILLARY = set(AncillaryUnitType._value2member_map_)


def organize_units(container: Container, known: list[DataUnit] | None = None) -> tuple[list[DataUnit], list[str]]:
    """Check unit types and their order; return the critical units and the skipped ones (the
    ancillary units this decoder does not know). The ancillary units it knows (clause 6.3)
    are appended to ``known`` when given, else skipped too."""
    critical: list[DataUnit] = []
    skipped: list[str] = []
    for idx, u in enumerate(container.units):
        if u.is_ancillary:
            if not critical:
                raise BitstreamError(f"data unit {idx}: an ancillary unit precedes the scene parameter set (or gaussian parameter set)")
            if known is not None and u.unit_type in _KNOWN_ANCILLARY:
                known.append(u)
            else:
                skipped.append(f"{u.type_name} ({len(u.payload)} bytes at byte {u.offset})")
        elif u.unit_type in _LETTER:
            critical.append(u)
        else:
            raise UnsupportedStreamError(f"data unit {idx} has unit type 0x{u.unit_type:02x}, which this "
                                         "decoder does not know and which is not marked ancillary")
    letters = "".join(_LETTER[UnitType(u.unit_type)] for u in critical)
    if "S" not in letters and "P" not in letters:
        raise BitstreamError("the stream has no scene_parameter_set or gaussian_parameter_set unit")
    for t in (UnitType.GEOMETRY, UnitType.ATTRIBUTE, UnitType.DECODED_SCENE_HASH):
        if _LETTER[t] not in letters:
            raise BitstreamError(f"the stream has no {t.name.lower()} unit")
    if not _UNIT_ORDER.fullmatch(letters):
        names = ", ".join(u.type_name for u in critical)
        raise BitstreamError(f"data units are out of order or repeated: {names} (expected scene_parameter_set, "
                             "[render_model], geometry, [context_model], attribute (1 or 2), decoded_scene_hash; "
                             "or gaussian_parameter_set, geometry, [context_model], attribute (1 or 2), "
                             "decoded_scene_hash)")
    return critical, skipped


@dataclass
class _Levels:
    """What the attribute units of a scene decode into."""
    values: np.ndarray  # float32 [N, M]
    mask: np.ndarray | None  # bool [N, K] (anchor scenes with offset masks)
    hierarchy: Hierarchy | None


def decode_attribute_units(attribute_units: list[DataUnit], layout, steps: np.ndarray, coords: np.ndarray,
                           ps, context_unit: DataUnit | None, entries, progress: bool,
                           memory: MemoryPlan | None = None) -> tuple[_Levels, object]:
    """Decode the one or two attribute units of a scene (clause 13 steps 4-6): level 1 (or every
    point) with its per-channel prior, then level 2 with the context model when there is one.
    ``ps``: the parameter set (hierarchy flag and coarse voxel scale). ``memory``: the memory
    plan each unit is checked against before it is decoded."""
    n = coords.shape[0]
    if len(attribute_units) != (2 if ps.hierarchy_enabled_flag else 1):
        raise BitstreamError(f"{len(attribute_units)} attribute units with hierarchy_enabled_flag = "
                             f"{ps.hierarchy_enabled_flag}")
    context_model = None
    if context_unit is not None:
        if not ps.hierarchy_enabled_flag:
            raise BitstreamError("a context model unit in a stream without the hierarchy")
        context_model = read_context_model(context_unit.payload, layout, entries)
    values = np.empty((n, layout.num_channels), dtype=np.float32)
    mask = np.ones((n, layout.num_offsets), dtype=bool) if layout.offset_mask_present else None
    hier = None
    if ps.hierarchy_enabled_flag:
        hier = build_hierarchy(coords, ps.coarse_voxel_scale)
        if hier.num_level2 == 0:
            raise BitstreamError("hierarchy_enabled_flag is 1 but level 2 is empty")
        levels = [(LEVEL_1, hier.level1_idx), (LEVEL_2, hier.level2_idx)]
    else:
        levels = [(LEVEL_ALL, None)]
    q_level1 = None

    def level2_context(model_id: int) -> attr.CodingParams:
        if context_model is None or model_id != context_model[0]:
            raise BitstreamError(f"the level-2 attribute unit uses context model {model_id}, but the stream's "
                                 "context model unit " + ("is missing" if context_model is None else
                                                          f"holds model {context_model[0]}"))
        return level2_coding_params(context_model, coords[hier.level1_idx], q_level1, coords[hier.level2_idx],
                                    hier.parent_of_level2, ps.coarse_voxel_scale)

    bar = progress_bar(total=n, desc="decode attributes", unit="point", disable=not progress, leave=False)
    for unit, (level, rows) in zip(attribute_units, levels):
        num_rows = n if rows is None else rows.size
        if memory is not None:
            memory.check_attribute_unit(unit.payload, num_rows, level, context_model,
                                        hier.num_level1 if rows is not None else None)
        _, m, q = attr.read_attribute_unit(unit.payload, layout, steps, num_rows, level, values, rows,
                                           level2_context if level == LEVEL_2 else None, entries,
                                           keep_q=level == LEVEL_1 and context_model is not None,
                                           on_chunk=bar.update)
        if level == LEVEL_1:
            q_level1 = q
        if mask is not None:
            mask[slice(None) if rows is None else rows] = m
    bar.close()
    return _Levels(values, mask, hier), context_model


def _hierarchy_tools(ps, hier: Hierarchy | None, context_model, point: str) -> list[str]:
    if not ps.hierarchy_enabled_flag:
        return []
    return [f"two-level hierarchy (coarse voxels of {ps.coarse_voxel_scale}; {hier.num_level1:,} level-1 "
            f"and {hier.num_level2:,} level-2 {point}s)",
            "level-2 context: " + ("per-channel prior" if context_model is None
                                   else describe_context_model(context_model))]


def decode_stream(data: bytes, *, verify_hash: bool = True, trace: bool = False,
                  max_anchors: int | None = None, max_memory: int | None = DEFAULT_MAX_MEMORY,
                  progress: bool = False) -> DecodeResult:
    """Decode a whole stream. Raises a BitstreamError subclass naming the problem, or
    ResourceLimitError for a stream beyond ``max_anchors`` points (anchors or Gaussians) or one
    whose decoding needs more than ``max_memory`` bytes (None: no bound), computed from its
    headers before anything sized by the stream is allocated (decoder/limits.py). ``progress``
    shows a bar of decoded points on stderr."""
    entries: list[TraceEntry] | None = [] if trace else None
    container = read_container(data)
    ancillary: list[DataUnit] = []
    units, skipped = organize_units(container, ancillary)
    by_type: dict[int, list[DataUnit]] = {}
    for u in units:
        by_type.setdefault(u.unit_type, []).append(u)
    ps, layout = _read_parameter_set(by_type, entries)
    source_info, notes = read_source_info(ancillary, entries)
    point = "Gaussian" if isinstance(ps, GaussianParameterSet) else "anchor"
    n = ps.num_anchors
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise BitstreamError(f"{n} {point}s x {layout.num_channels} channels exceeds the level limit of "
                             f"{MAX_ATTRIBUTE_VALUES} attribute values")
    if max_anchors is not None and n > max_anchors:
        raise ResourceLimitError(f"the stream declares {n} {point}s, more than the allowed maximum {max_anchors}")
    memory = MemoryPlan(max_memory, ps, by_type, len(data), layout)  # refuses before anything sized by the stream exists
    context_unit = by_type.get(UnitType.CONTEXT_MODEL, [None])[0]
    mlps = {}
    if UnitType.RENDER_MODEL in by_type:
        mlps = read_render_model_unit(by_type[UnitType.RENDER_MODEL][0].payload, entries)
    coords = decode_geometry(by_type[UnitType.GEOMETRY][0].payload, n, entries)
    steps = layout.steps(ps)
    dec, context_model = decode_attribute_units(by_type[UnitType.ATTRIBUTE], layout, steps, coords, ps, context_unit,
                                                entries, progress, memory)
    scene = _scene_of(ps, layout, coords, dec, mlps)
    hash_unit = DecodedSceneHashUnit.from_bytes(by_type[UnitType.DECODED_SCENE_HASH][0].payload, entries,
                                                what="decoded scene hash unit")
    if verify_hash:
        _check_scene_hash(scene, hash_unit.scene_hash)
    return DecodeResult(scene, breakdown_of(container, n, point), verify_hash, hash_unit.scene_hash, skipped,
                        entries, _stream_tools(ps, dec, context_model, point), source_info, notes)


def _read_parameter_set(by_type: dict[int, list[DataUnit]], entries) -> tuple[SceneParameterSet | GaussianParameterSet,
                                                                              object]:
    """The stream's parameter set (an explicit-Gaussian stream's, else the anchor scene's) and
    its channel layout."""
    if UnitType.GAUSSIAN_PARAMETER_SET in by_type:
        ps = GaussianParameterSet.from_bytes(by_type[UnitType.GAUSSIAN_PARAMETER_SET][0].payload, entries,
                                             what="gaussian parameter set")
        return ps, attr.gaussian_layout_of(ps)
    ps = SceneParameterSet.from_bytes(by_type[UnitType.SCENE_PARAMETER_SET][0].payload, entries,
                                      what="scene parameter set")
    return ps, attr.layout_of(ps)


def _scene_of(ps, layout, coords: np.ndarray, dec: _Levels, mlps: dict) -> AnchorScene | GaussianScene:
    """The decoded scene: positions on the grid of the parameter set, attributes split by the layout."""
    if isinstance(ps, GaussianParameterSet):
        sh, opacity, log_scales, rotations = layout.split(dec.values)
        return GaussianScene.on_grid(coords, float(ps.voxel_size), ps.origin, sh, opacity, log_scales, rotations)
    features, scalings, offsets = layout.split(dec.values)
    return AnchorScene(coords=coords, voxel_size=float(ps.voxel_size), origin=np.asarray(ps.origin, dtype=np.float32),
                       features=features, scalings=scalings, offsets=offsets, offset_mask=dec.mask, mlps=mlps)


def _check_scene_hash(scene: AnchorScene | GaussianScene, scene_hash: bytes) -> None:
    """Clause 12: the SHA-256 of the decoded scene must equal the stream's decoded_scene_hash."""
    digest = digest_of(scene)
    if digest != scene_hash:
        raise HashMismatchError("the decoded scene does not match the hash in the stream "
                                f"(decoded SHA-256 {digest.hex()}, stream {scene_hash.hex()})")


def _stream_tools(ps, dec: _Levels, context_model, point: str) -> list[str]:
    """The coding tools the stream uses, in words (lghcc-dec prints them)."""
    if isinstance(ps, GaussianParameterSet):
        tools = [f"explicit Gaussians (SH degree {ps.sh_degree})"]
    else:
        tools = ["offset masks"] if ps.offset_mask_present_flag else []
    return tools + _hierarchy_tools(ps, dec.hierarchy, context_model, point)


def read_source_info(units: list[DataUnit], trace: list[TraceEntry] | None = None
                     ) -> tuple[SourceInfo | None, list[str]]:
    """The source_info unit among the known ancillary ``units`` (clause 7.3.10), and notes on
    what was ignored (clause 6.3): the first source_info when its elements do not fit its
    payload (or its alignment bits are not zero), and every source_info after the first, well
    formed or not (a stream has at most one). Never raises: nothing the decoded scene depends
    on is in it. Its trace entries follow the parameter set's."""
    info, notes, seen = None, [], 0
    for u in units:
        if u.unit_type != AncillaryUnitType.SOURCE_INFO:
            continue
        where = f"source_info ({len(u.payload)} bytes at byte {u.offset})"
        seen += 1
        if seen > 1:
            notes.append(f"{where}: a second source_info unit, ignored (a stream has at most one)")
            continue
        mark = None if trace is None else len(trace)
        try:
            info = SourceInfo.from_payload(u.payload, trace)
        except BitstreamError as e:
            if trace is not None:
                del trace[mark:]
            notes.append(f"{where}: cannot be parsed ({e}); ignored")
    return info, notes
