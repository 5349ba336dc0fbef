"""The context-model unit (spec clause 7.3.7): the level-2 context model (R_model).

Its scalar hyperparameters are syntax elements of ``context_model_unit()``, each with its
descriptor and its allowed range (checked as it is parsed; spec clause 7.2): ``num_features``,
for GG-Conv ``neighbour_level``, ``k``, ``radius_sq`` and ``h_shift``, and the shift of every
MLP layer. A parent-MLP unit has no GG-Conv element, so a scene without GG-Conv spends no bit
on them. The model's arrays (``parent_base``, GG-Conv's table, every layer's weights and
biases) are integer arrays with a shape, a bit width and a signedness (``int_array_header()``);
their values are entropy coded in one chunk, mean 0, one scale level per array. Array names
are not written: they follow from the model and its layer counts, in the fixed order of
``array_names``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..entropy.symbol_coder import best_level, decode_symbols, encode_symbols
from ..errors import BitstreamError
from ..syntax import SyntaxStructure, SyntaxVisitor
from ..units import (CONTEXT_GGCONV, CONTEXT_PARENT_MLP, MAX_CONTEXT_MODEL_ID, MAX_FEATURE_DIM,
                     NUM_SCALE_LEVELS_BITS)

MAX_ARRAY_DIMS = 4
MAX_MODEL_LAYERS = 8
MAX_CONTEXT_PARAMETERS = 1 << 24  # level limit
MAX_VALUE_BITS = 62  # |value| < 2^62: the symbol coder's range
# ranges of the hyperparameters (spec clause 7.2; Annex H.4, H.5.1, H.6.1)
MAX_NUM_FEATURES = MAX_FEATURE_DIM  # num_features = C of the scene (clause 8.3)
NEIGHBOUR_LEVELS = (1, 2)  # 1: neighbours are level-1 anchors; 2: level-2 anchors (the paper's graph)
MAX_K = 64
MAX_RADIUS_SQ_BITS = 62
MAX_RADIUS_SQ = (1 << MAX_RADIUS_SQ_BITS) - 1
H_SHIFT_BITS = 6
MAX_H_SHIFT = 40
LAYER_SHIFT_BITS = 5  # a layer's shift: u(5), every value of [0, 31] (intnn.MAX_SHIFT)


@dataclass(frozen=True)
class NamedIntArray:
    """One parameter array: integer values of ``bits`` bits, signed or unsigned."""

    name: str
    values: np.ndarray  # int64, any shape
    bits: int
    signed: bool


@dataclass
class Hyperparameters:
    """A context model's scalar hyperparameters, the syntax elements of context_model_unit()
    (clause 7.3.7); those of GG-Conv alone are None in a parent-MLP model. The layer counts of
    the model's MLPs are the lengths of the shift lists."""

    num_features: int
    head_layer_shift: list[int]
    feat_layer_shift: list[int] | None = None  # GG-Conv
    neighbour_level: int | None = None  # GG-Conv
    k: int | None = None  # GG-Conv
    radius_sq: int | None = None  # GG-Conv
    h_shift: int | None = None  # GG-Conv


def required(value: int | None, name: str) -> int:
    """A GG-Conv hyperparameter, which a parent-MLP model leaves None; ValueError naming it when missing."""
    if value is None:
        raise ValueError(f"a GG-Conv model needs the hyperparameter {name}")
    return int(value)


def mlp_arrays(name: str, mlp) -> list[NamedIntArray]:
    """The arrays of an integer MLP (common/intnn.py IntMLP) named ``name``, layer by layer:
    {name}.{l}.weight (s8 or s16 [out, in]), {name}.{l}.bias (s32 [out]). Each layer's shift is
    a syntax element (``Hyperparameters``)."""
    out: list[NamedIntArray] = []
    for l, layer in enumerate(mlp.layers):
        out += [NamedIntArray(f"{name}.{l}.weight", layer.weight.copy(), layer.weight_bits, True),
                NamedIntArray(f"{name}.{l}.bias", layer.bias.copy(), 32, True)]
    return out


def array_names(model_id: int, feat_layers: int, head_layers: int) -> list[str]:
    """The normative order of a context model's arrays."""
    def mlp(name: str, layers: int) -> list[str]:
        return [f"{name}.{l}.{part}" for l in range(layers) for part in ("weight", "bias")]
    if model_id == CONTEXT_GGCONV:
        return ["parent_base", "table"] + mlp("feat", feat_layers) + mlp("head", head_layers)
    if model_id == CONTEXT_PARENT_MLP:
        return ["parent_base"] + mlp("head", head_layers)
    raise ValueError(f"context model {model_id} has no parameters")


@dataclass
class IntArrayHeader(SyntaxStructure):
    syntax_name = "int_array_header"
    clause = "7.3.8"
    array_ndim: int = 0
    array_dim_minus1: list = field(default_factory=list)
    array_bits_minus1: int = 0
    array_signed_flag: int = 0
    array_level: int = 0

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(3, self, "array_ndim", hi=MAX_ARRAY_DIMS)
        for d in v.loop(self.array_ndim, "array_ndim", self, ("array_dim_minus1",), index="d"):
            v.ue(self, "array_dim_minus1", d, hi=MAX_CONTEXT_PARAMETERS - 1)
        v.u(6, self, "array_bits_minus1", hi=MAX_VALUE_BITS - 1)
        v.flag(self, "array_signed_flag")
        v.u(NUM_SCALE_LEVELS_BITS, self, "array_level")

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(d + 1 for d in self.array_dim_minus1)


@dataclass
class ContextModelUnit(SyntaxStructure):
    syntax_name = "context_model_unit"
    clause = "7.3.7"
    context_model_id: int = CONTEXT_GGCONV
    feat_num_layers_minus1: int = 0
    head_num_layers_minus1: int = 0
    num_features: int = 1
    neighbour_level: int = 1
    k: int = 1
    radius_sq_bits_minus1: int = 0
    radius_sq: int = 1
    h_shift: int = 0
    feat_layer_shift: list = field(default_factory=list)
    head_layer_shift: list = field(default_factory=list)
    arrays: list = field(default_factory=list)
    coded_size: int = 0
    coded_data: bytes = b""

    @property
    def num_feat_layers(self) -> int:
        return self.feat_num_layers_minus1 + 1 if self.context_model_id == CONTEXT_GGCONV else 0

    @property
    def num_arrays(self) -> int:
        return len(array_names(self.context_model_id, self.num_feat_layers, self.head_num_layers_minus1 + 1))

    def syntax(self, v: SyntaxVisitor) -> None:
        v.u(3, self, "context_model_id", lo=CONTEXT_PARENT_MLP, hi=MAX_CONTEXT_MODEL_ID)
        for _ in v.when(self.context_model_id == CONTEXT_GGCONV, "context_model_id == 2"):
            v.ue(self, "feat_num_layers_minus1", hi=MAX_MODEL_LAYERS - 1)
        v.ue(self, "head_num_layers_minus1", hi=MAX_MODEL_LAYERS - 1)
        v.ue(self, "num_features", lo=1, hi=MAX_NUM_FEATURES)
        for _ in v.when(self.context_model_id == CONTEXT_GGCONV, "context_model_id == 2"):
            v.u(2, self, "neighbour_level", lo=NEIGHBOUR_LEVELS[0], hi=NEIGHBOUR_LEVELS[-1])
            v.ue(self, "k", lo=1, hi=MAX_K)
            v.u(6, self, "radius_sq_bits_minus1", hi=MAX_RADIUS_SQ_BITS - 1)
            v.u(self.radius_sq_bits_minus1 + 1, self, "radius_sq", lo=1, hi=MAX_RADIUS_SQ,
                width="radius_sq_bits_minus1 + 1")
            v.u(H_SHIFT_BITS, self, "h_shift", hi=MAX_H_SHIFT)
            for l in v.loop(self.feat_num_layers_minus1 + 1, "feat_num_layers_minus1 + 1", self,
                            ("feat_layer_shift",), index="l"):
                v.u(LAYER_SHIFT_BITS, self, "feat_layer_shift", l)
        for l in v.loop(self.head_num_layers_minus1 + 1, "head_num_layers_minus1 + 1", self,
                        ("head_layer_shift",), index="l"):
            v.u(LAYER_SHIFT_BITS, self, "head_layer_shift", l)
        for a in v.loop(self.num_arrays, "NumArrays", self, ("arrays",), index="a"):
            v.struct(self, "arrays", a, IntArrayHeader)
        v.ue(self, "coded_size")
        v.byte_align()
        v.payload(self, "coded_data", self.coded_size)

    def hyperparameters(self) -> Hyperparameters:
        if self.context_model_id != CONTEXT_GGCONV:
            return Hyperparameters(self.num_features, list(self.head_layer_shift))
        return Hyperparameters(self.num_features, list(self.head_layer_shift), list(self.feat_layer_shift),
                               self.neighbour_level, self.k, self.radius_sq, self.h_shift)

    def set_hyperparameters(self, hp: Hyperparameters) -> None:
        """The elements of ``hp`` (layer counts from its shift lists; radius_sq in the fewest bits)."""
        self.num_features = int(hp.num_features)
        self.head_num_layers_minus1 = len(hp.head_layer_shift) - 1
        self.head_layer_shift = [int(s) for s in hp.head_layer_shift]
        if self.context_model_id != CONTEXT_GGCONV:
            return
        self.feat_num_layers_minus1 = len(hp.feat_layer_shift or []) - 1
        self.feat_layer_shift = [int(s) for s in hp.feat_layer_shift or []]
        self.neighbour_level, self.k = required(hp.neighbour_level, "neighbour_level"), required(hp.k, "k")
        self.h_shift, self.radius_sq = required(hp.h_shift, "h_shift"), required(hp.radius_sq, "radius_sq")
        self.radius_sq_bits_minus1 = max(self.radius_sq.bit_length(), 1) - 1


def write_context_model_unit(model_id: int, hp: Hyperparameters, arrays: list[NamedIntArray]) -> bytes:
    """The context-model unit of a model: its hyperparameters as syntax elements (ValueError when
    one is outside its range) and its arrays, in the order of ``array_names``."""
    unit = ContextModelUnit(context_model_id=model_id)
    unit.set_hyperparameters(hp)
    names = array_names(model_id, unit.num_feat_layers, unit.head_num_layers_minus1 + 1)
    if [a.name for a in arrays] != names:
        raise ValueError(f"context model arrays must come in the order {names}")
    symbols, levels = [], []
    for a in arrays:
        v = np.asarray(a.values, dtype=np.int64).reshape(-1)
        if a.bits > MAX_VALUE_BITS:
            raise ValueError(f"{a.name}: {a.bits}-bit values exceed the {MAX_VALUE_BITS}-bit limit")
        lv = best_level(v)
        shape = np.shape(a.values) or ()
        unit.arrays.append(IntArrayHeader(array_ndim=len(shape), array_dim_minus1=[d - 1 for d in shape],
                                          array_bits_minus1=a.bits - 1, array_signed_flag=int(a.signed),
                                          array_level=lv))
        symbols.append(v)
        levels.append(np.full(v.size, lv, dtype=np.int64))
    unit.coded_data = encode_symbols(np.concatenate(symbols), np.concatenate(levels))
    unit.coded_size = len(unit.coded_data)
    return unit.to_bytes()


def read_context_model_unit(payload: bytes, trace=None) -> tuple[int, Hyperparameters, list[NamedIntArray]]:
    """-> (context_model_id, hyperparameters, arrays); BitstreamError on an element outside its
    range, an array beyond the level limit or a value outside its array's declared width."""
    unit = ContextModelUnit.from_bytes(payload, trace, what="context model unit")
    names = array_names(unit.context_model_id, unit.num_feat_layers, unit.head_num_layers_minus1 + 1)
    sizes = []
    for a in unit.arrays:
        if any(d > MAX_CONTEXT_PARAMETERS for d in a.shape):
            raise BitstreamError("context model unit: an array dimension exceeds the level limit", condition="E41")
        sizes.append(int(np.prod(a.shape, dtype=np.int64)))
        if sum(sizes) > MAX_CONTEXT_PARAMETERS:
            raise BitstreamError(f"context model unit: more than {MAX_CONTEXT_PARAMETERS} parameters (level limit)", condition="E41")
    levels = np.concatenate([np.full(s, a.array_level, np.int64) for s, a in zip(sizes, unit.arrays)]) \
        if sizes else np.zeros(0, np.int64)
    values = decode_symbols(unit.coded_data, levels, "context model coded data")
    out, pos = [], 0
    for name, a, s in zip(names, unit.arrays, sizes):
        v = values[pos:pos + s].reshape(a.shape)
        pos += s
        bits = a.array_bits_minus1 + 1
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if a.array_signed_flag else (0, (1 << bits) - 1)
        if v.size and (int(v.min()) < lo or int(v.max()) > hi):
            raise BitstreamError(f"context model unit: {name} has values outside its {bits}-bit range", condition="E40")
        out.append(NamedIntArray(name, v, bits, bool(a.array_signed_flag)))
    return unit.context_model_id, unit.hyperparameters(), out
