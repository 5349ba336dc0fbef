#!/usr/bin/env python
"""Geometry coding research (informative): where the bits of lossless geometry go, and what
context / adaptation changes would save, measured as ideal code lengths (sum of -log2 p of
every decision with the adaptive integer probabilities, + raw bits) of variants of the octree
coder of lghcc.common.geometry. Nothing here is normative; common/ is untouched.

The baseline variant reproduces common/geometry.py exactly (its ideal length is checked against
the real payload size: within a few bytes).
Usage: python tools/bench_geometry_contexts.py [--variants base ...] [--sets garden6 ...]
Its findings: tools/results/geometry_research.md (the table there is this command's output).
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_geometry as bg  # noqa: E402
from lghcc.common import geometry as G  # noqa: E402

T = G.TOTAL_FREQUENCY
LOG2T = np.log2(T)


# --- cost-measuring symbol coder ------------------------------------------------------------

class CostIO:
    """Same decision grouping/chunking as geometry._SymbolIO, but only adds up ideal code lengths.
    est = 'kt' (the normative estimate), 'seq' (counts updated after every decision: the bound of
    finer adaptation), or a backoff estimate when ``coarse`` contexts are given."""

    def __init__(self, chunk_log2: int = G.CHUNK_LOG2, seq: bool = False):
        self.bits = defaultdict(float)
        self.tag = "?"
        self.chunk_log2 = chunk_log2
        self.seq = seq

    shift = None  # (r_fast, r_slow): sequential two-speed integer estimator instead of counts
    states: dict = {}

    def _shift(self, ctx, table, values, coarse=None, ctable=None, n0=4):
        """Per decision: p1 (16-bit) of two estimators with warm-up p += (v*2^16 - p) // min(n+2, 2^r),
        averaged; the state lives beside ``table`` (one per table)."""
        key = id(table)
        if key not in self.states:
            size = table.shape[0]
            self.states[key] = ([32768] * size, [32768] * size, [0] * size)
        pf, ps, cnt = self.states[key]
        if coarse is not None:
            ckey = id(ctable)
            if ckey not in self.states:
                size = ctable.shape[0]
                self.states[ckey] = ([32768] * size, [32768] * size, [0] * size)
            cpf, cps, ccnt = self.states[ckey]
            coarse = coarse.tolist()
        rf, rs = self.shift
        df, ds = 1 << rf, 1 << rs
        total = 0.0
        lg = np.log2
        costs = []
        for i, (c, v) in enumerate(zip(ctx.tolist(), values.tolist())):
            if coarse is not None:
                cc = coarse[i]
                if cnt[c] == 0 and ccnt[cc] > 0:  # a new fine context starts from its coarse one
                    pf[c], ps[c], cnt[c] = cpf[cc], cps[cc], min(ccnt[cc], n0)
                t = v << 16
                cpf[cc] += (t - cpf[cc]) // min(ccnt[cc] + 2, 1 << rf)
                cps[cc] += (t - cps[cc]) // min(ccnt[cc] + 2, 1 << rs)
                ccnt[cc] += 1
            p = (pf[c] + ps[c]) >> 1
            p = min(max(p, 64), 65536 - 64)
            costs.append(p if v else 65536 - p)
            n = cnt[c]
            t = v << 16
            pf[c] += (t - pf[c]) // min(n + 2, df)
            ps[c] += (t - ps[c]) // min(n + 2, ds)
            cnt[c] = n + 1
        total = float(np.sum(16 - lg(np.array(costs, dtype=np.float64))))
        self.bits[self.tag] += total

    def bounds(self, n: int) -> list[int]:
        if self.seq:
            return list(range(0, n + 1, 1)) if n < 64 else None
        b, size = [0], 1 << self.chunk_log2
        if n == 0:
            return b
        while size < n:
            b.append(size)
            size *= 2
        b.append(n)
        return b

    def binary(self, ctx, table, values, coarse=None, ctable=None, K=None, limit=G.COUNT_LIMIT):
        ctx = np.asarray(ctx, dtype=np.int64)
        values = np.asarray(values, dtype=np.int64)
        n = ctx.size
        if n == 0:
            return values
        if self.shift is not None:
            self._shift(ctx, table, values, coarse, ctable, K or 4)
            return values
        b = self.bounds(n)
        if b is None:  # sequential updates: exact cumulative counts per context (no halving within)
            self._seq(ctx, table, values, coarse, ctable, K, limit)
            return values
        for c0, c1 in zip(b[:-1], b[1:]):
            f1 = self.freq(ctx[c0:c1], table, None if coarse is None else coarse[c0:c1], ctable, K)
            v = values[c0:c1]
            p = np.where(v == 1, f1, T - f1)
            self.bits[self.tag] += float(np.sum(LOG2T - np.log2(p)))
            np.add.at(table, (ctx[c0:c1], v), 1)
            G.limit_counts(table, limit)
            if coarse is not None:
                np.add.at(ctable, (coarse[c0:c1], v), 1)
                G.limit_counts(ctable, limit)
        return values

    def _seq(self, ctx, table, values, coarse, ctable, K, limit):
        # counts before each decision = table + number of earlier decisions of the same context
        def running(c, tab):
            order = np.argsort(c, kind="stable")
            sc, sv = c[order], values[order]
            start = np.flatnonzero(np.concatenate(([True], sc[1:] != sc[:-1])))
            grp = np.repeat(start, np.diff(np.append(start, sc.size)))
            c1 = np.cumsum(sv) - sv
            c1 = c1 - c1[grp]
            idx = np.arange(sc.size) - grp
            out = np.empty((c.size, 2), dtype=np.int64)
            out[order, 1] = tab[sc, 1] + c1
            out[order, 0] = tab[sc, 0] + idx - c1
            np.add.at(tab, (c, values), 1)
            G.limit_counts(tab, limit)
            return out
        cf = running(ctx, table)
        cc = None if coarse is None else running(coarse, ctable)
        f1 = estimate(cf, cc, K)
        p = np.where(values == 1, f1, T - f1)
        self.bits[self.tag] += float(np.sum(LOG2T - np.log2(p)))

    def freq(self, ctx, table, coarse, ctable, K):
        return estimate(table[ctx], None if coarse is None else ctable[coarse], K)

    def raw(self, nbits, values):
        self.bits[self.tag] += nbits * values.size


def estimate(cf, cc, K):
    """Integer f1 (of 2^24): KT of the fine counts, or with a coarse KT estimate as prior of weight K."""
    n0, n1 = cf[:, 0], cf[:, 1]
    if cc is None:
        f1 = ((2 * n1 + 1) * T) // (2 * (n0 + n1) + 2)
    else:
        fc = ((2 * cc[:, 1] + 1) * T) // (2 * (cc[:, 0] + cc[:, 1]) + 2)
        f1 = (n1 * T + K * fc) // (n0 + n1 + K)
    return np.clip(f1, 1, T - 1)


# --- context variants of the occupancy passes -------------------------------------------------

def pass_features(k, occ, padded, nb, exists):
    """Per axis a (x, y, z): c_a, and the known neighbourhood of child k: sibling s and +a
    neighbour's child o across the face (when c_a = 1), the parent-level exists[-a], exists[+a]."""
    feats = []
    for a in range(3):
        bit = G.AXIS_BIT[a]
        if k & bit:
            j = k ^ bit
            s = (occ >> j) & 1
            o = (padded[nb[2 * a + 1]] >> j) & 1
        else:
            s = o = np.zeros_like(occ)
        feats.append(dict(c=int(bool(k & bit)), s=s, o=o, em=exists[2 * a], ep=exists[2 * a + 1]))
    return feats


def ctx_base(k, occ, feats, dens, nbr_count):
    axes = np.zeros_like(occ)
    for f in feats:
        axes = axes * 3 + (f["s"] + f["o"] if f["c"] else f["em"])
    before = G.POPCOUNT8[occ & ((1 << k) - 1)]
    return (axes * 4 + np.minimum(before, 3)) * 4 + dens, G.NUM_OCC_CONTEXTS


def ctx_full6(k, occ, feats, dens, nbr_count):
    """Every axis 4 states: c_a = 1: (s, o) separately; c_a = 0: (exists[-a], exists[+a])."""
    axes = np.zeros_like(occ)
    for f in feats:
        axes = axes * 4 + (f["s"] * 2 + f["o"] if f["c"] else f["em"] * 2 + f["ep"])
    before = G.POPCOUNT8[occ & ((1 << k) - 1)]
    return (axes * 4 + np.minimum(before, 3)) * 7 + nbr_count, 64 * 4 * 7


def ctx_full6s(k, occ, feats, dens, nbr_count):
    """full6 with c_a = 1 also seeing exists[-a] (the far face), and the exact sibling pattern."""
    axes = np.zeros_like(occ)
    for f in feats:
        axes = axes * 8 + (f["s"] * 4 + f["o"] * 2 + f["em"] if f["c"] else f["em"] * 2 + f["ep"])
    pat = occ & ((1 << k) - 1)
    return (axes * 128 + pat) * 7 + nbr_count, 512 * 128 * 7


def child_level(k, occ_known, known, nb, exists):
    """Per axis: inward (sibling k^bit) and outward (the face neighbour's child k^bit across the
    face) child-level neighbours of child k: each 0 empty, 1 occupied, 2 unknown (not yet coded).
    ``known`` = mask of the coded bits of every node (padded: index -1 reads 'known empty')."""
    ins, outs = [], []
    pk = np.append(known, 0xFF)
    po = np.append(occ_known, 0)
    me = np.arange(occ_known.size)
    for a in range(3):
        bit = G.AXIS_BIT[a]
        j = k ^ bit
        side = 1 if k & bit else 0
        nbr = nb[2 * a + side]
        for arr, idx in ((ins, me), (outs, nbr)):
            kn = (pk[idx] >> j) & 1
            arr.append(np.where(kn == 1, (po[idx] >> j) & 1, 2))
    return ins, outs


def ctx_cl_axes(k, occ, feats, dens, nbr_count, cl):
    ins, outs = cl
    axes = np.zeros_like(occ)
    for i, o in zip(ins, outs):
        axes = axes * 9 + i * 3 + o
    before = G.POPCOUNT8[occ & ((1 << k) - 1)]
    return axes * 4 + np.minimum(before, 3), 729 * 4


def ctx_cl_count(k, occ, feats, dens, nbr_count, cl):
    ins, outs = cl
    vals = np.stack(ins + outs)
    occn = (vals == 1).sum(axis=0)
    unk = (vals == 2).sum(axis=0)
    before = G.POPCOUNT8[occ & ((1 << k) - 1)]
    return ((occn * 7 + unk) * 4 + np.minimum(before, 3)) * 4 + dens, 49 * 16


def ctx_cl_mix(k, occ, feats, dens, nbr_count, cl):
    """Outward states per axis (3^3), known-occupied inward count, before, dens."""
    ins, outs = cl
    o = (outs[0] * 3 + outs[1]) * 3 + outs[2]
    iocc = sum((i == 1).astype(np.int64) for i in ins)
    before = G.POPCOUNT8[occ & ((1 << k) - 1)]
    return ((o * 4 + iocc) * 4 + np.minimum(before, 3)) * 4 + dens, 27 * 64


def exists_offsets(q, depth):
    """{offset (dx, dy, dz): bool [M]} for the 26 neighbour offsets, nodes q in Morton order."""
    keys = G._morton21(q)
    size = 1 << depth
    out = {}
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if dx == dy == dz == 0:
                    continue
                nq = q + np.array([dx, dy, dz])
                ok = np.all((nq >= 0) & (nq < size), axis=1)
                kq = G._morton21(np.where(ok[:, None], nq, 0))
                pos = np.minimum(np.searchsorted(keys, kq), keys.size - 1)
                out[(dx, dy, dz)] = ok & (keys[pos] == kq)
    return out


def octant_count(k, ex):
    """Occupied parent-level neighbours toward child k's corner (3 face, 3 edge, 1 corner): 0..7,
    and the face/edge/corner split."""
    sgn = [1 if k & G.AXIS_BIT[a] else -1 for a in range(3)]
    face = edge = corner = 0
    for mx in (0, 1):
        for my in (0, 1):
            for mz in (0, 1):
                w = mx + my + mz
                if w == 0:
                    continue
                e = ex[(mx * sgn[0], my * sgn[1], mz * sgn[2])].astype(np.int64)
                if w == 1:
                    face = face + e
                elif w == 2:
                    edge = edge + e
                else:
                    corner = corner + e
    return face, edge, corner


def _axes_and_before(k, occ, feats):
    """(the three axes' face-neighbour classes, children coded before child k, capped at 3) as one index."""
    axes = np.zeros_like(occ)
    for f in feats:
        axes = axes * 3 + (f["s"] + f["o"] if f["c"] else f["em"])
    return axes * 4 + np.minimum(G.POPCOUNT8[occ & ((1 << k) - 1)], 3)


def ctx_oct(k, occ, feats, dens, nbr_count, oc):
    face, edge, corner = oc
    return (_axes_and_before(k, occ, feats) * 4 + edge) * 2 + corner, 27 * 4 * 4 * 2


def ctx_oct2(k, occ, feats, dens, nbr_count, oc):
    face, edge, corner = oc
    return (_axes_and_before(k, occ, feats) * 4 + dens) * 8 + face + edge + corner, 432 * 8


VARIANTS = {"base": ctx_base, "full6": ctx_full6, "full6s": ctx_full6s}
def ctx_cl_oct(k, occ, feats, dens, nbr_count, cl, oc):
    c, n = ctx_cl_axes(k, occ, feats, dens, nbr_count, cl)
    face, edge, corner = oc
    return (c * 4 + edge) * 2 + corner, n * 8


CL_VARIANTS = {"cl_axes": ctx_cl_axes, "cl_count": ctx_cl_count, "cl_mix": ctx_cl_mix, "cl_oct": None}


class State(G._ContextState):
    def __init__(self):
        super().__init__()
        self.tabs = {}

    def tab(self, key, size):
        if key not in self.tabs:
            self.tabs[key] = np.zeros((size, 2), dtype=np.int64)
        return self.tabs[key]


def code_occupancy(io, st, q, depth, remaining, bit_depth, occ_true, opt):
    for key, t in st.tabs.items():
        G.limit_counts(t, opt["level_limit"])
    nb = G._face_neighbours(q, depth)
    exists = (nb >= 0).astype(np.int64)
    nbr_count = exists.sum(axis=0)
    dens = G.DENS_BUCKET[nbr_count]
    if "oct" in opt["ctx"]:
        st.ex = exists_offsets(q, depth)
    splits = [remaining - 1 < d for d in bit_depth]
    valid = [k for k in range(8) if all(splits[a] or not (k & G.AXIS_BIT[a]) for a in range(3))]
    last = valid[-1]
    ncls = opt.get("classes", 1)
    cls = (q.sum(axis=1) & 1) if ncls == 2 else np.zeros(q.shape[0], dtype=np.int64)
    if ncls == 8:
        cls = (q[:, 0] & 1) * 4 + (q[:, 1] & 1) * 2 + (q[:, 2] & 1)
    known = np.zeros(q.shape[0], dtype=np.int64)
    for c in range(ncls):
        mine = np.flatnonzero(cls == c)
        for k in valid:
            known[mine] = (1 << k) - 1
            _code_pass(io, st, k, k == last, mine, occ_true, known, nb, exists, dens, nbr_count, depth, opt)
        known[mine] = 0xFF
    return occ_true, nbr_count


def _code_pass(io, st, k, is_last, mine, occ_true, known, nb, exists, dens, nbr_count, depth, opt):
    occ_known = occ_true & known
    occ = occ_known[mine]
    if opt["ctx"] in CL_VARIANTS:
        ins, outs = child_level(k, occ_known, known, nb, exists)
        cl = ([x[mine] for x in ins], [x[mine] for x in outs])
        if opt["ctx"] == "cl_oct":
            oc = [x[mine] for x in octant_count(k, st.ex)]
            ctx, nctx = ctx_cl_oct(k, occ, None, dens[mine], nbr_count[mine], cl, oc)
        else:
            ctx, nctx = CL_VARIANTS[opt["ctx"]](k, occ, None, dens[mine], nbr_count[mine], cl)
        cl_base = True
    elif opt["ctx"] in ("oct", "oct2"):
        padded = np.append(occ_known, 0)
        feats = pass_features(k, occ, padded, nb[:, mine], exists[:, mine])
        oc = [x[mine] for x in octant_count(k, st.ex)]
        ctx, nctx = (ctx_oct if opt["ctx"] == "oct" else ctx_oct2)(k, occ, feats, dens[mine], nbr_count[mine], oc)
        cl_base = False
    else:
        padded = np.append(occ_known, 0)
        feats = pass_features(k, occ, padded, nb[:, mine], exists[:, mine])
        ctx, nctx = VARIANTS[opt["ctx"]](k, occ, feats, dens[mine], nbr_count[mine])
        cl_base = False
    vals = (occ_true[mine] >> k) & 1
    sel = np.flatnonzero(G.POPCOUNT8[occ] > 0) if is_last else slice(None)
    io.tag = f"occ d{depth}"
    if opt.get("coarse") is None:
        io.binary(ctx[sel], st.tab(("f", k), nctx), vals[sel], limit=opt["limit"])
        return
    if cl_base:
        padded = np.append(occ_known, 0)
        feats = pass_features(k, occ, padded, nb[:, mine], exists[:, mine])
    cc, ncc = VARIANTS[opt["coarse"]](k, occ, feats, dens[mine], nbr_count[mine])
    io.binary(ctx[sel], st.tab(("f", k), nctx), vals[sel], cc[sel], st.tab(("c", k), ncc),
              opt["K"], limit=opt["limit"])


def run_octree(pts_in, opt, idcm_mode=G.IDCM_ISOLATED):
    """Ideal bits of the octree of unique int coords with the variant ``opt``; per-tag dict."""
    c = np.asarray(pts_in, dtype=np.int64)
    off = c - c.min(axis=0)
    bit_depth = G._bit_depths(off)
    pts = off[G._morton_perm(off, max(bit_depth))]
    io = CostIO(chunk_log2=opt.get("chunk_log2", G.CHUNK_LOG2), seq=opt.get("seq", False))
    if opt.get("rf"):
        io.shift = (opt["rf"], opt["rs"])
        io.states = {}
    st = State()
    nodes = G._NodeState.root()
    dmax = max(bit_depth)
    for depth in range(dmax):
        remaining = dmax - depth
        q_all, starts = G._nodes_of_points(pts, remaining)
        q = q_all[starts]
        elig = nodes.idcm_eligible(idcm_mode, remaining)
        if elig.size:
            io.tag = f"idcm d{depth}"
            keep = G._encode_direct_nodes(io, st, pts, starts, elig, nodes, remaining, bit_depth)
            pts = pts[np.repeat(keep, np.diff(np.append(starts, pts.shape[0])))]
            q, nodes = q[keep], nodes.without(keep)
            if pts.shape[0] == 0:
                break
            q_all, starts = G._nodes_of_points(pts, remaining)
        r1 = remaining - 1
        ci = (((pts[:, 0] >> r1) & 1) << 2) | (((pts[:, 1] >> r1) & 1) << 1) | ((pts[:, 2] >> r1) & 1)
        occ = np.bitwise_or.reduceat(np.left_shift(1, ci), starts)
        occ, nbr_count = code_occupancy(io, st, q, depth, remaining, bit_depth, occ, opt)
        _, parent = G._children(q, occ)
        nodes = nodes.children(occ, nbr_count, parent)
    return dict(io.bits)


BASE = dict(ctx="base", limit=G.COUNT_LIMIT, level_limit=G.LEVEL_COUNT_LIMIT)


# --- driver -----------------------------------------------------------------------------------

def load(names: list[str]) -> dict[str, np.ndarray]:
    sets, _ = bg.load_sets(bg.DEFAULT_DATA, [6, 8, 10, 12, 14], [10_000, 100_000])
    out = {}
    for name, bits, coords in sets:
        key = (name.split()[0][:4] + (str(bits) if bits else name.split()[-1])).replace("surf", "surf")
        if not names or key in names:
            out[key] = coords
    return out


def gpcc_cached(key: str, coords: np.ndarray, cache: Path) -> float | None:
    import json
    d = json.loads(cache.read_text()) if cache.exists() else {}
    if key not in d:
        tmc3, why = bg.find_tmc3(None)
        if tmc3 is None:
            return None
        d[key] = bg.gpcc_bits(tmc3, key, coords)[0]
        cache.write_text(json.dumps(d, indent=1))
    return d[key] / coords.shape[0]


def parse_variant(spec: str) -> dict:
    """'base' or 'ctx=full6,coarse=base,K=4,seq=1,...' over BASE."""
    opt = dict(BASE)
    if spec == "base":
        return opt
    for kv in spec.split(","):
        k, v = kv.split("=")
        opt[k] = v if k in ("ctx", "coarse") else int(v)
    opt.setdefault("K", 4)
    return opt


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--sets", nargs="*", default=[])
    p.add_argument("--variants", nargs="+", default=["base"])
    p.add_argument("--detail", action="store_true", help="bits per tag (depth, idcm/occ)")
    args = p.parse_args(argv)
    cache = Path("/tmp/gpcc_bits.json")
    sets = load(args.sets)
    print("set        voxels   G-PCC  " + "  ".join(f"{v[:24]:>24s}" for v in args.variants))
    for key, coords in sets.items():
        n = coords.shape[0]
        g = gpcc_cached(key, coords, cache)
        cells = []
        for v in args.variants:
            o = parse_variant(v)
            bits = run_octree(coords, o, o.get("idcm", G.IDCM_ISOLATED))
            bpv = (sum(bits.values()) + 8 * 16) / n  # + header and coder flush, about 16 bytes
            cells.append(f"{bpv:7.3f} ({bpv / g:5.3f}x)" if g else f"{bpv:7.3f}")
            if args.detail:
                for t, b in bits.items():
                    print(f"    {v} {t:10s} {b / n:7.3f}")
        print(f"{key:8s} {n:>8d} {g or 0:7.3f}  " + "  ".join(f"{c:>24s}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
