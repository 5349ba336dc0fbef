"""Memory bounded before allocation: what decoding a stream will need, computed from its headers.

The level limits of spec clause 8 bound every array a conforming stream can make a decoder
allocate, but not to something every machine has: 2^21 anchors x 1024 channels is within them,
and its attribute array alone is 8 GiB, from a stream of a few kB (an empty symbol chunk decodes
every value, spec 10.6.4). A decoder that allocates first finds out from the operating system,
late and badly (a MemoryError, or the machine swapping). The reference decoder instead adds up,
from the headers it has parsed, the memory each stage of the decoding process will hold, and
refuses a stream that needs more than ``max_memory`` with ResourceLimitError naming the amount
and its largest part, before anything sized by the stream is allocated:

1. ``MemoryPlan(...)``, right after the scene parameter set (decoding process, spec 13 step 2):
   the stream's bytes and their copies, the attribute array (N x M binary32), offset masks,
   coordinates and the geometry decoder's working set, the hierarchy, the hash's row blocks,
   the render model and context model units (their parameter counts come from their headers),
   and the smallest attribute chunk (one row). A stream beyond the bound is refused in
   milliseconds, before geometry decoding.
2. ``MemoryPlan.check_attribute_unit(...)``, before each attribute unit is decoded: the same
   with the unit's real chunk size (rows_per_chunk from its header), the level-1 quantized
   values a context model keeps, and the context model's working set (the Ball k-NN candidate
   blocks, GG-Conv's per-anchor terms and per-block edge tensors, the parent MLP's blocks),
   now that its parameters (k, layer widths) are decoded.

The amounts are upper bounds of what the reference implementation allocates (the constants
are bytes per value of its arrays, measured with tracemalloc and the kernel's peak RSS:
tests/test_limits.py checks that no stream of the suite, and none of a few larger ones, goes
above its estimate); they count the data a stream makes the decoder hold, not the program
itself (Python, NumPy and torch, about 300 MiB). This module is informative: a bound on memory
is a property of a decoder, not of the format (the format's bound is clause 8).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..common import attributes as attr
from ..common.bitio import BitReader
from ..common.container import DataUnit, UnitType
from ..common.errors import LghccError, ResourceLimitError
from ..common.units import GaussianParameterSet, SceneParameterSet

DEFAULT_MAX_MEMORY = 4 << 30  # lghcc-dec --max-memory and decode_stream(max_memory=...)

# Bytes per element of the reference implementation's arrays (measured; module docstring).
STREAM_COPIES = 3  # the container's payloads, the attribute unit's body, its chunk pieces
GEOMETRY_PER_ANCHOR = 192  # octree node lists, contexts, Morton keys and the final permutation (155 measured)
HIERARCHY_PER_ANCHOR = 128  # coarse voxels, lexsort, groups, level indices (98 measured)
PERSISTENT_PER_ANCHOR = 24 + 48  # coordinates int64 [N, 3]; level indices, parents, level coordinates
CHUNK_PER_VALUE_BROADCAST = 32  # per-channel prior without masks: bins int32, residuals int64, q, target (26)
CHUNK_PER_VALUE_GENERAL = 96  # levels per value: sort order, bins, residuals, escapes, q, target (77 measured)
CHUNK_PER_VALUE_CONTEXT = 6  # the context model's mean int32, level int8, step adjustment int8 per value
CHUNK_PER_VALUE_PREDICTION = 24  # cross-channel prediction (clause 11.6): deviations, q and a broadcast mean, int64
GAUSSIAN_SCENE_PER_POINT = 12 + 12  # a decoded Gaussian scene's means float32 [N, 3] and their float32 coordinates
HASH_BLOCK_ROWS = 1 << 16  # lghcc.common.hashing.HASH_BLOCK_ROWS
ENTROPY_PER_SYMBOL = 96  # one coded chunk of n symbols with levels per symbol (render / context model units)
RENDER_PER_PARAMETER = 4 + 8  # decoded binary32 weights, and their integers while dequantized
CONTEXT_PER_PARAMETER = 48  # int64 arrays, IntLinear's int64 and float64 copies, the float64 table
KNN_PER_CANDIDATE = 80  # Ball k-NN, per candidate of one row: distances, indices, exact d2, sort keys (110 B per
# candidate of the first ask measured on a tie-heavy grid; the plan counts twice the first ask)
KNN_BLOCK_ROWS = 1 << 17  # lghcc.common.knn._BLOCK
KNN_PER_DATA_POINT = 128  # k-d tree and float64 / int64 copies of the data points
GGCONV_BLOCK_ROWS = 1 << 12  # lghcc.common.context.ggconv.MAX_BLOCK_ROWS
GGCONV_LUT_MAX = 1 << 17  # lghcc.common.context.ggconv._LUT_MAX
PARENT_MLP_BLOCK_ROWS = 1 << 16  # lghcc.common.context.parent_mlp._BLOCK
NEIGHBOUR_PER_VALUE = 20  # neighbour prediction, per value and neighbour of one LoD: the neighbours' values int64
# and one masked copy at a time (548 B per value measured with 32 neighbours, 128 B with 6: counted 720 and 200)
F64 = 8
FIXED = 1 << 20  # whatever the stream: geometry count tables, frequency models, small arrays (65 kB measured)


@dataclass(frozen=True)
class Need:
    """One part of what decoding holds at once: bytes and how they arise, in words."""

    what: str
    bytes: int


def _fmt(n: int) -> str:
    from ..app.cli_common import format_bytes

    return format_bytes(n)


def _mlp_widths(shapes: list[tuple[int, ...]]) -> list[int]:
    """Fan-outs of an MLP's layers from its weight shapes [out, in]."""
    return [int(s[0]) for s in shapes if len(s) == 2]


def _render_model_parameters(unit: DataUnit | None) -> int:
    if unit is None:
        return 0
    from ..common.units import RenderModelUnit

    try:
        r = RenderModelUnit.from_bytes(unit.payload)
    except LghccError:
        return 0  # malformed: the decoding process reports it where it reads the unit
    total = 0
    for h in r.mlps:
        fan_in = h.input_dim_minus1 + 1
        for l in range(h.num_layers_minus1 + 1):
            out = h.output_dim_minus1[l] + 1
            total += out * fan_in + out
            fan_in = out
    return total


def _context_model_values(unit: DataUnit | None) -> int:
    if unit is None:
        return 0
    from ..common.context.model_unit import ContextModelUnit

    try:
        c = ContextModelUnit.from_bytes(unit.payload)
    except LghccError:
        return 0
    total = 0
    for a in c.arrays:
        n = 1
        for d in a.shape:
            n *= d
        total += n
    return total


class MemoryPlan:
    """The memory decoding a stream will hold, checked against ``max_memory`` (bytes; None: no
    bound) stage by stage (module docstring). Raises ResourceLimitError on construction when the
    parts known from the parameter set (a scene_parameter_set, or the gaussian_parameter_set of
    an explicit-Gaussian scene, whose points are its Gaussians) and the model units' headers
    already exceed it. ``layout``: the scene's channel layout (derived from ``sps`` if not given)."""

    def __init__(self, max_memory: int | None, sps: SceneParameterSet | GaussianParameterSet,
                 units: dict[int, list[DataUnit]], stream_bytes: int, layout=None):
        self.max_memory = max_memory
        self.sps = sps
        gaussians = isinstance(sps, GaussianParameterSet)
        if layout is None:
            layout = attr.gaussian_layout_of(sps) if gaussians else attr.layout_of(sps)
        self.layout = layout
        n, m, k = sps.num_points, layout.num_channels, layout.num_offsets
        self.n, self.m, self.k = n, m, k
        render_params = _render_model_parameters((units.get(UnitType.RENDER_MODEL) or [None])[0])
        context_values = _context_model_values((units.get(UnitType.CONTEXT_MODEL) or [None])[0])
        hash_rows = min(n, HASH_BLOCK_ROWS)
        # held from the geometry on, to the end
        self.persistent = [
            Need("fixed working set (count tables, frequency models)", FIXED),
            Need(f"the stream and its copies: {STREAM_COPIES} x {stream_bytes:,} bytes", STREAM_COPIES * stream_bytes),
            Need(f"attribute values: {n:,} anchors x {m:,} channels x 4 bytes", 4 * n * m),
            Need(f"coordinates and anchor indices: {n:,} anchors x {PERSISTENT_PER_ANCHOR} bytes",
                 PERSISTENT_PER_ANCHOR * n),
            Need(f"render model: {render_params:,} parameters x {RENDER_PER_PARAMETER} bytes",
                 RENDER_PER_PARAMETER * render_params),
            Need(f"context model: {context_values:,} values x {CONTEXT_PER_PARAMETER} bytes",
                 CONTEXT_PER_PARAMETER * context_values),
        ]
        if layout.offset_mask_present:
            self.persistent.append(Need(f"offset masks: 2 x {n:,} anchors x {k} offsets", 2 * n * k))
        if getattr(sps, "tiles_enabled_flag", 0):  # the tiles' arrays, then their join in stream order
            self.persistent.append(Need(f"tiles joined: a second copy of {n:,} anchors' values, coordinates and "
                                        "masks", 4 * n * m + 24 * n + 2 * n * k))
        if gaussians:
            self.persistent.append(Need(f"Gaussian positions: {n:,} Gaussians x {GAUSSIAN_SCENE_PER_POINT} bytes",
                                        GAUSSIAN_SCENE_PER_POINT * n))
        # one stage at a time: the largest is what is added on top of the persistent parts
        self.stages = [
            Need(f"geometry decoding: {n:,} anchors x {GEOMETRY_PER_ANCHOR} bytes", GEOMETRY_PER_ANCHOR * n),
            Need(f"decoded scene hash: {n:,} anchors x {k} offsets x 14 bytes and {hash_rows:,} rows x {m:,} "
                 "channels x 8 bytes", 14 * n * k + 8 * hash_rows * m),
            Need(f"render model decoding: {render_params:,} parameters x {ENTROPY_PER_SYMBOL} bytes",
                 ENTROPY_PER_SYMBOL * render_params),
            Need(f"context model decoding: {context_values:,} values x {ENTROPY_PER_SYMBOL} bytes",
                 ENTROPY_PER_SYMBOL * context_values),
            Need(f"attribute chunk of one row: {m:,} channels x {CHUNK_PER_VALUE_GENERAL} bytes",
                 CHUNK_PER_VALUE_GENERAL * m),
        ]
        if sps.hierarchy_enabled_flag:
            self.stages.append(Need(f"hierarchy: {n:,} anchors x {HIERARCHY_PER_ANCHOR} bytes",
                                    HIERARCHY_PER_ANCHOR * n))
        self.check(self.persistent, self.stages)

    def total(self, persistent: list[Need], stages: list[Need]) -> tuple[int, Need | None]:
        """Bytes needed at the worst moment, and the largest single part."""
        peak_stage = max(stages, key=lambda s: s.bytes, default=None)
        parts = persistent + ([peak_stage] if peak_stage else [])
        return sum(p.bytes for p in parts), max(parts, key=lambda p: p.bytes, default=None)

    def check(self, persistent: list[Need], stages: list[Need]) -> int:
        need, largest = self.total(persistent, stages)
        if self.max_memory is not None and need > self.max_memory and largest is not None:
            raise ResourceLimitError(
                f"decoding this stream needs about {_fmt(need)} of memory, more than the allowed {_fmt(self.max_memory)} "
                f"(--max-memory); the largest part is {largest.what} = {_fmt(largest.bytes)}")
        return need

    def check_attribute_unit(self, payload: bytes, num_rows: int, level: int, context_model=None,
                             num_level1: int | None = None) -> int:
        """Before decoding an attribute unit of ``num_rows`` rows: its chunk working set (from its
        header's rows_per_chunk), the level-1 values kept for a context model, and the context
        model's working set at level 2 (``context_model``: the stream's, decoder/core.py;
        ``num_level1``: N1). Returns the bytes needed; ResourceLimitError beyond the bound. A
        header that does not parse is left to the decoding process to report."""
        from ..common.units import LEVEL_1, LEVEL_2, AttributeUnitHeader

        layout, m, k = self.layout, self.m, self.k
        try:
            h = AttributeUnitHeader.parse(BitReader(payload, "attribute unit"), None, num_channels=m, num_offsets=k,
                                          offset_mask_present=layout.offset_mask_present,
                                          channel_prediction_allowed=layout.channel_prediction_allowed,
                                          num_rows=num_rows)
        except LghccError:
            return 0
        rows = min(h.rows_per_chunk, num_rows)
        with_model = h.context_model_id != 0
        general = with_model or bool(layout.offset_mask_present)
        per_value = (CHUNK_PER_VALUE_GENERAL if general else CHUNK_PER_VALUE_BROADCAST) \
            + (CHUNK_PER_VALUE_CONTEXT if with_model else 0) \
            + (CHUNK_PER_VALUE_PREDICTION if h.num_channel_predictions else 0)
        persistent = list(self.persistent)
        stages = [Need(f"attribute chunk: {rows:,} rows x {m:,} channels x {per_value} bytes", per_value * rows * m)]
        if context_model is not None and level in (LEVEL_1, LEVEL_2):
            n1 = num_level1 if num_level1 is not None else num_rows
            persistent.append(Need(f"level-1 quantized values for the context model: {n1:,} anchors x {m:,} "
                                   "channels x 8 bytes", 8 * n1 * m))
            if level == LEVEL_2 and with_model:
                persistent += context_working_set(context_model, n1, num_rows, m)
        return self.check(persistent, stages)

    def check_predicted_attribute_unit(self, num_rows: int, unit) -> int:
        """Before decoding a tile's attribute unit coded with neighbour prediction (``unit``): the
        quantized values of every row and the neighbour graph, kept while the LoDs decode; then,
        one after the other, the Ball k-NN of the largest LoD (its candidate blocks, twice the
        first ask as for GG-Conv), the neighbours' values of one LoD while its means and levels
        are computed, and one LoD's means and levels with a chunk."""
        from ..common.units import lod_sizes_of

        m, k = self.m, unit.num_neighbours
        persistent = self.persistent + [
            Need(f"neighbour prediction: {num_rows:,} rows x {m:,} channels x 8 bytes of quantized values and "
                 f"{k} neighbours x 8 bytes", 8 * num_rows * (m + k))]
        sizes = lod_sizes_of(num_rows, unit.num_lods)
        lod = max(sizes)
        finer = max(sizes[1:], default=0)
        ask = 2 * (k + 2)
        stages = self.stages + [
            Need(f"neighbour search of one LoD: {finer:,} rows x {ask} candidates x {KNN_PER_CANDIDATE} bytes and "
                 f"{num_rows:,} points x {KNN_PER_DATA_POINT} bytes",
                 finer * ask * KNN_PER_CANDIDATE + KNN_PER_DATA_POINT * num_rows),
            Need(f"neighbour values of one LoD: {finer:,} rows x {k} neighbours x {m:,} channels x "
                 f"{NEIGHBOUR_PER_VALUE} bytes", NEIGHBOUR_PER_VALUE * finer * m * (k + 4)),
            Need(f"means and levels of one LoD and its chunk: {lod:,} rows x {m:,} channels x "
                 f"{16 + CHUNK_PER_VALUE_GENERAL + CHUNK_PER_VALUE_PREDICTION} bytes",
                 (16 + CHUNK_PER_VALUE_GENERAL + CHUNK_PER_VALUE_PREDICTION) * lod * m)]
        return self.check(persistent, stages)


def context_working_set(context_model, n1: int, n2: int, m: int) -> list[Need]:
    """What evaluating the level-2 context model holds besides the attribute chunk: the arrays it
    keeps for all rows, and the largest of its per-block stages (GG-Conv: the Ball k-NN's
    candidate blocks, then the per-block edge tensors)."""
    from ..common.units import CONTEXT_GGCONV

    p = context_model.params
    if context_model.model_id != CONTEXT_GGCONV:
        widths = [layer.fan_out for layer in p.head_mlp.layers]
        rows = min(n2, PARENT_MLP_BLOCK_ROWS)
        per_row = F64 * (3 + m) * 3 + 2 * F64 * sum(widths) + 4 * F64 * m
        return [Need(f"parent MLP: level-1 values {n1:,} x {m:,} x 8 bytes", F64 * n1 * m),
                Need(f"parent MLP block: {rows:,} rows x {per_row:,} bytes", rows * per_row)]
    kk = p.k
    data = n1 if p.neighbour_level == 1 else n2
    ask = min(2 * (kk + (3 if p.neighbour_level == 1 else 9)), max(data, 1))
    knn_rows = min(n2, KNN_BLOCK_ROWS)
    feat, head = p.feat_mlp.layers, p.head_mlp.layers
    h, ch, hh = feat[0].fan_out, p.context_channels, head[0].fan_out
    side = 2 * p.radius + 1
    lut = side ** 3 if side ** 3 <= min(GGCONV_LUT_MAX, max(1 << 10, 2 * n2 * kk)) else 0
    block = min(n2, GGCONV_BLOCK_ROWS)
    edges = block * kk
    geometry_per_edge = F64 * (h + 4 * ch + 32)
    per_edge = F64 * (h + ch + 8) + 2 * F64 * sum(l.fan_out for l in feat[1:]) + (0 if lut else geometry_per_edge)
    per_row = 2 * F64 * sum(l.fan_out for l in head) + F64 * (ch + 8) + 5 * F64 * m
    stages = [Need(f"Ball k-NN: {knn_rows:,} rows x {ask} candidates x {KNN_PER_CANDIDATE} bytes and "
                   f"{data:,} data points x {KNN_PER_DATA_POINT} bytes",
                   knn_rows * ask * KNN_PER_CANDIDATE + KNN_PER_DATA_POINT * data),
              Need(f"GG-Conv block: {edges:,} edges x {per_edge:,} bytes and {block:,} rows x {per_row:,} bytes",
                   edges * per_edge + block * per_row)]
    return [Need(f"GG-Conv graph: {n2:,} anchors x {kk} neighbours x 26 bytes", 26 * n2 * kk + 64 * n2),
            Need(f"GG-Conv level-1 terms: {n1:,} anchors x ({m:,} channels x 16 + {h + hh:,} x 8) bytes",
                 n1 * (16 * m + F64 * (h + hh))),
            Need(f"GG-Conv geometry table: {lut:,} offsets x {geometry_per_edge:,} bytes", lut * geometry_per_edge),
            max(stages, key=lambda s: s.bytes)]
