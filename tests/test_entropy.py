"""Frozen scale tables and the attribute symbol coder (common/entropy/{tables,symbol_coder}.py)."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lghcc.common.entropy import symbol_coder as sc
from lghcc.common.entropy.range_coder import RangeEncoder, exact_model
from lghcc.common.entropy.symbol_coder import (
    best_level,
    best_level_and_bits,
    decode_chunked,
    decode_symbols,
    encode_chunked,
    encode_symbols,
    escape_class,
)
from lghcc.common.entropy.tables import (
    MAX_ABS_RESIDUAL,
    NUM_ESCAPE_CLASSES,
    NUM_SCALE_LEVELS,
    SCALE_SIGMAS,
    SCALE_TABLES_SHA256,
    TABLES,
    TABLES_PATH,
    TOTAL_FREQUENCY,
    canonical_bytes,
    load_tables,
)
from lghcc.common.errors import BitstreamError
from lghcc.encoder.context.code_lengths import estimate_bits_float, ideal_code_length_bits, level_for_sigma
from test_range_coder import RefRangeDecoder, cumulative, ref_decode_bits, words_of

ROOT = Path(__file__).resolve().parents[1]
BIG = MAX_ABS_RESIDUAL


# --- tables --------------------------------------------------------------------------------

def test_table_invariants():
    L = TABLES.half_widths
    assert L.size == NUM_SCALE_LEVELS and TABLES_PATH.stat().st_size < 1_000_000
    for i in range(NUM_SCALE_LEVELS):
        f = TABLES.level(i)
        assert f.size == 2 * L[i] + 2
        assert int(f.sum()) == TOTAL_FREQUENCY and int(f.min()) >= 1
        body = f[:-1]
        assert np.array_equal(body, body[::-1]), f"level {i} not symmetric"
        half = body[L[i]:]
        assert np.all(np.diff(half) <= 0), f"level {i} not unimodal"
        assert L[i] >= min(np.ceil(8 * SCALE_SIGMAS[i]), 4096)
    c = TABLES.escape_class_freqs
    assert c.size == NUM_ESCAPE_CLASSES and int(c.sum()) == TOTAL_FREQUENCY and int(c.min()) >= 1
    assert np.all(np.diff(c) <= 0)


def test_tables_are_monotone_in_level():
    L = TABLES.half_widths
    centre = np.array([TABLES.level(i)[L[i]] for i in range(NUM_SCALE_LEVELS)])
    assert np.all(np.diff(L) >= 0)
    assert np.all(np.diff(centre) < 0)
    assert np.all(np.diff(SCALE_SIGMAS) > 0)
    assert SCALE_SIGMAS[0] == pytest.approx(0.11) and SCALE_SIGMAS[-1] == pytest.approx(512.0)


def test_tables_match_their_sha256_and_the_spec():
    t = TABLES
    digest = hashlib.sha256(canonical_bytes(t.half_widths, t.freqs, t.escape_class_freqs)).hexdigest()
    assert digest == SCALE_TABLES_SHA256
    assert SCALE_TABLES_SHA256 in (ROOT / "spec" / "entropy.md").read_text()


def test_tables_close_to_the_gaussian_they_model():
    from scipy.special import ndtr
    for i in (0, 20, 40, 63):
        s, L = SCALE_SIGMAS[i], int(TABLES.half_widths[i])
        r = np.arange(-L, L + 1)
        p = ndtr((r + 0.5) / s) - ndtr((r - 0.5) / s)
        q = TABLES.level(i)[:-1] / TOTAL_FREQUENCY
        m = p > 0
        kl = float(np.sum(p[m] * np.log2(p[m] / q[m])))
        # the floor of one unit per bin costs at most (2 L + 2) / 2^24 of mass: < 5e-4 bits/symbol
        assert kl < 5e-4, (i, kl)


def test_damaged_tables_are_refused(tmp_path):
    with np.load(TABLES_PATH) as z:
        arrays = {k: z[k].copy() for k in z.files}
    arrays["freqs"][10] += 1
    arrays["freqs"][11] -= 1
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(RuntimeError, match="SHA-256"):
        load_tables(bad)
    with pytest.raises(RuntimeError):
        load_tables(tmp_path / "missing.npz")


@pytest.mark.slow
def test_generator_reproduces_the_stored_tables():
    """Informative: the float generation reproduces the frozen constants on this machine."""
    res = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_scale_tables.py"), "--check"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


# --- round trips -----------------------------------------------------------------------------

def roundtrip(r, lv) -> bytes:
    r = np.asarray(r, dtype=np.int64)
    lv = np.asarray(lv)
    data = encode_symbols(r, lv)
    out = decode_symbols(data, lv)
    assert out.dtype == np.int64 and out.shape == lv.shape
    assert np.array_equal(out, r)
    return data


residual = st.one_of(
    st.integers(-3, 3), st.integers(-200, 200), st.integers(-20000, 20000),
    st.integers(-BIG, BIG), st.sampled_from([BIG, -BIG, BIG - 1, -BIG + 1, 2**61, -(2**61), 2**61 - 1]))


@settings(max_examples=80)
@given(st.lists(st.tuples(residual, st.integers(0, NUM_SCALE_LEVELS - 1)), max_size=120))
def test_round_trip_random(pairs):
    r = np.array([p[0] for p in pairs], dtype=np.int64)
    lv = np.array([p[1] for p in pairs], dtype=np.int64)
    roundtrip(r, lv)


@settings(max_examples=25)
@given(st.integers(0, 2**32 - 1), st.integers(1, 3000), st.booleans())
def test_round_trip_gaussian_with_outliers(seed, n, same_level):
    rng = np.random.default_rng(seed)
    lv = np.full(n, int(rng.integers(64))) if same_level else rng.integers(0, 64, n)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv] * rng.uniform(0.5, 3))).astype(np.int64)
    out = rng.random(n) < 0.01
    r[out] = rng.integers(-(2**40), 2**40, int(out.sum()))
    roundtrip(r, lv.astype(np.int32))


def test_edge_cases():
    assert encode_symbols(np.zeros(0, np.int64), np.zeros(0, np.int64)) == b""
    assert decode_symbols(b"", np.zeros(0, np.int64)).shape == (0,)
    for lv in (0, 31, 63):
        for v in (0, 1, -1, int(TABLES.half_widths[lv]), -int(TABLES.half_widths[lv]),
                  int(TABLES.half_widths[lv]) + 1, -int(TABLES.half_widths[lv]) - 1, BIG, -BIG):
            roundtrip([v], [lv])
    # every escape class boundary, both signs, every level
    vals, lvs = [], []
    for lv in range(NUM_SCALE_LEVELS):
        L = int(TABLES.half_widths[lv])
        for k in range(0, 63):
            for m in {max((1 << k) - 1, 0), 1 << max(k - 1, 0) if k else 0}:
                if L + 1 + m <= BIG:
                    vals += [L + 1 + m, -(L + 1 + m)]
                    lvs += [lv, lv]
    roundtrip(vals, lvs)
    # all one level, all zeros: the coder spends next to nothing
    assert len(roundtrip(np.zeros(10000, np.int64), np.zeros(10000, np.int64))) <= 8
    # unsigned and narrow dtypes are fine
    roundtrip(np.array([1, 2, 3], dtype=np.uint16), np.array([5, 5, 5], dtype=np.uint8))
    # 2-D input is coded in row-major order and comes back in the levels' shape
    r2 = np.arange(12).reshape(3, 4) - 6
    lv2 = np.arange(12).reshape(3, 4) % 64
    assert np.array_equal(decode_symbols(encode_symbols(r2, lv2), lv2), r2)
    assert encode_symbols(r2, lv2) == encode_symbols(r2.ravel(), lv2.ravel())


@pytest.mark.parametrize("r, lv", [
    ([2**62], [0]), ([-(2**62)], [0]), ([np.iinfo(np.int64).min], [3]), ([np.iinfo(np.int64).max], [3]),
    ([0], [64]), ([0], [-1]), ([0.0], [0]), ([0, 1], [0]),
])
def test_encoder_rejects_out_of_range_input(r, lv):
    with pytest.raises(ValueError):
        encode_symbols(np.array(r), np.array(lv))
    with pytest.raises(ValueError):
        ideal_code_length_bits(np.array(r), np.array(lv))


def test_encoder_rejects_huge_unsigned():
    with pytest.raises(ValueError):
        encode_symbols(np.array([2**63], dtype=np.uint64), np.array([0]))


def test_escape_class_is_the_bit_length():
    rng = np.random.default_rng(3)
    m = np.concatenate([[0, 1, 2, 3, 4], [(1 << k) + d for k in range(62) for d in (-1, 0, 1)],
                        rng.integers(0, 2**62, 1000)]).astype(np.int64)
    m = m[m >= 0]
    assert escape_class(m).tolist() == [int(x).bit_length() for x in m.tolist()]
    small = m[m < 2**53]  # the float64 path
    assert escape_class(small).tolist() == [int(x).bit_length() for x in small.tolist()]
    assert escape_class(np.zeros((0, 3), np.int64)).shape == (0, 3)


@given(st.lists(st.one_of(st.integers(0, 2**53 + 2), st.integers(0, 2**63 - 1)), min_size=1, max_size=40))
def test_escape_class_is_the_bit_length_on_both_paths(values):
    m = np.array(values, dtype=np.uint64).reshape(-1, 1)
    assert escape_class(m).ravel().tolist() == [int(x).bit_length() for x in values]
    assert escape_class(m.astype(np.int64)).ravel().tolist() == [int(x).bit_length() for x in values]


# --- the code length -------------------------------------------------------------------------

def test_ideal_code_length_by_hand():
    f0 = TABLES.level(0)
    L0 = int(TABLES.half_widths[0])
    assert ideal_code_length_bits([0], [0]) == pytest.approx(24 - np.log2(f0[L0]))
    c = TABLES.escape_class_freqs
    r = L0 + 1 + 5  # m = 5: class 3, 2 remainder bits
    expected = (24 - np.log2(f0[-1])) + 1 + (24 - np.log2(c[3])) + 2
    assert ideal_code_length_bits([-r], [0]) == pytest.approx(expected)
    assert ideal_code_length_bits([], []) == 0.0


def test_overhead_over_the_ideal_is_below_a_thousandth():
    rng = np.random.default_rng(11)
    n = 100_000
    lv = rng.integers(0, 64, n)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv] * 1.3)).astype(np.int64)
    r[rng.random(n) < 0.001] = 10**6
    data = roundtrip(r, lv)
    ideal = ideal_code_length_bits(r, lv)
    assert ideal < len(data) * 8 < ideal * 1.001
    # the informative float estimate agrees closely (no escapes here)
    r2 = np.rint(rng.normal(0, SCALE_SIGMAS[lv])).astype(np.int64)
    assert estimate_bits_float(r2, SCALE_SIGMAS[lv]) == pytest.approx(ideal_code_length_bits(r2, lv), rel=0.01)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(-(1 << 20), 1 << 20), min_size=1, max_size=300), st.integers(0, 1000), st.booleans())
def test_best_level_is_the_cheapest_of_all_levels(values, zeros, narrow):
    """best_level is the argmin over all 64 levels of the ideal code length (lowest level on
    ties), also for heavy-tailed inputs: many zeros and a few large values; best_level_and_bits
    gives that length too. ``narrow``: every |r| <= 1024 (counted without a sort)."""
    r = np.array(values + [0] * zeros, dtype=np.int64)
    if narrow:
        r = np.clip(r, -1024, 1024)
    costs = [ideal_code_length_bits(r, np.full(r.size, lv)) for lv in range(64)]
    lv = best_level(r)
    assert costs[lv] <= min(costs) + 1e-6 * max(1.0, min(costs))
    assert lv == min(i for i, c in enumerate(costs) if c <= min(costs) + 1e-6 * max(1.0, min(costs)))
    level, bits = best_level_and_bits(r)
    assert level == lv and bits == pytest.approx(costs[lv], rel=1e-12)


def test_best_level_codes_a_heavy_tailed_channel_narrowly():
    """Mostly zeros with 2% large values (the offsets of a rate-trained scene): a narrow level plus
    escapes costs far less than the level of the RMS."""
    rng = np.random.default_rng(3)
    r = np.where(rng.random(5000) < 0.02, rng.integers(-300, 300, 5000), 0)
    rms_level = int(level_for_sigma(np.array([np.sqrt(np.mean(r.astype(float) ** 2))]))[0])
    lv = best_level(r)
    assert lv < rms_level - 10
    assert ideal_code_length_bits(r, np.full(r.size, lv)) < 0.5 * ideal_code_length_bits(r, np.full(r.size, rms_level))


def test_code_lengths_sum_to_the_ideal_code_length():
    rng = np.random.default_rng(4)
    lv = rng.integers(0, 64, 2000)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv] * 3)).astype(np.int64)
    per = sc.code_lengths_bits(r.reshape(40, 50), lv.reshape(40, 50))
    assert per.shape == (40, 50) and (per > 0).all()
    assert per.sum() == pytest.approx(ideal_code_length_bits(r, lv))


@settings(max_examples=60, deadline=None)
@given(r=st.lists(st.one_of(st.integers(-1030, 1030), st.integers(-(2 ** 62) + 1, 2 ** 62 - 1)), min_size=1,
                  max_size=60),
       seed=st.integers(0, 2 ** 32 - 1))
def test_code_lengths_from_the_lookup_table_equal_the_tables_bit_for_bit(r, seed):
    """code_lengths_bits reads residuals within +-_LUT_R from a table built with the same formula
    and computes the others: every value equal to the formula's, escapes and table edges included."""
    r = np.array(r + [sc._LUT_R, -sc._LUT_R, sc._LUT_R + 1, -sc._LUT_R - 1], dtype=np.int64)
    lv = np.random.default_rng(seed).integers(0, 64, r.size)
    np.testing.assert_array_equal(sc.code_lengths_bits(r, lv), sc._code_lengths_bits(r, lv.astype(np.uint8)))
    with pytest.raises(ValueError, match="codable range"):
        sc.code_lengths_bits(np.array([2 ** 62]), np.array([3]))
    with pytest.raises(ValueError, match="levels must lie"):
        sc.code_lengths_bits(np.array([1]), np.array([64]))


def test_level_for_sigma():
    assert np.array_equal(level_for_sigma(SCALE_SIGMAS), np.arange(64))
    assert np.array_equal(level_for_sigma(SCALE_SIGMAS * 1.05), np.arange(64))
    assert level_for_sigma(np.array([0.0, 1e-9, 1e9, np.inf])).tolist() == [0, 0, 63, 63]
    with pytest.raises(ValueError):
        level_for_sigma(np.array([np.nan]))


# --- malformed chunks ------------------------------------------------------------------------

def sample_chunk(seed=5, n=400):
    rng = np.random.default_rng(seed)
    lv = rng.integers(0, 64, n)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv])).astype(np.int64)
    r[::37] = rng.integers(-(2**50), 2**50, r[::37].size)
    return r, lv, encode_symbols(r, lv)


@settings(max_examples=60)
@given(st.data())
def test_damaged_chunks_raise_bitstream_error_or_decode_to_the_right_shape(data):
    r, lv, chunk = sample_chunk()
    how = data.draw(st.sampled_from(["truncate", "flip", "append", "words"]))
    b = bytearray(chunk)
    if how == "truncate":
        b = b[:data.draw(st.integers(0, len(b) - 1))]
    elif how == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, len(b) * 8 - 1))
            b[i // 8] ^= 1 << (i % 8)
    elif how == "append":
        b += data.draw(st.binary(min_size=1, max_size=12))
    else:
        b = bytearray(data.draw(st.binary(max_size=200)))
    try:
        out = decode_symbols(bytes(b), lv, "damaged")
    except BitstreamError:
        return
    assert out.shape == lv.shape and out.dtype == np.int64
    assert np.abs(out).max() <= MAX_ABS_RESIDUAL


def test_trailing_words_and_oversized_escapes_are_errors():
    r, lv, chunk = sample_chunk()
    with pytest.raises(BitstreamError):
        decode_symbols(chunk + b"\x01\x02\x03\x04" * 2, lv)
    with pytest.raises(BitstreamError):
        decode_symbols(chunk, lv[:-50])
    # an escape of class 62 with all remainder bits set: |r| = L + 2^62 > 2^62 - 1
    enc = RangeEncoder()
    enc.encode(np.array([2 * TABLES.half_widths[0] + 1]), exact_model(TABLES.level(0)))
    enc.encode_bits(np.array([0], np.uint64), 1)
    enc.encode(np.array([62]), exact_model(TABLES.escape_class_freqs))
    enc.encode_bits(np.array([(1 << 61) - 1], np.uint64), 61)
    with pytest.raises(BitstreamError, match="exceeds"):
        decode_symbols(enc.to_bytes(), np.array([0]))


# --- chunks ----------------------------------------------------------------------------------

@settings(max_examples=25)
@given(st.integers(0, 60), st.integers(1, 4), st.integers(1, 25), st.integers(0, 2**32 - 1))
def test_chunked_round_trip(N, M, S, seed):
    rng = np.random.default_rng(seed)
    lv = rng.integers(0, 64, (N, M))
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv] * 2)).astype(np.int64)
    chunks = encode_chunked(r, lv, S)
    assert len(chunks) == -(-N // S)
    for k, c in enumerate(chunks):
        assert c == encode_symbols(r[k * S:(k + 1) * S], lv[k * S:(k + 1) * S])
    assert np.array_equal(decode_chunked(chunks, lv, S), r)


def test_chunked_errors():
    lv = np.zeros((10, 2), np.int64)
    r = np.zeros((10, 2), np.int64)
    chunks = encode_chunked(r, lv, 3)
    assert len(chunks) == 4
    with pytest.raises(BitstreamError):
        decode_chunked(chunks[:-1], lv, 3)
    with pytest.raises(BitstreamError):
        decode_chunked(chunks + [b""], lv, 3)
    for bad in (0, -1, 1.5):
        with pytest.raises(ValueError):
            encode_chunked(r, lv, bad)
        with pytest.raises(ValueError):
            decode_chunked(chunks, lv, bad)
    with pytest.raises(ValueError):
        encode_chunked(r, lv[:5], 3)
    assert encode_chunked(np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64), 4) == []


# --- the spec's chunk decoding process, written independently --------------------------------

def spec_decode_chunk(data: bytes, levels: list[int]) -> list[int]:
    """spec/entropy.md, clause "Decoding a chunk", in plain Python on the reference range decoder."""
    dec = RefRangeDecoder(words_of(data))
    n = len(levels)
    bins = [0] * n
    for i in range(NUM_SCALE_LEVELS):
        f = TABLES.level(i).tolist()
        cum = cumulative(f)
        for j in range(n):
            if levels[j] == i:
                bins[j] = dec.decode(cum, f)
    L = [int(TABLES.half_widths[lv]) for lv in levels]
    esc = [j for j in range(n) if bins[j] == 2 * L[j] + 1]
    out = [bins[j] - L[j] for j in range(n)]
    signs = ref_decode_bits(dec, [1] * len(esc))
    cf = TABLES.escape_class_freqs.tolist()
    ccum = cumulative(cf)
    classes = [dec.decode(ccum, cf) for _ in esc]
    rems = ref_decode_bits(dec, [max(k - 1, 0) for k in classes])
    for j, s, k, rem in zip(esc, signs, classes, rems):
        m = 0 if k == 0 else (1 << (k - 1)) + rem
        mag = L[j] + 1 + m
        assert mag <= MAX_ABS_RESIDUAL
        out[j] = -mag if s else mag
    assert dec.exhausted()
    return out


@settings(max_examples=15)
@given(st.integers(0, 2**32 - 1), st.integers(0, 300))
def test_spec_decoding_process_matches(seed, n):
    rng = np.random.default_rng(seed)
    lv = rng.integers(0, 64, n)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv] * 1.5)).astype(np.int64)
    sel = rng.random(n) < 0.1
    r[sel] = rng.integers(-(2**62) + 1, 2**62, int(sel.sum()))
    assert spec_decode_chunk(encode_symbols(r, lv), lv.tolist()) == r.tolist()


# --- throughput (informative; spec/entropy.md annex) -----------------------------------------

@pytest.mark.slow
def test_throughput_at_least_five_million_symbols_per_second():
    import time
    rng = np.random.default_rng(0)
    n = 2_000_000
    lv = rng.integers(0, 64, n)
    r = np.rint(rng.normal(0, SCALE_SIGMAS[lv])).astype(np.int64)
    encode_symbols(r[:1000], lv[:1000])
    t = time.perf_counter()
    data = encode_symbols(r, lv)
    te = time.perf_counter() - t
    t = time.perf_counter()
    out = decode_symbols(data, lv)
    td = time.perf_counter() - t
    assert np.array_equal(out, r)
    assert n / te > 5e6 and n / td > 5e6, (n / te, n / td)


def test_models_are_cached():
    sc._level_model(7)
    assert sc._level_model(7) is sc._level_model(7)
    assert sc._class_model() is sc._class_model()


@given(st.integers(1, 40), st.integers(1, 20), st.integers(0, 2 ** 32 - 1))
def test_column_level_fast_path_is_the_same_code(rows, cols, seed):
    """Levels given as one row broadcast over the chunk take a sort-free path: it must write
    and read exactly the bytes of the general path (the normative order)."""
    rng = np.random.default_rng(seed)
    row = rng.integers(0, 64, cols)
    broadcast = np.broadcast_to(row, (rows, cols))
    full = np.ascontiguousarray(broadcast)
    r = np.rint(rng.normal(size=(rows, cols)) * 4).astype(np.int64)
    r.flat[rng.integers(0, r.size)] = int(rng.integers(-(2 ** 40), 2 ** 40))  # one escape
    data = encode_symbols(r, full)
    assert encode_symbols(r, broadcast) == data
    assert np.array_equal(decode_symbols(data, broadcast), r)


def test_escape_class_by_table_below_2_16_and_by_frexp_above():
    m = np.arange(0, (1 << 16) + 3, dtype=np.int64)  # the look-up's whole range, then its edge
    assert escape_class(m).tolist() == [int(x).bit_length() for x in m.tolist()]
    for last in ((1 << 16) - 1, 1 << 16):  # one value past the table sends the whole array to frexp
        block = np.array([[0, 1, 5], [7, 3, last]], np.int64)
        assert escape_class(block).tolist() == [[int(x).bit_length() for x in row] for row in block.tolist()]
        assert escape_class(block).dtype == np.int64
    assert escape_class(np.array([0], np.int32)).tolist() == [0]
