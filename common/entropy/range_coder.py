"""Range coding with exact integer frequency tables (normative).

Every probability the codec uses is an integer frequency table of total 2^24 with
every frequency >= 1; constriction's queue RangeEncoder (32-bit words, 24-bit
precision) codes with exactly those frequencies. ``Categorical((f - 1), perfect=False)``
reproduces f exactly: constriction gives each symbol one unit and shares out the rest
in proportion to the weights, and the weights f - 1 sum to exactly 2^24 - n
(tests/test_range_coder.py checks this against the coder's own state).

Coded words are serialized as little-endian uint32.
"""

from __future__ import annotations

import constriction
import numpy as np

from ..errors import BitstreamError

PRECISION_BITS = 24
TOTAL_FREQUENCY = 1 << PRECISION_BITS
MAX_UNIFORM_BITS = 16  # raw bits are sent in pieces of at most this many


def check_frequencies(freqs: np.ndarray) -> np.ndarray:
    f = np.asarray(freqs, dtype=np.int64)
    if f.ndim != 1 or f.size < 1:
        raise ValueError("a frequency table is a non-empty 1-D array")
    if int(f.sum()) != TOTAL_FREQUENCY or int(f.min()) < 1:
        raise ValueError(f"frequencies must be >= 1 and sum to 2^{PRECISION_BITS} (sum={int(f.sum())}, "
                         f"min={int(f.min())})")
    return f


def exact_model(freqs: np.ndarray):
    """A constriction model that codes with exactly these integer frequencies."""
    f = check_frequencies(freqs)
    if f.size == 1:
        # One symbol costs nothing; constriction needs at least two entries, so give the
        # second one unit: the same code for the only symbol that can occur.
        f = np.array([TOTAL_FREQUENCY - 1, 1], dtype=np.int64)
    # (the ignores: constriction is a compiled module whose submodules pyright cannot see)
    return constriction.stream.model.Categorical((f - 1).astype(np.float64), perfect=False)  # pyright: ignore[reportAttributeAccessIssue]


# Binary models as a constriction model family: one call codes a run of binary decisions, each
# with its own model, instead of one call (and ~6 us of overhead) per context group. A row of
# weights is exact_model's for [2^24 - f1, f1] (w = f - 1, perfect=False), which constriction
# quantizes row by row exactly as it quantizes one Categorical (tests/test_range_coder.py).
_BINARY_FAMILY = constriction.stream.model.Categorical(perfect=False)  # pyright: ignore[reportAttributeAccessIssue]


def binary_weights(f1: np.ndarray, check: bool = True) -> np.ndarray:
    """The constriction weights [n, 2] of the binary models whose symbol 1 has frequency
    f1 (1 <= f1 < 2^24): row j codes with exactly the frequencies [2^24 - f1[j], f1[j]].
    ``check`` False: f1 is known to be in range (a caller that clipped it, once per chunk)."""
    f = np.asarray(f1, dtype=np.int64).ravel()
    if check and f.size and (int(f.min()) < 1 or int(f.max()) >= TOTAL_FREQUENCY):
        raise ValueError(f"binary frequency outside [1, 2^{PRECISION_BITS}): {int(f.min())}..{int(f.max())}")
    w = np.empty((f.size, 2), dtype=np.float64)
    w[:, 0] = TOTAL_FREQUENCY - 1 - f
    w[:, 1] = f - 1
    return w


def _uniform(nbits: int):
    return constriction.stream.model.Uniform(1 << nbits)  # pyright: ignore[reportAttributeAccessIssue]


class RangeEncoder:
    def __init__(self) -> None:
        self._enc = constriction.stream.queue.RangeEncoder()  # pyright: ignore[reportAttributeAccessIssue]

    def encode(self, symbols: np.ndarray, model) -> None:
        """Code i.i.d. symbols (0-based indices) with one model from ``exact_model``."""
        s = np.ascontiguousarray(symbols, dtype=np.int32)
        if s.size:
            try:
                self._enc.encode(s, model)
            except (KeyError, ValueError) as e:  # constriction signals a symbol outside the model this way
                raise ValueError(f"a symbol is outside its model's alphabet ({e})") from None

    def encode_binary(self, symbols: np.ndarray, f1: np.ndarray) -> None:
        """Code binary decisions (0 or 1), decision j with frequency f1[j] of symbol 1 (of 2^24)."""
        self.encode_binary_models(symbols, binary_weights(f1))

    def encode_binary_models(self, symbols: np.ndarray, models: np.ndarray) -> None:
        """Code binary decisions, decision j with the model of row j of ``models`` (rows of
        ``binary_weights``: a coder of many decisions computes each context's row once)."""
        s = np.ascontiguousarray(symbols, dtype=np.int32).ravel()
        if s.size:
            if int(s.min()) < 0 or int(s.max()) > 1:
                raise ValueError("a binary decision is not 0 or 1")
            self._enc.encode(s, _BINARY_FAMILY, models)

    def encode_bits(self, values: np.ndarray, nbits: np.ndarray | int) -> None:
        """Code unsigned integers of ``nbits`` bits each (0..64) with uniform probabilities."""
        raw = np.asarray(values).ravel()
        if raw.size and np.issubdtype(raw.dtype, np.signedinteger) and raw.min() < 0:
            raise ValueError("encode_bits codes unsigned values only")
        v = raw.astype(np.uint64)
        nb = np.broadcast_to(np.asarray(nbits, dtype=np.int64), v.shape)
        if nb.size and (nb.min() < 0 or nb.max() > 64):
            raise ValueError("bit widths must be in [0, 64]")
        narrow = nb < 64
        if np.any(v[narrow] >> nb[narrow].astype(np.uint64)):
            raise ValueError("a value does not fit in its bit width")
        for shift in range(0, int(nb.max(initial=0)), MAX_UNIFORM_BITS):
            sel = nb > shift
            if not sel.any():
                break
            width = np.minimum(nb[sel] - shift, MAX_UNIFORM_BITS)
            piece = (v[sel] >> np.uint64(shift)) & ((np.uint64(1) << width.astype(np.uint64)) - np.uint64(1))
            for w in np.unique(width):
                m = width == w
                self._enc.encode(piece[m].astype(np.int32), _uniform(int(w)))

    def to_bytes(self) -> bytes:
        return self._enc.get_compressed().astype("<u4").tobytes()


class RangeDecoder:
    def __init__(self, data: bytes, what: str = "coded data") -> None:
        if len(data) % 4:
            raise BitstreamError(f"{what}: length {len(data)} is not a whole number of 32-bit words", condition="E35")
        self._what = what
        words = np.frombuffer(data, dtype="<u4").astype(np.uint32)
        try:
            self._dec = constriction.stream.queue.RangeDecoder(words)  # pyright: ignore[reportAttributeAccessIssue]
        except Exception as e:  # constriction rejects some impossible word sequences up front
            raise BitstreamError(f"{what}: invalid range-coded data ({e})", condition="E36") from None

    def decode(self, count: int, model) -> np.ndarray:
        """``count`` symbols (int32, as constriction returns them)."""
        if count == 0:
            return np.zeros(0, dtype=np.int32)
        try:
            return self._dec.decode(model, int(count))
        except Exception as e:
            raise BitstreamError(f"{self._what}: range decoding failed ({e})", condition="E36") from None

    def decode_binary(self, f1: np.ndarray) -> np.ndarray:
        """One binary decision per entry of f1 (frequency of symbol 1, of 2^24); int32."""
        return self.decode_binary_models(binary_weights(f1))

    def decode_binary_models(self, w: np.ndarray) -> np.ndarray:
        """One binary decision per row of ``w`` (rows of ``binary_weights``); int32."""
        if not w.shape[0]:
            return np.zeros(0, dtype=np.int32)
        try:
            return self._dec.decode(_BINARY_FAMILY, w)
        except Exception as e:
            raise BitstreamError(f"{self._what}: range decoding failed ({e})", condition="E36") from None

    def decode_bits(self, nbits: np.ndarray | int, count: int | None = None) -> np.ndarray:
        nb = np.asarray(nbits, dtype=np.int64)
        if nb.ndim == 0:
            if count is None:
                raise ValueError("decode_bits with one width needs a count")
            nb = np.full(int(count), int(nb), dtype=np.int64)
        out = np.zeros(nb.shape, dtype=np.uint64)
        for shift in range(0, int(nb.max(initial=0)), MAX_UNIFORM_BITS):
            sel = np.flatnonzero(nb > shift)
            if not sel.size:
                break
            width = np.minimum(nb[sel] - shift, MAX_UNIFORM_BITS)
            piece = np.zeros(sel.size, dtype=np.uint64)
            for w in np.unique(width):
                m = width == w
                piece[m] = self.decode(int(m.sum()), _uniform(int(w))).astype(np.uint64)
            out[sel] |= piece << np.uint64(shift)
        return out

    def check_exhausted(self) -> None:
        """The coder must have consumed all its words: leftover data means corruption."""
        if self._dec.maybe_exhausted() is False:
            raise BitstreamError(f"{self._what}: data left over after decoding", condition="E38")
