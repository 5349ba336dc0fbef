"""The decoding process of spec clause 13: bitstream in, scene out, nothing else needed.

This module is the normative decoder and imports only common/ (tests/test_architecture.py): no
worker processes, progress, memory bound or reports. Those live in the driver above it
(decoder/decode.py), which reaches in through plain arguments only: ``admit`` (called once the
parameter set is read, before anything sized by the stream exists), ``checks`` (called before each
attribute unit) and ``on_rows`` (rows decoded so far, for a progress bar).

Clause 13's steps and the functions that make them:

====================================================  =============================================
13.1 step 1: the container, unit types, counts, order  ``read_container`` (common), ``organize_units``
13.1 step 2: the parameter set and the level limits    ``read_parameter_set``, ``check_level_limits``
13.1 step 3: the render model                          ``read_render_model_unit`` (common)
13.1 step 4: the units before the tile index           ``read_context_model_unit``,
                                                       ``read_neighbour_prediction_unit``,
                                                       ``with_rotation_length``, ``with_sh_transform``
13.1 step 5: the tile index and the tiles              ``tiles_of``
13.1 steps 1 to 5 together                             ``parse_stream`` -> ``ParsedStream``
13.2 a tile: step 1 geometry, steps 2-3 the attribute  ``decode_tile``; ``decode_attribute_units``
units, step 4 the tile's hash                          (``decode_predicted_attribute_units`` with a
                                                       neighbour_prediction unit); ``check_tile_hash``
13.1 step 7: the scene, tiles in stream order          ``join_tiles``, ``scene_of``
13.3 partial decoding: a box, the level-1 preview      ``selected_tiles``; ``max_level`` LEVEL_1
====================================================  =============================================

Critical data units come in the order (clause 6.3, version 1)
    scene_parameter_set, [render_model], [context_model], [tile_index], tile+
for an anchor scene, or
    gaussian_parameter_set, [context_model], [tile_index], tile+
for an explicit-Gaussian scene (with the optional units of clause 6.3 between), where a tile is
    geometry, attribute x (1 or 2), decoded_scene_hash
with two attribute units (level 1, then level 2) when the hierarchy is enabled and the tile's
level 2 is not empty. Without tiles (tiles_enabled_flag = 0) the stream has one tile, which
holds every point, and no tile_index unit. Ancillary units (type >= 0x80) may appear anywhere
after the parameter set. This decoder knows one, source_info (0x80, clause 7.3.10), and returns
what it says; it skips the others. The decoded scene and its hash never depend on an ancillary
unit: a source_info this decoder cannot parse, or a second one, is noted and ignored.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from ..common import attributes as attr
from ..common.attributes import ChannelLayout, GaussianLayout
from ..common.container import AncillaryUnitType, Container, DataUnit, UnitType, read_container
from ..common.context.models import Level2CodingParams, level2_coding_params, read_context_model
from ..common.errors import BitstreamError, HashMismatchError, UnsupportedStreamError, UsageError
from ..common.geometry import decode_geometry
from ..common.hashing import digest_of
from ..common.hierarchy import Hierarchy, build_hierarchy
from ..common.neighbour_prediction import read_predicted_attribute_unit
from ..common.render_model import RenderMLP, read_render_model_unit
from ..common.scene import AnchorScene, GaussianScene
from ..common.syntax import TraceEntry
from ..common.tiles import Box, cell_intersects_box, check_points_in_cell, check_tile_index
from ..common.units import (CONTEXT_GGCONV, CONTEXT_PARENT_MLP, LEVEL_1, LEVEL_2, LEVEL_ALL, MAX_ATTRIBUTE_VALUES,
                            DecodedSceneHashUnit, GaussianParameterSet, NeighbourPredictionUnit, RotationLengthUnit,
                            SceneParameterSet, ShDegreeUnit, ShTransformUnit, SourceInfo, StepAdjustFlagsUnit,
                            StepAdjustUnit, TileIndex)

if TYPE_CHECKING:  # the models' modules load torch: imported when a stream has a context model
    from ..common.context.ggconv import GGConvParams
    from ..common.context.parent_mlp import ParentMlpParams

ParameterSet = SceneParameterSet | GaussianParameterSet
Layout = ChannelLayout | GaussianLayout
Trace = list[TraceEntry] | None


@dataclass(frozen=True)
class ParentMlpContext:
    """A context_model unit with context_model_id 1 (clause 7.3.7): the parent MLP."""
    params: ParentMlpParams
    model_id: ClassVar[int] = CONTEXT_PARENT_MLP

    @property
    def pair(self) -> tuple[int, ParentMlpParams]:
        """(model_id, params): the form common/context/models.py takes."""
        return self.model_id, self.params


@dataclass(frozen=True)
class GgconvContext:
    """A context_model unit with context_model_id 2 (clause 7.3.7): GG-Conv."""
    params: GGConvParams
    model_id: ClassVar[int] = CONTEXT_GGCONV

    @property
    def pair(self) -> tuple[int, GGConvParams]:
        """(model_id, params): the form common/context/models.py takes."""
        return self.model_id, self.params


ContextModel = ParentMlpContext | GgconvContext
# What the attribute units of a stream are decoded with besides their own prior: the context model
# (with the hierarchy), the neighbour_prediction unit with its step_adjust, step_adjust_flags and
# sh_degree units (without it; clause 8.3 rule 14: never both), or nothing.
AttributeContext = ParentMlpContext | GgconvContext | NeighbourPredictionUnit | None


class UnitChecks(Protocol):
    """What the driver checks before each attribute unit is decoded (decoder/limits.py's
    MemoryPlan: the memory the unit's decoding will hold). Raises to refuse the unit."""

    def check_attribute_unit(self, payload: bytes, num_rows: int, level: int, context_model: ContextModel | None,
                             num_level1: int | None) -> int: ...

    def check_predicted_attribute_unit(self, num_rows: int, unit: NeighbourPredictionUnit) -> int: ...


# --- 13.1 step 1: unit types and their order ---------------------------------------------------

_LETTER = {UnitType.SCENE_PARAMETER_SET: "S", UnitType.GAUSSIAN_PARAMETER_SET: "P", UnitType.RENDER_MODEL: "R",
           UnitType.GEOMETRY: "G", UnitType.CONTEXT_MODEL: "C", UnitType.ATTRIBUTE: "A",
           UnitType.DECODED_SCENE_HASH: "H", UnitType.TILE_INDEX: "I", UnitType.NEIGHBOUR_PREDICTION: "N",
           UnitType.STEP_ADJUST: "Q", UnitType.STEP_ADJUST_FLAGS: "F", UnitType.SH_DEGREE: "B",
           UnitType.ROTATION_LENGTH: "W", UnitType.SH_TRANSFORM: "T"}
# an anchor scene, or an explicit-Gaussian scene, which has no render model but may have neighbour
# prediction (and with it step adjustment and the SH degrees), rotation lengths and the SH transform;
# then the tiles
_UNIT_ORDER = re.compile(r"(SR?|P(N(QF?)?B?)?W?T?)C?I?(GA{1,2}H)+")
_KNOWN_ANCILLARY = set(AncillaryUnitType._value2member_map_)


def _order_condition(letters: str) -> str:
    """The row of clause 8.2 a unit order that ``_UNIT_ORDER`` refuses breaks: E61 (a case of E14 with
    a row of its own) when the neighbour_prediction units alone are wrong (in an anchor stream,
    repeated, or not right after the gaussian_parameter_set), else E14."""
    if "N" in letters:
        rest = letters.replace("N", "")
        if _UNIT_ORDER.fullmatch(rest.replace("P", "PN", 1) if rest.startswith("P") else rest):
            return "E61"
    return "E14"


def organize_units(container: Container, known: list[DataUnit] | None = None) -> tuple[list[DataUnit], list[str]]:
    """Check unit types and their order; return the critical units and the skipped ones (the
    ancillary units this decoder does not know). The ancillary units it knows (clause 6.3)
    are appended to ``known`` when given, else skipped too."""
    critical: list[DataUnit] = []
    skipped: list[str] = []
    for idx, u in enumerate(container.units):
        if u.is_ancillary:
            if not critical:
                raise BitstreamError(f"data unit {idx}: an ancillary unit precedes the scene parameter set (or gaussian parameter set)", condition="E11")
            if known is not None and u.unit_type in _KNOWN_ANCILLARY:
                known.append(u)
            else:
                skipped.append(f"{u.type_name} ({len(u.payload)} bytes at byte {u.offset})")
        elif u.unit_type in _LETTER:
            critical.append(u)
        else:
            raise UnsupportedStreamError(f"data unit {idx} has unit type 0x{u.unit_type:02x}, which this "
                                         "decoder does not know and which is not marked ancillary", condition="E10")
    letters = "".join(_LETTER[UnitType(u.unit_type)] for u in critical)
    if "S" not in letters and "P" not in letters:
        raise BitstreamError("the stream has no scene_parameter_set or gaussian_parameter_set unit", condition="E12")
    for t in (UnitType.GEOMETRY, UnitType.ATTRIBUTE, UnitType.DECODED_SCENE_HASH):
        if _LETTER[t] not in letters:
            raise BitstreamError(f"the stream has no {t.name.lower()} unit", condition="E13")
    if not _UNIT_ORDER.fullmatch(letters):
        names = ", ".join(u.type_name for u in critical)
        raise BitstreamError(f"data units are out of order or repeated: {names} (expected scene_parameter_set, "
                             "[render_model], [context_model], [tile_index], then per tile geometry, attribute "
                             "(1 or 2), decoded_scene_hash; or gaussian_parameter_set, [neighbour_prediction [step_adjust "
                             "[step_adjust_flags]] [sh_degree]], "
                             "[rotation_length], [sh_transform], "
                             "[context_model], "
                             "[tile_index], then the tiles)", condition=_order_condition(letters))
    if "I" not in letters and letters.count("G") > 1:
        raise BitstreamError(f"the stream has {letters.count('G')} tiles (geometry units) but no tile_index unit", condition="E54")
    return critical, skipped


def units_by_type(units: list[DataUnit]) -> dict[int, list[DataUnit]]:
    """The critical units by unit type, each type's in stream order."""
    by_type: dict[int, list[DataUnit]] = {}
    for u in units:
        by_type.setdefault(u.unit_type, []).append(u)
    return by_type


def _first(by_type: dict[int, list[DataUnit]], unit_type: UnitType) -> DataUnit | None:
    return by_type.get(unit_type, [None])[0]


# --- 13.1 step 2: the parameter set and the level limits ----------------------------------------

# lghcc-dec --level 1 on a stream without the hierarchy (clause 13.3)
NO_PREVIEW = ("the stream has no level-1 preview: it was coded without the hierarchy (hierarchy_enabled_flag 0; "
              "the lghcc-* presets code one), so --level 1 would decode the whole scene; decode it whole "
              "(--level 2, the default) or a part of it with --box")


def read_parameter_set(by_type: dict[int, list[DataUnit]], entries: Trace) -> tuple[ParameterSet, Layout]:
    """The stream's parameter set (an explicit-Gaussian stream's, else the anchor scene's) and
    its channel layout."""
    if UnitType.GAUSSIAN_PARAMETER_SET in by_type:
        ps = GaussianParameterSet.from_bytes(by_type[UnitType.GAUSSIAN_PARAMETER_SET][0].payload, entries,
                                             what="gaussian parameter set")
        return ps, attr.gaussian_layout_of(ps)
    ps = SceneParameterSet.from_bytes(by_type[UnitType.SCENE_PARAMETER_SET][0].payload, entries,
                                      what="scene parameter set")
    return ps, attr.layout_of(ps)


def point_word(ps: ParameterSet) -> str:
    """What the stream's points are, in words: Gaussians or anchors."""
    return "Gaussian" if isinstance(ps, GaussianParameterSet) else "anchor"


def check_level_limits(ps: ParameterSet, layout: Layout) -> None:
    """The level limit on attribute values (clause 8)."""
    n = ps.num_points
    if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:
        raise BitstreamError(f"{n} {point_word(ps)}s x {layout.num_channels} channels exceeds the level limit of "
                             f"{MAX_ATTRIBUTE_VALUES} attribute values", condition="E22")


def steps_of(ps: ParameterSet, layout: Layout) -> np.ndarray:
    """float32 [M]: the quantization step of each channel (the layout is the parameter set's)."""
    if isinstance(ps, GaussianParameterSet) and isinstance(layout, GaussianLayout):
        return layout.steps(ps)
    if isinstance(ps, SceneParameterSet) and isinstance(layout, ChannelLayout):
        return layout.steps(ps)
    raise TypeError(f"a {type(layout).__name__} is not the layout of a {type(ps).__name__}")


def sh_degree_of(ps: ParameterSet) -> int:
    """The SH degree of an explicit-Gaussian scene (the unit order puts the units that need it only
    after a gaussian_parameter_set)."""
    if not isinstance(ps, GaussianParameterSet):
        raise TypeError("an anchor scene's scene_parameter_set has no sh_degree")
    return ps.sh_degree


def read_source_info(units: list[DataUnit], trace: Trace = None) -> tuple[SourceInfo | None, list[str]]:
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
        mark = 0 if trace is None else len(trace)
        try:
            info = SourceInfo.from_payload(u.payload, trace)
        except BitstreamError as e:
            if trace is not None:
                del trace[mark:]
            notes.append(f"{where}: cannot be parsed ({e}); ignored")
    return info, notes


# --- 13.1 step 4: the units between the parameter set and the tile index ------------------------

def read_context_model_unit(context_unit: DataUnit | None, ps: ParameterSet, layout: Layout,
                            entries: Trace) -> ContextModel | None:
    """The stream's context model (None without a context_model unit). Raises BitstreamError."""
    if context_unit is None:
        return None
    if not ps.hierarchy_enabled_flag:
        raise BitstreamError("a context model unit in a stream without the hierarchy", condition="E16")
    _, params = read_context_model(context_unit.payload, layout, entries)
    from ..common.context.ggconv import GGConvParams  # loaded by read_context_model (torch with it)

    return GgconvContext(params) if isinstance(params, GGConvParams) else ParentMlpContext(params)


def read_neighbour_prediction_unit(unit: DataUnit | None, ps: ParameterSet, layout: Layout, entries: Trace,
                                   step_adjust_unit: DataUnit | None = None,
                                   sh_degree_unit: DataUnit | None = None,
                                   step_flags_unit: DataUnit | None = None) -> NeighbourPredictionUnit | None:
    """The stream's neighbour_prediction unit (None without one), with the stream's step_adjust,
    step_adjust_flags and sh_degree units as its context (the unit order puts them only after a
    neighbour_prediction unit, the step_adjust_flags unit only after the step_adjust unit). Raises
    BitstreamError."""
    if unit is None:
        return None
    if ps.hierarchy_enabled_flag:
        raise BitstreamError("a neighbour_prediction unit in a stream with the hierarchy (hierarchy_enabled_flag 1)", condition="E60")
    neighbour = NeighbourPredictionUnit.from_bytes(unit.payload, entries, what="neighbour prediction unit",
                                                   num_channels=layout.num_channels)
    if step_adjust_unit is not None:
        neighbour.step_adjust = StepAdjustUnit.from_bytes(step_adjust_unit.payload, entries, what="step_adjust unit")
    if step_flags_unit is not None:
        adjust = neighbour.step_adjust
        assert adjust is not None, "the unit order puts a step_adjust_flags unit only after a step_adjust unit"
        neighbour.step_flags = StepAdjustFlagsUnit.from_bytes(step_flags_unit.payload, entries,
                                                              what="step_adjust_flags unit",
                                                              max_step_adjust=adjust.max_step_adjust)
    if sh_degree_unit is not None:
        neighbour.sh_degree_unit = ShDegreeUnit.from_bytes(sh_degree_unit.payload, entries, what="sh_degree unit",
                                                           sh_degree=sh_degree_of(ps))
    return neighbour


def with_rotation_length(layout: Layout, unit: DataUnit | None, entries: Trace) -> Layout:
    """The layout of a stream with a rotation_length unit (clause 7.3.15): its channel w carries
    the length index (clause 11.10); ``layout`` itself without one."""
    if unit is None:
        return layout
    rl = RotationLengthUnit.from_bytes(unit.payload, entries, what="rotation_length unit")
    return dataclasses.replace(layout, max_rotation_length_index=rl.max_rotation_length_index)


def with_sh_transform(layout: Layout, unit: DataUnit | None, ps: ParameterSet, entries: Trace) -> Layout:
    """The layout of a stream with an sh_transform unit (clause 7.3.17): its SH-rest channels carry
    transform coefficients (clause 11.11); ``layout`` itself without one."""
    if unit is None:
        return layout
    st = ShTransformUnit.from_bytes(unit.payload, entries, what="sh_transform unit", sh_degree=sh_degree_of(ps))
    return dataclasses.replace(layout, sh_transform=attr.ShTransform.from_unit(st))


def read_attribute_context(by_type: dict[int, list[DataUnit]], ps: ParameterSet, layout: Layout,
                           entries: Trace) -> AttributeContext:
    """The attribute units' context: the context model or the neighbour_prediction unit with its
    own context units (a stream has at most one of them: one needs the hierarchy, the other its
    absence)."""
    context_model = read_context_model_unit(_first(by_type, UnitType.CONTEXT_MODEL), ps, layout, entries)
    neighbour = read_neighbour_prediction_unit(_first(by_type, UnitType.NEIGHBOUR_PREDICTION), ps, layout, entries,
                                               _first(by_type, UnitType.STEP_ADJUST),
                                               _first(by_type, UnitType.SH_DEGREE),
                                               _first(by_type, UnitType.STEP_ADJUST_FLAGS))
    return neighbour if neighbour is not None else context_model


# --- 13.1 step 5: the tile index and the tiles -------------------------------------------------

@dataclass
class TileUnits:
    """The units of one tile (clause 7.3.11): its cell (None: the one tile of a stream without
    tiles), its point count, geometry, attribute units and decoded_scene_hash unit."""
    cell: tuple[int, int, int] | None
    num_points: int
    geometry: DataUnit
    attributes: list[DataUnit]
    scene_hash: DataUnit


def _tile_groups(units: list[DataUnit]) -> list[list[DataUnit]]:
    """The critical units from the first geometry unit on, cut after each decoded_scene_hash."""
    start = next(i for i, u in enumerate(units) if u.unit_type == UnitType.GEOMETRY)
    groups: list[list[DataUnit]] = []
    cur: list[DataUnit] = []
    for u in units[start:]:
        cur.append(u)
        if u.unit_type == UnitType.DECODED_SCENE_HASH:
            groups.append(cur)
            cur = []
    return groups


def tiles_of(units: list[DataUnit], by_type: dict[int, list[DataUnit]], n: int,
             entries: Trace) -> tuple[list[TileUnits], TileIndex | None]:
    """The tiles of the stream, checked against its tile index (clause 7.3.11): each tile's units
    start at the byte the index gives and take tile_data_size bytes, so the index can be used to
    seek. Raises BitstreamError."""
    groups = _tile_groups(units)
    if UnitType.TILE_INDEX not in by_type:
        g = groups[0]
        return [TileUnits(None, n, g[0], g[1:-1], g[-1])], None
    iu = by_type[UnitType.TILE_INDEX][0]
    index = TileIndex.from_bytes(iu.payload, entries, what="tile index unit", num_points=n)
    check_tile_index(index, n)
    if index.num_tiles != len(groups):
        raise BitstreamError(f"tile_index_unit lists {index.num_tiles} tiles, the stream holds {len(groups)}", condition="E55")
    pos = iu.offset + iu.size
    tiles = []
    for t, g in enumerate(groups):
        end = g[-1].offset + g[-1].size
        at = g[0].offset
        for u in g:  # the tile's units one after the other: no ancillary unit among them
            if u.offset != at:
                raise BitstreamError(f"tile {t}: an ancillary unit stands among its units (at byte {at}); the tiles "
                                     "hold only their critical units", condition="E55")
            at += u.size
        if g[0].offset != pos or end - pos != index.tile_data_size[t]:
            raise BitstreamError(f"tile_index_unit: tile {t} is said to take {index.tile_data_size[t]} bytes at byte "
                                 f"{pos}, its units take {end - g[0].offset} bytes at byte {g[0].offset}", condition="E55")
        tiles.append(TileUnits(index.cells[t], index.tile_num_points_minus1[t] + 1, g[0], g[1:-1], g[-1]))
        pos = end
    return tiles, index


# --- 13.1 steps 1 to 5 --------------------------------------------------------------------------

@dataclass
class ParsedStream:
    """What clause 13.1 steps 1 to 5 give before any tile is decoded: the container, the critical
    units (and the skipped ones), the parameter set and channel layout, the render MLPs, the
    attribute units' context (context model or neighbour_prediction unit) and the tiles."""
    container: Container
    skipped: list[str]
    ps: ParameterSet
    layout: Layout
    mlps: dict[str, RenderMLP]
    context_model: AttributeContext
    tiles: list[TileUnits]
    source_info: SourceInfo | None
    notes: list[str]

    @property
    def point(self) -> str:
        return point_word(self.ps)


def parse_stream(data: bytes, entries: Trace = None, *, max_level: int = LEVEL_2,
                 admit: Callable[[ParameterSet, Layout, dict[int, list[DataUnit]]], None] | None = None) -> ParsedStream:
    """Clause 13.1 steps 1 to 5, made alike for a full and a partial decode: the container, the
    unit order, the parameter set and its limits, the models and the tile index. ``max_level`` 1
    on a stream without the hierarchy raises UsageError (clause 13.3: such a stream has no
    preview) once its parameter set is read. ``admit(ps, layout, units by type)``: the driver's
    own bounds, checked after the level limits and before anything sized by the stream exists."""
    container = read_container(data)
    ancillary: list[DataUnit] = []
    units, skipped = organize_units(container, ancillary)
    by_type = units_by_type(units)
    ps, layout = read_parameter_set(by_type, entries)
    if max_level == LEVEL_1 and not ps.hierarchy_enabled_flag:
        raise UsageError(NO_PREVIEW)
    source_info, notes = read_source_info(ancillary, entries)
    check_level_limits(ps, layout)
    if admit is not None:
        admit(ps, layout, by_type)
    if (UnitType.TILE_INDEX in by_type) != bool(ps.tiles_enabled_flag):
        raise BitstreamError(f"tiles_enabled_flag is {ps.tiles_enabled_flag} but the stream "
                             + ("has a tile_index unit" if ps.tiles_enabled_flag == 0 else "has no tile_index unit"), condition="E54")
    mlps = {}
    if UnitType.RENDER_MODEL in by_type:
        mlps = read_render_model_unit(by_type[UnitType.RENDER_MODEL][0].payload, entries)
    context = read_attribute_context(by_type, ps, layout, entries)
    layout = with_rotation_length(layout, _first(by_type, UnitType.ROTATION_LENGTH), entries)
    layout = with_sh_transform(layout, _first(by_type, UnitType.SH_TRANSFORM), ps, entries)
    tiles, _ = tiles_of(units, by_type, ps.num_points, entries)
    return ParsedStream(container, skipped, ps, layout, mlps, context, tiles, source_info, notes)


# --- 13.2 steps 2 and 3: the attribute units of a tile ------------------------------------------

@dataclass
class DecodedAttributes:
    """What the attribute units of a tile (or of the joined tiles) decode into."""
    values: np.ndarray  # float32 [N, M]
    mask: np.ndarray | None  # bool [N, K] (anchor scenes with offset masks)
    hierarchy: Hierarchy | None


def decode_predicted_attribute_units(attribute_units: list[DataUnit], layout: Layout, steps: np.ndarray,
                                    coords: np.ndarray, unit: NeighbourPredictionUnit, entries: Trace,
                                    checks: UnitChecks | None = None,
                                    on_rows: Callable[[int], object] | None = None) -> DecodedAttributes:
    """The attribute unit of a tile of a stream with a neighbour_prediction unit (clause 11.7):
    exactly one per tile."""
    n = coords.shape[0]
    if len(attribute_units) != 1:
        raise BitstreamError(f"a tile of {n} points without the hierarchy has {len(attribute_units)} attribute "
                             "units, not 1", condition="E63")
    values = np.empty((n, layout.num_channels), dtype=np.float32)
    if checks is not None:
        checks.check_predicted_attribute_unit(n, unit)
    read_predicted_attribute_unit(attribute_units[0].payload, layout, steps, coords, unit, values, entries,
                                  on_chunk=on_rows, step_adjust=unit.step_adjust, sh_degree=unit.sh_degree_unit,
                                  step_flags=unit.step_flags)
    return DecodedAttributes(values, None, None)


Levels = Sequence[tuple[int, "np.ndarray | None"]]  # (attribute level, its rows in the tile; None: every row)


def hierarchy_levels(coords: np.ndarray, ps: ParameterSet) -> tuple[Hierarchy | None, Levels]:
    """13.2 step 2: the tile's hierarchy (None without one) and its levels as (level, rows):
    level 1, then level 2 when it is not empty; without the hierarchy one level of every row."""
    if not ps.hierarchy_enabled_flag:
        return None, [(LEVEL_ALL, None)]
    hier = build_hierarchy(coords, ps.coarse_voxel_scale)
    levels: Levels = [(LEVEL_1, hier.level1_idx)] + ([(LEVEL_2, hier.level2_idx)] if hier.num_level2 else [])
    return hier, levels


def decode_attribute_units(attribute_units: list[DataUnit], layout: Layout, steps: np.ndarray, coords: np.ndarray,
                           ps: ParameterSet, context_model: AttributeContext, entries: Trace,
                           checks: UnitChecks | None = None, max_level: int = LEVEL_2,
                           on_rows: Callable[[int], object] | None = None) -> DecodedAttributes:
    """Decode the attribute units of a tile (clause 13.2 steps 2-3): level 1 (or every point) with
    its per-channel prior, then level 2 with the context model when there is one; a tile whose
    level 2 is empty has one unit. ``ps``: the parameter set (hierarchy flag and coarse voxel
    scale). ``checks``: what each unit is checked against before it is decoded.
    ``max_level`` 1: stop after level 1 (the preview; level-2 rows are left undefined)."""
    n = coords.shape[0]
    if isinstance(context_model, NeighbourPredictionUnit):
        return decode_predicted_attribute_units(attribute_units, layout, steps, coords, context_model, entries,
                                                checks, on_rows)
    hier, levels = hierarchy_levels(coords, ps)
    if len(attribute_units) != len(levels):
        raise BitstreamError(f"a tile of {n} points with hierarchy_enabled_flag = {ps.hierarchy_enabled_flag} "
                             + (f"and {hier.num_level2} level-2 points " if hier is not None else "")
                             + f"has {len(attribute_units)} attribute units, not {len(levels)}", condition="E15")
    if max_level == LEVEL_1:
        levels = levels[:1]
    values = np.empty((n, layout.num_channels), dtype=np.float32)
    mask = np.ones((n, layout.num_offsets), dtype=bool) if layout.offset_mask_present else None
    q_level1 = None

    def level2_context(model_id: int) -> Level2CodingParams:
        if context_model is None or model_id != context_model.model_id:
            raise BitstreamError(f"the level-2 attribute unit uses context model {model_id}, but the stream's "
                                 "context model unit " + ("is missing" if context_model is None else
                                                          f"holds model {context_model.model_id}"), condition="E47")
        assert hier is not None and q_level1 is not None  # a level-2 unit follows level 1 of a hierarchy
        return level2_coding_params(context_model.pair, coords[hier.level1_idx], q_level1, coords[hier.level2_idx],
                                    hier.parent_of_level2, ps.coarse_voxel_scale)

    for unit, (level, rows) in zip(attribute_units, levels):
        num_rows = n if rows is None else rows.size
        if checks is not None:
            checks.check_attribute_unit(unit.payload, num_rows, level, context_model,
                                        hier.num_level1 if hier is not None and rows is not None else None)
        _, m, q = attr.read_attribute_unit(unit.payload, layout, steps, num_rows, level, values, rows,
                                           level2_context if level == LEVEL_2 else None, entries,
                                           keep_q=level == LEVEL_1 and context_model is not None,
                                           on_chunk=on_rows)
        if level == LEVEL_1:
            q_level1 = q
        if mask is not None:
            mask[slice(None) if rows is None else rows] = m
    return DecodedAttributes(values, mask, hier)


# --- 13.2: one tile ------------------------------------------------------------------------------

@dataclass
class DecodedTile:
    """What one tile decodes to: its points in normative order, their attribute values and
    offset mask, whether its decoded_scene_hash was checked, and its level counts (N1, N2; None
    without the hierarchy)."""
    coords: np.ndarray
    values: np.ndarray
    mask: np.ndarray | None
    hash_checked: bool
    level_counts: tuple[int, int] | None = None

    @property
    def num_points(self) -> int:
        return int(self.coords.shape[0])


def decode_tile(tile: TileUnits, t: int, ps: ParameterSet, layout: Layout, context_model: AttributeContext,
                mlps: dict[str, RenderMLP], *, verify_hash: bool = True, entries: Trace = None,
                checks: UnitChecks | None = None, max_level: int = LEVEL_2,
                on_rows: Callable[[int], object] | None = None) -> DecodedTile:
    """Decode tile ``t`` on its own (clause 13.2): geometry, attribute units, and its hash (the
    hash of the tile's points as a scene). ``max_level`` 1: only the level-1 points (the
    preview; no hash can be checked)."""
    coords = decode_geometry(tile.geometry.payload, tile.num_points, entries)
    if tile.cell is not None:
        check_points_in_cell(coords, tile.cell, ps.tile_size, t)
    dec = decode_attribute_units(tile.attributes, layout, steps_of(ps, layout), coords, ps, context_model, entries,
                                 checks, max_level, on_rows)
    hash_unit = DecodedSceneHashUnit.from_bytes(tile.scene_hash.payload, entries, what="decoded scene hash unit")
    h = dec.hierarchy
    counts = None if h is None else (h.num_level1, h.num_level2)
    if max_level == LEVEL_1 and h is not None:
        keep = h.level1_idx
        return DecodedTile(coords[keep], dec.values[keep], None if dec.mask is None else dec.mask[keep], False, counts)
    if verify_hash:
        scene = scene_of(ps, layout, coords, dec, mlps)
        check_tile_hash(scene, hash_unit.scene_hash, "" if tile.cell is None else f"tile {t}: ")
    return DecodedTile(coords, dec.values, dec.mask, verify_hash, counts)


def check_tile_hash(scene: AnchorScene | GaussianScene, scene_hash: bytes, where: str = "") -> None:
    """Clause 12: the SHA-256 of the decoded scene (of a tile's points, in a tiled stream) must
    equal the decoded_scene_hash of the stream (of the tile)."""
    digest = digest_of(scene)
    if digest != scene_hash:
        raise HashMismatchError(f"{where}the decoded scene does not match the hash in the stream "
                                f"(decoded SHA-256 {digest.hex()}, stream {scene_hash.hex()})", condition="E53")


# --- 13.1 step 7: the scene ---------------------------------------------------------------------

def join_tiles(parts: list[DecodedTile], layout: Layout) -> tuple[np.ndarray, DecodedAttributes]:
    """The tiles' points in stream order: coordinates and attributes."""
    if len(parts) == 1:
        p = parts[0]
        return p.coords, DecodedAttributes(p.values, p.mask, None)
    coords = np.concatenate([p.coords for p in parts]) if parts else np.empty((0, 3), np.int64)
    values = np.concatenate([p.values for p in parts]) if parts else np.empty((0, layout.num_channels), np.float32)
    mask = None
    if layout.offset_mask_present:
        masks = [p.mask for p in parts if p.mask is not None]
        mask = np.concatenate(masks) if masks else np.empty((0, layout.num_offsets), bool)
    return coords, DecodedAttributes(values, mask, None)


def scene_of(ps: ParameterSet, layout: Layout, coords: np.ndarray, dec: DecodedAttributes,
             mlps: dict[str, RenderMLP]) -> AnchorScene | GaussianScene:
    """The decoded scene: positions on the grid of the parameter set, attributes split by the layout."""
    if isinstance(ps, GaussianParameterSet) and isinstance(layout, GaussianLayout):
        sh, opacity, log_scales, rotations = layout.split(dec.values)
        return GaussianScene.on_grid(coords, float(ps.voxel_size), ps.origin, sh, opacity, log_scales, rotations)
    assert isinstance(layout, ChannelLayout), "an anchor scene's layout"
    features, scalings, offsets = layout.split(dec.values)
    return AnchorScene(coords=coords, voxel_size=float(ps.voxel_size), origin=np.asarray(ps.origin, dtype=np.float32),
                       features=features, scalings=scalings, offsets=offsets, offset_mask=dec.mask, mlps=mlps)


# --- 13.3: partial decoding ---------------------------------------------------------------------

def selected_tiles(tiles: list[TileUnits], ps: ParameterSet, box: Box | None) -> list[int]:
    """Every tile, or those whose cell meets the box (a stream without tiles: its one tile)."""
    if box is None or tiles[0].cell is None:
        return list(range(len(tiles)))
    return [t for t, tile in enumerate(tiles)
            if tile.cell is not None
            and cell_intersects_box(tile.cell, ps.tile_size, float(ps.voxel_size), ps.origin, box)]
