"""Differential fuzzing: the reference decoder against the JavaScript decoder (js/lghcc-decoder),
on the same streams (issue 56, item 3).

Each case is decoded by both: the reference in the fuzz sandbox (conformance/fuzz.py ``Sandbox``,
with ``reference_judge``, which also returns the decoded scene's SHA-256 of clause 12), the
JavaScript decoder in one long-lived Node process (tools/js_decode_server.mjs; a Node start per
case would cost more than most cases). The two agree when

* both decode, to the same hash (a box decode: the same hash of the tiles the box selects);
* both reject the stream (BitstreamError and its subclasses on both sides) for the same condition
  of clause 8.2 (the error's ``condition``), or for two conditions the stream is shown to break
  both of (clause 8.2 does not order the checks, so a decoder may report any condition a stream
  breaks): the reference decoder names c_ref, the JavaScript decoder c_js, and either
  - the JavaScript decoder with its checks of c_js removed (conformance/js_checks.py: a copy of
    its sources, loaded once in a Node server of its own) rejects the stream for c_ref, or,
    removing the checks of each condition it then names in turn (at most MAX_CONFIRM_CHAIN
    conditions), reaches c_ref (AGREE_REJECTED_TWO_JS); or
  - the reference with its check of c_ref removed (conformance/conditions.py's CHECK_REMOVALS and
    mutant_decode) likewise reaches c_js, or the elements c_js is about, read alone, break it (a
    decoded_scene_hash unit; the first elements of an attribute unit header; E61, a case of E14)
    (AGREE_REJECTED_TWO);
* the JavaScript decoder rejects a stream the reference rejects as UnsupportedStreamError with no
  condition (an anchor stream, the hierarchy: outside its profile);
* the reference decodes a stream outside the explicit-Gaussian profile (an anchor stream, the
  hierarchy) and the JavaScript decoder rejects it as UnsupportedStreamError (spec clause 8.4);
* either refuses it for a resource bound of its own (ResourceLimitError): not compared.

Anything else is a disagreement (a hash that differs, a stream one decodes and the other rejects,
a condition of the JavaScript decoder the stream is not shown to break, a rejection that names no
condition, an exception of another class or a hang of the JavaScript decoder), which is a bug in
one decoder or an ambiguity of spec/; a reference-side bug of conformance/fuzz.py's kind ('BUG:
...') is reported too. The cases both reject are counted by their pair of conditions.

Cases come from conformance/fuzz.py's ``Mutator`` (its seeds: the conformance streams that decode)
and from a scene source (tools/fuzz_scenes.py: fresh encoder streams, which then join the seeds).
tools/fuzz_differential.py runs campaigns; tests/test_differential.py a short one.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import selectors
import shutil
import subprocess
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from ..common.errors import LghccError
from .fuzz import VALID, Mutator, Sandbox
from .js_checks import JsCheckRemovals

ROOT = Path(__file__).resolve().parents[1]
JS_SERVER = ROOT / "tools" / "js_decode_server.mjs"
JS_DECODER = ROOT / "js" / "lghcc-decoder"

AGREE_DECODED = "agree: both decoded, same hash"
AGREE_REJECTED = "agree: both rejected, for the same condition"
AGREE_REJECTED_TWO = "agree: both rejected, for two conditions the stream breaks (confirmed without the check)"
AGREE_REJECTED_TWO_JS = ("agree: both rejected, for two conditions the stream breaks (confirmed by the JavaScript decoder "
                         "without its check)")
AGREE_REJECTED_OUTSIDE = "agree: both rejected, JS as outside its profile (UnsupportedStreamError, no condition)"
CONDITIONS_DIFFER = "DISAGREE: rejected for different conditions"
# the most checks of the reference decoder removed, one after the other, to confirm the JavaScript decoder's condition
MAX_CONFIRM_CHAIN = 8
# seconds a decode of the JavaScript decoder with checks removed may take: without its checks it may loop on
# data that no longer means anything (a 60 s case timeout spent on each such chain halved a campaign's speed)
CONFIRM_TIMEOUT = 15.0
# CPU seconds a decode of the reference with checks removed may take (its wall-clock bound is the case's
# timeout): a bound in CPU time gives the same verdict on a busy machine as on a quiet one (15 s of wall
# clock did not: a niced mutant that reads on to the next condition took 14 s at load 10)
CONFIRM_CPU_SECONDS = 5
# copies of the JavaScript decoder without checks one Node server loads before it is started afresh
# (each keeps its modules and its WebAssembly memory)
JS_MUTANTS_LOADED = 24
AGREE_UNSUPPORTED = "agree: outside the profile, JS rejects it as UnsupportedStreamError"
NOT_COMPARED = "not compared: a resource limit"
SCENE_REFUSED = "scene refused by the encoder (InputError; not a case)"


@dataclass(frozen=True)
class Verdict:
    """One decoder's answer: ``outcome`` 'decoded' (``hash``), 'rejected' (``kind``: the error
    class, ``message``), 'resource' (a ResourceLimitError) or 'bug' (``kind``: an exception of
    another class, a timeout, a dead process). ``in_profile``: of a reference decode, whether the
    stream lies in the explicit-Gaussian profile (no anchors, no hierarchy)."""

    outcome: str
    hash: str = ""
    kind: str = ""
    message: str = ""
    in_profile: bool = True
    condition: str | None = None  # of a rejection: the row of clause 8.2 the error names

    def describe(self) -> str:
        if self.outcome == "decoded":
            return f"decoded {self.hash}" + ("" if self.in_profile else " (outside the profile)")
        cond = f" ({self.condition})" if self.condition else ""
        return f"{self.outcome}: {self.kind}{cond}: {self.message}".strip()


def reference_judge(data: bytes, options: dict | None = None) -> tuple[str, str]:
    """In the sandbox's worker: (kind, detail) as fuzz.classify, with the decoded scene's hash and
    'in' / 'out' (the profile) as detail of a valid decode."""
    from ..decoder.decode import decode_stream, parse_stream
    from ..common.scene import GaussianScene
    from .fuzz import _MAX_MEMORY, classify

    options = dict(options or {})
    try:
        res = decode_stream(data, max_memory=_MAX_MEMORY[0], **options)
    except LghccError as e:  # detail: the condition (or '-') and the message
        return f"error: {type(e).__name__}", f"{getattr(e, 'condition', None) or '-'} {str(e)[:300]}"
    except Exception:  # noqa: BLE001 - the reference's bug: classify reports it with its traceback
        return classify(data, options)
    in_profile = isinstance(res.scene, GaussianScene) and not parse_stream(data).ps.hierarchy_enabled_flag
    return VALID, f"{res.stream_hash.hex()} {'in' if in_profile else 'out'}"


def reference_verdict(kind: str, detail: str) -> Verdict:
    """A sandbox result of ``reference_judge`` as a Verdict."""
    if kind == VALID:
        digest, profile = detail.split()
        return Verdict("decoded", hash=digest, in_profile=profile == "in")
    if kind.startswith("error: "):
        condition, _, message = detail.partition(" ")
        condition = None if condition == "-" else condition
        if kind == "error: ResourceLimitError":
            return Verdict("resource", kind="ResourceLimitError", message=message)
        return Verdict("rejected", kind=kind[len("error: "):], message=message, condition=condition)
    return Verdict("bug", kind=kind, message=detail.strip().splitlines()[-1] if detail.strip() else "")


class JsDecoder:
    """The JavaScript decoder in a Node process (tools/js_decode_server.mjs) that decodes one
    stream per request. ``decoder_dir``: the decoder's folder (a mutated copy in the tests); a
    request that gets no answer within ``timeout`` seconds is a hang: the process is killed and the
    next request starts another."""

    def __init__(self, decoder_dir: Path | None = None, timeout: float = 30.0, max_memory: int = 1 << 30,
                 node: str | None = None, max_decoders: int = JS_MUTANTS_LOADED):
        self.node = node or shutil.which("node")
        if self.node is None:
            raise LghccError("node (Node.js) is not on the PATH: the JavaScript decoder runs in it")
        self.decoder_dir = Path(decoder_dir or JS_DECODER)
        self.timeout, self.max_memory = timeout, max_memory
        self._proc: subprocess.Popen | None = None
        self._buffer = b""
        self.max_decoders = max_decoders  # other copies of the decoder one server loads before it starts afresh
        self._decoders: set[str] = set()

    def _start(self) -> None:
        self._proc = subprocess.Popen([self.node, str(JS_SERVER), str(self.decoder_dir)], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self._buffer, self._decoders = b"", set()
        line = self._readline(60.0)
        if line is None or "ready" not in json.loads(line):
            self.close()
            raise LghccError(f"the JavaScript decoder server did not start ({JS_SERVER})")

    def _readline(self, timeout: float) -> str | None:
        """The next line of the server's stdout; None when none came within ``timeout`` or it ended."""
        deadline = time.monotonic() + timeout
        fd = self._proc.stdout.fileno()
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while b"\n" not in self._buffer:
                left = deadline - time.monotonic()
                if left <= 0 or not sel.select(left):
                    return None
                chunk = os.read(fd, 1 << 16)
                if not chunk:
                    return None
                self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode()

    def run(self, data: bytes, box=None, decoder: Path | None = None) -> Verdict:
        """Decode ``data`` (``box``: a common.tiles.Box, or None for the whole stream; ``decoder``:
        another copy of the decoder, which the server loads on its first request and keeps)."""
        return self.collect(self.submit(data, box, decoder))

    def submit(self, data: bytes, box=None, decoder: Path | None = None) -> Verdict | None:
        """Send the request and return at once (None), or the verdict when it cannot be sent."""
        if decoder is not None and str(decoder) not in self._decoders and len(self._decoders) >= self.max_decoders:
            self.close()  # the server keeps each copy it loaded (its modules, its WebAssembly memory)
        if self._proc is None or self._proc.poll() is not None:
            self._start()
        if decoder is not None:
            self._decoders.add(str(decoder))
        request = {"box": list(box.lo) + list(box.hi) if box is not None else None, "maxMemory": self.max_memory}
        if decoder is not None:
            request["decoder"] = str(decoder)
        options = json.dumps(request).encode()
        try:
            self._proc.stdin.write(len(options).to_bytes(4, "big") + options + len(data).to_bytes(4, "big") + data)
            self._proc.stdin.flush()
        except BrokenPipeError:
            self.close()
            return Verdict("bug", kind="JS process died", message="its stdin closed")
        return None

    def collect(self, failed: Verdict | None = None) -> Verdict:
        """The answer to the request ``submit`` sent (``failed``: what submit returned)."""
        if failed is not None:
            return failed
        line = self._readline(self.timeout)
        if line is None:
            died = self._proc.poll() is not None
            self.close()
            return Verdict("bug", kind="JS process died" if died else "JS timeout",
                           message="" if died else f"no answer within {self.timeout:g} s")
        return _js_verdict(json.loads(line))

    def close(self) -> None:
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            for f in (self._proc.stdin, self._proc.stdout):
                f.close()
        self._proc = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _js_verdict(answer: dict) -> Verdict:
    outcome = answer["outcome"]
    if outcome == "decoded":
        return Verdict("decoded", hash=answer["hash"])
    if outcome == "resource":
        return Verdict("resource", kind="ResourceLimitError", message=answer["message"])
    if outcome == "rejected":
        return Verdict("rejected", kind=answer["kind"], message=answer["message"], condition=answer.get("condition"))
    return Verdict("bug", kind=f"JS {answer['kind']}", message=answer["message"])


def compare(ref: Verdict, js: Verdict) -> str:
    """The case's outcome: one of the AGREE_ labels, NOT_COMPARED, or 'DISAGREE: ...' / 'BUG: ...'."""
    if ref.outcome == "bug":
        return f"BUG: reference {ref.kind}"
    if js.outcome == "bug":
        return f"DISAGREE: {js.kind}"
    if "resource" in (ref.outcome, js.outcome):
        return NOT_COMPARED
    if ref.outcome == "decoded" and not ref.in_profile:
        if js.outcome == "rejected" and js.kind == "UnsupportedStreamError":
            return AGREE_UNSUPPORTED
        return f"DISAGREE: outside the profile, JS {'decoded it' if js.outcome == 'decoded' else 'rejected it as ' + js.kind}"
    if ref.outcome == js.outcome == "decoded":
        return AGREE_DECODED if ref.hash == js.hash else "DISAGREE: decoded hashes differ"
    if ref.outcome == js.outcome == "rejected":
        return _compare_rejections(ref, js)
    return f"DISAGREE: reference {ref.outcome}, JS {js.outcome}"


def _compare_rejections(ref: Verdict, js: Verdict) -> str:
    """Both rejected: AGREE_REJECTED for one condition, CONDITIONS_DIFFER for two (``Differential``
    then asks the reference decoder whether the stream breaks the JavaScript decoder's too)."""
    if ref.condition is None and ref.kind != "UnsupportedStreamError":
        return "BUG: the reference's rejection names no condition of clause 8.2"
    if js.condition is None:
        if js.kind == "UnsupportedStreamError":
            return AGREE_REJECTED_OUTSIDE
        return "DISAGREE: JS's rejection names no condition of clause 8.2"
    return AGREE_REJECTED if ref.condition == js.condition else CONDITIONS_DIFFER


def neighbour_unit_misplaced(data: bytes) -> bool:
    """Whether the stream breaks E61: a neighbour_prediction unit in an anchor stream, more than one,
    or one not right after the gaussian_parameter_set (clause 6.3)."""
    from ..common.container import UnitType, read_container
    from ..decoder.core import _LETTER

    letters = "".join(_LETTER[UnitType(u.unit_type)] for u in read_container(data).units
                      if not u.is_ancillary and u.unit_type in _LETTER)
    return "N" in letters and ("S" in letters or letters.count("N") > 1 or "PN" not in letters)


def hash_unit_conditions(data: bytes) -> set[str]:
    """The conditions the stream's decoded_scene_hash units break, each parsed alone by the
    reference's syntax (the reference decoder parses one only after its tile's data, which a
    stream broken earlier in the tile may keep it from reaching). The units are found by their
    headers' sizes alone: a stream may break the container's own checks as well."""
    from ..common.container import CONTAINER_HEADER_BYTES, UNIT_CRC_BYTES, UNIT_HEADER_BYTES, UnitType
    from ..common.errors import BitstreamError
    from ..common.units import DecodedSceneHashUnit

    out, pos = set(), CONTAINER_HEADER_BYTES
    while pos + UNIT_HEADER_BYTES <= len(data):
        size = int.from_bytes(data[pos + 1:pos + UNIT_HEADER_BYTES], "big")
        if data[pos] == UnitType.DECODED_SCENE_HASH and pos + UNIT_HEADER_BYTES + size <= len(data):
            try:
                DecodedSceneHashUnit.from_bytes(data[pos + UNIT_HEADER_BYTES:pos + UNIT_HEADER_BYTES + size],
                                                what="decoded scene hash unit")
            except BitstreamError as e:
                out.add(e.condition)
        pos += UNIT_HEADER_BYTES + size + UNIT_CRC_BYTES
    return out


def _units_by_headers(data: bytes):
    """(unit_type, payload) of each unit of ``data``, found by its header's size alone (a stream may
    break the container's own checks as well)."""
    from ..common.container import CONTAINER_HEADER_BYTES, UNIT_CRC_BYTES, UNIT_HEADER_BYTES

    pos = CONTAINER_HEADER_BYTES
    while pos + UNIT_HEADER_BYTES <= len(data):
        size = int.from_bytes(data[pos + 1:pos + UNIT_HEADER_BYTES], "big")
        if pos + UNIT_HEADER_BYTES + size <= len(data):
            yield data[pos], data[pos + UNIT_HEADER_BYTES:pos + UNIT_HEADER_BYTES + size]
        pos += UNIT_HEADER_BYTES + size + UNIT_CRC_BYTES


def attribute_header_conditions(data: bytes) -> set[str]:
    """The conditions the first two elements of the stream's attribute unit headers break, read
    alone (attribute_level u(2), context_model_id u(3), clause 7.3.5): E46 (context_model_id 1 or 2
    at level 0 or 1), E62 (context_model_id not 0 in a stream with a neighbour_prediction unit) and,
    in a stream of a gaussian_parameter_set without the hierarchy, E45 (a level other than 0). The
    JavaScript decoder checks them as it reads them; the reference parses the whole header first
    (its syntax depends on context_model_id), so another element's range may stop it first, and
    without those checks it reads the rest of the unit as other elements."""
    from ..common.container import UnitType
    from ..common.units import GaussianParameterSet

    units = list(_units_by_headers(data))
    flat = None
    if units and units[0][0] == UnitType.GAUSSIAN_PARAMETER_SET:
        try:
            flat = not GaussianParameterSet.from_bytes(units[0][1]).hierarchy_enabled_flag
        except LghccError:
            pass
    neighbours = any(t == UnitType.NEIGHBOUR_PREDICTION for t, _ in units)
    out = set()
    for t, payload in units:
        if t != UnitType.ATTRIBUTE or not payload:
            continue
        level, model = payload[0] >> 6, (payload[0] >> 3) & 7
        if flat and level != 0:
            out.add("E45")
        if model in (1, 2) and level in (0, 1):
            out.add("E46")
        if model and neighbours:
            out.add("E62")
    return out


def confirm_condition(data: bytes, c_ref: str, c_js: str, timeout: float = 120.0,
                      cpu_seconds: int | None = CONFIRM_CPU_SECONDS) -> tuple[bool, str]:
    """Does ``data`` break ``c_js`` as well as ``c_ref``? The reference decoder with every check of
    c_ref removed, then of each condition it names next (MAX_CONFIRM_CHAIN conditions at most), in
    a forked child: (True when it reaches c_js, the chain as text)."""
    from .conditions import combined, confirm_removals, mutant_decode

    if {c_ref, c_js} == {"E14", "E61"}:  # E61 is a case of E14: one check, no removal tells them apart
        ok = neighbour_unit_misplaced(data)
        return ok, f"{c_ref} -> E61 is a case of E14: the neighbour_prediction unit {'is' if ok else 'is not'} out of place"
    if c_js in hash_unit_conditions(data):  # the JavaScript decoder reads them before the tiles' data
        return True, f"{c_ref} -> {c_js} in a decoded_scene_hash unit (parsed alone)"
    if c_js in attribute_header_conditions(data):
        return True, f"{c_ref} -> {c_js} in an attribute unit header's first elements (read alone)"
    removed, named, cond = [], [c_ref], c_ref
    while len(named) <= MAX_CONFIRM_CHAIN:
        more = confirm_removals(cond)
        if not more:
            return False, f"{' -> '.join(named)}: no mutation removes the check of {cond}"
        removed += more
        res = mutant_decode(tuple(combined(removed)), data, timeout, cpu_seconds)
        if res.decoded or res.condition is None or res.condition in named:
            return False, f"{' -> '.join(named)}, then without those checks: {res.describe()[:200]}"
        named.append(res.condition)
        if res.condition == c_js:
            return True, " -> ".join(named)
        cond = res.condition
    return False, f"{' -> '.join(named)}: not {c_js} within {MAX_CONFIRM_CHAIN} checks removed"


@dataclass
class DiffSummary:
    """What a campaign found: outcomes by label, the error-class pairs of the cases both rejected,
    and the disagreements (label, case, reference verdict, JS verdict)."""

    cases: int = 0
    seconds: float = 0.0
    stopped: bool = False
    outcomes: Counter = field(default_factory=Counter)
    class_pairs: Counter = field(default_factory=Counter)  # (reference class, JS class) of both-rejected cases
    condition_pairs: Counter = field(default_factory=Counter)  # (reference condition, JS condition), likewise
    confirmed: list[tuple[str, str]] = field(default_factory=list)  # the first 20 chains of AGREE_REJECTED_TWO
    scene_cases: int = 0
    duplicates: int = 0  # mutations that gave a stream already compared (skipped, not counted as cases)
    disagreements: list[tuple[str, str, str, str]] = field(default_factory=list)
    not_compared: list[tuple[str, str, str, str]] = field(default_factory=list)  # the first 20 resource-limit cases
    # the first 20 both-rejected cases whose classes differ, the JavaScript decoder's UnsupportedStreamError
    # (a stream outside its profile) aside: clause 8.2 gives each condition its class
    classes_differ: list[tuple[str, str, str, str]] = field(default_factory=list)

    @property
    def bugs(self) -> int:
        return sum(n for k, n in self.outcomes.items() if k.startswith(("DISAGREE", "BUG")))

    def add(self, label: str, what: str, ref: Verdict, js: Verdict, data: bytes,
            failures_dir: Path | None = None) -> None:
        self.cases += 1
        self.outcomes[label] += 1
        if ref.outcome == js.outcome == "rejected":
            self.condition_pairs[(ref.condition or "-", js.condition or "-")] += 1
        if label in (AGREE_REJECTED, AGREE_REJECTED_TWO, AGREE_REJECTED_TWO_JS, AGREE_REJECTED_OUTSIDE):
            self.class_pairs[(ref.kind, js.kind)] += 1
            if ref.kind != js.kind and js.kind != "UnsupportedStreamError" and len(self.classes_differ) < 20:
                self.classes_differ.append((label, what, ref.describe(), js.describe()))
        if label == NOT_COMPARED and len(self.not_compared) < 20:  # two decoders' bounds differ: worth a look
            self.not_compared.append((label, what, ref.describe(), js.describe()))
        if label.startswith(("DISAGREE", "BUG")):
            self.disagreements.append((label, what, ref.describe(), js.describe()))
            if failures_dir is not None:
                save_disagreement(Path(failures_dir), label, what, ref, js, data)

    def text(self) -> str:
        lines = [f"cases: {self.cases} in {self.seconds:.1f} s ({self.cases / max(self.seconds, 1e-9):.1f} cases/s), "
                 f"{self.scene_cases} of them fresh scene streams; {self.duplicates} duplicate mutations skipped",
                 "outcomes:"]
        for k, n in sorted(self.outcomes.items(), key=lambda kv: (not kv[0].startswith(("DISAGREE", "BUG")), -kv[1])):
            lines.append(f"  {n:>7}  {k}")
        lines.append(f"disagreements and bugs: {self.bugs}")
        return "\n".join(lines)


def save_disagreement(folder: Path, label: str, what: str, ref: Verdict, js: Verdict, data: bytes) -> Path:
    """The stream as <tag>_<sha>.lghcc and both verdicts beside it (.txt)."""
    folder.mkdir(parents=True, exist_ok=True)
    name = f"diff_{hashlib.sha256(data).hexdigest()[:12]}"
    (folder / f"{name}.lghcc").write_bytes(data)
    (folder / f"{name}.txt").write_text(f"{label}\n{what}\n\nreference: {ref.describe()}\nJavaScript: {js.describe()}\n")
    return folder / f"{name}.lghcc"


class Differential:
    """Both decoders side by side: ``check(data, box)`` -> (label, reference verdict, JS verdict).
    ``js_checks``: copies of the JavaScript decoder with checks removed (conformance/js_checks.py),
    run by ``js_mutants`` (a Node server of their own, so that a copy that hangs or crashes leaves
    the campaign's server alone); without them only the reference confirms a second condition."""

    def __init__(self, sandbox: Sandbox, js: JsDecoder, js_checks=None, js_mutants: JsDecoder | None = None):
        self.sandbox, self.js = sandbox, js
        self.js_checks, self.js_mutants = js_checks, js_mutants
        self.last_chain = ""  # of the last case confirmed without a check (AGREE_REJECTED_TWO, _TWO_JS)
        self.last_seconds = 0.0  # the reference's CPU seconds on the last case

    def check(self, data: bytes, box=None) -> tuple[str, Verdict, Verdict]:
        # both decoders at work at once: the reference in its worker process, the JavaScript one in Node
        self.sandbox.submit(data, None if box is None else {"box": box})
        js = self.js.collect(self.js.submit(data, box))
        res = self.sandbox.collect()
        ref = reference_verdict(res.kind, res.detail)
        self.last_seconds = res.cpu_seconds
        label = compare(ref, js)
        if label == CONDITIONS_DIFFER:
            label, self.last_chain = self.confirm(data, box, ref.condition, js.condition)
            if label == CONDITIONS_DIFFER:
                js = Verdict(js.outcome, js.hash, js.kind, f"{js.message} [{self.last_chain}]", js.in_profile,
                             js.condition)
        return label, ref, js

    def confirm(self, data: bytes, box, c_ref: str, c_js: str) -> tuple[str, str]:
        """AGREE_REJECTED_TWO_JS or AGREE_REJECTED_TWO when one decoder without its checks of its own
        condition reaches the other's (the JavaScript decoder first: its copies are loaded already
        and decode in milliseconds, the reference's mutant is a forked process); else
        CONDITIONS_DIFFER. With the chains tried, as text."""
        ok, js_chain = self.js_confirms(data, box, c_ref, c_js)
        if ok:
            return AGREE_REJECTED_TWO_JS, js_chain
        ok, ref_chain = confirm_condition(data, c_ref, c_js, self.sandbox.timeout)
        if ok:
            return AGREE_REJECTED_TWO, f"reference: {ref_chain}"
        return CONDITIONS_DIFFER, f"reference: {ref_chain}; JavaScript: {js_chain}"

    def js_confirms(self, data: bytes, box, c_ref: str, c_js: str) -> tuple[bool, str]:
        """Does the JavaScript decoder with its checks of c_js removed (then of each condition it names
        next, MAX_CONFIRM_CHAIN at most) reject ``data`` for c_ref? (True when it does, the chain)."""
        if self.js_checks is None or self.js_mutants is None:
            return False, "no copy without checks"
        removed, cond = [], c_js
        while len(removed) < MAX_CONFIRM_CHAIN:
            removed.append(cond)
            copy = self.js_checks.copy_without(removed)
            if copy is None:
                return False, f"{' -> '.join(removed)}: no check of {cond} in the JavaScript sources to remove"
            v = self.js_mutants.run(data, box, decoder=copy)
            if v.outcome != "rejected" or v.condition is None or v.condition in removed:
                return False, f"{' -> '.join(removed)}, then without those checks: {v.describe()[:200]}"
            if v.condition == c_ref:
                return True, " -> ".join(removed + [c_ref])
            cond = v.condition
        return False, f"{' -> '.join(removed)}: not {c_ref} within {MAX_CONFIRM_CHAIN} checks removed"


def run_differential(mutator: Mutator, *, seed: int = 0, cases: int | None = None, seconds: float | None = None,
                     timeout: float = 30.0, memory_mb: int = 2048, decoder_dir: Path | None = None,
                     failures_dir: Path | None = None, progress=None, scene_source=None,
                     mutations_per_scene: int = 20, pool_size: int = 32, cost_cap: float | None = None) -> DiffSummary:
    """Run cases until ``cases`` are done or ``seconds`` have passed: mutations of the mutator's
    seeds and, with ``scene_source`` (tools/fuzz_scenes.py's), one fresh scene stream every
    ``mutations_per_scene`` mutations, decoded whole and with its box decodes; each fresh stream
    both decode joins the seeds (the ``pool_size`` newest). ``cost_cap`` (seconds): a seed whose
    reference decode takes longer is drawn less often (``cost_weight``). Ctrl-C / SIGTERM stops the
    run with the figures of the cases done (``stopped``)."""
    if cases is None and seconds is None:
        raise ValueError("give cases or seconds")
    rng, scene_rng = random.Random(seed), random.Random(f"differential-scenes-{seed}")
    summary = DiffSummary()
    t0 = time.perf_counter()
    sandbox = Sandbox(timeout, memory_mb, judge=reference_judge)
    js_checks = JsCheckRemovals(decoder_dir or JS_DECODER)
    with sandbox, js_checks, JsDecoder(decoder_dir, timeout, max_memory=sandbox.max_memory or 1 << 30) as js, \
            JsDecoder(decoder_dir, min(timeout, CONFIRM_TIMEOUT), max_memory=sandbox.max_memory or 1 << 30) as js_mutants:
        if cost_cap:
            weigh_seeds_by_cost(mutator, sandbox, cost_cap)
        loop = _Loop(Differential(sandbox, js, js_checks, js_mutants), mutator, summary, failures_dir, pool_size,
                     cost_cap)
        try:
            since_scene = mutations_per_scene
            while (cases is None or summary.cases < cases) and (seconds is None or time.perf_counter() - t0 < seconds):
                if scene_source is not None and since_scene >= mutations_per_scene:
                    since_scene = 0
                    loop.scene(scene_source(scene_rng))
                else:
                    since_scene += 1
                    data, what = mutator.case(rng)
                    if loop.seen_before(data):
                        summary.duplicates += 1
                    else:
                        loop.one(data, what)
                if progress is not None:
                    summary.seconds = time.perf_counter() - t0
                    progress(summary)
        except KeyboardInterrupt:
            summary.stopped = True
    summary.seconds = time.perf_counter() - t0
    return summary


def cost_weight(seconds: float, cap: float | None) -> float:
    """A seed's draw weight factor for a reference decode of ``seconds`` (CPU): 1 up to ``cap``, then
    halved for each doubling beyond it (a power of two, so that the noise of a shared machine seldom
    changes it): a seed's mutations cost at most about ``cap`` per draw, and every seed is still
    mutated."""
    if not cap or seconds <= cap:
        return 1.0
    return 2.0 ** -math.ceil(math.log2(seconds / cap))


def weigh_seeds_by_cost(mutator: Mutator, sandbox: Sandbox, cap: float) -> None:
    """Each seed decoded once by the reference (in ``sandbox``), its weight times ``cost_weight``."""
    if mutator.weights is None:
        mutator.weights = {sid: 1.0 for sid in mutator.ids}
    for sid in list(mutator.ids):
        mutator.weights[sid] *= cost_weight(sandbox.run(mutator.seeds[sid]).cpu_seconds, cap)


class _Loop:
    """run_differential's cases into its summary; fresh scene streams join the mutator's seeds."""

    def __init__(self, diff: Differential, mutator: Mutator, summary: DiffSummary, failures_dir, pool_size: int,
                 cost_cap: float | None = None):
        self.diff, self.mutator, self.summary, self.cost_cap = diff, mutator, summary, cost_cap
        self.failures_dir, self.pool_size, self.pool = failures_dir, pool_size, []
        self.seen: set[bytes] = set()

    def seen_before(self, data: bytes) -> bool:
        """Whether this stream was compared already in the campaign (the mutator draws some twice,
        e.g. a syntax element set to the same extreme value): the decoders are deterministic."""
        key = hashlib.blake2b(data, digest_size=12).digest()
        if key in self.seen:
            return True
        if len(self.seen) >= SEEN_LIMIT:  # a bound on memory: forget them all (a few may be compared twice)
            self.seen.clear()
        self.seen.add(key)
        return False

    def one(self, data: bytes, what: str, box=None) -> tuple[str, Verdict]:
        label, ref, js = self.diff.check(data, box)
        self.summary.add(label, what, ref, js, data, self.failures_dir)
        if label in (AGREE_REJECTED_TWO, AGREE_REJECTED_TWO_JS) and len(self.summary.confirmed) < 20:
            self.summary.confirmed.append((what, self.diff.last_chain))
        return label, ref

    def scene(self, sc) -> None:
        what = f"scene {self.summary.cases}: {sc.what}"
        if sc.bug:  # the encoder's exception: no stream to compare, a bug all the same
            self.summary.add("BUG: encoder", what, Verdict("bug", kind="encoder", message=sc.bug.strip().splitlines()[-1]),
                             Verdict("bug", kind="not run"), b"")
            return
        if sc.data is None:  # refused by the encoder (InputError): not a case
            self.summary.outcomes[SCENE_REFUSED] += 1
            return
        self.summary.scene_cases += 1
        label, ref = self.one(sc.data, what)
        cost = self.diff.last_seconds
        if ref.outcome != "decoded":  # a fresh stream must decode: the reference's bug
            self.summary.add("BUG: reference round trip", what, ref, Verdict("bug", kind="not run"), sc.data,
                             self.failures_dir)
            return
        for opts in sc.decodes:
            if set(opts) == {"box"}:  # the JavaScript decoder has no preview (no hierarchy) and no worker choice here
                self.one(sc.data, f"{what}; box {opts['box']}", opts["box"])
        if label == AGREE_DECODED or label == AGREE_UNSUPPORTED:
            sid = f"scene{self.summary.cases}"
            self.mutator.add_seed(sid, sc.data)
            if self.mutator.weights is not None:  # the differential campaign's weights: see seed_weights
                self.mutator.weights[sid] = (1.0 if ref.in_profile else OUTSIDE_PROFILE_WEIGHT) * \
                    cost_weight(cost, self.cost_cap)
            self.pool.append(sid)
            if len(self.pool) > self.pool_size:
                self.mutator.drop_seed(self.pool.pop(0))


# the most stream digests run_differential keeps to skip duplicates (about 100 bytes each)
SEEN_LIMIT = 2_000_000

# a seed outside the explicit-Gaussian profile is mutated a tenth as often as one in it: the JavaScript
# decoder rejects every mutation of an anchor stream as unsupported, early, so they teach little
OUTSIDE_PROFILE_WEIGHT = 0.1


def seed_weights(seeds: dict[str, bytes]) -> dict[str, float]:
    """Weights of the seeds for Mutator.weights: 1 for a stream in the explicit-Gaussian profile
    (a gaussian_parameter_set without the hierarchy), OUTSIDE_PROFILE_WEIGHT for the others."""
    from ..common.units import GaussianParameterSet
    from ..decoder.decode import parse_stream

    out = {}
    for sid, data in seeds.items():
        try:
            ps = parse_stream(data).ps
            in_profile = isinstance(ps, GaussianParameterSet) and not ps.hierarchy_enabled_flag
        except LghccError:
            in_profile = False
        out[sid] = 1.0 if in_profile else OUTSIDE_PROFILE_WEIGHT
    return out
