"""Edits of encoded streams for conformance streams that make a decoder's decisions matter
(issue 14): values the encoder never writes (escapes up to the limit, every scale level),
hand-built integer context models whose means, levels and step adjustments reach every clamp
and rounding tie, and streams that break one rule each (a syntax element just beyond its range,
a geometry constraint, a context array out of its range ...). Used by the suite's generator,
conformance/generate.py (``post`` keys of conformance/sources.yaml; see ``apply_edits``): these edits
are format tools (they write what the spec allows, or one rule broken), not the encoder's choices.

Every edit is deterministic (seeded): from the same encoded stream, the same edited stream.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..common import attributes as attr
from ..common.bitio import BitReader
from ..common.container import DataUnit, UnitType
from ..common.units import AttributeUnitHeader, GaussianParameterSet, SceneParameterSet


def _index(units, unit_type, nth: int = 0) -> int:
    return [j for j, u in enumerate(units) if u.unit_type == unit_type][nth]


def _ps_index(units) -> int:
    """The index of the stream's parameter set: the scene parameter set of an anchor stream, the
    gaussian parameter set of an explicit-Gaussian one."""
    kinds = (UnitType.SCENE_PARAMETER_SET, UnitType.GAUSSIAN_PARAMETER_SET)
    return next(j for j, u in enumerate(units) if u.unit_type in kinds)


def _sps(units) -> SceneParameterSet | GaussianParameterSet:
    """The stream's parameter set (either kind gives num_anchors, the geometry's point count)."""
    u = units[_ps_index(units)]
    kind = GaussianParameterSet if u.unit_type == UnitType.GAUSSIAN_PARAMETER_SET else SceneParameterSet
    return kind.from_bytes(u.payload)


def _layout(ps):
    """The channel layout of a parameter set of either kind (an explicit-Gaussian stream's without
    its optional units: the edits that use it refuse those streams or do not depend on them)."""
    return attr.gaussian_layout_of(ps) if isinstance(ps, GaussianParameterSet) else attr.layout_of(ps)


def _parse_attribute(payload: bytes, sps, num_rows: int):
    """(header, byte offset of the chunk data)."""
    r = BitReader(payload)
    layout = _layout(sps)
    h = AttributeUnitHeader.parse(r, num_channels=layout.num_channels, num_offsets=layout.num_offsets,
                                  offset_mask_present=layout.offset_mask_present, num_rows=num_rows,
                                  channel_prediction_allowed=int(isinstance(sps, GaussianParameterSet)))
    return h, r.bit_position // 8


def _level0_q(units):
    """The single (no hierarchy) attribute unit: its header, masks and quantized values."""
    sps = _sps(units)
    j = _index(units, UnitType.ATTRIBUTE)
    layout = _layout(sps)
    values = np.empty((sps.num_points, layout.num_channels), np.float32)
    h, mask, q = attr.read_attribute_unit(units[j].payload, layout, layout.steps(sps), sps.num_points, 0, values,
                                          keep_q=True)
    return sps, j, h, mask, q


def _recode_level0(units, h, mask, q) -> None:
    """Write the single attribute unit again with header ``h`` (prior means / levels) and values q."""
    sps = _sps(units)
    layout = _layout(sps)
    j = _index(units, UnitType.ATTRIBUTE)
    new = AttributeUnitHeader(num_channels=layout.num_channels, num_offsets=sps.num_offsets,
                              offset_mask_present=h.offset_mask_present, num_rows=sps.num_points,
                              attribute_level=h.attribute_level, context_model_id=0, prior_mean=list(h.prior_mean),
                              prior_level=list(h.prior_level), mask_live_prob=list(h.mask_live_prob),
                              rows_per_chunk_minus1=h.rows_per_chunk_minus1)
    units[j] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(new, layout, q, mask, attr.prior_params(new)))


# --- values the encoder never writes ---------------------------------------------------------------

def set_q(units, spec: dict) -> None:
    """spec: {values: [[row, channel, q], ...], prior_mean: {channel: mean}, prior_level: {channel: level},
    every_level: bool}. Quantized values and prior parameters of the single attribute unit are
    rewritten and the unit re-coded (rehash the stream: the decoded scene changes).
    ``every_level``: channel c gets scale level c mod 64 (one stream exercises every table)."""
    sps, j, h, mask, q = _level0_q(units)
    q = q.copy()
    for row, col, value in spec.get("values", []):
        q[int(row), int(col)] = int(value)
    for c, m in (spec.get("prior_mean") or {}).items():
        h.prior_mean[int(c)] = int(m)
    for c, lv in (spec.get("prior_level") or {}).items():
        h.prior_level[int(c)] = int(lv)
    if spec.get("every_level"):
        h.prior_level = [c % 64 for c in range(len(h.prior_level))]
    _recode_level0(units, h, mask, q)


def escape_classes(units, spec: dict) -> None:
    """Channel ``channel`` of rows 0.. gets a residual of every escape class k = 0..62 at its level
    (|r| = L + 1 + m with m = 0 and m = 2^(k-1) + (2^(k-1) - 1)), both signs alternating, the
    last one the largest codable |r| = 2^62 - 1 (clause 10.5)."""
    from ..common.entropy.tables import HALF_WIDTHS, MAX_ABS_RESIDUAL

    sps, j, h, mask, q = _level0_q(units)
    col = int(spec.get("channel", 0))
    level = int(spec.get("level", 0))
    h.prior_level[col], h.prior_mean[col] = level, 0
    half = int(HALF_WIDTHS[level])
    mags = [half + 1] + [half + 1 + (1 << (k - 1)) + (1 << (k - 1)) - 1 for k in range(1, 62)] + [MAX_ABS_RESIDUAL]
    if len(mags) > sps.num_points:
        raise ValueError(f"escape_classes needs {len(mags)} rows")
    q = q.copy()
    for row, mag in enumerate(mags):
        q[row, col] = mag if row % 2 == 0 else -mag
    _recode_level0(units, h, mask, q)


def _chunk_pieces(units, j, sps, num_rows):
    h, off = _parse_attribute(units[j].payload, sps, num_rows)
    sizes = [x for pair in zip(h.mask_chunk_size, h.chunk_size) for x in pair] if h.offset_mask_present \
        else list(h.chunk_size)
    return h, attr.split_chunks(units[j].payload[off:], sizes, "attribute unit")


def _reframe(units, j, h, pieces) -> None:
    if h.offset_mask_present:
        h.mask_chunk_size = [len(p) for p in pieces[0::2]]
        h.chunk_size = [len(p) for p in pieces[1::2]]
    else:
        h.chunk_size = [len(p) for p in pieces]
    units[j] = DataUnit(units[j].unit_type, h.to_bytes() + b"".join(pieces))


def edit_chunk(units, spec: dict) -> None:
    """Damage one symbol chunk of the single attribute unit, chunk sizes kept consistent:
    {chunk: i, append_hex: '...'} (trailing bytes), or {chunk: i, failing_words: seed} (words found by
    a seeded search on which range decoding fails, q >= 2^24 in clause 10.6.4), or
    {chunk: i, failing_mask_words: seed} (the same for mask chunk i), or
    {chunk: i, append_mask_hex: '...'} (trailing bytes after mask chunk i), or
    {chunk: i, escape_beyond_limit: true} (one escaped residual of magnitude 2^62 + L, clause 10.5)."""
    from ..common.entropy import symbol_coder
    from ..common.entropy.range_coder import RangeEncoder
    from ..common.entropy.tables import HALF_WIDTHS
    from ..common.errors import BitstreamError

    sps = _sps(units)
    j = _index(units, UnitType.ATTRIBUTE)
    h, pieces = _chunk_pieces(units, j, sps, sps.num_points)
    i = int(spec.get("chunk", 0))
    k = 2 * i + 1 if h.offset_mask_present else i
    rows = min(h.rows_per_chunk, sps.num_points - i * h.rows_per_chunk)
    m = _layout(sps).num_channels
    levels = np.broadcast_to(np.asarray(h.prior_level, np.int64), (rows, m))
    if "append_hex" in spec:
        pieces[k] = pieces[k] + bytes.fromhex(spec["append_hex"])
    elif "append_mask_hex" in spec:
        if not h.offset_mask_present:
            raise ValueError("append_mask_hex needs offset masks")
        pieces[2 * i] = pieces[2 * i] + bytes.fromhex(spec["append_mask_hex"])
    elif "failing_words" in spec:
        rng = np.random.default_rng(int(spec["failing_words"]))
        for _ in range(200000):
            words = rng.integers(0, 256, size=4 * int(rng.integers(1, 4)), dtype=np.uint8).tobytes()
            try:
                symbol_coder.decode_symbols(words, levels)
            except BitstreamError as e:
                if "range decoding failed" in str(e):
                    pieces[k] = words
                    break
        else:
            raise ValueError("no failing words found")
    elif "failing_mask_words" in spec:  # the mask chunk i instead of the symbol chunk
        if not h.offset_mask_present:
            raise ValueError("failing_mask_words needs offset masks")
        models = attr.mask_models(h.mask_live_prob)
        pieces[2 * i] = _failing_words(int(spec["failing_mask_words"]),
                                       lambda words: attr.decode_mask_chunk(words, rows, models, "mask chunk"))
    elif spec.get("escape_beyond_limit"):
        if _layout(sps).offset_mask_present or len(set(h.prior_level)) != 1:
            raise ValueError("escape_beyond_limit needs one prior level and no offset masks")
        level = int(h.prior_level[0])
        half = int(HALF_WIDTHS[level])
        bins = np.full(rows * m, half, np.int32)
        bins[0] = 2 * half + 1  # the escape bin
        enc = RangeEncoder()
        enc.encode(bins, symbol_coder._level_model(level))
        enc.encode_bits(np.zeros(1, np.uint64), 1)  # sign +
        enc.encode(np.array([62], np.int32), symbol_coder._class_model())  # class 62: m = 2^61 + rem
        enc.encode_bits(np.array([(1 << 61) - 1], np.uint64), 61)  # m = 2^62 - 1: |r| = L + 2^62 > 2^62 - 1
        pieces[k] = enc.to_bytes()
    _reframe(units, j, h, pieces)


def _failing_words(seed: int, decode) -> bytes:
    """1 to 3 words, found by a search seeded with ``seed``, on which ``decode(words)`` (a range
    decoding) fails with q >= 2^24 (clause 10.6.4): "range decoding failed"."""
    from ..common.errors import BitstreamError

    rng = np.random.default_rng(seed)
    for _ in range(200000):
        words = rng.integers(0, 256, size=4 * int(rng.integers(1, 4)), dtype=np.uint8).tobytes()
        try:
            decode(words)
        except BitstreamError as e:
            if "range decoding failed" in str(e):
                return words
    raise ValueError("no failing words found")


def _level0_header_parser(units):
    """payload -> byte offset of the chunk data, for the single attribute unit of an anchor stream or
    of an explicit-Gaussian stream without neighbour prediction (its header then has the same syntax,
    with the Gaussian layout's channels and cross-channel prediction allowed)."""
    from ..common.units import GaussianParameterSet

    if not any(u.unit_type == UnitType.GAUSSIAN_PARAMETER_SET for u in units):
        sps = _sps(units)
        return lambda payload: _parse_attribute(payload, sps, sps.num_points)[1]
    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    layout = attr.gaussian_layout_of(gps)

    def header_end(payload: bytes) -> int:
        r = BitReader(payload)
        AttributeUnitHeader.parse(r, num_channels=layout.num_channels, num_offsets=layout.num_offsets,
                                  offset_mask_present=layout.offset_mask_present,
                                  channel_prediction_allowed=layout.channel_prediction_allowed,
                                  num_rows=gps.num_gaussians_minus1 + 1)
        return r.bit_position // 8
    return header_end


def nonzero_alignment(units, spec: dict) -> None:
    """{unit: attribute}: the last alignment bit of the (single, level-0) attribute unit's header
    set to 1 (clause 6.4: byte_alignment() bits are zero); the header must end unaligned."""
    from ..common.errors import BitstreamError

    if spec.get("unit", "attribute") != "attribute":
        raise ValueError("nonzero_alignment: only the attribute unit")
    j = _index(units, UnitType.ATTRIBUTE)
    parse = _level0_header_parser(units)
    off = parse(units[j].payload)
    payload = bytearray(units[j].payload)
    payload[off - 1] |= 1
    try:
        parse(bytes(payload))
    except BitstreamError as e:
        if "alignment" not in str(e):
            raise
    else:
        raise ValueError("the attribute unit header ends byte-aligned: no alignment bit to set")
    units[j] = DataUnit(units[j].unit_type, bytes(payload))


def recode_attribute_header(units, spec: dict) -> None:
    """Rewrite the header of attribute unit ``nth`` (default: the last), its chunks kept:
    {context_model_id: id} for a unit that names a context model the stream does not hold."""
    from ..common.geometry import decode_geometry
    from ..common.hierarchy import build_hierarchy

    sps = _sps(units)
    nth = int(spec.get("nth", -1))
    attribute_units = [j for j, u in enumerate(units) if u.unit_type == UnitType.ATTRIBUTE]
    j = attribute_units[nth]
    level = 0
    num_rows = sps.num_points
    if sps.hierarchy_enabled_flag:
        coords = decode_geometry(units[_index(units, UnitType.GEOMETRY)].payload, sps.num_points)
        hier = build_hierarchy(coords, sps.coarse_voxel_scale)
        level = attribute_units.index(j) + 1
        num_rows = hier.num_level1 if level == 1 else hier.num_level2
    h, off = _parse_attribute(units[j].payload, sps, num_rows)
    new = AttributeUnitHeader(num_channels=h.num_channels, num_offsets=h.num_offsets,
                              offset_mask_present=h.offset_mask_present, num_rows=num_rows, attribute_level=level,
                              context_model_id=int(spec["context_model_id"]), prior_mean=list(h.prior_mean),
                              prior_level=list(h.prior_level), mask_live_prob=list(h.mask_live_prob),
                              rows_per_chunk_minus1=h.rows_per_chunk_minus1,
                              mask_chunk_size=list(h.mask_chunk_size), chunk_size=list(h.chunk_size))
    units[j] = DataUnit(UnitType.ATTRIBUTE, new.to_bytes() + units[j].payload[off:])


# --- syntax elements just beyond their range ---------------------------------------------------------

def set_elements(units, edits: list[dict]) -> None:
    """[{name: 'structure.element[i]', value: v, nth: 0}, ...]: re-code syntax elements in place
    (lghcc.conformance.fuzz.replace_element: later bits move, CRCs are recomputed by the writer).
    f(32) values are given as numbers (or 'nan', 'inf'). Located from the decoder's trace of the
    unedited stream."""
    from ..common.container import write_container
    from ..common.syntax import f32_bits
    from .fuzz import replace_element, stream_elements

    els = stream_elements(write_container(units))
    picked = []
    for e in edits:
        matches = [el for el in els if el.name == e["name"]]
        if len(matches) <= int(e.get("nth", 0)):
            raise ValueError(f"no element {e['name']} (occurrence {e.get('nth', 0)})")
        el = matches[int(e.get("nth", 0))]
        v = e["value"]
        picked.append((el, f32_bits(float(v)) if el.descriptor == "f(32)" else int(v)))
    for el, v in sorted(picked, key=lambda p: (p[0].unit, -p[0].bit)):  # later elements first
        units[el.unit] = DataUnit(units[el.unit].unit_type, replace_element(units[el.unit].payload, el, v))


# --- geometry constraints -----------------------------------------------------------------------------

def _encode_geometry_unchecked(coords: np.ndarray, shift_min: list[int] | None = None) -> bytes:
    """encode_geometry without its checks, for payloads that break a rule on purpose: duplicate
    points allowed, and ``shift_min`` subtracted from the bounding-box minimum (the points then do
    not attain it). The coding itself is the reference encoder's (its source, edited)."""
    import inspect
    import textwrap

    from ..common import geometry

    src = textwrap.dedent(inspect.getsource(geometry.encode_geometry))
    src = src.replace('raise ValueError("coordinates must be unique")', "pass")
    src = src.replace("bmin = c.min(axis=0)", "bmin = c.min(axis=0) - np.asarray(_SHIFT, dtype=np.int64)")
    ns: dict = {}
    exec(compile(src, "<encode_geometry unchecked>", "exec"), dict(vars(geometry), _SHIFT=shift_min or [0, 0, 0]),
         ns)
    return ns["encode_geometry"](coords)


def _box_min_x_for_top(payload: bytes, coords: np.ndarray, top: int) -> dict:
    """The geometry header's box-minimum fields moved along x so that the largest decoded x is ``top``."""
    return _box_min_shifted(payload, [top - int(coords[:, 0].max()), 0, 0])


def _geometry_with_header(payload: bytes, fields: dict) -> bytes:
    """A geometry unit's payload with header fields rewritten, the coded data after its byte alignment kept."""
    from ..common.bitio import BitWriter
    from ..common.geometry import GeometryHeader

    r = BitReader(payload)
    gh = GeometryHeader.parse(r)
    r.byte_align()
    for name, value in fields.items():
        setattr(gh, name, value)
    w = BitWriter()
    gh.write_to(w)
    w.byte_align()
    return w.getvalue() + payload[r.bit_position // 8:]


def tile_point_beyond_cell(units, spec: dict) -> None:
    """{t, by}: the geometry unit of tile t (default the last) with its box minimum along x moved so
    that the tile's largest decoded x lies ``by`` voxels beyond its cell (clause 7.3.11, E58; by 1:
    the first coordinate outside), the tile's tile_data_size following the unit's new length."""
    from ..common.geometry import decode_geometry
    from ..common.tiles import cell_bounds

    i, index, starts, ends = _tiles(units)
    t = int(spec.get("t", -1)) % len(starts)
    g = starts[t]
    cell = (index.tile_x[t], index.tile_y[t], index.tile_z[t])
    coords = decode_geometry(units[g].payload, index.tile_num_points_minus1[t] + 1)
    _, hi = cell_bounds(cell, _sps(units).tile_size)
    fields = _box_min_x_for_top(units[g].payload, coords, int(hi[0]) + int(spec.get("by", 1)))
    units[g] = DataUnit(UnitType.GEOMETRY, _geometry_with_header(units[g].payload, fields))
    _reframe_tile(units, index, t, starts, ends, cell)
    units[i] = DataUnit(UnitType.TILE_INDEX, index.to_bytes())


def _tiles(units):
    """(tile_index unit position, its TileIndex, each tile's geometry unit position, each tile's hash unit position)."""
    from ..common.units import TileIndex

    i = _index(units, UnitType.TILE_INDEX)
    starts = [j for j, u in enumerate(units) if u.unit_type == UnitType.GEOMETRY]
    ends = [j for j, u in enumerate(units) if u.unit_type == UnitType.DECODED_SCENE_HASH]
    return i, TileIndex.parse(BitReader(units[i].payload), num_points=1 << 24), starts, ends


def _box_min_shifted(payload: bytes, delta) -> dict:
    """The geometry header's box-minimum fields moved by ``delta`` voxels per axis (the coded offsets kept)."""
    from ..common.geometry import GeometryHeader

    gh = GeometryHeader.parse(BitReader(payload))
    mins = [(-a if f else a) + int(d) for a, f, d in zip(gh.geom_bbox_min_abs, gh.geom_bbox_min_sign_flag, delta)]
    return {"geom_bbox_min_sign_flag": [int(m < 0) for m in mins], "geom_bbox_min_abs": [abs(m) for m in mins]}


def _reframe_tile(units, index, t: int, starts, ends, cell) -> None:
    """Tile t's cell set and its tile_data_size made that of its units (after an edit of them)."""
    from ..common.container import UNIT_CRC_BYTES, UNIT_HEADER_BYTES

    index.tile_x[t], index.tile_y[t], index.tile_z[t] = (int(c) for c in cell)
    index.tile_data_size[t] = sum(UNIT_HEADER_BYTES + len(u.payload) + UNIT_CRC_BYTES
                                  for u in units[starts[t]:ends[t] + 1])


def tile_into_cell_of(units, spec: dict) -> None:
    """{t, of}: tile t moved into tile ``of``'s cell: its cell set to that one and its points moved by
    the whole cells between (its geometry box minimum shifted), so that every point lies in its
    tile's cell and two tiles share a cell (clause 7.3.11, E56 with equal cells)."""
    i, index, starts, ends = _tiles(units)
    t, of = int(spec["t"]), int(spec["of"])
    size = _sps(units).tile_size
    cell_t = (index.tile_x[t], index.tile_y[t], index.tile_z[t])
    cell_of = (index.tile_x[of], index.tile_y[of], index.tile_z[of])
    delta = [(b - a) * size for a, b in zip(cell_t, cell_of)]
    g = starts[t]
    units[g] = DataUnit(UnitType.GEOMETRY, _geometry_with_header(units[g].payload, _box_min_shifted(units[g].payload,
                                                                                                    delta)))
    _reframe_tile(units, index, t, starts, ends, cell_of)
    units[i] = DataUnit(UnitType.TILE_INDEX, index.to_bytes())


def tile_scale_cells(units, spec: dict) -> None:
    """{tile_scale_minus1: s}: the parameter set's tile_scale_minus1 set to s and every tile's cell
    recomputed from its points for that tile size (each tile's points must share one cell of it;
    the cells must stay in increasing order): a stream consistent but for the element's range when s
    is beyond it (clause 7.3.1)."""
    from ..common.geometry import decode_geometry

    i, index, starts, ends = _tiles(units)
    ps_at, ps = _ps_index(units), _sps(units)
    ps.tile_scale_minus1 = int(spec["tile_scale_minus1"])
    units[ps_at] = DataUnit(units[ps_at].unit_type, ps.to_bytes())
    for t, g in enumerate(starts):
        coords = decode_geometry(units[g].payload, index.tile_num_points_minus1[t] + 1)
        cells = np.unique(np.floor_divide(coords, ps.tile_size), axis=0)
        if len(cells) != 1:
            raise ValueError(f"tile {t}'s points lie in {len(cells)} cells of {ps.tile_size} voxels")
        _reframe_tile(units, index, t, starts, ends, cells[0])
    units[i] = DataUnit(UnitType.TILE_INDEX, index.to_bytes())


def geometry_edit(units, spec: dict) -> None:
    """{duplicate_isolated: true}: one isolated anchor repeated (an IDCM node with the same point
    twice, num_anchors + 1; with ``with_row``, the attribute unit re-coded with a row for it); {shift_min: [1, 0, 0]}: the box minimum one below every point;
    {append_hex: '...'}: bytes after the coded data; {anchors_delta: d}: num_anchors changed by d
    (the sps re-written); {top_x: t}: the box minimum along x set so that the largest decoded x is t
    (the coded offsets kept)."""
    from ..common.geometry import decode_geometry

    j = _index(units, UnitType.GEOMETRY)
    s = _ps_index(units)
    sps = _sps(units)
    coords = decode_geometry(units[j].payload, sps.num_points)
    if spec.get("duplicate_isolated"):
        rows = _level0_q(units) if spec.get("with_row") else None  # the attributes of the N points
        far = coords[np.argmax(np.abs(coords - np.median(coords, axis=0)).sum(axis=1))]
        dup = np.concatenate([coords, far[None]])
        units[j] = DataUnit(UnitType.GEOMETRY, _encode_geometry_unchecked(dup))
        sps.num_anchors_minus1 += 1
        units[s] = DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())
        if rows is not None:  # with_row: a row for the repeated point too (the last row again)
            _, _, h, mask, q = rows
            _recode_level0(units, h, None if mask is None else np.vstack([mask, mask[-1:]]), np.vstack([q, q[-1:]]))
    if "shift_min" in spec:
        units[j] = DataUnit(UnitType.GEOMETRY, _encode_geometry_unchecked(coords, spec["shift_min"]))
    if "append_hex" in spec:
        units[j] = DataUnit(UnitType.GEOMETRY, units[j].payload + bytes.fromhex(spec["append_hex"]))
    if "top_x" in spec:  # the box minimum along x moved so that the largest decoded x is exactly top_x
        spec = {**spec, "header": {**spec.get("header", {}), **_box_min_x_for_top(units[j].payload, coords,
                                                                                  int(spec["top_x"]))}}
    if "header" in spec:  # header fields rewritten, the coded data after the byte alignment kept
        units[j] = DataUnit(UnitType.GEOMETRY, _geometry_with_header(units[j].payload, spec["header"]))
    if "anchors_delta" in spec:
        sps.num_anchors_minus1 += int(spec["anchors_delta"])
        units[s] = DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())


# --- context-model and render-model units that break a rule ---------------------------------------------

def context_unit(units, spec: dict) -> None:
    """Replace the context-model unit's arrays: {array: name, values: [...], bits: b} (values
    outside the width; or {array: name, shape: [...], fill: v, bits: b}: another shape, or only
    another width with neither values nor shape), or {oversized: true} (arrays of more than 2^24
    values in all, coded data empty); or the arrays kept and the coded data damaged:
    {failing_words: seed} (words on which range decoding fails), {coded_size_delta: d} (coded_size
    beyond the payload). The hyperparameters, syntax elements, are edited with set_elements."""
    from ..common.context.model_unit import (ContextModelUnit, IntArrayHeader, NamedIntArray,
                                                 read_context_model_unit, write_context_model_unit)

    j = _index(units, UnitType.CONTEXT_MODEL)
    model_id, hp, arrays = read_context_model_unit(units[j].payload)
    unit = ContextModelUnit.from_bytes(units[j].payload)
    if "failing_words" in spec or "coded_size_delta" in spec:  # the arrays kept, the coded data damaged
        from ..common.entropy.symbol_coder import decode_symbols

        if "failing_words" in spec:
            levels = np.concatenate([np.full(int(np.prod(a.shape, dtype=np.int64)), a.array_level, np.int64)
                                     for a in unit.arrays])
            unit.coded_data = _failing_words(int(spec["failing_words"]), lambda w: decode_symbols(w, levels))
            unit.coded_size = len(unit.coded_data)
        unit.coded_size += int(spec.get("coded_size_delta", 0))  # beyond the payload: a truncation
        units[j] = DataUnit(UnitType.CONTEXT_MODEL, unit.to_bytes())
        return
    if spec.get("oversized"):
        unit.arrays = [IntArrayHeader(array_ndim=4, array_dim_minus1=[256, 256, 256, 0], array_bits_minus1=15,
                                      array_signed_flag=1) if a.array_ndim == 4 else a for a in unit.arrays]
        unit.coded_size, unit.coded_data = 0, b""
        units[j] = DataUnit(UnitType.CONTEXT_MODEL, unit.to_bytes())
        return
    new = []
    for a in arrays:
        v, bits = np.asarray(a.values), a.bits
        if a.name == spec.get("array"):
            if "values" in spec:
                v = np.asarray(spec["values"], np.int64).reshape(v.shape)
            elif "shape" in spec:  # another shape, every value ``fill``
                v = np.full(spec["shape"], int(spec.get("fill", 0)), np.int64)
            bits = int(spec.get("bits", bits))
        new.append(NamedIntArray(a.name, v, bits, a.signed))
    units[j] = DataUnit(UnitType.CONTEXT_MODEL, write_context_model_unit(model_id, hp, new))


def render_unit(units, spec: dict) -> None:
    """Replace the render-model unit: {weight_2_24: true} (one weight integer of magnitude 2^24),
    {duplicate_role: true} (the first MLP twice), {oversized: true} (two 4096 x 4096 layers: more
    than 2^24 parameters, coded data empty), {failing_words: seed} (coded data on which range
    decoding fails, q >= 2^24), {coded_size_delta: d} (coded_size beyond the payload)."""
    from ..common.entropy.symbol_coder import encode_symbols
    from ..common.units import RenderMlpHeader, RenderModelUnit

    j = _index(units, UnitType.RENDER_MODEL)
    unit = RenderModelUnit.from_bytes(units[j].payload)
    if spec.get("oversized"):
        h = RenderMlpHeader(mlp_role=0, num_layers_minus1=1, input_dim_minus1=4095, output_dim_minus1=[4095, 4095],
                            activation=[1, 0], weight_exponent=[0, 0], weight_level=[0, 0], bias_exponent=[0, 0],
                            bias_level=[0, 0])
        unit = RenderModelUnit(num_mlps=1, mlps=[h], coded_size=0, coded_data=b"")
    elif spec.get("duplicate_role"):
        from ..common.entropy.symbol_coder import decode_symbols

        h = unit.mlps[0]
        first = []
        for l, (i, o) in enumerate(_shapes(h)):
            first += [h.weight_level[l]] * (o * i) + [h.bias_level[l]] * o
        first_levels = np.asarray(first, np.int64)
        all_levels = _all_levels(unit)
        q = decode_symbols(unit.coded_data, all_levels)
        data = encode_symbols(np.concatenate([q, q[:first_levels.size]]), np.concatenate([all_levels, first_levels]))
        unit = RenderModelUnit(num_mlps=unit.num_mlps + 1, mlps=list(unit.mlps) + [h], coded_size=len(data),
                               coded_data=data)
    elif "failing_words" in spec:
        from ..common.entropy.symbol_coder import decode_symbols

        levels = _all_levels(unit)
        unit.coded_data = _failing_words(int(spec["failing_words"]), lambda w: decode_symbols(w, levels))
        unit.coded_size = len(unit.coded_data)
    elif "coded_size_delta" in spec:  # coded_size beyond the payload: a truncation
        unit.coded_size += int(spec["coded_size_delta"])
    elif spec.get("weight_2_24"):
        from ..common.entropy.symbol_coder import decode_symbols

        levels = _all_levels(unit)
        q = decode_symbols(unit.coded_data, levels)
        q[0] = 1 << 24
        data = encode_symbols(q, levels)
        unit.coded_size, unit.coded_data = len(data), data
    units[j] = DataUnit(UnitType.RENDER_MODEL, unit.to_bytes())


def _shapes(h):
    out, fan_in = [], h.input_dim_minus1 + 1
    for l in range(h.num_layers_minus1 + 1):
        out.append((fan_in, h.output_dim_minus1[l] + 1))
        fan_in = h.output_dim_minus1[l] + 1
    return out


def _all_levels(unit) -> np.ndarray:
    lv = []
    for h in unit.mlps:
        for l, (i, o) in enumerate(_shapes(h)):
            lv += [h.weight_level[l]] * (o * i) + [h.bias_level[l]] * o
    return np.asarray(lv, np.int64)


def raw_container_edit(data: bytes, spec: dict) -> bytes:
    """Edits of the container header's bytes that the writer refuses: {magic_hex: '4c474844'}."""
    if "magic_hex" in spec:
        data = bytes.fromhex(spec["magic_hex"]) + data[4:]
    return data


# --- designed integer context models (decodable) ------------------------------------------------------

def _weights(rng: np.random.Generator, kind, shape, bits: int) -> np.ndarray:
    lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    if isinstance(kind, int):
        return np.full(shape, kind, np.int64)
    if kind == "zero":
        return np.zeros(shape, np.int64)
    if kind == "small":
        return rng.integers(-3, 4, size=shape)
    if kind == "extreme":
        return rng.choice([lo, hi, -1, 0, 1], size=shape)
    if kind == "wide":
        return rng.integers(lo, hi, size=shape, endpoint=True)
    raise ValueError(f"unknown weight kind {kind!r}")


def _bias(rng: np.random.Generator, kind, n: int) -> np.ndarray:
    if isinstance(kind, int):
        return np.full(n, kind, np.int64)
    if isinstance(kind, dict):  # {cycle: [v0, v1, ...]}: the values in turn, channel by channel
        return np.resize(np.asarray(kind["cycle"], np.int64), n)
    if isinstance(kind, list):  # [lo, hi]
        return rng.integers(int(kind[0]), int(kind[1]), size=n, endpoint=True)
    if kind == "zero":
        return np.zeros(n, np.int64)
    if kind == "small":
        return rng.integers(-100, 101, size=n)
    if kind == "extreme":
        return rng.choice([-(1 << 31), (1 << 31) - 1, -(1 << 20), 1 << 20, 0], size=n)
    raise ValueError(f"unknown bias kind {kind!r}")


def _layers(rng, specs: list[dict], fan_in: int, last_out: int, m: int | None = None):
    """IntLinear layers from specs [{out, w, b, shift, bits}, ...]; the last one has ``last_out``
    outputs. With ``m`` (a head: 3M outputs), the last layer's rows of means, levels and step
    adjustments take their own weights and biases (w/b, level_w/level_b, adjust_w/adjust_b)."""
    from ..common.intnn import IntLinear

    layers = []
    for l, sp in enumerate(specs):
        last = l == len(specs) - 1
        out = last_out if last else int(sp["out"])
        bits = int(sp.get("bits", 16))
        w = _weights(rng, sp.get("w", "small"), (out, fan_in), bits)
        b = _bias(rng, sp.get("b", "zero"), out)
        if last and m is not None:
            w[m:2 * m] = _weights(rng, sp.get("level_w", "zero"), (m, fan_in), bits)
            w[2 * m:] = _weights(rng, sp.get("adjust_w", "zero"), (m, fan_in), bits)
            b[m:2 * m] = _bias(rng, sp.get("level_b", [4, 20]), m)
            b[2 * m:] = _bias(rng, sp.get("adjust_b", "zero"), m)
        layers.append(IntLinear(w, b, int(sp.get("shift", 0)), not last, bits))
        fan_in = out
    return layers


def _designed_params(spec: dict, c: int, m: int):
    """(context_model_id, parameters) of ``designed_model``'s model for C features and M channels."""
    from ..common.context.ggconv import GGConvParams
    from ..common.context.parent_mlp import ParentMlpParams
    from ..common.intnn import IntMLP
    from ..common.units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP

    rng = np.random.default_rng(int(spec.get("seed", 0)))
    base = {"ones": np.ones(m, np.int64), "zeros": np.zeros(m, np.int64),
            "random": rng.integers(0, 2, size=m)}[spec.get("parent_base", "random")]
    if spec.get("model", "ggconv") == "parent_mlp":
        head = IntMLP(_layers(rng, spec["head"], 3 + m, 3 * m, m))
        model_id, params = CONTEXT_PARENT_MLP, ParentMlpParams(c, head, base)
    else:
        ch, d = int(spec.get("channels", 2)), int(spec.get("grid", 2))
        table = _weights(rng, spec.get("table", "small"), (d, d, d, ch), 16)
        feat = IntMLP(_layers(rng, spec["feat"], c + 3, ch))
        head = IntMLP(_layers(rng, spec["head"], ch + 4 + m, 3 * m, m))
        params = GGConvParams(num_features=c, k=int(spec.get("k", 4)), radius_sq=int(spec.get("radius_sq", 12)),
                              table=table, h_shift=int(spec.get("h_shift", 0)), feat_mlp=feat, head_mlp=head,
                              neighbour_level=int(spec.get("neighbour_level", 1)), parent_base=base)
        model_id = CONTEXT_GGCONV
    return model_id, params


def designed_model(units, spec: dict) -> None:
    """Code level 2 with a context model built from ``spec`` (seeded; every layer's weights,
    biases, shift and width, the GG-Conv graph and table), so that its means, levels and step
    adjustments reach the clamps and rounding ties a wrong decoder gets wrong. The level-2 values
    the per-channel stream decoded to are re-quantized with the model's adjusted steps; the caller
    rehashes the stream. spec: {model: ggconv | parent_mlp, seed, k, radius_sq, grid, channels,
    h_shift, neighbour_level, table: small|extreme|wide, parent_base: random|ones|zeros,
    feat: [layer, ...], head: [layer, ...]} with layer = {out, w, b, shift, bits} (the head's last
    layer also level_w, level_b, adjust_w, adjust_b)."""
    from ..common.context.model_unit import write_context_model_unit
    from ..common.context.models import level2_coding_params, read_context_model
    from ..common.geometry import decode_geometry
    from ..common.hierarchy import build_hierarchy
    from ..common.units import LEVEL_1, LEVEL_2

    sps = _sps(units)
    layout = _layout(sps)
    m, c = layout.num_channels, sps.feature_dim
    coords = decode_geometry(units[_index(units, UnitType.GEOMETRY)].payload, sps.num_points)
    hier = build_hierarchy(coords, sps.coarse_voxel_scale)
    values = np.empty((sps.num_points, m), np.float32)
    a1, a2 = _index(units, UnitType.ATTRIBUTE, 0), _index(units, UnitType.ATTRIBUTE, 1)
    if UnitType.CONTEXT_MODEL in [u.unit_type for u in units]:
        raise ValueError("designed_model starts from a stream without a context model")
    steps = layout.steps(sps)
    _, _, q1 = attr.read_attribute_unit(units[a1].payload, layout, steps, hier.num_level1, LEVEL_1, values,
                                        hier.level1_idx, keep_q=True)
    h2, mask2, _ = attr.read_attribute_unit(units[a2].payload, layout, steps, hier.num_level2, LEVEL_2, values,
                                            hier.level2_idx, keep_q=True)
    model_id, params = _designed_params(spec, c, m)
    unit = write_context_model_unit(model_id, *params.to_syntax())
    model = read_context_model(unit, layout)
    cp = level2_coding_params(model, coords[hier.level1_idx], q1, coords[hier.level2_idx], hier.parent_of_level2,
                              sps.coarse_voxel_scale).materialize()
    v2 = values[hier.level2_idx].astype(np.float64)
    q2 = np.rint(v2 / attr.effective_steps(layout.steps(sps), cp.step_adjust).astype(np.float64)).astype(np.int64)
    live = layout.live_channels(mask2, hier.num_level2)
    if live is not None:
        q2 = q2 * live
    h = AttributeUnitHeader(num_channels=m, num_offsets=sps.num_offsets, offset_mask_present=h2.offset_mask_present,
                            num_rows=hier.num_level2, attribute_level=LEVEL_2, context_model_id=model_id,
                            mask_live_prob=list(h2.mask_live_prob), rows_per_chunk_minus1=h2.rows_per_chunk_minus1)
    units[a2] = DataUnit(UnitType.ATTRIBUTE, attr.write_attribute_unit(h, layout, q2, mask2, cp))
    units.insert(_index(units, UnitType.GEOMETRY), DataUnit(UnitType.CONTEXT_MODEL, unit))


# --- neighbour prediction (version 1.1, clauses 7.3.12 and 11.7) ------------------------------------------

def neighbour_prediction(units, spec: dict) -> None:
    """Re-code the single attribute unit of an explicit-Gaussian stream (no tiles, no hierarchy, coded
    with the per-channel prior) with neighbour prediction and insert the neighbour_prediction unit
    after the parameter set. Lossless: the quantized values, hence the decoded scene and its hash,
    stay. spec: {lods, neighbours, buckets (the unit's L, k, B), flags: [neighbour_mean_flag per
    channel] (default: the encoder's choice), bucket_level: {index: level} (entries of the encoder's
    table replaced; any level decodes the same values), rows_per_chunk, channel_prediction: bool,
    fault: chunks_across_lods (the chunks cut every rows_per_chunk rows of the coding order, across
    the LoDs, padded with empty chunks to NumChunks) | context_model_id_1 (the header names context
    model 1, its chunks kept) | no_graph (points beyond the extent limit: no graph is built, every
    chunk empty)}."""
    from ..common.geometry import decode_geometry
    from ..common.units import GaussianParameterSet, NeighbourPredictionUnit
    from ..encoder.stream.neighbour_coding import NeighbourCoding

    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    if gps.hierarchy_enabled_flag or gps.tiles_enabled_flag:
        raise ValueError("neighbour_prediction edits a stream without the hierarchy and without tiles")
    layout = attr.gaussian_layout_of(gps)
    n, m = gps.num_gaussians, layout.num_channels
    j = _index(units, UnitType.ATTRIBUTE)
    values = np.empty((n, m), np.float32)
    h0, _, q = attr.read_attribute_unit(units[j].payload, layout, layout.steps(gps), n, 0, values, keep_q=True)
    coords = decode_geometry(units[_index(units, UnitType.GEOMETRY)].payload, n)
    lods, k, b = int(spec["lods"]), int(spec["neighbours"]), int(spec["buckets"])
    h = attr.new_attribute_header(layout, n, 0)
    h.rows_per_chunk_minus1 = min(int(spec.get("rows_per_chunk", n)), n) - 1
    fault = spec.get("fault")
    if fault == "no_graph":
        unit = NeighbourPredictionUnit(num_channels=m, num_lods_minus1=lods - 1, num_neighbours_minus1=k - 1,
                                       num_buckets_minus1=b - 1, neighbour_mean_flag=[1] * m,
                                       bucket_level=[10] * (m * b))
        h.prior_mean, h.prior_level, h.num_lods = list(h0.prior_mean), list(h0.prior_level), lods
        h.chunk_size = [0] * h.num_chunks
        payload = h.to_bytes()
    else:
        nc = NeighbourCoding(q, coords, lods, k, b, bool(spec.get("channel_prediction", False)), layout)
        unit = nc.unit
        if "flags" in spec or "bucket_level" in spec:
            unit.neighbour_mean_flag = [int(f) for f in spec.get("flags", unit.neighbour_mean_flag)]
            for i, level in (spec.get("bucket_level") or {}).items():
                unit.bucket_level[int(i)] = int(level)
            nc = NeighbourCoding(q, coords, lods, k, b, bool(spec.get("channel_prediction", False)), layout, unit)
        payload = nc.write(h)
        if fault == "chunks_across_lods":
            payload = _chunks_across_lods(h, nc)
        elif fault == "context_model_id_1":
            body = payload[len(h.to_bytes()):]
            h.context_model_id = 1
            payload = h.to_bytes() + body
        elif fault is not None:
            raise ValueError(f"neighbour_prediction: unknown fault {fault!r}")
    units[j] = DataUnit(UnitType.ATTRIBUTE, payload)
    units.insert(_index(units, UnitType.GAUSSIAN_PARAMETER_SET) + 1,
                 DataUnit(UnitType.NEIGHBOUR_PREDICTION, unit.to_bytes()))


def _adjust_indices(kind: str, n: int, top: int) -> np.ndarray:
    """``step_adjust``'s indices of n rows: zero | const:<a> | cycle | cycle:<n>."""
    if kind.startswith("const:"):
        return np.full(n, int(kind.split(":")[1]), dtype=np.int64)
    period = 1 if kind == "zero" else int(kind.split(":")[1]) if ":" in kind else top + 1
    return np.arange(n, dtype=np.int64) % period


def _edit_adjust_chunks(h: AttributeUnitHeader, payload: bytes, spec: dict) -> bytes:
    """``step_adjust``'s empty_adjust_chunks and append_adjust_hex: the chunks of indices edited, the
    header's sizes kept consistent."""
    body = payload[len(h.to_bytes()):]
    pieces, pos = [], 0  # per chunk [indices, values]
    for a_size, v_size in zip(h.adjust_chunk_size, h.chunk_size):
        pieces.append([body[pos:pos + a_size], body[pos + a_size:pos + a_size + v_size]])
        pos += a_size + v_size
    if spec.get("empty_adjust_chunks"):  # every chunk of indices empty: each decodes as bin 0 of its table
        for piece in pieces:
            piece[0] = b""
    if "append_adjust_hex" in spec:
        a = spec["append_adjust_hex"]
        pieces[int(a["chunk"])][0] += bytes.fromhex(a["hex"])
    h.adjust_chunk_size = [len(p[0]) for p in pieces]
    return h.to_bytes() + b"".join(p[0] + p[1] for p in pieces)


def step_adjust(units, spec: dict) -> None:
    """Give every row of the single attribute unit of an explicit-Gaussian stream coded with
    neighbour prediction (no tiles) a step-adjustment index and insert the step_adjust unit after
    the neighbour_prediction unit (version 1.2, clause 7.3.13). The quantized values stay, so the
    decoded values scale by their rows' factors (rehash the stream). spec: {max (max_step_adjust),
    indices: zero | const:<a> | cycle (row i gets i mod (max + 1)) | cycle:<n> (i mod n, beyond max
    when n > max + 1: a fault), adjust_mean, adjust_level (default the encoder's),
    empty_adjust_chunks (every chunk of indices 0 bytes: each index decodes as bin 0 of the
    level's table, -L + adjust_mean; as flags, every flag 0 and every index 0), flags (version 1.5:
    the indices as flags with a step_adjust_flags unit after the step_adjust unit; true: the
    encoder's probabilities, extreme: step_flag_prob[i] 0 for even i and 4095 for odd i, or a list),
    append_adjust_hex ({chunk, hex}: words appended to a chunk of indices, the sizes kept
    consistent)}."""
    from ..common.neighbour_prediction import neighbour_graph
    from ..common.units import NUM_STEP_FLAG_CONTEXTS, GaussianParameterSet, StepAdjustFlagsUnit, StepAdjustUnit
    from ..encoder.stream.neighbour_coding import NeighbourCoding, flag_counts, flag_probabilities

    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    if gps.hierarchy_enabled_flag or gps.tiles_enabled_flag:
        raise ValueError("step_adjust edits a stream without the hierarchy and without tiles")
    layout = attr.gaussian_layout_of(gps)
    n = gps.num_gaussians
    k, unit, coords, j, h0, values = _predicted_attribute_unit(units, gps, layout)
    q = np.rint(values / layout.steps(gps)).astype(np.int64)  # index 0 throughout: exact
    top = int(spec["max"])
    adjust = _adjust_indices(str(spec.get("indices", "cycle")), n, top)
    flags = spec.get("flags")
    if flags:  # the stream's step_adjust_flags unit: the neighbour unit carries it to the coding
        graph = neighbour_graph(coords, unit.num_lods, unit.num_neighbours)
        probs = flag_probabilities(flag_counts(graph, adjust, top)) if flags is True else \
            [4095 * (i % 2) for i in range(top * NUM_STEP_FLAG_CONTEXTS)] if flags == "extreme" else [int(p) for p in flags]
        unit.step_flags = StepAdjustFlagsUnit(max_step_adjust=top, step_flag_prob=probs)
    nc = NeighbourCoding(q, coords, unit.num_lods, unit.num_neighbours, unit.num_buckets,
                         bool(h0.num_channel_predictions), layout, unit, adjust=adjust)
    h = attr.new_attribute_header(layout, n, 0)
    h.rows_per_chunk_minus1 = h0.rows_per_chunk_minus1
    payload = nc.write(h)
    if "adjust_mean" in spec or "adjust_level" in spec:  # recoded with the given model
        from ..common.neighbour_prediction import write_predicted_attribute_unit

        h.adjust_mean = int(spec.get("adjust_mean", h.adjust_mean))
        h.adjust_level = int(spec.get("adjust_level", h.adjust_level))
        payload = write_predicted_attribute_unit(h, layout, q, nc.graph, unit, nc.prediction, adjust,
                                                 step_flags=unit.step_flags)
    if spec.get("empty_adjust_chunks") or "append_adjust_hex" in spec:
        payload = _edit_adjust_chunks(h, payload, spec)
    units[j] = DataUnit(UnitType.ATTRIBUTE, payload)
    units.insert(k + 1, DataUnit(UnitType.STEP_ADJUST, StepAdjustUnit(max_step_adjust=top).to_bytes()))
    if unit.step_flags is not None:
        units.insert(k + 2, DataUnit(UnitType.STEP_ADJUST_FLAGS, unit.step_flags.to_bytes()))


def sh_degrees_of_rule(sh_rest_energy: np.ndarray, sh_degree: int, rule: str) -> np.ndarray:
    """Each Gaussian's SH degree (int64 [n]) by a conformance entry's rule: ``energy`` (the Gaussian
    of rank r among n by its SH-rest energy, ties by index, gets floor((d + 1) r / n): the degrees
    mixed, higher where the colour changes more with the view), ``const:<D>`` (every Gaussian D) or
    ``cycle`` (row i gets i mod (d + 1))."""
    n = sh_rest_energy.shape[0]
    if rule == "energy":
        rank = np.empty(n, np.int64)
        rank[np.argsort(sh_rest_energy, kind="stable")] = np.arange(n)
        return (sh_degree + 1) * rank // max(n, 1)
    if rule.startswith("const:"):
        return np.full(n, int(rule.split(":")[1]), np.int64)
    if rule == "cycle":
        return np.arange(n, dtype=np.int64) % (sh_degree + 1)
    raise ValueError(f"sh_degrees: unknown rule {rule!r}")


def _degree_chunk_faults(h: AttributeUnitHeader, payload: bytes, spec: dict) -> bytes:
    """The attribute unit ``payload`` (header ``h`` as written) with some of its SH-degree chunks
    emptied (``empty_degree_chunks``: [i], degree_chunk_size[i] 0), words appended to one
    (``append_degree_hex``: {chunk, hex}, sizes kept consistent) or ``degree_chunk_size_add`` bytes
    added to degree_chunk_size[0] alone (the sizes then miss the payload)."""
    from ..common.neighbour_prediction import chunk_piece_sizes

    sizes = chunk_piece_sizes(h)
    body, pos, pieces = payload[len(h.to_bytes()):], 0, []
    for size in sizes:
        pieces.append(body[pos:pos + size])
        pos += size
    per = len(sizes) // len(h.chunk_size)  # pieces per chunk: the degree data is the one before the symbols
    for i in spec.get("empty_degree_chunks", []):
        pieces[per * i + per - 2] = b""
    if "append_degree_hex" in spec:
        a = spec["append_degree_hex"]
        pieces[per * int(a["chunk"]) + per - 2] += bytes.fromhex(a["hex"])
    h.degree_chunk_size = [len(pieces[per * i + per - 2]) for i in range(len(h.chunk_size))]
    h.degree_chunk_size[0] += int(spec.get("degree_chunk_size_add", 0))
    return h.to_bytes() + b"".join(pieces)


def sh_degree(units, spec: dict) -> None:
    """Give every row of the single attribute unit of an explicit-Gaussian stream coded with
    neighbour prediction (no tiles, no step adjustment) an SH degree and insert the sh_degree unit
    after the neighbour_prediction unit (version 1.3, clause 7.3.14). The bands above a row's degree
    become 0, so the decoded scene changes (rehash the stream). spec: {degrees: a rule of
    sh_degrees_of_rule (default energy), zero_chunks: [i] (the rows of chunk i get degree 0),
    probabilities: extreme (degree_flag_prob[i] 0 for even i, 4095 for odd i) or a list (default:
    the encoder's, from the flags' counts), predictions: [[target, source, weight]] (the unit's
    cross-channel predictions, e.g. from channels a row may not code), and the faults of
    _degree_chunk_faults}."""
    from ..common.neighbour_prediction import chunk_segments
    from ..common.units import NUM_DEGREE_CONTEXTS, GaussianParameterSet, ShDegreeUnit
    from ..encoder.stream.neighbour_coding import NeighbourCoding

    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    if gps.hierarchy_enabled_flag or gps.tiles_enabled_flag or any(u.unit_type == UnitType.STEP_ADJUST for u in units):
        raise ValueError("sh_degree edits a stream without the hierarchy, tiles or step adjustment")
    layout = attr.gaussian_layout_of(gps)
    n, d = gps.num_gaussians, gps.sh_degree
    k, unit, coords, j, h0, values = _predicted_attribute_unit(units, gps, layout)
    q = np.rint(values / layout.steps(gps)).astype(np.int64)
    degrees = sh_degrees_of_rule((values[:, 3:layout.sh_channels].astype(np.float64) ** 2).sum(axis=1), d,
                                 str(spec.get("degrees", "energy")))
    h = attr.new_attribute_header(layout, n, 0)
    h.rows_per_chunk_minus1, h.num_lods = h0.rows_per_chunk_minus1, unit.num_lods
    nc = NeighbourCoding(q, coords, unit.num_lods, unit.num_neighbours, unit.num_buckets,
                         bool(h0.num_channel_predictions), layout, unit)
    segments = list(chunk_segments(h, nc.graph))
    for i in spec.get("zero_chunks", []):
        level, lo, hi = segments[int(i)]
        degrees[nc.graph.rows[level][lo:hi]] = 0
    probs = spec.get("probabilities")
    if probs is not None:  # the stream's probabilities given: the neighbour unit carries them to the coding
        count = d * NUM_DEGREE_CONTEXTS
        unit.sh_degree_unit = ShDegreeUnit(sh_degree=d, degree_flag_prob=[4095 * (i % 2) for i in range(count)]
                                           if probs == "extreme" else [int(p) for p in probs])
    nc = NeighbourCoding(q, coords, unit.num_lods, unit.num_neighbours, unit.num_buckets,
                         bool(h0.num_channel_predictions), layout, unit, graph=nc.graph, degrees=degrees)
    if "predictions" in spec:  # [[target, source, weight]]: cross-channel predictions of the stream's choosing
        t, src, w = (np.asarray(col, np.int64) for col in zip(*spec["predictions"]))
        nc.prediction = attr.ChannelPrediction(t, src, w)
    payload = _degree_chunk_faults(h, nc.write(h), spec)
    units[j] = DataUnit(UnitType.ATTRIBUTE, payload)
    units.insert(k + 1, DataUnit(UnitType.SH_DEGREE, nc.degree_unit.to_bytes()))


def _predicted_attribute_unit(units, gps, layout):
    """The single neighbour-predicted attribute unit of an explicit-Gaussian stream, decoded:
    (index of the neighbour_prediction unit, that unit, the positions, index of the attribute unit,
    its header, the decoded values [N, M])."""
    from ..common.geometry import decode_geometry
    from ..common.neighbour_prediction import read_predicted_attribute_unit
    from ..common.units import NeighbourPredictionUnit

    n = gps.num_gaussians
    k = _index(units, UnitType.NEIGHBOUR_PREDICTION)
    unit = NeighbourPredictionUnit.from_bytes(units[k].payload, num_channels=layout.num_channels)
    coords = decode_geometry(units[_index(units, UnitType.GEOMETRY)].payload, n)
    j = _index(units, UnitType.ATTRIBUTE)
    values = np.empty((n, layout.num_channels), np.float32)
    h0 = read_predicted_attribute_unit(units[j].payload, layout, layout.steps(gps), coords, unit, values)
    return k, unit, coords, j, h0, values


def rotation_length(units, spec: dict) -> None:
    """Give every row of the single attribute unit of an explicit-Gaussian stream coded with the
    rotation_length unit and neighbour prediction (no tiles, no step adjustment, no SH degrees) the
    rotation length index of a rule, and the unit the maximum ``max`` (version 1.4, clauses 7.3.15,
    11.10). x, y and z stay, so the implied w changes (rehash the stream). spec: {indices: cycle:<n>
    (row i gets i mod n; beyond ``max``, or negative with ``offset``, a fault), offset (added to
    every index, default 0), max, rows: {row: [qx, qy, qz]} (those rows' quantized x, y, z), xyz_all:
    [qx, qy, qz] (every row's)}."""
    from ..common.units import GaussianParameterSet, RotationLengthUnit
    from ..encoder.stream.neighbour_coding import NeighbourCoding

    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    if gps.hierarchy_enabled_flag or gps.tiles_enabled_flag or \
            any(u.unit_type in (UnitType.STEP_ADJUST, UnitType.SH_DEGREE) for u in units):
        raise ValueError("rotation_length edits a stream without the hierarchy, tiles, step adjustment or SH degrees")
    r = _index(units, UnitType.ROTATION_LENGTH)
    layout = attr.gaussian_layout_of(gps, RotationLengthUnit.from_bytes(units[r].payload).max_rotation_length_index)
    n, w = gps.num_gaussians, layout.rotation_start
    k, unit, coords, j, h0, values = _predicted_attribute_unit(units, gps, layout)
    q = np.rint(values / layout.steps(gps)).astype(np.int64)  # exact but for column w, replaced here
    period = int(str(spec["indices"]).split(":")[1])
    q[:, w] = np.arange(n, dtype=np.int64) % period + int(spec.get("offset", 0))
    if "xyz_all" in spec:  # every row's quantized x, y, z
        q[:, w + 1:w + 4] = np.asarray(spec["xyz_all"], np.int64)
    for row, xyz in (spec.get("rows") or {}).items():  # given x, y, z of some rows (normative order)
        q[int(row), w + 1:w + 4] = xyz
    top = int(spec["max"])
    layout = dataclasses.replace(layout, max_rotation_length_index=top)
    h = attr.new_attribute_header(layout, n, 0)
    h.rows_per_chunk_minus1, h.num_lods = h0.rows_per_chunk_minus1, unit.num_lods
    nc = NeighbourCoding(q, coords, unit.num_lods, unit.num_neighbours, unit.num_buckets,
                         bool(h0.num_channel_predictions), layout, unit)
    units[j] = DataUnit(UnitType.ATTRIBUTE, nc.write(h))
    units[r] = DataUnit(UnitType.ROTATION_LENGTH, RotationLengthUnit(max_rotation_length_index=top).to_bytes())


def sh_transform(units, spec: dict) -> None:
    """Replace the matrix of the sh_transform unit of an explicit-Gaussian stream (version 1.6, clauses
    7.3.17, 11.11) by a designed one; the coefficients stay, so the decoded SH rest changes (rehash
    the stream). spec: {matrix: identity (2^shift on the diagonal), extreme (the entries cycling
    -2^(B-1), 2^(B-1) - 1, 0, and seeded values of every magnitude), or keep (the unit's own), shift: R
    (default the unit's), bits: B (1 .. 16; default the fewest that hold the matrix), seed,
    scale_coefficients: s (every coefficient multiplied by s, the attribute unit coded again: a stream with
    neighbour prediction and no tiles, step adjustment or SH degrees whose coefficients are below 2^24)}."""
    from ..common.units import GaussianParameterSet, ShTransformUnit

    gps = GaussianParameterSet.from_bytes(units[_index(units, UnitType.GAUSSIAN_PARAMETER_SET)].payload)
    if "scale_coefficients" in spec:
        _scale_coefficients(units, gps, int(spec["scale_coefficients"]))
    r = _index(units, UnitType.SH_TRANSFORM)
    old = attr.ShTransform.from_unit(ShTransformUnit.from_bytes(units[r].payload, sh_degree=gps.sh_degree))
    shift = int(spec.get("shift", old.shift))
    n = old.size
    kind = spec.get("matrix", "keep")
    if kind == "identity":
        matrix = (np.eye(n, dtype=np.int64) << shift).ravel()
    elif kind == "extreme":
        bits = int(spec["bits"])
        lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        rng = np.random.default_rng(int(spec.get("seed", 0)))
        matrix = (rng.integers(lo, hi, size=n * n, endpoint=True) >> rng.integers(0, bits, size=n * n)).astype(np.int64)
        matrix[0::3], matrix[1::3] = lo, hi
    else:
        matrix = np.asarray(old.matrix, np.int64)
    unit = attr.ShTransform(shift, tuple(int(x) for x in matrix)).to_unit(gps.sh_degree)
    if "bits" in spec:  # the same entries in a wider field
        bits = int(spec["bits"])
        unit = ShTransformUnit(sh_degree=gps.sh_degree, sh_transform_shift=shift, sh_transform_bits_minus1=bits - 1,
                               sh_transform_coeff=[int(x) + (1 << (bits - 1)) for x in matrix])
    units[r] = DataUnit(UnitType.SH_TRANSFORM, unit.to_bytes())


def _scale_coefficients(units, gps, factor: int) -> None:
    """The single neighbour-predicted attribute unit coded again with its SH-rest coefficients times
    ``factor`` (large coefficients: sums of products beyond 2^53, clause 11.11). The coefficients are read
    as the values a layout without the transform reconstructs, float32(t) * step, exact below 2^24."""
    from ..encoder.stream.neighbour_coding import NeighbourCoding

    if gps.tiles_enabled_flag or any(u.unit_type in (UnitType.STEP_ADJUST, UnitType.SH_DEGREE) for u in units):
        raise ValueError("scale_coefficients edits a stream without tiles, step adjustment or SH degrees")
    layout = attr.gaussian_layout_of(gps)  # no transform: channel c's q as its value
    k, unit, coords, j, h0, values = _predicted_attribute_unit(units, gps, layout)
    q = np.rint(values / layout.steps(gps)).astype(np.int64)
    if np.abs(q).max(initial=0) >= 1 << 24:
        raise ValueError("scale_coefficients needs coefficients below 2^24")
    q[:, 3:layout.sh_channels] *= factor
    h = attr.new_attribute_header(layout, gps.num_gaussians, 0)
    h.rows_per_chunk_minus1, h.num_lods = h0.rows_per_chunk_minus1, unit.num_lods
    nc = NeighbourCoding(q, coords, unit.num_lods, unit.num_neighbours, unit.num_buckets,
                         bool(h0.num_channel_predictions), layout, unit)
    units[j] = DataUnit(UnitType.ATTRIBUTE, nc.write(h))


def _chunks_across_lods(h: AttributeUnitHeader, nc) -> bytes:
    """The attribute unit of ``nc`` (already written into ``h``) with its rows, in coding order, cut
    every rows_per_chunk rows regardless of the LoDs (a version-1.0 chunking of the LoD-major order),
    then empty chunks up to the NumChunks of clause 7.3.12."""
    from ..common.neighbour_prediction import (
        level_table,
        lod_coding_params,
        mean_flags,
    )

    order, graph, unit = nc.graph.coding_order, nc.graph, nc.unit
    prior = attr.prior_params(h)
    mean = np.empty(nc.q.shape, np.int64)
    level = np.empty(nc.q.shape, np.int64)
    mean[graph.rows[0]], level[graph.rows[0]] = prior.mean[0], prior.level[0]
    for lod in range(1, len(graph.rows)):
        rows = graph.rows[lod]
        if rows.size:
            p = lod_coding_params(nc.q, graph.neighbours[lod], level_table(unit), unit.num_buckets, mean_flags(unit),
                                  prior.mean[0])
            mean[rows], level[rows] = p.mean, p.level
    r = nc.prediction.residuals(nc.q[order], mean[order])
    s = h.rows_per_chunk
    chunks = [attr.encode_residual_chunk(r[lo:lo + s], level[order][lo:lo + s], None) for lo in range(0, len(order), s)]
    if len(chunks) > h.num_chunks:
        raise ValueError("chunks_across_lods: more chunks than NumChunks")
    chunks += [b""] * (h.num_chunks - len(chunks))
    h.chunk_size = [len(c) for c in chunks]
    return h.to_bytes() + b"".join(chunks)


def swap_tiles(units, pair: list[int]) -> None:
    """Tiles a and b exchanged with their tile_index entries (cell, point count, size): every
    tile's points still lie in its cell and the index still gives each tile's bytes, but the
    cells are out of their increasing order (clause 7.3.11)."""
    from ..common.units import TileIndex

    i = _index(units, UnitType.TILE_INDEX)
    index = TileIndex.parse(BitReader(units[i].payload), num_points=1 << 24)
    starts = [j for j, u in enumerate(units) if u.unit_type == UnitType.GEOMETRY]
    ends = [j for j, u in enumerate(units) if u.unit_type == UnitType.DECODED_SCENE_HASH]
    groups = [units[s:e + 1] for s, e in zip(starts, ends)]
    a, b = (int(t) for t in pair)
    groups[a], groups[b] = groups[b], groups[a]
    for name in ("tile_x", "tile_y", "tile_z", "tile_num_points_minus1", "tile_data_size"):
        values = getattr(index, name)
        values[a], values[b] = values[b], values[a]
    units[i] = DataUnit(UnitType.TILE_INDEX, index.to_bytes())
    units[starts[0]:ends[-1] + 1] = [u for g in groups for u in g]


def flatten_hierarchy(units, spec: dict) -> None:
    """hierarchy_enabled_flag 0, the level-1 and level-2 units (both with the per-channel prior)
    replaced by one level-0 unit of every row with the level-1 unit's prior: the same decoded
    scene without the hierarchy. Any context_model unit stays (clause 6.3: then an error)."""
    from ..common.geometry import decode_geometry
    from ..common.hierarchy import build_hierarchy
    from ..common.units import LEVEL_1, LEVEL_2

    sps = _sps(units)
    layout = _layout(sps)
    coords = decode_geometry(units[_index(units, UnitType.GEOMETRY)].payload, sps.num_points)
    hier = build_hierarchy(coords, sps.coarse_voxel_scale)
    values = np.empty((sps.num_points, layout.num_channels), np.float32)
    q = np.zeros((sps.num_points, layout.num_channels), np.int64)
    mask = np.ones((sps.num_points, layout.num_offsets), bool) if sps.offset_mask_present_flag else None
    a1, a2 = _index(units, UnitType.ATTRIBUTE, 0), _index(units, UnitType.ATTRIBUTE, 1)
    headers = []
    for j, level, rows in ((a1, LEVEL_1, hier.level1_idx), (a2, LEVEL_2, hier.level2_idx)):
        h, m, ql = attr.read_attribute_unit(units[j].payload, layout, layout.steps(sps), rows.size, level, values,
                                            rows, keep_q=True)
        q[rows] = ql
        if mask is not None:
            mask[rows] = m
        headers.append(h)
    h1 = headers[0]
    del units[a2]
    sps.hierarchy_enabled_flag = 0
    units[_index(units, UnitType.SCENE_PARAMETER_SET)] = DataUnit(UnitType.SCENE_PARAMETER_SET, sps.to_bytes())
    h1.attribute_level = 0
    _recode_level0(units, h1, mask, q)


def apply_edits(units, post: dict) -> None:
    """The edits of this module that ``post`` asks for, in a fixed order (the generator's
    post_process calls it after its own unit edits and before the rehash)."""
    for edit in _EDITS_IN_ORDER:
        if edit.__name__ in post:
            edit(units, post[edit.__name__])


# the order in which apply_edits makes the edits a stream's ``post`` names (each keyed by its name)
_EDITS_IN_ORDER = (
    designed_model, set_q, escape_classes, edit_chunk, recode_attribute_header,
    geometry_edit, context_unit, render_unit, neighbour_prediction, step_adjust,
    sh_degree, rotation_length, sh_transform, set_elements, flatten_hierarchy, swap_tiles, tile_point_beyond_cell,
    tile_into_cell_of, tile_scale_cells, nonzero_alignment,
)
