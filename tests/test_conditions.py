"""Isolated error streams (issue 35): every rejection condition of spec clause 8.2 has an error
stream that breaks it alone (test.yaml ``condition``), or a stated reason why none can; the
reference decoder rejects each; the decoder without exactly that check accepts it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from lghcc.common.container import CONTAINER_HEADER_BYTES, UNIT_CRC_BYTES, UNIT_HEADER_BYTES, UnitType
from lghcc.conformance import conditions, mutations, runner

SPEC = Path(__file__).resolve().parents[1] / "spec" / "lghcc.md"


def _spec_rows() -> dict[str, list[str]]:
    """The rows of the table of clause 8.2: condition -> its cells."""
    text = SPEC.read_text()
    section = text[text.index("### 8.2 "):text.index("### 8.3 ")]
    rows = {}
    for line in section.splitlines():
        m = re.match(r"\| (E\d+) \|", line)
        if m:
            rows[m.group(1)] = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
    return rows


def test_every_condition_has_its_isolated_stream_or_a_reason():
    rows = _spec_rows()
    assert list(rows) == conditions.CONDITIONS
    streams = conditions.isolated_streams()
    ids = {m.id for m in mutations.MUTATIONS}
    for cond in conditions.CONDITIONS:
        isolated = rows[cond][-1]
        if cond in streams:
            assert cond not in conditions.NOT_ISOLATED, cond
            assert isolated.startswith(streams[cond].split("_")[0]), (cond, isolated)
            assert conditions.CHECK_REMOVALS[cond] in ids, cond
        else:
            assert conditions.NOT_ISOLATED.get(cond), f"{cond}: no isolated stream and no reason"
            assert isolated.startswith("no"), (cond, isolated)
    assert set(conditions.CHECK_REMOVALS) <= set(conditions.CONDITIONS)
    assert set(conditions.CHECK_REMOVALS.values()) <= ids


def test_second_checks_of_a_mutation_apply_to_todays_code():
    """``also``: the edits that remove a rule's second check match the code once each."""
    with_also = [m for m in mutations.MUTATIONS if m.also]
    assert {m.id for m in with_also} >= {"check.E40", "check.E44", "check.E64"}
    for m in with_also:
        for target, edits in m.also:
            compile(mutations.mutated_source(mutations.Mutation(m.id, m.group, target, "", edits)), m.id, "exec")


def test_reference_decoder_rejects_every_isolated_stream():
    cases = [c for c in runner.load_cases() if c.meta.get("condition")]
    assert len(cases) == len(conditions.isolated_stream_list()) >= 30
    for case in cases:
        assert case.expect == "error"
        outcome = runner.run_case(case)
        assert outcome.passed, (case.id, outcome.note)


def test_every_rejection_names_its_condition():
    """The reference decoder rejects each isolated stream for exactly its condition (the error's
    ``condition``) and every other error stream for the condition its test.yaml records
    (expect_condition), never for none; the condition survives pickling (a decoding worker)."""
    import pickle

    from lghcc.common.errors import BitstreamError
    from lghcc.decoder.decode import decode_stream

    cases = [c for c in runner.load_cases() if c.expect == "error"]
    assert len(cases) >= 200
    for case in cases:
        with pytest.raises(BitstreamError) as info:
            decode_stream(case.stream.read_bytes())
        want = case.meta.get("condition") or case.meta["expect_condition"]
        assert conditions.CONDITION_ID.fullmatch(want), case.id
        assert info.value.condition == want, (case.id, info.value.condition, str(info.value))
        if case.meta.get("condition"):
            assert case.meta["expect_condition"] == case.meta["condition"], case.id
    again = pickle.loads(pickle.dumps(info.value))
    assert type(again) is type(info.value) and again.condition == info.value.condition and str(again) == str(info.value)


def test_every_check_of_a_condition_can_be_removed():
    """all_check_removals (the differential fuzzer's confirmation): its edits match today's code
    once each, also when a chain of conditions edits one function twice (combined)."""
    chain = []
    for cond in conditions.CONDITIONS:
        removals = conditions.all_check_removals(cond)
        assert removals or cond in ("E39", "E46"), cond
        chain += removals
        for m in conditions.combined(removals):
            if m.value is None:
                compile(mutations.mutated_source(m), m.id, "exec")
    for m in conditions.combined(chain):  # every removal at once: no two edits of one function collide
        if m.value is None:
            compile(mutations.mutated_source(m), m.id, "exec")


def test_a_wrong_condition_fails_the_runner():
    """The runner holds the reference decoder to an error stream's recorded condition."""
    case = next(c for c in runner.load_cases() if c.id.startswith("x013"))
    ok, note = runner._judge_error(case, "BitstreamError", case.meta["expect_message"], "E20")
    assert not ok and "E20 instead of E21" in note
    ok, _ = runner._judge_error(case, "BitstreamError", case.meta["expect_message"], "E21")
    assert ok


def test_unit_order_names_e61_for_the_neighbour_prediction_unit_alone():
    from lghcc.decoder.core import _order_condition

    assert _order_condition("PNNGAH") == "E61"  # repeated
    assert _order_condition("PIGAHNGAH") == "E61" and _order_condition("SNGAH") == "E61"
    assert _order_condition("PQGAH") == "E14"  # a step_adjust unit without neighbour prediction
    assert _order_condition("PNGAHP") == "E14"


def _stored_hashes(stream: Path) -> tuple[bytes, ...]:
    """The scene hashes in the stream's decoded_scene_hash units, read from the unit framing
    alone (an isolated stream may break the container's own checks: magic, CRC, trailing bytes)."""
    data, pos, out = stream.read_bytes(), CONTAINER_HEADER_BYTES, []
    while pos + UNIT_HEADER_BYTES <= len(data):
        size = int.from_bytes(data[pos + 1:pos + UNIT_HEADER_BYTES], "big")
        if data[pos] == UnitType.DECODED_SCENE_HASH:
            out.append(data[pos + UNIT_HEADER_BYTES + 1:pos + UNIT_HEADER_BYTES + 33])
        pos += UNIT_HEADER_BYTES + size + UNIT_CRC_BYTES
    return tuple(out)


def _accepts(isolated: conditions.IsolatedStream) -> None:
    stream = runner.STREAMS_DIR / isolated.id / "stream.lghcc"
    res = conditions.mutant_decode(isolated.check_removal, stream.read_bytes())
    assert res.decoded, (isolated.id, res.describe())
    if isolated.condition != conditions.HASH_CONDITION:
        assert res.digests == _stored_hashes(stream), isolated.id  # the stream carries that decoder's hashes


def _isolated(stream_id: str) -> conditions.IsolatedStream:
    return next(s for s in conditions.isolated_stream_list() if s.id == stream_id)


@pytest.mark.parametrize("stream_id", ["x006_crc_mismatch", "x013_parameter_set_trailing_byte", "x025_attribute_level_mismatch",
                                       "x040_tile_point_counts_beside_num_anchors",
                                       "x055_gaussians_chunk_one_word_unread", "x057_gaussians_value_at_minus_limit",
                                       "x063_gaussians_band_step_zero", "x064_rotation_w_value_overflows"])
def test_decoder_without_the_check_accepts_its_isolated_stream(stream_id):
    _accepts(_isolated(stream_id))


def test_isolated_streams_of_one_condition_name_their_bound():
    """A condition with several isolated streams (both ends of a range, each field of a two-field
    rule, each profile): every stream but the table's first says which bound it breaks, no two alike;
    a narrower check removal than the condition's is a mutation that exists."""
    by_condition: dict[str, list[conditions.IsolatedStream]] = {}
    for s in conditions.isolated_stream_list():
        by_condition.setdefault(s.condition, []).append(s)
    ids = {m.id for m in mutations.MUTATIONS}
    first = conditions.isolated_streams()  # read once: each call parses every test.yaml
    assert any(len(v) > 1 for v in by_condition.values())
    for cond, streams in by_condition.items():
        assert streams[0].id == first[cond]
        bounds = [s.bound for s in streams[1:]]
        assert all(bounds) and len(set(bounds)) == len(bounds), (cond, bounds)
        assert all(s.check_removal in ids for s in streams), cond


def test_another_check_removed_still_rejects_for_the_condition():
    """With some other check removed, the isolated stream is still rejected, for its condition."""
    stream = runner.STREAMS_DIR / conditions.isolated_streams()["E21"] / "stream.lghcc"
    res = conditions.mutant_decode("container.no_magic_check", stream.read_bytes())  # another check removed
    assert not res.decoded and "unexpected trailing bytes" in res.message


@pytest.mark.slow
def test_every_check_removal_accepts_its_isolated_stream():
    for isolated in conditions.isolated_stream_list():
        _accepts(isolated)
