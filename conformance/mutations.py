"""Mutation testing of the reference decoder: does the conformance suite catch a wrong decoder?

A conformance suite is only as good as the decisions of the decoding process it makes matter.
Each ``Mutation`` below is one mistake a careless implementer of spec/ could make in one
normative integer operation (a rounding shift rounding ties the other way, a missing clamp, a
floor instead of a round, an off-by-one range check, a missing rejection ...), applied to the
reference decoder by rewriting the source of one function (or one constant) at run time. The
mutation is *killed* when some conformance stream then fails (a hash changes, a stream that must
be rejected decodes or is rejected for another reason, or the decoder crashes or hangs): the
suite would catch that implementer. ``tools/mutation_test.py`` runs them (each in a forked
process, against the whole suite, in-process decoder) and reports killed/total per module in
tools/results/conformance.md.

Mutations are keyed by the function they change (``target``: module and qualified name) and a
description, and are applied as literal find/replace edits of that function's source: after a
refactor an edit whose text is no longer found is reported as *stale* (to be rewritten), never
silently skipped. Adding a mutation for a new operation (the explicit-Gaussian mode, a v1 with
tiles) is adding an entry.

Where the reference code evaluates a normative operation in a folded, informative form (the
integer networks as float64 GEMMs with the rounding offset folded into the bias, GG-Conv's first
layer as differences of per-anchor products), the mutation is written against that form so that
it has the effect of the implementer's mistake on the normative result (the docstring of each
says which).

Not listed, with the reason (each would be an *equivalent* mutation: no stream can tell):
* binary_frequency's clip to [1, 2^24 - 1]: the counts are at most 1024 + 1024 at the start of a
  chunk (COUNT_LIMIT), so f1 lies in [2^24 / 4098, 2^24 - 2^24 / 4098] without it;
* check_levels in the attribute decoder: levels come from u(6) prior levels or from a context
  model's clamp to [0, 63], so no level outside reaches it;
* the self-exclusion of the Ball k-NN with separate queries (d2 != 0): level-1 and level-2
  positions are distinct positions of one scene;
* the N * M <= 2^31 comparison as >= : the stream at the limit takes 8 GiB to decode (e005 covers
  the rejection beyond it);
* IntLinear's shift-0 case (no rounding offset): adding 0.5 before the floor of an integer is the
  integer;
* sh_degree's range 0..3 (clause 7.3.9): u(2) holds nothing else; likewise a context-model layer's
  shift, u(5), whose range is 0..31;
* GGConvParams' own checks of k, radius_sq, h_shift and neighbour_level and IntLinear's of a
  shift: the context-model unit's syntax rejects every value outside those ranges first (the
  syntax.* mutations of those elements stand for them);
* the SH transform's sums of products in binary64 instead of int64 (clause 11.11): with at most 45 terms
  below 2^61 a binary64 sum errs by a few units of its last place, and the inverse transform is then
  rounded by the shift and by float32() of clause 11.5 to 24 significant bits: the output differs only
  where the binary64 error moves the value across a binary32 rounding boundary, which no stream of a
  reasonable size meets (c120's sums beyond 2^53 differ in one integer of 1,248, not in any value);
  the binary32 sum is listed instead;
* the ranges of pred_source_channel (<= M - 2), of pred_target_channel from below (>= 1) and of
  num_channel_predictions (<= M (M - 1) / 2): an entry beyond them breaks source < target or the
  strictly increasing order of the entries, which the decoder rejects anyway (as BitstreamError;
  only the message would differ).
"""

from __future__ import annotations

import importlib
import inspect
import sys
import textwrap
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Mutation:
    """One wrong decoder: ``edits`` (find, replace) applied to the source of ``target``
    ('module:Qualified.name'), or ``value`` (an expression of the old value ``v``) assigned to a
    module constant ``target`` ('module:NAME')."""

    id: str
    group: str  # the report's module (intnn, ggconv, parent_mlp, knn, hierarchy, attributes, entropy, ...)
    target: str
    description: str
    edits: tuple[tuple[str, str], ...] = ()
    value: str | None = None
    kills_with: tuple[str, ...] = field(default=())  # informative: streams written to kill it
    # (target, edits) of the same mistake where the reference decoder checks the same rule a second time
    also: tuple[tuple[str, tuple[tuple[str, str], ...]], ...] = field(default=())


def M(id, group, target, description, *edits, value=None, kills_with=(), also=()):
    return Mutation(id, group, target, description, tuple(edits), value, tuple(kills_with), tuple(also))


INTNN = "lghcc.common.intnn"
GGCONV = "lghcc.common.context.ggconv"
PARENT = "lghcc.common.context.parent_mlp"
MODELS = "lghcc.common.context.models"
MODEL_UNIT = "lghcc.common.context.model_unit"
KNN = "lghcc.common.knn"
HIER = "lghcc.common.hierarchy"
ATTR = "lghcc.common.attributes"
SYMBOL = "lghcc.common.entropy.symbol_coder"
RANGE = "lghcc.common.entropy.range_coder"
GEOM = "lghcc.common.geometry"
UNITS = "lghcc.common.units"
SYNTAX = "lghcc.common.syntax"
RENDER = "lghcc.common.render_model"
CONTAINER = "lghcc.common.container"
DECODE = "lghcc.decoder.core"  # the decoding process of clause 13 (decoder/decode.py drives it)
HASHING = "lghcc.common.hashing"
TILES = "lghcc.common.tiles"
NEIGHBOUR = "lghcc.common.neighbour_prediction"
SH_DEGREE = "lghcc.common.sh_degree"

_BIAS_HALF = "(float(1 << (self.shift - 1)) if self.shift else 0.0)"

MUTATIONS: list[Mutation] = [
    # --- integer networks (Annex H.4): the decoder folds the rounding offset into the float64 bias
    M("intnn.ties_down", "intnn", f"{INTNN}:IntLinear.__post_init__",
      "rshift_round rounds ties toward minus infinity: (acc + 2^(s-1) - 1) >> s",
      (_BIAS_HALF, "(float((1 << (self.shift - 1)) - 1) if self.shift else 0.0)")),
    M("intnn.floor_shift", "intnn", f"{INTNN}:IntLinear.__post_init__",
      "no rounding offset: acc >> s (floor)", (_BIAS_HALF, "0.0")),
    M("intnn.ceil_shift", "intnn", f"{INTNN}:IntLinear.__post_init__",
      "rounds up: (acc + 2^s - 1) >> s", (_BIAS_HALF, "(float((1 << self.shift) - 1) if self.shift else 0.0)")),
    M("intnn.no_hidden_clamp", "intnn", f"{INTNN}:IntLinear.finish_f64",
      "hidden (ReLU) layers not clamped to 32767",
      ("clamp_(0.0 if self.relu else float(ACT_MIN), float(ACT_MAX))",
       "clamp_(0.0 if self.relu else float(ACT_MIN), None if self.relu else float(ACT_MAX))")),
    M("intnn.no_output_clamp", "intnn", f"{INTNN}:IntLinear.finish_f64",
      "the last layer of a network not clamped to 16 bits",
      ("clamp_(0.0 if self.relu else float(ACT_MIN), float(ACT_MAX))",
       "clamp_(0.0 if self.relu else None, float(ACT_MAX) if self.relu else None)")),
    M("intnn.no_relu", "intnn", f"{INTNN}:IntLinear.finish_f64",
      "hidden layers without ReLU (clamped to 16 bits only)",
      ("clamp_(0.0 if self.relu else float(ACT_MIN), float(ACT_MAX))", "clamp_(float(ACT_MIN), float(ACT_MAX))")),
    M("intnn.clamp_15_bits", "intnn", f"{INTNN}:IntLinear.finish_f64",
      "activations clamped to 15 bits [-16384, 16383]",
      ("clamp_(0.0 if self.relu else float(ACT_MIN), float(ACT_MAX))",
       "clamp_(0.0 if self.relu else -16384.0, 16383.0)")),

    # --- GG-Conv (Annex H.5)
    M("ggconv.grid_floor", "ggconv", f"{GGCONV}:grid_coordinate",
      "grid coordinate U floored instead of rounded (no + 2R)",
      ("* ((grid - 1) << (GRID_FRAC_BITS + 1)) + 2 * radius", "* ((grid - 1) << (GRID_FRAC_BITS + 1))")),
    M("ggconv.grid_ties_down", "ggconv", f"{GGCONV}:grid_coordinate",
      "grid coordinate U rounds ties down (+ 2R - 1)",
      ("* ((grid - 1) << (GRID_FRAC_BITS + 1)) + 2 * radius", "* ((grid - 1) << (GRID_FRAC_BITS + 1)) + 2 * radius - 1")),
    M("ggconv.cell_unclamped", "ggconv", f"{GGCONV}:trilinear_corners",
      "cell index i0 = U >> FB not clamped to D - 2 (at dp = R the upper cell is outside the table)",
      ("torch.clamp(u >> GRID_FRAC_BITS, max=grid - 2)", "(u >> GRID_FRAC_BITS)")),
    M("ggconv.weights_swapped", "ggconv", f"{GGCONV}:trilinear_corners",
      "trilinear weights of the lower and upper grid line swapped (t for the lower corner)",
      ("torch.stack([one - t, t], 2)", "torch.stack([t, one - t], 2)")),
    M("ggconv.tri_floor", "ggconv", f"{GGCONV}:_geometry_terms",
      "trilinear sum shifted by 24 with floor instead of rounding",
      ("rshift_round(trilinear_sum(table_f, ci, cw), TRI_SHIFT)", "(trilinear_sum(table_f, ci, cw) >> TRI_SHIFT)")),
    M("ggconv.tri_ties_down", "ggconv", f"{GGCONV}:_geometry_terms",
      "trilinear sum rounds ties down",
      ("rshift_round(trilinear_sum(table_f, ci, cw), TRI_SHIFT)",
       "((trilinear_sum(table_f, ci, cw) + ((1 << (TRI_SHIFT - 1)) - 1)) >> TRI_SHIFT)")),
    M("ggconv.du_not_centred", "ggconv", f"{GGCONV}:_geometry_terms",
      "feature-MLP grid inputs U not centred (U instead of U - (D-1) 2^(FB-1))",
      ("du = (u - ((g - 1) << (GRID_FRAC_BITS - 1))).to(torch.float64)", "du = u.to(torch.float64)")),
    M("ggconv.h_ties_down", "ggconv", f"{GGCONV}:GGConvEvaluator.rows",
      "aggregated context h = rshift_round(hsum, h_shift) rounds ties down",
      ("hsum.add_(0.5)", "hsum.sub_(0.5)"), ("h = hsum.floor_()", "h = hsum.ceil_()")),
    M("ggconv.h_floor", "ggconv", f"{GGCONV}:GGConvEvaluator.rows",
      "aggregated context h floored (hsum >> h_shift)", ("hsum.add_(0.5)", "hsum.add_(0.0)")),
    M("ggconv.h_unclamped", "ggconv", f"{GGCONV}:GGConvEvaluator.rows",
      "aggregated context h not clamped to 16 bits",
      ("h = hsum.floor_().clamp_(ACT_MIN, ACT_MAX)", "h = hsum.floor_()")),
    M("ggconv.diff_clamped", "ggconv", f"{GGCONV}:GGConvEvaluator.rows",
      "feature differences y_j - x_i clamped to 16 bits (the spec keeps them 17-bit)",
      ("acc = g_lin.add_(self.p1.index_select(0, y_rows)).view(nb, k, hdim)\n"
       "        acc.sub_(self.p1.index_select(0, pi)[:, None, :])",
       "cf = params.num_features\n"
       "        diff = (self.x1f.index_select(0, y_rows).view(nb, k, -1)[:, :, :cf]\n"
       "                - self.x1f.index_select(0, pi)[:, None, :cf]).clamp_(ACT_MIN, ACT_MAX)\n"
       "        acc = g_lin.view(nb, k, hdim).add_(diff @ feat0._ws[:cf])")),
    M("ggconv.parent_unclamped", "ggconv", f"{GGCONV}:GGConvEvaluator.__init__",
      "parent and neighbour attributes x not clamped to 16 bits",
      ("self.x1f = clamp16(torch.from_numpy(np.ascontiguousarray(x1))).to(torch.float64)",
       "self.x1f = torch.from_numpy(np.ascontiguousarray(x1)).to(torch.float64)")),
    M("ggconv.local_unclamped", "ggconv", f"{GGCONV}:GGConvEvaluator.__init__",
      "position inside the coarse voxel not clamped to 32767",
      ("local_position(c, self.voxel_scale)).clamp_(0, ACT_MAX)", "local_position(c, self.voxel_scale))")),
    M("ggconv.local_truncating_mod", "ggconv", f"{GGCONV}:GGConvEvaluator.__init__",
      "p mod s with C's % (truncation: negative for negative p) instead of floor mod",
      ("local_position(c, self.voxel_scale)", "np.fmod(c, np.int64(self.voxel_scale))")),
    M("ggconv.n_valid_is_k", "ggconv", f"{GGCONV}:GGConvEvaluator.__init__",
      "n_valid counts every slot (k) instead of the valid ones",
      ("self.n_valid = self.valid_t.sum(1).to(torch.float64)",
       "self.n_valid = torch.full((self.num_rows,), float(params.k), dtype=torch.float64)")),
    M("ggconv.mean_unclamped", "ggconv", f"{GGCONV}:split_outputs",
      "mean = parent_base x + o not clamped to 16 bits",
      ("return (clamp16(xpar * base + o[:, :m]),", "return ((xpar * base + o[:, :m]),")),
    M("ggconv.parent_base_ignored", "ggconv", f"{GGCONV}:split_outputs",
      "parent_base ignored: the parent's value is the base of every channel",
      ("return (clamp16(xpar * base + o[:, :m]),", "return (clamp16(xpar + o[:, :m]),")),
    M("ggconv.level_max_62", "ggconv", f"{GGCONV}:split_outputs",
      "scale level clamped to [0, 62] (off by one)",
      ("o[:, m:2 * m].clamp(0, NUM_LEVELS - 1)", "o[:, m:2 * m].clamp(0, NUM_LEVELS - 2)")),
    M("ggconv.step_adjust_max_6", "ggconv", f"{GGCONV}:split_outputs",
      "step adjustment clamped to [0, 6] (off by one)",
      ("o[:, 2 * m:].clamp(0, NUM_STEP_ADJUST - 1)", "o[:, 2 * m:].clamp(0, NUM_STEP_ADJUST - 2)")),
    M("ggconv.step_adjust_low_1", "ggconv", f"{GGCONV}:split_outputs",
      "step adjustment clamped to [1, 7] (off by one at the bottom)",
      ("o[:, 2 * m:].clamp(0, NUM_STEP_ADJUST - 1)", "o[:, 2 * m:].clamp(1, NUM_STEP_ADJUST - 1)")),
    M("ggconv.level_low_1", "ggconv", f"{GGCONV}:split_outputs",
      "scale level clamped to [1, 63]", ("o[:, m:2 * m].clamp(0, NUM_LEVELS - 1)", "o[:, m:2 * m].clamp(1, NUM_LEVELS - 1)")),
    M("ggconv.no_grid_check", "ggconv", f"{GGCONV}:GGConvParams.__post_init__",
      "table size D not checked against [2, 16]",
      ("or not MIN_GRID <= t.shape[0] <= MAX_GRID:", "or False:")),
    M("ggconv.grid_max_15", "ggconv", f"{GGCONV}:GGConvParams.__post_init__",
      "table size limit off by one: D = 16 rejected",
      ("or not MIN_GRID <= t.shape[0] <= MAX_GRID:", "or not MIN_GRID <= t.shape[0] < MAX_GRID:")),
    M("ggconv.no_feat_shape_check", "ggconv", f"{GGCONV}:GGConvParams.__post_init__",
      "feature MLP's input and output counts not checked against C + 3 and Ch",
      ("if c < 1 or self.feat_mlp.in_dim != c + 3 or self.feat_mlp.out_dim != ch:", "if c < 1:")),
    M("ggconv.no_extent_check", "ggconv", f"{MODELS}:check_ggconv_extent",
      "no extent limit (spec clause 8): the Ball k-NN's squared distances overflow",
      ("if extent > MAX_EXTENT:", "if False:")),
    M("ggconv.extent_off_by_one", "ggconv", f"{MODELS}:check_ggconv_extent",
      "extent limit off by one: E = MAX_EXTENT rejected", ("if extent > MAX_EXTENT:", "if extent >= MAX_EXTENT:")),

    # --- parent MLP (Annex H.6)
    M("parent_mlp.parent_unclamped", "parent_mlp", f"{PARENT}:ParentMlpEvaluator.__init__",
      "parent attributes not clamped to 16 bits",
      ("self.x1c = clamp16(torch.from_numpy(np.ascontiguousarray(x1)))",
       "self.x1c = torch.from_numpy(np.ascontiguousarray(x1))")),
    M("parent_mlp.local_unclamped", "parent_mlp", f"{PARENT}:ParentMlpEvaluator.rows",
      "position inside the coarse voxel not clamped to 32767",
      ("local_position(self.coords[b_lo:b_hi], self.voxel_scale).clip(0, ACT_MAX)",
       "local_position(self.coords[b_lo:b_hi], self.voxel_scale)")),
    M("parent_mlp.local_truncating_mod", "parent_mlp", f"{PARENT}:ParentMlpEvaluator.rows",
      "p mod s with truncation instead of floor mod", ("local_position(self.coords[b_lo:b_hi], self.voxel_scale)", "np.fmod(self.coords[b_lo:b_hi], np.int64(self.voxel_scale))")),
    M("parent_mlp.inputs_swapped", "parent_mlp", f"{PARENT}:ParentMlpEvaluator.rows",
      "head inputs in the order [x_i, local position] instead of [local position, x_i]",
      ("torch.cat([local, xpar], 1)", "torch.cat([xpar, local], 1)")),

    # --- canonical Ball k-NN (Annex H.3)
    M("knn.open_ball", "knn", f"{KNN}:_CandidateSearch.candidates_in_ball", "open ball: d2 < radius_sq",
      ("ok = d2 <= self.radius_sq", "ok = d2 < self.radius_sq")),
    M("knn.ties_high_index", "knn", f"{KNN}:_first_by_distance_then_index",
      "equal distances ordered by decreasing index",
      ("key = np.where(ok, d2 * (n + 1) + cidx, _BIG)", "key = np.where(ok, d2 * (n + 1) + (n - cidx), _BIG)"),
      ("si = key - sd * (n + 1)", "si = n - (key - sd * (n + 1))"),
      ("order = np.lexsort((key_i, key_d), axis=-1)[:, :take]", "order = np.lexsort((-key_i, key_d), axis=-1)[:, :take]")),
    M("knn.ties_high_index_wide", "knn", f"{KNN}:_first_by_distance_then_index",
      "equal distances ordered by decreasing index, where the radius is too large for one sort key",
      ("order = np.lexsort((key_i, key_d), axis=-1)[:, :take]", "order = np.lexsort((-key_i, key_d), axis=-1)[:, :take]")),
    M("knn.self_included", "knn", f"{KNN}:_CandidateSearch.candidates_in_ball", "a level-2 anchor is its own neighbour (self not excluded)",
      ("ok &= (cidx != rows[:, None]) if self.self_mode else (d2 != 0)", "ok &= True if self.self_mode else (d2 != 0)")),
    M("knn.manhattan", "knn", f"{KNN}:_CandidateSearch.candidates_in_ball", "distance sum of |d| per axis squared wrongly: d2 = sum |d| (L1)",
      ("d2 = d * d if d2 is None else d2 + d * d", "d2 = np.abs(d) if d2 is None else d2 + np.abs(d)")),

    # --- hierarchy (Annex H.2)
    M("hierarchy.truncating_division", "hierarchy", f"{HIER}:coarse_voxels",
      "coarse voxel by division rounding toward zero (-1 // 4 = 0)",
      ("np.floor_divide(coords, np.int64(scale))", "(np.abs(coords) // np.int64(scale)) * np.sign(coords)")),
    M("hierarchy.last_of_voxel", "hierarchy", f"{HIER}:build_hierarchy",
      "level 1 takes the anchor of highest index of each coarse voxel",
      ("order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))", "order = np.lexsort((-np.arange(n), v[:, 2], v[:, 1], v[:, 0]))")),

    M("hierarchy.parent_off_by_one", "hierarchy", f"{HIER}:build_hierarchy",
      "parent map: the level-1 anchor after the voxel's own (searchsorted to the right)",
      ("rank_of_group = np.searchsorted(level1_idx, first_of_group)",
       "rank_of_group = np.minimum(np.searchsorted(level1_idx, first_of_group, side='right'), level1_idx.size - 1)")),
    M("ggconv.neighbour_levels_swapped", "ggconv", f"{GGCONV}:GGConvEvaluator.__init__",
      "neighbour_level 1 and 2 swapped (level-1 neighbours where the model says level 2)",
      ("self.level1_data = params.neighbour_level == 1", "self.level1_data = params.neighbour_level == 2")),
    M("ggconv.head_inputs_order", "ggconv", f"{GGCONV}:GGConvEvaluator.rows",
      "head inputs [h, n_valid, position] instead of [h, position, n_valid]",
      ("z = torch.cat([h, self.local[b_lo:b_hi], self.n_valid[b_lo:b_hi, None]], 1)",
       "z = torch.cat([h, self.n_valid[b_lo:b_hi, None], self.local[b_lo:b_hi]], 1)")),

    # --- attribute decoding (clause 11)
    M("attributes.no_dead_zero", "attributes", f"{ATTR}:decode_chunk_values",
      "values of dead offsets not set to 0 (they keep the mean)", ("q *= live", "q *= 1")),
    M("attributes.no_finite_check", "attributes", f"{ATTR}:reconstruct_chunk",
      "a non-finite reconstruction is not rejected (clause 11.5)",
      ("if not np.isfinite(target).all():", "if False:")),
    M("attributes.no_level_check", "attributes", f"{ATTR}:read_attribute_unit",
      "attribute_level not checked against the unit's place",
      ("if h.attribute_level != level:", "if False:")),
    M("attributes.mask_shift", "attributes", f"{ATTR}:mask_models",
      "mask probability scaled by 2^11 instead of 2^12", ("shift = PRECISION_BITS - MASK_PROB_BITS", "shift = PRECISION_BITS - 1 - MASK_PROB_BITS")),
    M("attributes.mask_symbols_swapped", "attributes", f"{ATTR}:mask_models",
      "mask model with p for symbol 0 (dead) instead of 1 (live)",
      ("np.array([TOTAL_FREQUENCY - live, live]", "np.array([live, TOTAL_FREQUENCY - live]")),
    M("attributes.mask_slots_reversed", "attributes", f"{ATTR}:decode_mask_chunk",
      "mask flags decoded with the models of the slots in reverse",
      ("for k, model in enumerate(models):", "for k, model in enumerate(models[::-1]):")),
    M("attributes.mask_layout", "attributes", f"{ATTR}:ChannelLayout.live_channels",
      "offset flags spread to channels slot-major (tile) instead of 3 axes per slot",
      ("np.repeat(offset_mask.astype(bool), 3, axis=1)", "np.tile(offset_mask.astype(bool), 3)")),
    M("attributes.trailing_bytes", "attributes", f"{ATTR}:split_chunks",
      "chunk sizes may add up to less than the payload (trailing bytes accepted)",
      ("if total != len(payload):", "if total > len(payload):")),
    M("attributes.reconstruct_f64", "attributes", f"{ATTR}:reconstruct",
      "q * step computed in float64 and rounded once (not float32(q) times a binary32 step)",
      ("return np.multiply(q.astype(np.float32), effective_steps(steps, step_adjust), out=out, dtype=np.float32)",
       "return np.multiply(q.astype(np.float64), effective_steps(steps, step_adjust).astype(np.float64), out=out, "
       "casting='unsafe')")),
    M("attributes.step_factor_f64", "attributes", f"{ATTR}:effective_steps",
      "adjusted step float32(step * 2^(a/4)) in float64 (not a binary32 product of the frozen factors)",
      ("return (s * STEP_ADJUST_FACTORS[step_adjust]).astype(np.float32)",
       "return (s.astype(np.float64) * 2.0 ** (np.asarray(step_adjust, np.float64) / 4)).astype(np.float32)")),
    *[M(f"attributes.step_factor_{a}", "attributes", f"{ATTR}:effective_steps",
        f"step-adjustment factor {a} one binary32 ulp off",
        ("return (s * STEP_ADJUST_FACTORS[step_adjust]).astype(np.float32)",
         f"return (s * np.where(np.asarray(step_adjust) == {a}, np.nextafter(STEP_ADJUST_FACTORS[{a}], "
         "np.float32(4)), STEP_ADJUST_FACTORS[step_adjust]).astype(np.float32)).astype(np.float32)"))
      for a in range(8)],
    M("attributes.context_missing_ok", "attributes", f"{ATTR}:read_attribute_unit",
      "a context_model_id with no context-model unit decoded with the per-channel prior's zero means",
      ("        if context is None:\n            raise BitstreamError(",
       "        if context is None:\n            return h, None, None\n            raise BitstreamError(")),

    # --- entropy coding (clause 10)
    M("entropy.escape_off_by_one", "entropy", f"{SYMBOL}:_finish_escapes",
      "escaped magnitude |r| = L + m instead of L + 1 + m",
      ("mag = m + (half_of_escaped() + 1).astype(np.uint64)", "mag = m + (half_of_escaped() + 0).astype(np.uint64)")),
    M("entropy.escape_class_0", "entropy", f"{SYMBOL}:_finish_escapes",
      "escape class k = 0 decoded as m = 1 (like k = 1)",
      ("m = np.where(k > 0, np.left_shift", "m = np.where(k >= 0, np.left_shift")),
    M("entropy.escape_sign", "entropy", f"{SYMBOL}:_finish_escapes", "escape sign bit 1 read as positive",
      ("out[esc] = np.where(neg, -mag, mag)", "out[esc] = np.where(neg, mag, -mag)")),
    M("entropy.no_escape_limit", "entropy", f"{SYMBOL}:_finish_escapes",
      "escaped magnitudes above 2^62 - 1 not rejected (clause 10.5)",
      ("if int(mag.max()) > MAX_ABS_RESIDUAL:", "if False:")),
    M("entropy.escape_limit_off_by_one", "entropy", f"{SYMBOL}:_finish_escapes",
      "escape limit off by one: |r| = 2^62 - 1 rejected", ("if int(mag.max()) > MAX_ABS_RESIDUAL:",
                                                          "if int(mag.max()) >= MAX_ABS_RESIDUAL:")),
    M("entropy.escape_parts_order", "entropy", f"{SYMBOL}:_finish_escapes",
      "escape section read as classes, then signs (instead of signs, classes, remainders)",
      ("neg = dec.decode_bits(1, ne).astype(bool)\n            k = dec.decode(ne, _class_model())",
       "k = dec.decode(ne, _class_model())\n            neg = dec.decode_bits(1, ne).astype(bool)")),
    M("entropy.no_exhaustion_check", "entropy", f"{SYMBOL}:decode_symbols",
      "a chunk with words left over is accepted (clause 10.6.5)", ("    dec.check_exhausted()\n", "    pass\n")),
    M("entropy.no_mask_exhaustion_check", "entropy", f"{ATTR}:decode_mask_chunk",
      "a mask chunk with words left over is accepted (clause 10.6.5)", ("    dec.check_exhausted()", "    pass")),
    M("entropy.levels_descending", "entropy", f"{SYMBOL}:_decode_residuals_by_level",
      "level groups decoded from level 63 down",
      ("for i in np.flatnonzero(counts):", "for i in np.flatnonzero(counts)[::-1]:")),
    M("entropy.levels_descending_by_column", "entropy", f"{SYMBOL}:_decode_bins_by_column",
      "level groups of a per-channel prior decoded from level 63 down",
      ("for i in np.unique(row_levels):", "for i in np.unique(row_levels)[::-1]:")),
    M("entropy.remainder_width", "entropy", f"{SYMBOL}:_finish_escapes",
      "escape remainders of k bits instead of k - 1", ("width = np.maximum(k - 1, 0)", "width = np.maximum(k, 0)")),
    M("entropy.model_weights", "entropy", f"{RANGE}:exact_model",
      "frequencies used as constriction weights without the unit each symbol gets (f instead of f - 1)",
      ("Categorical((f - 1).astype(np.float64), perfect=False)", "Categorical(f.astype(np.float64), perfect=False)")),
    M("entropy.binary_weights", "entropy", f"{RANGE}:binary_weights",
      "binary models' frequencies used as constriction weights without the unit each symbol gets",
      ("w[:, 0] = TOTAL_FREQUENCY - 1 - f\n    w[:, 1] = f - 1", "w[:, 0] = TOTAL_FREQUENCY - f\n    w[:, 1] = f")),
    M("entropy.raw_pieces_msb_first", "entropy", f"{RANGE}:RangeDecoder.decode_bits",
      "raw values reassembled with the first 16-bit piece as the most significant",
      ("out[sel] |= piece << np.uint64(shift)",
       "out[sel] |= piece << np.uint64(max(int(nb[sel].max()) - shift - 16, 0))")),
    M("entropy.raw_piece_width", "entropy", f"{RANGE}:RangeDecoder.decode_bits",
      "raw bits in pieces of 15 bits", ("width = np.minimum(nb[sel] - shift, MAX_UNIFORM_BITS)",
                                         "width = np.minimum(nb[sel] - shift, MAX_UNIFORM_BITS - 1)")),
    M("entropy.no_word_alignment_check", "entropy", f"{RANGE}:RangeDecoder.__init__",
      "a chunk whose length is not a multiple of 4 is read (the tail ignored)",
      ("if len(data) % 4:", "if False:"), ("words = np.frombuffer(data, dtype=\"<u4\")",
                                          "words = np.frombuffer(data[:len(data) // 4 * 4], dtype=\"<u4\")")),
    M("entropy.half_words_ok", "entropy", f"{RANGE}:RangeDecoder.__init__",
      "a chunk of whole 16-bit words is read (its last two bytes ignored; E35 checked on 2-byte words)",
      ("if len(data) % 4:", "if len(data) % 2:"), ("words = np.frombuffer(data, dtype=\"<u4\")",
                                                   "words = np.frombuffer(data[:len(data) // 4 * 4], dtype=\"<u4\")")),
    M("entropy.decode_error_unreported", "entropy", f"{RANGE}:RangeDecoder.decode",
      "a range-decoder error (q >= 2^24) is not turned into a stream error",
      ("    except Exception as e:\n        raise BitstreamError", "    except ZeroDivisionError as e:\n        raise BitstreamError")),
    *[M(f"entropy.table_level_{i}", "entropy", f"{SYMBOL}:_level_model",
        f"scale table of level {i}: one unit moved from the escape bin to r = 0",
        ("m = _LEVEL_MODELS[i] = exact_model(TABLES.level(i))",
         f"m = _LEVEL_MODELS[i] = exact_model(TABLES.level(i) + np.where(i == {i}, np.bincount([HALF_WIDTHS[i]], "
         "minlength=TABLES.level(i).size) - np.bincount([2 * HALF_WIDTHS[i] + 1], minlength=TABLES.level(i).size), 0))"))
      for i in range(64)],
    M("entropy.class_table", "entropy", f"{SYMBOL}:_class_model",
      "escape class table: one unit moved from class 0 to class 1",
      ("_CLASS_MODEL = exact_model(TABLES.escape_class_freqs)",
       "_CLASS_MODEL = exact_model(TABLES.escape_class_freqs + np.bincount([1], minlength=63) "
       "- np.bincount([0], minlength=63))")),

    # --- geometry (clause 9, geometry.md)
    M("geometry.kt_rounded", "geometry", f"{GEOM}:binary_frequency",
      "KT estimate rounded to nearest instead of floored",
      ("f1 = ((2 * n1 + 1) * TOTAL_FREQUENCY) // (2 * (n0 + n1) + 2)",
       "f1 = ((2 * n1 + 1) * TOTAL_FREQUENCY + (n0 + n1 + 1)) // (2 * (n0 + n1) + 2)")),
    M("geometry.halve_down", "geometry", f"{GEOM}:limit_counts",
      "count halving rounds down ((n + 1) >> 1 as n >> 1)", ("table[big] = (table[big] + 1) >> 1",
                                                              "table[big] = table[big] >> 1")),
    M("geometry.limit_inclusive", "geometry", f"{GEOM}:limit_counts",
      "counts halved when n0 + n1 >= limit (not > limit)", ("big = table[:, 0] + table[:, 1] > limit",
                                                             "big = table[:, 0] + table[:, 1] >= limit")),
    M("geometry.count_limit_1023", "geometry", f"{GEOM}:COUNT_LIMIT", "count limit 1023 instead of 1024",
      value="v - 1"),
    M("geometry.level_count_limit_63", "geometry", f"{GEOM}:LEVEL_COUNT_LIMIT",
      "per-depth count limit 63 instead of 64", value="v - 1"),
    M("geometry.chunk_log2_7", "geometry", f"{GEOM}:CHUNK_LOG2", "first adaptation chunk of 128 decisions",
      value="v - 1"),
    M("geometry.chunks_linear", "geometry", f"{GEOM}:chunk_bounds", "adaptation chunks of constant size 256",
      ("size *= 2", "size += 1 << CHUNK_LOG2")),
    M("geometry.contexts_descending", "geometry", f"{GEOM}:_SymbolIO._binary_chunk",
      "a chunk's context groups decoded in decreasing context order",
      ("order = np.argsort(ctx.astype(np.uint16) if table.shape[0] <= 1 << 16 else ctx, kind=\"stable\")",
       "order = np.argsort(-ctx, kind=\"stable\")")),
    M("geometry.before_cap_2", "geometry", f"{GEOM}:_code_occupancy",
      "occupancy context counts at most 2 earlier siblings (min(before, 2))",
      ("ctx = ((axes * 4 + np.minimum(before, 3)) * 4 + dens)", "ctx = ((axes * 4 + np.minimum(before, 2)) * 4 + dens)")),
    M("geometry.no_inferred_last", "geometry", f"{GEOM}:_code_occupancy",
      "the last child is coded even when no earlier child is occupied (not inferred)",
      ("        if k == last:\n", "        if False:\n")),
    M("geometry.dens_bucket", "geometry", f"{GEOM}:DENS_BUCKET", "density bucket of 2 face neighbours is 1, not 2",
      value="__import__('numpy').array([0, 1, 1, 1, 2, 3, 3])"),
    M("geometry.neighbour_term_missing", "geometry", f"{GEOM}:_code_occupancy",
      "axis state without the neighbour's child (s_a = own sibling bit only)",
      ("axes = axes * 3 + s + o", "axes = axes * 3 + s")),
    M("geometry.split_rule", "geometry", f"{GEOM}:_code_occupancy",
      "an axis of bit depth d splits from depth D - d - 1 on (one depth early)",
      ("splits = [remaining - 1 < d for d in bit_depth]", "splits = [remaining - 1 <= d for d in bit_depth]")),
    M("geometry.neighbour_side", "geometry", f"{GEOM}:_code_occupancy",
      "axis state of a child with c_a = 0 from the neighbour at q + e_a instead of q - e_a",
      ("axes = axes * 3 + exists[2 * a]", "axes = axes * 3 + exists[2 * a + 1]")),
    M("geometry.idcm_par_sib1_lt_2", "geometry", f"{GEOM}:_idcm_eligible",
      "IDCM mode 1 eligibility par_sib1 < 2 instead of <= 2",
      ("(par_sib1 <= 2)", "(par_sib1 < 2)")),
    M("geometry.idcm_min_levels", "geometry", f"{GEOM}:_idcm_eligible",
      "IDCM needs 3 levels below the node instead of 2",
      ("remaining < MIN_IDCM_LEVELS", "remaining <= MIN_IDCM_LEVELS")),
    M("geometry.idcm_mode2_one_neighbour", "geometry", f"{GEOM}:_idcm_eligible",
      "IDCM mode 2 also for parents with one face neighbour", ("    return par_nbr == 0\n", "    return par_nbr <= 1\n")),
    M("geometry.idcm_context_swapped", "geometry", f"{GEOM}:_idcm_flag_context",
      "IDCM flag context with sib1 and par_sib1 swapped",
      ("np.minimum(sib1 - 1, 2) * 3 + np.minimum(par_sib1 - 1, 2)",
       "np.minimum(par_sib1 - 1, 2) * 3 + np.minimum(sib1 - 1, 2)")),
    M("geometry.idcm_raw_bits", "geometry", f"{GEOM}:_decode_direct_nodes",
      "IDCM low bits: R bits per axis even where the axis has fewer (d_a < R)",
      ("io.raw(min(remaining, bit_depth[a]), count=owner.size)", "io.raw(remaining, count=owner.size)")),
    M("geometry.no_idcm_count_check", "geometry", f"{GEOM}:_decode_direct_nodes",
      "direct coding may decode more than N points (G.5.2 step 3 not checked)",
      ("if num_direct + owner.size + (q.shape[0] - direct.size) > n:", "if False:")),
    M("geometry.no_duplicate_point_check", "geometry", f"{GEOM}:_decode_direct_nodes",
      "the two points of a direct node may be equal (G.5.2 step 5)", ("if same.any():", "if False:")),
    M("geometry.no_depth_count_check", "geometry", f"{GEOM}:_decode_octree",
      "more than N points at a depth not rejected (G.5.4 step 4)", ("if num_direct + num_children > n:", "if False:")),
    M("geometry.no_exhaustion_check", "geometry", f"{GEOM}:decode_geometry",
      "geometry data left over not rejected", ("    dec.check_exhausted()\n", "    pass\n")),
    M("geometry.fewer_points_ok", "geometry", f"{GEOM}:_output_points",
      "fewer than N points accepted", ("if pts.shape[0] != n:", "if pts.shape[0] > n:")),
    M("geometry.no_min_attained_check", "geometry", f"{GEOM}:_output_points",
      "decoded points need not attain the bounding-box minimum (G.5.5)",
      ("if np.any(pts.min(axis=0) != 0):", "if False:")),
    M("geometry.no_coordinate_max_check", "geometry", f"{GEOM}:_output_points",
      "decoded coordinates beyond 2^31 - 1 accepted", ("if int(coords.max()) > COORD_MAX:", "if False:")),
    M("geometry.coordinate_max_off_by_one", "geometry", f"{GEOM}:_output_points",
      "a decoded coordinate of exactly 2^31 accepted (E34 off by one)",
      ("if int(coords.max()) > COORD_MAX:", "if int(coords.max()) > COORD_MAX + 1:")),
    M("geometry.no_depth0_data_check", "geometry", f"{GEOM}:_read_geometry_header",
      "coded data after a header of bit depth 0 accepted",
      ("if max(header.geom_bit_depth) == 0 and data:", "if False:")),
    M("geometry.no_bbox_sign_check", "geometry", f"{GEOM}:_validate_header",
      "a positive bounding-box minimum of 2^31 accepted",
      ("if h.geom_bbox_min_sign_flag[a] == 0 and h.geom_bbox_min_abs[a] > COORD_MAX:", "if False:")),
    M("geometry.box_capacity_strict", "geometry", f"{GEOM}:_validate_header",
      "N = 2^(total bit depth) (a full box) rejected", ("if num_points > (1 << total_bits):",
                                                          "if num_points >= (1 << total_bits):")),
    M("geometry.no_box_capacity_check", "geometry", f"{GEOM}:_validate_header",
      "more anchors than the bounding box holds accepted", ("if num_points > (1 << total_bits):", "if False:")),
    M("geometry.morton_z_major", "geometry", f"{GEOM}:_morton21",
      "Morton order with z as the most significant axis",
      ("(_spread3(q[:, 0]) << np.uint64(2)) | (_spread3(q[:, 1]) << np.uint64(1)) | _spread3(q[:, 2])",
       "(_spread3(q[:, 2]) << np.uint64(2)) | (_spread3(q[:, 1]) << np.uint64(1)) | _spread3(q[:, 0])")),
    M("geometry.morton_wide_halves", "geometry", f"{GEOM}:_morton_perm",
      "Morton order beyond 21 bits sorts by the low bits first", ("np.lexsort((lo, hi))", "np.lexsort((hi, lo))")),

    # --- syntax ranges (clause 7; syntax_tables.md)
    M("syntax.num_anchors_max", "syntax", f"{UNITS}:SceneParameterSet.syntax",
      "num_anchors_minus1 range off by one (2^24 + 1 anchors accepted)",
      ('v.ue(self, "num_anchors_minus1", hi=MAX_POINTS - 1)', 'v.ue(self, "num_anchors_minus1", hi=MAX_POINTS)')),
    M("syntax.feature_dim_max", "syntax", f"{UNITS}:SceneParameterSet.syntax", "C = 1025 accepted",
      ('v.ue(self, "feature_dim_minus1", hi=MAX_FEATURE_DIM - 1)', 'v.ue(self, "feature_dim_minus1", hi=MAX_FEATURE_DIM)')),
    M("syntax.num_offsets_max", "syntax", f"{UNITS}:SceneParameterSet.syntax", "K = 65 accepted",
      ('v.ue(self, "num_offsets_minus1", hi=MAX_NUM_OFFSETS - 1)', 'v.ue(self, "num_offsets_minus1", hi=MAX_NUM_OFFSETS)')),
    M("syntax.coarse_voxel_scale_max", "syntax", f"{UNITS}:SceneParameterSet.syntax", "coarse voxels of 2^20 + 1 accepted",
      ('hi=MAX_COARSE_VOXEL_SCALE - 1)', 'hi=MAX_COARSE_VOXEL_SCALE)')),
    M("syntax.voxel_size_positive", "syntax", f"{UNITS}:SceneParameterSet.syntax", "voxel_size <= 0 accepted",
      ('v.f32(self, "voxel_size", positive=True)', 'v.f32(self, "voxel_size")')),
    M("syntax.step_positive", "syntax", f"{UNITS}:SceneParameterSet.syntax", "feature_step <= 0 accepted",
      ('v.f32(self, "feature_step", positive=True)', 'v.f32(self, "feature_step")')),
    M("syntax.f32_finite", "syntax", f"{SYNTAX}:_checked_f32", "a non-finite f(32) accepted",
      ('if x != x or x in (float("inf"), float("-inf")):', "if False:")),
    M("syntax.f32_infinity_ok", "syntax", f"{SYNTAX}:_checked_f32", "an infinite f(32) accepted (NaN still refused)",
      ('if x != x or x in (float("inf"), float("-inf")):', "if x != x:"),
      also=((f"{SYNTAX}:_checked_f32_value",
             (('if y != y or y in (float("inf"), float("-inf")) or (positive and not y > 0):',
               "if y != y or (positive and not y > 0):"),)),)),
    M("syntax.rows_per_chunk_range", "syntax", f"{UNITS}:AttributeUnitHeader.syntax",
      "rows_per_chunk_minus1 one above its range (num_rows_minus1 + 1) accepted",
      ('v.ue(self, "rows_per_chunk_minus1", hi=self.num_rows_minus1)',
       'v.ue(self, "rows_per_chunk_minus1", hi=self.num_rows_minus1 + 1)')),
    M("syntax.tile_scale_range", "syntax", f"{UNITS}:tile_syntax",
      "tile_scale_minus1 one above its range (2^20) accepted",
      ('v.ue(ps, "tile_scale_minus1", hi=MAX_TILE_SCALE - 1)', 'v.ue(ps, "tile_scale_minus1", hi=MAX_TILE_SCALE)')),
    M("syntax.mask_prob_zero", "syntax", f"{UNITS}:AttributeUnitHeader.syntax", "mask_live_prob = 0 accepted",
      ('lo=1, hi=(1 << MASK_PROB_BITS) - 1)', 'lo=0, hi=(1 << MASK_PROB_BITS) - 1)')),
    M("syntax.rows_per_chunk_max", "syntax", f"{UNITS}:AttributeUnitHeader.syntax",
      "rows_per_chunk_minus1 may exceed num_rows_minus1", ('v.ue(self, "rows_per_chunk_minus1", hi=self.num_rows_minus1)',
                                                           'v.ue(self, "rows_per_chunk_minus1", hi=self.num_rows_minus1 + 1)')),
    M("syntax.attribute_level_max", "syntax", f"{UNITS}:AttributeUnitHeader.syntax", "attribute_level 3 accepted",
      ('v.u(2, self, "attribute_level", hi=LEVEL_2)', 'v.u(2, self, "attribute_level")')),
    M("syntax.context_model_id_max", "syntax", f"{UNITS}:AttributeUnitHeader.syntax",
      "attribute context_model_id above 2 accepted",
      ('v.u(3, self, "context_model_id", hi=MAX_CONTEXT_MODEL_ID)', 'v.u(3, self, "context_model_id")')),
    M("syntax.num_mlps_max", "syntax", f"{UNITS}:RenderModelUnit.syntax", "5 render MLPs accepted",
      ('v.ue(self, "num_mlps", hi=MAX_MLPS)', 'v.ue(self, "num_mlps", hi=MAX_MLPS + 1)')),
    M("syntax.mlp_layers_max", "syntax", f"{UNITS}:RenderMlpHeader.syntax", "9 layers accepted",
      ('v.ue(self, "num_layers_minus1", hi=MAX_MLP_LAYERS - 1)', 'v.ue(self, "num_layers_minus1", hi=MAX_MLP_LAYERS)')),
    M("syntax.mlp_width_max", "syntax", f"{UNITS}:RenderMlpHeader.syntax", "an output width of 4097 accepted",
      ('v.ue(self, "output_dim_minus1", l, hi=MAX_MLP_WIDTH - 1)', 'v.ue(self, "output_dim_minus1", l, hi=MAX_MLP_WIDTH)')),
    M("syntax.exponent_range", "syntax", f"{UNITS}:RenderMlpHeader.syntax", "weight exponent 65 accepted",
      ('v.se(self, "weight_exponent", l, lo=-MAX_EXPONENT, hi=MAX_EXPONENT)',
       'v.se(self, "weight_exponent", l, lo=-MAX_EXPONENT - 1, hi=MAX_EXPONENT + 1)')),
    M("syntax.geom_bit_depth_max", "syntax", f"{GEOM}:GeometryHeader.syntax", "geom_bit_depth 33 accepted",
      ('v.u(6, self, "geom_bit_depth", i, hi=MAX_BIT_DEPTH)', 'v.u(6, self, "geom_bit_depth", i, hi=MAX_BIT_DEPTH + 1)')),
    M("syntax.idcm_mode_max", "syntax", f"{GEOM}:GeometryHeader.syntax", "geom_idcm_mode 3 accepted (as mode 2)",
      ('v.ue(self, "geom_idcm_mode", hi=MAX_IDCM_MODE)', 'v.ue(self, "geom_idcm_mode", hi=MAX_IDCM_MODE + 1)')),
    M("syntax.bbox_min_abs_max", "syntax", f"{GEOM}:GeometryHeader.syntax", "geom_bbox_min_abs 2^31 + 1 accepted",
      ('v.ue(self, "geom_bbox_min_abs", i, hi=1 << 31)', 'v.ue(self, "geom_bbox_min_abs", i, hi=(1 << 31) + 1)')),
    M("syntax.hash_type", "syntax", f"{UNITS}:DecodedSceneHashUnit.syntax", "hash_type 2 accepted",
      ('v.u(8, self, "hash_type", lo=HASH_TYPE_SHA256, hi=HASH_TYPE_SHA256)', 'v.u(8, self, "hash_type")')),
    M("syntax.array_ndim_max", "syntax", f"{MODEL_UNIT}:IntArrayHeader.syntax", "array_ndim 5 accepted",
      ('v.u(3, self, "array_ndim", hi=MAX_ARRAY_DIMS)', 'v.u(3, self, "array_ndim")')),
    M("syntax.array_bits_max", "syntax", f"{MODEL_UNIT}:IntArrayHeader.syntax", "63-bit context arrays accepted",
      ('v.u(6, self, "array_bits_minus1", hi=MAX_VALUE_BITS - 1)', 'v.u(6, self, "array_bits_minus1", hi=MAX_VALUE_BITS)')),
    M("syntax.model_layers_max", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "9-layer context MLPs accepted",
      ('v.ue(self, "head_num_layers_minus1", hi=MAX_MODEL_LAYERS - 1)', 'v.ue(self, "head_num_layers_minus1", hi=MAX_MODEL_LAYERS)')),
    M("syntax.model_id_zero", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "a context-model unit of model 0 accepted",
      ('lo=CONTEXT_PARENT_MLP, hi=MAX_CONTEXT_MODEL_ID)', 'lo=0, hi=MAX_CONTEXT_MODEL_ID)')),
    # the context model's hyperparameters (clause 7.2; GGConvParams' own checks of k, radius_sq, h_shift and
    # neighbour_level come after the syntax's and so cannot fail: the mistakes are made here)
    M("syntax.num_features_zero", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "num_features = 0 accepted",
      ('v.ue(self, "num_features", lo=1, hi=MAX_NUM_FEATURES)', 'v.ue(self, "num_features", hi=MAX_NUM_FEATURES)')),
    M("syntax.num_features_max", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax",
      "num_features range off by one: a model of C = 1024 features rejected",
      ('v.ue(self, "num_features", lo=1, hi=MAX_NUM_FEATURES)', 'v.ue(self, "num_features", lo=1, hi=MAX_NUM_FEATURES - 1)')),
    M("syntax.neighbour_level_unchecked", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax",
      "neighbour_level not checked (0 and 3 accepted; anything but 1 taken as 2)",
      ('v.u(2, self, "neighbour_level", lo=NEIGHBOUR_LEVELS[0], hi=NEIGHBOUR_LEVELS[-1])', 'v.u(2, self, "neighbour_level")')),
    M("syntax.k_unchecked", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "k not checked (k = 0 or k > 64 accepted)",
      ('v.ue(self, "k", lo=1, hi=MAX_K)', 'v.ue(self, "k")')),
    M("syntax.k_max_63", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "k limit off by one: k = 64 rejected",
      ('v.ue(self, "k", lo=1, hi=MAX_K)', 'v.ue(self, "k", lo=1, hi=MAX_K - 1)')),
    M("syntax.k_max_65", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "k limit off by one: k = 65 accepted",
      ('v.ue(self, "k", lo=1, hi=MAX_K)', 'v.ue(self, "k", lo=1, hi=MAX_K + 1)')),
    M("syntax.radius_sq_bits_max", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "a radius_sq of 63 bits accepted",
      ('hi=MAX_RADIUS_SQ_BITS - 1)', 'hi=MAX_RADIUS_SQ_BITS)')),
    M("syntax.radius_sq_zero", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "radius_sq = 0 accepted",
      ('self, "radius_sq", lo=1, hi=MAX_RADIUS_SQ,', 'self, "radius_sq", lo=0, hi=MAX_RADIUS_SQ,')),
    M("syntax.h_shift_unchecked", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "h_shift not checked against 40",
      ('v.u(H_SHIFT_BITS, self, "h_shift", hi=MAX_H_SHIFT)', 'v.u(H_SHIFT_BITS, self, "h_shift")')),
    M("syntax.h_shift_max_39", "syntax", f"{MODEL_UNIT}:ContextModelUnit.syntax", "h_shift limit off by one: 40 rejected",
      ('v.u(H_SHIFT_BITS, self, "h_shift", hi=MAX_H_SHIFT)', 'v.u(H_SHIFT_BITS, self, "h_shift", hi=MAX_H_SHIFT - 1)')),

    # --- context-model unit, render model (clauses 7.3.2, 7.3.7)
    M("model_unit.no_value_range_check", "model_unit", f"{MODEL_UNIT}:read_context_model_unit",
      "context-array values outside their bit width accepted",
      ("if v.size and (int(v.min()) < lo or int(v.max()) > hi):", "if False:")),
    M("model_unit.no_parameter_limit", "model_unit", f"{MODEL_UNIT}:read_context_model_unit",
      "more than 2^24 context-model values accepted", ("if sum(sizes) > MAX_CONTEXT_PARAMETERS:", "if False:")),
    M("model_unit.no_model_fit_check", "model_unit", f"{MODELS}:read_context_model",
      "a context model for another channel layout accepted",
      ("if params.num_attrs != layout.num_channels or params.num_features != layout.feature_dim:", "if False:")),
    M("render_model.exponent_sign", "render_model", f"{RENDER}:dequantize",
      "weights scaled by 2^-exponent", ("np.ldexp(q.astype(np.float32), np.int32(exponent))",
                                       "np.ldexp(q.astype(np.float32), np.int32(-exponent))")),
    M("render_model.no_weight_limit", "render_model", f"{RENDER}:read_render_model_unit",
      "render-MLP integers of magnitude 2^24 accepted", ("if q.size and np.abs(q).max() > MAX_WEIGHT_MAGNITUDE:",
                                                         "if False:")),
    M("render_model.no_duplicate_role_check", "render_model", f"{RENDER}:read_render_model_unit",
      "an MLP role given twice accepted", ("if role in roles:", "if False:")),
    M("render_model.no_parameter_limit", "render_model", f"{RENDER}:read_render_model_unit",
      "more than 2^24 render-model parameters accepted", ("if total > MAX_MODEL_PARAMETERS:", "if False:")),

    # --- container and decoding process (clauses 6, 13)
    M("container.no_magic_check", "container", f"{CONTAINER}:read_container", "a wrong magic number accepted",
      ("if header.magic != MAGIC:", "if False:")),
    M("container.no_crc_check", "container", f"{CONTAINER}:read_container", "CRC-32 not checked",
      ("if zlib.crc32(data[pos:end]) != stored:", "if False:")),
    M("container.major_version", "container", f"{CONTAINER}:read_container", "version 0.x and 2.x accepted",
      ("if header.version_major != VERSION_MAJOR:", "if False:")),
    M("container.no_reserved_check", "container", f"{CONTAINER}:read_container",
      "reserved_zero_8bits not checked", ("if header.reserved_zero_8bits != 0:", "if False:")),
    M("decode.unknown_critical_skipped", "decode", f"{DECODE}:organize_units",
      "an unknown critical unit is skipped like an ancillary one",
      ("        else:\n            raise UnsupportedStreamError(", "        elif False:\n            raise UnsupportedStreamError(")),
    M("decode.ancillary_first_ok", "decode", f"{DECODE}:organize_units",
      "an ancillary unit before the scene parameter set accepted", ("if not critical:", "if False:")),
    M("decode.no_order_check", "decode", f"{DECODE}:organize_units", "critical units in any order",
      ("if not _UNIT_ORDER.fullmatch(letters):", "if False:")),
    M("decode.attribute_count", "decode", f"{DECODE}:decode_attribute_units",
      "the number of a tile's attribute units not checked against the hierarchy and its level 2",
      ("if len(attribute_units) != len(levels):", "if False:")),
    M("decode.context_without_hierarchy", "decode", f"{DECODE}:read_context_model_unit",
      "a context-model unit without the hierarchy accepted (ignored)",
      ("    if not ps.hierarchy_enabled_flag:\n        raise BitstreamError(\"a context model unit",
       "    if False:\n        raise BitstreamError(\"a context model unit")),
    M("decode.empty_level2_two_units", "decode", f"{DECODE}:hierarchy_levels",
      "a tile with an empty level 2 expected to carry a level-2 unit anyway (version 0's rule)",
      ("+ ([(LEVEL_2, hier.level2_idx)] if hier.num_level2 else [])", "+ [(LEVEL_2, hier.level2_idx)]")),
    # --- tiles (version 1: clauses 7.3.11, 13.2)
    M("tiles.no_order_check", "tiles", f"{TILES}:check_tile_index", "tile cells in any order, or twice",
      ("if not cells[t - 1] < cells[t]:", "if False:")),
    M("tiles.no_point_count_check", "tiles", f"{TILES}:check_tile_index", "tile point counts not added up to N",
      ("if total != num_points:", "if False:")),
    M("tiles.fewer_points_ok", "tiles", f"{TILES}:check_tile_index",
      "tile point counts adding up to fewer than N accepted (E57 one-sided)",
      ("if total != num_points:", "if total > num_points:")),
    M("tiles.no_cell_check", "tiles", f"{TILES}:check_points_in_cell", "points outside their tile's cell accepted",
      ("if outside.any():", "if False:")),
    M("tiles.cell_off_by_one", "tiles", f"{TILES}:check_points_in_cell",
      "a point one voxel beyond its tile's cell accepted (E58 off by one)",
      ("outside = ((coords < lo) | (coords > hi)).any(axis=1)", "outside = ((coords < lo) | (coords > hi + 1)).any(axis=1)")),
    M("tiles.no_offset_check", "tiles", f"{DECODE}:tiles_of", "tile byte offsets and sizes not checked",
      ("if g[0].offset != pos or end - pos != index.tile_data_size[t]:", "if False:")),
    M("tiles.no_tile_count_check", "tiles", f"{DECODE}:tiles_of", "the index's tile count not compared with the tiles",
      ("if index.num_tiles != len(groups):", "if False:")),
    M("tiles.flag_not_checked", "tiles", f"{DECODE}:parse_stream",
      "tiles_enabled_flag not compared with the presence of the tile index",
      ("if (UnitType.TILE_INDEX in by_type) != bool(ps.tiles_enabled_flag):", "if False:")),
    M("tiles.several_without_index", "tiles", f"{DECODE}:organize_units", "several tiles without a tile index accepted",
      ('if "I" not in letters and letters.count("G") > 1:', "if False:")),
    # --- partial decoding (clause 13.3): which tiles a box selects (issue 35: the boxes select strict subsets)
    M("tiles.box_ignored", "tiles", f"{DECODE}:selected_tiles", "a box decode outputs every tile (the box ignored)",
      ("if box is None or tiles[0].cell is None:", "if True:"),
      kills_with=("c065_tiles_small", "c078_neighbour_prediction_tiles")),
    M("tiles.box_faces_open", "tiles", f"{TILES}:cell_intersects_box",
      "a box face on a cell face selects no cell there (open intervals, < instead of <=)",
      ("return all(a <= bh and b >= bl for", "return all(a < bh and b > bl for"),
      kills_with=("c078_neighbour_prediction_tiles", "c063_tiles_gaussians")),
    M("tiles.box_cell_ends_at_last_voxel", "tiles", f"{TILES}:cell_intersects_box",
      "a cell's high face at its last voxel ((cell + 1) * TileSize - 1) instead of the next cell's low face",
      ("whi = [float((int(c) + 1) * int(tile_size))", "whi = [float((int(c) + 1) * int(tile_size) - 1)"),
      kills_with=("c078_neighbour_prediction_tiles",)),
    M("tiles.box_cells_in_binary32", "tiles", f"{TILES}:cell_intersects_box",
      "the cell faces rounded to binary32 (single precision) instead of kept in binary64",
      ("    return all(a <= bh", "    wlo, whi = [float(np.float32(x)) for x in wlo], [float(np.float32(x)) for x in whi]\n"
       "    return all(a <= bh"),
      kills_with=("c067_tiles_at_maximum_scale",)),
    M("tiles.size_in_voxels", "tiles", f"{UNITS}:tile_size_of",
      "TileSize in voxels (tile_scale_minus1 + 1) instead of coarse voxels with the hierarchy",
      ("* (ps.coarse_voxel_scale if ps.hierarchy_enabled_flag else 1)", "* 1")),
    M("attributes.num_rows_unchecked", "attributes", f"{ATTR}:read_attribute_unit",
      "num_rows_minus1 not compared with the tile's NumRows",
      ("if h.num_rows_minus1 + 1 != num_rows:", "if False:")),
    M("tiles.ancillary_inside_tiles", "tiles", f"{DECODE}:tiles_of", "an ancillary unit inside a tile accepted",
      ("if u.offset != at:", "if False:")),
    M("decode.model_id_mismatch", "decode", f"{DECODE}:decode_attribute_units",
      "the level-2 unit's context_model_id not compared with the unit's model",
      ("if context_model is None or model_id != context_model.model_id:", "if context_model is None:")),
    M("decode.no_hash_check", "decode", f"{DECODE}:check_tile_hash", "the decoded scene hash not compared",
      ("if digest != scene_hash:", "if False:")),
    M("decode.attribute_limit", "decode", f"{DECODE}:check_level_limits", "N * M above 2^31 accepted",
      ("if n * layout.num_channels > MAX_ATTRIBUTE_VALUES:", "if False:")),

    # --- explicit-Gaussian scenes (format 0.2): gaussian_parameter_set (clause 7.3.9), the Gaussian
    # channel layout (clause 11.1), their unit order (clause 6.3) and hash (clause 12)
    M("gaussians.num_gaussians_max", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "num_gaussians_minus1 range off by one (2^24 + 1 Gaussians accepted)",
      ('v.ue(self, "num_gaussians_minus1", hi=MAX_POINTS - 1)', 'v.ue(self, "num_gaussians_minus1", hi=MAX_POINTS)')),
    M("gaussians.voxel_size_positive", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "a gaussian_parameter_set voxel_size <= 0 accepted",
      ('v.f32(self, "voxel_size", positive=True)', 'v.f32(self, "voxel_size")')),
    M("gaussians.band_step_positive", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "an sh_band_step <= 0 accepted",
      ('v.f32(self, "sh_band_step", b, positive=True)', 'v.f32(self, "sh_band_step", b)')),
    M("gaussians.coarse_voxel_scale_max", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "a gaussian_parameter_set's coarse voxels of 2^20 + 1 accepted",
      ('hi=MAX_COARSE_VOXEL_SCALE - 1)', 'hi=MAX_COARSE_VOXEL_SCALE)')),
    M("gaussians.band_steps_count", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "one sh_band_step per band including the DC band (d + 1 of them instead of d)",
      ('v.loop(self.sh_degree, "sh_degree"', 'v.loop(self.sh_degree + 1, "sh_degree"')),
    M("gaussians.steps_order", "gaussians", f"{UNITS}:GaussianParameterSet.syntax",
      "scale_step read before opacity_step",
      ('    v.f32(self, "opacity_step", positive=True)\n    v.f32(self, "scale_step", positive=True)',
       '    v.f32(self, "scale_step", positive=True)\n    v.f32(self, "opacity_step", positive=True)')),
    M("gaussians.coefficients_of_last_band", "gaussians", f"{ATTR}:GaussianLayout.sh_channels",
      "S = 2d + 1 SH coefficients per colour (those of band d) instead of (d + 1)^2",
      ("return 3 * sh_coeffs_per_channel(self.sh_degree)", "return 3 * (2 * self.sh_degree + 1)")),
    M("gaussians.colour_major", "gaussians", f"{ATTR}:GaussianLayout.split",
      "SH channels colour-major (channel c is coefficient c mod S of colour c / S) instead of coefficient-major",
      ("values[:, :self.sh_channels].reshape(n, self.sh_channels // 3, 3)",
       "values[:, :self.sh_channels].reshape(n, 3, self.sh_channels // 3).transpose(0, 2, 1)")),
    M("gaussians.band_by_channel", "gaussians", f"{ATTR}:GaussianLayout.band_of_channel",
      "SH band from the channel index, floor(sqrt(c)), instead of from the coefficient index floor(c / 3)",
      ("i = np.arange(self.sh_channels) // 3", "i = np.arange(self.sh_channels)")),
    M("gaussians.band_step_off_by_one", "gaussians", f"{ATTR}:GaussianLayout.steps",
      "band b > 0 takes sh_band_step[b] (one band up; the last band the DC step) instead of sh_band_step[b - 1]",
      ("band_steps = [gps.sh_dc_step] + list(gps.sh_band_step)",
       "band_steps = [gps.sh_dc_step] + list(gps.sh_band_step)[1:] + [gps.sh_dc_step]")),
    M("gaussians.opacity_scale_steps_swapped", "gaussians", f"{ATTR}:GaussianLayout.steps",
      "the opacity channel quantized with scale_step",
      ("s[self.opacity_channel] = np.float32(gps.opacity_step)", "s[self.opacity_channel] = np.float32(gps.scale_step)")),
    M("gaussians.rotation_xyzw", "gaussians", f"{ATTR}:GaussianLayout.split",
      "rotation channels read as (x, y, z, w) instead of (w, x, y, z)",
      ("values[:, self.rotation_start:])", "np.roll(values[:, self.rotation_start:], 1, axis=1))")),
    M("gaussians.opacity_is_feature", "gaussians", f"{ATTR}:GaussianLayout.feature_dim",
      "the opacity counted among a context model's features (C = 3S + 1 instead of 3S)",
      ("return self.sh_channels", "return self.sh_channels + 1")),
    M("gaussians.render_model_ok", "gaussians", f"{DECODE}:_UNIT_ORDER",
      "a render_model unit accepted (and ignored) in an explicit-Gaussian stream",
      value='__import__("re").compile(r"(SR?|PR?)C?I?(GA{1,2}H)+")'),
    M("gaussians.hash_field_order", "gaussians", f"{HASHING}:gaussian_scene_digest",
      "the opacities hashed before the SH coefficients (clause 12)",
      ("for arr in (scene.sh, scene.opacity, scene.log_scales, scene.rotations):",
       "for arr in (scene.opacity, scene.sh, scene.log_scales, scene.rotations):")),

    # --- cross-channel prediction (clause 11.6)
    M("prediction.ignored", "prediction", f"{ATTR}:decode_chunk_values",
      "cross-channel prediction entries parsed but not applied (q = r + mean)",
      ("    if h.channel_prediction_allowed:\n        q = prediction.reconstruct(",
       "    if False:\n        q = prediction.reconstruct(")),
    M("prediction.ties_down", "prediction", f"{ATTR}:ChannelPrediction._term",
      "prediction sum rounds ties down: (sum + 2^7 - 1) >> 8",
      ("(acc + (1 << (CHANNEL_PREDICTION_SHIFT - 1)))", "(acc + ((1 << (CHANNEL_PREDICTION_SHIFT - 1)) - 1))")),
    M("prediction.floor", "prediction", f"{ATTR}:ChannelPrediction._term",
      "prediction sum floored (no rounding offset): sum >> 8", ("(acc + (1 << (CHANNEL_PREDICTION_SHIFT - 1)))", "(acc)")),
    M("prediction.truncate", "prediction", f"{ATTR}:ChannelPrediction._term",
      "prediction sum divided by 2^8 rounding toward zero (C's /) instead of the rounding shift",
      ("return (acc + (1 << (CHANNEL_PREDICTION_SHIFT - 1))) >> CHANNEL_PREDICTION_SHIFT",
       "return np.sign(acc) * (np.abs(acc) >> CHANNEL_PREDICTION_SHIFT)")),
    M("prediction.shift_minus_one", "prediction", f"{ATTR}:ChannelPrediction._term",
      "weights in units of 2^-7 (shift 7, off by one)",
      (">> CHANNEL_PREDICTION_SHIFT", ">> (CHANNEL_PREDICTION_SHIFT - 1)")),
    M("prediction.shift_plus_one", "prediction", f"{ATTR}:ChannelPrediction._term",
      "weights in units of 2^-9 (shift 9, off by one)",
      (">> CHANNEL_PREDICTION_SHIFT", ">> (CHANNEL_PREDICTION_SHIFT + 1)")),
    M("prediction.weight_sign", "prediction", f"{ATTR}:ChannelPrediction._term",
      "pred_weight applied with the opposite sign",
      ("acc += self.weights[e] * dev[:, self.sources[e]]", "acc -= self.weights[e] * dev[:, self.sources[e]]")),
    M("prediction.source_target_swapped", "prediction", f"{ATTR}:ChannelPrediction.from_header",
      "pred_target_channel and pred_source_channel taken for each other",
      ("t = np.asarray(h.pred_target_channel, np.int64)\n    s = np.asarray(h.pred_source_channel, np.int64)",
       "t = np.asarray(h.pred_source_channel, np.int64)\n    s = np.asarray(h.pred_target_channel, np.int64)")),
    M("prediction.source_without_mean", "prediction", f"{ATTR}:ChannelPrediction.reconstruct",
      "the source's q instead of its deviation q - mean",
      ("dev[:, c] = q[:, c] - np.broadcast_to(mean, q.shape)[:, c]", "dev[:, c] = q[:, c]")),
    M("prediction.source_residual", "prediction", f"{ATTR}:ChannelPrediction.reconstruct",
      "the source's residual r (its deviation before prediction) instead of q - mean",
      ("dev[:, c] = q[:, c] - np.broadcast_to(mean, q.shape)[:, c]",
       "dev[:, c] = np.broadcast_to(r, q.shape)[:, c]")),
    M("prediction.no_source_check", "prediction", f"{ATTR}:ChannelPrediction.from_header",
      "a prediction whose source is not before its target accepted", ("if (s >= t).any():", "if False:")),
    M("prediction.no_order_check", "prediction", f"{ATTR}:ChannelPrediction.from_header",
      "prediction entries in any order accepted", ("if (np.diff(key) <= 0).any():", "if False:")),
    M("prediction.duplicates_ok", "prediction", f"{ATTR}:ChannelPrediction.from_header",
      "entries need only be non-decreasing: the same (target, source) twice accepted",
      ("if (np.diff(key) <= 0).any():", "if (np.diff(key) < 0).any():")),
    M("prediction.no_magnitude_check", "prediction", f"{ATTR}:_check_magnitude",
      "decoded values beyond 2^40 steps accepted", ("if q.size and int(np.abs(q).max()) > MAX_PREDICTED_MAGNITUDE:",
                                                   "if False:")),
    M("prediction.magnitude_off_by_one", "prediction", f"{ATTR}:_check_magnitude",
      "magnitude limit off by one: |q| = 2^40 rejected",
      ("int(np.abs(q).max()) > MAX_PREDICTED_MAGNITUDE:", "int(np.abs(q).max()) >= MAX_PREDICTED_MAGNITUDE:")),
    M("prediction.magnitude_negative_off_by_one", "prediction", f"{ATTR}:_check_magnitude",
      "the lower end of the magnitude limit off by one: q = -(2^40 + 1) accepted (E51)",
      ("if q.size and int(np.abs(q).max()) > MAX_PREDICTED_MAGNITUDE:",
       "if q.size and max(int(q.max()), -int(q.min()) - 1) > MAX_PREDICTED_MAGNITUDE:")),
    M("prediction.magnitude_positive_off_by_one", "prediction", f"{ATTR}:_check_magnitude",
      "the upper end of the magnitude limit off by one: q = 2^40 + 1 accepted (E51)",
      ("if q.size and int(np.abs(q).max()) > MAX_PREDICTED_MAGNITUDE:",
       "if q.size and max(int(q.max()) - 1, -int(q.min())) > MAX_PREDICTED_MAGNITUDE:")),
    M("prediction.check_before_prediction", "prediction", f"{ATTR}:ChannelPrediction.reconstruct",
      "|q| <= 2^40 checked on r + mean only, not on the predicted value",
      ("    if self.empty:\n        _check_magnitude(q, what)\n",
       "    _check_magnitude(q, what)\n    if self.empty:\n"),
      ("        _check_magnitude(q[:, c], what)\n", "")),
    M("prediction.weight_range", "prediction", f"{UNITS}:AttributeUnitHeader.syntax",
      "pred_weight of magnitude 2^15 + 1 accepted",
      ("lo=-MAX_CHANNEL_PREDICTION_WEIGHT, hi=MAX_CHANNEL_PREDICTION_WEIGHT)",
       "lo=-MAX_CHANNEL_PREDICTION_WEIGHT - 1, hi=MAX_CHANNEL_PREDICTION_WEIGHT + 1)")),
    M("prediction.target_max", "prediction", f"{UNITS}:AttributeUnitHeader.syntax",
      "pred_target_channel = M (beyond the last channel) accepted (and never applied)",
      ('v.ue(self, "pred_target_channel", i, lo=1, hi=m - 1)', 'v.ue(self, "pred_target_channel", i, lo=1, hi=m)')),

    # --- neighbour prediction (version 1.1: clauses 7.3.12, 11.7)
    M("neighbour.mean_floor", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the neighbours' mean without the rounding offset: floor(sum / n)",
      ("(total + den // 2) // den", "total // den")),
    M("neighbour.mean_ties_down", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the mean's ties rounded down: floor((sum + floor((n - 1) / 2)) / n)",
      ("(total + den // 2) // den", "(total + (den - 1) // 2) // den")),
    M("neighbour.mean_toward_zero", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the mean's division truncates toward zero (C integer division) instead of flooring",
      ("(total + den // 2) // den", "np.sign(total + den // 2) * (np.abs(total + den // 2) // den)")),
    M("neighbour.mean_over_k", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the mean divides by k (and rounds with floor(k / 2)) where fewer than k coarser points exist",
      ("n = valid.sum(axis=1, keepdims=True).astype(np.int64)", "n = np.full((valid.shape[0], 1), valid.shape[1], np.int64)")),
    M("neighbour.flag_ignored", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "neighbour_mean_flag ignored: every channel's mean is the neighbours'",
      ("np.where(neighbour_mean[None, :], (total + den // 2) // den, own_prior)",
       "np.where(True, (total + den // 2) // den, own_prior)")),
    M("neighbour.flag_inverted", "neighbour", f"{NEIGHBOUR}:mean_flags",
      "neighbour_mean_flag read the other way round (1: the prior mean)",
      ("return np.asarray(unit.neighbour_mean_flag, dtype=bool)", "return ~np.asarray(unit.neighbour_mean_flag, dtype=bool)")),
    M("neighbour.activity_with_empty_slots", "neighbour", f"{NEIGHBOUR}:_neighbour_sum_and_spread",
      "the activity taken over all k slots, the missing neighbours counted as 0",
      ("np.where(ok, v, -big), np.where(ok, v, big))", "np.where(ok, v, 0), np.where(ok, v, 0))")),
    M("neighbour.bucket_floor_log2", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "bucket = floor(log2(a)) (0 for a <= 1) instead of bit_length(a)",
      ("np.minimum(escape_class(spread), num_buckets - 1)", "np.minimum(np.maximum(escape_class(spread) - 1, 0), num_buckets - 1)")),
    M("neighbour.bucket_of_a_plus_1", "neighbour", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "bucket = bit_length(a + 1): a = 2^j - 1 put in the next bucket",
      ("np.minimum(escape_class(spread), num_buckets - 1)", "np.minimum(escape_class(spread + 1), num_buckets - 1)")),
    M("neighbour.bucket_level_transposed", "neighbour", f"{NEIGHBOUR}:level_table",
      "bucket_level indexed [bucket * NumChannels + c] instead of [c * B + bucket]",
      ("reshape(unit.num_channels, unit.num_buckets)", "reshape(unit.num_buckets, unit.num_channels).T")),
    M("neighbour.lod_from_row_1", "neighbour", f"{NEIGHBOUR}:lod_of_rows",
      "the LoD rule applied to i + 1 (rows numbered from 1)",
      ("i = np.arange(num_rows, dtype=np.int64)", "i = np.arange(1, num_rows + 1, dtype=np.int64)")),
    M("neighbour.lod_reversed", "neighbour", f"{NEIGHBOUR}:lod_of_rows",
      "the LoDs numbered the other way round: LoD min(ctz(i), L - 1) (the odd rows are LoD 0, row 0 the finest)",
      ("lod[i % (1 << t) == 0] = num_lods - 1 - t", "lod[i % (1 << t) == 0] = t"),
      ("lod = np.full(num_rows, num_lods - 1, dtype=np.int64)", "lod = np.zeros(num_rows, dtype=np.int64)")),
    M("neighbour.ties_by_coding_order", "neighbour", f"{NEIGHBOUR}:neighbour_graph",
      "neighbours at equal distance ordered by coding order (LoD first) instead of by row index",
      ("coarser = np.sort(np.concatenate([coarser, cur]))", "coarser = np.concatenate([coarser, cur])")),
    M("neighbour.ties_by_higher_row", "neighbour", f"{NEIGHBOUR}:neighbour_graph",
      "neighbours at equal distance ordered by the higher row index",
      ("coarser = np.sort(np.concatenate([coarser, cur]))", "coarser = np.sort(np.concatenate([coarser, cur]))[::-1]"),
      ("    coarser = rows[0]\n", "    coarser = rows[0][::-1]\n")),
    M("neighbour.same_lod_neighbours", "neighbour", f"{NEIGHBOUR}:neighbour_graph",
      "the neighbours searched among the rows of LoD <= l (the row's own LoD included, itself excluded)",
      (("        idx, valid = ball_knn(coords[coarser], k, WHOLE_EXTENT_RADIUS_SQ, query=coords[cur], exclude_self=False)\n"
        "        neighbours.append(np.where(valid, coarser[np.where(valid, idx, 0)], -1))\n"
        "        coarser = np.sort(np.concatenate([coarser, cur]))"),
       ("        coarser = np.sort(np.concatenate([coarser, cur]))\n"
        "        idx, valid = ball_knn(coords[coarser], k, WHOLE_EXTENT_RADIUS_SQ, query=coords[cur], exclude_self=True)\n"
        "        neighbours.append(np.where(valid, coarser[np.where(valid, idx, 0)], -1))"))),
    M("neighbour.k_minus1", "neighbour", f"{UNITS}:NeighbourPredictionUnit.num_neighbours",
      "k = num_neighbours_minus1 (the + 1 forgotten)",
      ("return self.num_neighbours_minus1 + 1", "return max(self.num_neighbours_minus1, 1)")),
    M("neighbour.lods_minus1", "neighbour", f"{UNITS}:NeighbourPredictionUnit.num_lods",
      "L = num_lods_minus1 (the + 1 forgotten)", ("return self.num_lods_minus1 + 1", "return max(self.num_lods_minus1, 1)")),
    M("neighbour.buckets_minus1", "neighbour", f"{UNITS}:NeighbourPredictionUnit.num_buckets",
      "B = num_buckets_minus1 in the bucket rule (the + 1 forgotten; the table keeps its size)",
      ("return self.num_buckets_minus1 + 1", "return max(self.num_buckets_minus1, 1)")),
    M("neighbour.chunks_across_lods", "neighbour", f"{UNITS}:AttributeUnitHeader.num_chunks",
      "NumChunks = ceil(NumRows / S) with LoDs (the LoDs' rows not chunked on their own)",
      ("    if not self.num_lods:\n", "    if True:\n")),
    M("neighbour.lod_sizes_floor", "neighbour", f"{UNITS}:lod_sizes_of",
      "the LoD row counts with floor instead of ceil (NumChunks from them)",
      ("sizes.append(-(-num_rows // (1 << t)) - -(-num_rows // (1 << (t + 1))))",
       "sizes.append(num_rows // (1 << t) - num_rows // (1 << (t + 1)))")),
    M("neighbour.last_chunk_full", "neighbour", f"{NEIGHBOUR}:chunk_segments",
      "the last chunk of each LoD counted as rows_per_chunk rows", ("min(rows.size, lo + rpc)", "lo + rpc")),
    M("neighbour.no_extent_check", "neighbour", f"{NEIGHBOUR}:_check_predicted_header",
      "the neighbour prediction's extent limit not checked (clause 8.1)", ("    if why:\n", "    if False:\n")),
    M("neighbour.extent_off_by_one", "neighbour", f"{NEIGHBOUR}:check_extent",
      "the extent limit off by one: an extent of exactly 1 753 413 056 rejected", ("if extent > MAX_EXTENT:", "if extent >= MAX_EXTENT:")),
    M("neighbour.no_context_model_check", "neighbour", f"{NEIGHBOUR}:_check_predicted_header",
      "an attribute unit with context_model_id 1 or 2 accepted in a stream with neighbour prediction",
      ("if h.context_model_id != CONTEXT_PER_CHANNEL_PRIOR:", "if False:")),
    M("neighbour.no_num_rows_check", "neighbour", f"{NEIGHBOUR}:_check_predicted_header",
      "num_rows_minus1 + 1 not compared with the tile's point count", ("if h.num_rows_minus1 + 1 != n:", "if False:")),
    M("neighbour.with_hierarchy", "neighbour", f"{DECODE}:read_neighbour_prediction_unit",
      "a neighbour_prediction unit accepted with hierarchy_enabled_flag 1", ("    if ps.hierarchy_enabled_flag:\n", "    if False:\n")),
    M("neighbour.unit_count", "neighbour", f"{DECODE}:decode_predicted_attribute_units",
      "a tile of a stream with neighbour prediction may have 2 attribute units (the first decoded)",
      ("    if len(attribute_units) != 1:\n", "    if False:\n")),
    M("neighbour.unit_repeated", "neighbour", f"{DECODE}:_UNIT_ORDER",
      "the neighbour_prediction unit may be repeated",
      value="__import__('re').compile(r'(SR?|PN*)C?I?(GA{1,2}H)+')"),
    M("neighbour.unit_in_anchor_stream", "neighbour", f"{DECODE}:_UNIT_ORDER",
      "a neighbour_prediction unit accepted after a scene_parameter_set",
      value="__import__('re').compile(r'(SN?R?|PN?)C?I?(GA{1,2}H)+')"),
    M("neighbour.unit_after_tile_index", "neighbour", f"{DECODE}:_UNIT_ORDER",
      "the neighbour_prediction unit accepted after the tile index",
      value="__import__('re').compile(r'(SR?|PN?)C?I?N?(GA{1,2}H)+')"),
    # --- checks of clause 8.2 that no mutation above removes (issue 35: each condition's isolated stream
    # kills the mutation that removes its check through acceptance; conformance/conditions.py)
    M("check.E1", "check", f"{CONTAINER}:read_container",
      "a stream shorter than the container header not refused up front (E1)",
      ("if len(data) < CONTAINER_HEADER_BYTES:", "if False:")),
    M("check.E4", "check", f"{CONTAINER}:read_container", "any profile_idc accepted (E4)",
      ("if header.profile_idc not in Profile._value2member_map_:", "if False:")),
    M("check.E6", "check", f"{CONTAINER}:read_container",
      "1 to 8 bytes after the last data unit ignored as padding (E6)",
      (('            raise BitstreamError(f"stream ends inside the header of data unit {len(units)} at byte {pos}", '
        'condition="E6")'), "            break")),
    M("check.E7", "check", f"{CONTAINER}:UnitHeader.syntax", "unit_type 0 accepted (E7)",
      ('v.u(8, self, "unit_type", lo=1)', 'v.u(8, self, "unit_type")')),
    M("check.E8", "check", f"{CONTAINER}:read_container",
      "a data unit extending beyond the end of the stream not refused up front (E8)",
      ("if end + UNIT_CRC_BYTES > len(data):", "if False:")),
    M("check.E12", "check", f"{DECODE}:organize_units", "a stream without a parameter set not refused up front (E12)",
      ('if "S" not in letters and "P" not in letters:', "if False:")),
    M("check.E13", "check", f"{DECODE}:organize_units",
      "a stream without a geometry, attribute or decoded_scene_hash unit not refused up front (E13)",
      ("        if _LETTER[t] not in letters:", "        if False:")),
    M("check.E17", "check", "lghcc.common.bitio:BitReader.u",
      "a structure read beyond its payload: the missing bits read as 0 (E17)",
      ("    self._need(nbits, name)\n", ""),
      ("byte = self._data[pos >> 3]", "byte = self._data[pos >> 3] if pos >> 3 < len(self._data) else 0")),
    M("check.E18", "check", "lghcc.common.bitio:BitReader.ue",
      "Exp-Golomb codes with 32 or more leading zero bits accepted (E18)",
      ("if zeros >= MAX_EXP_GOLOMB_PREFIX:", "if False:")),
    M("check.E20", "check", "lghcc.common.bitio:BitReader.byte_align", "non-zero byte_alignment() bits accepted (E20)",
      ('if pad and self.u(pad, "alignment_zero_bits") != 0:', 'if pad and self.u(pad, "alignment_zero_bits") < 0:')),
    M("check.E21", "check", f"{SYNTAX}:SyntaxStructure.from_bytes",
      "whole bytes after the last element of a unit's structure ignored (E21)",
      ("if reader.bits_left >= 8:", "if False:")),
    M("check.E40", "check", f"{MODEL_UNIT}:read_context_model_unit",
      "context-array values outside their declared width accepted, here and where GG-Conv reads its arrays (E40)",
      ("if v.size and (int(v.min()) < lo or int(v.max()) > hi):", "if False:"),
      also=((f"{GGCONV}:arrays_by_name", (("if v.size and (int(v.min()) < lo or int(v.max()) > hi):", "if False:"),)),)),
    M("check.E44", "check", f"{MODELS}:check_ggconv_extent",
      "the GG-Conv extent limit not checked, here nor in the Ball k-NN (E44)", ("if extent > MAX_EXTENT:", "if False:"),
      also=((f"{KNN}:check_extent", (("if extent > MAX_EXTENT:", "if False:"),)),)),
    M("check.E64", "check", f"{NEIGHBOUR}:_check_predicted_header",
      "the neighbour prediction's extent limit not checked, here nor in the k-NN (E64)", ("    if why:\n", "    if False:\n"),
      also=((f"{KNN}:check_extent", (("if extent > MAX_EXTENT:", "if False:"),)),)),
    M("check.E45", "check", f"{ATTR}:read_attribute_unit",
      "attribute_level not compared with the level the unit's position requires (E45)",
      ("if h.attribute_level != level:", "if False:")),
    # --- step adjustment (version 1.2, clauses 7.3.13 and 11.8)
    M("step_adjust.fixed_point_floor", "step_adjust", f"{NEIGHBOUR}:ADJUST_FIXED_POINT",
      "the fixed-point factors floor(2^12 * 2^(a/4)) instead of rounded (4870 for 4871 ...)",
      value="np.floor(4096 * 2.0 ** (np.arange(8) / 4)).astype(np.int64)"),
    M("step_adjust.level_shift_is_index", "step_adjust", f"{NEIGHBOUR}:ADJUST_LEVEL_SHIFT",
      "the prior's level lowered by a levels instead of ADJUST_LEVEL_SHIFT[a]",
      value="np.arange(8, dtype=np.int64)"),
    M("step_adjust.level_raised", "step_adjust", f"{NEIGHBOUR}:prior_level_in_steps",
      "the prior's level raised by ADJUST_LEVEL_SHIFT[a] (capped at 63) instead of lowered",
      ("np.maximum(np.asarray(level, np.int64) - ADJUST_LEVEL_SHIFT[adjust], 0)",
       "np.minimum(np.asarray(level, np.int64) + ADJUST_LEVEL_SHIFT[adjust], 63)")),
    M("step_adjust.prior_mean_floor", "step_adjust", f"{NEIGHBOUR}:prior_mean_in_steps",
      "the prior mean carried to the row's steps by a floor division instead of rounded",
      ("_round_div(prior_mean * ADJUST_FIXED_POINT[0], ADJUST_FIXED_POINT[adjust][:, None])",
       "(prior_mean * ADJUST_FIXED_POINT[0]) // ADJUST_FIXED_POINT[adjust][:, None]")),
    M("step_adjust.prior_mean_kept", "step_adjust", f"{NEIGHBOUR}:prior_mean_in_steps",
      "the prior mean used as it is in every row's steps (not carried to them)",
      ("_round_div(prior_mean * ADJUST_FIXED_POINT[0], ADJUST_FIXED_POINT[adjust][:, None])",
       "np.repeat(prior_mean, len(adjust), axis=0)")),
    M("step_adjust.neighbours_in_own_steps", "step_adjust", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the neighbours' values taken as if in the row's own steps (each neighbour's factor ignored)",
      ("ADJUST_FIXED_POINT[adjust[safe]]",
       "np.broadcast_to(ADJUST_FIXED_POINT[row_adjust][:, None], safe.shape)")),
    M("step_adjust.spread_not_rescaled", "step_adjust", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the neighbours' spread left in fixed point (not divided by the row's factor) for the bucket",
      ("        spread //= unit\n", "        pass\n")),
    M("step_adjust.mean_rounding_offset", "step_adjust", f"{NEIGHBOUR}:neighbour_means_and_buckets",
      "the neighbour mean rounded with half the neighbour count (n // 2) instead of half its divisor n * F",
      ("(total + den // 2) // den", "(total + n // 2) // den")),
    M("step_adjust.index_mean_left_out", "step_adjust", f"{NEIGHBOUR}:decode_adjust_chunk",
      "the decoded indices used without adding adjust_mean",
      ("+ h.adjust_mean", "+ 0")),
    M("step_adjust.index_range_unchecked", "step_adjust", f"{NEIGHBOUR}:decode_adjust_chunk",
      "an index above max_step_adjust accepted (E65)",
      ("if a.size and (a.min() < 0 or a.max() > step_adjust.max_step_adjust):", "if False:")),
    M("step_adjust.index_max_off_by_one", "step_adjust", f"{NEIGHBOUR}:decode_adjust_chunk",
      "an index of max_step_adjust + 1 accepted (E65 off by one)",
      ("a.max() > step_adjust.max_step_adjust):", "a.max() > step_adjust.max_step_adjust + 1):")),
    M("step_adjust.factor_off_by_one", "step_adjust", f"{ATTR}:effective_steps",
      "the step of index a taken as 2^((a + 1) / 4) for a < 7 (the table read one entry on; clauses 11.5 and 11.8)",
      ("STEP_ADJUST_FACTORS[step_adjust]", "STEP_ADJUST_FACTORS[np.minimum(step_adjust + 1, 7)]")),
    M("step_adjust.unit_repeated", "step_adjust", f"{DECODE}:_UNIT_ORDER",
      "the step_adjust unit may be repeated (E17)",
      value="__import__('re').compile(r'(SR?|P(N(Q*F?)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("step_adjust.unit_without_neighbours", "step_adjust", f"{DECODE}:_UNIT_ORDER",
      "a step_adjust unit accepted without a neighbour_prediction unit",
      value="__import__('re').compile(r'(SR?|P(N(QF?)?B?|QF?)?W?T?)C?I?(GA{1,2}H)+')"),
    # --- per-Gaussian SH degree (version 1.3, clauses 7.3.14 and 11.9)
    M("sh_degree.context_share_rounded", "sh_degree", f"{SH_DEGREE}:flag_contexts",
      "the context of a partial share rounded, 2 + (3 m + n / 2) // n, instead of floored",
      ("2 + (3 * m) // np.maximum(n, 1)", "2 + (3 * m + n // 2) // np.maximum(n, 1)")),
    M("sh_degree.context_off_by_one", "sh_degree", f"{SH_DEGREE}:flag_contexts",
      "the contexts of a partial share one lower (1 + (3 m) // n: 1, 2 or 3)",
      ("2 + (3 * m) // np.maximum(n, 1)", "1 + (3 * m) // np.maximum(n, 1)")),
    M("sh_degree.context_all_is_four", "sh_degree", f"{SH_DEGREE}:flag_contexts",
      "context 4 (not 5) when every neighbour has the band", ("np.where(m == n, 5,", "np.where(m == n, 4,")),
    M("sh_degree.neighbour_above_band", "sh_degree", f"{SH_DEGREE}:flag_contexts",
      "m counts the neighbours of degree above b instead of at least b", ("(sub >= band)", "(sub > band)")),
    M("sh_degree.lod0_context_one", "sh_degree", f"{SH_DEGREE}:flag_contexts",
      "the flags of LoD 0 coded in context 1 (no neighbour has the band) instead of 0",
      ("return np.zeros(rows.size, np.int64)", "return np.ones(rows.size, np.int64)")),
    M("sh_degree.no_half_unit", "sh_degree", f"{SH_DEGREE}:flag_weights",
      "the flag model f[1] = 4096 p + 1 instead of 4096 p + 2048",
      ("FLAG_PROB_UNIT * p + FLAG_PROB_UNIT // 2", "FLAG_PROB_UNIT * p + 1")),
    M("sh_degree.probability_is_zero", "sh_degree", f"{SH_DEGREE}:flag_weights",
      "degree_flag_prob taken as the probability of flag 0 (f[0] = 4096 p + 2048) instead of flag 1",
      ("binary_weights(f1)", "binary_weights(TOTAL_FREQUENCY - f1)")),
    M("sh_degree.probabilities_context_major", "sh_degree", f"{SH_DEGREE}:flag_weights",
      "degree_flag_prob indexed x * d + (b - 1) (context-major) instead of (b - 1) * 6 + x",
      ("binary_weights(f1).reshape(levels, NUM_DEGREE_CONTEXTS, 2)",
       "binary_weights(f1).reshape(NUM_DEGREE_CONTEXTS, levels, 2).transpose(1, 0, 2)")),
    M("sh_degree.flags_row_major", "sh_degree", f"{SH_DEGREE}:decode_flag_chunk",
      "the flags decoded row after row (each row's flags b = 1, 2, ... until a 0) instead of band by band",
      ("    for band in range(1, levels + 1):\n        if not active.size:\n            break\n"
       "        flags = dec.decode_binary_models(weights[band - 1][flag_contexts(band, nd, active)])\n"
       "        active = active[flags == 1]\n        out[active] = band\n",
       "    for r in range(num_rows):\n        for band in range(1, levels + 1):\n"
       "            flag = dec.decode_binary_models(weights[band - 1][flag_contexts(band, nd, np.array([r]))])[0]\n"
       "            if flag == 0:\n                break\n            out[r] = band\n")),
    M("sh_degree.flags_not_truncated", "sh_degree", f"{SH_DEGREE}:decode_flag_chunk",
      "a flag of every band for every row (D the highest band whose flag is 1), not only after a 1",
      ("        active = active[flags == 1]\n        out[active] = band\n", "        out[active[flags == 1]] = band\n")),
    M("sh_degree.coded_one_band_more", "sh_degree", f"{SH_DEGREE}:coded_channels",
      "the channels of band D + 1 coded too (c < 3 (D + 2)^2)", ("(c < 3 * (d + 1) ** 2)", "(c < 3 * (d + 2) ** 2)")),
    M("sh_degree.opacity_not_coded", "sh_degree", f"{SH_DEGREE}:coded_channels",
      "the opacity channel 3S counted among the SH channels a row may leave uncoded",
      ("(c >= sh_channels)", "(c > sh_channels)")),
    M("sh_degree.chunk_all_coded_if_one_full", "sh_degree", f"{NEIGHBOUR}:chunk_coded_channels",
      "a chunk with one row of degree d decoded as if every row had every band",
      ("int(row_degrees.min()) == layout.sh_degree", "int(row_degrees.max()) == layout.sh_degree")),
    M("sh_degree.uncoded_value_is_mean", "sh_degree", f"{ATTR}:ChannelPrediction.reconstruct",
      "a value not coded decodes to its mean (r = 0) instead of 0",
      ("    q = r + mean\n    if coded is not None:\n        q *= coded\n", "    q = r + mean\n")),
    M("sh_degree.uncoded_target_predicted", "sh_degree", f"{ATTR}:ChannelPrediction.reconstruct",
      "a channel not coded takes the predictions that target it (q = 0 + term instead of 0)",
      ("            if coded is not None:\n                q[:, c] *= coded[:, c]\n", "")),
    M("sh_degree.uncoded_source_contributes", "sh_degree", f"{ATTR}:ChannelPrediction.reconstruct",
      "a source not coded in the row contributes pred_weight * (0 - mean) instead of 0",
      ("        if coded is not None:\n            dev[:, c] *= coded[:, c]\n", "")),
    M("sh_degree.uncoded_in_sums_as_mean", "sh_degree", f"{NEIGHBOUR}:read_predicted_attribute_unit",
      "the values a row does not code enter its neighbours' sums as their means instead of 0",
      ("        q_all[rows] = q\n", "        q_all[rows] = q if coded is None else np.where(coded, q, p.mean)\n")),
    M("sh_degree.unit_count", "sh_degree", f"{UNITS}:ShDegreeUnit.syntax",
      "d + 1 bands of probabilities in the sh_degree unit (the DC band counted)",
      ("count = self.sh_degree * NUM_DEGREE_CONTEXTS", "count = (self.sh_degree + 1) * NUM_DEGREE_CONTEXTS")),
    M("sh_degree.header_size_not_read", "sh_degree", f"{UNITS}:AttributeUnitHeader.syntax",
      "no degree_chunk_size in the attribute unit header (ShDegreePresent ignored)",
      ('v.when(self.sh_degree_present, "ShDegreePresent")', 'v.when(False, "ShDegreePresent")')),
    M("sh_degree.chunk_after_adjust_swapped", "sh_degree", f"{NEIGHBOUR}:chunk_piece_sizes",
      "a chunk's SH-degree data before its step-adjustment data (the sizes and the data in that order)",
      ("[h.adjust_chunk_size] * bool(h.step_adjust_present) + [h.degree_chunk_size] * bool(h.sh_degree_present)",
       "[h.degree_chunk_size] * bool(h.sh_degree_present) + [h.adjust_chunk_size] * bool(h.step_adjust_present)")),
    M("sh_degree.unit_repeated", "sh_degree", f"{DECODE}:_UNIT_ORDER",
      "the sh_degree unit may be repeated", value="__import__('re').compile(r'(SR?|P(N(QF?)?B*)?W?T?)C?I?(GA{1,2}H)+')"),
    M("sh_degree.unit_without_neighbours", "sh_degree", f"{DECODE}:_UNIT_ORDER",
      "an sh_degree unit accepted without a neighbour_prediction unit",
      value="__import__('re').compile(r'(SR?|P(N(QF?)?B?|B)?W?T?)C?I?(GA{1,2}H)+')"),
    M("sh_degree.unit_before_step_adjust", "sh_degree", f"{DECODE}:_UNIT_ORDER",
      "the sh_degree unit expected before the step_adjust unit", value="__import__('re').compile(r'(SR?|P(NB?(QF?)?)?W?T?)C?I?(GA{1,2}H)+')"),
    # --- rotations as a length index and x, y, z (version 1.4, clauses 7.3.15 and 11.10)
    M("rotation_length.index_range_unchecked", "rotation_length", f"{ATTR}:check_rotation_length_index",
      "a length index above max_rotation_length_index (or below 0) accepted (E66)",
      ("if k.size and (int(k.min()) < 0 or int(k.max()) > max_index):", "if False:")),
    # --- step-adjustment indices as flags (version 1.5, clauses 7.3.16 and 11.8; the flags' decoding is
    # the SH degrees', whose mutations above cover it for both tools)
    M("step_adjust_flags.header_unchecked", "step_adjust_flags", f"{NEIGHBOUR}:_check_predicted_header",
      "adjust_mean and adjust_level other than 0 accepted beside a step_adjust_flags unit (E67)",
      ("    if step_flags is not None:\n        check_flag_header(h, what)\n", "")),
    M("step_adjust_flags.adjust_level_unchecked", "step_adjust_flags", f"{NEIGHBOUR}:check_flag_header",
      "adjust_level other than 0 accepted beside a step_adjust_flags unit (E67's second field unchecked)",
      ("if h.adjust_mean or h.adjust_level:", "if h.adjust_mean:")),
    M("step_adjust_flags.unit_repeated", "step_adjust_flags", f"{DECODE}:_UNIT_ORDER",
      "the step_adjust_flags unit may be repeated", value="__import__('re').compile(r'(SR?|P(N(QF*)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("step_adjust_flags.unit_without_step_adjust", "step_adjust_flags", f"{DECODE}:_UNIT_ORDER",
      "a step_adjust_flags unit accepted without a step_adjust unit",
      value="__import__('re').compile(r'(SR?|P(N(Q?F?)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("step_adjust_flags.unit_after_sh_degree", "step_adjust_flags", f"{DECODE}:_UNIT_ORDER",
      "the step_adjust_flags unit expected after the sh_degree unit",
      value="__import__('re').compile(r'(SR?|P(N(QB?F?|B)?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("step_adjust_flags.no_neighbour_context", "step_adjust_flags", f"{NEIGHBOUR}:decode_adjust_chunk",
      "every flag in context 0 (as in LoD 0) instead of the share of the row's neighbours with an index of at least b",
      ("return decode_flag_chunk(piece, num_rows, nd,", "return decode_flag_chunk(piece, num_rows, None,")),
    M("step_adjust_flags.one_level_fewer", "step_adjust_flags", f"{NEIGHBOUR}:decode_adjust_chunk",
      "the flags stop at b = max_step_adjust - 1 (the largest index never coded)",
      ("num_rows, nd, flags.max_step_adjust,", "num_rows, nd, flags.max_step_adjust - 1,")),
    M("step_adjust_flags.symbols_kept", "step_adjust_flags", f"{NEIGHBOUR}:decode_adjust_chunk",
      "the indices decoded as symbols (version 1.2) whatever the step_adjust_flags unit says",
      ("    if flags is not None:\n        return decode_flag_chunk(", "    if False:\n        return decode_flag_chunk(")),
    M("rotation_length.binary32", "rotation_length", f"{ATTR}:implied_w",
      "w computed in binary32 instead of binary64",
      ("xyz[:, a].astype(np.float64)", "xyz[:, a]"), ("np.asarray(ROTATION_LENGTH_SQ)[k]", "np.asarray(ROTATION_LENGTH_SQ, np.float32)[k]")),
    M("rotation_length.sum_order", "rotation_length", f"{ATTR}:implied_w",
      "the squares summed as x*x + (y*y + z*z) instead of (x*x + y*y) + z*z",
      ("((x * x + y * y) + z * z)", "(x * x + (y * y + z * z))")),
    M("rotation_length.length_off_by_one", "rotation_length", f"{ATTR}:implied_w",
      "the squared length of index k taken as 2^-(k + 1)", ("ROTATION_LENGTH_SQ)[k]", "ROTATION_LENGTH_SQ)[k + 1]")),
    M("rotation_length.length_not_squared", "rotation_length", f"{ATTR}:implied_w",
      "the length 2^(-k/2) used where its square 2^-k belongs", ("np.asarray(ROTATION_LENGTH_SQ)[k]",
                                                                 "np.sqrt(np.asarray(ROTATION_LENGTH_SQ)[k])")),
    M("rotation_length.no_clamp", "rotation_length", f"{ATTR}:implied_w",
      "a negative 2^-k - |v|^2 taken by its magnitude instead of max(0, ...)", ("np.maximum(t, 0.0)", "np.abs(t)")),
    M("rotation_length.w_not_implied", "rotation_length", f"{ATTR}:reconstruct_rotations",
      "channel w reconstructed as float32(k) * step, as without the unit", ("    values[:, w] = implied_w(", "    _ = (")),
    M("rotation_length.w_from_index_value", "rotation_length", f"{ATTR}:reconstruct_rotations",
      "the implied w from 2^-k less the squares of channels w, x, y (one channel early)",
      ("values[:, w + 1:w + 4]", "values[:, w:w + 3]")),
    M("rotation_length.unit_repeated", "rotation_length", f"{DECODE}:_UNIT_ORDER",
      "the rotation_length unit may be repeated", value="__import__('re').compile(r'(SR?|P(N(QF?)?B?)?W*T?)C?I?(GA{1,2}H)+')"),
    M("rotation_length.unit_before_neighbours", "rotation_length", f"{DECODE}:_UNIT_ORDER",
      "the rotation_length unit accepted before the neighbour_prediction unit",
      value="__import__('re').compile(r'(SR?|PW?(N(QF?)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("rotation_length.unit_in_anchor_stream", "rotation_length", f"{DECODE}:_UNIT_ORDER",
      "a rotation_length unit accepted in an anchor stream",
      value="__import__('re').compile(r'(SW?R?|P(N(QF?)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
    M("rotation_length.unit_width", "rotation_length", f"{UNITS}:RotationLengthUnit.syntax",
      "max_rotation_length_index read as u(3)", ("v.u(ROTATION_LENGTH_BITS,", "v.u(3,")),
    # --- the SH rest as transform coefficients (version 1.6, clauses 7.3.17 and 11.11)
    M("sh_transform.no_magnitude_check", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "an inverse transform beyond 2^40 accepted (E68)",
      ("if v.size and int(np.abs(v).max()) > MAX_PREDICTED_MAGNITUDE:", "if False:")),
    M("sh_transform.no_rounding_offset", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "the shift without its rounding offset (floor instead of round)",
      ("v = (u + ((1 << transform.shift) >> 1)) >> transform.shift", "v = u >> transform.shift")),
    M("sh_transform.ties_down", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "ties rounded towards minus infinity (offset 2^(R-1) - 1)",
      ("v = (u + ((1 << transform.shift) >> 1)) >> transform.shift",
       "v = (u + max(((1 << transform.shift) >> 1) - 1, 0)) >> transform.shift")),
    M("sh_transform.towards_zero", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "the shift of a negative sum towards zero instead of the floor",
      ("v = (u + ((1 << transform.shift) >> 1)) >> transform.shift",
       "w = u + ((1 << transform.shift) >> 1); v = np.sign(w) * (np.abs(w) >> transform.shift)")),
    M("sh_transform.transposed", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "T[k][j] in place of T[j][k] (the matrix read column-major)",
      ("exact_matmul(q[:, SH_REST_START:end], transform.array.T)",
       "exact_matmul(q[:, SH_REST_START:end], transform.array)")),
    M("sh_transform.binary32_sum", "sh_transform", f"{ATTR}:inverse_sh_transform",
      "the sums of products in binary32 instead of integers",
      ("u = exact_matmul(q[:, SH_REST_START:end], transform.array.T)",
       "u = (q[:, SH_REST_START:end].astype(np.float32) @ transform.array.T.astype(np.float32)).astype(np.int64)")),
    M("sh_transform.from_dc", "sh_transform", f"{ATTR}:SH_REST_START",
      "the transform applied from channel 0 (the DC term) on", value="0"),
    M("sh_transform.entries_unsigned", "sh_transform", f"{ATTR}:ShTransform.from_unit",
      "the entries read without their offset 2^(B-1)", ("int(c) - offset", "int(c)")),
    M("sh_transform.not_applied", "sh_transform", f"{ATTR}:reconstruct_chunk",
      "the coefficients reconstructed as the values (the transform ignored)",
      ("values_q = q if layout is None else inverse_sh_transform(", "values_q = q if True else inverse_sh_transform(")),
    M("sh_transform.shift_width", "sh_transform", f"{UNITS}:ShTransformUnit.syntax",
      "sh_transform_shift read as u(4)", ("v.u(SH_TRANSFORM_SHIFT_BITS,", "v.u(4,")),
    M("sh_transform.unit_repeated", "sh_transform", f"{DECODE}:_UNIT_ORDER",
      "the sh_transform unit may be repeated", value="__import__('re').compile(r'(SR?|P(N(QF?)?B?)?W?T*)C?I?(GA{1,2}H)+')"),
    M("sh_transform.unit_before_rotation_length", "sh_transform", f"{DECODE}:_UNIT_ORDER",
      "the sh_transform unit accepted before the rotation_length unit",
      value="__import__('re').compile(r'(SR?|P(N(QF?)?B?)?(W?T?|TW))C?I?(GA{1,2}H)+')"),
    M("sh_transform.unit_in_anchor_stream", "sh_transform", f"{DECODE}:_UNIT_ORDER",
      "an sh_transform unit accepted in an anchor stream",
      value="__import__('re').compile(r'(ST?R?|P(N(QF?)?B?)?W?T?)C?I?(GA{1,2}H)+')"),
]


# --- applying one mutation ------------------------------------------------------------------------

class StaleMutation(Exception):
    """The mutation's target or find text is not in the code any more (rewrite the entry)."""


def _resolve(target: str):
    module_name, _, qual = target.partition(":")
    module = importlib.import_module(module_name)
    owner, obj = module, module
    for part in qual.split("."):
        owner = obj
        if not hasattr(obj, part):
            raise StaleMutation(f"{target}: no {part!r} in {getattr(owner, '__name__', owner)}")
        obj = getattr(obj, part)
    return module, owner, qual.split(".")[-1], obj


def _holders(obj) -> list[tuple[object, str]]:
    """Every module attribute holding ``obj`` (a function imported by name elsewhere)."""
    out = []
    for m in list(sys.modules.values()):
        if getattr(m, "__name__", "").startswith("lghcc."):
            for name, v in list(vars(m).items()):
                if v is obj:
                    out.append((m, name))
    return out


def mutated_source(mutation: Mutation) -> str:
    """The target's source with the edits applied; StaleMutation when one does not match once."""
    _, _, _, obj = _resolve(mutation.target)
    if isinstance(obj, property):
        obj = obj.fget
    func = inspect.unwrap(obj.__func__ if isinstance(obj, (classmethod, staticmethod)) else obj)
    src = textwrap.dedent(inspect.getsource(func))
    for find, replace in mutation.edits:
        n = src.count(find)
        if n != 1:
            raise StaleMutation(f"{mutation.id}: {'not found' if n == 0 else f'found {n} times'} in "
                                f"{mutation.target}: {find[:60]!r}")
        src = src.replace(find, replace)
    return src


def apply(mutation: Mutation) -> None:
    """Patch the running decoder (for good: run it in a child process). Caches built from the
    patched code are cleared (frequency models, binary models)."""
    for target, edits in mutation.also:  # the second check of the same rule goes too
        apply(Mutation(mutation.id, mutation.group, target, mutation.description, tuple(edits)))
    module, owner, name, obj = _resolve(mutation.target)
    if mutation.value is not None:
        new = eval(mutation.value, {"v": obj, "np": __import__("numpy")})  # noqa: S307 - our own list
        for holder, attr in [(module, name)] + [(m, a) for m, a in _holders(obj) if a == name]:
            setattr(holder, attr, new)
    else:
        src = mutated_source(mutation)
        ns: dict = {}
        exec(compile(src, f"<mutation {mutation.id}>", "exec"), vars(module), ns)  # noqa: S102
        new = ns[name]
        if isinstance(owner, type):
            if isinstance(obj, property) and not isinstance(new, property):  # its source without @property
                new = property(new)
            setattr(owner, name, new)
        else:
            for holder, attr in [(module, name)] + _holders(obj):
                setattr(holder, attr, new)
    _clear_caches()


def _clear_caches() -> None:
    from ..common.entropy import symbol_coder

    symbol_coder._LEVEL_MODELS[:] = [None] * len(symbol_coder._LEVEL_MODELS)
    symbol_coder._CLASS_MODEL = None
