"""Structure-aware fuzzing (tools/fuzz_scenes.py) and mutation testing (conformance/mutations.py,
tools/mutation_test.py): short runs here; the long ones are `make fuzz-long` and `make mutations`."""

import random
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from lghcc.conformance import fuzz, mutations
from lghcc.conformance.fuzz import Mutator, Sandbox, load_seeds, run_campaign

TOOLS = Path(__file__).resolve().parents[1] / "tools"
sys.path.insert(0, str(TOOLS))

import fuzz_scenes  # noqa: E402
import mutation_test  # noqa: E402


@pytest.fixture(scope="module")
def box():
    with Sandbox(timeout=60.0, memory_mb=2048) as b:
        yield b


@pytest.mark.integration
def test_fresh_scene_streams_decode_to_their_own_hash(box):
    """25 generator draws from fixed seeds: every scene the encoder accepts decodes, in the sandbox,
    to exactly the encoded scene; a refusal is an InputError with a message; nothing else happens.
    Fixed seeds, not Hypothesis: its derandomized draws depended on what had run before in the
    process (10 valid cases instead of 22 after tests/test_geometry.py; likely its pool of constants
    from the loaded modules), so the coverage counts below failed in some test orders."""
    kinds = Counter()
    for seed in range(1000, 1025):
        case = fuzz_scenes.scene_case(random.Random(seed))
        assert not case.bug, case.bug
        if case.data is None:
            assert case.refused, case.what
            kinds["refused"] += 1
            continue
        res = fuzz.scene_outcome(box.run(case.data))
        assert res.kind == fuzz.SCENE_VALID, f"{case.what}: {res.detail}"
        kinds["valid"] += 1
        kinds["hierarchy"] += "'hierarchy': True" in case.what
        kinds["gaussians"] += case.what.startswith("Gaussians")
    # a third of the draws are explicit-Gaussian scenes (fewer anchor scenes with the hierarchy)
    assert kinds["valid"] >= 20 and kinds["hierarchy"] >= 5 and kinds["gaussians"] >= 3, kinds


@pytest.mark.integration
def test_gaussian_scenes_with_neighbour_prediction_step_adjustment_and_tiles_round_trip(box):
    """The explicit-Gaussian cases: neighbour prediction, step adjustment and several tiles; every
    stream the encoder writes decodes, in the sandbox, to its own hash."""
    kinds = Counter()
    for seed in range(10):
        case = fuzz_scenes.gaussian_scene_case(random.Random(seed))
        assert not case.bug, case.bug
        if case.data is None:
            assert case.refused, case.what
            continue
        res = fuzz.scene_outcome(box.run(case.data))
        assert res.kind == fuzz.SCENE_VALID, f"{case.what}: {res.detail}"
        kinds["valid"] += 1
        kinds["neighbour"] += "'neighbour_prediction': True" in case.what
        kinds["step_adjust"] += "'step_adjust_max': 0" not in case.what and "step_adjust_max" in case.what
        kinds["tiles"] += "tile_points" in case.what
    assert kinds["valid"] >= 6 and kinds["neighbour"] >= 4 and kinds["step_adjust"] >= 1 and kinds["tiles"] >= 3, kinds


def test_box_preview_and_worker_decodes_of_fresh_streams(box):
    """The scene cases' extra decodes (clause 13.3): a box around a tile's cell, a box meeting no
    cell, the level-1 preview (of the box too) and 2 tile workers all succeed; a box decode that
    is not the full decode's rows of its tiles is found."""
    from lghcc.common.tiles import Box
    from lghcc.decoder.decode import decode_stream

    from lghcc.conformance import STREAMS_DIR

    data = (STREAMS_DIR / "c063_tiles_gaussians" / "stream.lghcc").read_bytes()  # tiles and the hierarchy
    opts = fuzz_scenes.partial_decodes(random.Random(5), data)
    assert {tuple(sorted(o)) for o in opts} == {("box",), ("max_level",), ("box", "max_level"), ("exact_jobs", "jobs")}
    for o in opts:
        assert fuzz.scene_outcome(box.run(data, o), fuzz.SCENE_PARTIAL).kind == fuzz.SCENE_PARTIAL, o
    one = Box((0.05,) * 3, (0.1,) * 3)
    assert fuzz.partial_mismatch(data, one, decode_stream(data, box=one).scene) == ""
    assert "differ" in fuzz.partial_mismatch(data, one, decode_stream(data, box=Box((-0.1,) * 3, (-0.05,) * 3)).scene)


def test_the_generator_reaches_the_extremes():
    """Over a few hundred seeds: extents beyond GG-Conv's limit, C up to 1024, K up to 64, 3000 anchors,
    every layout, hand-built context models."""
    layouts, extents, cs, ks, ns = set(), [], [], [], []
    for seed in range(300):
        rng = random.Random(seed)
        scene, what = fuzz_scenes.random_scene(rng)
        layouts.add(what.split("(")[1].split(")")[0])
        c = scene.coords
        extents.append(int((c.max(axis=0) - c.min(axis=0)).max()))
        cs.append(scene.feature_dim)
        ks.append(scene.num_offsets)
        ns.append(scene.num_anchors)
    assert layouts == {"cloud", "cube", "line", "plane", "cluster_far", "corners", "huge_extent", "sparse_wide"}
    assert max(extents) > 1_753_413_056 and min(extents) <= 2
    assert max(cs) > 500 and min(cs) == 1 and max(ks) > 32 and max(ns) > 1000 and min(ns) == 1


def test_hand_built_models_are_valid_at_their_extremes():
    from lghcc.common.context.ggconv import GGConvParams

    seen = Counter()
    for seed in range(60):
        model_id, p = fuzz_scenes.hand_context_model(random.Random(seed), 3, 3 + 6 + 3)
        seen[model_id] += 1
        if isinstance(p, GGConvParams):
            seen["radius_max"] += p.radius_sq == (1 << 62) - 1
            seen["k_64"] += p.k == 64
    assert seen[1] and seen[2] and seen["radius_max"] and seen["k_64"]


def test_seeds_drawn_by_decode_time():
    seeds = {k: v for k, v in load_seeds().items() if k in ("c001_one_anchor", "c013_ggconv_context")}
    m = Mutator(seeds)
    m.weigh_by_time({"c001_one_anchor": 0.002, "c013_ggconv_context": 0.2})
    rng = random.Random(1)
    picks = Counter(m.case(rng)[1].split(":")[0] for _ in range(2000))
    assert picks["c013_ggconv_context"] > 0 and picks["c001_one_anchor"] > 50 * picks["c013_ggconv_context"]


def test_campaign_with_scenes_pools_fresh_streams(tmp_path):
    m = Mutator({k: v for k, v in load_seeds().items() if k == "c001_one_anchor"})
    s = run_campaign(m, seed=3, cases=40, timeout=60.0, scene_source=fuzz_scenes.scene_case, mutations_per_scene=4,
                     failures_dir=tmp_path)
    assert s.bugs == 0, s.text()
    scenes = s.outcomes[fuzz.SCENE_VALID] + s.outcomes[fuzz.SCENE_REFUSED]
    assert scenes >= 7 and len(m.ids) > 1  # fresh streams joined the seeds
    assert "most CPU" in s.text()


# --- mutation testing ---------------------------------------------------------------------------------

def test_every_mutation_applies_to_todays_code():
    import lghcc.common.context.ggconv  # noqa: F401
    import lghcc.common.context.parent_mlp  # noqa: F401
    import lghcc.decoder.decode  # noqa: F401

    ids = [m.id for m in mutations.MUTATIONS]
    assert len(ids) == len(set(ids)) >= 200
    for m in mutations.MUTATIONS:
        if m.value is None:
            src = mutations.mutated_source(m)  # StaleMutation if an edit no longer matches exactly once
            compile(src, m.id, "exec")
        else:
            mutations._resolve(m.target)
    groups = Counter(m.group for m in mutations.MUTATIONS)
    for g in ("intnn", "ggconv", "parent_mlp", "knn", "hierarchy", "attributes", "entropy", "geometry", "syntax",
              "gaussians", "prediction", "neighbour"):
        assert groups[g] >= 2, g


def test_a_stale_mutation_is_reported_not_skipped():
    m = mutations.Mutation("x", "x", "lghcc.common.intnn:rshift_round", "nothing", (("no such text", "y"),))
    with pytest.raises(mutations.StaleMutation, match="not found"):
        mutations.mutated_source(m)


@pytest.mark.parametrize("mid, killer", [
    ("entropy.escape_sign", "c004_escape_values"),
    ("ggconv.tri_ties_down", "c044_ggconv_trilinear_ties"),
    ("attributes.step_factor_7", "c047_ggconv_limits_every_level_and_step"),
    ("geometry.count_limit_1023", "c051_geometry_count_limit"),
    ("prediction.magnitude_off_by_one", "c052_gaussians_value_at_limit"),
    ("prediction.check_before_prediction", "e084_prediction_value_limit"),
    ("neighbour.lod_sizes_floor", "c082_neighbour_prediction_small_chunks"),
])
def test_named_streams_kill_their_mutations(mid, killer):
    """The harness end to end: the mutation fails the stream written for it, and the same stream passes
    with the unmutated decoder."""
    import lghcc.decoder.decode  # noqa: F401 (imported before the fork, nothing decoded)

    status, who, note, _ = mutation_test.run_one(mid, [killer], 120)
    assert (status, who) == ("killed", killer), note
    probe = mutations.Mutation("probe", "probe", "lghcc.common.entropy.range_coder:check_frequencies", "no change",
                               (("def check_frequencies", "def check_frequencies"),))
    mutations.MUTATIONS.append(probe)
    try:
        assert mutation_test.run_one("probe", [killer], 120)[0] == "survived"
    finally:
        mutations.MUTATIONS.remove(probe)


def test_value_mutations_reach_every_holder():
    """A constant imported by name elsewhere is patched there too (in a child process: for good)."""
    import multiprocessing as mp

    def child(conn):
        from lghcc.common import geometry
        mutations.apply(next(m for m in mutations.MUTATIONS if m.id == "geometry.dens_bucket"))
        conn.send(list(geometry.DENS_BUCKET))

    ctx = mp.get_context("fork")
    a, b = ctx.Pipe()
    p = ctx.Process(target=child, args=(b,))
    p.start()
    assert a.recv() == [0, 1, 1, 1, 2, 3, 3]
    p.join()
    from lghcc.common import geometry
    assert list(geometry.DENS_BUCKET) == [0, 1, 1, 2, 2, 3, 3]
    assert np.array_equal(geometry.DENS_BUCKET, [0, 1, 1, 2, 2, 3, 3])


def test_property_mutations_replace_the_property():
    """A derived value of a layout (a property) is mutated as a property, in a child process."""
    import multiprocessing as mp

    from lghcc.common.attributes import GaussianLayout

    def child(conn):
        mutations.apply(next(m for m in mutations.MUTATIONS if m.id == "gaussians.coefficients_of_last_band"))
        conn.send(GaussianLayout(3).sh_channels)

    ctx = mp.get_context("fork")
    a, b = ctx.Pipe()
    p = ctx.Process(target=child, args=(b,))
    p.start()
    assert a.recv() == 21  # 3 x (2d + 1) for d = 3
    p.join()
    assert GaussianLayout(3).sh_channels == 48  # 3 x (d + 1)^2 here


def test_a_stopped_campaign_keeps_its_figures():
    """Ctrl-C or SIGTERM (tools/fuzz_decoder.py turns it into KeyboardInterrupt) ends the run with the
    summary of the cases done, so a long run cut short still reports them."""
    m = Mutator({k: v for k, v in load_seeds().items() if k == "c001_one_anchor"})

    def interrupt_after_5(s):
        if s.cases == 5:
            raise KeyboardInterrupt

    s = run_campaign(m, seed=1, cases=100, progress=interrupt_after_5)
    assert s.stopped and s.cases == 5 and s.seconds > 0 and sum(s.outcomes.values()) == 5
