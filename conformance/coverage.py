"""Which syntax elements, and which classes of their values, a set of streams exercises.

Elements come from the syntax descriptions (the same ones that generate the spec's tables),
the container header and data-unit headers included; observed values come from the decoder's
bit trace, and from the container layer for its headers. Value classes of an element:

  enumerated elements (flags, modes, roles, activations, levels of the hierarchy, fixed
  values such as the magic number, and integers with at most 5 allowed values): each value;
  other integers: 'minimum' (its lowest allowed value), 'maximum' (its profile/level limit or,
  for u(n) without one, the largest value of its width; a context-dependent limit for
  rows_per_chunk_minus1: num_rows_minus1, one chunk per LoD), 'other' (strictly between); ue(v) elements
  without an upper limit (byte counts) have no 'maximum';
  se(v): 'minimum', 'maximum', and 'negative' / 'zero' / 'positive' strictly between;
  f(32) > 0: 'minimum' (2^-149, the smallest subnormal), 'maximum' (the largest finite
  binary32) and 'other'; other f(32): as se(v), with -/+ the largest finite binary32;
  byte strings: 'empty', 'non-empty' (fixed-length ones: 'non-empty').
Data-unit types are classes of data_unit_header.unit_type: each known type and 'ancillary'.

Classes that no stream a conforming decoder accepts can exercise are in ``IMPOSSIBLE`` with the
reason: reported as such and left out of the denominator (a stream that exercises one would
contradict the reason; the report says so). Classes that are possible but not exercised on
purpose are in ``NOT_EXERCISED`` with the reason: they stay in the denominator, so the
percentage is what the suite really covers.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

from ..common.container import ANCILLARY_UNIT_TYPE_MIN, MAGIC, Profile, UnitType, read_container
from ..common.spec_tables import all_structures
from ..common.syntax import TableVisitor

F32_MAX = struct.unpack("<f", struct.pack("<I", 0x7F7FFFFF))[0]
F32_MIN_POSITIVE = struct.unpack("<f", struct.pack("<I", 0x00000001))[0]

# elements whose values are an enumeration (their syntax gives a wider or no range)
ENUMERATIONS = {
    "container_header.magic": [MAGIC],
    "container_header.version_major": [1],
    "container_header.profile_idc": [int(p) for p in Profile],
    "container_header.reserved_zero_8bits": [0],
    "render_mlp_header.mlp_role": [0, 1, 2, 3],
    "render_mlp_header.activation": [0, 1, 2, 3],
}
# integer elements with a value of their own beside minimum / other / maximum
SPECIAL_VALUES: dict[str, list[int]] = {}  # (version_minor: 0 is its minimum; this document's, 1, is other)
# upper limits that depend on earlier elements: element -> how the limit is found (see _contextual_max)
CONTEXT_DEPENDENT_MAX = {"attribute_unit_header.rows_per_chunk_minus1": "NumRows - 1 (a single chunk)",
                         "attribute_unit_header.num_channel_predictions": "M (M - 1) / 2 (every pair)",
                         "attribute_unit_header.pred_target_channel": "M - 1 (the last channel)",
                         "attribute_unit_header.pred_source_channel": "M - 2",
                         "sh_transform_unit.sh_transform_coeff": "2^B - 1 (B = sh_transform_bits_minus1 + 1)"}
ENUM_MAX_VALUES = 5  # integers with at most this many allowed values are enumerated
FIXED_LENGTH = {"decoded_scene_hash_unit.scene_hash"}  # byte strings that cannot be empty
UNIT_TYPE = "data_unit_header.unit_type"

# (element, value class) -> why no decodable stream can exercise it (checked against the code,
# see tests/test_spec_and_conformance.py for the executable parts of each argument).
IMPOSSIBLE: dict[tuple[str, str], str] = {
    ("int_array_header.array_ndim", 0):
        "every context-model array has a fixed number of dimensions (clause 7.3.8; Annex H, clauses H.5.1 and "
        "H.6.1): parent_base and the biases 1, the weights 2, the GG-Conv table 4; a model rejects any other "
        "shape. The scalars are syntax elements of context_model_unit(), not arrays",
    ("int_array_header.array_ndim", 3):
        "as array_ndim 0: no context-model array has 3 dimensions",
    ("context_model_unit.coded_size", "minimum"):
        "every context model has the array parent_base (values 0 or 1, at least one value); an empty chunk "
        "decodes every symbol as bin 0 of its table (spec 10.6.4: point = 0), i.e. the value -L_level <= -4 "
        "(every half-width L_i >= 4), outside an unsigned width or, declared signed, outside 0 .. 1, so both "
        "models reject the unit",
    ("context_model_unit.coded_data", "empty"):
        "coded_data is coded_size bytes; see context_model_unit.coded_size: minimum",
    ("tile_index_unit.tile_data_size", "minimum"):
        "a tile is at least a geometry, an attribute and a decoded_scene_hash unit, each with its 5-byte header "
        "and 4-byte CRC (clause 6.3): never 0 bytes",
}

# (element, value class) -> why the suite does not exercise it although a stream could
NOT_EXERCISED: dict[tuple[str, str], str] = {
    ("scene_parameter_set.num_anchors_minus1", "maximum"):
        "2^24 anchors: a stream of tens of MB that takes minutes to encode and decode",
    ("gaussian_parameter_set.num_gaussians_minus1", "maximum"):
        "2^24 Gaussians: a stream of tens of MB that takes minutes to encode and decode",
    ("attribute_unit_header.num_channel_predictions", "maximum"):
        "every pair of channels predicted (1,596 entries at SH degree 3): the encoder predicts within groups "
        "of related channels; entries are plain syntax, c036 exercises many of them and both weight limits",
    ("data_unit_header.unit_payload_size", "maximum"):
        "a payload of 2^32 - 1 bytes (4 GiB)",
    ("int_array_header.array_dim_minus1", "maximum"):
        "an array of 2^24 values (also the limit on all context-model values together): a stream of many MB",
    ("tile_index_unit.tile_data_size", "maximum"):
        "a tile of 2^32 - 2 bytes (4 GiB)",
    ("attribute_unit_header.num_rows_minus1", "maximum"):
        "a unit of 2^24 rows: every one of 2^24 points in one tile (as num_anchors_minus1: maximum)",
}

# element -> the conformance stream still to be written for it. Such an element is left out of the
# report's elements and classes (listed apart, as pending) until a stream exercises it; then the
# entry is stale and must go (CoverageReport.stale).
PENDING: dict[str, str] = {}


@dataclass(frozen=True)
class ElementInfo:
    """How one element's values are classified."""
    name: str
    descriptor: str
    classes: tuple
    lo: int | float | None = None
    hi: int | float | None = None  # None: no maximum class (or contextual)
    kind: str = "integer"  # enum, integer, signed, float, positive_float, bytes


class _Probe(TableVisitor):
    """A TableVisitor that also records which f(32) elements must be > 0."""

    def __init__(self) -> None:
        super().__init__()
        self.positive: dict[str, bool] = {}

    def f32(self, obj, name, i=None, *, positive=False):
        self.positive[name] = positive
        return super().f32(obj, name, i, positive=positive)


def _element_info(struct_name: str, row, positive: dict[str, bool]) -> ElementInfo:
    base = row.text.split("[")[0].strip()
    name = f"{struct_name}.{base}"
    d = row.descriptor
    lo, hi = row.lo, row.hi
    if name in ENUMERATIONS:
        return ElementInfo(name, d, tuple(ENUMERATIONS[name]), kind="enum")
    if name == UNIT_TYPE:
        return ElementInfo(name, d, tuple(t.name.lower() for t in UnitType) + ("ancillary",), kind="enum")
    if d == "f(32)":
        if positive.get(base):
            return ElementInfo(name, d, ("minimum", "other", "maximum"), F32_MIN_POSITIVE, F32_MAX, "positive_float")
        return ElementInfo(name, d, ("minimum", "negative", "zero", "positive", "maximum"), -F32_MAX, F32_MAX,
                           "float")
    if d.startswith("b("):
        return ElementInfo(name, d, ("non-empty",) if name in FIXED_LENGTH else ("empty", "non-empty"), kind="bytes")
    if name in CONTEXT_DEPENDENT_MAX:
        return ElementInfo(name, d, ("minimum", "other", "maximum"), lo or 0, None, "integer")
    if d.startswith("u(") and hi is None:
        hi = (1 << int(d[2:-1])) - 1
    lo = 0 if lo is None and d != "se(v)" else lo
    if lo is not None and hi is not None and hi - lo < ENUM_MAX_VALUES:
        return ElementInfo(name, d, tuple(range(lo, hi + 1)), lo, hi, "enum")
    if d == "se(v)":
        cls = (("minimum",) if lo is not None else ()) + ("negative", "zero", "positive") + \
              (("maximum",) if hi is not None else ())
        return ElementInfo(name, d, cls, lo, hi, "signed")
    special = tuple(SPECIAL_VALUES.get(name, ()))
    return ElementInfo(name, d, ("minimum",) + special + ("other",) + (("maximum",) if hi is not None else ()),
                       lo, hi, "integer")


def element_infos() -> dict[str, ElementInfo]:
    out: dict[str, ElementInfo] = {}
    for cls in all_structures():
        v = _Probe()
        cls().syntax(v)
        for row in v.rows:
            if row.descriptor:
                info = _element_info(cls.syntax_name, row, v.positive)
                out[info.name] = info
    return out


def element_minimums() -> dict[str, int]:
    """The smallest allowed value of each integer element (its ``lo``; 0 when unbounded)."""
    return {k: (i.lo or 0) for k, i in element_infos().items() if i.kind in ("integer", "signed", "enum")}


def element_classes() -> dict[str, list]:
    return {k: list(i.classes) for k, i in element_infos().items()}


def value_class(info: ElementInfo, value, contextual_max: int | None = None):
    """The class of one observed value of an element."""
    if info.kind == "bytes":
        return "empty" if not value else "non-empty"
    if info.kind == "enum":
        return value
    if info.kind in ("float", "positive_float"):
        x = float(value)
        if x == info.lo:
            return "minimum"
        if x == info.hi:
            return "maximum"
        if info.kind == "positive_float":
            return "other"
        return "negative" if x < 0 else "zero" if x == 0 else "positive"
    v = int(value)
    hi = contextual_max if info.name in CONTEXT_DEPENDENT_MAX else info.hi
    if info.lo is not None and v == info.lo:
        return "minimum"
    if hi is not None and v == hi:
        return "maximum"
    if v in SPECIAL_VALUES.get(info.name, ()):
        return v
    if info.kind == "signed":
        return "negative" if v < 0 else "zero" if v == 0 else "positive"
    return "other"


@dataclass
class CoverageReport:
    classes: dict[str, list]
    seen: dict[str, set] = field(default_factory=dict)
    impossible: dict[tuple[str, object], str] = field(default_factory=lambda: dict(IMPOSSIBLE))
    not_exercised: dict[tuple[str, object], str] = field(default_factory=lambda: dict(NOT_EXERCISED))
    rejections: list[tuple[str, str, str]] = field(default_factory=list)  # (id, error class, message fragment)
    pending: dict[str, str] = field(default_factory=dict)  # PENDING entries of elements that exist
    pending_seen: dict[str, set] = field(default_factory=dict)  # values the streams gave them nevertheless
    pending_unknown: list[str] = field(default_factory=list)  # PENDING entries naming no element

    def _possible(self, name: str) -> list:
        return [c for c in self.classes[name] if (name, c) not in self.impossible]

    @property
    def elements_covered(self) -> int:
        return sum(1 for k in self.classes if self.seen.get(k))

    @property
    def classes_total(self) -> int:
        """Value classes that some stream can exercise (the impossible ones left out)."""
        return sum(len(self._possible(k)) for k in self.classes)

    @property
    def classes_covered(self) -> int:
        return sum(len(set(self._possible(k)) & self.seen.get(k, set())) for k in self.classes)

    def missing_classes(self) -> list[tuple[str, object]]:
        return [(k, c) for k in self.classes for c in self._possible(k) if c not in self.seen.get(k, set())]

    def unexplained(self) -> list[tuple[str, object]]:
        """Classes neither exercised nor listed in NOT_EXERCISED with a reason."""
        return [m for m in self.missing_classes() if m not in self.not_exercised]

    def missing(self) -> list[str]:
        out: dict[str, list] = {}
        for k, c in self.missing_classes():
            out.setdefault(k, []).append(c)
        return [f"{k}: {', '.join(map(str, cs))}" for k, cs in out.items()]

    def contradictions(self) -> list[str]:
        """Classes marked impossible or not exercised that a stream exercises nevertheless."""
        return [f"{k}: {c}" for (k, c) in list(self.impossible) + list(self.not_exercised)
                if c in self.seen.get(k, set())]

    def stale(self) -> list[str]:
        """IMPOSSIBLE / NOT_EXERCISED entries naming an element or class that does not exist, and
        PENDING entries naming no element or one a stream now exercises."""
        return ([f"{k}: {c}" for (k, c) in list(self.impossible) + list(self.not_exercised)
                 if k not in self.classes or c not in self.classes[k]]
                + [f"{k}: pending, but no such element" for k in self.pending_unknown]
                + [f"{k}: pending, but exercised (values {sorted(v, key=str)}): remove it from PENDING"
                   for k, v in self.pending_seen.items()])

    def text(self) -> str:
        n = len(self.classes)
        lines = [f"syntax elements exercised: {self.elements_covered}/{n} "
                 f"({100 * self.elements_covered / n:.1f}%)",
                 f"value classes exercised:   {self.classes_covered}/{self.classes_total} "
                 f"({100 * self.classes_covered / self.classes_total:.1f}%), "
                 f"{len(self.impossible)} more impossible by construction"]
        unexplained = self.unexplained()
        if unexplained:
            lines.append("not exercised:")
            lines += [f"  {k}: {c}" for k, c in unexplained]
        gaps = [(k, c, why) for (k, c), why in self.not_exercised.items() if c not in self.seen.get(k, set())]
        if gaps:
            lines.append("not exercised, on purpose (counted as missing):")
            lines += [f"  {k}: {c}: {why}" for k, c, why in gaps]
        if self.pending:
            lines.append("pending: elements whose streams are still to be written (not counted):")
            lines += [f"  {k}: {why}" for k, why in self.pending.items()]
        if self.impossible:
            lines.append("impossible by construction (not counted):")
            lines += [f"  {k}: {c}: {why}" for (k, c), why in self.impossible.items()]
        if self.rejections:
            lines.append(f"rejections exercised by {len(self.rejections)} error streams:")
            lines += [f"  {i}: {kind}: '{msg}'" for i, kind, msg in self.rejections]
        bad = self.contradictions()
        if bad:
            lines.append("EXERCISED ALTHOUGH MARKED IMPOSSIBLE OR NOT EXERCISED:")
            lines += [f"  {b}" for b in bad]
        return "\n".join(lines)


def _container_values(data: bytes):
    """(element, value) of the container header and every data-unit header of a stream."""
    c = read_container(data)
    for name in ("magic", "version_major", "version_minor", "profile_idc", "reserved_zero_8bits"):
        yield f"container_header.{name}", getattr(c.header, name)
    for u in c.units:
        t = "ancillary" if u.unit_type >= ANCILLARY_UNIT_TYPE_MIN else UnitType(u.unit_type).name.lower()
        yield UNIT_TYPE, t
        yield "data_unit_header.unit_payload_size", len(u.payload)


def _trace_values(trace):
    """(element, value, contextual maximum) for each trace entry; the maximum of
    rows_per_chunk_minus1 is NumRows - 1 = num_rows_minus1 (one chunk without LoDs; with neighbour
    prediction, one chunk per LoD)."""
    entries = [(re.sub(r"\[\d+\]", "", e.name), e.value) for e in trace]
    m = None  # channels of a Gaussian scene (3 (d + 1)^2 + 8), the limit of the prediction elements
    num_rows_minus1 = None
    coeff_max = None  # 2^B - 1, the largest entry of an sh_transform unit
    for name, value in entries:
        ctx = None
        if name == "sh_transform_unit.sh_transform_bits_minus1":
            coeff_max = (1 << (int(value) + 1)) - 1
        elif name == "sh_transform_unit.sh_transform_coeff":
            ctx = coeff_max
        if name == "gaussian_parameter_set.sh_degree":
            m = 3 * (int(value) + 1) ** 2 + 8
        elif m is not None and name == "attribute_unit_header.num_channel_predictions":
            ctx = m * (m - 1) // 2
        elif m is not None and name == "attribute_unit_header.pred_target_channel":
            ctx = m - 1
        elif m is not None and name == "attribute_unit_header.pred_source_channel":
            ctx = m - 2
        if name == "attribute_unit_header.num_rows_minus1":
            num_rows_minus1 = int(value)
        if name == "attribute_unit_header.rows_per_chunk_minus1":
            ctx = num_rows_minus1  # parsed just before it (version 1): its maximum, S = NumRows
        yield name, value, ctx


def coverage_report(streams: list[Path], error_cases: list | None = None) -> CoverageReport:
    """Coverage of the decodable ``streams``; ``error_cases`` (runner Cases) are listed with the
    rejection each one exercises."""
    from ..decoder.decode import decode_stream

    infos = element_infos()
    report = CoverageReport({k: list(i.classes) for k, i in infos.items() if k not in PENDING},
                            pending={k: v for k, v in PENDING.items() if k in infos},
                            pending_unknown=[k for k in PENDING if k not in infos])
    for path in streams:
        data = Path(path).read_bytes()
        for name, value in _container_values(data):
            report.seen.setdefault(name, set()).add(value_class(infos[name], value))
        for name, value, ctx in _trace_values(decode_stream(data, trace=True).trace):
            info = infos.get(name)
            if name in report.pending:
                report.pending_seen.setdefault(name, set()).add(value_class(info, value, ctx))
            elif info is not None:
                report.seen.setdefault(name, set()).add(value_class(info, value, ctx))
    for case in error_cases or []:
        report.rejections.append((case.id, case.meta.get("expect_error", "?"), case.meta.get("expect_message", "?")))
    return report
