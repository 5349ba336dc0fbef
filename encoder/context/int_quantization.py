"""Quantization of float layers into the integer networks of common/intnn.py (informative: the
encoder's choice of scales; the decoder evaluates whatever integers the stream carries).
"""

from __future__ import annotations

import math

import numpy as np

from ...common.intnn import ACT_BITS, BIAS_BITS, MAX_SHIFT, IntLinear, int_range


def round_half_up(x: np.ndarray) -> np.ndarray:
    """floor(x + 1/2): the rounding of rshift_round, for float arrays."""
    return np.floor(np.asarray(x, dtype=np.float64) + 0.5)


def frac_bits_for(max_abs: float, bits: int = ACT_BITS, lo: int = -MAX_SHIFT, hi: int = 24) -> int:
    """Largest f in [lo, hi] with max_abs * 2^f <= 2^(bits-1) - 1 (the per-tensor power-of-two scale)."""
    top = (1 << (bits - 1)) - 1
    if not math.isfinite(max_abs):
        raise ValueError("cannot scale a tensor containing NaN or Inf")
    if max_abs <= 0:
        return hi
    f = math.floor(math.log2(top / max_abs))
    while f > lo and max_abs * 2.0**f > top:  # guard log2 rounding
        f -= 1
    return max(lo, min(hi, f))


def quantize_linear(weight: np.ndarray, bias: np.ndarray, out_frac: int, relu: bool,
                    weight_bits: int = 16) -> tuple[IntLinear, int]:
    """Turn a float layer acting on the integer input values (y_real = x_int @ weight.T + bias,
    output stored as round(y_real * 2^out_frac)) into an IntLinear with one power-of-two weight
    scale 2^acc_frac. Returns the layer and acc_frac (the accumulator's fractional bits;
    shift = acc_frac - out_frac)."""
    w = np.asarray(weight, dtype=np.float64)
    b = np.asarray(bias, dtype=np.float64)
    acc_frac = min(frac_bits_for(float(np.abs(w).max()) if w.size else 0.0, weight_bits,
                                 lo=out_frac, hi=out_frac + MAX_SHIFT),
                   frac_bits_for(float(np.abs(b).max()) if b.size else 0.0, BIAS_BITS,
                                 lo=out_frac, hi=out_frac + MAX_SHIFT))  # biases must fit 32 bits too
    lo, hi = int_range(weight_bits)
    wq = np.clip(round_half_up(w * 2.0**acc_frac), lo, hi).astype(np.int64)
    blo, bhi = int_range(BIAS_BITS)
    bq = np.clip(round_half_up(b * 2.0**acc_frac), blo, bhi).astype(np.int64)
    return IntLinear(wq, bq, acc_frac - out_frac, relu, weight_bits), acc_frac
