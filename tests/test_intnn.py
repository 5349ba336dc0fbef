"""Integer network arithmetic (common/intnn.py): exactness, bounds, rounding, determinism."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.intnn import (
    ACC_LIMIT,
    ACT_MAX,
    ACT_MIN,
    MAX_FAN_IN,
    IntLinear,
    IntMLP,
    rshift_round,
)
from lghcc.encoder.context.int_quantization import quantize_linear
from reference_impl import rshift_round_np


@given(st.integers(-(2 ** 61), 2 ** 61), st.integers(0, 40))
def test_rshift_round_is_round_half_up(x, s):
    got = int(rshift_round(torch.tensor([x]), s)[0])
    # exact rational rounding: floor(x / 2^s + 1/2)
    assert got == (2 * x + (1 << s)) // (2 << s) if s else got == x
    assert int(rshift_round_np(np.array([x]), s)[0]) == got


def test_rshift_round_negative_ties():
    x = torch.tensor([-6, -5, -3, -1, 1, 3, 5, 6])
    assert rshift_round(x, 1).tolist() == [-3, -2, -1, 0, 1, 2, 3, 3]  # ties toward +inf


def _exact(layer, x):
    acc = x.astype(object) @ layer.weight.T.astype(object) + layer.bias.astype(object)
    y = np.array([[(v + (1 << (layer.shift - 1))) >> layer.shift if layer.shift else v for v in row]
                  for row in acc], dtype=object)
    return np.clip(y, 0 if layer.relu else ACT_MIN, ACT_MAX).astype(np.int64)


@settings(max_examples=30)
@given(st.integers(1, 70), st.integers(1, 5), st.sampled_from([8, 16]), st.integers(0, 31), st.booleans(),
       st.integers(0, 2 ** 32 - 1))
def test_linear_matches_exact_python_ints(fan_in, fan_out, wb, shift, relu, seed):
    rng = np.random.default_rng(seed)
    lo, hi = -(1 << (wb - 1)), (1 << (wb - 1)) - 1
    layer = IntLinear(rng.integers(lo, hi + 1, (fan_out, fan_in)), rng.integers(-2 ** 31, 2 ** 31, fan_out),
                      shift, relu, wb)
    x = rng.integers(ACT_MIN, ACT_MAX + 1, (20, fan_in))
    x[0] = ACT_MIN  # extreme rows
    x[1] = ACT_MAX
    assert np.array_equal(layer(torch.from_numpy(x)).numpy(), _exact(layer, x))


def test_accumulator_bound_asserted_at_extremes():
    # widest layer, every weight and input at the extreme: the bound holds with a margin
    w = np.full((1, MAX_FAN_IN), -(1 << 15), dtype=np.int64)
    layer = IntLinear(w, np.array([-(2 ** 31)]), 31, False, 16)
    assert layer.accumulator_bound() == MAX_FAN_IN * 2 ** 30 + 2 ** 31 < 2 ** 47 < ACC_LIMIT
    x = torch.full((2, MAX_FAN_IN), ACT_MIN, dtype=torch.int64)
    acc = MAX_FAN_IN * 2 ** 30 - 2 ** 31
    assert layer(x).tolist() == [[min(ACT_MAX, (acc + 2 ** 30) >> 31)]] * 2
    with pytest.raises(ValueError, match="fan-in"):
        IntLinear(np.zeros((1, MAX_FAN_IN + 1), np.int64), np.zeros(1, np.int64), 0, False)


def test_rejects_out_of_range():
    with pytest.raises(ValueError, match="8-bit"):
        IntLinear(np.array([[128]]), np.array([0]), 0, False, 8)
    with pytest.raises(ValueError, match="32-bit"):
        IntLinear(np.array([[1]]), np.array([2 ** 31]), 0, False)
    with pytest.raises(ValueError, match="shift"):
        IntLinear(np.array([[1]]), np.array([0]), 32, False)
    with pytest.raises(ValueError, match="weight_bits"):
        IntLinear(np.array([[1]]), np.array([0]), 0, False, 12)
    layer = IntLinear(np.array([[1]]), np.array([0]), 0, False)
    with pytest.raises(ValueError, match="activation range"):
        layer(torch.tensor([[ACT_MAX + 1]]))
    with pytest.raises(ValueError, match="does not match|fan-in"):
        IntMLP([layer, IntLinear(np.ones((1, 2), np.int64), np.zeros(1, np.int64), 0, False)])


def test_mlp_deterministic_across_thread_counts():
    rng = np.random.default_rng(7)
    mlp = IntMLP([IntLinear(rng.integers(-2 ** 15, 2 ** 15, (64, 48)), rng.integers(-2 ** 31, 2 ** 31, 64), 18, True),
                  IntLinear(rng.integers(-128, 128, (64, 64)), rng.integers(-2 ** 20, 2 ** 20, 64), 9, True, 8),
                  IntLinear(rng.integers(-2 ** 15, 2 ** 15, (30, 64)), rng.integers(-2 ** 31, 2 ** 31, 30), 20, False)])
    x = torch.from_numpy(rng.integers(ACT_MIN, ACT_MAX + 1, (100_000, 48)))
    old = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        y1 = mlp(x)
        torch.set_num_threads(2)
        y2 = mlp(x)
    finally:
        torch.set_num_threads(old)
    assert torch.equal(y1, y2)
    assert int(y1.min()) >= ACT_MIN and int(y1.max()) <= ACT_MAX
    # and equal to an independent exact evaluation on a slice
    h = x[:200].numpy()
    for layer in mlp.layers:
        h = _exact(layer, h)
    assert np.array_equal(y1[:200].numpy(), h)


def test_quantize_linear_approximates_float_layer():
    rng = np.random.default_rng(8)
    w = rng.normal(0, 0.02, (16, 40))
    b = rng.normal(0, 0.5, 16)
    x = rng.integers(-500, 500, (1000, 40))
    for wb in (8, 16):
        layer, acc_frac = quantize_linear(w, b, out_frac=6, relu=False, weight_bits=wb)
        assert layer.shift == acc_frac - 6 >= 0
        assert np.abs(layer.weight).max() <= (1 << (wb - 1)) - 1
        y = layer(torch.from_numpy(x)).numpy() / 2 ** 6
        ref = x @ w.T + b
        tol = (40 * 500 * 2.0 ** -acc_frac) + 2 ** -6
        assert np.abs(y - ref).max() <= tol


def test_quantize_linear_large_bias_fits_32_bits():
    # tiny weights would ask for a huge scale; the bias must still fit int32 (no silent clipping)
    layer, acc_frac = quantize_linear(np.full((2, 3), 1e-5), np.array([30.0, -30.0]), out_frac=0, relu=False)
    assert np.abs(layer.bias).max() < 2 ** 31
    y = layer(torch.tensor([[0, 0, 0]])).tolist()[0]
    assert y == [30, -30]


def test_float64_path_equals_int64_path_at_extremes():
    """IntLinear evaluates as a float64 GEMM with the rounding folded into the weights; it must
    equal the int64 evaluation exactly, also at the architectural bound (largest fan-in
    products, extreme biases, every shift)."""
    rng = np.random.default_rng(11)
    for wb in (8, 16):
        lo, hi = -(1 << (wb - 1)), (1 << (wb - 1)) - 1
        for shift in (0, 1, 7, 17, 31):
            fan_in = 4096
            w = rng.choice([lo, hi, 0, 1, -1], (6, fan_in))
            w[0], w[1] = hi, lo  # rows whose accumulators reach the bound
            b = rng.choice([-(2 ** 31), 2 ** 31 - 1, 0, 12345], 6)
            layer = IntLinear(w, b, shift, relu=bool(shift % 2), weight_bits=wb)
            x = torch.from_numpy(rng.choice([ACT_MIN, ACT_MAX, 0, -1, 1, 2 ** 14], (300, fan_in)))
            x[0] = ACT_MAX
            x[1] = ACT_MIN
            assert torch.equal(layer(x), layer.call_int64(x))
            h = _exact(layer, x[:3].numpy())
            assert np.array_equal(layer(x[:3]).numpy(), h)
