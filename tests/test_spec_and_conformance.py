"""Frozen artefacts: the spec's syntax tables match the code; the conformance streams are the frozen
ones (conformance/manifest.yaml) and decode to their recorded hashes; the generator can still make
the suite (integration tier; the encoder is not required to reproduce the frozen streams); the runner
works."""

import hashlib
import itertools
import sys
from pathlib import Path

import pytest
import yaml

import numpy as np

from lghcc.common import attributes as attr
from lghcc.common.bitio import BitReader
from lghcc.common.container import UnitType, read_container
from lghcc.common.context.model_unit import (ContextModelUnit, NamedIntArray, read_context_model_unit,
                                             write_context_model_unit)
from lghcc.common.context.models import read_context_model
from lghcc.common.entropy.tables import HALF_WIDTHS
from lghcc.common.errors import BitstreamError
from lghcc.common.geometry import decode_geometry
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.spec_tables import syntax_tables_markdown
from lghcc.common.units import AttributeUnitHeader, SceneParameterSet
from lghcc.conformance import generate as gen
from lghcc.conformance import manifest, runner
from lghcc.conformance.coverage import (F32_MAX, NOT_EXERCISED, coverage_report, element_classes,
                                        element_infos, value_class)

ROOT = Path(__file__).resolve().parents[1]


def test_spec_syntax_tables_match_the_code():
    committed = (ROOT / "spec" / "syntax_tables.md").read_text()
    assert committed == syntax_tables_markdown(), "run `make spec` (tools/gen_spec_tables.py) and commit"


def test_every_conformance_stream_passes_the_reference_decoder():
    cases = runner.load_cases()
    assert len(cases) >= 10
    outcomes = [runner.run_case(c) for c in cases]
    failed = [(o.case.id, o.note) for o in outcomes if not o.passed]
    assert not failed


def test_stream_files_match_their_recorded_digests():
    for case in runner.load_cases():
        data = case.stream.read_bytes()
        assert hashlib.sha256(data).hexdigest() == case.meta["stream_sha256"], case.id
        assert len(data) == case.meta["stream_bytes"]


def test_the_streams_are_the_frozen_ones():
    """Every file under conformance/streams/ is the one conformance/manifest.yaml records, no file is
    missing or added, and the manifest's outcome of each stream is its test.yaml's: the suite changes
    only through the generator, which rewrites the manifest (conformance/README.md)."""
    assert manifest.manifest_problems() == []
    frozen = manifest.read_manifest()
    assert frozen["format_version"] == manifest.FORMAT_VERSION, \
        "the format's version changed: add its streams (conformance/README.md) and regenerate the manifest"
    assert set(frozen["streams"]) == {e["id"] for e in gen.load_sources()}, \
        "conformance/sources.yaml and the frozen streams disagree: generate the streams added to sources.yaml"
    for case in runner.load_cases():
        assert frozen["streams"][case.id]["files"]["stream.lghcc"] == case.meta["stream_sha256"], case.id


def test_the_manifest_check_names_each_difference(tmp_path):
    import shutil

    streams = tmp_path / "streams"
    for sid in ("c001_one_anchor", "e001_unknown_critical_unit"):
        shutil.copytree(runner.STREAMS_DIR / sid, streams / sid)
    path = tmp_path / "manifest.yaml"
    manifest.write_manifest(streams, path)
    assert manifest.manifest_problems(streams, path) == []
    assert manifest.main(["--streams", str(streams), "--manifest", str(path)]) == 0
    data = bytearray((streams / "c001_one_anchor" / "stream.lghcc").read_bytes())
    data[-1] ^= 1  # one bit of the stream
    (streams / "c001_one_anchor" / "stream.lghcc").write_bytes(bytes(data))
    (streams / "c001_one_anchor" / "render_000.npy").write_bytes(b"")
    shutil.rmtree(streams / "e001_unknown_critical_unit")
    shutil.copytree(runner.STREAMS_DIR / "c004_escape_values", streams / "c004_escape_values")
    assert manifest.manifest_problems(streams, path) == [
        "e001_unknown_critical_unit: in the manifest, not in " + str(streams),
        "c004_escape_values: in " + str(streams) + ", not in the manifest",
        "c001_one_anchor/render_000.npy: not in the manifest",
        "c001_one_anchor/stream.lghcc: changed"]
    text = path.read_text().replace("expect: decode", "expect: error", 1)
    path.write_text(text)
    assert any("the manifest's outcome" in p for p in manifest.manifest_problems(streams, path))
    assert manifest.main(["--streams", str(streams), "--manifest", str(path)]) == 1
    assert manifest.main(["--streams", str(streams), "--manifest", str(tmp_path / "none.yaml")]) == 2
    assert manifest.main(["--streams", str(streams), "--manifest", str(path), "--write"]) == 0
    assert manifest.manifest_problems(streams, path) == []


@pytest.mark.integration
def test_the_generator_still_makes_the_suite(capsys):
    """The streams are frozen, so an encoder change never has to reproduce them; what must hold is
    that the suite can be made again when the format changes: with today's encoder and decoder
    every edit of sources.yaml still applies, every stream meets its expectation, every isolated
    stream still isolates its condition, every stream's derived tools hold its intent, and every
    frozen test.yaml is what the generator derives from its frozen stream."""
    import torch

    threads = torch.get_num_threads()
    assert gen.main(["--check"]) == 0, capsys.readouterr().out[-4000:]
    assert torch.get_num_threads() == threads, "generate() must restore torch's thread count"
    out = capsys.readouterr().out
    assert f"{len(gen.load_sources())} streams checked, 0 with problems" in out


def test_the_generator_check_reports_a_stream_it_can_no_longer_make(monkeypatch, capsys):
    entry = next(e for e in gen.load_sources() if e["id"] == "c001_one_anchor")

    def refuse(e):
        raise SystemExit(f"{e['id']}: the reference decoder rejects the stream")

    monkeypatch.setattr(gen, "generate", refuse)
    problems, same = gen._check(entry, runner.STREAMS_DIR / "c001_one_anchor")
    assert not same and len(problems) == 1 and problems[0].startswith("the generator can no longer make it")
    assert gen.main(["--check", "c001_one_anchor"]) == 1
    assert "1 streams checked, 1 with problems" in capsys.readouterr().out
    # today's encoder makes another stream (allowed), but one that no longer shows the entry's intent:
    # c001's stream where c004's must exercise escapes
    one = (runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc").read_bytes()
    monkeypatch.setattr(gen, "generate", lambda e: (one, runner.load_cases(ids=["c001_one_anchor"])[0].meta["decoded_sha256"]))
    escape = next(e for e in gen.load_sources() if e["id"] == "c004_escape_values")
    problems, same = gen._check(escape, runner.STREAMS_DIR / "c004_escape_values")
    assert not same and len(problems) == 1 and "escape" in problems[0], problems


def test_generator_rejects_unknown_ids(capsys):
    assert gen.main(["--check", "no_such_id"]) == 2
    assert "no_such_id" in capsys.readouterr().err
    assert gen.main(["--renders", "no_such_id"]) == 2


def test_derived_tools_follow_what_the_decoder_did():
    """`tools` come from the decoded result: escape exactly where an escaped residual was decoded."""
    sources = {e["id"]: e for e in gen.load_sources()}
    data = (runner.STREAMS_DIR / "c004_escape_values" / "stream.lghcc").read_bytes()
    with gen.EscapeCounter() as esc:
        from lghcc.decoder.decode import decode_stream
        decode_stream(data)
    assert esc.count > 0
    assert "escape" in gen.derive_tools(data)
    assert "escape" not in gen.derive_tools((runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc").read_bytes())
    from lghcc.common.entropy import symbol_coder
    from lghcc.common import attributes
    assert attributes.decode_symbols is symbol_coder.decode_symbols, "EscapeCounter must restore the decoder"
    for sid, tag in (("c020_idcm_mode_2", "geometry_idcm_2"), ("c015_geometry_origin_no_idcm", "geometry_idcm_0"),
                     ("c021_container_version_1_3", "container_version"), ("c017_empty_chunks", "empty_chunk"),
                     ("c010_ancillary_unit", "ancillary_unit"), ("e002_hash_mismatch", "hash"),
                     ("e007_crc_mismatch", "container"), ("e008_attribute_trailing_bytes", "attributes")):
        data = (runner.STREAMS_DIR / sid / "stream.lghcc").read_bytes()
        assert tag in gen.derive_tools(data, sources[sid].get("rejected_in")), (sid, tag)
    assert sources["e008_attribute_trailing_bytes"]["rejected_in"] == "attributes"
    with pytest.raises(SystemExit, match="no decoding stage rejects"):  # a stage declared for a stream that decodes
        gen.derive_tools((runner.STREAMS_DIR / "c001_one_anchor" / "stream.lghcc").read_bytes(), "geometry")


def test_runner_cli_and_external_decoder(capsys):
    assert runner.main(["c001_one_anchor", "e001_unknown_critical_unit"]) == 0
    out = capsys.readouterr().out
    assert "2 passed, 0 failed in" in out and "of imports, not counted" in out
    cmd = f"{sys.executable} -m lghcc.decoder.cli {{stream}} --print-hash"
    assert runner.main(["c004_escape_values", "e002_hash_mismatch", "--decoder-cmd", cmd]) == 0
    # A decoder that outputs a wrong hash fails, and the runner says so.
    assert runner.main(["c001_one_anchor", "--decoder-cmd", "echo " + "0" * 64 + " {stream}"]) == 1
    assert "FAIL" in capsys.readouterr().out
    assert runner.main(["no_such_stream"]) == 2
    with pytest.raises(SystemExit) as e:  # a template without {stream} is a usage error
        runner.main(["c001_one_anchor", "--decoder-cmd", "echo " + "0" * 64])
    assert e.value.code == 2 and "{stream}" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # --render with an external decoder needs {out}
        runner.main(["c002_procedural_medium", "--render", "--decoder-cmd", cmd])


def _external(tmp_path, body: str) -> str:
    script = tmp_path / "dec.py"
    script.write_text("import os, sys, time, signal\n" + body)
    return f"{sys.executable} {script} {{stream}}"


@pytest.mark.parametrize("body, note", [
    ("sys.exit(3)", "rejected a stream that must decode"),
    ("time.sleep(30)", "timed out after 2 s"),
    ("os.kill(os.getpid(), signal.SIGSEGV)", "killed by SIGSEGV"),
    ("sys.exit(1)", "not a verdict on the stream"),
    ("sys.exit(2)", "usage error"),
    ("sys.exit(4)", "resource limit"),
    ("sys.exit(130)", "interrupted"),
    ("sys.exit(7)", "exit code 7"),
    ("print('not a hash')", "not a SHA-256"),
])
def test_external_decoder_protocol_fails_crashes_hangs_and_blanket_rejections(tmp_path, body, note):
    """Only exit code 3 (invalid stream, lghcc.app.cli_common) counts as a rejection: a decoder that
    rejects everything fails the decodable streams; crashes, hangs, usage, input and resource
    errors fail every stream, since none of them is a verdict on the stream."""
    cmd = _external(tmp_path, body)
    cases = {c.id: c for c in runner.load_cases(ids=["c001_one_anchor", "e007_crc_mismatch"])}
    o = runner.run_case(cases["c001_one_anchor"], cmd, timeout=2)
    assert not o.passed and note in o.note, o.note
    o = runner.run_case(cases["e007_crc_mismatch"], cmd, timeout=2)
    assert o.passed == (body == "sys.exit(3)"), o.note
    if body != "sys.exit(3)" and "SHA" not in note:
        assert note in o.note


def test_external_rejection_is_checked_against_the_expected_class(tmp_path, monkeypatch):
    """Exit code 3 passes every error stream of the suite (each expects a BitstreamError subclass,
    exit code 3); an expected class with another exit code would need that code."""
    cmd = _external(tmp_path, "sys.exit(3)")
    cases = {c.id: c for c in runner.load_cases(ids=["e002_hash_mismatch", "e007_crc_mismatch",
                                                     "e011_unsupported_profile"])}
    for case in cases.values():
        assert runner.run_case(case, cmd).passed
    monkeypatch.setattr(runner, "exit_code_for_class", lambda name: 4)
    o = runner.run_case(cases["e007_crc_mismatch"], cmd)
    assert not o.passed and "is exit code 4" in o.note


def test_reference_decoder_error_class_and_reason_are_checked(tmp_path, monkeypatch):
    cases = {c.id: c for c in runner.load_cases(ids=["e007_crc_mismatch", "c001_one_anchor"])}
    case = cases["e007_crc_mismatch"]
    wrong_kind = runner.Case(case.id, case.folder, dict(case.meta, expect_error="HashMismatchError"))
    o = runner.run_case(wrong_kind)
    assert not o.passed and "instead of HashMismatchError" in o.note
    wrong_reason = runner.Case(case.id, case.folder, dict(case.meta, expect_message="level 2 is empty"))
    o = runner.run_case(wrong_reason)
    assert not o.passed and "another reason" in o.note

    def boom(_):
        raise IndexError("decoder bug")
    monkeypatch.setattr(runner, "decode_scene_internal", boom)  # an unexpected exception: a FAIL row
    o = runner.run_case(cases["c001_one_anchor"])
    assert not o.passed and "IndexError" in o.note


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.pop("decoded_sha256"), "missing decoded_sha256"),
    (lambda m: m.update(expect="maybe"), "unknown expect value"),
    (lambda m: m.update(decoded_sha256="xyz"), "not 64 lower-case hex"),
    (lambda m: m.update(stream_sha256="AB" * 32), "not 64 lower-case hex"),
    (lambda m: m.update(expect="error"), "an error stream has a decoded_sha256"),
    (lambda m: (m.update(expect="error"), m.pop("decoded_sha256")), "expect_error None is not one of"),
    (lambda m: m.update(renders={"cameras": "orbit:2"}), "renders: missing size"),
    (lambda m: m.update(source_info={"source_sh_degree": 4, "ignored": 0}), "is not 0..3 or null"),
    (lambda m: m.update(source_info={"source_sh_degree": 1}), "source_info is not a mapping"),
])
def test_invalid_test_yaml_is_reported_clearly(tmp_path, edit, message):
    src = runner.STREAMS_DIR / "c001_one_anchor"
    folder = tmp_path / "c001_one_anchor"
    folder.mkdir()
    (folder / "stream.lghcc").write_bytes((src / "stream.lghcc").read_bytes())
    meta = yaml.safe_load((src / "test.yaml").read_text())
    edit(meta)
    (folder / "test.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(runner.LghccError, match=message):
        runner.load_cases(tmp_path)
    assert runner.main(["--streams", str(tmp_path)]) == 2


def test_source_info_of_the_reference_decoder_is_checked():
    """test.yaml's source_info (informative, clauses 6.3 and 7.3.10): what the reference decoder
    outputs for the stream's source_info units, and how many it ignores."""
    cases = {c.id: c for c in runner.load_cases(ids=["c059_source_info_twice", "c061_source_info_malformed_then_well_formed"])}
    for case in cases.values():
        assert runner.run_case(case).passed
    twice = cases["c059_source_info_twice"]
    assert twice.meta["source_info"] == {"source_sh_degree": 1, "ignored": 1}
    wrong = runner.Case(twice.id, twice.folder, dict(twice.meta, source_info={"source_sh_degree": 3, "ignored": 1}))
    o = runner.run_case(wrong)
    assert not o.passed and "source_sh_degree 1, 1 ignored" in o.note and "3, 1 ignored" in o.note
    assert cases["c061_source_info_malformed_then_well_formed"].meta["source_info"] == {"source_sh_degree": None,
                                                                                         "ignored": 2}


def test_every_error_stream_names_its_rejection():
    for case in runner.load_cases():
        if case.expect == "error":
            assert case.meta["expect_error"] in runner.ERROR_KINDS and case.meta["expect_message"], case.id


def test_reference_renders_pass_and_a_perturbed_scene_fails():
    """Streams with reference renders: the decoded scene renders within the tolerance; the same scene
    with every feature scaled by 1.02 does not (renders are informative: a tolerance, not a hash)."""
    import torch

    from lghcc.decoder.decode import decode_stream

    with_renders = [c for c in runner.load_cases() if "renders" in c.meta]
    assert {"c002_procedural_medium", "c003_offset_masks", "c011_hierarchy_per_channel"} <= {c.id for c in with_renders}
    before = torch.get_num_threads()
    try:
        for threads in (1, 2):  # 2 threads: one stream (slow on shared cores); the tolerance absorbs it
            torch.set_num_threads(threads)
            for case in with_renders if threads == 1 else with_renders[:1]:
                o = runner.run_case(case, render=True)
                assert o.passed and "renders: PSNR" in o.note, (case.id, o.note)
    finally:
        torch.set_num_threads(before)
    case = with_renders[0]
    spec = case.meta["renders"]
    assert "not normative" in spec["note"]
    scene = decode_stream(case.stream.read_bytes()).scene
    ok, note = runner.compare_renders(scene, spec, case.folder)
    assert ok, note
    scene.features = scene.features * np.float32(1.02)  # a 2 % change of every feature
    ok, note = runner.compare_renders(scene, spec, case.folder)
    assert not ok and "tolerance" in note, note


def test_external_decoder_renders_from_its_output_scene(tmp_path):
    cmd = f"{sys.executable} -m lghcc.decoder.cli {{stream}} -o {{out}} --print-hash"
    assert runner.main(["c003_offset_masks", "--render", "--decoder-cmd", cmd]) == 0


def test_coverage_of_syntax_elements_and_value_classes():
    """Every element is exercised; every possible value class is exercised or listed in NOT_EXERCISED
    with its reason (and those stay in the denominator)."""
    cases = runner.load_cases()
    rep = coverage_report([c.stream for c in cases if c.expect == "decode"], [c for c in cases if c.expect == "error"])
    assert rep.elements_covered == len(rep.classes), rep.text()
    assert not rep.unexplained(), rep.text()
    assert rep.classes_covered == rep.classes_total - len(NOT_EXERCISED), rep.text()
    assert not rep.contradictions(), rep.text()
    assert not rep.stale(), "a stale IMPOSSIBLE / NOT_EXERCISED entry"
    assert len(rep.rejections) == sum(c.expect == "error" for c in cases)


def test_value_classes_have_minimum_maximum_and_enumerations():
    cls = element_classes()
    assert cls["geometry_header.geom_idcm_mode"] == [0, 1, 2]  # each mode its own class
    assert cls["render_mlp_header.num_layers_minus1"] == ["minimum", "other", "maximum"]
    assert cls["attribute_unit_header.rows_per_chunk_minus1"] == ["minimum", "other", "maximum"]
    assert cls["container_header.version_minor"] == ["minimum", "other", "maximum"]  # 0 (version 1.0) is the minimum
    assert "ancillary" in cls["data_unit_header.unit_type"]
    assert cls["scene_parameter_set.voxel_size"] == ["minimum", "other", "maximum"]
    assert cls["render_model_unit.coded_size"] == ["minimum", "other"]  # ue(v) without a limit: no maximum
    info = element_infos()
    rows = info["attribute_unit_header.rows_per_chunk_minus1"]
    assert value_class(rows, 6, 6) == "maximum" and value_class(rows, 3, 6) == "other"
    assert value_class(rows, 0, 0) == "minimum"
    assert value_class(info["render_mlp_header.weight_exponent"], 64) == "maximum"
    assert value_class(info["render_mlp_header.weight_exponent"], -3) == "negative"
    assert value_class(info["scene_parameter_set.origin"], -F32_MAX) == "minimum"


def test_impossible_prior_mean_beyond_se_v_range():
    """IMPOSSIBLE: se(v) codes at most 2^31 - 1 in magnitude, below prior_mean's syntax limit 2^40."""
    from lghcc.common.bitio import BitReader, BitWriter

    w = BitWriter()
    w.se((1 << 31) - 1)
    w.se(-((1 << 31) - 1))
    w.byte_align()
    r = BitReader(w.getvalue())
    assert (r.se(), r.se()) == ((1 << 31) - 1, -((1 << 31) - 1))
    with pytest.raises(ValueError):
        BitWriter().se(1 << 31)
    with pytest.raises(BitstreamError, match="Exp-Golomb"):
        BitReader(bytes(5) + b"\xff" * 4).ue()  # 32 leading zeros


def _units(case_id: str):
    return read_container((runner.STREAMS_DIR / case_id / "stream.lghcc").read_bytes()).units


def test_impossible_context_model_unit_without_coded_data():
    """IMPOSSIBLE: an empty context-model chunk decodes parent_base (the first array of both models)
    as -L <= -4: outside an unsigned width, and outside 0 .. 1 when declared signed."""
    assert int(HALF_WIDTHS.min()) >= 4
    for case_id in ("c012_parent_mlp_context", "c019_ggconv_minimal"):
        payload = next(u.payload for u in _units(case_id) if u.unit_type == UnitType.CONTEXT_MODEL)
        sps = SceneParameterSet.from_bytes(_units(case_id)[0].payload)
        for signed in (0, 1):
            unit = ContextModelUnit.from_bytes(payload)
            unit.arrays[0].array_signed_flag, unit.arrays[0].array_bits_minus1 = signed, 7
            unit.coded_size, unit.coded_data = 0, b""
            with pytest.raises(BitstreamError, match="parent_base|outside its"):  # (or a later array first)
                read_context_model(unit.to_bytes(), attr.layout_of(sps))


def test_impossible_context_model_arrays_of_0_or_3_dimensions():
    """IMPOSSIBLE: no context-model array has 0 or 3 dimensions (the scalars are syntax elements);
    each array of both models, given either, is rejected."""
    for case_id in ("c012_parent_mlp_context", "c019_ggconv_minimal"):
        payload = next(u.payload for u in _units(case_id) if u.unit_type == UnitType.CONTEXT_MODEL)
        sps = SceneParameterSet.from_bytes(_units(case_id)[0].payload)
        n = len(ContextModelUnit.from_bytes(payload).arrays)
        for a, ndim in itertools.product(range(n), (0, 3)):
            model_id, hp, arrays = read_context_model_unit(payload)
            v = arrays[a].values
            v = v.reshape(-1)[0] if ndim == 0 else v.reshape(1, 1, v.size)  # one value; or all in 3 dimensions
            arrays[a] = NamedIntArray(arrays[a].name, np.asarray(v), arrays[a].bits, arrays[a].signed)
            with pytest.raises(BitstreamError):
                read_context_model(write_context_model_unit(model_id, hp, arrays), attr.layout_of(sps))


def test_impossible_coarse_voxel_scale_one():
    """IMPOSSIBLE: decoded coordinates are distinct, so coarse voxels of 1 leave level 2 empty (e006)."""
    for case_id in ("c011_hierarchy_per_channel", "c019_ggconv_minimal"):
        units = _units(case_id)
        sps = SceneParameterSet.from_bytes(units[0].payload)
        coords = decode_geometry(next(u.payload for u in units if u.unit_type == UnitType.GEOMETRY), sps.num_points)
        assert np.unique(coords, axis=0).shape[0] == sps.num_points
        assert build_hierarchy(coords, 1).num_level2 == 0


def test_empty_chunks_decode_as_bin_zero():
    """c017: its empty chunks hold, per spec 10.6.4, residual -L_level for every coded value (checked here
    against the header, independently of the range decoder), and every offset of an empty mask chunk is dead."""
    from lghcc.decoder.decode import decode_stream

    units = _units("c017_empty_chunks")
    sps = SceneParameterSet.from_bytes(units[0].payload)
    layout = attr.layout_of(sps)
    h = AttributeUnitHeader.parse(BitReader(units[2].payload), num_channels=layout.num_channels,
                                  num_offsets=sps.num_offsets, offset_mask_present=1, num_rows=sps.num_points)
    assert h.chunk_size[1] == h.mask_chunk_size[1] == h.chunk_size[3] == 0 and h.mask_chunk_size[3] > 0
    scene = decode_stream((runner.STREAMS_DIR / "c017_empty_chunks" / "stream.lghcc").read_bytes()).scene
    values = layout.join(scene.features, scene.scalings, scene.offsets)
    q = np.asarray(h.prior_mean) - HALF_WIDTHS[np.asarray(h.prior_level)]
    want = attr.reconstruct(q[None, :], layout.steps(sps))[0]
    s = h.rows_per_chunk
    assert not scene.offset_mask[s:2 * s].any()
    assert np.array_equal(values[s:2 * s, :layout.offset_start], np.broadcast_to(want[:layout.offset_start],
                                                                                 (s, layout.offset_start)))
    assert not values[s:2 * s, layout.offset_start:].any()
    rows = values[3 * s:4 * s]
    live = layout.live_channels(scene.offset_mask[3 * s:4 * s], s)
    live = np.ones_like(rows, dtype=bool) if live is None else live
    assert np.array_equal(rows[live], np.broadcast_to(want, rows.shape)[live])
    assert not rows[~live].any()


def _decode_or_error(stream) -> str:
    try:
        return runner.decode_internal(stream)
    except BitstreamError as e:
        return f"{type(e).__name__}: {e}"


@pytest.mark.integration
def test_decoding_is_identical_with_1_and_2_torch_threads():
    """Cross-environment determinism, within one machine: every stream decodes to the same hash with
    1 and with 2 torch threads (intra-op parallelism must not change a bit), and every error stream
    is rejected with the same error class and message."""
    import torch

    cases = runner.load_cases()
    before = torch.get_num_threads()
    results = {}
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results[threads] = {c.id: _decode_or_error(c.stream) for c in cases}
    finally:
        torch.set_num_threads(before)
    assert results[1] == results[2]
    assert {c.id: results[1][c.id] for c in cases if c.expect == "decode"} == \
        {c.id: c.meta["decoded_sha256"] for c in cases if c.expect == "decode"}
    for c in cases:
        if c.expect == "error":
            assert results[1][c.id].startswith(c.meta["expect_error"] + ": "), (c.id, results[1][c.id])
            assert c.meta["expect_message"] in results[1][c.id], c.id


def _box_decodes():
    """(case, its parsed stream, partial decode) for every box of the suite's partial_decodes."""
    from lghcc.decoder.decode import parse_stream

    for case in runner.load_cases():
        boxes = [p for p in case.meta.get("partial_decodes", []) if "box" in p]
        if boxes:
            s = parse_stream(case.stream.read_bytes())
            for p in boxes:
                yield case, s, p


def test_partial_decode_boxes_select_a_strict_subset_of_the_tiles():
    """Issue 35: every box selects a proper subset of its stream's tiles (empty exactly where its
    purpose says 'no tile'), so a decoder that ignores the box, or gets the tile test wrong, fails;
    and the boxes vary: one tile, a few, none, previews of a part."""
    from lghcc.common.tiles import Box
    from lghcc.decoder.decode import selected_tiles

    sizes, previews = [], 0
    for case, s, p in _box_decodes():
        where = f"{case.id} box {p['box']}"
        tiles = p["tiles"]
        assert set(tiles) < set(range(len(s.tiles))), f"{where}: selects every tile of {len(s.tiles)}"
        assert len(tiles) == p["tiles_decoded"], where
        assert (not tiles) == p["purpose"].startswith("no tile"), f"{where}: {len(tiles)} tiles, {p['purpose']!r}"
        assert tiles == selected_tiles(s.tiles, s.ps, Box(tuple(p["box"][:3]), tuple(p["box"][3:]))), where
        whole = case.meta["decoded_sha256"] if "level" not in p else \
            next(q for q in case.meta["partial_decodes"] if q.get("level") == 1 and "box" not in q)["decoded_sha256"]
        assert p["decoded_sha256"] != whole, f"{where}: the hash of the unselected decode"
        sizes.append(len(tiles))
        previews += "level" in p
    assert sizes.count(0) >= 4 and sizes.count(1) >= 4 and sum(n > 1 for n in sizes) >= 6 and previews >= 4


def test_partial_decode_tile_count_is_checked(tmp_path):
    """The runner holds the reference decoder to tiles_decoded, and test.yaml's tiles to it."""
    case = runner.load_cases(ids=["c078_neighbour_prediction_tiles"])[0]
    parts = [dict(p) for p in case.meta["partial_decodes"]]
    parts[0]["tiles_decoded"] += 1
    o = runner.run_case(runner.Case(case.id, case.folder, dict(case.meta, partial_decodes=parts)))
    assert not o.passed and "tiles decoded" in o.note
    parts[0]["tiles"] = [0, 0]
    with pytest.raises(runner.LghccError, match="increasing tile indices"):
        runner.validate_partial_decodes(parts, "decode", case.folder)


def test_a_preview_without_the_hierarchy_is_held_to_its_refusal(monkeypatch):
    """Clause 13.3: a stream without the hierarchy has no level-1 preview. The suite's refused
    previews (an anchor stream with and without masks, an explicit-Gaussian one) pass by refusing;
    a decoder that outputs the whole decode as the preview fails them; a refused entry carries no hash."""
    from lghcc.decoder import decode

    cases = runner.load_cases(ids=["c065_tiles_small", "c069_gaussian_tiles_at_maximum_scale",
                                   "c121_tiles_offset_masks"])
    for case in cases:
        assert any(p.get("refused") for p in case.meta["partial_decodes"]), case.id
        assert runner.run_case(case).passed, case.id
    whole = decode.decode_stream
    monkeypatch.setattr(decode, "decode_stream", lambda data, box=None, max_level=2: whole(data, box=box))
    o = runner.run_case(cases[0])
    assert not o.passed and "expected a refusal" in o.note
    bad = [{"level": 1, "refused": True, "decoded_sha256": "0" * 64}]
    with pytest.raises(runner.LghccError, match="refused: true goes with level: 1 alone"):
        runner.validate_partial_decodes(bad, "decode", cases[0].folder)


def test_a_box_that_selects_no_tile_outputs_the_empty_scene():
    """Clause 13.3: no tile selected is no error; the output is the scene of N = 0 with the stream's
    header (for an explicit-Gaussian stream, an anchor stream and a level-1 preview)."""
    from lghcc.common.hashing import digest_of
    from lghcc.common.tiles import Box
    from lghcc.decoder.decode import decode_stream

    far = Box((1e308,) * 3, (1.7976931348623157e308,) * 3)
    for sid, level in (("c078_neighbour_prediction_tiles", 2), ("c062_tiles_ggconv", 2), ("c063_tiles_gaussians", 1)):
        data = (runner.STREAMS_DIR / sid / "stream.lghcc").read_bytes()
        res = decode_stream(data, box=far, max_level=level, jobs=2, exact_jobs=True)
        assert res.tiles_decoded == 0 and len(res.scene.coords) == 0, sid
        assert len(digest_of(res.scene).hex()) == 64
