"""Architecture: the layering (the decoder never imports the encoder; common/ is normative and
imports only itself), a layout in which folder paths are import paths (relative imports only inside
the package, resolvable by a static tool from a plain checkout), and the size of every function."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The package's folders (the repository root is the package lghcc: its __init__.py and api.py are here)
PACKAGE_DIRS = ("app", "batch", "common", "conformance", "decoder", "encoder", "formats", "render", "viewer")
NOT_ENCODER = ("app", "common", "conformance", "decoder", "formats", "render")
# A function in any package folder reads as one step: at most this many lines
# (docstring included) and cyclomatic complexity 15 (ruff's C901, configured in pyproject.toml)
MAX_FUNCTION_LINES = 60


def _package_files() -> list[Path]:
    files = [ROOT / "__init__.py", ROOT / "api.py"]
    for d in PACKAGE_DIRS:
        files += sorted(p for p in (ROOT / d).rglob("*.py") if "node_modules" not in p.parts)
    return files


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(["lghcc"] + (parts[:-1] if parts[-1] == "__init__" else parts))


def _imports(path: Path, root: Path = ROOT) -> set[str]:
    """Absolute names of the modules a file imports (relative imports resolved; ``root``: the package's)."""
    module = _module_name(path, root)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            names.add(base)
            names |= {f"{base}.{a.name}" for a in node.names}
    return names


def test_imports_inside_the_package_are_relative():
    """An absolute `lghcc.` import resolves only through an installed package; a relative one
    resolves from the folder layout, for any reader or static tool."""
    offenders = []
    for f in _package_files():
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "lghcc" for a in node.names):
                offenders.append(f"{f.relative_to(ROOT)}:{node.lineno}")
            elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == "lghcc":
                offenders.append(f"{f.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, f"absolute lghcc imports inside the package: {offenders}"


# The conformance suite's generator makes each base stream with the encoder (the edits of
# stream_edits.py re-code with its neighbour coding); nothing else in conformance/ imports them
CONFORMANCE_GENERATOR = {"conformance/generate.py", "conformance/stream_edits.py"}


def test_no_source_file_outside_encoder_imports_it():
    offenders = []
    for d in NOT_ENCODER:
        for f in (ROOT / d).rglob("*.py"):
            if str(f.relative_to(ROOT)) in CONFORMANCE_GENERATOR:
                continue
            if any(n.startswith("lghcc.encoder") for n in _imports(f)):
                offenders.append(str(f.relative_to(ROOT)))
    assert not offenders, f"these import lghcc.encoder: {offenders}"


def test_only_the_generator_imports_the_generator():
    """The runner, the manifest check and the rest of conformance/ (what a decoder's implementer
    runs) never load the encoder through the generator."""
    generator = {_module_name(ROOT / f) for f in CONFORMANCE_GENERATOR}
    offenders = sorted(name for name, deps in _import_graph().items()
                       if name not in generator and deps & generator)
    assert not offenders, f"these import the conformance generator: {offenders}"


def test_common_is_normative_only():
    """common/ (what the spec describes) imports nothing of the package outside itself."""
    offenders = {str(f.relative_to(ROOT)): sorted(n for n in _imports(f) if n.startswith("lghcc.")
                                                  and not n.startswith("lghcc.common"))
                 for f in (ROOT / "common").rglob("*.py")}
    assert not {k: v for k, v in offenders.items() if v}


# The normative decoder (docs/architecture.md): clause 13's decoding process, below its driver
# decoder/decode.py. Of the package it imports common/ alone; beside it the standard library, numpy and
# torch (common/'s context models), but nothing that runs processes or threads: the driver does that.
DECODER_CORE = ROOT / "decoder" / "core.py"
CORE_THIRD_PARTY = {"numpy", "torch"}
CORE_FORBIDDEN_STDLIB = {"multiprocessing", "concurrent", "threading", "subprocess", "time"}


def _core_offenders(path: Path, root: Path = ROOT) -> list[str]:
    """What decoder/core.py (``path``, in the package at ``root``) may not import or do."""
    names = _imports(path, root)
    tops = {n.split(".")[0] for n in names if n}
    package = sorted(n for n in names if n.startswith("lghcc.") and not n.startswith("lghcc.common"))
    other = sorted(t for t in tops - {"lghcc"} - CORE_THIRD_PARTY
                   if t not in sys.stdlib_module_names or t in CORE_FORBIDDEN_STDLIB)
    source = path.read_text()
    state = [f"global statement at line {n.lineno}" for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Global)]
    return package + other + state


def test_the_decoder_core_imports_only_common():
    """decoder/core.py imports of the package only common/ (no app/, no driver module), of the rest
    only the standard library (no processes, threads or clocks), numpy and torch, and sets no
    module-global state."""
    assert DECODER_CORE.is_file()
    assert _core_offenders(DECODER_CORE) == []


def test_the_core_import_check_finds_offenders(tmp_path):
    core = tmp_path / "decoder" / "core.py"
    core.parent.mkdir()
    core.write_text("import multiprocessing\nimport scipy\nfrom ..app.progress import progress_bar\n"
                    "from ..common.units import LEVEL_1\n_STATE = None\n\n\ndef f():\n    global _STATE\n")
    found = _core_offenders(core, tmp_path)
    assert found == ["lghcc.app.progress", "lghcc.app.progress.progress_bar", "multiprocessing", "scipy",
                     "global statement at line 9"], found


def test_every_module_imports():
    """With the static check (which resolves modules), this shows that every imported name exists."""
    code = ("import importlib, pkgutil, lghcc\n"
            "for m in pkgutil.walk_packages(lghcc.__path__, 'lghcc.'):\n"
            "    importlib.import_module(m.name)\n"
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/")
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


@pytest.mark.integration
def test_static_import_check():
    """pyright (pinned in tools/node, installed by `make node-tools`) resolves every import of the
    package from the checkout: [tool.pyright] in pyproject.toml."""
    pyright = ROOT / "tools" / "node" / "node_modules" / ".bin" / "pyright"
    if not pyright.exists():
        pytest.skip("pyright is not installed (make node-tools installs it into tools/node)")
    out = subprocess.run([str(pyright), "--pythonpath", sys.executable], capture_output=True, text=True, cwd=ROOT,
                         timeout=600)
    assert out.returncode == 0, out.stdout[-4000:]


def test_complexity():
    """ruff's C901 (max-complexity 15, pyproject.toml) over every package folder."""
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    if ruff is None:
        pytest.skip("ruff is not installed (it is in the [test] extra)")
    out = subprocess.run([ruff, "check", "--select", "C901", "--output-format", "concise",
                          *PACKAGE_DIRS, "__init__.py", "api.py"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout


def test_function_length():
    long = []
    for f in _package_files():
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{f.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports, at any depth of the file (an import inside a
    function is still a dependency, only a later one)."""
    modules = {_module_name(f): f for f in _package_files()}
    graph = {}
    for name, f in modules.items():
        deps = set()
        for n in _imports(f):
            while n and n not in modules:  # `from .x import name`: the module x
                n = n.rpartition(".")[0]
            if n and n not in (name, "lghcc"):
                deps.add(n)
        graph[name] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(sorted(comp))
    return found


def test_cycle_finder_finds_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e2"}, "e2": {"e"}, "f": set()}
    assert sorted(_cycles(graph)) == [["a", "b", "c"], ["e", "e2"]]


def test_no_import_cycle_between_modules():
    """Modules import one another in one direction only (a package's __init__ aside), so that each
    can be read, tested and moved on its own."""
    cycles = _cycles(_import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


# encoder/'s top level: the library API and the console scripts (lghcc-enc, lghcc-train), over its rooms
ENCODER_TOP = {"__init__.py", "api.py", "cli.py", "train.py"}
# Each room uses only the rooms below it (docs/architecture.md, "encoder/ by route")
ENCODER_ROOMS = {"context": set(), "stream": {"context"}, "gaussians": {"stream", "context"},
                 "anchors": {"stream", "context"}, "training": {"anchors", "stream", "context"}}
# The imports that still go up, each for a reason: stream/encode.py's encode_scene is the anchor
# route's stream and prunes with NAAP (in prune_scene); EncodeStats holds a TranscodeStats (a type only)
ENCODER_UPWARD = {("lghcc.encoder.stream.encode", "lghcc.encoder.anchors.naap"),
                  ("lghcc.encoder.stream.stats", "lghcc.encoder.anchors.transcode")}


def test_encoder_top_level_holds_the_api_and_the_rooms():
    here = {p.name for p in (ROOT / "encoder").iterdir() if p.suffix == ".py" or p.is_dir()} - {"__pycache__"}
    assert here == ENCODER_TOP | set(ENCODER_ROOMS) | {"presets"}


def _encoder_room(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if parts[:2] == ["lghcc", "encoder"] and len(parts) > 2 else None


def test_encoder_rooms_import_only_the_rooms_below():
    up = {(name, d) for name, deps in _import_graph().items() if _encoder_room(name) in ENCODER_ROOMS
          for d in deps if _encoder_room(d) not in (None, _encoder_room(name), *ENCODER_ROOMS[_encoder_room(name)])}
    assert up == ENCODER_UPWARD


def test_importing_the_decoder_loads_no_encoder_module():
    code = ("import sys, lghcc.decoder.cli, lghcc.decoder.decode; "
            "print(sorted(m for m in sys.modules if m.startswith('lghcc.encoder')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_no_bare_common_package_is_importable():
    out = subprocess.run([sys.executable, "-c", "import common"], capture_output=True, text=True, cwd="/")
    assert out.returncode != 0


def test_a_stream_without_context_model_decodes_without_torch():
    """Only what a stream calls for: torch (the context models' inference) is not even imported
    for a stream without a context model; it is for one with GG-Conv."""
    code = ("import sys; from lghcc.decoder.decode import decode_stream; "
            "d = decode_stream(open(sys.argv[1], 'rb').read()); print('torch' in sys.modules)")
    streams = ROOT / "conformance" / "streams"
    for stream, uses_torch in (("c002_procedural_medium", "False"), ("c030_ggconv_level1_neighbours", "True")):
        out = subprocess.run([sys.executable, "-c", code, str(streams / stream / "stream.lghcc")],
                             capture_output=True, text=True, check=True).stdout.strip()
        assert out == uses_torch, (stream, out)


def test_root_init_imports_as_a_lone_module():
    """pytest imports the __init__.py of the folder it collects from (the repository root) as a lone
    module when the checkout's folder name is not an identifier (a clone in lghcc-main/): that must
    not fail (it did, with 'attempted relative import with no known parent package')."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("__init__", ROOT / "__init__.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.__version__
