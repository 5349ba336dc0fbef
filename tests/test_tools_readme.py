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


def _runners() -> dict[str, str]:
    """Each tool's "run by" cell (the last of its row in a table of tools/README.md)."""
    rows = {}
    for line in (TOOLS / "README.md").read_text().splitlines():
        m = re.match(r"\| `([a-z_0-9]+\.py)` \|", line)
        if m:
            rows[m.group(1)] = line.rstrip().rstrip("|").rsplit("|", 1)[1]
    return rows


def test_every_tool_is_run_by_a_test_a_target_or_another_tool():
    """Each tool's "run by" names a test file that names the tool, a Makefile target whose recipe
    runs it, or another tool that uses it: a tool that nothing runs is not kept."""
    root = TOOLS.parent
    makefile = (root / "Makefile").read_text()
    runners = _runners()
    assert set(runners) == {p.name for p in TOOLS.glob("*.py")}
    for tool, cell in runners.items():
        tests = re.findall(r"`(tests/test_[a-z_0-9]+\.py)`", cell)
        targets = re.findall(r"`make ([a-z-]+)`", cell)
        users = re.findall(r"used by `([a-z_0-9]+\.py)`", cell)
        assert tests or targets or users, f"{tool}: tools/README.md names nothing that runs it"
        for t in tests:
            assert tool.removesuffix(".py") in (root / t).read_text(), f"{tool}: {t} does not name it"
        for target in targets:
            recipe = re.search(rf"^{re.escape(target)}:.*\n((?:\t.*\n)+)", makefile, re.M)
            assert recipe, f"{tool}: no Makefile target {target}"
            assert tool in recipe.group(1), f"{tool}: the recipe of make {target} does not run it"
        for u in users:
            assert tool.removesuffix(".py") in (TOOLS / u).read_text(), f"{tool}: {u} does not use it"
