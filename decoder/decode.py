"""The decoding process (spec clause 12): bitstream in, anchor scene out, nothing else needed.

Order of data units (clause 6.4): scene_parameter_set first; then render_model (optional),
geometry, one attribute unit per level; decoded_scene_hash last. Ancillary units
(type >= 0x80) may appear anywhere after the scene parameter set and are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lghcc.common import attributes as attr
from lghcc.common.bitio import BitReader
from lghcc.common.container import Container, DataUnit, UnitType, read_container
from lghcc.common.errors import BitstreamError, HashMismatchError, UnsupportedStreamError
from lghcc.common.geometry import decode_geometry
from lghcc.common.hashing import scene_digest
from lghcc.common.render_model import read_render_model_unit
from lghcc.common.report import SizeBreakdown, breakdown_of
from lghcc.common.scene import AnchorScene
from lghcc.common.syntax import TraceEntry
from lghcc.common.units import (CONTEXT_PER_CHANNEL_PRIOR, MAX_ATTRIBUTE_VALUES, AttributeUnitHeader,
                                DecodedSceneHashUnit, SceneParameterSet)

# Units a stream of this version must carry exactly once, in this order.
REQUIRED_ORDER = (UnitType.SCENE_PARAMETER_SET, UnitType.GEOMETRY, UnitType.ATTRIBUTE,
                  UnitType.DECODED_SCENE_HASH)


@dataclass
class DecodeResult:
    scene: AnchorScene
    breakdown: SizeBreakdown
    hash_checked: bool
    stream_hash: bytes
    skipped_units: list[str] = field(default_factory=list)
    trace: list[TraceEntry] | None = None


def _organize(container: Container) -> tuple[dict[int, DataUnit], list[str]]:
    """Check unit types, multiplicity and order; return the critical units by type."""
    by_type: dict[int, DataUnit] = {}
    skipped: list[str] = []
    order: list[int] = []
    for idx, u in enumerate(container.units):
        if u.is_ancillary:
            if not order:
                raise BitstreamError(f"data unit {idx}: an ancillary unit precedes the scene parameter set")
            skipped.append(f"{u.type_name} ({len(u.payload)} bytes at byte {u.offset})")
            continue
        if u.unit_type not in UnitType._value2member_map_ or u.unit_type == UnitType.CONTEXT_MODEL:
            raise UnsupportedStreamError(f"data unit {idx} has unit type 0x{u.unit_type:02x}, which this "
                                         "decoder does not know and which is not marked ancillary")
        if u.unit_type in by_type:
            raise BitstreamError(f"data unit {idx}: a second {u.type_name} unit")
        if order and order[-1] == UnitType.DECODED_SCENE_HASH:
            raise BitstreamError(f"data unit {idx}: {u.type_name} after the decoded scene hash unit")
        by_type[u.unit_type] = u
        order.append(u.unit_type)
    for t in REQUIRED_ORDER:
        if t not in by_type:
            raise BitstreamError(f"the stream has no {UnitType(t).name.lower()} unit")
    required_seen = [t for t in order if t in REQUIRED_ORDER]
    if required_seen != list(REQUIRED_ORDER):
        raise BitstreamError("data units are out of order: expected " +
                             ", ".join(UnitType(t).name.lower() for t in REQUIRED_ORDER))
    if order[0] != UnitType.SCENE_PARAMETER_SET:
        raise BitstreamError("the first data unit is not the scene parameter set")
    if UnitType.RENDER_MODEL in by_type and order.index(UnitType.RENDER_MODEL) > order.index(UnitType.GEOMETRY):
        raise BitstreamError("the render model unit must precede the geometry unit")
    return by_type, skipped


def decode_attribute_unit(payload: bytes, sps: SceneParameterSet, num_rows: int, level: int,
                          trace: list[TraceEntry] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Returns (q int64 [rows, M], offset_mask bool [rows, K] or None)."""
    layout = attr.layout_of(sps)
    reader = BitReader(payload, "attribute unit")
    h = AttributeUnitHeader.parse(reader, trace, num_channels=layout.num_channels, num_offsets=sps.num_offsets,
                                  offset_mask_present=sps.offset_mask_present_flag, num_rows=num_rows)
    if h.attribute_level != level:
        raise BitstreamError(f"attribute unit: attribute_level {h.attribute_level}, expected {level}")
    body = payload[reader.bit_position // 8:]
    sizes = [s for pair in zip(h.mask_chunk_size, h.chunk_size) for s in pair] if h.offset_mask_present \
        else list(h.chunk_size)
    pieces = attr.split_chunks(body, sizes, "attribute unit")
    if h.context_model_id != CONTEXT_PER_CHANNEL_PRIOR:  # guarded by the header's range check
        raise UnsupportedStreamError(f"context model {h.context_model_id} is not supported")
    prior_mean = np.asarray(h.prior_mean, dtype=np.int64)
    prior_level = np.asarray(h.prior_level, dtype=np.int64)
    models = attr.mask_models(h.mask_live_prob) if h.offset_mask_present else None
    q = np.empty((num_rows, layout.num_channels), dtype=np.int64)
    mask = np.ones((num_rows, sps.num_offsets), dtype=bool) if h.offset_mask_present else None
    it = iter(pieces)
    for i in range(h.num_chunks):
        lo, hi = i * h.rows_per_chunk, min(num_rows, (i + 1) * h.rows_per_chunk)
        if models is not None:
            mask[lo:hi] = attr.decode_mask_chunk(next(it), hi - lo, models, f"attribute mask chunk {i}")
        live = layout.live_channels(None if mask is None else mask[lo:hi], hi - lo)
        levels = np.broadcast_to(prior_level, (hi - lo, layout.num_channels))
        q[lo:hi] = attr.decode_residual_chunk(next(it), levels, live, f"attribute chunk {i}") + prior_mean * live
    return q, mask


def decode_stream(data: bytes, *, verify_hash: bool = True, trace: bool = False,
                  max_anchors: int | None = None) -> DecodeResult:
    """Decode a whole stream. Raises a BitstreamError subclass naming the problem."""
    entries: list[TraceEntry] | None = [] if trace else None
    container = read_container(data)
    units, skipped = _organize(container)
    sps = SceneParameterSet.from_bytes(units[UnitType.SCENE_PARAMETER_SET].payload, entries,
                                       what="scene parameter set")
    layout = attr.layout_of(sps)
    n = sps.num_anchors
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise BitstreamError(f"{n} anchors x {layout.num_channels} channels exceeds the level limit of "
                             f"{MAX_ATTRIBUTE_VALUES} attribute values")
    if max_anchors is not None and n > max_anchors:
        raise BitstreamError(f"the stream declares {n} anchors, more than the allowed maximum {max_anchors}")

    mlps = {}
    if UnitType.RENDER_MODEL in units:
        mlps = read_render_model_unit(units[UnitType.RENDER_MODEL].payload, entries)
    coords = decode_geometry(units[UnitType.GEOMETRY].payload, n)
    q, mask = decode_attribute_unit(units[UnitType.ATTRIBUTE].payload, sps, n, 0, entries)
    values = attr.reconstruct(q, layout.steps(sps))  # dead offsets have q = 0, so they reconstruct to 0
    features, scalings, offsets = layout.split(values)
    scene = AnchorScene(coords=coords, voxel_size=float(sps.voxel_size),
                        origin=np.asarray(sps.origin, dtype=np.float32), features=features,
                        scalings=scalings, offsets=offsets, offset_mask=mask, mlps=mlps)

    hash_unit = DecodedSceneHashUnit.from_bytes(units[UnitType.DECODED_SCENE_HASH].payload, entries,
                                                what="decoded scene hash unit")
    if verify_hash:
        digest = scene_digest(scene)
        if digest != hash_unit.scene_hash:
            raise HashMismatchError("the decoded scene does not match the hash in the stream "
                                    f"(decoded {digest.hex()[:16]}..., stream {hash_unit.scene_hash.hex()[:16]}...)")
    return DecodeResult(scene, breakdown_of(container, n), verify_hash, hash_unit.scene_hash, skipped, entries)
