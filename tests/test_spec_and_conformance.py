"""Frozen artefacts: the spec's syntax tables match the code; the conformance streams decode
to their recorded hashes, the encoder reproduces them byte for byte, and the runner works."""

import hashlib
import importlib.util
import sys
from pathlib import Path

import pytest
import yaml

import numpy as np

from lghcc.common import attributes as attr
from lghcc.common.bitio import BitReader
from lghcc.common.container import UnitType, read_container
from lghcc.common.context.model_unit import ContextModelUnit
from lghcc.common.context.models import read_context_model
from lghcc.common.entropy.tables import HALF_WIDTHS
from lghcc.common.errors import BitstreamError
from lghcc.common.geometry import decode_geometry
from lghcc.common.hierarchy import build_hierarchy
from lghcc.common.spec_tables import syntax_tables_markdown
from lghcc.common.units import AttributeUnitHeader, SceneParameterSet
from lghcc.conformance import runner
from lghcc.conformance.coverage import IMPOSSIBLE, coverage_report

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


def test_coverage_of_syntax_elements_and_value_classes():
    cases = [c.stream for c in runner.load_cases() if c.meta.get("expect", "decode") == "decode"]
    rep = coverage_report(cases)
    assert rep.elements_covered == len(rep.classes), rep.text()
    assert rep.classes_covered == rep.classes_total, rep.text()
    assert not rep.contradictions(), rep.text()
    assert all(k in rep.classes and c in rep.classes[k] for k, c in IMPOSSIBLE), "a stale impossible class"


def _units(case_id: str):
    return read_container((runner.STREAMS_DIR / case_id / "stream.lghcc").read_bytes()).units


def test_impossible_context_model_unit_without_coded_data():
    """IMPOSSIBLE: an empty context-model chunk decodes num_features as -L <= -4, which both models reject."""
    assert int(HALF_WIDTHS.min()) >= 4
    for case_id in ("c012_parent_mlp_context", "c019_ggconv_minimal"):
        payload = next(u.payload for u in _units(case_id) if u.unit_type == UnitType.CONTEXT_MODEL)
        unit = ContextModelUnit.from_bytes(payload)
        unit.coded_size, unit.coded_data = 0, b""
        sps = SceneParameterSet.from_bytes(_units(case_id)[0].payload)
        with pytest.raises(BitstreamError, match="num_features|outside its"):
            read_context_model(unit.to_bytes(), attr.layout_of(sps))


def test_impossible_coarse_voxel_scale_one():
    """IMPOSSIBLE: decoded coordinates are distinct, so coarse voxels of 1 leave level 2 empty (e006)."""
    for case_id in ("c011_hierarchy_per_channel", "c019_ggconv_minimal"):
        units = _units(case_id)
        sps = SceneParameterSet.from_bytes(units[0].payload)
        coords = decode_geometry(next(u.payload for u in units if u.unit_type == UnitType.GEOMETRY), sps.num_anchors)
        assert np.unique(coords, axis=0).shape[0] == sps.num_anchors
        assert build_hierarchy(coords, 1).num_level2 == 0


def test_empty_chunks_decode_as_bin_zero():
    """c017: its empty chunks hold, per spec 10.6.4, residual -L_level for every coded value (checked here
    against the header, independently of the range decoder), and every offset of an empty mask chunk is dead."""
    from lghcc.decoder.decode import decode_stream

    units = _units("c017_empty_chunks")
    sps = SceneParameterSet.from_bytes(units[0].payload)
    layout = attr.layout_of(sps)
    h = AttributeUnitHeader.parse(BitReader(units[2].payload), num_channels=layout.num_channels,
                                  num_offsets=sps.num_offsets, offset_mask_present=1, num_rows=sps.num_anchors)
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


def test_decoding_is_identical_with_1_and_2_torch_threads():
    """Cross-environment determinism, within one machine: every stream decodes to the same hash with
    1 and with 2 torch threads (intra-op parallelism must not change a bit)."""
    import torch

    cases = [c for c in runner.load_cases() if c.meta.get("expect", "decode") == "decode"]
    before = torch.get_num_threads()
    digests = {}
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            digests[threads] = {c.id: runner.decode_internal(c.stream) for c in cases}
    finally:
        torch.set_num_threads(before)
    assert digests[1] == digests[2]
    assert digests[1] == {c.id: c.meta["decoded_sha256"] for c in cases}
