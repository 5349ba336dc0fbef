"""The differential fuzzer (lghcc.conformance.differential, tools/fuzz_differential.py): a short
seeded run of the reference and the JavaScript decoder on the same streams finds no disagreement,
and a JavaScript decoder with a planted bug (a mutation of tools/js_mutation_test.py, in a copy)
is caught as one. Skips where node is absent."""

import math
import random
import shutil
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lghcc.conformance import differential
from lghcc.conformance.differential import (AGREE_DECODED, AGREE_REJECTED, AGREE_REJECTED_OUTSIDE,
                                            AGREE_REJECTED_TWO, AGREE_REJECTED_TWO_JS, AGREE_UNSUPPORTED,
                                            CONDITIONS_DIFFER,
                                            NOT_COMPARED, Differential, JsDecoder, Verdict, compare,
                                            confirm_condition, reference_judge, run_differential, seed_weights)
from lghcc.conformance import runner
from lghcc.conformance.fuzz import Mutator, Sandbox, load_seeds
from lghcc.conformance.js_checks import JsCheckRemovals, without_checks

TOOLS = Path(__file__).resolve().parents[1] / "tools"
sys.path.insert(0, str(TOOLS))

import fuzz_differential  # noqa: E402
import js_mutation_test  # noqa: E402


def needs_node(test):
    """A test that runs the JavaScript decoder in Node: the integration tier, skipped without node."""
    skip = pytest.mark.skipif(shutil.which("node") is None, reason="node (Node.js) is not on the PATH")
    return pytest.mark.integration(skip(test))


# small, quick seeds: explicit-Gaussian streams of the JavaScript decoder's profile, and one anchor stream
SEEDS = ("c032_gaussians_sh0", "c033_gaussians_sh3_prediction", "c078_neighbour_prediction_tiles",
         "c085_step_adjust", "c001_one_anchor")


@pytest.fixture
def mutator():
    """A fresh mutator per test: a campaign adds its fresh scene streams to the seeds."""
    seeds = {k: v for k, v in load_seeds().items() if k in SEEDS}
    assert len(seeds) == len(SEEDS)
    m = Mutator(seeds)
    m.weights = seed_weights(seeds)
    return m


def test_compare_rules():
    decoded = Verdict("decoded", hash="ab")
    anchor = Verdict("decoded", hash="cd", in_profile=False)
    rejected = Verdict("rejected", kind="BitstreamError", condition="E9")
    unsupported = Verdict("rejected", kind="UnsupportedStreamError")  # outside the JavaScript decoder's profile
    assert compare(decoded, Verdict("decoded", hash="ab")) == AGREE_DECODED
    assert compare(decoded, Verdict("decoded", hash="ef")).startswith("DISAGREE")
    assert compare(rejected, Verdict("rejected", kind="BitstreamError", condition="E9")) == AGREE_REJECTED
    assert compare(rejected, Verdict("rejected", kind="HashMismatchError", condition="E53")) == CONDITIONS_DIFFER
    assert compare(rejected, unsupported) == AGREE_REJECTED_OUTSIDE
    assert compare(rejected, Verdict("rejected", kind="BitstreamError")).startswith("DISAGREE")  # no condition
    assert compare(Verdict("rejected", kind="BitstreamError"), rejected).startswith("BUG")
    assert compare(anchor, unsupported) == AGREE_UNSUPPORTED
    assert compare(anchor, rejected).startswith("DISAGREE")  # a valid anchor stream: unsupported, not broken
    assert compare(decoded, rejected).startswith("DISAGREE") and compare(rejected, decoded).startswith("DISAGREE")
    assert compare(decoded, Verdict("resource")) == NOT_COMPARED
    assert compare(rejected, Verdict("bug", kind="JS TypeError")).startswith("DISAGREE")
    assert compare(Verdict("bug", kind="BUG: IndexError"), rejected).startswith("BUG")


def test_a_second_condition_is_confirmed_only_when_the_stream_breaks_it():
    """A stream with a wrong magic number (E2) and a non-zero reserved byte (E5): the reference
    names E2, and without that check E5, so a decoder that names E5 agrees; E9 (the CRCs are
    right) is not confirmed. An isolated stream breaks nothing else."""
    data = bytearray(load_seeds()["c032_gaussians_sh0"])
    data[0], data[7] = ord("X"), 1
    ok, chain = confirm_condition(bytes(data), "E2", "E5")
    assert ok and chain == "E2 -> E5"
    ok, chain = confirm_condition(bytes(data), "E2", "E9")
    assert not ok and "E9" not in chain.split(" -> ")
    hash_type_0 = bytearray(load_seeds()["c032_gaussians_sh0"])
    hash_type_0[-37] = 0  # the last unit: decoded_scene_hash (hash_type, 32 bytes, CRC); CRC now wrong (E9)
    assert differential.hash_unit_conditions(bytes(hash_type_0)) == {"E19"}
    assert confirm_condition(bytes(hash_type_0), "E9", "E19")[0]
    isolated = (runner.STREAMS_DIR / "x013_parameter_set_trailing_byte" / "stream.lghcc").read_bytes()
    ok, chain = confirm_condition(isolated, "E21", "E20")
    assert not ok and "decoded" in chain


def test_e61_and_e14_agree_only_when_the_neighbour_unit_is_out_of_place():
    """E61 is a case of E14 (one check of the unit order in both decoders): a stream whose
    neighbour_prediction unit stands after the tile breaks both; one whose step_adjust unit does
    breaks E14 alone."""
    from lghcc.common.container import UnitType, read_container

    data = load_seeds()["c085_step_adjust"]
    units = read_container(data).units
    assert [UnitType(u.unit_type).name for u in units[:3]] == ["GAUSSIAN_PARAMETER_SET", "NEIGHBOUR_PREDICTION",
                                                               "STEP_ADJUST"]

    def moved_to_end(i):
        return bytes(data[:8]) + b"".join(_unit_bytes(data, u) for u in units[:i] + units[i + 1:] + units[i:i + 1])

    assert not differential.neighbour_unit_misplaced(data)
    assert differential.neighbour_unit_misplaced(moved_to_end(1))
    assert confirm_condition(moved_to_end(1), "E14", "E61")[0] and confirm_condition(moved_to_end(1), "E61", "E14")[0]
    assert not differential.neighbour_unit_misplaced(moved_to_end(2))
    ok, why = confirm_condition(moved_to_end(2), "E14", "E61")
    assert not ok and "is not out of place" in why


def _unit_bytes(data: bytes, u) -> bytes:
    """A data unit's bytes as they stand in ``data`` (header, payload, CRC)."""
    from lghcc.common.container import UNIT_CRC_BYTES, UNIT_HEADER_BYTES

    return bytes(data[u.offset:u.offset + UNIT_HEADER_BYTES + len(u.payload) + UNIT_CRC_BYTES])


def test_duplicate_mutations_are_skipped(mutator):
    """A stream compared once is not compared again: it counts as a duplicate, not as a case."""
    loop = differential._Loop(None, mutator, differential.DiffSummary(), None, 4)
    assert not loop.seen_before(b"abc") and loop.seen_before(b"abc") and not loop.seen_before(b"abd")


def test_seed_weights_favour_the_profile(mutator):
    assert mutator.weights["c032_gaussians_sh0"] == 1.0
    assert mutator.weights["c001_one_anchor"] == differential.OUTSIDE_PROFILE_WEIGHT


@needs_node
def test_short_differential_run_agrees(mutator, tmp_path):
    """40 cases (seed 7): mutations of the seeds and fresh scene streams with their box decodes."""
    summary = run_differential(mutator, seed=7, cases=40, timeout=60.0, failures_dir=tmp_path, scene_source=fuzz_differential.differential_scene_case,
                               mutations_per_scene=8)
    assert summary.bugs == 0, summary.text() + "\n" + "\n".join(map(str, summary.disagreements))
    assert summary.cases == 40 and summary.scene_cases >= 2
    assert summary.outcomes[AGREE_DECODED] + summary.outcomes[AGREE_UNSUPPORTED] >= 2
    assert summary.outcomes[AGREE_REJECTED] >= 10


@needs_node
def test_seeds_agree_unmutated(mutator):
    """Each seed as it is: the same hash from both, or (the anchor stream) unsupported by the JavaScript decoder."""
    with Sandbox(60.0, 2048, judge=reference_judge) as box, JsDecoder() as js:
        diff = Differential(box, js)
        labels = {sid: diff.check(data)[0] for sid, data in mutator.seeds.items()}
    assert labels == {sid: AGREE_UNSUPPORTED if sid == "c001_one_anchor" else AGREE_DECODED for sid in SEEDS}


@needs_node
def test_planted_javascript_bug_is_a_disagreement(mutator, tmp_path):
    """The JavaScript decoder with se(v)'s signs swapped decodes nothing right: the first fresh
    scene stream (a case of its own every other case) disagrees, and is saved with both verdicts."""
    planted = next(m for m in js_mutation_test.MUTATIONS if m.id == "bitreader.se_sign_swapped")
    decoder = js_mutation_test.mutated_copy(planted, tmp_path / "mutant")
    summary = run_differential(mutator, seed=3, cases=12, timeout=60.0, decoder_dir=decoder,
                               failures_dir=tmp_path / "failures", mutations_per_scene=1,
                               scene_source=fuzz_differential.differential_scene_case)
    assert summary.bugs >= 1, summary.text()
    assert any(label.startswith("DISAGREE: reference decoded, JS rejected") for label, *_ in summary.disagreements)
    saved = sorted((tmp_path / "failures").glob("diff_*.txt"))
    assert saved and any("reference: decoded" in p.read_text() for p in saved)
    assert all(p.with_suffix(".lghcc").exists() for p in saved)


@needs_node
def test_a_wrong_condition_of_the_javascript_decoder_is_a_disagreement(tmp_path):
    """A JavaScript decoder that names E21 for non-zero byte_alignment() bits (E20) disagrees on
    e187 (the reference names E20, and the stream breaks nothing else), and the verdict says
    what the reference found; the real decoder agrees, for the same condition."""
    decoder = tmp_path / "js" / "lghcc-decoder"
    shutil.copytree(differential.JS_DECODER, decoder)
    f = decoder / "bitreader.mjs"
    text = f.read_text()
    assert text.count("(clause 2, E20)`, 'E20')") == 1
    f.write_text(text.replace("(clause 2, E20)`, 'E20')", "(clause 2, E20)`, 'E21')"))
    data = next((runner.STREAMS_DIR).glob("e187_*/stream.lghcc")).read_bytes()
    with Sandbox(60.0, 2048, judge=reference_judge) as box:
        with JsDecoder(decoder) as js:
            label, ref, wrong = Differential(box, js).check(data)
        assert label == CONDITIONS_DIFFER and ref.condition == "E20" and wrong.condition == "E21"
        assert "reference: E20" in wrong.message
        with JsDecoder() as js:
            assert Differential(box, js).check(data)[0] == AGREE_REJECTED


@needs_node
def test_js_decoder_server_survives_a_hang_bound(tmp_path):
    """A request the server does not answer in time is a 'JS timeout'; the next request starts a
    fresh server and is answered."""
    seeds = load_seeds()
    data = seeds["c032_gaussians_sh0"]
    with JsDecoder(timeout=1e-6) as js:
        v = js.run(data)
        assert v.outcome == "bug" and v.kind == "JS timeout"
        js.timeout = 60.0
        assert js.run(data).outcome == "decoded"
        assert js.run(random.Random(1).randbytes(40)).outcome == "rejected"


def test_results_section_is_rewritten_in_place_and_kept_by_fuzz_decoder(tmp_path):
    """--out rewrites only the differential section of tools/results/fuzz.md; tools/fuzz_decoder.py,
    which writes the file whole, keeps it."""
    import fuzz_decoder

    out = tmp_path / "fuzz.md"
    out.write_text("# Decoder fuzzing: long run\n\nfigures\n")
    first = fuzz_differential.BEGIN + "\nrun 1\n" + fuzz_differential.END + "\n"
    fuzz_differential.write_section(out, first)
    fuzz_differential.write_section(out, first.replace("run 1", "run 2"))
    text = out.read_text()
    assert text.startswith("# Decoder fuzzing") and "run 2" in text and "run 1" not in text
    assert text.count(fuzz_differential.BEGIN) == 1
    fuzz_decoder.write_results(str(out), "# Decoder fuzzing: long run\n\nnew figures\n")
    text = out.read_text()
    assert "new figures" in text and "run 2" in text and "\nfigures" not in text


def test_js_survivors_are_told_apart_equivalent_or_missing_a_stream():
    """tools/js_mutation_test.py's report: a survivor whose condition cannot be isolated (clause 8.2)
    or that EQUIVALENT names is equivalent under the rejection protocol; any other names what the
    suite lacks. Every EQUIVALENT entry is a mutation of the list."""
    by_id = {m.id: m for m in js_mutation_test.MUTATIONS}
    assert set(js_mutation_test.EQUIVALENT) <= set(by_id)
    equivalent, why = js_mutation_test.missing_stream(by_id["container.unit_type_0_ok"], {}, set())
    assert equivalent and why.startswith("E7 cannot be isolated")
    equivalent, why = js_mutation_test.missing_stream(by_id["units.equal_cells_ok"],
                                                      {"E56": ["x042_tiles_swapped_with_their_cells"]}, set())
    assert not equivalent and "x042_tiles_swapped_with_their_cells" in why and "outside the profile" in why
    equivalent, _ = js_mutation_test.missing_stream(by_id["decoder.fewer_rows_ok"], {}, set())
    assert equivalent


# Streams of the first campaign (seed 1456) on which the two decoders named different conditions and
# the reference without its checks did not reach the JavaScript decoder's (regression streams):
# (reference's condition, JavaScript decoder's, stream as base64)
SAVED = {
    "E19/E49": ("E19", "E49", "TEdIQwEEAQAHAAAAIYeEeuFAAAAAAAAAAAAAAAAHrrhR59MzM0fB64UnpHrhQGCG9EAMAAAAAQDfG1CZAwAAAAgDgCCECD8BAL+tzSIEAAAA"
                "GQQIECAMAAVYAOwIARADAA28oggDlPwlAgBy+EIoBgAAACEBZBao8K09EC+8D95zGY80zLy7REE/YBLQjz9I5psd88jrrsb/"),
    "E17/E46": ("E17", "E46", "TEdIQwEEAQAHAAAAJaeEeuFOQu7C+S6EgAkuhIAHrrhR5764UefTMzNHweuFJ6R64UBln/7TDAAAAAEA3xtQmQMAAAAEQEBAQEcvVcME"
                "AAAAHwwIECBAgQIECBAgQAOoACbAAR4EAIgGAEgcoPLnAwA8GgTZBgAAACEBroLgeO7HC92o5BYIusbHV31ZuZdOPI4AjWsbigw8LrJH7RAl"),
    "E19/E45": ("E19", "E45", "TEdIQwEBAQAHAAAAIUHhHrhSS6EgBkuhIAAAAAAB6R64UfJmZmnuZmZp564UeIbhSlgDAAAAF4AAAAEAB7VGBAQEWCsAwAO8Uv4A8X+/pTw4"
                "yAQAAAAYRPkwI8eTJgQIAwYNnGRs4uIVmA7oNYXT0CujlwYAAAAhAV3tIxf0VdomhN5FIP23k3ZVbzbnbOq1O3z0bU/6FTKGhQ+P6A=="),
    "E19/E48": ("E19", "E48", "TEdIQwEEAQAHAAAAIYeEeuFAAAAAAAAAAAAAAAAHnrhR58MzM0ex64UnlHrhQMH9NW4MAAAAAQDfG1CZAwAAAARAQEBARy9VwwQAAAAd"
                "BAgQIABBwAFqAEgIBAAdAAzABMjGhXgz5fwlAgDlmZA/BgAAACEBZ49iP7MhGaudAlajedwApDlCI9YLpf/ydarNK9RJARQTeZtf"),
}


def _saved(key: str) -> tuple[str, str, bytes]:
    import base64

    c_ref, c_js, b64 = SAVED[key]
    return c_ref, c_js, base64.b64decode(b64)


def test_without_checks_removes_exactly_the_throws_naming_the_condition():
    """Each ``throw new XError(..., 'E48')`` goes, whatever its message holds (templates with ${...},
    brackets, quotes), a ternary of two conditions for either; no other text changes."""
    src = ("if (s >= t) throw new BitstreamError(`x ${f(a, [1, ')'])} (E48) ${'}'}`, 'E48');\n"
           "if (u) {\n    throw new BitstreamError(`y ${c ? 'E62' : 'E46'}`, c ? 'E62' : 'E46');\n}\n"
           "if (v) throw new BitstreamError('E48 in a message', 'E49');\n"
           "return new BitstreamError(`z`, 'E48');\n")
    out, n = without_checks(src, {"E48"})
    assert n == 1
    assert out.splitlines()[0] == "if (s >= t) void 0;" and out.splitlines()[1:] == src.splitlines()[1:]
    for c in ("E62", "E46"):
        out, n = without_checks(src, {c})
        assert n == 1 and "    void 0;" in out.splitlines() and "'E48');" in out
    assert without_checks(src, {"E49"})[0].splitlines()[4] == "if (v) void 0;"
    assert without_checks(src, {"E1", "E50"}) == (src, 0)  # a returned error is no check removed
    out, n = without_checks(src, {"E48", "E49", "E62"})
    assert n == 3 and out.count("void 0") == 3


def test_js_check_removal_copies_are_built_once(tmp_path):
    """A copy per set of conditions, built on first use and kept; None for a condition the
    JavaScript sources check only inside the WebAssembly module (E38) or do not name."""
    with JsCheckRemovals(differential.JS_DECODER) as removals:
        a = removals.copy_without(["E48"])
        assert a is not None and removals.copy_without(("E48",)) == a
        assert "'E48');" not in (a / "units.mjs").read_text() and "'E49');" in (a / "units.mjs").read_text()
        assert (a / "decoder.mjs").read_text() == (differential.JS_DECODER / "decoder.mjs").read_text()
        b = removals.copy_without(["E49", "E48"])
        assert b not in (None, a) and removals.copy_without(["E48", "E49"]) == b
        assert removals.copy_without(["E38"]) is None and removals.copy_without(["E48", "E38"]) is None
        assert removals.copy_without(["E99"]) is None
    assert not a.exists()  # the folder goes with the object


def test_attribute_header_conditions_read_alone():
    """E45, E46 and E62 from the first five bits of each attribute unit (attribute_level,
    context_model_id): none in the seeds, each where a header's bits break it."""
    from lghcc.common.container import UNIT_HEADER_BYTES, UnitType, read_container

    seeds = load_seeds()
    for sid in SEEDS:
        assert differential.attribute_header_conditions(seeds[sid]) == set(), sid

    def first_attribute_byte(data: bytes, value: int) -> bytes:
        u = next(u for u in read_container(data).units if u.unit_type == UnitType.ATTRIBUTE)
        out = bytearray(data)
        out[u.offset + UNIT_HEADER_BYTES] = value
        return bytes(out)

    flat, neighbours = seeds["c032_gaussians_sh0"], seeds["c078_neighbour_prediction_tiles"]
    assert differential.attribute_header_conditions(first_attribute_byte(flat, 0b01_000_000)) == {"E45"}
    assert differential.attribute_header_conditions(first_attribute_byte(flat, 0b00_001_000)) == {"E46"}
    assert differential.attribute_header_conditions(first_attribute_byte(flat, 0b10_010_000)) == {"E45"}  # level 2
    assert differential.attribute_header_conditions(first_attribute_byte(flat, 0b00_011_000)) == set()  # E19 only
    assert differential.attribute_header_conditions(first_attribute_byte(neighbours, 0b00_011_000)) == {"E62"}
    assert differential.attribute_header_conditions(first_attribute_byte(neighbours, 0b00_010_000)) == {"E46", "E62"}
    assert differential.attribute_header_conditions(b"LGHC") == set()  # no unit at all


@given(st.floats(min_value=0.0, max_value=1e6, allow_nan=False), st.floats(min_value=1e-6, max_value=10.0))
def test_cost_weight_caps_a_seeds_cost_per_draw(seconds, cap):
    """1 up to the cap; beyond it a power of two such that the cost per draw lies in (cap / 2, cap]."""
    w = differential.cost_weight(seconds, cap)
    if seconds <= cap:
        assert w == 1.0
    else:
        assert 0 < w < 1 and math.log2(w) == int(math.log2(w))
        assert cap / 2 < seconds * w <= cap * (1 + 1e-12)
    assert differential.cost_weight(seconds, None) == differential.cost_weight(seconds, 0) == 1.0


def test_jobs_split_the_budget_and_the_seeds(tmp_path):
    args = fuzz_differential.parse_args(["--cases", "11", "--jobs", "3", "--seed", "5", "--scenes", "--json",
                                         str(tmp_path / "d.json"), "--failures", str(tmp_path / "f")])
    argvs = [fuzz_differential.job_argv(args, j) for j in range(3)]
    value = lambda argv, flag: argv[argv.index(flag) + 1]  # noqa: E731
    assert [int(value(a, "--cases")) for a in argvs] == [4, 4, 3]
    assert [int(value(a, "--seed")) for a in argvs] == [5, 5 + fuzz_differential.JOB_SEED_STEP,
                                                        5 + 2 * fuzz_differential.JOB_SEED_STEP]
    assert len({value(a, "--json") for a in argvs}) == 3 and len({value(a, "--failures") for a in argvs}) == 3
    assert all("--scenes" in a and "--jobs" not in a and value(a, "--scene-max-points") == "1000" for a in argvs)
    with pytest.raises(SystemExit):
        fuzz_differential.parse_args(["--jobs", "0"])


@needs_node
def test_saved_streams_agree_confirmed_one_way_or_the_other():
    """The saved streams of the first campaign: each now agrees, confirmed by the JavaScript decoder
    without its check of its condition (E49, E48: reached E19 as it reads on) or from the attribute
    unit header read alone (E46 at level 0: the reference reads the header's other elements first)."""
    with Sandbox(60.0, 2048, judge=reference_judge) as box, JsCheckRemovals(differential.JS_DECODER) as removals, \
            JsDecoder() as js, JsDecoder(timeout=15.0) as js_mutants:
        diff = Differential(box, js, removals, js_mutants)
        for key in SAVED:
            c_ref, c_js, data = _saved(key)
            label, ref, jsv = diff.check(data)
            assert (ref.condition, jsv.condition) == (c_ref, c_js), key
            assert label in (AGREE_REJECTED_TWO, AGREE_REJECTED_TWO_JS), (key, label, diff.last_chain)
            if key in ("E19/E49", "E19/E48"):
                assert label == AGREE_REJECTED_TWO_JS and diff.last_chain.endswith(" -> E19"), diff.last_chain
            if key == "E17/E46":
                assert label == AGREE_REJECTED_TWO and "attribute unit header" in diff.last_chain


@needs_node
def test_js_confirms_by_its_own_check_removal_only_what_the_stream_breaks(tmp_path):
    """A wrong magic number (E2) and a non-zero reserved byte (E5): the JavaScript decoder without its
    check of E2 names E5, so E5 is confirmed; E9 is not (the CRCs are right: without E2 and E5 it
    decodes). The mutant server starts afresh once it holds max_decoders copies."""
    data = bytearray(load_seeds()["c032_gaussians_sh0"])
    data[0], data[7] = ord("X"), 1
    with Sandbox(60.0, 2048, judge=reference_judge) as box, JsCheckRemovals(differential.JS_DECODER) as removals, \
            JsDecoder() as js, JsDecoder(timeout=15.0, max_decoders=1) as js_mutants:
        diff = Differential(box, js, removals, js_mutants)
        assert diff.js_confirms(bytes(data), None, "E5", "E2") == (True, "E2 -> E5")
        first = js_mutants._proc.pid
        ok, chain = diff.js_confirms(bytes(data), None, "E9", "E2")
        assert not ok and chain.startswith("E2 -> E5") and "decoded" in chain
        assert js_mutants._proc.pid != first  # a second copy (without E2 and E5): a fresh server
        assert Differential(box, js).js_confirms(bytes(data), None, "E5", "E2")[0] is False  # no copies given


@needs_node
def test_jobs_run_side_by_side_and_merge(tmp_path):
    """--jobs 2: two campaigns as child processes, their summaries merged into --json."""
    import json

    out = tmp_path / "d.json"
    assert fuzz_differential.main(["--cases", "8", "--jobs", "2", "--seed", "2", "--json", str(out), "--failures",
                                   str(tmp_path / "f"), "--quiet", "--cost-cap-ms", "0"]) == 0
    merged = json.loads(out.read_text())
    assert merged["cases"] == 8 and len(merged["commands"]) == 2
    assert all((tmp_path / f"d.json.job{j}").exists() for j in (1, 2))


def test_fresh_scenes_keep_to_their_bound():
    """--scene-max-points: no fresh scene, Gaussian or anchor, has more points than the bound."""
    import re

    sizes = []
    for i in range(12):
        sc = fuzz_differential.differential_scene_case(random.Random(i), 20)
        n = re.search(r"\bN=(\d+)", sc.what)
        assert n is not None, sc.what
        sizes.append(int(n.group(1)))
    assert max(sizes) <= 20 and len(set(sizes)) > 1


# c105_rotation_length_summation_order, payload_bitflip of unit 1 (bits 353, 203): the reference meets a
# rotation length index beyond its table in chunk 1 (E66), the JavaScript decoder, which decodes every
# chunk's symbols before it reconstructs a rotation, meets data left over in chunk 2 (E38)
E66_E38 = (
    "TEdIQwEEAQAHAAAAIwIAeEeuFAAAAAAAAAAAAAAAAHpHrhR8mZmae5mZmmEAAAAAdtnlyAkAAAAtUqc3AAAApAAAvoAAAAoAeAecAAAjhAAAhg"
    "AAAihAAAAAAAAAAAAAAAAAAABA6dKasAwAAAABAN8bUJkDAAAAaZxJxJxEuY//f8RU8a/kv0Avk34wflEAAHq3OeGZyRcA2ztuO3UuWb5HPkPR"
    "whBWEEQAAOsKA2IGANqCEA+pcC6Hu/QS5B30HHq55JgSTGxfHFQQwYMrxBnhhxaI+JOs9mRwW0sdAACAesiOmocEAAAHqgByACQ0CyaaBPcAor"
    "gTWYAAAAAIm354AAAAAJxdZgAAAAAL5cTOAIEACADkHoH0B4gHdAHcgP/M///O/2T+zP//////zf97J2T/aQ+klksb75rujnsNNl/lcnV36wif"
    "4too2yvTHJMJVT4f6QvZ/8z//87/ZP7M///////N/7+mZP88RIKjmBdp+47d0xcB/DAp+OIXqg8hb68R0gTjoKHW40JgMKvU96vI/8z//87/ZP"
    "7M///////N////ZP//m//M/////2n/lv7/////MabdoYulV3d/pg8afC9ka6h7PUKdNWqEyoBfivktyACsJwfLNGDsOofqxa6J8XX//sy8cOrq"
    "561b99G4ygRfSSgeoi+fJe98tV8JBDVeSW5C4aNRAACCM//M///O/2T+zP//////zf///2T//5v/zP////9p/5b+/////wDN//9r/mTLzf////"
    "//BQD//mT//9P+zP////+h/pb+//////ITMsW6F05V9WlgCKHIKv1McYj+wZvISZOdl3wwd30U1x51befj61ZjAfndMT6mR6aoMHTHs+Jfdbp9"
    "k6GPwp0OCN2d5/ynNszRobW/a8DnyksqUrjjXPUPdyrvmmmF8T+nKqBw/Muahaf+H27i/YHo6rQEokBHlKgDf7SkA7AJvv6Pzv98iYR1N/dHJ8"
    "FwTObTNlHPHLygm9VA+2h2FJlH75gXwD3wCv/M///O/2T+zP//////zf///2T//5v/zP////9p/5b+/////wDN//9r/mTLzf//////BQD//mT/"
    "/9P+zP////+h/pb+/////wHN///X/GSXzf//////PQH//GT//wv+zP/////Z/Zb+/////wLN//9D+2Rjzf//////dQL/+mT//0P9zP////8R/Z"
    "b+/////xbNEnq7SCA5BTFSVg5vr8Ar4Q9SnASKTLH4jUESdb2Z2geUlcbp6j+15z7/poAk20yt0WJQImrUCyjWqT1sYUF45w2J8ruMmSpnSPwl"
    "5YgJgGE0gPcsg/MGCudZ8H/g3kk7T43rGrj379Oei6nSy1/6HHXz4C9S6RSZ6+7eBqJge2B2O0r68RKFK/V004lilERHyJ6uwL/EGTCLwGDzPW"
    "+TlY8PWUVVJZzmiEtENIV0PEBp+P8UrDxsuv5Mtp10K00kK/9jUYg7xKu+q+BoeDRhZ+7NqXsQPjjs4shgY7GHn0x/de+SkLoq3c5vEJKuBcf8"
    "O4M92z7mhWkllbTeVO7kVOBfTGo1wb5uGpg8TrZ4oB4fQLnsKAt1J5lDrwoCkYAFVnmps+EREAsl3FJiacxNaYtwx9zzwMHjgIPIwk3fCrOO/n"
    "b0EfSwI4fi/8z//87/ZP7M///////N////ZP//m//M/////2n/lv7/////AM3//2v+ZMvN//////8FAP/+ZP//0/7M/////6H+lv7/////Ac3/"
    "/9f8ZJfN//////89Af/8ZP//C/7M/////9n9lv7/////As3//0P7ZGPN//////91Av/6ZP//Q/3M/////xH9lv7/////A83//6/5ZC/N//////"
    "+tAv/5ZP//e/zM/////0n8lv7/////A83//xv4ZPvN///////lA//3ZP//s/vM/////4H7lv7/////BM3//4f2ZMfN//////8dBP/2ZP//6/rM"
    "/////7n6lv7/////Bc3///P0ZJPN//////9VBf/0ZP//I/rM//////H5lv7/////rGNizXgePzunBEoR8ZJQYgX3T/+V+jd+gYhwIJlqrG5SQN"
    "f7b92pJUbeRxO7wLbT6q4eFGuCB9kUQp456LjqfZkdXctOOTcJp1w4AIQRizYvOuisXXTP8PVicOqwwwQBCAkuBZBfm1uAOuogQ0Mh+pOV9i1j"
    "1lM8dpAKtPRGTYBPCx0dSAURSnyHq+ucCVNwUmO7A/T7jh53I/McAlqsQtctr4K7FMDOLD8cirdZIY9Xt0BIvEIqsU0fmq3pDp2wW2Yt4wYtSq"
    "0g0spQoiy1khresf75g8/VqTQfQOwFApGVZs+mxVTCTPaQhE8W5DPibhesufbJSbejFSd+mOWnuMCoJqZSvLurUBwmVR+B+IUMidaVO6k48foD"
    "RTzne5paHAISnP651uYdYQPL/6nPQOSXUtFKMbH/bJgRUWr6Z0+PJWfGDGIAncwzV6FsIY057/Xmpl+/V3/C8z/9nJj+63dg+irO/MAaXgJLH5"
    "D/1CyEEFdYOg5NThJW6VozDIHlOF16GqN1He1zs5NzLM2V/x6tJeBEO2K2wmrnFsv1MZYMStL3sJUIVAkOl10o5LNf3usJF24Fe/XkHAJMHer3"
    "fGiF+2kQfebQC1ZOWv0qkhdgxQ0o1kyIdC9BaSqWd0y38f9Xd2osS2uwQM4SgFkUbM+GSRQ7WGOH97hX3pqym/eynVFHB15gyBcxBYs4+r2K6i"
    "Nc9qyqxZWMzqUkZMBXbSGvqnnGGHGyKIh6jy8qMBzCb7/pvOEKmXg+rLqsWkt1Y8PJY1NOVMej2Vk4ZsqMPd/IUvk9ler9hXZHiGAM6VrPj1y8"
    "UJpzta3ezpXLuNcNkas2VDuLMFAQLVJjnvg1gFPbUcGtodciPZydtVTIM71dQZo3RZNUcPE5ojcGAAAAIQFZZzSDZe9wiFva1jhv7UptTXHluC"
    "hoyaBylJ8hggFlyvQOeps="
)


def test_e66_is_read_past_with_its_index_clamped():
    """Without E66's check the reference indexes out of its table; confirm_condition clamps the index
    instead (conditions.CONFIRM_INSTEAD), reads on and meets the JavaScript decoder's E38."""
    import base64

    from lghcc.conformance.conditions import all_check_removals, combined, confirm_removals, mutant_decode

    data = base64.b64decode(E66_E38)
    assert reference_judge(data)[1].startswith("E66 ")
    plain = mutant_decode(tuple(combined(all_check_removals("E66"))), data, 120.0)
    assert not plain.decoded and plain.error == "IndexError"
    assert [m.id for m in confirm_removals("E66")] == ["confirm.E66"]
    assert confirm_removals("E48") == all_check_removals("E48")
    assert confirm_condition(data, "E66", "E38", 120.0) == (True, "E66 -> E38")


def test_a_mutant_that_reads_on_is_stopped_by_its_cpu_time():
    """The reference without E17's and E18's checks reads on beyond the end of a unit: stopped by
    its CPU bound (the same on a busy machine as on a quiet one), reported as a hang."""
    from lghcc.conformance.conditions import all_check_removals, combined, mutant_decode

    _, _, data = _saved("E17/E46")
    res = mutant_decode(tuple(combined(all_check_removals("E17") + all_check_removals("E18"))), data, 300.0,
                        cpu_seconds=1)
    assert not res.decoded and res.error == "hang" and res.message == "more than 1 s of CPU"
    ok, chain = confirm_condition(data, "E17", "E9", 300.0, cpu_seconds=1)
    assert not ok and chain.startswith("E17") and chain.endswith("hang: more than 1 s of CPU")
