"""The JavaScript decoder (js/lghcc-decoder) with the checks of some conditions of clause 8.2
removed, in copies: the differential fuzzer's second way to confirm that a stream breaks two
conditions (conformance/differential.py): the JavaScript decoder names c_js, the reference c_ref;
the JavaScript decoder without its checks of c_js rejecting the stream for c_ref shows the stream
breaks c_ref too, as the reference without its checks of c_ref reaching c_js shows it breaks c_js.

A check of condition c is a ``throw new ...Error(..., 'c')`` of the decoder's JavaScript sources
(every check of the decoder that names its row throws so, the condition its last argument); the
copy has each such throw replaced by ``void 0``, so that the decoder goes on as a decoder without
that check would. Checks made inside the WebAssembly module (wasm/decoder.ts: a range decoder's
exhaustion, E38; an index range of clause 11) are reported back as error codes and turned into an
error by a function that returns it (symbols.mjs); no copy removes those (it would need the
module rebuilt): ``JsCheckRemovals.copy_without`` returns None for such a condition.
"""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

_THROW = re.compile(r"\bthrow new \w*Error\(")
_CONDITION_LITERAL = re.compile(r"'(E[1-9][0-9]?)'")


def _skip_quoted(text: str, i: int) -> int:
    """Past the string literal that opens at text[i] (' or ")."""
    quote, i = text[i], i + 1
    while i < len(text) and text[i] != quote:
        i += 2 if text[i] == "\\" else 1
    return i + 1


def _skip_template(text: str, i: int) -> int:
    """Past the template literal that opens at text[i] (a backquote), its ${...} parts included."""
    i += 1
    while i < len(text) and text[i] != "`":
        if text[i] == "\\":
            i += 2
        elif text.startswith("${", i):
            i = _closing(text, i + 2) + 1
        else:
            i += 1
    return i + 1


def _closing(text: str, i: int) -> int:
    """The index of the bracket that closes the one just before text[i] (strings and templates skipped)."""
    depth = 0
    while i < len(text):
        c = text[i]
        if c in "'\"":
            i = _skip_quoted(text, i)
            continue
        if c == "`":
            i = _skip_template(text, i)
            continue
        if c in "([{":
            depth += 1
        elif c in ")]}":
            if depth == 0:
                return i
            depth -= 1
        i += 1
    raise ValueError("an unclosed bracket")


def without_checks(source: str, conditions: set[str]) -> tuple[str, int]:
    """``source`` with each ``throw new XError(...)`` whose arguments name one of ``conditions`` as a
    quoted literal replaced by ``void 0``; and how many were replaced."""
    out, pos, removed = [], 0, 0
    for m in _THROW.finditer(source):
        if m.start() < pos:
            continue  # inside a throw already replaced
        end = _closing(source, m.end()) + 1
        if set(_CONDITION_LITERAL.findall(source[m.end():end - 1])) & conditions:
            out += [source[pos:m.start()], "void 0"]
            pos, removed = end, removed + 1
    return "".join(out) + source[pos:], removed


class JsCheckRemovals:
    """Copies of the JavaScript decoder without the checks of a set of conditions, built on first
    use in a temporary folder and kept (at most ``limit`` of them; the oldest goes first):
    ``copy_without(conditions)`` -> the copy's folder, or None when its sources have no check of one
    of them to remove."""

    def __init__(self, decoder_dir: Path, limit: int = 64):
        self.decoder_dir, self.limit = Path(decoder_dir), limit
        self._tmp = tempfile.TemporaryDirectory(prefix="lghcc-js-checks-")
        self._copies: dict[tuple[str, ...], Path | None] = {}
        self._built = 0

    def copy_without(self, conditions) -> Path | None:
        key = tuple(sorted(set(conditions)))
        if key not in self._copies:
            if len(self._copies) >= self.limit:
                oldest = next(iter(self._copies))
                if self._copies[oldest] is not None:
                    shutil.rmtree(self._copies[oldest], ignore_errors=True)
                del self._copies[oldest]
            self._copies[key] = self._build(key)
        return self._copies[key]

    def _build(self, key: tuple[str, ...]) -> Path | None:
        """The copy, or None when some condition of ``key`` has no check in the JavaScript sources."""
        sources = {f.name: f.read_text() for f in sorted(self.decoder_dir.glob("*.mjs"))}
        for c in key:
            if not any(without_checks(text, {c})[1] for text in sources.values()):
                return None
        self._built += 1
        target = Path(self._tmp.name) / f"copy{self._built}"
        shutil.copytree(self.decoder_dir, target, ignore=shutil.ignore_patterns("node_modules"))
        for name, text in sources.items():
            new, n = without_checks(text, set(key))
            if n:
                (target / name).write_text(new)
        return target

    def close(self) -> None:
        self._tmp.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
