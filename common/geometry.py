"""Lossless geometry coding of anchor positions: the geometry data unit payload (normative).

The payload is a small header (``GeometryHeader``, spec/geometry.md clause G.2), byte
alignment, then one range-coded stream (``lghcc.common.entropy.range_coder``) holding an
octree of the anchor coordinates relative to their bounding-box minimum:

* depth by depth, nodes in Morton order;
* at each depth, first the direct-coding decisions (IDCM) of eligible isolated nodes and
  the raw low bits of their points, then the occupancy of the remaining nodes, coded as
  up to 8 binary decisions in 8 vectorized passes (child 0 .. 7);
* every binary decision has a context computed from data the decoder already has
  (face neighbours at the node's depth, already-coded sibling bits, already-coded
  children of neighbouring nodes); the symbols of one pass are grouped by context and
  each group is coded with one exact frequency table derived, in integer arithmetic, from
  the counts of every symbol coded before in that context. Nothing about the
  probabilities is transmitted.

Encoder and decoder share the coding of every decision (``_SymbolIO`` writes or reads a
binary decision with the same contexts and count updates; ``_code_occupancy``, the IDCM
eligibility and context, and the node state of the next depth are one function each, used
by both), so they cannot drift apart.

The normative anchor order is Morton (z-order) of the coordinates relative to their
bounding-box minimum, x the most significant of each bit triple (``normative_order``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bitio import BitReader, BitWriter
from .entropy.range_coder import TOTAL_FREQUENCY, RangeDecoder, RangeEncoder, binary_weights
from .errors import BitstreamError
from .syntax import SyntaxStructure, SyntaxVisitor

COORD_MIN = -(1 << 31)
COORD_MAX = (1 << 31) - 1
MAX_BIT_DEPTH = 32

# geom_idcm_mode values (eligibility rules for direct coding, spec G.5.2)
IDCM_OFF = 0
IDCM_ISOLATED = 1  # only child, parent without face neighbours, parent with <= 2 siblings+1
IDCM_NO_NEIGHBOURS = 2  # parent without face neighbours
MAX_IDCM_MODE = 2
MIN_IDCM_LEVELS = 2  # a node is eligible only when at least this many levels remain below it

# Probability adaptation (spec G.6)
COUNT_LIMIT = 1 << 10  # a context whose n0 + n1 exceeds this has both counts halved (rounded up)
LEVEL_COUNT_LIMIT = 1 << 6  # the same, applied to the occupancy counts at the start of every depth
CHUNK_LOG2 = 8  # decisions of one pass are coded in chunks 0..2^8, 2^8..2^9, 2^9..2^10, ...

# Occupancy context layout (spec G.5.4): per pass k, ctx = ((axes * 4) + sib) * 4 + dens
NUM_AXES_STATES = 27
NUM_OCC_CONTEXTS = NUM_AXES_STATES * 4 * 4
DENS_BUCKET = np.array([0, 1, 1, 2, 2, 3, 3], dtype=np.int64)  # by number of occupied face neighbours
POPCOUNT8 = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)
NUM_IDCM_FLAG_CONTEXTS = 9

_MORTON_BITS = 21  # one 64-bit Morton key holds 21 bits per axis


@dataclass
class GeometryHeader(SyntaxStructure):
    """geometry_header: bounding-box minimum, bit depth per axis, direct-coding mode."""

    syntax_name = "geometry_header"
    clause = "7.3.4"
    geom_bbox_min_sign_flag: list = field(default_factory=lambda: [0, 0, 0])
    geom_bbox_min_abs: list = field(default_factory=lambda: [0, 0, 0])
    geom_bit_depth: list = field(default_factory=lambda: [0, 0, 0])
    geom_idcm_mode: int = IDCM_ISOLATED

    def syntax(self, v: SyntaxVisitor) -> None:
        for i in v.loop(3, "3", self, ("geom_bbox_min_sign_flag", "geom_bbox_min_abs", "geom_bit_depth")):
            v.flag(self, "geom_bbox_min_sign_flag", i)
            v.ue(self, "geom_bbox_min_abs", i, hi=1 << 31)
            v.u(6, self, "geom_bit_depth", i, hi=MAX_BIT_DEPTH)
        v.ue(self, "geom_idcm_mode", hi=MAX_IDCM_MODE)

    # derived values (spec G.3)
    @property
    def bbox_min(self) -> list[int]:
        return [-a if s else a for s, a in zip(self.geom_bbox_min_sign_flag, self.geom_bbox_min_abs)]

    @classmethod
    def for_min(cls, bbox_min, bit_depth, idcm_mode: int) -> "GeometryHeader":
        m = [int(x) for x in bbox_min]
        return cls(geom_bbox_min_sign_flag=[int(x < 0) for x in m], geom_bbox_min_abs=[abs(x) for x in m],
                   geom_bit_depth=[int(d) for d in bit_depth], geom_idcm_mode=int(idcm_mode))


# --- Morton order -----------------------------------------------------------------------------

def _spread3(v: np.ndarray) -> np.ndarray:
    """Spread the low 21 bits of v (uint64) so that bit i moves to bit 3i."""
    x = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


def _morton21(q: np.ndarray) -> np.ndarray:
    """Morton keys of non-negative coordinates < 2^21, x most significant."""
    return (_spread3(q[:, 0]) << np.uint64(2)) | (_spread3(q[:, 1]) << np.uint64(1)) | _spread3(q[:, 2])


def _morton_perm(offsets: np.ndarray, depth: int) -> np.ndarray:
    """Stable permutation sorting non-negative offsets (< 2^depth) into Morton order."""
    if depth <= _MORTON_BITS:
        return np.argsort(_morton21(offsets), kind="stable")
    lo = _morton21(offsets & ((1 << _MORTON_BITS) - 1))
    hi = _morton21(offsets >> _MORTON_BITS)
    return np.lexsort((lo, hi))


def _check_coords(coords) -> np.ndarray:
    c = np.asarray(coords)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"coordinates must have shape [N, 3], not {list(c.shape)}")
    if c.shape[0] < 1:
        raise ValueError("at least one anchor is needed")
    if not np.issubdtype(c.dtype, np.integer):
        raise ValueError(f"coordinates must be integers, not {c.dtype}")
    c = c.astype(np.int64)
    lo, hi = int(c.min()), int(c.max())
    if lo < COORD_MIN or hi > COORD_MAX:
        raise ValueError(f"coordinates must lie in [-2^31, 2^31), found [{lo}, {hi}]")
    return c


def _bit_depths(offsets: np.ndarray) -> list[int]:
    return [int(offsets[:, a].max()).bit_length() for a in range(3)]


def normative_order(coords: np.ndarray) -> np.ndarray:
    """coords int64 [N,3] (unique). The permutation (int64 [N]) that puts anchors in the normative
    order: Morton order of coords - min(coords) (per axis), x most significant; stable."""
    c = _check_coords(coords)
    off = c - c.min(axis=0)
    return _morton_perm(off, max(_bit_depths(off))).astype(np.int64)


# --- adaptive binary coding -------------------------------------------------------------------

def binary_frequency(counts: np.ndarray) -> np.ndarray:
    """Frequency (of 2^24) of symbol 1 from counts [..., 2] = (n0, n1): the integer KT estimate
    floor((2*n1 + 1) * 2^24 / (2*(n0 + n1) + 2)), clipped to [1, 2^24 - 1] (spec G.6)."""
    n0 = counts[..., 0].astype(np.int64, copy=False)
    n1 = counts[..., 1].astype(np.int64, copy=False)
    f1 = ((2 * n1 + 1) * TOTAL_FREQUENCY) // (2 * (n0 + n1) + 2)
    return np.minimum(np.maximum(f1, 1), TOTAL_FREQUENCY - 1)  # the clip, without np.clip's overhead


def chunk_bounds(n: int) -> list[int]:
    """Chunk boundaries of n decisions: 0, 2^c, 2^(c+1), ... (c = CHUNK_LOG2), then n."""
    b = [0]
    if n == 0:
        return b
    size = 1 << CHUNK_LOG2
    while size < n:
        b.append(size)
        size *= 2
    b.append(n)
    return b


def limit_counts(table: np.ndarray, limit: int) -> None:
    """Halve (rounding up) both counts of every context whose n0 + n1 exceeds limit, repeatedly."""
    while True:
        big = table[:, 0] + table[:, 1] > limit  # n0 + n1 (called per chunk: no reduction)
        if not np.logical_or.reduce(big):
            return
        table[big] = (table[big] + 1) >> 1


class _SymbolIO:
    """Writes or reads binary decisions grouped by context; one class for both directions."""

    def __init__(self, encoder: RangeEncoder | None = None, decoder: RangeDecoder | None = None):
        self.enc = encoder
        self.dec = decoder

    @property
    def encoding(self) -> bool:
        return self.enc is not None

    def binary(self, ctx: np.ndarray, table: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """Code one binary decision per entry of ctx with the adaptive table (counts [C, 2]).
        The decisions are cut into chunks (``chunk_bounds``); within a chunk they are grouped by
        context, in increasing context order, each group in its original order, and coded with
        the table's frequencies; then the chunk's decisions are added to the counts."""
        n = int(ctx.size)
        out = np.empty(n, dtype=np.int64)
        bounds = chunk_bounds(n)
        for c0, c1 in zip(bounds[:-1], bounds[1:]):
            out[c0:c1] = self._binary_chunk(ctx[c0:c1], table, None if values is None else values[c0:c1])
        return out

    def _binary_chunk(self, ctx: np.ndarray, table: np.ndarray, values: np.ndarray | None) -> np.ndarray:
        n = int(ctx.size)
        # a stable sort groups the decisions by context, each group in its original order (radix
        # sort on 16-bit keys: every context table here is far smaller than 2^16)
        order = np.argsort(ctx.astype(np.uint16) if table.shape[0] <= 1 << 16 else ctx, kind="stable")
        # each decision with its context's model: the models of the table's contexts, gathered
        # (clipped: in range; np.take gathers rows many times faster than fancy indexing)
        models = np.take(binary_weights(binary_frequency(table), check=False), ctx[order], axis=0)
        if self.enc is not None:  # encoding: the values are given
            assert values is not None
            values = values.astype(np.int64, copy=False)
            self.enc.encode_binary_models(values[order], models)
        else:
            assert self.dec is not None
            values = np.empty(n, dtype=np.int64)
            values[order] = self.dec.decode_binary_models(models)
        table += np.bincount(ctx.astype(np.int64, copy=False) * 2 + values, minlength=table.size).reshape(table.shape)
        limit_counts(table, COUNT_LIMIT)
        return values

    def raw(self, nbits: int, values: np.ndarray | None = None, count: int = 0) -> np.ndarray:
        if nbits == 0:
            return np.zeros(count if values is None else values.size, dtype=np.int64)
        if self.enc is not None:  # encoding: the values are given
            assert values is not None
            self.enc.encode_bits(values.astype(np.uint64), nbits)
            return values
        assert self.dec is not None
        return self.dec.decode_bits(nbits, count).astype(np.int64)


# --- neighbours -------------------------------------------------------------------------------

_SPREAD_MASK = np.uint64(0x1249249249249249)  # bits 0, 3, ..., 60: one axis of a Morton key
_AXIS_MASKS = [_SPREAD_MASK << np.uint64(2 - a) for a in range(3)]  # x, y, z (x most significant)


def _morton_step(keys: np.ndarray, a: int, delta: int) -> np.ndarray:
    """Morton keys of the nodes one step (delta = -1 or +1) along axis a from ``keys``, by dilated
    integer arithmetic on the axis' bits (the other axes' bits are kept); the caller keeps only
    nodes whose neighbour is inside the grid, so no carry or borrow leaves the axis' bits."""
    mask = _AXIS_MASKS[a]
    rest = keys & ~mask
    if delta > 0:
        moved = ((keys | ~mask) + np.uint64(1)) & mask
    else:
        moved = ((keys & mask) - np.uint64(1)) & mask
    return moved | rest


def _face_neighbours(q: np.ndarray, depth: int) -> np.ndarray:
    """Index of the node at q -/+ e_a among the nodes q (Morton order, unique), or -1.
    Returns int64 [6, M] for the directions -x, +x, -y, +y, -z, +z."""
    m = q.shape[0]
    out = np.full((6, m), -1, dtype=np.int64)
    if m == 0:
        return out
    size = 1 << depth
    if depth <= _MORTON_BITS:
        keys = _morton21(q)  # ascending: the nodes are in Morton order
        perm = None
    else:
        raw = np.ascontiguousarray(q.astype(">u4")).view("S12").ravel()
        perm = np.argsort(raw, kind="stable")
        keys = raw[perm]
    for a in range(3):
        for side, delta in ((0, -1), (1, 1)):
            nq = q[:, a] + delta
            ok = (nq >= 0) & (nq < size)
            if not ok.any():
                continue
            idx = np.flatnonzero(ok)
            if perm is None:
                kq = _morton_step(keys[idx], a, delta)
            else:
                qq = q[idx].copy()
                qq[:, a] = nq[idx]
                kq = np.ascontiguousarray(qq.astype(">u4")).view("S12").ravel()
            pos = np.searchsorted(keys, kq)
            pos_c = np.minimum(pos, m - 1)
            hit = (pos < m) & (keys[pos_c] == kq)
            found = pos_c[hit] if perm is None else perm[pos_c[hit]]
            out[2 * a + side, idx[hit]] = found
    return out


# --- the octree (shared by encoder and decoder) ----------------------------------------------

AXIS_BIT = (4, 2, 1)  # bit of the child index that carries axis a (x, y, z)


class _ContextState:
    """Adaptive counts, identical at encoder and decoder."""

    def __init__(self) -> None:
        self.occ = np.zeros((8, NUM_OCC_CONTEXTS, 2), dtype=np.int64)
        self.idcm_flag = np.zeros((NUM_IDCM_FLAG_CONTEXTS, 2), dtype=np.int64)
        self.idcm_two = np.zeros((1, 2), dtype=np.int64)


def _idcm_eligible(mode: int, remaining: int, sib1: np.ndarray, par_nbr: np.ndarray,
                   par_sib1: np.ndarray) -> np.ndarray:
    if mode == IDCM_OFF or remaining < MIN_IDCM_LEVELS:
        return np.zeros(sib1.shape, dtype=bool)
    if mode == IDCM_ISOLATED:
        return (sib1 == 1) & (par_nbr == 0) & (par_sib1 <= 2)
    return par_nbr == 0


def _code_occupancy(io: _SymbolIO, st: _ContextState, q: np.ndarray, depth: int, remaining: int,
                    bit_depth: list[int], occ_true: np.ndarray | None,
                    nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Code the occupancy bytes of the nodes q at ``depth`` (children at depth + 1); ``nb``: their
    face neighbours (``_NodeState.nb``, carried from the parents; ``_face_neighbours`` defines them).
    Returns (occupancy uint8-valued int64 [M], number of occupied face neighbours [M])."""
    m = q.shape[0]
    for k in range(8):
        limit_counts(st.occ[k], LEVEL_COUNT_LIMIT)
    exists = (nb >= 0).astype(np.int64)
    nbr_count = exists.sum(axis=0)
    dens = DENS_BUCKET[nbr_count]
    occ = np.zeros(m, dtype=np.int64) if occ_true is None else occ_true
    splits = [remaining - 1 < d for d in bit_depth]  # axis a splits at this depth
    valid = [k for k in range(8) if all(splits[a] or not (k & AXIS_BIT[a]) for a in range(3))]
    last = valid[-1]
    # index -1 (no neighbour) reads an empty node: occ with a 0 appended, once when encoding (occ is known
    # whole), per child when decoding (the children decoded so far)
    padded_whole = None if occ_true is None else np.append(occ, 0)
    for k in valid:
        padded = padded_whole if padded_whole is not None else np.append(occ, 0)
        axes = np.zeros(m, dtype=np.int64)
        for a in range(3):
            bit = AXIS_BIT[a]
            if k & bit:
                j = k ^ bit
                s = (occ >> j) & 1
                o = (padded[nb[2 * a + 1]] >> j) & 1
                axes = axes * 3 + s + o
            else:
                axes = axes * 3 + exists[2 * a]
        before = POPCOUNT8[occ & ((1 << k) - 1)]
        ctx = ((axes * 4 + np.minimum(before, 3)) * 4 + dens)
        if k == last:
            coded = np.flatnonzero(before > 0)
            inferred = np.flatnonzero(before == 0)
        else:
            coded = None
            inferred = None
        if coded is None:
            vals = io.binary(ctx, st.occ[k], None if occ_true is None else (occ_true >> k) & 1)
            if occ_true is None:
                occ |= vals << k
        else:
            vals = io.binary(ctx[coded], st.occ[k], None if occ_true is None else (occ_true[coded] >> k) & 1)
            if occ_true is None:
                occ[coded] |= vals << k
                occ[inferred] |= 1 << k
    return occ, nbr_count


def _children(q: np.ndarray, occ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Children of the nodes q with occupancy occ, in Morton order: (coords [M', 3], parent index)."""
    bits = np.unpackbits(occ.astype(np.uint8)[:, None], axis=1, bitorder="little")
    parent, k = np.nonzero(bits)
    child = 2 * q[parent] + np.stack([(k >> 2) & 1, (k >> 1) & 1, k & 1], axis=1)
    return child, parent


def _validate_header(h: GeometryHeader, num_points: int) -> None:
    for a in range(3):
        if h.geom_bbox_min_sign_flag[a] == 0 and h.geom_bbox_min_abs[a] > COORD_MAX:
            raise BitstreamError(f"geometry_header.geom_bbox_min_abs[{a}] = {h.geom_bbox_min_abs[a]} "
                                 f"puts the bounding-box minimum outside [-2^31, 2^31)", condition="E26")
    total_bits = sum(h.geom_bit_depth)
    if num_points > (1 << total_bits):
        raise BitstreamError(f"{num_points} points cannot be distinct in a bounding box of "
                             f"{h.geom_bit_depth} bits per axis", condition="E27")


# NTH_BIT[b, r]: the index of the r-th set bit of the byte b (0 where b has fewer)
NTH_BIT = np.zeros((256, 8), dtype=np.int64)
for _b in range(256):
    _set = [j for j in range(8) if _b >> j & 1]
    NTH_BIT[_b, :len(_set)] = _set


def _child_neighbours(nb: np.ndarray, occ: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """The face neighbours (as ``_face_neighbours``, [6, M']) of the children of nodes with face
    neighbours ``nb`` [6, M] and occupancy ``occ``, the children in Morton order (``parent``: each
    one's parent), from the parents' (informative: the same answer without a search). Along axis
    a a child's neighbour is its sibling with child index k ^ bit_a when that lies toward the
    neighbour, else the child k ^ bit_a of the parent's neighbour on that side; it exists where
    that node's occupancy has bit k ^ bit_a."""
    count = POPCOUNT8[occ]
    first = np.cumsum(count) - count  # index of each node's first child
    k = NTH_BIT[occ[parent], np.arange(parent.size) - first[parent]]
    occ_p, first_p = np.append(occ, 0), np.append(first, -1)  # index -1 (no node): nothing occupied
    out = np.empty((6, parent.size), dtype=np.int64)
    for a in range(3):
        upper = (k & AXIS_BIT[a]) != 0  # the child is on its parent's + side along a
        j = k ^ AXIS_BIT[a]
        for side, sibling in ((0, upper), (1, ~upper)):
            owner = np.where(sibling, parent, nb[2 * a + side][parent])
            o = occ_p[owner]
            out[2 * a + side] = np.where(((o >> j) & 1) == 1, first_p[owner] + POPCOUNT8[o & ((1 << j) - 1)], -1)
    return out


def _kept_neighbours(nb: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Face neighbours among the nodes ``keep`` (bool [M]) from those among all M nodes."""
    new = np.append(np.where(keep, np.cumsum(keep) - 1, -1), -1)  # index -1 (no node) stays -1
    return new[nb[:, keep]]


@dataclass
class _NodeState:
    """Per node of the current depth (G.5.1): sib1 (occupied children of its parent), par_nbr
    (occupied face neighbours of its parent), par_sib1 (the parent's sib1); and nb, the index of
    each face neighbour among the nodes, or -1 ([6, M], ``_face_neighbours``'s order)."""

    sib1: np.ndarray
    par_nbr: np.ndarray
    par_sib1: np.ndarray
    nb: np.ndarray

    @classmethod
    def root(cls) -> "_NodeState":
        """The one node of depth 0: sib1 = 1, par_nbr = 0, par_sib1 = 1, no neighbours."""
        return cls(np.ones(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.int64),
                   np.full((6, 1), -1, dtype=np.int64))

    def idcm_eligible(self, mode: int, remaining: int) -> np.ndarray:
        """Indices of the nodes eligible for direct coding (G.5.2)."""
        return np.flatnonzero(_idcm_eligible(mode, remaining, self.sib1, self.par_nbr, self.par_sib1))

    def idcm_flag_context(self, nodes: np.ndarray) -> np.ndarray:
        return _idcm_flag_context(self.sib1[nodes], self.par_sib1[nodes])

    def without(self, keep: np.ndarray) -> "_NodeState":
        """The nodes that are not direct (``keep``); only sib1 is read again at this depth."""
        return _NodeState(self.sib1[keep], self.par_nbr, self.par_sib1, _kept_neighbours(self.nb, keep))

    def children(self, occ: np.ndarray, nbr_count: np.ndarray, parent: np.ndarray) -> "_NodeState":
        """The state of the nodes of depth l + 1, children of the nodes ``parent`` (G.5.4 step 5)."""
        return _NodeState(POPCOUNT8[occ][parent], nbr_count[parent], self.sib1[parent],
                          _child_neighbours(self.nb, occ, parent))


def _idcm_flag_context(sib1: np.ndarray, par_sib1: np.ndarray) -> np.ndarray:
    """Context of idcm_flag (G.5.2 step 1): min(sib1 - 1, 2) * 3 + min(par_sib1 - 1, 2)."""
    return np.minimum(sib1 - 1, 2) * 3 + np.minimum(par_sib1 - 1, 2)


# --- encoding (the same decisions, written) ---------------------------------------------------

def encode_geometry(coords: np.ndarray, idcm_mode: int = IDCM_ISOLATED) -> bytes:
    """coords int64 [N,3], unique, N>=1, each coordinate in [-2**31, 2**31). Returns the geometry
    unit payload: geometry_header, byte alignment, range-coded octree data."""
    c = _check_coords(coords)
    if idcm_mode not in (IDCM_OFF, IDCM_ISOLATED, IDCM_NO_NEIGHBOURS):
        raise ValueError(f"idcm_mode={idcm_mode} is not one of 0, 1, 2")
    bmin = c.min(axis=0)
    off = c - bmin
    bit_depth = _bit_depths(off)
    pts = off[_morton_perm(off, max(bit_depth))]
    if pts.shape[0] > 1 and not np.any(pts[1:] != pts[:-1], axis=1).all():
        raise ValueError("coordinates must be unique")
    header = GeometryHeader.for_min(bmin.tolist(), bit_depth, idcm_mode)
    w = BitWriter()
    header.write_to(w)
    w.byte_align()
    enc = RangeEncoder()
    _encode_octree(_SymbolIO(encoder=enc), pts, bit_depth, idcm_mode)
    return w.getvalue() + enc.to_bytes()


def _nodes_of_points(pts: np.ndarray, remaining: int) -> tuple[np.ndarray, np.ndarray]:
    """The nodes holding the points (Morton order): coordinates of each point's node, and the
    index of the first point of every node (the points of a node are contiguous)."""
    q_all = pts >> remaining
    new = np.ones(pts.shape[0], dtype=bool)
    new[1:] = np.any(q_all[1:] != q_all[:-1], axis=1)
    return q_all, np.flatnonzero(new)


def _encode_octree(io: _SymbolIO, pts: np.ndarray, bit_depth: list[int], idcm_mode: int) -> None:
    """Code the offsets ``pts`` (Morton order, unique) depth by depth (G.5, G.7)."""
    st = _ContextState()
    nodes = _NodeState.root()
    dmax = max(bit_depth)
    for depth in range(dmax):
        remaining = dmax - depth
        q_all, starts = _nodes_of_points(pts, remaining)
        q = q_all[starts]
        elig = nodes.idcm_eligible(idcm_mode, remaining)
        if elig.size:
            keep_nodes = _encode_direct_nodes(io, st, pts, starts, elig, nodes, remaining, bit_depth)
            pts = pts[np.repeat(keep_nodes, np.diff(np.append(starts, pts.shape[0])))]
            q, nodes = q[keep_nodes], nodes.without(keep_nodes)
            if pts.shape[0] == 0:
                break
            q_all, starts = _nodes_of_points(pts, remaining)
        ci = (((pts[:, 0] >> (remaining - 1)) & 1) << 2) | (((pts[:, 1] >> (remaining - 1)) & 1) << 1) \
            | ((pts[:, 2] >> (remaining - 1)) & 1)
        occ = np.bitwise_or.reduceat(np.left_shift(1, ci), starts)
        occ, nbr_count = _code_occupancy(io, st, q, depth, remaining, bit_depth, occ, nodes.nb)
        _, parent = _children(q, occ)
        nodes = nodes.children(occ, nbr_count, parent)


def _encode_direct_nodes(io: _SymbolIO, st: _ContextState, pts: np.ndarray, starts: np.ndarray,
                         elig: np.ndarray, nodes: _NodeState, remaining: int, bit_depth: list[int]) -> np.ndarray:
    """Direct coding (G.5.2) of the eligible nodes that hold one or two points: idcm_flag,
    idcm_two_points and the low bits of their points. Returns which nodes are not direct."""
    npts = np.diff(np.append(starts, pts.shape[0]))
    flag = (npts[elig] <= 2).astype(np.int64)
    io.binary(nodes.idcm_flag_context(elig), st.idcm_flag, flag)
    direct = elig[flag == 1]
    two = (npts[direct] == 2).astype(np.int64)
    io.binary(np.zeros(direct.size, dtype=np.int64), st.idcm_two, two)
    first = starts[direct]
    sel = np.concatenate([first, first[two == 1] + 1])
    sel.sort()
    for a in range(3):
        nb_a = min(remaining, bit_depth[a])
        io.raw(nb_a, pts[sel, a] & ((1 << nb_a) - 1))
    keep_nodes = np.ones(starts.size, dtype=bool)
    keep_nodes[direct] = False
    return keep_nodes


# --- decoding (G.5) ---------------------------------------------------------------------------

def decode_geometry(payload: bytes, num_points: int, trace: list | None = None) -> np.ndarray:
    """Decode the geometry payload of ``num_points`` points (anchors or Gaussians). Returns int64 [N,3]
    coordinates in normative order. Raises BitstreamError on any malformed payload."""
    n = int(num_points)
    if n < 1:
        raise BitstreamError(f"N = {n}: the geometry of at least one point is needed", condition="E19")
    header, data = _read_geometry_header(payload, n, trace)
    dec = RangeDecoder(data, "geometry data")
    pts = _decode_octree(_SymbolIO(decoder=dec), list(header.geom_bit_depth), header.geom_idcm_mode, n)
    dec.check_exhausted()
    return _output_points(pts, header, n)


def _read_geometry_header(payload: bytes, n: int, trace: list | None) -> tuple[GeometryHeader, bytes]:
    """geometry_header (G.2), checked (G.3), and the coded data after the byte alignment."""
    reader = BitReader(payload, "geometry payload")
    header = GeometryHeader.parse(reader, trace)
    reader.byte_align()
    _validate_header(header, n)
    data = bytes(payload[reader.bit_position // 8:])
    if max(header.geom_bit_depth) == 0 and data:
        raise BitstreamError(f"geometry payload: {len(data)} bytes of coded data after a header of bit depth 0", condition="E28")
    return header, data


def _decode_octree(io: _SymbolIO, bit_depth: list[int], mode: int, n: int) -> np.ndarray:
    """The offsets of the anchors (G.5.1 to G.5.4): the directly decoded points, then the leaves."""
    st = _ContextState()
    dmax = max(bit_depth)
    q = np.zeros((1, 3), dtype=np.int64)
    nodes = _NodeState.root()
    direct_pts: list[np.ndarray] = []
    num_direct = 0
    for depth in range(dmax):
        remaining = dmax - depth
        elig = nodes.idcm_eligible(mode, remaining)
        if elig.size:
            p, keep = _decode_direct_nodes(io, st, q, elig, nodes, remaining, bit_depth, n, num_direct, depth)
            direct_pts.append(p)
            num_direct += p.shape[0]
            q, nodes = q[keep], nodes.without(keep)
            if q.shape[0] == 0:
                break
        occ, nbr_count = _code_occupancy(io, st, q, depth, remaining, bit_depth, None, nodes.nb)
        num_children = int(POPCOUNT8[occ].sum())
        if num_direct + num_children > n:
            raise BitstreamError(f"geometry data: {num_direct + num_children} points at depth {depth + 1}, "
                                 f"more than N = {n}", condition="E31")
        q, parent = _children(q, occ)
        nodes = nodes.children(occ, nbr_count, parent)
    return np.concatenate(direct_pts + [q]) if (dmax == 0 or q.shape[0]) else np.concatenate(direct_pts)


def _decode_direct_nodes(io: _SymbolIO, st: _ContextState, q: np.ndarray, elig: np.ndarray, nodes: _NodeState,
                         remaining: int, bit_depth: list[int], n: int, num_direct: int, depth: int
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Direct coding (G.5.2) of the eligible nodes, ``num_direct`` points having been decoded
    directly before. Returns the points of the direct nodes and which nodes are not direct."""
    flag = io.binary(nodes.idcm_flag_context(elig), st.idcm_flag)
    direct = elig[flag == 1]
    two = io.binary(np.zeros(direct.size, dtype=np.int64), st.idcm_two)
    owner = np.sort(np.concatenate([direct, direct[two == 1]]))
    if num_direct + owner.size + (q.shape[0] - direct.size) > n:
        raise BitstreamError(f"geometry data: more than N = {n} points at depth {depth}", condition="E29")
    low = np.stack([io.raw(min(remaining, bit_depth[a]), count=owner.size) for a in range(3)], axis=1)
    p = (q[owner] << remaining) | low
    if owner.size > 1:
        same = (owner[1:] == owner[:-1]) & np.all(p[1:] == p[:-1], axis=1)
        if same.any():
            raise BitstreamError(f"geometry data: a directly coded node at depth {depth} holds "
                                 f"the same point twice", condition="E30")
    keep = np.ones(q.shape[0], dtype=bool)
    keep[direct] = False
    return p, keep


def _output_points(pts: np.ndarray, header: GeometryHeader, n: int) -> np.ndarray:
    """G.5.5: exactly N points attaining the bounding-box minimum, as coordinates in normative order."""
    if pts.shape[0] != n:
        raise BitstreamError(f"geometry data holds {pts.shape[0]} points, N = {n}", condition="E32")
    bmin = np.array(header.bbox_min, dtype=np.int64)
    if np.any(pts.min(axis=0) != 0):
        raise BitstreamError("geometry data: the decoded points do not attain the bounding-box minimum", condition="E33")
    coords = pts + bmin
    if int(coords.max()) > COORD_MAX:
        raise BitstreamError("geometry data: decoded coordinates exceed 2^31 - 1", condition="E34")
    return coords[_morton_perm(pts, max(header.geom_bit_depth))]
