"""A short fuzz run of the decoder with the engine of tools/fuzz_decoder.py (lghcc.conformance.fuzz):
mutated conformance streams end in LghccError or a valid decode, quickly, without huge
allocations. The long run is `python tools/fuzz_decoder.py --minutes N`."""

import random
import time

import pytest

from lghcc.conformance import fuzz
from lghcc.conformance.fuzz import Mutator, Sandbox, load_seeds, replace_element, run_campaign


@pytest.fixture(scope="module")
def mutator():
    seeds = load_seeds()
    # the small streams keep this run short; the tool mutates every stream
    return Mutator({k: v for k, v in seeds.items() if len(v) < 20_000 and not k.startswith("c013")})


def test_short_fuzz_run_finds_no_bug(mutator, tmp_path):
    t0 = time.perf_counter()
    summary = run_campaign(mutator, seed=20240601, cases=300, timeout=5.0, memory_mb=2048, failures_dir=tmp_path)
    assert summary.cases == 300
    assert summary.bugs == 0, "\n".join(f"{k}: {w}\n{d}" for k, w, d, _ in summary.failures[:3])
    assert sum(n for k, n in summary.outcomes.items() if k.startswith("error")) > 0
    assert time.perf_counter() - t0 < 25


def test_every_mutation_kind_produces_bytes(mutator):
    rng = random.Random(5)
    for op in mutator.ops:
        for sid in mutator.ids[:4]:
            data, what = getattr(mutator, "_" + op)(rng, sid)
            assert isinstance(data, bytes) and isinstance(what, str)


def test_syntax_elements_are_located_exactly(mutator):
    """Re-coding each element with its own value gives the unit back: positions and lengths are right;
    a different value changes the unit and reaches the parser."""
    for sid in mutator.ids:
        units = mutator._units[sid]
        els = mutator.elements(sid)
        assert {e.name.split(".")[0] for e in els} >= {"scene_parameter_set", "geometry_header",
                                                       "attribute_unit_header", "decoded_scene_hash_unit"}
        for el in els:
            assert replace_element(units[el.unit].payload, el, el.value) == units[el.unit].payload, (sid, el)


def test_chunk_sizes_and_counts_are_mutated(mutator):
    names = {e.name.split("[")[0] for sid in mutator.ids for e in mutator.elements(sid)}
    for n in ("attribute_unit_header.chunk_size", "attribute_unit_header.mask_chunk_size",
              "render_model_unit.coded_size", "render_mlp_header.output_dim_minus1",
              "context_model_unit.coded_size", "int_array_header.array_dim_minus1",
              "scene_parameter_set.num_anchors_minus1"):
        assert n in names


_classify = fuzz.classify


def _fake_classify(data: bytes):
    if data == b"sleep":
        time.sleep(30)
    if data == b"alloc":
        import numpy as np
        np.empty(4 << 30, np.uint8)  # 4 GiB, not touched: only the address-space limit stops it
    if data == b"die":
        import os
        os._exit(3)
    return _classify(data)


def test_sandbox_reports_timeouts_memory_and_crashes(monkeypatch):
    monkeypatch.setattr(fuzz, "classify", _fake_classify)  # the forked worker inherits the patch
    with Sandbox(timeout=1.0, memory_mb=512) as box:
        assert box.run(b"sleep")[0] == "BUG: timeout"
        assert box.run(b"alloc")[0] == "BUG: MemoryError"
        assert box.run(b"die")[0] == "BUG: worker died"
        kind, detail, _ = box.run(b"LGHC")  # the worker restarts after each of those
        assert kind == "error: BitstreamError" and "shorter than the container header" in detail
