"""The differential fuzzer (lghcc.conformance.differential, tools/fuzz_differential.py): a short
seeded run of the reference and the JavaScript decoder on the same streams finds no disagreement,
and a JavaScript decoder with a planted bug (a mutation of tools/js_mutation_test.py, in a copy)
is caught as one. Skips where node is absent."""

import random
import shutil
import sys
from pathlib import Path

import pytest

from lghcc.conformance import differential
from lghcc.conformance.differential import (AGREE_DECODED, AGREE_REJECTED, AGREE_REJECTED_OUTSIDE,
                                            AGREE_UNSUPPORTED, CONDITIONS_DIFFER,
                                            NOT_COMPARED, Differential, JsDecoder, Verdict, compare,
                                            confirm_condition, reference_judge, run_differential, seed_weights)
from lghcc.conformance import runner
from lghcc.conformance.fuzz import Mutator, Sandbox, load_seeds

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
