"""Helpers shared by the benchmark tools (tools/bench_*.py): the machine's load and the
markdown results files."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path


def command_line(tool: str, argv: list[str] | None = None) -> str:
    """The command that reproduces a results table, quoted so that it can be pasted into a shell
    (labels such as \"NAAP in training (keep 0.7)=...\" carry spaces and parentheses)."""
    return shlex.join(["python", f"tools/{tool}", *(sys.argv[1:] if argv is None else argv)])


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
