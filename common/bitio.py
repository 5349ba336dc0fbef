"""Bit-level reading and writing (MSB first), with the spec's descriptors:
u(n) fixed-width unsigned, ue(v) / se(v) 0-th order Exp-Golomb, b(8n) byte strings.

Every read is bounds-checked and names the element it was reading, so a truncated
or corrupted stream ends in a BitstreamError that says where.
"""

from __future__ import annotations

from .errors import BitstreamError

# ue(v) codes values up to 2^32 - 2; more leading zeros than this is corruption, not data.
MAX_EXP_GOLOMB_PREFIX = 32


class BitWriter:
    def __init__(self) -> None:
        self._buf = bytearray()
        self._acc = 0  # pending bits, MSB first
        self._nacc = 0

    @property
    def bit_position(self) -> int:
        return 8 * len(self._buf) + self._nacc

    def u(self, nbits: int, value: int, name: str = "") -> None:
        if nbits < 0 or nbits > 64:
            raise ValueError(f"u({nbits}) is not a valid descriptor")
        if value < 0 or value >> nbits:
            raise ValueError(f"{name or 'value'}={value} does not fit in u({nbits})")
        self._acc = (self._acc << nbits) | value
        self._nacc += nbits
        while self._nacc >= 8:
            self._nacc -= 8
            self._buf.append((self._acc >> self._nacc) & 0xFF)
        self._acc &= (1 << self._nacc) - 1

    def ue(self, value: int, name: str = "") -> None:
        if value < 0 or value >= (1 << MAX_EXP_GOLOMB_PREFIX) - 1:
            raise ValueError(f"{name or 'value'}={value} is outside the range of ue(v)")
        v1 = value + 1
        n = v1.bit_length() - 1
        self.u(n, 0, name)
        self.u(n + 1, v1, name)

    def se(self, value: int, name: str = "") -> None:
        self.ue(2 * value - 1 if value > 0 else -2 * value, name)

    def byte_align(self) -> None:
        if self._nacc:
            self.u(8 - self._nacc, 0, "alignment_zero_bits")

    def bytes(self, data: bytes, name: str = "") -> None:
        if self._nacc:
            raise ValueError(f"{name}: byte strings must start byte-aligned")
        self._buf += data

    def getvalue(self) -> bytes:
        if self._nacc:
            raise ValueError("stream is not byte-aligned")
        return bytes(self._buf)


class BitReader:
    def __init__(self, data: bytes, what: str = "data") -> None:
        self._data = memoryview(data)
        self._pos = 0  # in bits
        self._what = what

    @property
    def bit_position(self) -> int:
        return self._pos

    @property
    def bits_left(self) -> int:
        return 8 * len(self._data) - self._pos

    def _need(self, nbits: int, name: str) -> None:
        if nbits > self.bits_left:
            raise BitstreamError(
                f"{self._what} ends while reading {name or 'a syntax element'} "
                f"(needs {nbits} bits at bit {self._pos}, {self.bits_left} left)"
            , condition="E17")

    def u(self, nbits: int, name: str = "") -> int:
        self._need(nbits, name)
        value = 0
        pos = self._pos
        end = pos + nbits
        while pos < end:
            byte = self._data[pos >> 3]
            take = min(8 - (pos & 7), end - pos)
            shift = 8 - (pos & 7) - take
            value = (value << take) | ((byte >> shift) & ((1 << take) - 1))
            pos += take
        self._pos = end
        return value

    def ue(self, name: str = "") -> int:
        zeros = 0
        while self.u(1, name) == 0:
            zeros += 1
            if zeros >= MAX_EXP_GOLOMB_PREFIX:
                raise BitstreamError(f"{self._what}: invalid Exp-Golomb code for {name or 'a syntax element'}", condition="E18")
        return ((1 << zeros) | self.u(zeros, name)) - 1

    def se(self, name: str = "") -> int:
        k = self.ue(name)
        return (k + 1) // 2 if k & 1 else -(k // 2)

    def byte_align(self) -> None:
        pad = (-self._pos) & 7
        if pad and self.u(pad, "alignment_zero_bits") != 0:
            raise BitstreamError(f"{self._what}: non-zero alignment bits at bit {self._pos}", condition="E20")

    def bytes(self, nbytes: int, name: str = "") -> bytes:
        if self._pos & 7:
            raise BitstreamError(f"{self._what}: {name} is not byte-aligned")
        self._need(8 * nbytes, name)
        start = self._pos >> 3
        self._pos += 8 * nbytes
        return bytes(self._data[start : start + nbytes])
