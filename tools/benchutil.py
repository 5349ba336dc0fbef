"""Helpers shared by the benchmark tools (tools/bench_*.py): the machine's load and the
markdown results files."""

from __future__ import annotations

from pathlib import Path


def load_average() -> str:
    """The 1, 5 and 15-minute load averages (timings on a shared machine need them beside them)."""
    try:
        return " ".join(open("/proc/loadavg").read().split()[:3])
    except OSError:
        return "n/a"


def write_lines(path: Path, lines: list[str]) -> None:
    """Write a results table (markdown lines), creating its folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
