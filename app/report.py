"""Size breakdown of a stream, in the categories of the paper's Table 2: every byte of the
file is counted in exactly one category, so the categories add up to the file size."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..common.container import CONTAINER_HEADER_BYTES, Container, UnitType

CATEGORY_OF_UNIT = {
    UnitType.SCENE_PARAMETER_SET: "header",
    UnitType.GAUSSIAN_PARAMETER_SET: "header",
    UnitType.DECODED_SCENE_HASH: "header",
    UnitType.TILE_INDEX: "header",
    UnitType.GEOMETRY: "geometry",
    UnitType.ATTRIBUTE: "attributes",
    UnitType.RENDER_MODEL: "model",
    UnitType.CONTEXT_MODEL: "model",
}
CATEGORIES = ("header", "geometry", "attributes", "model", "ancillary")


@dataclass
class SizeBreakdown:
    num_points: int  # the points of the scene: anchors, or Gaussians (``point_name``)
    bytes_by_category: dict[str, int] = field(default_factory=dict)
    point_name: str = "anchor"

    @property
    def total_bytes(self) -> int:
        return sum(self.bytes_by_category.values())

    def table(self) -> str:
        per = f"bits/{self.point_name}"
        rows = [f"{'part':<12}{'bytes':>12}{per:>15}{'share':>9}"]
        total = max(self.total_bytes, 1)
        for cat in CATEGORIES:
            b = self.bytes_by_category.get(cat, 0)
            if cat == "ancillary" and not b:
                continue
            rows.append(f"{cat:<12}{b:>12,}{8 * b / self.num_points:>15.2f}{100 * b / total:>8.1f}%")
        rows.append(f"{'total':<12}{self.total_bytes:>12,}{8 * self.total_bytes / self.num_points:>15.2f}"
                    f"{100.0:>8.1f}%")
        return "\n".join(rows)


def breakdown_of(container: Container, num_points: int, point_name: str = "anchor") -> SizeBreakdown:
    """Unit framing (type, size, CRC) is charged to the unit it frames; the container header to 'header'."""
    by = {c: 0 for c in CATEGORIES}
    by["header"] += CONTAINER_HEADER_BYTES
    for u in container.units:
        cat = "ancillary" if u.is_ancillary else CATEGORY_OF_UNIT.get(u.unit_type, "header")  # an unknown type: "header"
        by[cat] += u.size
    return SizeBreakdown(num_points, by, point_name)
