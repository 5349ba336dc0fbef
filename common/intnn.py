"""Integer network arithmetic (normative; spec/hierarchy_ggconv.md, clause "Integer networks").

Every value that flows between layers is an *activation*: a signed 16-bit integer in
[ACT_MIN, ACT_MAX] = [-32768, 32767]. A layer ``IntLinear`` computes, per output o,

    acc_o = bias_o + sum_i weight_{o,i} * x_i          exact, int64
    y_o   = rshift_round(acc_o, shift)                  (acc + 2^(shift-1)) >> shift; y = acc if shift == 0
    y_o   = clamp(y_o, 0, ACT_MAX) if relu else clamp(y_o, ACT_MIN, ACT_MAX)

with weights of weight_bits in {8, 16} bits (two's complement range), bias int32, shift in
[0, MAX_SHIFT]. ``>>`` is the arithmetic shift, i.e. floor division by 2^shift; with the
added half, rshift_round rounds to nearest with ties toward plus infinity (-2.5 -> -2,
2.5 -> 3) for negative and positive values alike.

Bit-width bound (asserted for every layer at construction): with |x_i| <= 2^15,
|weight| <= 2^(weight_bits-1), fan-in n <= MAX_FAN_IN = 2^16 and |bias| <= 2^31,

    |acc| <= n * 2^15 * 2^(weight_bits-1) + 2^31 <= 2^16 * 2^30 + 2^31 < 2^47 < 2^62,

and adding the rounding half (< 2^31) keeps it below 2^62. Integer addition being
associative, the result cannot depend on the summation order, the thread count or the
BLAS.

Evaluation (informative; the result is what is normative): ``IntLinear.__call__`` runs the
layer as a float64 GEMM. This is exact: every input, weight and bias is an integer, every
product is an integer of magnitude < 2^46 and every partial sum, in whatever order or
blocking the BLAS uses (FMA or not), is an integer of magnitude < 2^47 < 2^53, hence exactly
representable; an IEEE operation whose exact result is representable returns it exactly.
rshift_round is folded into the GEMM: with weights w 2^-shift and bias (b + 2^(shift-1)) 2^-shift,
every product and partial sum is an integer multiple of 2^-shift of magnitude < 2^(47-shift),
i.e. at most 47 + 1 significant bits: exact again, and the GEMM returns
(acc + 2^(shift-1)) / 2^shift exactly; floor and clamp are exact.
``call_int64`` is the same layer in int64 arithmetic (torch's int64 matmul, no BLAS); the
tests compare the two, and the constructor asserts the precondition (the architectural
accumulator bound plus the rounding half below 2^53) for every layer.

The encoder turns a float network into this form with encoder/context/int_quantization.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

ACT_BITS = 16
ACT_MIN = -(1 << (ACT_BITS - 1))
ACT_MAX = (1 << (ACT_BITS - 1)) - 1
BIAS_BITS = 32
WEIGHT_BITS_ALLOWED = (8, 16)
MAX_SHIFT = 31
MAX_FAN_IN = 1 << 16
ACC_LIMIT = 1 << 62  # the asserted bound on |accumulator|
F64_EXACT = 1 << 53  # integers below this are exact in float64
_ROWS_PER_CHUNK = 1 << 16


def int_range(bits: int) -> tuple[int, int]:
    """Two's complement range of a signed integer of `bits` bits."""
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


def rshift_round(x: torch.Tensor, shift: int) -> torch.Tensor:
    """(x + 2^(shift-1)) >> shift for shift >= 1 (floor semantics of >> for negatives: rounds to
    nearest, ties toward +inf); x unchanged for shift == 0. x: int64 tensor."""
    if shift < 0 or shift > 62:
        raise ValueError(f"shift must be in [0, 62], got {shift}")
    if shift == 0:
        return x
    return (x + (1 << (shift - 1))) >> shift


def clamp_act(x: torch.Tensor, relu: bool = False) -> torch.Tensor:
    return x.clamp(0 if relu else ACT_MIN, ACT_MAX)


def check_activations(x: torch.Tensor, what: str = "input") -> None:
    """Assert that every value of x is a 16-bit activation (the precondition of the bound)."""
    if x.dtype != torch.int64:
        raise TypeError(f"{what} must be an int64 tensor, got {x.dtype}")
    if x.numel() and (int(x.min()) < ACT_MIN or int(x.max()) > ACT_MAX):
        raise ValueError(f"{what} outside the 16-bit activation range [{ACT_MIN}, {ACT_MAX}]: "
                         f"[{int(x.min())}, {int(x.max())}]")


@dataclass
class IntLinear:
    weight: np.ndarray  # int [out, in], in int_range(weight_bits)
    bias: np.ndarray  # int [out], in int_range(32)
    shift: int  # [0, MAX_SHIFT]
    relu: bool
    weight_bits: int = 16
    _w: torch.Tensor = field(init=False, repr=False, compare=False)
    _b: torch.Tensor = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        w = np.asarray(self.weight)
        b = np.asarray(self.bias)
        if self.weight_bits not in WEIGHT_BITS_ALLOWED:
            raise ValueError(f"weight_bits must be one of {WEIGHT_BITS_ALLOWED}, got {self.weight_bits}")
        if w.ndim != 2 or b.shape != (w.shape[0],):
            raise ValueError(f"weight {list(w.shape)} and bias {list(b.shape)} do not match")
        if w.size and not np.issubdtype(w.dtype, np.integer) or b.size and not np.issubdtype(b.dtype, np.integer):
            raise ValueError("IntLinear weights and biases must be integers")
        if not 1 <= w.shape[1] <= MAX_FAN_IN or w.shape[0] < 1:
            raise ValueError(f"fan-in must be in [1, {MAX_FAN_IN}] and fan-out >= 1, got {list(w.shape)}")
        lo, hi = int_range(self.weight_bits)
        if w.size and (int(w.min()) < lo or int(w.max()) > hi):
            raise ValueError(f"weights outside the {self.weight_bits}-bit range")
        blo, bhi = int_range(BIAS_BITS)
        if b.size and (int(b.min()) < blo or int(b.max()) > bhi):
            raise ValueError("biases outside the 32-bit range")
        if isinstance(self.shift, bool) or not 0 <= int(self.shift) <= MAX_SHIFT:
            raise ValueError(f"shift must be in [0, {MAX_SHIFT}], got {self.shift}")
        self.shift = int(self.shift)
        self.relu = bool(self.relu)
        self.weight = w.astype(np.int64)
        self.bias = b.astype(np.int64)
        # The bit-width proof, asserted: architectural bound and the tighter bound of these weights.
        arch = self.fan_in * (1 << (ACT_BITS - 1)) * (1 << (self.weight_bits - 1)) + (1 << (BIAS_BITS - 1))
        assert arch + (1 << MAX_SHIFT) < ACC_LIMIT, "accumulator bound violated"
        assert self.accumulator_bound() <= arch
        # float64 evaluation is exact: |acc| + rounding half < 2^47 + 2^31 < 2^53 (module docstring)
        assert arch + (1 << MAX_SHIFT) < F64_EXACT, "float64 exactness bound violated"
        self._w = torch.from_numpy(np.ascontiguousarray(self.weight.T))  # [in, out] int64
        self._b = torch.from_numpy(self.bias.copy())
        # float64 evaluation with the rounding folded in: weights * 2^-shift, (bias + half) * 2^-shift,
        # so that the GEMM yields (acc + 2^(shift-1)) / 2^shift exactly (module docstring)
        sc = 2.0 ** -self.shift
        self._ws = self._w.to(torch.float64).mul_(sc)
        self._bs = (self._b.to(torch.float64) + (float(1 << (self.shift - 1)) if self.shift else 0.0)).mul_(sc)

    @property
    def fan_in(self) -> int:
        return int(self.weight.shape[1])

    @property
    def fan_out(self) -> int:
        return int(self.weight.shape[0])

    def accumulator_bound(self) -> int:
        """max over outputs of sum_i |w_oi| * 2^15 + |b_o|: no accumulator can exceed it."""
        s = np.abs(self.weight).sum(axis=1) * (1 << (ACT_BITS - 1)) + np.abs(self.bias)
        return int(s.max())

    def finish_f64(self, acc_s: torch.Tensor) -> torch.Tensor:
        """acc_s = (acc + 2^(shift-1)) / 2^shift in float64 (what the scaled GEMM gives) ->
        floor and clamp, in place; returns the float64 activations (exact)."""
        return acc_s.floor_().clamp_(0.0 if self.relu else float(ACT_MIN), float(ACT_MAX))

    def forward_f64(self, x: torch.Tensor) -> torch.Tensor:
        """x: float64 [R, fan_in] holding 16-bit activations -> float64 [R, fan_out] activations
        (exact, see the module docstring)."""
        if x.shape[0] == 0:
            return torch.zeros((0, self.fan_out), dtype=torch.float64)
        return self.finish_f64(torch.addmm(self._bs, x, self._ws))

    def __call__(self, x: torch.Tensor, check: bool = True) -> torch.Tensor:
        """x: int64 [R, fan_in] activations -> int64 [R, fan_out] activations (float64 GEMM, exact)."""
        if check:
            check_activations(x)
        if x.ndim != 2 or x.shape[1] != self.fan_in:
            raise ValueError(f"expected input [R, {self.fan_in}], got {list(x.shape)}")
        return self.forward_f64(x.to(torch.float64)).to(torch.int64)

    def call_int64(self, x: torch.Tensor, check: bool = True) -> torch.Tensor:
        """The same layer in int64 arithmetic (reference for the float64 path)."""
        if check:
            check_activations(x)
        if x.ndim != 2 or x.shape[1] != self.fan_in:
            raise ValueError(f"expected input [R, {self.fan_in}], got {list(x.shape)}")
        outs = []
        for lo in range(0, x.shape[0], _ROWS_PER_CHUNK):
            acc = torch.addmm(self._b, x[lo:lo + _ROWS_PER_CHUNK], self._w)
            outs.append(clamp_act(rshift_round(acc, self.shift), self.relu))
        if not outs:
            return torch.zeros((0, self.fan_out), dtype=torch.int64)
        return outs[0] if len(outs) == 1 else torch.cat(outs)


@dataclass
class IntMLP:
    layers: list[IntLinear]

    def __post_init__(self) -> None:
        if not self.layers:
            raise ValueError("an IntMLP needs at least one layer")
        for l in range(1, len(self.layers)):
            if self.layers[l].fan_in != self.layers[l - 1].fan_out:
                raise ValueError(f"layer {l}: fan-in {self.layers[l].fan_in} != previous fan-out "
                                 f"{self.layers[l - 1].fan_out}")

    @property
    def in_dim(self) -> int:
        return self.layers[0].fan_in

    @property
    def out_dim(self) -> int:
        return self.layers[-1].fan_out

    def num_parameters(self) -> int:
        return sum(l.weight.size + l.bias.size for l in self.layers)

    def forward_f64(self, x: torch.Tensor) -> torch.Tensor:
        """float64 activations in and out (exact; no input check)."""
        for layer in self.layers:
            x = layer.forward_f64(x)
        return x

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        check_activations(x)
        if x.ndim != 2 or x.shape[1] != self.in_dim:
            raise ValueError(f"expected input [R, {self.in_dim}], got {list(x.shape)}")
        out = []
        for lo in range(0, x.shape[0], _ROWS_PER_CHUNK):  # every layer output is an activation
            out.append(self.forward_f64(x[lo:lo + _ROWS_PER_CHUNK].to(torch.float64)).to(torch.int64))
        if not out:
            return torch.zeros((0, self.out_dim), dtype=torch.int64)
        return out[0] if len(out) == 1 else torch.cat(out)

    def call_int64(self, x: torch.Tensor) -> torch.Tensor:
        """int64 reference evaluation (equal to ``__call__``)."""
        check_activations(x)
        for layer in self.layers:
            x = layer.call_int64(x, check=False)
        return x
