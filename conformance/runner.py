"""lghcc-conformance: decode every conformance stream and check its decoded-scene hash.

Each stream lives in ``conformance/streams/<id>/`` as ``stream.lghcc`` and ``test.yaml``
(purpose, profile, tools exercised, expected outcome, SHA-256 of the decoded scene
and of the stream itself). A decoder conforms when it reproduces every hash and
rejects every stream marked ``expect: error``.

Another implementation is tested with ``--decoder-cmd``: a command template with
``{stream}``; it must exit 0 and print the decoded scene's SHA-256 (spec clause 11)
as 64 hex digits on the last line of its output, or exit non-zero to reject a stream.
Example: ``lghcc-conformance --decoder-cmd "lghcc-dec {stream} --print-hash"``.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from lghcc.common.errors import LghccError

STREAMS_DIR = Path(__file__).resolve().parent / "streams"


@dataclass
class Case:
    id: str
    folder: Path
    meta: dict

    @property
    def stream(self) -> Path:
        return self.folder / "stream.lghcc"


@dataclass
class Outcome:
    case: Case
    passed: bool
    seconds: float
    note: str


def load_cases(root: Path = STREAMS_DIR, ids: list[str] | None = None) -> list[Case]:
    if not root.is_dir():
        raise LghccError(f"{root}: no conformance streams folder")
    cases = []
    for folder in sorted(p for p in root.iterdir() if (p / "test.yaml").is_file()):
        if ids and folder.name not in ids:
            continue
        cases.append(Case(folder.name, folder, yaml.safe_load((folder / "test.yaml").read_text())))
    if ids:
        missing = sorted(set(ids) - {c.id for c in cases})
        if missing:
            raise LghccError(f"no such conformance stream: {', '.join(missing)}")
    return cases


def decode_internal(stream: Path) -> str:
    """The reference decoder: returns the decoded scene's SHA-256 (hex); raises LghccError."""
    from lghcc.common.hashing import scene_digest
    from lghcc.decoder.decode import decode_stream

    return scene_digest(decode_stream(stream.read_bytes()).scene).hex()


def decode_external(template: str, stream: Path, timeout: float) -> tuple[int, str]:
    cmd = [a.replace("{stream}", str(stream)) for a in shlex.split(template)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return -1, f"timed out after {timeout:.0f} s"
    except OSError as e:
        raise LghccError(f"cannot run the decoder command: {e}") from None
    lines = out.stdout.strip().splitlines()
    return out.returncode, lines[-1].strip() if lines else ""


def run_case(case: Case, decoder_cmd: str | None = None, timeout: float = 120.0) -> Outcome:
    expect = case.meta.get("expect", "decode")
    t0 = time.perf_counter()
    if decoder_cmd is None:
        try:
            digest, err = decode_internal(case.stream), None
        except LghccError as e:
            digest, err = None, str(e)
    else:
        rc, last = decode_external(decoder_cmd, case.stream, timeout)
        digest, err = (last, None) if rc == 0 else (None, f"exit code {rc}")
    dt = time.perf_counter() - t0
    if expect == "error":
        ok = err is not None
        note = f"rejected: {err}" if ok else "decoded a stream that must be rejected"
    else:
        want = case.meta["decoded_sha256"]
        ok = err is None and digest == want
        note = "hash matches" if ok else (f"error: {err}" if err else f"hash {str(digest)[:16]}... != {want[:16]}...")
    return Outcome(case, ok, dt, note)


def format_table(outcomes: list[Outcome]) -> str:
    w = max([len(o.case.id) for o in outcomes] + [6])
    lines = [f"{'stream':<{w}}  {'expect':<7} {'result':<6} {'ms':>8}  note"]
    for o in outcomes:
        lines.append(f"{o.case.id:<{w}}  {o.case.meta.get('expect', 'decode'):<7} "
                     f"{'pass' if o.passed else 'FAIL':<6} {1000 * o.seconds:>8.1f}  {o.note[:100]}")
    n_pass = sum(o.passed for o in outcomes)
    lines.append(f"{n_pass} passed, {len(outcomes) - n_pass} failed")
    return "\n".join(lines)


def setup_args() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lghcc-conformance", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("ids", nargs="*", help="stream ids to run (default: all)")
    p.add_argument("--streams", default=str(STREAMS_DIR), help="folder of conformance streams")
    p.add_argument("--decoder-cmd", help="external decoder command template with {stream}")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per stream for an external decoder")
    p.add_argument("--threads", type=int, help="torch threads for the reference decoder")
    p.add_argument("--coverage", action="store_true",
                   help="also report which syntax elements and value classes the suite exercises")
    return p


def main(argv: list[str] | None = None) -> int:
    args = setup_args().parse_args(argv)
    try:
        if args.threads:
            import torch
            torch.set_num_threads(args.threads)
        cases = load_cases(Path(args.streams), args.ids or None)
        outcomes = [run_case(c, args.decoder_cmd, args.timeout) for c in cases]
    except LghccError as e:
        print(f"lghcc-conformance: error: {e}", file=sys.stderr)
        return 2
    print(format_table(outcomes))
    if args.coverage:
        from lghcc.conformance.coverage import coverage_report
        print()
        print(coverage_report([c.stream for c in cases if c.meta.get("expect", "decode") == "decode"]).text())
    return 0 if all(o.passed for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
