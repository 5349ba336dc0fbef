#!/usr/bin/env python3
"""Coverage-guided fuzz target for the decoder (optional; needs atheris: pip install -e '.[fuzz]').

    python tools/fuzz_atheris.py -atheris_runs=20000 -max_len=4096 [corpus_dir ...]

Without a corpus folder it starts from the conformance streams (those up to -max_len
bytes are used as seeds through a temporary folder). A case passes when the decoder ends in
lghcc.common.errors.LghccError or a valid decode; any other exception is reported by
libFuzzer as a crash with its input saved (crash-<sha1>). The script sets libFuzzer's bounds
unless given on the command line: -timeout=5 (seconds per input: a hang is reported as a
timeout with its input saved) and -rss_limit_mb=4096 (a larger resident size is reported as
out-of-memory), the bounds of tools/fuzz_decoder.py's sandbox.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import atheris

with atheris.instrument_imports():
    from lghcc.common.errors import LghccError
    from lghcc.decoder.decode import decode_stream


def test_one_input(data: bytes) -> None:
    try:
        decode_stream(data)
    except LghccError:
        pass


DEFAULT_FLAGS = {"-timeout": "5", "-rss_limit_mb": "4096"}


def with_default_flags(argv: list[str]) -> list[str]:
    """argv plus each libFuzzer flag of DEFAULT_FLAGS that it does not set."""
    args = list(argv)
    for flag, value in DEFAULT_FLAGS.items():
        if not any(a.startswith(flag + "=") for a in args[1:]):
            args.insert(1, f"{flag}={value}")
    return args


def main() -> None:
    args = with_default_flags(sys.argv)
    if not any(not a.startswith("-") for a in args[1:]):
        from lghcc.conformance.fuzz import load_seeds

        corpus = Path(tempfile.mkdtemp(prefix="lghcc-atheris-"))
        for sid, data in load_seeds(max_bytes=4096).items():
            (corpus / sid).write_bytes(data)
        args.append(str(corpus))
    atheris.Setup(args, test_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
