"""Layering: the decoder (and everything it uses) never imports the encoder."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NORMATIVE_DIRS = ("common", "decoder", "render", "conformance")


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_no_source_file_outside_encoder_imports_it():
    offenders = []
    for d in NORMATIVE_DIRS:
        for f in (ROOT / d).rglob("*.py"):
            if any(n.startswith("lghcc.encoder") for n in _imports(f)):
                offenders.append(str(f.relative_to(ROOT)))
    assert not offenders, f"these import lghcc.encoder: {offenders}"


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
