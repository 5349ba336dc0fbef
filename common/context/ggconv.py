"""GG-Conv context model for level-2 anchors, integer inference (normative;
spec/hierarchy_ggconv.md, clause "GG-Conv").

Per level-2 anchor i (rows in level-2 order), with x_i the parent's decoded attributes
(M = C features + 6 scalings + 3K offsets, integer quantization units, clamped to 16 bits):

1. neighbours j: canonical Ball k-NN (common/knn.py) from p_i, k and radius_sq from the model
   parameters; invalid slots contribute nothing. The model's neighbour_level says among which
   anchors: 2 = the other level-2 anchors, each carrying its parent's attributes x_j (the
   paper's graph over the preliminary context set A_pre^(2)); 1 = the level-1 anchors, each
   carrying its own decoded attributes x_j at its own position.
2. geometry branch: R = isqrt(radius_sq); per axis U = floor(((dp + R) (D-1) 2^(FB+1) + 2R) / (4R))
   in [0, (D-1) 2^FB] (FB = 8 fractional bits); cell i0 = min(U >> FB, D-2), t = U - i0 2^FB;
   w_ij = rshift_round(sum over the 8 corners of prod_axes(t or 2^FB - t) * T[corner], 3 FB),
   T the int16 table [D, D, D, Ch].
3. feature branch: e_ij = feat_mlp([x_j[:C] - x_i[:C], U - (D-1) 2^(FB-1)]), Ch outputs; the
   feature differences are NOT clamped (17-bit inputs of the first layer, |acc| < 2^48).
4. h_i = clamp16(rshift_round(sum_j valid_ij * w_ij * e_ij, h_shift)).
5. o_i = head_mlp([h_i, clamp(p_i mod s, 0, 32767) (3), n_valid_i, x_i]), 3M outputs;
   mean = clamp16(parent_base * x_i + o[0:M]) (parent_base[m] = 1: the parent's value is the
   base of channel m's prediction; 0: o alone, for channels a parent does not predict),
   level = clamp(o[M:2M], 0, 63), step_adjust = clamp(o[2M:3M], 0, 7).

Bounds: trilinear sum |.| <= 2^24 * 2^15 = 2^39; sum_j |w e| <= MAX_K * 2^30 = 2^36; the MLPs
obey common/intnn.py (|acc| < 2^47; < 2^48 for the feature MLP's first layer with its 17-bit
difference inputs). Every intermediate is an integer below 2^53 (exact in float64 too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..attributes import NUM_STEP_ADJUST, STEP_ADJUST_FACTORS  # noqa: F401 (re-exported)
from ..entropy.scale_levels import NUM_SCALE_LEVELS as NUM_LEVELS  # the float twin imports it by this name
from .model_unit import (MAX_H_SHIFT, MAX_K, MAX_RADIUS_SQ, NEIGHBOUR_LEVELS, Hyperparameters,  # noqa: F401
                         NamedIntArray, mlp_arrays, required)
from ..intnn import ACT_MAX, ACT_MIN, IntLinear, IntMLP, WEIGHT_BITS_ALLOWED, rshift_round
from ..hierarchy import local_position
from ..knn import ball_knn
from ..scene import NUM_SCALINGS

GRID_FRAC_BITS = 8  # FB: fractional bits of the grid coordinate U
TRI_SHIFT = 3 * GRID_FRAC_BITS  # the trilinear weights sum to 2^24
MIN_GRID, MAX_GRID = 2, 16  # allowed table size D


@dataclass
class GGConvParams:
    num_features: int  # C: the first C attribute channels are features
    k: int  # neighbours per anchor, [1, MAX_K]
    radius_sq: int  # squared ball radius, in squared voxel units, [1, MAX_RADIUS_SQ]
    table: np.ndarray  # int16 [D, D, D, Ch]
    h_shift: int  # [0, MAX_H_SHIFT]
    feat_mlp: IntMLP  # C + 3 -> ... -> Ch
    head_mlp: IntMLP  # Ch + 3 + 1 + M -> ... -> 3 M
    neighbour_level: int = 2  # NEIGHBOUR_LEVELS: the hierarchy level whose anchors are the neighbours
    parent_base: np.ndarray | None = None  # int [M] of 0/1 (None: all 1), see check_parent_base

    def __post_init__(self) -> None:
        t = np.asarray(self.table)
        if t.ndim != 4 or not (t.shape[0] == t.shape[1] == t.shape[2]) or not MIN_GRID <= t.shape[0] <= MAX_GRID:
            raise ValueError(f"table must have shape [D, D, D, Ch] with D in [{MIN_GRID}, {MAX_GRID}], "
                             f"got {list(t.shape)}")
        if t.size and (int(t.min()) < ACT_MIN or int(t.max()) > ACT_MAX):
            raise ValueError("table values outside the 16-bit range")
        self.table = t.astype(np.int64)
        if not 1 <= int(self.k) <= MAX_K:
            raise ValueError(f"k must be in [1, {MAX_K}], got {self.k}")
        if not 1 <= int(self.radius_sq) <= MAX_RADIUS_SQ:
            raise ValueError(f"radius_sq must be in [1, {MAX_RADIUS_SQ}], got {self.radius_sq}")
        if not 0 <= int(self.h_shift) <= MAX_H_SHIFT:
            raise ValueError(f"h_shift must be in [0, {MAX_H_SHIFT}], got {self.h_shift}")
        if isinstance(self.neighbour_level, bool) or int(self.neighbour_level) not in NEIGHBOUR_LEVELS:
            raise ValueError(f"neighbour_level must be one of {NEIGHBOUR_LEVELS}, got {self.neighbour_level}")
        self.k, self.radius_sq, self.h_shift = int(self.k), int(self.radius_sq), int(self.h_shift)
        self.neighbour_level = int(self.neighbour_level)
        ch = self.context_channels
        c = int(self.num_features)
        if c < 1 or self.feat_mlp.in_dim != c + 3 or self.feat_mlp.out_dim != ch:
            raise ValueError(f"feature MLP must map C + 3 = {c + 3} inputs to Ch = {ch} outputs, got "
                             f"{self.feat_mlp.in_dim} -> {self.feat_mlp.out_dim}")
        if self.head_mlp.out_dim % 3:
            raise ValueError("head MLP output count must be 3 M")
        m = self.num_attrs
        if m < c + NUM_SCALINGS or self.head_mlp.in_dim != ch + 4 + m:
            raise ValueError(f"head MLP must map Ch + 4 + M = {ch + 4 + m} inputs to 3 M outputs, got "
                             f"{self.head_mlp.in_dim} -> {self.head_mlp.out_dim}")
        for name, mlp in (("feat", self.feat_mlp), ("head", self.head_mlp)):
            for l, layer in enumerate(mlp.layers):
                if layer.relu != (l < len(mlp.layers) - 1):
                    raise ValueError(f"{name} MLP: ReLU follows every layer but the last")
        self.parent_base = check_parent_base(self.parent_base, m)

    @property
    def base(self) -> np.ndarray:
        """parent_base as __post_init__ made it: int [M] of 0/1."""
        assert self.parent_base is not None, "set by __post_init__"
        return self.parent_base

    @property
    def grid_size(self) -> int:
        return int(self.table.shape[0])

    @property
    def context_channels(self) -> int:
        return int(self.table.shape[3])

    @property
    def num_attrs(self) -> int:
        return self.head_mlp.out_dim // 3

    @property
    def radius(self) -> int:
        return math.isqrt(self.radius_sq)

    def num_parameters(self) -> int:
        return int(self.table.size) + self.feat_mlp.num_parameters() + self.head_mlp.num_parameters()

    # -- serialization -----------------------------------------------------------------------
    def to_syntax(self) -> tuple[Hyperparameters, list[NamedIntArray]]:
        """The context-model unit's content (spec clause 7.3.7, Annex H.5.4): the hyperparameters
        num_features, neighbour_level, k, radius_sq, h_shift and every layer's shift (syntax
        elements), and the arrays parent_base (u1 [M]), table (s16 [D,D,D,Ch]), then for mlp in
        (feat, head), for each layer l: {mlp}.{l}.weight (s8 or s16 [out, in]), {mlp}.{l}.bias
        (s32 [out]). ReLU follows every layer but the last."""
        hp = Hyperparameters(int(self.num_features), [layer.shift for layer in self.head_mlp.layers],
                             [layer.shift for layer in self.feat_mlp.layers], self.neighbour_level, self.k,
                             self.radius_sq, self.h_shift)
        arrays = [NamedIntArray("parent_base", self.base.copy(), 1, False),
                  NamedIntArray("table", self.table.copy(), 16, True)]
        return hp, arrays + mlp_arrays("feat", self.feat_mlp) + mlp_arrays("head", self.head_mlp)

    @classmethod
    def from_syntax(cls, hp: Hyperparameters, arrays: list[NamedIntArray]) -> "GGConvParams":
        """Inverse of ``to_syntax``; ValueError on a missing, unknown or malformed array, or a
        model whose parts do not fit together (the message names the parameter)."""
        by = arrays_by_name(arrays)
        p = cls(num_features=hp.num_features, neighbour_level=required(hp.neighbour_level, "neighbour_level"),
                k=required(hp.k, "k"), radius_sq=required(hp.radius_sq, "radius_sq"),
                h_shift=required(hp.h_shift, "h_shift"), parent_base=take_array(by, "parent_base").values,
                table=take_array(by, "table").values, feat_mlp=mlp_from_arrays(by, "feat", hp.feat_layer_shift),
                head_mlp=mlp_from_arrays(by, "head", hp.head_layer_shift))
        if by:
            raise ValueError(f"unknown parameters: {sorted(by)}")
        return p


def arrays_by_name(arrays: list[NamedIntArray]) -> dict[str, NamedIntArray]:
    """The arrays by name, values as int64; ValueError on a duplicate name, a value that is not an
    integer, or one outside the array's declared width."""
    by = {}
    for a in arrays:
        if a.name in by:
            raise ValueError(f"duplicate parameter {a.name!r}")
        v = np.asarray(a.values)
        if v.size and not np.issubdtype(v.dtype, np.integer):
            raise ValueError(f"parameter {a.name!r} is not integer")
        lo, hi = (-(1 << (a.bits - 1)), (1 << (a.bits - 1)) - 1) if a.signed else (0, (1 << a.bits) - 1)
        if v.size and (int(v.min()) < lo or int(v.max()) > hi):
            raise ValueError(f"parameter {a.name!r} outside its {a.bits}-bit range")
        by[a.name] = NamedIntArray(a.name, v.astype(np.int64), a.bits, a.signed)
    return by


def take_array(by: dict[str, NamedIntArray], name: str) -> NamedIntArray:
    if name not in by:
        raise ValueError(f"missing parameter {name!r}")
    return by.pop(name)


def mlp_from_arrays(by: dict[str, NamedIntArray], name: str, shifts) -> IntMLP:
    """The integer MLP ``name`` from its arrays {name}.{l}.weight / .bias (taken out of ``by``)
    and the layers' shifts (syntax elements); ReLU after every layer but the last."""
    if not shifts:
        raise ValueError(f"the {name} MLP has no layers")
    layers = []
    for l, shift in enumerate(shifts):
        w, b = take_array(by, f"{name}.{l}.weight"), take_array(by, f"{name}.{l}.bias")
        if w.bits not in WEIGHT_BITS_ALLOWED:
            raise ValueError(f"{name}.{l}.weight: weight bits must be one of {WEIGHT_BITS_ALLOWED}")
        layers.append(IntLinear(w.values, b.values, int(shift), l < len(shifts) - 1, w.bits))
    return IntMLP(layers)


# -- normative building blocks, shared with the float twin (encoder/context/ggconv_train.py) ----------

def check_parent_base(parent_base, num_attrs: int) -> np.ndarray:
    """The per-channel parent_base flags as int64 [M] (None: every channel 1); ValueError
    unless shape [M] with values in {0, 1}."""
    if parent_base is None:
        return np.ones(num_attrs, dtype=np.int64)
    b = np.asarray(parent_base)
    if b.shape != (num_attrs,) or (b.size and not np.issubdtype(b.dtype, np.integer) and b.dtype != bool):
        raise ValueError(f"parent_base must be integer [M] = [{num_attrs}], got {b.dtype} {list(b.shape)}")
    b = b.astype(np.int64)
    if b.size and (int(b.min()) < 0 or int(b.max()) > 1):
        raise ValueError("parent_base values must be 0 or 1")
    return b


def clamp16(x):
    return x.clamp(ACT_MIN, ACT_MAX) if isinstance(x, torch.Tensor) else np.clip(x, ACT_MIN, ACT_MAX)


def grid_coordinate(dp: torch.Tensor, radius: int, grid: int) -> torch.Tensor:
    """U = floor(((dp + R) (D-1) 2^(FB+1) + 2R) / (4R)) for |dp| <= R: fixed-point position in
    the table's grid [0, D-1] with FB fractional bits (rounded to nearest, ties up)."""
    num = (dp + radius) * ((grid - 1) << (GRID_FRAC_BITS + 1)) + 2 * radius
    return torch.div(num, 4 * radius, rounding_mode="floor")


def trilinear_corners(u: torch.Tensor, grid: int) -> tuple[torch.Tensor, torch.Tensor]:
    """u: int64 [R, 3] grid coordinates. Returns flat table row indices [R, 8] and integer
    weights [R, 8] (each in [0, 2^24], summing to 2^24); corner b = 4 bx + 2 by + bz, flat
    index ((ix D) + iy) D + iz."""
    one = 1 << GRID_FRAC_BITS
    i0 = torch.clamp(u >> GRID_FRAC_BITS, max=grid - 2)
    t = u - (i0 << GRID_FRAC_BITS)
    wa = torch.stack([one - t, t], 2)  # [R, 3, 2]: weight of the lower / upper grid line per axis
    w = (wa[:, 0, :, None, None] * wa[:, 1, None, :, None] * wa[:, 2, None, None, :]).reshape(-1, 8)
    base = (i0[:, 0] * grid + i0[:, 1]) * grid + i0[:, 2]
    corner = torch.tensor([bx * grid * grid + by * grid + bz for bx in (0, 1) for by in (0, 1) for bz in (0, 1)],
                          dtype=torch.int64)
    return base[:, None] + corner, w


def trilinear_sum(table_f64: torch.Tensor, corner_idx: torch.Tensor, corner_w: torch.Tensor) -> torch.Tensor:
    """sum over the 8 corners of corner_w * T[corner_idx], exact, as int64 [E, Ch].

    Evaluated in float64 with one fused gather-multiply-sum: every product (<= 2^24 * 2^15) and
    every partial sum (<= 2^39) is an integer below 2^53, so each float64 operation is exact
    and the result equals the int64 sum, whatever the summation order."""
    if corner_idx.shape[0] == 0:
        return torch.zeros((0, table_f64.shape[1]), dtype=torch.int64)
    s = torch.nn.functional.embedding_bag(corner_idx, table_f64, per_sample_weights=corner_w.to(torch.float64),
                                          mode="sum")
    return s.to(torch.int64)


@dataclass
class EdgeInputs:
    """The valid edges of a block of anchors (rows r of the block, neighbour slots flattened)."""
    row: torch.Tensor  # int64 [E]: anchor row (within the block) of each edge
    feat_in: torch.Tensor  # int64 [E, C + 3]: x_j - x_i features (17 bits), U - (D-1) 2^(FB-1)
    corner_idx: torch.Tensor  # int64 [E, 8]
    corner_w: torch.Tensor  # int64 [E, 8]


def edge_inputs(q_coords: torch.Tensor, q_attrs: torch.Tensor, d_coords: torch.Tensor, d_attrs: torch.Tensor,
                nbr: torch.Tensor, valid: torch.Tensor, rows: slice | torch.Tensor, num_features: int, radius: int,
                grid: int) -> EdgeInputs:
    """Normative edge quantities for the level-2 anchors `rows` (a slice or an int64 index
    tensor); edges come row by row, slots in order. q_*: the level-2 anchors (positions,
    clamped parent attributes); d_*: the neighbour set (the same tensors for neighbour_level 2,
    the level-1 anchors for neighbour_level 1); nbr indexes d_*."""
    v = valid[rows]
    r_loc, slot = torch.nonzero(v, as_tuple=True)
    i = r_loc + rows.start if isinstance(rows, slice) else rows[r_loc]
    j = nbr[rows][r_loc, slot]
    dp = d_coords[j] - q_coords[i]
    u = grid_coordinate(dp, radius, grid)
    du = u - ((grid - 1) << (GRID_FRAC_BITS - 1))
    df = d_attrs[j, :num_features] - q_attrs[i, :num_features]  # not clamped: 17-bit values
    ci, cw = trilinear_corners(u, grid)
    return EdgeInputs(r_loc, torch.cat([df, du], 1), ci, cw)


def head_inputs(h: torch.Tensor, local_pos: torch.Tensor, n_valid: torch.Tensor, xpar: torch.Tensor) -> torch.Tensor:
    return torch.cat([h, local_pos.clamp(0, ACT_MAX), n_valid[:, None], xpar], 1)


def split_outputs(o: torch.Tensor, xpar: torch.Tensor, parent_base: np.ndarray, m: int
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """mean = clamp16(parent_base * parent value + o[0:M]); level, step_adjust: o clamped to
    their ranges."""
    base = torch.from_numpy(parent_base).to(xpar.dtype)
    return (clamp16(xpar * base + o[:, :m]), o[:, m:2 * m].clamp(0, NUM_LEVELS - 1),
            o[:, 2 * m:].clamp(0, NUM_STEP_ADJUST - 1))


def neighbour_graph(k: int, radius_sq: int, neighbour_level: int, coords2: np.ndarray,
                    coords1: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The canonical Ball k-NN graph of the level-2 anchors: among the other level-2 anchors
    (neighbour_level 2, self excluded) or among the level-1 anchors (neighbour_level 1)."""
    if neighbour_level == 2:
        return ball_knn(coords2, k, radius_sq, exclude_self=True)
    return ball_knn(coords1, k, radius_sq, query=coords2)


def level2_graph(params: GGConvParams, coords2: np.ndarray, coords1: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The graph ``params`` calls for (coords1, the level-1 positions, needed for neighbour_level 1)."""
    return neighbour_graph(params.k, params.radius_sq, params.neighbour_level, coords2, coords1)


def _int_array(a, cols: int, what: str) -> np.ndarray:
    x = np.asarray(a)
    if x.ndim != 2 or x.shape[1] != cols or (x.size and not np.issubdtype(x.dtype, np.integer)):
        raise ValueError(f"{what} must be integer [N, {cols}], got {x.dtype} {list(x.shape)}")
    return x.astype(np.int64, copy=False)


def check_level2_inputs(num_attrs: int, coords2, parent, coords1, attrs1, voxel_scale):
    """The inputs of a level-2 context model (Annex H, clause H.5.2) as int64 arrays, checked:
    level-2 positions [N2, 3], parent [N2] (indices into level 1), level-1 positions [N1, 3]
    and decoded attributes [N1, M]; ValueError naming the input otherwise."""
    c2 = _int_array(coords2, 3, "coords2")
    c1 = _int_array(coords1, 3, "level-1 coords")
    x1 = _int_array(attrs1, num_attrs, "level-1 attributes")
    par = np.asarray(parent)
    if par.shape != (c2.shape[0],) or (par.size and not np.issubdtype(par.dtype, np.integer)):
        raise ValueError(f"parent must be integer [N2] = [{c2.shape[0]}], got {par.dtype} {list(par.shape)}")
    if c1.shape[0] != x1.shape[0]:
        raise ValueError("level-1 coords and attributes differ in length")
    if par.size and (int(par.min()) < 0 or int(par.max()) >= x1.shape[0]):
        raise ValueError("a parent index is outside level 1")
    if isinstance(voxel_scale, bool) or not isinstance(voxel_scale, (int, np.integer)) or voxel_scale < 1:
        raise ValueError(f"voxel_scale must be an integer >= 1, got {voxel_scale!r}")
    return c2, par.astype(np.int64, copy=False), c1, x1


def _geometry_terms(dp: torch.Tensor, params: GGConvParams, table_f: torch.Tensor, lin0_u: torch.Tensor,
                    lin0_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For offsets dp (int64 [L, 3], |dp| <= R): the grid part of the feature MLP's first
    accumulator, bias + W[:, C:] (U - (D-1) 2^(FB-1)) (float64 [L, H], exact: |.| < 3 2^11 2^15
    + 2^31), and the geometry weights w (float64 [L, Ch], 16-bit integers)."""
    g = params.grid_size
    u = grid_coordinate(dp, params.radius, g)
    du = (u - ((g - 1) << (GRID_FRAC_BITS - 1))).to(torch.float64)
    ci, cw = trilinear_corners(u, g)
    w = rshift_round(trilinear_sum(table_f, ci, cw), TRI_SHIFT).to(torch.float64)
    return torch.addmm(lin0_b, du, lin0_u), w


_LUT_MAX = 1 << 17  # largest (2R+1)^3 for which the geometry terms are tabulated per offset
# rows evaluated at once: 512 per torch thread, so that a thread's share of a block's edge terms
# (512 x K x H float64, 2 MiB at K = 8, H = 64) stays in its core's L2 cache: 24-33% faster than
# 4096 rows on one thread, up to 24% on two (tools/results/ggconv_blocks.md);
# the result does not depend on it
BLOCK_ROWS_PER_THREAD = 1 << 9
MAX_BLOCK_ROWS = 1 << 12


def block_rows() -> int:
    return min(BLOCK_ROWS_PER_THREAD * torch.get_num_threads(), MAX_BLOCK_ROWS)


def ggconv_coding_params(params: GGConvParams, coords2, parent, coords1, attrs1, voxel_scale: int,
                         neighbours: tuple[np.ndarray, np.ndarray] | None = None,
                         block: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coding parameters of the level-2 attributes (Annex H, clause H.5).

    coords2: int [N2, 3] level-2 positions in level-2 order; parent: int [N2] each one's
    level-1 parent (an index into level 1); coords1: int [N1, 3] and attrs1: int [N1, M] the
    level-1 positions and decoded attributes in quantization units (features first);
    voxel_scale: the hierarchy's coarse voxel scale s; neighbours: (idx, valid) from
    ``level2_graph`` (computed when None).
    Returns mean (int32), level (int8), step_adjust (int8), each [N2, M]: the integer mean of
    each attribute symbol, its scale level in [0, 64) and its step adjustment in [0, 8).
    (``GGConvEvaluator`` gives any range of rows; decoders use it chunk by chunk.)
    """
    ev = GGConvEvaluator(params, coords2, parent, coords1, attrs1, voxel_scale, neighbours)
    return ev.rows(0, ev.num_rows, block)


class GGConvEvaluator:
    """GG-Conv coding parameters of any range of level-2 rows: the Ball k-NN graph, the
    first-layer terms of the level-1 attribute vectors and the geometry table are computed
    once, so a decoder evaluates a chunk's rows when it decodes that chunk (memory O(chunk)).

    Evaluation (informative; bit-exact with the normative text, see the tests against a
    one-anchor-at-a-time Python-integer reference):
    * every quantity is an integer held in float64 and every operation's exact result is an
      integer of magnitude < 2^53, so float64 arithmetic is exact (common/intnn.py);
    * the feature MLP's first layer is linear in its input, and its input is the *unclamped*
      difference y_j - x_i: its accumulator is
          A_ij = P(y_j) - P(x_i) + bias + W[:, C:] du_ij,  P(x) = W[:, :C] x[:C]   (|P| <= C 2^30 < 2^46)
      and every x_i and y_j is the attribute vector of a level-1 anchor (a parent's, or the
      neighbour's own), so P is computed once per level-1 anchor and gathered per edge (|A| < 2^48);
    * the geometry terms depend only on the offset dp = q_j - p_i, so for small radii they are
      tabulated once for every dp in [-R, R]^3 (every partial sum of P(y_j) + G(dp_ij) - P(x_i)
      is a partial sum of the accumulator's terms, so it is exact too);
    * the head MLP's first layer is linear in its input as well, and its M parent-attribute
      inputs are a level-1 anchor's vector: bias + W_head[:, Ch+4:] x is computed once per
      level-1 anchor and gathered per row as the GEMM's addend (|.| < 2^47, exact);
    * edges are laid out densely [block, K]; invalid slots use j = 0 with dp = 0 and are masked
      to zero before the aggregation (sum of at most 64 products |w e| <= 2^30: exact).
    """

    def __init__(self, params: GGConvParams, coords2, parent, coords1, attrs1, voxel_scale: int,
                 neighbours: tuple[np.ndarray, np.ndarray] | None = None):
        c, par, c1, x1 = check_level2_inputs(params.num_attrs, coords2, parent, coords1, attrs1, voxel_scale)
        self.params, self.num_rows, self.voxel_scale, self.coords = params, c.shape[0], int(voxel_scale), c
        if self.num_rows == 0:
            return
        self.level1_data = params.neighbour_level == 1  # neighbours are level-1 anchors (else level-2 ones)
        n_data = c1.shape[0] if self.level1_data else self.num_rows
        if neighbours is None:
            nbr, valid = level2_graph(params, c, c1)
        else:
            nbr, valid = (np.asarray(a) for a in neighbours)
            if nbr.shape != (self.num_rows, params.k) or valid.shape != (self.num_rows, params.k):
                raise ValueError(f"neighbours must be two [N2, {params.k}] arrays")
            if valid.any() and (int(nbr[valid].min()) < 0 or int(nbr[valid].max()) >= n_data):
                raise ValueError("neighbour index out of range")
        ch = params.context_channels
        self.coords_t = torch.from_numpy(np.ascontiguousarray(c))
        self.parent_t = torch.from_numpy(np.ascontiguousarray(par))
        self.valid_t = torch.from_numpy(np.ascontiguousarray(valid, dtype=bool))
        self.nbr_t = torch.where(self.valid_t, torch.from_numpy(np.ascontiguousarray(nbr, dtype=np.int64)), 0)
        self.n_valid = self.valid_t.sum(1).to(torch.float64)
        self.data_coords = torch.from_numpy(np.ascontiguousarray(c1)) if self.level1_data else self.coords_t
        self.x1f = clamp16(torch.from_numpy(np.ascontiguousarray(x1))).to(torch.float64)  # [N1, M] activations
        self.table_f = torch.from_numpy(params.table.reshape(-1, ch).astype(np.float64))
        # the first layer's scaled weights and bias (common/intnn.py): every term below is an integer
        # multiple of 2^-shift of magnitude < 2^(48-shift), exact in float64
        feat0 = params.feat_mlp.layers[0]
        w0 = feat0._ws  # [C + 3, H]
        cf = params.num_features
        self.lin0_u, self.lin0_b = w0[cf:].contiguous(), feat0._bs
        self.p1 = self.x1f[:, :cf] @ w0[:cf].contiguous()  # [N1, H]: W[:, :C] x 2^-shift of each level-1 vector
        head0 = params.head_mlp.layers[0]
        self.head0_z = head0._ws[:ch + 4].contiguous()  # the weights of [h, local position, n_valid]
        self.q1 = torch.addmm(head0._bs, self.x1f, head0._ws[ch + 4:].contiguous())  # [N1, Hh]: bias + W x
        self.local = torch.from_numpy(local_position(c, self.voxel_scale)).clamp_(0, ACT_MAX).to(torch.float64)
        self.w_scale = 2.0 ** -params.h_shift  # folded into the geometry weights: sum_j (w 2^-hs) e is exact
        r = params.radius
        self.side = 2 * r + 1
        self.use_lut = self.side ** 3 <= min(_LUT_MAX, max(1 << 10, 2 * self.num_rows * params.k))
        if self.use_lut:  # geometry terms of every offset in [-R, R]^3, and a last row for invalid slots
            ax = torch.arange(-r, r + 1, dtype=torch.int64)
            grid_dp = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
            self.lut_lin, lut_w = _geometry_terms(grid_dp, params, self.table_f, self.lin0_u, self.lin0_b)
            self.lut_w = torch.cat([lut_w.mul_(self.w_scale), torch.zeros((1, ch), dtype=torch.float64)])
            self.invalid_code = self.side ** 3

    def rows(self, lo: int, hi: int, block: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean int32, level int8, step_adjust int8), each [hi - lo, M], for level-2 rows lo..hi-1,
        evaluated ``block`` rows at a time (default ``block_rows()``; the result does not depend on it)."""
        block = block or block_rows()
        params = self.params
        m, k, ch, r = params.num_attrs, params.k, params.context_channels, params.radius
        count = max(0, hi - lo)
        mean = np.empty((count, m), dtype=np.int32)
        level = np.empty((count, m), dtype=np.int8)
        adj = np.empty((count, m), dtype=np.int8)
        if count == 0:
            return mean, level, adj
        if not 0 <= lo <= hi <= self.num_rows:
            raise ValueError(f"rows {lo}..{hi} outside the {self.num_rows} level-2 rows")
        feat0, feat_rest = params.feat_mlp.layers[0], params.feat_mlp.layers[1:]
        head0, head_rest = params.head_mlp.layers[0], params.head_mlp.layers[1:]
        hdim = feat0.fan_out
        outs = [torch.from_numpy(a) for a in (mean, level, adj)]
        for b_lo in range(lo, hi, block):
            b_hi = min(hi, b_lo + block)
            nb = b_hi - b_lo
            j = self.nbr_t[b_lo:b_hi].reshape(-1)  # [nb K]
            v = self.valid_t[b_lo:b_hi].reshape(-1)
            dp = (self.data_coords.index_select(0, j).view(nb, k, 3) - self.coords_t[b_lo:b_hi, None, :]).view(-1, 3)
            dp.mul_(v[:, None])  # invalid slots: dp = 0 (their terms are masked below)
            pi = self.parent_t[b_lo:b_hi]
            if self.use_lut:
                code = ((dp[:, 0] + r) * self.side + (dp[:, 1] + r)) * self.side + (dp[:, 2] + r)
                g_lin = self.lut_lin.index_select(0, code)
                g_w = self.lut_w.index_select(0, torch.where(v, code, self.invalid_code))
            else:
                g_lin, g_w = _geometry_terms(dp, params, self.table_f, self.lin0_u, self.lin0_b)
                g_w.mul_((v.to(torch.float64) * self.w_scale)[:, None])
            y_rows = j if self.level1_data else self.parent_t.index_select(0, j)  # level-1 row of each y_j
            acc = g_lin.add_(self.p1.index_select(0, y_rows)).view(nb, k, hdim)
            acc.sub_(self.p1.index_select(0, pi)[:, None, :])
            e = feat0.finish_f64(acc.view(-1, hdim))
            for layer in feat_rest:
                e = layer.forward_f64(e)
            hsum = g_w.mul_(e).view(nb, k, ch).sum(1)  # sum_j w e / 2^hs: |.| <= 64 2^30 / 2^hs, exact
            if params.h_shift:
                hsum.add_(0.5)
            h = hsum.floor_().clamp_(ACT_MIN, ACT_MAX)
            z = torch.cat([h, self.local[b_lo:b_hi], self.n_valid[b_lo:b_hi, None]], 1)
            o = head0.finish_f64(torch.addmm(self.q1.index_select(0, pi), z, self.head0_z))
            for layer in head_rest:
                o = layer.forward_f64(o)
            xf = self.x1f.index_select(0, pi)  # [nb, M]: the parents' attributes x_i
            out = slice(b_lo - lo, b_hi - lo)
            for dst, val in zip(outs, split_outputs(o, xf, params.base, m)):
                dst[out] = val
        return mean, level, adj
