"""Which syntax elements, and which classes of their values, a set of streams exercises.

Elements come from the syntax descriptions (the same ones that generate the spec's
tables); observed values come from the decoder's bit trace. Value classes:
  flags (u(1)) and enumerated elements: each allowed value;
  se(v): negative, zero, positive;  other integers: at their minimum, above it;
  f(32) and byte strings: present (byte strings: empty / non-empty).
Data-unit types are counted too: each known type and 'ancillary'.

Some classes cannot occur in any stream a conforming decoder accepts; ``IMPOSSIBLE`` lists
them with the reason. They are reported as such and left out of the denominator; a stream
that exercised one would contradict the reason, and the report says so.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from lghcc.common.container import ANCILLARY_UNIT_TYPE_MIN, UnitType, read_container
from lghcc.common.spec_tables import all_structures
from lghcc.common.syntax import TableVisitor

ENUMERATIONS = {
    "render_mlp_header.mlp_role": [0, 1, 2, 3],
    "render_mlp_header.activation": [0, 1, 2, 3],
}
NOT_IN_TRACE = {"container_header", "data_unit_header"}  # parsed by the container layer; see unit types
FIXED_LENGTH = {"decoded_scene_hash_unit.scene_hash"}  # byte strings that cannot be empty

# (element, value class) -> why no decodable stream can exercise it (checked against the code,
# see tests/test_spec_and_conformance.py for the executable parts of each argument).
IMPOSSIBLE: dict[tuple[str, str], str] = {
    ("scene_parameter_set.coarse_voxel_scale_minus1", "minimum"):
        "coarse voxels of 1 voxel hold one anchor each, since decoded anchor coordinates are distinct "
        "(octree leaves are distinct and decode_geometry rejects a direct-coded node holding one point "
        "twice), so level 2 is empty and the decoder rejects hierarchy_enabled_flag = 1 with an empty "
        "level 2 (stream e006_coarse_voxel_scale_one)",
    ("context_model_unit.coded_size", "minimum"):
        "every context model has the scalar num_features (>= 1); an empty chunk decodes every symbol as "
        "bin 0 of its table (spec 10.6.4: point = 0), i.e. the value -L_level <= -4 (every half-width "
        "L_i >= 4), so num_features < 1 and both models reject the unit",
    ("context_model_unit.coded_data", "empty"):
        "coded_data is coded_size bytes; see context_model_unit.coded_size: minimum",
}


def element_minimums() -> dict[str, int]:
    """The smallest allowed value of each integer element (its ``lo``; 0 when unbounded)."""
    out = {}
    for cls in all_structures():
        v = TableVisitor()
        cls().syntax(v)
        for row in v.rows:
            if row.descriptor:
                out[f"{cls.syntax_name}.{row.text.split('[')[0].strip()}"] = row.lo or 0
    return out


def element_classes() -> dict[str, list]:
    classes: dict[str, list] = {}
    for cls in all_structures():
        if cls.syntax_name in NOT_IN_TRACE:
            continue
        v = TableVisitor()
        cls().syntax(v)
        for row in v.rows:
            if not row.descriptor:
                continue
            name = f"{cls.syntax_name}.{row.text.split('[')[0].strip()}"
            if name in ENUMERATIONS:
                classes[name] = list(ENUMERATIONS[name])
            elif row.lo is not None and row.hi is not None and row.hi - row.lo <= 1:
                classes[name] = list(range(row.lo, row.hi + 1))
            elif row.descriptor == "u(1)":
                classes[name] = [0, 1]
            elif row.descriptor == "se(v)":
                classes[name] = ["negative", "zero", "positive"]
            elif row.descriptor == "f(32)":
                classes[name] = ["present"]
            elif row.descriptor.startswith("b("):
                classes[name] = ["non-empty"] if name in FIXED_LENGTH else ["empty", "non-empty"]
            else:
                classes[name] = ["minimum", "above minimum"]
    classes["data_unit.unit_type"] = [t.name.lower() for t in UnitType] + ["ancillary"]
    return classes


def _value_class(name: str, value, kinds: list, minimum: int = 0):
    if isinstance(value, (bytes, bytearray)):
        return "empty" if not value else "non-empty"
    if kinds == ["present"]:
        return "present"
    if kinds == ["negative", "zero", "positive"]:
        return "negative" if value < 0 else "zero" if value == 0 else "positive"
    if kinds == ["minimum", "above minimum"]:
        return "minimum" if value == minimum else "above minimum"
    return value


@dataclass
class CoverageReport:
    classes: dict[str, list]
    seen: dict[str, set] = field(default_factory=dict)
    impossible: dict[tuple[str, str], str] = field(default_factory=lambda: dict(IMPOSSIBLE))

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

    def missing(self) -> list[str]:
        out = []
        for k in self.classes:
            miss = [c for c in self._possible(k) if c not in self.seen.get(k, set())]
            if miss:
                out.append(f"{k}: {', '.join(map(str, miss))}")
        return out

    def contradictions(self) -> list[str]:
        """Classes marked impossible that a stream exercises nevertheless (the reason is wrong)."""
        return [f"{k}: {c}" for (k, c) in self.impossible if c in self.seen.get(k, set())]

    def text(self) -> str:
        n = len(self.classes)
        lines = [f"syntax elements exercised: {self.elements_covered}/{n} "
                 f"({100 * self.elements_covered / n:.1f}%)",
                 f"value classes exercised:   {self.classes_covered}/{self.classes_total} "
                 f"({100 * self.classes_covered / self.classes_total:.1f}%), "
                 f"{len(self.impossible)} more impossible by construction"]
        miss = self.missing()
        if miss:
            lines.append("not exercised:")
            lines += [f"  {m}" for m in miss]
        if self.impossible:
            lines.append("impossible by construction (not counted):")
            lines += [f"  {k}: {c}: {why}" for (k, c), why in self.impossible.items()]
        bad = self.contradictions()
        if bad:
            lines.append("EXERCISED ALTHOUGH MARKED IMPOSSIBLE:")
            lines += [f"  {b}" for b in bad]
        return "\n".join(lines)


def coverage_report(streams: list[Path]) -> CoverageReport:
    from lghcc.decoder.decode import decode_stream

    report = CoverageReport(element_classes())
    minimums = element_minimums()
    for path in streams:
        data = Path(path).read_bytes()
        for u in read_container(data).units:
            t = "ancillary" if u.unit_type >= ANCILLARY_UNIT_TYPE_MIN else UnitType(u.unit_type).name.lower()
            report.seen.setdefault("data_unit.unit_type", set()).add(t)
        for e in decode_stream(data, trace=True).trace:
            name = re.sub(r"\[\d+\]", "", e.name)
            kinds = report.classes.get(name)
            if kinds is not None:
                report.seen.setdefault(name, set()).add(_value_class(name, e.value, kinds, minimums.get(name, 0)))
    return report
