"""Frozen artefacts: the spec's syntax tables match the code; the conformance streams decode
to their recorded hashes, the encoder reproduces them byte for byte, and the runner works."""

import hashlib
import importlib.util
import sys
from pathlib import Path

import pytest
import yaml

from lghcc.common.spec_tables import syntax_tables_markdown
from lghcc.conformance import runner
from lghcc.conformance.coverage import coverage_report

ROOT = Path(__file__).resolve().parents[1]


def _gen_module():
    spec = importlib.util.spec_from_file_location("gen_conformance", ROOT / "tools" / "gen_conformance.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


def test_encoder_reproduces_every_stream_byte_for_byte():
    gen = _gen_module()
    sources = {e["id"]: e for e in gen.load_sources()}
    cases = runner.load_cases()
    assert set(sources) == {c.id for c in cases}, "sources.yaml and conformance/streams disagree"
    for case in cases:
        data, decoded = gen.generate(sources[case.id])
        assert data == case.stream.read_bytes(), f"{case.id}: the encoder no longer reproduces the stream"
        assert decoded == case.meta.get("decoded_sha256")


def test_runner_cli_and_external_decoder(capsys):
    assert runner.main(["c001_one_anchor", "e001_unknown_critical_unit"]) == 0
    assert "2 passed, 0 failed" in capsys.readouterr().out
    cmd = f"{sys.executable} -m lghcc.decoder.cli {{stream}} --print-hash"
    assert runner.main(["c004_escape_values", "e002_hash_mismatch", "--decoder-cmd", cmd]) == 0
    # A decoder that outputs a wrong hash fails, and the runner says so.
    assert runner.main(["c001_one_anchor", "--decoder-cmd", "echo " + "0" * 64]) == 1
    assert "FAIL" in capsys.readouterr().out
    assert runner.main(["no_such_stream"]) == 2


def test_coverage_of_syntax_elements():
    cases = [c.stream for c in runner.load_cases() if c.meta.get("expect", "decode") == "decode"]
    rep = coverage_report(cases)
    assert rep.elements_covered == len(rep.classes), rep.text()
