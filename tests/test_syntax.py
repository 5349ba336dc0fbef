"""Bit I/O and the syntax visitors: write, read and size are one description."""

import pytest
from hypothesis import given, strategies as st

from lghcc.common.bitio import BitReader, BitWriter
from lghcc.common.errors import BitstreamError
from lghcc.common.syntax import TraceEntry
from lghcc.common.units import (AttributeUnitHeader, RenderMlpHeader, RenderModelUnit, SceneParameterSet)

elements = st.lists(st.one_of(
    st.tuples(st.just("u"), st.integers(0, 64).flatmap(lambda n: st.tuples(st.just(n), st.integers(0, 2 ** n - 1)))),
    st.tuples(st.just("ue"), st.integers(0, 2 ** 32 - 2)),
    st.tuples(st.just("se"), st.integers(-(2 ** 31) + 1, 2 ** 31 - 1)),
), max_size=50)


@given(elements)
def test_bitio_round_trip(items):
    w = BitWriter()
    for kind, val in items:
        if kind == "u":
            w.u(val[0], val[1])
        else:
            getattr(w, kind)(val)
    w.byte_align()
    r = BitReader(w.getvalue())
    for kind, val in items:
        if kind == "u":
            assert r.u(val[0]) == val[1]
        else:
            assert getattr(r, kind)() == val
    r.byte_align()
    assert r.bits_left == 0


def test_reader_names_the_element_on_truncation():
    with pytest.raises(BitstreamError, match="num_things"):
        BitReader(b"\x00").ue("num_things")
    with pytest.raises(BitstreamError, match="ends while reading x"):
        BitReader(b"\x01").u(16, "x")


def test_writer_rejects_values_that_do_not_fit():
    with pytest.raises(ValueError):
        BitWriter().u(3, 8)
    with pytest.raises(ValueError):
        BitWriter().ue(-1)


sps_strategy = st.builds(
    SceneParameterSet,
    num_anchors_minus1=st.integers(0, (1 << 24) - 1), feature_dim_minus1=st.integers(0, 1023),
    num_offsets_minus1=st.integers(0, 63),
    voxel_size=st.floats(2.0 ** -100, 2.0 ** 100, width=32),
    origin=st.lists(st.floats(-2.0 ** 100, 2.0 ** 100, width=32), min_size=3, max_size=3),
    offset_mask_present_flag=st.integers(0, 1),
    feature_step=st.floats(2.0 ** -100, 2.0 ** 100, width=32), scaling_step=st.floats(2.0 ** -100, 2.0 ** 100, width=32),
    offset_step=st.floats(2.0 ** -100, 2.0 ** 100, width=32))


@given(sps_strategy)
def test_sps_round_trip_and_size(sps):
    data = sps.to_bytes()
    assert SceneParameterSet.from_bytes(data) == sps
    assert (sps.bit_size() + 7) // 8 == len(data)


@given(st.integers(1, 3).flatmap(lambda n: st.lists(st.builds(
    lambda layers, ind, acts, e: RenderMlpHeader(
        mlp_role=acts[0] % 4, num_layers_minus1=layers - 1, input_dim_minus1=ind,
        output_dim_minus1=[ind % 50] * layers, activation=[a % 4 for a in (acts * layers)[:layers]],
        weight_exponent=[e] * layers, weight_level=[5] * layers, bias_exponent=[-e] * layers,
        bias_level=[63] * layers),
    st.integers(1, 8), st.integers(0, 4095), st.lists(st.integers(0, 3), min_size=1, max_size=8),
    st.integers(-64, 64)), min_size=n, max_size=n)), st.binary(max_size=64))
def test_nested_structures_round_trip_with_trace(mlps, coded):
    unit = RenderModelUnit(num_mlps=len(mlps), mlps=mlps, coded_size=len(coded), coded_data=coded)
    trace_w: list[TraceEntry] = []
    from lghcc.common.bitio import BitWriter as W
    w = W()
    unit.write_to(w, trace_w)
    w.byte_align()
    trace_r: list[TraceEntry] = []
    back = RenderModelUnit.from_bytes(w.getvalue(), trace_r)
    assert back == unit
    assert [(e.bit_position, e.name, e.value) for e in trace_r] == [(e.bit_position, e.name, e.value) for e in trace_w]
    assert any(e.name == "render_mlp_header.weight_exponent[0]" for e in trace_r)


def test_reader_rejects_out_of_range_values_by_name():
    bad = SceneParameterSet()
    w = BitWriter()
    w.ue(5)
    w.ue(2000)  # feature_dim_minus1 beyond 1023
    w.byte_align()
    with pytest.raises(BitstreamError, match=r"feature_dim_minus1 = 2000\b"):
        SceneParameterSet.from_bytes(w.getvalue() + bytes(40))
    assert bad.feature_dim == 1


def test_f32_rejects_nan_and_nonpositive_steps():
    sps = SceneParameterSet(voxel_size=float("nan"))
    with pytest.raises(ValueError):
        sps.to_bytes()
    good = bytearray(SceneParameterSet().to_bytes())
    # voxel_size starts after three ue(v) "1" bits: patch it to +0.0 -> must be rejected
    w = BitWriter()
    w.ue(0); w.ue(0); w.ue(0); w.u(32, 0)
    for _ in range(3):
        w.u(32, 0)
    w.u(1, 0)
    for _ in range(3):
        w.u(32, 0x3F800000)
    w.byte_align()
    with pytest.raises(BitstreamError, match=r"voxel_size=0.0\b.*zero"):
        SceneParameterSet.from_bytes(w.getvalue())
    assert len(good) == len(w.getvalue())


def test_attribute_header_depends_on_context_only_through_parsed_counts():
    h = AttributeUnitHeader(num_channels=3, num_offsets=2, offset_mask_present=1, num_rows=10,
                            prior_mean=[0, -5, 7], prior_level=[1, 2, 63], mask_live_prob=[1, 4095],
                            rows_per_chunk_minus1=3, mask_chunk_size=[4, 4, 4], chunk_size=[8, 12, 0])
    assert h.num_chunks == 3
    back = AttributeUnitHeader.from_bytes(h.to_bytes(), num_channels=3, num_offsets=2, offset_mask_present=1,
                                          num_rows=10)
    assert back == h


def test_syntax_table_shows_blocks():
    table = AttributeUnitHeader.syntax_table()
    assert "if( context_model_id == 0 ) {" in table
    assert "for( c = 0; c < NumChannels; c++ ) {" in table
    assert "prior_level[ c ] | u(6)" in table
    assert table.count("{") == table.count("}")


def test_syntax_table_index_follows_the_loop_variable():
    # Each array element is indexed by the variable of the loop around it, never a fixed [ i ].
    import re

    from lghcc.common.spec_tables import all_structures

    checked = 0
    for cls in all_structures():
        blocks: list[str | None] = []  # loop variable, or None for an if block
        for line in cls.syntax_table().splitlines()[2:-1]:
            text = line.split("|")[1].replace("&nbsp;", "").strip()
            if m := re.fullmatch(r"for\( (\w+) = 0; .*\{", text):
                blocks.append(m.group(1))
            elif text.startswith("if("):
                blocks.append(None)
            elif text == "}":
                blocks.pop()
            elif m := re.fullmatch(r"\w+\[ (\w+) \]", text):
                loops = [b for b in blocks if b is not None]
                assert loops and m.group(1) == loops[-1], (cls.syntax_name, text, blocks)
                checked += 1
        assert not blocks
    assert checked >= 12  # origin, geometry header, MLP layers, priors, masks, chunks, array dims
    table = RenderMlpHeader.syntax_table()
    assert "output_dim_minus1[ l ] | ue(v)" in table and "[ i ]" not in table


def test_syntax_table_says_what_n_is_in_byte_strings():
    from lghcc.common.context.model_unit import ContextModelUnit
    from lghcc.common.units import DecodedSceneHashUnit

    assert "coded_data | b(8*coded_size) |" in RenderModelUnit.syntax_table()
    assert "coded_data | b(8*coded_size) |" in ContextModelUnit.syntax_table()
    assert "scene_hash | b(8*32) |" in DecodedSceneHashUnit.syntax_table()
    # The trace of a real stream gives the actual byte count.
    trace: list[TraceEntry] = []
    unit = DecodedSceneHashUnit(scene_hash=bytes(range(32)))
    DecodedSceneHashUnit.from_bytes(unit.to_bytes(), trace=trace)
    assert [e.descriptor for e in trace] == ["u(8)", "b(8*32)"]
