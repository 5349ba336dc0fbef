"""The context-model unit (common/context/model_unit.py, spec clause 7.3.7): the model's scalar
hyperparameters are syntax elements with ranges, checked as they are parsed; the arrays round-trip."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.bitio import BitWriter
from lghcc.common.context.model_unit import (MAX_CONTEXT_PARAMETERS, ContextModelUnit, Hyperparameters,
                                             NamedIntArray, array_names, read_context_model_unit,
                                             write_context_model_unit)
from lghcc.common.errors import BitstreamError
from lghcc.common.syntax import TraceEntry
from lghcc.common.units import CONTEXT_GGCONV, CONTEXT_PARENT_MLP
from lghcc.conformance.fuzz import Element, code_bits, replace_element

GGCONV_ONLY = ("neighbour_level", "k", "radius_sq_bits_minus1", "radius_sq", "h_shift", "feat_layer_shift")

shifts = st.lists(st.integers(0, 31), min_size=1, max_size=8)


@st.composite
def hyperparameters(draw, model_id=None):
    model_id = draw(st.sampled_from([CONTEXT_PARENT_MLP, CONTEXT_GGCONV])) if model_id is None else model_id
    hp = Hyperparameters(draw(st.integers(1, 1024)), draw(shifts))
    if model_id == CONTEXT_GGCONV:
        hp = dataclasses.replace(hp, feat_layer_shift=draw(shifts), neighbour_level=draw(st.sampled_from([1, 2])),
                                 k=draw(st.integers(1, 64)), radius_sq=draw(st.integers(1, (1 << 62) - 1)),
                                 h_shift=draw(st.integers(0, 40)))
    return model_id, hp


def small_arrays(model_id: int, hp: Hyperparameters, seed: int) -> list[NamedIntArray]:
    """Arrays of the model's names with small shapes and values (the unit does not relate them)."""
    rng = np.random.default_rng(seed)
    feat = len(hp.feat_layer_shift or [])
    out = []
    for name in array_names(model_id, feat, len(hp.head_layer_shift)):
        ndim = 4 if name == "table" else 2 if name.endswith("weight") else 1
        bits, signed = (1, False) if name == "parent_base" else (16, True)
        lo = 0 if not signed else -(1 << (bits - 1))
        out.append(NamedIntArray(name, rng.integers(lo, 1 << (bits - 1 if signed else bits), (2,) * ndim), bits,
                                 signed))
    return out


def unit_with_trace(model_id: int, hp: Hyperparameters, arrays) -> tuple[bytes, list[TraceEntry]]:
    """The unit's bytes and the writer's trace of its elements (bit positions)."""
    payload = write_context_model_unit(model_id, hp, arrays)
    unit = ContextModelUnit.from_bytes(payload)
    trace: list[TraceEntry] = []
    w = BitWriter()
    unit.write_to(w, trace)
    w.byte_align()
    assert w.getvalue() == payload
    return payload, trace


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(hyperparameters(), st.integers(0, 2 ** 32 - 1))
def test_hyperparameters_round_trip(model_hp, seed):
    model_id, hp = model_hp
    arrays = small_arrays(model_id, hp, seed)
    payload, trace = unit_with_trace(model_id, hp, arrays)
    got_id, got_hp, got_arrays = read_context_model_unit(payload)
    assert got_id == model_id and got_hp == hp
    assert [(a.name, a.bits, a.signed) for a in got_arrays] == [(a.name, a.bits, a.signed) for a in arrays]
    assert all(np.array_equal(a.values, b.values) for a, b in zip(got_arrays, arrays))
    names = {e.name.split(".")[1].split("[")[0] for e in trace}
    # a tool a scene does not use costs no bits: a parent-MLP unit has no GG-Conv element
    assert names.isdisjoint(GGCONV_ONLY) == (model_id == CONTEXT_PARENT_MLP)
    if model_id == CONTEXT_GGCONV:  # radius_sq in the fewest bits
        width = next(e for e in trace if e.name == "context_model_unit.radius_sq").descriptor
        assert width == f"u({hp.radius_sq.bit_length()})"


# each element with a range that its descriptor can exceed: values outside it, as the descriptor codes them
OUT_OF_RANGE = {
    "context_model_id": st.sampled_from([0, 3, 4, 7]),
    "feat_num_layers_minus1": st.integers(8, 1 << 20),
    "head_num_layers_minus1": st.integers(8, 1 << 20),
    "num_features": st.one_of(st.just(0), st.integers(1025, 1 << 31)),
    "neighbour_level": st.sampled_from([0, 3]),
    "k": st.one_of(st.just(0), st.integers(65, 1 << 31)),
    "radius_sq_bits_minus1": st.sampled_from([62, 63]),
    "radius_sq": st.just(0),
    "h_shift": st.integers(41, 63),
}


@settings(max_examples=120, deadline=None, derandomize=True, database=None)
@given(hyperparameters(), st.data())
def test_each_hyperparameter_out_of_range_is_rejected(model_hp, data):
    """Every element outside its range of clause 7.2 is rejected as it is parsed, the message naming
    it; the writer refuses to write it (an encoder bug)."""
    model_id, hp = model_hp
    payload, trace = unit_with_trace(model_id, hp, small_arrays(model_id, hp, 0))
    elements = [e for e in trace if e.name.split(".", 1)[1] in OUT_OF_RANGE]
    e = data.draw(st.sampled_from(elements))
    name = e.name.split(".", 1)[1]
    value = data.draw(OUT_OF_RANGE[name])
    el = Element(0, e.bit_position, len(code_bits(e.descriptor, e.value)), e.name, e.descriptor, e.value)
    bad = replace_element(payload, el, value)
    with pytest.raises(BitstreamError, match=rf"context_model_unit\.{name} = {value} is outside its allowed range"):
        read_context_model_unit(bad)
    if name in ("num_features", "k", "h_shift", "neighbour_level", "radius_sq") and \
            (model_id == CONTEXT_GGCONV or name == "num_features"):
        with pytest.raises(ValueError, match=rf"{name} = {value} is outside its allowed range"):
            write_context_model_unit(model_id, dataclasses.replace(hp, **{name: value}),
                                     small_arrays(model_id, hp, 0))


def test_layer_shifts_take_every_value_of_u5():
    """A layer's shift is u(5): its range [0, 31] (Annex H.4) is every value of the descriptor."""
    hp = Hyperparameters(3, [31, 0], [0, 31], 1, 3, 48, 0)
    payload, trace = unit_with_trace(CONTEXT_GGCONV, hp, small_arrays(CONTEXT_GGCONV, hp, 1))
    assert {e.descriptor for e in trace if "layer_shift" in e.name} == {"u(5)"}
    assert read_context_model_unit(payload)[1] == hp
    with pytest.raises(ValueError):
        write_context_model_unit(CONTEXT_GGCONV, dataclasses.replace(hp, head_layer_shift=[32, 0]),
                                 small_arrays(CONTEXT_GGCONV, hp, 1))


def test_arrays_in_the_order_of_array_names():
    hp = Hyperparameters(2, [0])
    arrays = small_arrays(CONTEXT_PARENT_MLP, hp, 2)
    with pytest.raises(ValueError, match="order"):
        write_context_model_unit(CONTEXT_PARENT_MLP, hp, arrays[::-1])
    assert array_names(CONTEXT_PARENT_MLP, 0, 2) == ["parent_base", "head.0.weight", "head.0.bias", "head.1.weight",
                                                     "head.1.bias"]
    assert array_names(CONTEXT_GGCONV, 1, 1) == ["parent_base", "table", "feat.0.weight", "feat.0.bias",
                                                 "head.0.weight", "head.0.bias"]
    assert MAX_CONTEXT_PARAMETERS == 1 << 24
