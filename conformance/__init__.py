"""Conformance: the streams (``STREAMS_DIR``), their runner, the mutation list, the fuzzer."""

from pathlib import Path

STREAMS_DIR = Path(__file__).resolve().parent / "streams"
