"""GG-Conv integer inference (common/context/ggconv.py) and its fitting (encoder/context/ggconv_train.py)."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from lghcc.common.context.ggconv import (
    GRID_FRAC_BITS,
    STEP_ADJUST_FACTORS,
    GGConvParams,
    NamedIntArray,
    ggconv_coding_params,
    grid_coordinate,
    level2_graph,
    trilinear_corners,
)
from lghcc.common.entropy.scale_levels import sigma_of_level
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.intnn import ACT_MAX, ACT_MIN, IntLinear, IntMLP


def random_params(rng, c=6, koff=2, ch=5, hid=7, hid2=9, k=8, radius_sq=6, grid=5, wscale=2000, shift=12,
                  neighbour_level=2):
    m = c + 6 + 3 * koff

    def lin(i, o, relu):
        return IntLinear(rng.integers(-wscale, wscale + 1, (o, i)), rng.integers(-50000, 50000, o), shift, relu)

    return GGConvParams(c, k, radius_sq, rng.integers(-2 ** 15, 2 ** 15, (grid, grid, grid, ch)), 15,
                        IntMLP([lin(c + 3, hid, True), lin(hid, ch, False)]),
                        IntMLP([lin(ch + 4 + m, hid2, True), lin(hid2, 3 * m, False)]), neighbour_level,
                        rng.integers(0, 2, m))


def own_parents(p: GGConvParams, coords, x, s, *args, **kw):
    """ggconv_coding_params for a level-2 graph model given per-anchor parent attributes x:
    each level-2 anchor is given a level-1 parent row of its own holding x (the positions of
    those rows play no part with neighbour_level 2)."""
    n = len(coords)
    return ggconv_coding_params(p, coords, np.arange(n), np.zeros((n, 3), np.int64), x, s, *args, **kw)


def reference(p: GGConvParams, coords, xpar, s, level1=None):
    """The normative text of spec/hierarchy_ggconv.md, one anchor at a time in Python integers.
    level1 = (positions, attributes) of the level-1 anchors, for neighbour_level 1."""
    n, m, c, d, fb = len(coords), p.num_attrs, p.num_features, p.grid_size, GRID_FRAC_BITS
    r = math.isqrt(p.radius_sq)
    cl = lambda v, lo=ACT_MIN: max(lo, min(ACT_MAX, v))
    rs = lambda v, sh: (v + (1 << (sh - 1))) >> sh if sh else v

    def mlp(net, x):
        for layer in net.layers:
            x = [cl(rs(int(layer.bias[o]) + sum(int(layer.weight[o, i]) * x[i] for i in range(len(x))), layer.shift),
                    0 if layer.relu else ACT_MIN) for o in range(layer.fan_out)]
        return x

    x = [[cl(int(v)) for v in row] for row in xpar]
    if p.neighbour_level == 2:  # the other level-2 anchors, carrying their parents' attributes
        dpos, dx = coords, x
    else:  # the level-1 anchors, carrying their own attributes
        dpos, dx = level1[0], [[cl(int(v)) for v in row] for row in level1[1]]
    out = []
    for i in range(n):
        cand = sorted((sum((int(dpos[j][a]) - int(coords[i][a])) ** 2 for a in range(3)), j)
                      for j in range(len(dpos)) if p.neighbour_level == 1 or j != i)
        nb = [j for d2, j in cand if 0 < d2 <= p.radius_sq or (d2 == 0 and p.neighbour_level == 2)][:p.k]
        hsum = [0] * p.context_channels
        for j in nb:
            u = [((int(dpos[j][a]) - int(coords[i][a]) + r) * (d - 1) * 2 ** (fb + 1) + 2 * r) // (4 * r)
                 for a in range(3)]
            i0 = [min(ua >> fb, d - 2) for ua in u]
            t = [u[a] - (i0[a] << fb) for a in range(3)]
            w = []
            for ch in range(p.context_channels):
                acc = 0
                for bx in (0, 1):
                    for by in (0, 1):
                        for bz in (0, 1):
                            wt = 1
                            for a, bit in enumerate((bx, by, bz)):
                                wt *= t[a] if bit else (1 << fb) - t[a]
                            acc += wt * int(p.table[i0[0] + bx, i0[1] + by, i0[2] + bz, ch])
                w.append(rs(acc, 3 * fb))
            e = mlp(p.feat_mlp, [dx[j][q] - x[i][q] for q in range(c)] + [ua - (d - 1) * 2 ** (fb - 1) for ua in u])
            hsum = [hs + wc * ec for hs, wc, ec in zip(hsum, w, e)]
        h = [cl(rs(v, p.h_shift)) for v in hsum]
        loc = [cl(int(coords[i][a]) % s) for a in range(3)]
        o = mlp(p.head_mlp, h + loc + [len(nb)] + x[i])
        out.append(([cl(int(p.parent_base[q]) * x[i][q] + o[q]) for q in range(m)], [min(63, max(0, v)) for v in o[m:2 * m]],
                    [min(7, max(0, v)) for v in o[2 * m:]]))
    return [np.array([o[q] for o in out], dtype=np.int64).reshape(n, m) for q in range(3)]


def _scene(rng, n=40, extent=6):
    c = np.unique(rng.integers(-extent, extent, (n, 3)), axis=0)
    return c[rng.permutation(len(c))]


def test_matches_independent_reference():
    rng = np.random.default_rng(0)
    for trial in range(3):
        p = random_params(rng)
        c = _scene(rng)
        x = rng.integers(-300, 300, (len(c), p.num_attrs))
        got = own_parents(p, c, x, 3, block=7)
        ref = reference(p, c, x, 3)
        for g, r in zip(got, ref):
            assert np.array_equal(g, r)


def _split(rng, n=60, extent=6, s=3):
    """A random anchor set split by the hierarchy: (level-1 coords, level-2 coords, parent index)."""
    c = _scene(rng, n, extent)
    h = build_hierarchy(c, s)
    return c[h.level1_idx], c[h.level2_idx], h.parent_of_level2


def test_level1_neighbours_match_independent_reference():
    """neighbour_level 1: level-2 anchors gather the level-1 anchors, with their own attributes."""
    rng = np.random.default_rng(20)
    for trial in range(3):
        p = random_params(rng, neighbour_level=1, radius_sq=[6, 12, 30][trial])
        c1, c2, parent = _split(rng, 80, 7, 3)
        x1 = rng.integers(-300, 300, (len(c1), p.num_attrs))
        got = ggconv_coding_params(p, c2, parent, c1, x1, 3, block=5)
        ref = reference(p, c2, x1[parent], 3, level1=(c1, x1))
        for g, r in zip(got, ref):
            assert np.array_equal(g, r)
    with pytest.raises(ValueError, match="parent index"):
        ggconv_coding_params(p, c2, parent + len(c1), c1, x1, 3)


def test_level1_neighbours_hard_cases():
    """Fewer than k level-1 anchors in the ball, none at all, equidistant ones, extreme values."""
    rng = np.random.default_rng(21)
    p = random_params(rng, neighbour_level=1, radius_sq=1, k=8, wscale=2 ** 15 - 1, shift=0)
    c1 = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [50, 50, 50]])
    c2 = np.array([[0, 0, 0], [1, 1, 0], [-40, 0, 0]])  # 6 equidistant, 2 at d2 = 1, none
    x1 = rng.choice([-(2 ** 40), 2 ** 40, ACT_MIN, ACT_MAX, 0], (len(c1), p.num_attrs))
    parent = np.array([6, 0, 3])
    idx, valid = level2_graph(p, c2, c1)
    assert valid.sum(1).tolist() == [6, 2, 0] and idx[0, :6].tolist() == [0, 1, 2, 3, 4, 5]
    got = ggconv_coding_params(p, c2, parent, c1, x1, 2)
    assert all(np.array_equal(a, b) for a, b in zip(got, reference(p, c2, x1[parent], 2, level1=(c1, x1))))
    assert got[0].min() >= ACT_MIN and got[0].max() <= ACT_MAX
    # a level-1 set whose only anchor lies outside every ball: all slots invalid
    far = (np.array([[500, 500, 500]]), x1[:1])
    got = ggconv_coding_params(p, c2, np.zeros(3, np.int64), far[0], far[1], 2)
    assert all(np.array_equal(a, b) for a, b in zip(got, reference(p, c2, x1[[0, 0, 0]], 2, level1=far)))


def test_extreme_values_and_isolated_anchors():
    rng = np.random.default_rng(1)
    p = random_params(rng, wscale=2 ** 15 - 1, shift=0)
    c = np.concatenate([_scene(rng, 20, 3), [[100, 100, 100], [-100, 50, 0]]])  # two anchors with no neighbour
    x = rng.choice([-(2 ** 40), 2 ** 40, ACT_MIN, ACT_MAX, 0], (len(c), p.num_attrs))
    mean, level, adj = own_parents(p, c, x, 4)
    ref = reference(p, c, x, 4)
    assert all(np.array_equal(a, b) for a, b in zip((mean, level, adj), ref))
    assert mean.min() >= ACT_MIN and mean.max() <= ACT_MAX
    assert level.min() >= 0 and level.max() <= 63 and adj.min() >= 0 and adj.max() <= 7
    idx, valid = level2_graph(p, c)
    assert not valid[-2:].any()


def test_equidistant_neighbours_and_fewer_than_k():
    rng = np.random.default_rng(2)
    p = random_params(rng, radius_sq=1)
    # a plus-shaped cluster: the centre has 6 neighbours at d2 = 1 (< k = 8), the arms 1 each
    c = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    c = c[rng.permutation(7)]
    x = rng.integers(-50, 50, (7, p.num_attrs))
    idx, valid = level2_graph(p, c)
    centre = int(np.nonzero((c == 0).all(1))[0][0])
    assert valid[centre].sum() == 6 and idx[centre, :6].tolist() == sorted(set(range(7)) - {centre})
    got = own_parents(p, c, x, 2)
    assert all(np.array_equal(a, b) for a, b in zip(got, reference(p, c, x, 2)))


def test_bit_exact_across_thread_counts():
    rng = np.random.default_rng(3)
    p = random_params(rng, c=16, koff=4, ch=8, hid=16, hid2=24, radius_sq=5)
    c = _scene(rng, 20000, 25)
    x = rng.integers(-2000, 2000, (len(c), p.num_attrs))
    nb = level2_graph(p, c)
    old = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        a = own_parents(p, c, x, 4, nb)
        torch.set_num_threads(2)
        b = own_parents(p, c, x, 4, nb, block=4096)
    finally:
        torch.set_num_threads(old)
    assert all(np.array_equal(u, v) for u, v in zip(a, b))


def test_empty_and_single_anchor():
    rng = np.random.default_rng(4)
    p = random_params(rng)
    z = own_parents(p, np.zeros((0, 3), np.int64), np.zeros((0, p.num_attrs), np.int64), 2)
    assert all(a.shape == (0, p.num_attrs) for a in z)
    x = rng.integers(-5, 5, (1, p.num_attrs))
    got = own_parents(p, np.array([[3, 4, 5]]), x, 2)
    assert all(np.array_equal(a, b) for a, b in zip(got, reference(p, np.array([[3, 4, 5]]), x, 2)))


def test_grid_coordinate_and_trilinear_weights():
    for r in (1, 2, 3, 7, 1000):
        dp = torch.arange(-r, r + 1)[:, None].repeat(1, 3)
        u = grid_coordinate(dp, r, 5)
        assert int(u.min()) == 0 and int(u.max()) == 4 << GRID_FRAC_BITS
        assert torch.equal(u[:, 0] + u.flip(0)[:, 0], torch.full((2 * r + 1,), 4 << GRID_FRAC_BITS))  # symmetric
        idx, w = trilinear_corners(u, 5)
        assert (w.sum(1) == 1 << 24).all() and int(idx.min()) >= 0 and int(idx.max()) < 125


def test_serialization_round_trip_and_errors():
    """to_syntax / from_syntax: the hyperparameters are syntax elements, the rest arrays (spec H.5.4)."""
    rng = np.random.default_rng(5)
    p = random_params(rng)
    hp, arrays = p.to_syntax()
    assert (hp.num_features, hp.neighbour_level, hp.k, hp.radius_sq, hp.h_shift) == (6, 2, 8, 6, 15)
    assert hp.feat_layer_shift == [12, 12] and hp.head_layer_shift == [12, 12]
    assert [a.name for a in arrays] == ["parent_base", "table", "feat.0.weight", "feat.0.bias", "feat.1.weight",
                                        "feat.1.bias", "head.0.weight", "head.0.bias", "head.1.weight", "head.1.bias"]
    assert {a.name: a.bits for a in arrays}["parent_base"] == 1
    assert {a.name: a.bits for a in arrays}["table"] == 16 and {a.name: a.bits for a in arrays}["feat.0.bias"] == 32
    q = GGConvParams.from_syntax(hp, arrays)
    c = _scene(rng, 60)
    x = rng.integers(-100, 100, (len(c), p.num_attrs))
    assert all(np.array_equal(a, b) for a, b in zip(own_parents(p, c, x, 2), own_parents(q, c, x, 2)))
    with pytest.raises(ValueError, match="missing"):
        GGConvParams.from_syntax(hp, [a for a in arrays if a.name != "table"])
    with pytest.raises(ValueError, match="unknown"):
        GGConvParams.from_syntax(hp, arrays + [NamedIntArray("extra", np.array([1]), 8, False)])
    bad = [NamedIntArray(a.name, a.values + (1 << 20) if a.name == "table" else a.values, a.bits, a.signed)
           for a in arrays]
    with pytest.raises(ValueError, match="range"):
        GGConvParams.from_syntax(hp, bad)
    with pytest.raises(ValueError, match="neighbour_level"):
        GGConvParams.from_syntax(dataclasses.replace(hp, neighbour_level=3), arrays)
    with pytest.raises(ValueError, match="shift"):
        GGConvParams.from_syntax(dataclasses.replace(hp, feat_layer_shift=[32, 12]), arrays)
    with pytest.raises(ValueError, match="missing"):  # three head layers: no arrays for the third
        GGConvParams.from_syntax(dataclasses.replace(hp, head_layer_shift=[12, 12, 12]), arrays)
    for values in (np.ones(p.num_attrs - 1, np.int64), np.full(p.num_attrs, 2)):
        bad = [NamedIntArray(a.name, values, 8, False) if a.name == "parent_base" else a for a in arrays]
        with pytest.raises(ValueError, match="parent_base"):
            GGConvParams.from_syntax(hp, bad)


def test_parent_mlp_matches_independent_reference():
    """Spec H.6 one anchor at a time in Python integers, parent_base mixed."""
    from lghcc.common.context.parent_mlp import ParentMlpParams
    from reference_impl import parent_mlp_coding_params

    rng = np.random.default_rng(21)
    c, m, s = 4, 4 + 6 + 6, 3
    cl = lambda v, lo=ACT_MIN: max(lo, min(ACT_MAX, v))  # noqa: E731
    lin = lambda i, o, relu: IntLinear(rng.integers(-3000, 3001, (o, i)), rng.integers(-50000, 50000, o), 11, relu)  # noqa: E731
    p = ParentMlpParams(c, IntMLP([lin(3 + m, 9, True), lin(9, 3 * m, False)]), rng.integers(0, 2, m))
    q = ParentMlpParams.from_syntax(*p.to_syntax())
    assert np.array_equal(q.parent_base, p.parent_base)
    coords2 = rng.integers(-40, 40, (50, 3))
    attrs1 = rng.integers(-40000, 40000, (7, m))  # beyond 16 bits: clamped as x_i
    parent = rng.integers(0, 7, 50)
    got = parent_mlp_coding_params(q, coords2, parent, attrs1, s)
    for i in range(50):
        x = [cl(int(v)) for v in attrs1[parent[i]]]
        h = [cl(int(v) % s) for v in coords2[i]] + x
        for layer in p.head_mlp.layers:
            h = [cl((int(layer.bias[o]) + sum(int(layer.weight[o, j]) * h[j] for j in range(len(h)))
                     + (1 << (layer.shift - 1))) >> layer.shift, 0 if layer.relu else ACT_MIN)
                 for o in range(layer.fan_out)]
        assert got[0][i].tolist() == [cl(int(p.parent_base[q_]) * x[q_] + h[q_]) for q_ in range(m)]
        assert got[1][i].tolist() == [min(63, max(0, v)) for v in h[m:2 * m]]
        assert got[2][i].tolist() == [min(7, max(0, v)) for v in h[2 * m:]]


def test_parent_base_is_chosen_per_channel():
    """Channels a parent predicts keep it as the mean's base; the others start from their median."""
    from lghcc.encoder.context.ggconv_train import choose_parent_base

    rng = np.random.default_rng(3)
    xpar = torch.from_numpy(rng.normal(0, 30, (4000, 6)))
    targets = xpar.clone()
    targets[:, :3] += torch.from_numpy(rng.normal(0, 1, (4000, 3)))  # follow the parent
    targets[:, 3:] = torch.from_numpy(rng.normal(7, 2, (4000, 3)))  # independent of it
    base, center, spread = choose_parent_base(targets, xpar)
    assert base.tolist() == [1, 1, 1, 0, 0, 0]
    assert center[:3].abs().max() == 0 and torch.allclose(center[3:], torch.full((3,), 7.0, dtype=torch.float64), atol=0.2)
    assert (spread[:3] < 1.5).all() and (spread[3:] > 1.5).all()
    b0, c0, s0 = choose_parent_base(targets[:0], xpar[:0])  # no rows: the parent, unit spread
    assert b0.tolist() == [1] * 6 and c0.abs().max() == 0


def test_step_adjust_factors_frozen():
    assert STEP_ADJUST_FACTORS.dtype == np.float32 and not STEP_ADJUST_FACTORS.flags.writeable
    assert [float(np.float32(2 ** (a / 4))) for a in range(8)] == STEP_ADJUST_FACTORS.tolist()
    assert sigma_of_level(0) == pytest.approx(0.11) and sigma_of_level(63) == pytest.approx(512)
    from lghcc.common.entropy.tables import SCALE_SIGMAS

    assert np.allclose(SCALE_SIGMAS, sigma_of_level(np.arange(64)))


def _smooth_scene(n=3500, extent=32, c=6, koff=2, s=4, seed=0):
    """A smooth random field on random voxels, split by the hierarchy: returns the level-2
    positions, parents and targets, C, s and the level-1 (positions, attributes)."""
    rng = np.random.default_rng(seed)
    coords = np.unique(rng.integers(0, extent, (n, 3)), axis=0)
    coords = coords[rng.permutation(len(coords))]
    m = c + 6 + 3 * koff
    freq = rng.normal(0, 0.15, (m, 3))
    phase = rng.uniform(0, 6.28, m)
    vals = 20 * np.sin(coords @ freq.T + phase) + rng.normal(0, 0.3, (len(coords), m))
    h = build_hierarchy(coords, s)
    q1 = np.floor(vals[h.level1_idx] + 0.5).astype(np.int64)
    return coords[h.level2_idx], h.parent_of_level2, vals[h.level2_idx], c, s, (coords[h.level1_idx], q1)


@pytest.mark.parametrize("neighbour_level", [1, 2])
def test_fit_reduces_rate_and_twin_matches_integer_path(neighbour_level):
    from lghcc.encoder.context.ggconv_train import (
        GGConvTrainConfig,
        estimated_rate_bits,
        train_ggconv_twin,
        twin_outputs,
        zero_mean_prior_bits,
    )

    c2, parent, targets, c, s, level1 = _smooth_scene()
    cfg = GGConvTrainConfig(float_steps=100, qat_steps=30, batch=384, lam=1000.0, progress=False,
                            ctx_channels=8, feat_hidden=16, head_hidden=32, neighbour_level=neighbour_level)
    params, twin = train_ggconv_twin(c2, parent, *level1, targets, c, s, cfg)
    assert params.neighbour_level == neighbour_level
    bits, adj = estimated_rate_bits(params, c2, parent, *level1, targets, s)
    base = zero_mean_prior_bits(targets)
    assert (adj == 0).mean() > 0.99  # lambda high: same distortion as the reference
    assert bits < 0.85 * base, (bits / len(c2), base / len(c2))
    mean_t, level_t, adj_t = twin_outputs(twin, c2, parent, *level1, s)
    mean_i, level_i, adj_i = ggconv_coding_params(params, c2, parent, *level1, s)
    assert (np.abs(mean_t - mean_i) <= 1).mean() > 0.99
    # the quantized twin emulates the integer path exactly
    assert np.array_equal(mean_t, mean_i) and np.array_equal(level_t, level_i) and np.array_equal(adj_t, adj_i)
    # parameters survive serialization
    q = GGConvParams.from_syntax(*params.to_syntax())
    assert np.array_equal(ggconv_coding_params(q, c2, parent, *level1, s)[0], mean_i)


def test_large_radius_without_offset_table_matches_reference():
    """Radii with (2R+1)^3 beyond the offset table's limit take the per-edge geometry path."""
    rng = np.random.default_rng(12)
    p = random_params(rng, radius_sq=60 ** 2, k=5)
    c = _scene(rng, 30, 40)
    x = rng.choice([ACT_MIN, ACT_MAX, 0, 7, -300], (len(c), p.num_attrs))
    got = own_parents(p, c, x, 5, block=4)
    assert all(np.array_equal(a, b) for a, b in zip(got, reference(p, c, x, 5)))


def test_entries_that_are_not_coded_cost_nothing_in_the_fit():
    """NaN targets (dead offsets) leave the rate-distortion loss and the initial prediction
    exactly as if those entries were absent."""
    from lghcc.encoder.context.ggconv_train import choose_parent_base, rd_loss

    rng = np.random.default_rng(8)
    targets = torch.from_numpy(rng.normal(3, 4, (300, 5)))
    mean, level = torch.from_numpy(rng.normal(3, 1, (300, 5))), torch.full((300, 5), 20.0, dtype=torch.float64)
    adj = torch.from_numpy(rng.integers(0, 3, (300, 5)).astype(np.float64))
    dead = torch.from_numpy(rng.random((300, 5)) < 0.4)
    with_nan = torch.where(dead, torch.nan, targets)
    loss, bits = rd_loss(mean, level, adj, with_nan, 16.0)
    assert torch.isfinite(loss).all()
    for r in range(0, 300, 37):
        live = ~dead[r]
        l_ref, b_ref = rd_loss(mean[r:r + 1, live], level[r:r + 1, live], adj[r:r + 1, live], targets[r:r + 1, live], 16.0)
        assert torch.allclose(loss[r], l_ref[0]) and torch.allclose(bits[r], b_ref[0])
    xpar = torch.from_numpy(rng.normal(0, 4, (300, 5)))
    base, center, spread = choose_parent_base(with_nan, xpar)
    for ch in range(5):
        live = ~dead[:, ch]
        b1, c1, s1 = choose_parent_base(targets[live, ch:ch + 1], xpar[live, ch:ch + 1])
        assert base[ch] == b1[0] and torch.allclose(center[ch], c1[0]) and torch.allclose(spread[ch], s1[0])
    never = torch.full((300, 5), torch.nan, dtype=torch.float64)  # a channel never coded: finite start
    b0, c0, s0 = choose_parent_base(never, xpar)
    assert torch.isfinite(c0).all() and torch.isfinite(s0).all()


def test_context_twin_file_round_trip_and_rejects_what_it_cannot_use(tmp_path):
    """A ContextTwin saved and loaded is the same twin; a file whose state does not fit its sizes,
    or whose settings are out of range, is refused with ValueError naming the file."""
    import dataclasses

    import torch

    from lghcc.encoder.context.ggconv_train import ContextTwin, GGConvFloat, GGConvTrainConfig

    c, m = 4, 4 + 6 + 6
    cfg = GGConvTrainConfig(ctx_channels=3, feat_hidden=5, head_hidden=7)
    model = GGConvFloat(c, m, cfg, torch.ones(c + 3, dtype=torch.float64), torch.ones(m + 4, dtype=torch.float64))
    twin = ContextTwin(dict(model.state_dict()), model.feat_q, model.head_q_raw, 4, 8, 1, 30, 0.02, c, m)
    twin.save(tmp_path / "t.pt")
    back = ContextTwin.load(tmp_path / "t.pt")
    assert back.sizes == (3, 5, 7) and (back.k, back.radius_sq, back.step) == (8, 30, 0.02)
    assert all(torch.equal(v, twin.state[k]) for k, v in back.state.items())
    assert back.mismatch(c, m, 4, 8, np.full(m, 0.02)) is None
    assert "step" in back.mismatch(c, m, 4, 8, np.full(m, 0.05))
    assert "voxel scale" in back.mismatch(c, m, 2, 8, np.full(m, 0.02))
    bad_state = dict(twin.state)
    bad_state["head.1.lin.bias"] = torch.zeros(5, dtype=torch.float64)
    for bad in (dataclasses.replace(twin, state=bad_state), dataclasses.replace(twin, neighbour_level=3),
                dataclasses.replace(twin, radius_sq=0), dataclasses.replace(twin, step=float("nan"))):
        bad.save(tmp_path / "bad.pt")
        with pytest.raises(ValueError, match="bad.pt"):
            ContextTwin.load(tmp_path / "bad.pt")
