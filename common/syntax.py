"""One declarative syntax description per structure drives every operation on it.

A structure's ``syntax(v)`` method names each syntax element once, with its
descriptor and its allowed range. Visitors give that description its meanings:

  ReadVisitor   parse: sets fields, checks ranges (BitstreamError names the element)
  WriteVisitor  serialize: reads fields, checks ranges (ValueError: an encoder bug)
  SizeVisitor   count bits without writing
  TableVisitor  emit the spec's syntax table (spec/syntax_tables.md is generated from it)

Reading and writing optionally record a trace: one entry per element, with its bit
position, name, descriptor and value (``lghcc-dec --trace``).

Blocks are generators so that every visitor sees where they start and end::

    def syntax(self, v):
        v.ue(self, "num_levels_minus1", hi=7)
        for _ in v.when(self.adaptive_step_flag, "adaptive_step_flag"):
            for i in v.loop(self.num_levels_minus1 + 1, "num_levels_minus1 + 1", self, ("step_log2",)):
                v.ue(self, "step_log2", i)

Parsing never depends on derived state: conditions and counts use only elements
already parsed. Derivation is a separate step after parsing.
"""

from __future__ import annotations

import struct as _struct
from dataclasses import dataclass
from typing import Any, ClassVar, Iterator

from .bitio import BitReader, BitWriter
from .errors import BitstreamError


@dataclass
class TraceEntry:
    bit_position: int
    name: str
    descriptor: str
    value: Any


def _label(name: str, i: int | None) -> str:
    return name if i is None else f"{name}[{i}]"


def _get(obj: Any, name: str, i: int | None) -> Any:
    value = getattr(obj, name)
    return value if i is None else value[i]


def _set(obj: Any, name: str, i: int | None, value: Any) -> None:
    if i is None:
        setattr(obj, name, value)
    else:
        getattr(obj, name)[i] = value


def f32_bits(x: float) -> int:
    return _struct.unpack("<I", _struct.pack("<f", x))[0]


def bits_f32(b: int) -> float:
    return _struct.unpack("<f", _struct.pack("<I", b))[0]


class SyntaxVisitor:
    """Base: the element methods, each defined once in terms of ``_visit``."""

    structure: str = ""

    def _visit(self, desc: str, obj: Any, name: str, i: int | None, lo: int | None, hi: int | None,
               read, write, nbits) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- elements -----------------------------------------------------------------
    def u(self, nbits: int, obj: Any, name: str, i: int | None = None, *, lo: int = 0,
          hi: int | None = None, width: str | None = None) -> int:
        """Unsigned integer u(n) of ``nbits`` bits. ``width`` names a variable width (an expression
        of elements parsed before) in the table; a trace records the number of bits."""
        return self._visit(self._u_descriptor(nbits, width), obj, name, i, lo, hi,
                           lambda r, lab: r.u(nbits, lab), lambda w, v, lab: w.u(nbits, v, lab),
                           lambda v: nbits)

    def _u_descriptor(self, nbits: int, width: str | None) -> str:
        return f"u({nbits})"

    def flag(self, obj: Any, name: str, i: int | None = None) -> bool:
        return bool(self.u(1, obj, name, i))

    def ue(self, obj: Any, name: str, i: int | None = None, *, lo: int = 0, hi: int | None = None) -> int:
        return self._visit("ue(v)", obj, name, i, lo, hi,
                           lambda r, lab: r.ue(lab), lambda w, v, lab: w.ue(v, lab),
                           lambda v: 2 * (v + 1).bit_length() - 1)

    def se(self, obj: Any, name: str, i: int | None = None, *, lo: int | None = None,
           hi: int | None = None) -> int:
        return self._visit("se(v)", obj, name, i, lo, hi,
                           lambda r, lab: r.se(lab), lambda w, v, lab: w.se(v, lab),
                           lambda v: 2 * ((2 * v - 1 if v > 0 else -2 * v) + 1).bit_length() - 1)

    def f32(self, obj: Any, name: str, i: int | None = None, *, positive: bool = False) -> float:
        """IEEE 754 binary32, stored as its 32 bits; must be finite (and > 0 when ``positive``)."""
        return self._visit("f(32)", obj, name, i, None, None,
                           lambda r, lab: _checked_f32(r.u(32, lab), lab, positive),
                           lambda w, v, lab: w.u(32, f32_bits(_checked_f32_value(v, lab, positive)), lab),
                           lambda v: 32)

    def payload(self, obj: Any, name: str, nbytes: int) -> bytes:
        """A byte string b(8*n) of n = ``nbytes`` bytes; starts byte-aligned."""
        return self._visit(f"b(8*{nbytes})", obj, name, None, None, None,
                           lambda r, lab: r.bytes(nbytes, lab), lambda w, v, lab: w.bytes(v, lab),
                           lambda v: 8 * len(v))

    def byte_align(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- blocks ---------------------------------------------------------------------
    def when(self, condition: Any, text: str) -> Iterator[None]:
        if condition:
            yield None

    def loop(self, count: int, text: str, obj: Any = None, arrays: tuple[str, ...] = (),
             index: str = "i") -> Iterator[int]:
        """Iterate ``count`` times. A ReadVisitor first gives ``obj`` a fresh list per name in
        ``arrays``; ``count`` has been range-checked by the element it came from."""
        yield from range(count)

    def struct(self, obj: Any, name: str, i: int | None, cls: type["SyntaxStructure"], **context) -> Any:
        """A nested structure, stored in ``obj.name`` (or ``obj.name[i]``); ``context`` carries
        already-parsed values the child's syntax depends on."""
        child = _get(obj, name, i)
        saved = self.structure
        self.structure = cls.syntax_name
        child.syntax(self)
        self.structure = saved
        return child


def _checked_f32(bits: int, name: str, positive: bool) -> float:
    x = bits_f32(bits)
    if x != x or x in (float("inf"), float("-inf")):
        raise BitstreamError(f"{name} is not a finite number", condition="E19")
    if positive and not x > 0:
        raise BitstreamError(f"{name}={x} must be greater than zero", condition="E19")
    return x


def _checked_f32_value(x: float, name: str, positive: bool) -> float:
    y = bits_f32(f32_bits(float(x)))
    if y != y or y in (float("inf"), float("-inf")) or (positive and not y > 0):
        raise ValueError(f"{name}={x} is not a valid f(32) value here")
    return y


def _check_range(value: int, lo: int | None, hi: int | None) -> bool:
    return (lo is None or value >= lo) and (hi is None or value <= hi)


# a range check that is a row of clause 8.2's own, not E19 (a syntax element outside its range)
_RANGE_CONDITIONS = {("data_unit_header", "unit_type"): "E7"}


class ReadVisitor(SyntaxVisitor):
    def __init__(self, reader: BitReader, structure: str = "", trace: list[TraceEntry] | None = None):
        self.r = reader
        self.structure = structure
        self.trace = trace

    def _visit(self, desc, obj, name, i, lo, hi, read, write, nbits):
        lab = _label(name, i)
        pos = self.r.bit_position
        value = read(self.r, lab)
        if isinstance(value, int) and not _check_range(value, lo, hi):
            raise BitstreamError(
                f"{self.structure}.{lab} = {value} is outside its allowed range "
                f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]",
                condition=_RANGE_CONDITIONS.get((self.structure, lab), "E19"))
        _set(obj, name, i, value)
        if self.trace is not None:
            self.trace.append(TraceEntry(pos, f"{self.structure}.{lab}", desc, value))
        return value

    def byte_align(self) -> None:
        self.r.byte_align()

    def struct(self, obj, name, i, cls, **context):
        _set(obj, name, i, cls(**context))
        return super().struct(obj, name, i, cls, **context)

    def loop(self, count, text, obj=None, arrays=(), index="i"):
        for a in arrays:
            setattr(obj, a, [None] * count)
        yield from range(count)


class WriteVisitor(SyntaxVisitor):
    def __init__(self, writer: BitWriter, structure: str = "", trace: list[TraceEntry] | None = None):
        self.w = writer
        self.structure = structure
        self.trace = trace

    def _visit(self, desc, obj, name, i, lo, hi, read, write, nbits):
        lab = _label(name, i)
        value = _get(obj, name, i)
        if isinstance(value, bool):
            value = int(value)
        if isinstance(value, int) and not _check_range(value, lo, hi):
            raise ValueError(f"{self.structure}.{lab} = {value} is outside its allowed range [{lo}, {hi}]")
        pos = self.w.bit_position
        write(self.w, value, lab)
        if self.trace is not None:
            self.trace.append(TraceEntry(pos, f"{self.structure}.{lab}", desc, value))
        return value

    def byte_align(self) -> None:
        self.w.byte_align()


class SizeVisitor(SyntaxVisitor):
    """Counts the bits a structure occupies, without writing it."""

    def __init__(self) -> None:
        self.bits = 0

    def _visit(self, desc, obj, name, i, lo, hi, read, write, nbits):
        value = _get(obj, name, i)
        if isinstance(value, bool):
            value = int(value)
        self.bits += nbits(value)
        return value

    def byte_align(self) -> None:
        self.bits += (-self.bits) & 7


@dataclass
class TableRow:
    depth: int
    text: str
    descriptor: str = ""
    lo: int | None = None
    hi: int | None = None


class TableVisitor(SyntaxVisitor):
    """Walks every branch once and records the syntax table of a structure.

    An array element is labelled with the index variable of the innermost loop around it
    (``for( l ... ) output_dim_minus1[ l ]``). A byte string is labelled b(8*n) with n the
    element that gives its length, found by probing (``SyntaxStructure.syntax_table``):
    ``probe = (name, value)`` makes the scalar element ``name`` take ``value`` during a walk,
    and ``payload_sizes`` records the byte count each b(8*n) was given."""

    def __init__(self, probe: tuple[str, int] | None = None) -> None:
        self.rows: list[TableRow] = []
        self.depth = 1
        self.indices: list[str] = []  # index variables of the enclosing loops, innermost last
        self.scalars: list[str] = []  # scalar elements in table order
        self.payload_rows: list[int] = []  # row of each b(8*n)
        self.payload_sizes: list[int] = []
        self.probe = probe

    def _visit(self, desc, obj, name, i, lo, hi, read, write, nbits):
        if i is None:
            label = name
            self.scalars.append(name)
            if self.probe is not None and self.probe[0] == name:
                setattr(obj, name, self.probe[1])
                return self.probe[1]
        else:
            label = f"{name}[ {i if isinstance(i, str) else (self.indices[-1] if self.indices else 'i')} ]"
        self.rows.append(TableRow(self.depth, label, desc, lo, hi))
        try:
            return _get(obj, name, i)
        except (AttributeError, IndexError, TypeError):
            return 0

    def _u_descriptor(self, nbits: int, width: str | None) -> str:
        return f"u({width or nbits})"

    def payload(self, obj, name, nbytes):
        self.payload_rows.append(len(self.rows))
        self.payload_sizes.append(nbytes)
        self.rows.append(TableRow(self.depth, name, "b(8*n)"))
        return b""

    def byte_align(self) -> None:
        self.rows.append(TableRow(self.depth, "byte_alignment( )", ""))

    def when(self, condition, text):
        self.rows.append(TableRow(self.depth, f"if( {text} ) {{"))
        self.depth += 1
        yield None
        self.depth -= 1
        self.rows.append(TableRow(self.depth, "}"))

    def loop(self, count, text, obj=None, arrays=(), index="i"):
        for a in arrays:
            if obj is not None and not getattr(obj, a, None):
                setattr(obj, a, [0])
        self.rows.append(TableRow(self.depth, f"for( {index} = 0; {index} < {text}; {index}++ ) {{"))
        self.depth += 1
        self.indices.append(index)
        yield 0
        self.indices.pop()
        self.depth -= 1
        self.rows.append(TableRow(self.depth, "}"))

    def struct(self, obj, name, i, cls, **context):
        self.rows.append(TableRow(self.depth, f"{cls.syntax_name}( )"))

    def markdown(self, title: str) -> str:
        lines = [f"| {title} | Descriptor |", "|---|---|"]
        for row in self.rows:
            pad = "&nbsp;" * (4 * row.depth)
            lines.append(f"| {pad}{row.text} | {row.descriptor} |")
        return "\n".join(lines)


class SyntaxStructure:
    """A structure of the bitstream. Subclasses are dataclasses whose fields are the syntax
    elements (with defaults) and which define ``syntax(v)``."""

    syntax_name: ClassVar[str] = ""
    clause: ClassVar[str] = ""

    def syntax(self, v: SyntaxVisitor) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def parse(cls, reader: BitReader, trace: list[TraceEntry] | None = None, **context):
        """Parse one structure; ``context`` gives values from earlier structures (e.g. counts)."""
        obj = cls(**context)
        obj.syntax(ReadVisitor(reader, cls.syntax_name, trace))
        return obj

    @classmethod
    def from_bytes(cls, data: bytes, trace: list[TraceEntry] | None = None, what: str | None = None,
                   **context):
        reader = BitReader(data, what or cls.syntax_name)
        obj = cls.parse(reader, trace, **context)
        if reader.bits_left >= 8:
            raise BitstreamError(f"{cls.syntax_name}: {reader.bits_left // 8} unexpected trailing bytes", condition="E21")
        return obj

    def write_to(self, writer: BitWriter, trace: list[TraceEntry] | None = None) -> None:
        self.syntax(WriteVisitor(writer, self.syntax_name, trace))

    def to_bytes(self) -> bytes:
        w = BitWriter()
        self.write_to(w)
        w.byte_align()
        return w.getvalue()

    def bit_size(self) -> int:
        v = SizeVisitor()
        self.syntax(v)
        return v.bits

    @classmethod
    def syntax_table(cls) -> str:
        v = TableVisitor()
        cls().syntax(v)
        for p, row in enumerate(v.payload_rows):
            v.rows[row].descriptor = f"b(8*{cls._payload_length(v, p)})"
        head = f"{cls.syntax_name}( ) {{"
        return v.markdown(head) + "\n| } | |"

    @classmethod
    def _payload_length(cls, table: TableVisitor, p: int) -> str:
        """What n is in the p-th b(8*n) of the structure: the scalar element whose value it is,
        found by giving each element in turn an unusual value; else the constant byte count."""
        sentinel = 7919
        found = []
        for name in dict.fromkeys(table.scalars):
            probe = TableVisitor(probe=(name, sentinel))
            try:
                cls().syntax(probe)
            except Exception:  # an element the structure cannot take that value for: not a length
                continue
            if len(probe.payload_sizes) > p and probe.payload_sizes[p] == sentinel:
                found.append(name)
        if len(found) > 1:
            raise RuntimeError(f"{cls.syntax_name}: the length of byte string {p} follows from {found}")
        return found[0] if found else str(table.payload_sizes[p])
