"""The exact range coder (common/entropy/range_coder.py) and the arithmetic spec/entropy.md
describes: a pure-Python reference encoder and decoder written from the spec text must
produce and read the same words as constriction."""

from __future__ import annotations

import math
from bisect import bisect_right

import constriction
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.entropy.range_coder import (
    MAX_UNIFORM_BITS,
    TOTAL_FREQUENCY,
    RangeDecoder,
    RangeEncoder,
    binary_weights,
    check_frequencies,
    exact_model,
)
from lghcc.common.errors import BitstreamError

MASK64 = (1 << 64) - 1
SCALE0 = MASK64 >> 24  # scale of a fresh coder: range 2^64 - 1


# --- reference implementation of spec/entropy.md, clause "Range coder" ---------------------

class RefRangeEncoder:
    """64-bit state, 32-bit words, 24-bit precision; written from the spec text."""

    def __init__(self) -> None:
        self.words: list[int] = []
        self.lower = 0
        self.range = MASK64
        self.inverted: tuple[int, int] | None = None  # (count, first word)

    def encode(self, cum: int, freq: int) -> None:
        scale = self.range >> 24
        self.range = scale * freq
        new_lower = (self.lower + scale * cum) & MASK64
        if self.inverted is not None and ((new_lower + self.range) & MASK64) > new_lower:
            count, first = self.inverted
            if new_lower < self.lower:  # carry
                self.words += [(first + 1) & 0xFFFFFFFF] + [0] * (count - 1)
            else:
                self.words += [first] + [0xFFFFFFFF] * (count - 1)
            self.inverted = None
        self.lower = new_lower
        if self.range < 1 << 32:
            self.range <<= 32
            word = self.lower >> 32
            self.lower = (self.lower << 32) & MASK64
            if self.inverted is not None:
                self.inverted = (self.inverted[0] + 1, self.inverted[1])
            elif ((self.lower + self.range) & MASK64) > self.lower:
                self.words.append(word)
            else:
                self.inverted = (1, word)

    def finish(self) -> list[int]:
        if self.range == MASK64:
            return list(self.words)
        out = list(self.words)
        point = (self.lower + (1 << 32) - 1) & MASK64
        if self.inverted is not None:
            count, first = self.inverted
            if point < self.lower:
                out += [(first + 1) & 0xFFFFFFFF] + [0] * (count - 1)
            else:
                out += [first] + [0xFFFFFFFF] * (count - 1)
        point_word = point >> 32
        out.append(point_word)
        if ((self.lower + self.range) & MASK64) >> 32 == point_word:
            out.append(0)
        return out


class RefRangeDecoder:
    def __init__(self, words: list[int]) -> None:
        self.words = list(words)
        self.pos = 0
        self.point = 0
        for _ in range(2):
            self.point <<= 32
            if self.pos < len(self.words):
                self.point |= self.words[self.pos]
                self.pos += 1
        if not self.words:
            self.point = 0
        self.lower = 0
        self.range = MASK64

    def decode(self, cum: list[int], freq: list[int]) -> int:
        """``cum``: left cumulative frequencies (ascending, cum[0] = 0)."""
        scale = self.range >> 24
        q = ((self.point - self.lower) & MASK64) // scale
        if q >= 1 << 24:
            raise BitstreamError("invalid data")
        s = bisect_right(cum, q) - 1
        self.lower = (self.lower + scale * cum[s]) & MASK64
        self.range = scale * freq[s]
        if self.range < 1 << 32:
            self.lower = (self.lower << 32) & MASK64
            self.range <<= 32
            self.point = (self.point << 32) & MASK64
            if self.pos < len(self.words):
                self.point |= self.words[self.pos]
                self.pos += 1
        return s

    def exhausted(self) -> bool:
        return self.pos == len(self.words) and (
            self.range == MASK64 or ((self.point - self.lower) & MASK64) < (1 << 33) - 1)


def ref_bits_pieces(nbits: list[int]) -> list[tuple[int, int, int]]:
    """The order in which RangeEncoder.encode_bits codes its pieces: (value index, shift, width)."""
    out = []
    for shift in range(0, max(nbits, default=0), MAX_UNIFORM_BITS):
        sel = [j for j, nb in enumerate(nbits) if nb > shift]
        widths = {j: min(nbits[j] - shift, MAX_UNIFORM_BITS) for j in sel}
        for w in sorted(set(widths.values())):
            out += [(j, shift, w) for j in sel if widths[j] == w]
    return out


def ref_decode_bits(dec: RefRangeDecoder, nbits: list[int]) -> list[int]:
    vals = [0] * len(nbits)
    for j, shift, w in ref_bits_pieces(nbits):
        f = 1 << (24 - w)
        cum = [v * f for v in range(1 << w)]
        vals[j] |= dec.decode(cum, [f] * (1 << w)) << shift
    return vals


def cumulative(f) -> list[int]:
    return [0] + list(np.cumsum(np.asarray(f, dtype=np.int64))[:-1].tolist())


def words_of(data: bytes) -> list[int]:
    return np.frombuffer(data, dtype="<u4").astype(np.int64).tolist()


# --- frequency tables ----------------------------------------------------------------------

@st.composite
def freq_tables(draw):
    """Tables of total 2^24, each >= 1: many ones, a few mid-size, one huge (or spread)."""
    n = draw(st.integers(2, 400))
    kind = draw(st.sampled_from(["ones+huge", "random", "two"]))
    if kind == "two":
        a = draw(st.integers(1, TOTAL_FREQUENCY - 1))
        return np.array([a, TOTAL_FREQUENCY - a], dtype=np.int64)
    f = np.ones(n, dtype=np.int64)
    if kind == "random":
        seed = draw(st.integers(0, 2**32 - 1))
        w = np.random.default_rng(seed).exponential(size=n) ** 3
        extra = np.floor(w / w.sum() * (TOTAL_FREQUENCY - n)).astype(np.int64)
        f += extra
    big = draw(st.integers(0, n - 1))
    f[big] += TOTAL_FREQUENCY - int(f.sum())
    return f


def model_frequencies(model, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Read (cumulative, frequency) of every symbol from the coder's own state: a fresh
    coder has lower = 0, range = 2^64 - 1; one symbol makes lower = scale * cum and
    range = scale * f with scale = 2^40 - 1, and no renormalization (range >= 2^40 - 1)."""
    enc = constriction.stream.queue.RangeEncoder()
    cum = np.zeros(n, dtype=np.int64)
    freq = np.zeros(n, dtype=np.int64)
    for s in range(n):
        enc.clear()
        enc.encode(np.array([s], dtype=np.int32), model)
        pos, (lower, rng) = enc.pos()
        assert pos == 0 and lower % SCALE0 == 0 and rng % SCALE0 == 0
        cum[s], freq[s] = lower // SCALE0, rng // SCALE0
    return cum, freq


@settings(max_examples=40)
@given(freq_tables())
def test_exact_model_reproduces_the_frequencies(f):
    cum, freq = model_frequencies(exact_model(f), f.size)
    assert np.array_equal(freq, f)
    assert np.array_equal(cum, np.concatenate([[0], np.cumsum(f)[:-1]]))


def test_exact_model_extreme_tables():
    n = 5000
    f = np.ones(n, dtype=np.int64)
    f[1234] = TOTAL_FREQUENCY - (n - 1)
    cum, freq = model_frequencies(exact_model(f), n)
    assert np.array_equal(freq, f)
    # one-symbol table: the only symbol costs nothing measurable
    model = exact_model(np.array([TOTAL_FREQUENCY]))
    enc = RangeEncoder()
    enc.encode(np.zeros(1000, dtype=np.int64), model)
    data = enc.to_bytes()
    assert len(data) <= 8
    assert np.array_equal(RangeDecoder(data).decode(1000, model), np.zeros(1000))


BINARY_FREQUENCIES = st.one_of(st.integers(1, TOTAL_FREQUENCY - 1),
                               st.sampled_from([1, 2, TOTAL_FREQUENCY - 2, TOTAL_FREQUENCY - 1]))


@settings(max_examples=40)
@given(BINARY_FREQUENCIES)
def test_binary_weights_give_the_exact_two_symbol_model(f1):
    """A row of binary_weights, through constriction's model family, codes with exactly
    [2^24 - f1, f1], read from the coder's own state as for exact_model."""
    family = constriction.stream.model.Categorical(perfect=False)
    enc = constriction.stream.queue.RangeEncoder()
    for s, (cum, freq) in enumerate([(0, TOTAL_FREQUENCY - f1), (TOTAL_FREQUENCY - f1, f1)]):
        enc.clear()
        enc.encode(np.array([s], dtype=np.int32), family, binary_weights([f1]))
        pos, (lower, rng) = enc.pos()
        assert pos == 0 and (lower // SCALE0, rng // SCALE0) == (cum, freq)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 1), BINARY_FREQUENCIES), min_size=0, max_size=300))
def test_binary_decisions_round_trip_as_one_model_per_decision(pairs):
    """encode_binary codes the same words as one exact_model per decision, and decode_binary
    reads them back."""
    bits = np.array([b for b, _ in pairs], dtype=np.int64)
    f1 = np.array([f for _, f in pairs], dtype=np.int64)
    enc = RangeEncoder()
    enc.encode_binary(bits, f1)
    data = enc.to_bytes()
    one_by_one = RangeEncoder()
    for b, f in pairs:
        one_by_one.encode(np.array([b]), exact_model(np.array([TOTAL_FREQUENCY - f, f])))
    assert data == one_by_one.to_bytes()
    dec = RangeDecoder(data)
    assert np.array_equal(dec.decode_binary(f1), bits)
    dec.check_exhausted()


@pytest.mark.parametrize("f1", [0, TOTAL_FREQUENCY, -1])
def test_binary_weights_reject_frequencies_outside_the_table(f1):
    with pytest.raises(ValueError):
        binary_weights([5, f1])


def test_encode_binary_rejects_a_decision_that_is_not_a_bit():
    with pytest.raises(ValueError, match="not 0 or 1"):
        RangeEncoder().encode_binary(np.array([0, 2]), np.array([5, 5]))


@pytest.mark.parametrize("bad", [np.array([TOTAL_FREQUENCY - 1]), np.array([0, TOTAL_FREQUENCY]),
                                 np.array([2, TOTAL_FREQUENCY - 1]), np.zeros((2, 2))])
def test_check_frequencies_rejects(bad):
    with pytest.raises(ValueError):
        check_frequencies(bad)


@settings(max_examples=25)
@given(freq_tables(), st.integers(0, 2**32 - 1))
def test_size_is_ideal_within_two_words_and_reference_coder_agrees(f, seed):
    rng = np.random.default_rng(seed)
    p = f / f.sum()
    sym = rng.choice(f.size, size=int(rng.integers(0, 600)), p=p)
    enc = RangeEncoder()
    enc.encode(sym, exact_model(f))
    data = enc.to_bytes()
    ideal = float(np.sum(24 - np.log2(f[sym]))) if sym.size else 0.0
    assert len(data) * 8 <= ideal + 64 + 1e-6
    # the reference encoder of the spec produces the very same words ...
    cum = cumulative(f)
    ref = RefRangeEncoder()
    for s in sym.tolist():
        ref.encode(cum[s], int(f[s]))
    assert ref.finish() == words_of(data)
    # ... and the reference decoder reads them back, ending exhausted
    dec = RefRangeDecoder(words_of(data))
    fl = f.tolist()
    assert [dec.decode(cum, fl) for _ in range(sym.size)] == sym.tolist()
    assert dec.exhausted()
    d2 = RangeDecoder(data)
    assert np.array_equal(d2.decode(sym.size, exact_model(f)), sym)
    d2.check_exhausted()


def test_reference_coder_on_skewed_long_stream():
    """Many renormalizations with near-certain and near-impossible symbols mixed."""
    f = np.ones(64, dtype=np.int64)
    f[0] = TOTAL_FREQUENCY - 63
    rng = np.random.default_rng(7)
    sym = np.where(rng.random(20000) < 0.02, rng.integers(1, 64, 20000), 0)
    enc = RangeEncoder()
    enc.encode(sym, exact_model(f))
    data = enc.to_bytes()
    cum, fl = cumulative(f), f.tolist()
    ref = RefRangeEncoder()
    for s in sym.tolist():
        ref.encode(cum[s], fl[s])
    assert ref.finish() == words_of(data)


# --- raw bits --------------------------------------------------------------------------------

@pytest.mark.parametrize("width", list(range(0, 65)))
def test_bits_round_trip_every_width(width):
    rng = np.random.default_rng(width)
    v = rng.integers(0, 2**63, size=50, dtype=np.uint64) * np.uint64(2) + rng.integers(0, 2, 50).astype(np.uint64)
    v = v & np.uint64((1 << width) - 1) if width < 64 else v
    v[0] = (1 << width) - 1 if width else 0
    enc = RangeEncoder()
    enc.encode_bits(v, width)
    data = enc.to_bytes()
    assert len(data) * 8 <= 50 * width + 64
    dec = RangeDecoder(data)
    assert np.array_equal(dec.decode_bits(width, 50), v)
    dec.check_exhausted()


@settings(max_examples=30)
@given(st.lists(st.integers(0, 64), max_size=40), st.integers(0, 2**32 - 1))
def test_bits_mixed_widths_and_reference_order(widths, seed):
    rng = np.random.default_rng(seed)
    vals = [int(rng.integers(0, 2**62)) * 4 % (1 << w) if w else 0 for w in widths]
    vals = [(v | (1 << (w - 1))) if w else 0 for v, w in zip(vals, widths)]
    enc = RangeEncoder()
    enc.encode_bits(np.array(vals, dtype=np.uint64), np.array(widths, dtype=np.int64))
    data = enc.to_bytes()
    dec = RangeDecoder(data)
    assert dec.decode_bits(np.array(widths, dtype=np.int64)).tolist() == vals
    dec.check_exhausted()
    ref = RefRangeDecoder(words_of(data))
    assert ref_decode_bits(ref, widths) == vals
    assert ref.exhausted()


# --- malformed input -------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 3, 5, 7, 9])
def test_lengths_that_are_not_whole_words_are_rejected(n):
    with pytest.raises(BitstreamError):
        RangeDecoder(bytes(n), "test data")


@settings(max_examples=60)
@given(st.binary(max_size=64), st.integers(0, 200), st.integers(0, 70))
def test_random_bytes_raise_only_bitstream_errors(data, count, nbits):
    f = np.array([1000, 1, TOTAL_FREQUENCY - 1001 - 5, 5], dtype=np.int64)
    try:
        dec = RangeDecoder(data, "random")
        out = dec.decode(count, exact_model(f))
        assert out.shape == (count,) and (count == 0 or (out.min() >= 0 and out.max() < 4))
        bits = dec.decode_bits(min(nbits, 64), 3)
        assert bits.shape == (3,)
        dec.check_exhausted()
    except BitstreamError:
        pass


def test_all_ones_words_are_invalid_data():
    """point = 2^64 - 1 gives quantile 2^24 at the first symbol: impossible data."""
    dec = RangeDecoder(b"\xff" * 8, "ones")
    with pytest.raises(BitstreamError):
        dec.decode(1, exact_model(np.array([1, TOTAL_FREQUENCY - 1])))


def test_trailing_words_are_detected():
    f = np.array([TOTAL_FREQUENCY // 2] * 2)
    enc = RangeEncoder()
    enc.encode(np.arange(100) % 2, exact_model(f))
    data = enc.to_bytes()
    dec = RangeDecoder(data + b"\x12\x34\x56\x78" * 3)
    dec.decode(100, exact_model(f))
    with pytest.raises(BitstreamError):
        dec.check_exhausted()
    ref = RefRangeDecoder(words_of(data + b"\x12\x34\x56\x78" * 3))
    fl = f.tolist()
    assert [ref.decode([0, fl[0]], fl) for _ in range(100)] == (np.arange(100) % 2).tolist()
    assert ref.exhausted() is False
    assert math.isclose(len(data) * 8, 100, abs_tol=64)
