"""The step-adjustment indices as flags (format 1.5, clauses 7.3.16 and 11.8): bit-exact round trips of
the flag chunks and of whole streams, the same decoded scene as with the indices as symbols, the
encoder's choice between the two, and the version a stream declares (the hard cases: test_step_adjust.py,
with and without flags)."""

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from lghcc.common.container import UnitType, read_container
from lghcc.common.errors import BitstreamError
from lghcc.common.neighbour_prediction import (chunk_neighbours, decode_adjust_chunk, encode_adjust_chunk,
                                               neighbour_graph, step_flag_weights)
from lghcc.common.sh_degree import decode_flag_chunk, encode_flag_chunk, neighbour_degrees
from lghcc.common.units import NUM_STEP_FLAG_CONTEXTS, AttributeUnitHeader, StepAdjustFlagsUnit, StepAdjustUnit
from lghcc.decoder.decode import decode_stream
from lghcc.encoder.gaussians.gaussians import encode_gaussian_scene
from lghcc.encoder.stream.config import GaussianEncoderConfig
from lghcc.encoder.stream.neighbour_coding import flag_bits, flag_counts, flag_probabilities
from test_gaussians import assert_same, random_gaussians
from test_neighbour_prediction import _smooth_scene
from test_step_adjust import _sensitivity


def _units(data: bytes) -> list[int]:
    return [u.unit_type for u in read_container(data).units]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 400), st.integers(0, 7), st.integers(1, 5), st.integers(1, 6), st.booleans(),
       st.integers(0, 2 ** 31))
def test_flag_chunks_round_trip_in_their_neighbours_contexts(n, top, lods, k, extreme, seed):
    """Every LoD's chunk of indices, coded as flags in the contexts of its rows' neighbours (rows of
    coarser LoDs), decodes to its indices; with probabilities from the counts or at both ends of the
    element's range (0 and 4095: a flag of the unlikely value still codes, in more bits)."""
    rng = np.random.default_rng(seed)
    coords = rng.integers(0, 64, (n, 3))
    coords = np.unique(coords, axis=0)
    graph = neighbour_graph(coords, lods, k)
    adjust = rng.integers(0, top + 1, coords.shape[0]) if seed % 3 else np.full(coords.shape[0], top)
    probs = [4095 * (i % 2) for i in range(top * NUM_STEP_FLAG_CONTEXTS)] if extreme else \
        flag_probabilities(flag_counts(graph, adjust, top))
    unit = StepAdjustFlagsUnit(max_step_adjust=top, step_flag_prob=probs)
    assert StepAdjustFlagsUnit.from_bytes(unit.to_bytes(), max_step_adjust=top) == unit
    h = AttributeUnitHeader()
    for level, rows in enumerate(graph.rows):
        if not rows.size:
            continue
        chunk = encode_adjust_chunk(adjust, rows, h, graph, level, 0, rows.size, unit)
        nd = neighbour_degrees(chunk_neighbours(graph, level, 0, rows.size), adjust)
        got = decode_adjust_chunk(chunk, h, StepAdjustUnit(max_step_adjust=top), rows.size, level, unit, nd)
        assert got.tolist() == adjust[rows].tolist()


def test_flags_cost_what_their_counts_say():
    """The flags' ideal bits (the encoder's estimate) against the bytes the coder writes."""
    rng = np.random.default_rng(3)
    coords = np.unique(rng.integers(0, 200, (5000, 3)), axis=0)
    graph = neighbour_graph(coords, 5, 6)
    adjust = np.minimum(rng.geometric(0.3, coords.shape[0]) - 1, 7)
    counts = flag_counts(graph, adjust, 7)
    probs = flag_probabilities(counts)
    w = step_flag_weights(StepAdjustFlagsUnit(max_step_adjust=7, step_flag_prob=probs))
    coded = 0
    for level, rows in enumerate(graph.rows):
        nd = neighbour_degrees(graph.neighbours[level], adjust) if level else None
        chunk = encode_flag_chunk(adjust[rows], nd, 7, w)
        assert decode_flag_chunk(chunk, rows.size, nd, 7, w, "t").tolist() == adjust[rows].tolist()
        coded += 8 * len(chunk)
    ideal = flag_bits(counts, probs)
    assert ideal <= coded <= ideal + 64 * len(graph.rows)  # each chunk's flush: at most 2 words


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(2, 300), st.integers(0, 2), st.integers(1, 7), st.sampled_from([0, 60]), st.sampled_from([7, 65536]),
       st.integers(0, 2 ** 31))
def test_flags_and_symbols_decode_to_the_same_scene(n, degree, top, tile_points, rows_per_chunk, seed):
    """The same scene with the indices as flags and as symbols: the same decoded scene, bit-exact
    round trips, version 5 exactly where the unit is written; the encoder writes it only where it
    codes smaller (by the ideal bits: a few bytes of the coder's flush either way)."""
    rng = np.random.default_rng(seed)
    scene = _smooth_scene(n, degree, seed) if seed % 2 else random_gaussians(rng, n, degree)
    f = _sensitivity(scene, rng)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=top, tile_points=tile_points,
                                rows_per_chunk=rows_per_chunk)
    flags = encode_gaussian_scene(scene, cfg, sensitivity=f)
    symbols = encode_gaussian_scene(scene, dataclasses.replace(cfg, step_adjust_flags=False), sensitivity=f)
    assert_same(flags.decoded, symbols.decoded)
    for res in (flags, symbols):
        dec = decode_stream(res.data, jobs=2 if tile_points and seed % 3 == 0 else 1, exact_jobs=True)
        assert dec.hash_checked
        assert_same(dec.scene, res.decoded)
    assert UnitType.STEP_ADJUST_FLAGS not in _units(symbols.data)
    used = UnitType.STEP_ADJUST_FLAGS in _units(flags.data)
    assert read_container(flags.data).header.version_minor == (5 if used else read_container(symbols.data).header.version_minor)
    if used:
        assert _units(flags.data).index(UnitType.STEP_ADJUST_FLAGS) == _units(flags.data).index(UnitType.STEP_ADJUST) + 1
        # the choice is by ideal bits, which do not see each chunk's flush (up to a word either way)
        chunks = (n // rows_per_chunk + 8) * (1 + (tile_points > 0) * n // 60)
        assert len(flags.data) <= len(symbols.data) + 16 + 4 * chunks
    else:
        assert flags.data == symbols.data


def test_skewed_indices_cost_fewer_bits_as_flags():
    """Indices piled at the coarsest step (as on real scenes: tools/results/step_flags.md) cost the
    symbols' one-mean, one-level model over 3 bits each; as flags far fewer."""
    scene = _smooth_scene(3000, 0, seed=12)
    rng = np.random.default_rng(12)
    f = _sensitivity(scene, rng, spread=6.0)
    cfg = GaussianEncoderConfig(neighbour_prediction="always", step_adjust_max=7)
    flags = encode_gaussian_scene(scene, cfg, sensitivity=f)
    symbols = encode_gaussian_scene(scene, dataclasses.replace(cfg, step_adjust_flags=False), sensitivity=f)
    assert UnitType.STEP_ADJUST_FLAGS in _units(flags.data)
    assert flags.stats.step_adjust_coded_bits < 0.85 * symbols.stats.step_adjust_coded_bits
    assert len(flags.data) < len(symbols.data)


@pytest.mark.parametrize("field", ["adjust_mean", "adjust_level"])
def test_a_header_model_beside_the_flags_is_rejected(field):
    """With a step_adjust_flags unit the header's adjust_mean and adjust_level shall be 0 (E67)."""
    h = AttributeUnitHeader()
    setattr(h, field, 1)
    from lghcc.common.neighbour_prediction import check_flag_header
    with pytest.raises(BitstreamError, match="where both shall be 0"):
        check_flag_header(h, "attribute unit")
    check_flag_header(AttributeUnitHeader(), "attribute unit")
