"""The manifest of the frozen conformance streams, conformance/manifest.yaml: every file of
``streams/<id>/`` by its SHA-256, and what a decoder must do with each stream (decode it to a
hash, or reject it with an error class), in one file a reviewer reads.

The streams are reference material: the generator (``python -m lghcc.conformance.generate``,
``make conformance-regen``) writes them, and this manifest with them, when the bitstream format
changes or a stream is added; an encoder change never rewrites them. The default test tier checks
the files against the manifest with no encoder (tests/test_spec_and_conformance.py); so can anyone
holding a copy of the suite (``python -m lghcc.conformance.manifest``).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import yaml

from ..common.container import VERSION_MAJOR, VERSION_MINOR
from . import load_yaml

HERE = Path(__file__).resolve().parent
STREAMS = HERE / "streams"
MANIFEST = HERE / "manifest.yaml"
# test.yaml's keys that state the outcome a decoder must reach (conformance/runner.py checks them)
OUTCOME_KEYS = ("expect", "decoded_sha256", "expect_error", "condition")
FORMAT_VERSION = f"{VERSION_MAJOR}.{VERSION_MINOR}"  # the version the streams were generated at

HEADER = """\
# The frozen conformance streams: each stream's expected outcome and the SHA-256 of every file of
# streams/<id>/. Written with the streams by `python -m lghcc.conformance.generate` (make
# conformance-regen), only when the format changes or a stream is added (conformance/README.md);
# checked by tests/test_spec_and_conformance.py and `python -m lghcc.conformance.manifest`.
"""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def stream_record(folder: Path) -> dict:
    """One stream's entry: its outcome (from its test.yaml) and the SHA-256 of each of its files."""
    meta = load_yaml((folder / "test.yaml").read_text())
    record = {k: meta[k] for k in OUTCOME_KEYS if k in meta}
    record["files"] = {p.name: _sha256(p) for p in sorted(folder.iterdir()) if p.is_file()}
    return record


def build_manifest(streams: Path = STREAMS) -> dict:
    """The manifest of the streams as they are on disk (a folder per stream, with its test.yaml)."""
    folders = sorted(p for p in streams.iterdir() if (p / "test.yaml").is_file())
    return {"format_version": FORMAT_VERSION,
            "streams": {f.name: stream_record(f) for f in folders}}


def manifest_text(manifest: dict) -> str:
    return HEADER + yaml.safe_dump(manifest, sort_keys=False, width=120)


def write_manifest(streams: Path = STREAMS, path: Path = MANIFEST) -> None:
    path.write_text(manifest_text(build_manifest(streams)))


def read_manifest(path: Path = MANIFEST) -> dict:
    return load_yaml(path.read_text())


def manifest_problems(streams: Path = STREAMS, path: Path = MANIFEST) -> list[str]:
    """What differs between the streams on disk and the committed manifest, one line each
    (empty: the suite is the frozen one)."""
    if not path.is_file():
        return [f"{path}: no manifest"]
    want, have = read_manifest(path)["streams"], build_manifest(streams)["streams"]
    problems = [f"{sid}: in the manifest, not in {streams}" for sid in sorted(set(want) - set(have))]
    problems += [f"{sid}: in {streams}, not in the manifest" for sid in sorted(set(have) - set(want))]
    for sid in sorted(set(want) & set(have)):
        w, h = want[sid], have[sid]
        for name in sorted(set(w["files"]) | set(h["files"])):
            if w["files"].get(name) != h["files"].get(name):
                state = "missing" if name not in h["files"] else "not in the manifest" \
                    if name not in w["files"] else "changed"
                problems.append(f"{sid}/{name}: {state}")
        outcome = {k: v for k, v in w.items() if k != "files"}
        if outcome != {k: v for k, v in h.items() if k != "files"}:
            problems.append(f"{sid}: the manifest's outcome {outcome} is not its test.yaml's")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m lghcc.conformance.manifest",
        description="Check the conformance streams against conformance/manifest.yaml (every file's SHA-256 "
                    "and each stream's expected outcome). Exit status 0: the suite is the frozen one; 1: it "
                    "differs (each difference printed); 2: no manifest.")
    ap.add_argument("--streams", type=Path, default=STREAMS, help="the streams folder (default: %(default)s)")
    ap.add_argument("--manifest", type=Path, default=MANIFEST, help="the manifest (default: %(default)s)")
    ap.add_argument("--write", action="store_true",
                    help="rewrite the manifest from the files (after a change made on purpose outside the generator, "
                         "e.g. a merge that rewrote test.yaml files; the review then shows every file that changed)")
    args = ap.parse_args(argv)
    if args.write:
        write_manifest(args.streams, args.manifest)
        print(f"{args.manifest}: {len(read_manifest(args.manifest)['streams'])} streams written")
        return 0
    if not args.manifest.is_file():
        print(f"manifest: error: {args.manifest}: no such file", file=sys.stderr)
        return 2
    problems = manifest_problems(args.streams, args.manifest)
    for p in problems:
        print(p)
    n = len(read_manifest(args.manifest)["streams"])
    print(f"{n} streams in the manifest: " + (f"{len(problems)} differences" if problems else "all files match"))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
