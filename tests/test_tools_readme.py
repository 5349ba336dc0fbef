"""tools/README.md lists every command in tools/, and every results file it names exists."""

import re
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[1] / "tools"


def test_every_tool_is_listed():
    text = (TOOLS / "README.md").read_text()
    listed = set(re.findall(r"`([a-z_0-9]+\.py)`", text))
    present = {p.name for p in TOOLS.glob("*.py")}
    assert present - listed == set(), f"tools not in tools/README.md: {sorted(present - listed)}"
    assert listed - present == set(), f"tools/README.md lists missing tools: {sorted(listed - present)}"


def test_no_scratch_scripts():
    assert not [p.name for p in TOOLS.glob("*.py") if p.name.startswith(("scratch", "tmp", "test_"))]


def test_listed_results_files_exist():
    text = (TOOLS / "README.md").read_text()
    for name in re.findall(r"`results/([a-z_0-9]+\.(?:md|png))`", text):
        assert (TOOLS / "results" / name).exists(), name
