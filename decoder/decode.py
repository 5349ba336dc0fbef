"""The decoding process (spec clause 13): bitstream in, anchor scene out, nothing else needed.

Critical data units come in the order (clause 6.3)
    scene_parameter_set, [render_model], geometry, [context_model], attribute x (1 or 2), decoded_scene_hash
with two attribute units (level 1, then level 2) when the hierarchy is enabled. Ancillary
units (type >= 0x80) may appear anywhere after the scene parameter set and are skipped.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from lghcc.common import attributes as attr
from lghcc.common.container import Container, DataUnit, UnitType, read_container
from lghcc.common.errors import BitstreamError, HashMismatchError, ResourceLimitError, UnsupportedStreamError
from lghcc.common.context.models import describe_context_model, level2_coding_params, read_context_model
from lghcc.common.geometry import decode_geometry
from lghcc.common.hashing import scene_digest
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.render_model import read_render_model_unit
from lghcc.common.report import SizeBreakdown, breakdown_of
from lghcc.common.scene import AnchorScene
from lghcc.common.syntax import TraceEntry
from lghcc.common.units import (LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_ATTRIBUTE_VALUES, DecodedSceneHashUnit,
                                SceneParameterSet)
from lghcc.decoder.limits import DEFAULT_MAX_MEMORY, MemoryPlan

_LETTER = {UnitType.SCENE_PARAMETER_SET: "S", UnitType.RENDER_MODEL: "R", UnitType.GEOMETRY: "G",
           UnitType.CONTEXT_MODEL: "C", UnitType.ATTRIBUTE: "A", UnitType.DECODED_SCENE_HASH: "H"}
_UNIT_ORDER = re.compile(r"SR?GC?A{1,2}H")


@dataclass
class DecodeResult:
    scene: AnchorScene
    breakdown: SizeBreakdown
    hash_checked: bool
    stream_hash: bytes
    skipped_units: list[str] = field(default_factory=list)
    trace: list[TraceEntry] | None = None
    tools: list[str] = field(default_factory=list)  # the coding tools the stream uses, in words


def organize_units(container: Container) -> tuple[list[DataUnit], list[str]]:
    """Check unit types and their order; return the critical units and the skipped ones."""
    critical: list[DataUnit] = []
    skipped: list[str] = []
    for idx, u in enumerate(container.units):
        if u.is_ancillary:
            if not critical:
                raise BitstreamError(f"data unit {idx}: an ancillary unit precedes the scene parameter set")
            skipped.append(f"{u.type_name} ({len(u.payload)} bytes at byte {u.offset})")
        elif u.unit_type in _LETTER:
            critical.append(u)
        else:
            raise UnsupportedStreamError(f"data unit {idx} has unit type 0x{u.unit_type:02x}, which this "
                                         "decoder does not know and which is not marked ancillary")
    letters = "".join(_LETTER[UnitType(u.unit_type)] for u in critical)
    for t in (UnitType.SCENE_PARAMETER_SET, UnitType.GEOMETRY, UnitType.ATTRIBUTE, UnitType.DECODED_SCENE_HASH):
        if _LETTER[t] not in letters:
            raise BitstreamError(f"the stream has no {t.name.lower()} unit")
    if not _UNIT_ORDER.fullmatch(letters):
        names = ", ".join(u.type_name for u in critical)
        raise BitstreamError(f"data units are out of order or repeated: {names} (expected scene_parameter_set, "
                             "[render_model], geometry, [context_model], attribute (1 or 2), decoded_scene_hash)")
    return critical, skipped


def decode_stream(data: bytes, *, verify_hash: bool = True, trace: bool = False,
                  max_anchors: int | None = None, max_memory: int | None = DEFAULT_MAX_MEMORY,
                  progress: bool = False) -> DecodeResult:
    """Decode a whole stream. Raises a BitstreamError subclass naming the problem, or
    ResourceLimitError for a stream beyond ``max_anchors`` or one whose decoding needs more than
    ``max_memory`` bytes (None: no bound), computed from its headers before anything sized by
    the stream is allocated (decoder/limits.py). ``progress`` shows a bar of decoded anchors."""
    entries: list[TraceEntry] | None = [] if trace else None
    container = read_container(data)
    units, skipped = organize_units(container)
    by_type: dict[int, list[DataUnit]] = {}
    for u in units:
        by_type.setdefault(u.unit_type, []).append(u)

    sps = SceneParameterSet.from_bytes(by_type[UnitType.SCENE_PARAMETER_SET][0].payload, entries,
                                       what="scene parameter set")
    layout = attr.layout_of(sps)
    n = sps.num_anchors
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise BitstreamError(f"{n} anchors x {layout.num_channels} channels exceeds the level limit of "
                             f"{MAX_ATTRIBUTE_VALUES} attribute values")
    if max_anchors is not None and n > max_anchors:
        raise ResourceLimitError(f"the stream declares {n} anchors, more than the allowed maximum {max_anchors}")
    memory = MemoryPlan(max_memory, sps, by_type, len(data))  # refuses before anything sized by the stream exists
    attribute_units = by_type[UnitType.ATTRIBUTE]
    if len(attribute_units) != (2 if sps.hierarchy_enabled_flag else 1):
        raise BitstreamError(f"{len(attribute_units)} attribute units with hierarchy_enabled_flag = "
                             f"{sps.hierarchy_enabled_flag}")
    context_model = None
    if UnitType.CONTEXT_MODEL in by_type:
        if not sps.hierarchy_enabled_flag:
            raise BitstreamError("a context model unit in a stream without the hierarchy")
        context_model = read_context_model(by_type[UnitType.CONTEXT_MODEL][0].payload, layout, entries)

    mlps = {}
    if UnitType.RENDER_MODEL in by_type:
        mlps = read_render_model_unit(by_type[UnitType.RENDER_MODEL][0].payload, entries)
    coords = decode_geometry(by_type[UnitType.GEOMETRY][0].payload, n, entries)

    values = np.empty((n, layout.num_channels), dtype=np.float32)
    mask = np.ones((n, sps.num_offsets), dtype=bool) if sps.offset_mask_present_flag else None
    if sps.hierarchy_enabled_flag:
        hier = build_hierarchy(coords, sps.coarse_voxel_scale)
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
                                    hier.parent_of_level2, sps.coarse_voxel_scale)

    bar = tqdm(total=n, desc="decode attributes", unit="anchor", disable=not progress, leave=False)
    for unit, (level, rows) in zip(attribute_units, levels):
        num_rows = n if rows is None else rows.size
        memory.check_attribute_unit(unit.payload, num_rows, level, context_model, hier.num_level1 if rows is not None
                                    else None)
        _, m, q = attr.read_attribute_unit(unit.payload, sps, num_rows, level, values, rows,
                                           level2_context if level == LEVEL_2 else None, entries,
                                           keep_q=level == LEVEL_1 and context_model is not None,
                                           on_chunk=bar.update)
        if level == LEVEL_1:
            q_level1 = q
        if mask is not None:
            mask[slice(None) if rows is None else rows] = m
    bar.close()
    features, scalings, offsets = layout.split(values)
    scene = AnchorScene(coords=coords, voxel_size=float(sps.voxel_size),
                        origin=np.asarray(sps.origin, dtype=np.float32), features=features,
                        scalings=scalings, offsets=offsets, offset_mask=mask, mlps=mlps)

    hash_unit = DecodedSceneHashUnit.from_bytes(by_type[UnitType.DECODED_SCENE_HASH][0].payload, entries,
                                                what="decoded scene hash unit")
    if verify_hash:
        digest = scene_digest(scene)
        if digest != hash_unit.scene_hash:
            raise HashMismatchError("the decoded scene does not match the hash in the stream "
                                    f"(decoded SHA-256 {digest.hex()}, stream {hash_unit.scene_hash.hex()})")
    tools = ["offset masks"] if sps.offset_mask_present_flag else []
    if sps.hierarchy_enabled_flag:
        tools.append(f"two-level hierarchy (coarse voxels of {sps.coarse_voxel_scale}; {hier.num_level1:,} level-1 "
                     f"and {hier.num_level2:,} level-2 anchors)")
        tools.append("level-2 context: " + ("per-channel prior" if context_model is None
                                            else describe_context_model(context_model)))
    return DecodeResult(scene, breakdown_of(container, n), verify_hash, hash_unit.scene_hash, skipped, entries,
                        tools)
