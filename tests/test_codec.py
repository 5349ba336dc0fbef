"""End-to-end: encode, decode, compare bit for bit; hard cases; determinism."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from lghcc.common.errors import InputError
from lghcc.common.geometry import normative_order
from lghcc.common.hashing import scene_digest
from lghcc.formats.procedural import make_procedural_scene
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.stream.config import EncoderConfig, load_config
from lghcc.encoder.stream.encode import encode_scene
from lghcc.encoder.anchors.scene_prep import merge_duplicate_anchors

from scenes import random_scene, scenes


def assert_same_scene(a, b):
    assert np.array_equal(a.coords, b.coords)
    for name in ("features", "scalings", "offsets"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    assert (a.offset_mask is None) == (b.offset_mask is None)
    if a.offset_mask is not None:
        assert np.array_equal(a.offset_mask, b.offset_mask)
    assert a.mlps.keys() == b.mlps.keys()
    for role in a.mlps:
        for x, y in zip(a.mlps[role].weights + a.mlps[role].biases, b.mlps[role].weights + b.mlps[role].biases):
            assert x.tobytes() == y.tobytes()
    assert scene_digest(a) == scene_digest(b)


def test_procedural_round_trip_and_quantization_error():
    scene = make_procedural_scene(3000, seed=1)
    cfg = load_config("medium")
    res = encode_scene(scene, cfg, measure_ideal=True)
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)
    assert dec.breakdown.total_bytes == len(res.data)
    # The decoded scene is the input, reordered, within half a step.
    order = np.lexsort(scene.coords.T[::-1])
    dorder = np.lexsort(dec.scene.coords.T[::-1])
    assert np.array_equal(scene.coords[order], dec.scene.coords[dorder])
    err = np.abs(scene.features[order] - dec.scene.features[dorder]).max()
    assert err <= cfg.feature_step / 2 * (1 + 1e-5)
    # Attribute coding is within 0.1% of the model's own ideal code length.
    assert res.stats.attribute_coded_bits <= res.stats.attribute_ideal_bits * 1.001 + 64 * 32


HARD_CASES = ("random", "one_anchor", "one_coarse_voxel", "far_coordinates", "constant_features", "escape")


@st.composite
def hard_cases(draw):
    """(scene, hierarchy, coarse voxel scale, case): the scenes() strategy (sizes, spreads up to 2^30,
    value scales up to 1e6, voxel sizes 1e-30 .. 1e30, masks, with and without MLPs) turned into
    each hard case in turn."""
    case = draw(st.sampled_from(HARD_CASES))
    scene = draw(scenes())
    hierarchy = draw(st.booleans())
    scale = draw(st.sampled_from([1, 2, 4, 1 << 20]))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    n = scene.num_anchors

    def keep(rows):
        for name in ("coords", "features", "scalings", "offsets"):
            setattr(scene, name, getattr(scene, name)[rows])
        if scene.offset_mask is not None:
            scene.offset_mask = scene.offset_mask[rows]

    if case == "one_anchor":
        keep(slice(0, 1))
    elif case == "one_coarse_voxel":  # every anchor in the coarse voxel at the origin: one parent, n-1 children
        hierarchy, scale = True, draw(st.sampled_from([2, 4, 16]))
        cells = np.stack(np.meshgrid(*[np.arange(scale)] * 3, indexing="ij"), -1).reshape(-1, 3)
        rows = min(n, len(cells))
        keep(slice(0, rows))
        scene.coords = cells[rng.permutation(len(cells))[:rows]].astype(np.int64)
    elif case == "far_coordinates":
        scene.coords = np.clip(scene.coords, -10 ** 6, 10 ** 6)
        scene.coords[0] = (10 ** 6, 10 ** 6, 10 ** 6)
        if n > 1:
            scene.coords[1] = (-10 ** 6, -10 ** 6, -10 ** 6)
        _, first = np.unique(scene.coords, axis=0, return_index=True)
        keep(np.sort(first))
    elif case == "constant_features":
        scene.features[:] = draw(st.sampled_from([0.0, 1.0, -7.5, 123.25]))
    elif case == "escape":  # values 10^4 to 10^6 steps from any prior mean: past every table (|r| <= 4096)
        if n == 1:  # a second anchor, so that no prior mean can sit on every value
            scene.coords = np.concatenate([scene.coords, scene.coords + [1, 0, 0]])
            for name in ("features", "scalings", "offsets"):
                setattr(scene, name, np.concatenate([getattr(scene, name)] * 2))
            if scene.offset_mask is not None:
                scene.offset_mask = np.concatenate([scene.offset_mask] * 2)
        big = rng.choice([-1, 1], size=scene.features.shape) * 10.0 ** rng.uniform(2, 4, scene.features.shape)
        scene.features[:] = big.astype(np.float32)
        scene.features[0], scene.features[1] = np.float32(1e4), np.float32(-1e4)  # +-10^6 steps of 0.01
        scene.offsets[0, 0, :], scene.offsets[1, 0, :] = np.float32(2.5e3), np.float32(-2.5e3)
    return scene, hierarchy, scale, case


CONTEXT_MODELS = {  # level-2 coding options, with fits short enough for a property test
    "per_channel": {},
    "parent_mlp": dict(context_model="parent_mlp", context_float_steps=4, context_qat_steps=0),
    "ggconv_level1": dict(context_model="ggconv", context_neighbour_level=1, context_k=3, context_float_steps=4,
                          context_qat_steps=2),
    "ggconv_level2": dict(context_model="ggconv", context_neighbour_level=2, context_k=3, context_float_steps=4,
                          context_qat_steps=2),
}


def quantized(x: np.ndarray, step: float) -> np.ndarray:
    """What the decoder shall output for input x: float32(rint(x / step)) * step in binary32, with
    step the binary32 value the stream carries."""
    s = np.float32(step)
    q = np.rint(x.astype(np.float64) / np.float64(s)).astype(np.int64)  # integers: -0.0 becomes 0
    return q.astype(np.float32) * s


@settings(max_examples=60, deadline=None)
@given(hard_cases(), st.sampled_from(sorted(CONTEXT_MODELS)))
def test_round_trip_hard_cases(case, context):
    """Every hard case, coded with each level-2 model (a context model forces the hierarchy on and
    is always written), decodes bit-exactly to the quantized input."""
    scene, hierarchy, scale, kind = case
    over = dict(CONTEXT_MODELS[context], context_fallback=False)
    if context != "per_channel":
        hierarchy, scale = True, min(scale, 16)
    cfg = EncoderConfig(feature_step=0.01, scaling_step=0.1, offset_step=0.05, rows_per_chunk=7,
                        hierarchy=hierarchy, coarse_voxel_scale=scale, **over)
    with np.errstate(over="ignore", invalid="ignore"):
        representable = np.isfinite(scene.positions()).all()
    if not representable:  # e.g. voxel size 1e30 at coordinates 2^30: world positions overflow binary32
        with pytest.raises(InputError, match="overflow"):
            encode_scene(scene, cfg)
        return
    res = encode_scene(scene, cfg)
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)
    out = dec.scene
    # Against the input, not the encoder's own prediction.
    assert out.num_anchors == scene.num_anchors
    order = normative_order(scene.coords)
    assert np.array_equal(out.coords, scene.coords[order])  # the input's anchors, in normative order
    assert np.array_equal(np.unique(out.coords, axis=0), np.unique(scene.coords, axis=0))
    assert out.voxel_size == float(np.float32(scene.voxel_size))
    assert out.origin.tobytes() == np.asarray(scene.origin, np.float32).tobytes()
    live = np.ones((scene.num_anchors, scene.num_offsets), bool) if scene.offset_mask is None else scene.offset_mask
    live = live[order]
    out_live = np.ones_like(live) if out.offset_mask is None else out.offset_mask
    assert np.array_equal(out_live, live)
    ins = (scene.features[order], scene.scalings[order], np.where(live[:, :, None], scene.offsets[order], 0))
    outs = (out.features, out.scalings, out.offsets)
    steps = (cfg.feature_step, cfg.scaling_step, cfg.offset_step)
    if 2 not in res.stats.levels or res.stats.levels[2].context_model == "per-channel prior":
        for x, y, step in zip(ins, outs, steps):  # exactly float32(rint(x / step)) * step
            want = quantized(x, step)
            assert y.tobytes() == np.where(np.asarray(x) == 0, np.float32(0), want).astype(np.float32).tobytes()
        if kind == "constant_features":
            assert (out.features == out.features[0, 0]).all()
    else:  # a context model may code a value with a coarser step (step_adjust a: factor 2^(a/4) <= 2^(7/4))
        for x, y, step in zip(ins, outs, steps):
            bound = 0.5 * np.float32(step) * 3.36358571 + np.abs(x).astype(np.float64) * 2.0 ** -21
            assert (np.abs(y.astype(np.float64) - x.astype(np.float64)) <= bound).all()
    assert np.array_equal(out.offsets[~live], np.zeros_like(out.offsets[~live]))


def test_hard_case_generator_covers_every_case():
    seen = {}

    @settings(max_examples=150, deadline=None, database=None, derandomize=True)  # coverage must not hang on luck
    @given(hard_cases())
    def collect(case):
        scene, hierarchy, scale, kind = case
        if kind == "one_anchor":
            assert scene.num_anchors == 1
        if kind == "one_coarse_voxel":
            assert hierarchy and (np.floor_divide(scene.coords, scale) == 0).all()
        if kind == "far_coordinates":
            assert np.abs(scene.coords).max() == 10 ** 6
        if kind == "escape":  # every feature channel spans 2 * 10^6 steps of 0.01: some residual escapes
            from lghcc.common.entropy.tables import HALF_WIDTHS
            assert (np.ptp(scene.features, axis=0) / 0.01).min() > 2 * HALF_WIDTHS.max()
        seen[kind] = seen.get(kind, 0) + 1

    collect()
    assert set(seen) == set(HARD_CASES)


def test_hierarchy_levels_and_switch_off():
    # One anchor: level 2 is empty, so the hierarchy is switched off and costs nothing.
    one = random_scene(np.random.default_rng(0), 1)
    assert encode_scene(one, EncoderConfig(hierarchy=True)).data == encode_scene(one, EncoderConfig()).data
    # 501 anchors in one coarse voxel: one level-1 parent with 500 children.
    rng = np.random.default_rng(1)
    scene = random_scene(rng, 1)
    g = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)[:501]
    scene.coords = g.astype(np.int64)
    scene.features = rng.normal(size=(501, 4)).astype(np.float32)
    scene.scalings = rng.normal(size=(501, 6)).astype(np.float32)
    scene.offsets = rng.normal(size=(501, 2, 3)).astype(np.float32)
    res = encode_scene(scene, EncoderConfig(hierarchy=True, coarse_voxel_scale=8))
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)
    assert dec.breakdown.bytes_by_category["attributes"] > 0


def test_values_far_outside_the_tables_use_the_escape_path():
    rng = np.random.default_rng(3)
    scene = random_scene(rng, 50)
    scene.features[0, 0] = 1e9
    scene.features[1, 1] = -3e10
    res = encode_scene(scene, EncoderConfig(feature_step=1e-3))
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)
    assert dec.scene.features.max() == pytest.approx(1e9, rel=1e-6)


def test_too_large_values_are_rejected_not_clipped():
    scene = random_scene(np.random.default_rng(0), 5)
    scene.features[0, 0] = 1e30
    with pytest.raises(InputError, match="beyond the coding range"):
        encode_scene(scene, EncoderConfig(feature_step=1e-6))


@pytest.mark.parametrize("field,value,message", [
    ("features", np.nan, "features contain NaN or Inf"),
    ("scalings", np.inf, "scalings contain NaN or Inf"),
    ("offsets", -np.inf, "offsets contain NaN or Inf"),
])
def test_non_finite_input_is_rejected(field, value, message):
    scene = random_scene(np.random.default_rng(0), 5)
    getattr(scene, field).flat[3] = value
    with pytest.raises(InputError, match=message):
        encode_scene(scene)


def test_empty_and_mismatched_scenes_are_rejected():
    scene = random_scene(np.random.default_rng(0), 5)
    empty = random_scene(np.random.default_rng(0), 5)
    empty.coords = empty.coords[:0]
    with pytest.raises(InputError, match="no anchors"):
        encode_scene(empty)
    scene.scalings = scene.scalings[:, :5]
    with pytest.raises(InputError, match=r"scalings must have shape \[5, 6\]"):
        encode_scene(scene)


def test_duplicates_are_rejected_and_can_be_merged():
    scene = random_scene(np.random.default_rng(0), 10, mask=True)
    scene.coords[:] = scene.coords[0]  # all anchors in one voxel
    with pytest.raises(InputError, match="share a voxel"):
        encode_scene(scene)
    merged, count = merge_duplicate_anchors(scene)
    assert count == 9 and merged.num_anchors == 1
    assert np.allclose(merged.features[0], scene.features.mean(axis=0), atol=1e-6)
    dec = decode_stream(encode_scene(merged).data)
    assert dec.scene.num_anchors == 1


def test_all_live_mask_costs_nothing():
    scene = random_scene(np.random.default_rng(5), 200)
    plain = encode_scene(scene).data
    scene.offset_mask = np.ones((scene.num_anchors, scene.num_offsets), bool)
    masked = encode_scene(scene)
    assert masked.data == plain
    assert decode_stream(masked.data).scene.offset_mask is None


def test_decoding_is_the_same_with_1_and_2_threads():
    data = encode_scene(make_procedural_scene(2000, seed=2)).data
    digests = []
    before = torch.get_num_threads()
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            digests.append(scene_digest(decode_stream(data).scene))
    finally:
        torch.set_num_threads(before)  # leave the process as it was for the tests that follow
    assert torch.get_num_threads() == before
    assert digests[0] == digests[1]


def test_encoding_is_deterministic():
    scene = make_procedural_scene(1500, seed=4, with_mask=True)
    assert encode_scene(scene).data == encode_scene(scene).data


@pytest.mark.parametrize("model", ["parent_mlp", "ggconv"])
def test_context_models_round_trip_bit_exact_across_threads(model):
    scene = make_procedural_scene(1200, seed=5, feature_dim=6, num_offsets=2, with_mask=True)
    cfg = EncoderConfig(hierarchy=True, context_model=model, context_k=4, context_float_steps=20,
                        context_qat_steps=5, context_fallback=False)
    res = encode_scene(scene, cfg)
    assert res.breakdown.bytes_by_category["model"] > 0
    assert res.stats.levels[2].context_model != "per-channel prior"
    digests = []
    before = torch.get_num_threads()
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            dec = decode_stream(res.data)
            assert_same_scene(dec.scene, res.decoded)
            digests.append(scene_digest(dec.scene))
    finally:
        torch.set_num_threads(before)
    assert digests[0] == digests[1]


@pytest.mark.parametrize("context", ["parent_mlp", "ggconv_level1", "ggconv_level2"])
def test_a_level1_anchor_with_500_children(context):
    """One coarse voxel (s = 8) holding 501 anchors: one level-1 parent, 500 level-2 children;
    every context model codes them, bit-exactly."""
    rng = np.random.default_rng(7)
    scene = make_procedural_scene(600, seed=7, feature_dim=4, num_offsets=2)
    cells = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)
    rows = np.arange(501)
    scene.coords = cells[rng.permutation(512)[:501]].astype(np.int64)
    for name in ("features", "scalings", "offsets"):
        setattr(scene, name, getattr(scene, name)[rows])
    cfg = EncoderConfig(hierarchy=True, coarse_voxel_scale=8, context_fallback=False, **CONTEXT_MODELS[context])
    res = encode_scene(scene, cfg)
    assert res.stats.num_level1 == 1 and res.stats.num_level2 == 500
    assert res.stats.levels[2].context_model != "per-channel prior"
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)


def test_context_model_that_does_not_pay_is_not_written():
    # Two level-2 anchors cannot pay for a trained network: the encoder keeps the prior.
    scene = random_scene(np.random.default_rng(2), 1)
    scene.coords = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    scene.features = np.zeros((3, 4), np.float32)
    scene.scalings = np.zeros((3, 6), np.float32)
    scene.offsets = np.zeros((3, 2, 3), np.float32)
    cfg = EncoderConfig(hierarchy=True, coarse_voxel_scale=4, context_model="parent_mlp", context_float_steps=5,
                        context_qat_steps=0)
    res = encode_scene(scene, cfg)
    assert res.stats.levels[2].context_model == "per-channel prior"
    from lghcc.common.container import UnitType, read_container
    assert all(u.unit_type != UnitType.CONTEXT_MODEL for u in read_container(res.data).units)
    assert_same_scene(decode_stream(res.data).scene, res.decoded)


def test_auto_neighbour_level_keeps_the_smaller_of_both_fits():
    scene = make_procedural_scene(900, seed=9, feature_dim=4, num_offsets=2)
    cfg = EncoderConfig(hierarchy=True, context_model="ggconv", context_neighbour_level="auto", context_k=4,
                        context_float_steps=10, context_qat_steps=2, context_fallback=False)
    res = encode_scene(scene, cfg)
    fit = res.stats.context_fit
    sizes = [fit.bytes_by_neighbour_level[lv] for lv in (1, 2)]
    assert fit.bytes_with_context == min(sizes)
    dec = decode_stream(res.data)
    assert_same_scene(dec.scene, res.decoded)
    with pytest.raises(InputError, match="context_neighbour_level"):
        EncoderConfig(context_neighbour_level=3).validate()


@pytest.mark.parametrize("model", ["parent_mlp", "ggconv"])
def test_auto_parent_base_keeps_the_smaller_of_both_fits(model):
    scene = make_procedural_scene(900, seed=10, feature_dim=4, num_offsets=2, with_mask=True)
    cfg = EncoderConfig(hierarchy=True, context_model=model, context_parent_base="auto", context_k=4,
                        context_float_steps=10, context_qat_steps=2, context_fallback=False)
    res = encode_scene(scene, cfg)
    fit = res.stats.context_fit
    sizes = {b: fit.bytes_by_parent_base[b] for b in ("choose", "parent")}
    assert fit.bytes_with_context == min(sizes.values())
    assert sizes[fit.parent_base] == min(sizes.values())
    assert_same_scene(decode_stream(res.data).scene, res.decoded)
    with pytest.raises(InputError, match="context_parent_base"):
        EncoderConfig(context_parent_base="median").validate()


def test_a_context_fit_that_diverges_falls_back_to_the_prior(monkeypatch):
    """A context model that cannot be fitted is not a failure of the encoder: level 2 keeps the
    per-channel prior and the stats say why."""
    import lghcc.encoder.context.context_fit as cf

    def diverging(*args, **kwargs):
        raise ValueError("cannot scale a tensor containing NaN or Inf")

    monkeypatch.setattr(cf, "fit_ggconv", diverging)
    scene = make_procedural_scene(600, seed=3, feature_dim=4, num_offsets=2)
    res = encode_scene(scene, EncoderConfig(hierarchy=True, context_model="ggconv", context_fallback=False))
    assert res.stats.levels[2].context_model == "per-channel prior"
    assert "diverged" in res.stats.context_fit.error
    assert_same_scene(decode_stream(res.data).scene, res.decoded)
