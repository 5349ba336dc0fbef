"""Argument types shared by the command-line programs (lghcc-enc, lghcc-dec)."""

from __future__ import annotations

import argparse
import math
import textwrap


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0, with a message naming what was given."""
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return x


# --- what every lghcc-* program shares ------------------------------------------------------------

EXIT_OK = 0
EXIT_ERROR = 1  # bad input, a bad option value, an output that may not or cannot be written
EXIT_USAGE = 2  # the command line itself (argparse): unknown option, missing argument
EXIT_HASH_MISMATCH = 3  # lghcc-dec, lghcc-view: the decoded scene does not match the stream's hash
EXIT_INTERRUPTED = 130  # Ctrl-C (SIGINT), as shells report 128 + 2

OVERWRITE_RULE = textwrap.fill("Outputs: a file or a non-empty folder that exists is never overwritten unless -y (--overwrite) "
                  "is given; the program then stops before any work (as ffmpeg -n; -n says so explicitly). "
                  "Every file is written whole or not at all (a temporary file, renamed into place).", 88)


def exit_codes_text(extra: dict[int, str] | None = None) -> str:
    """The 'exit status' paragraph of a program's --help (README: the same table)."""
    codes = {EXIT_OK: "success", EXIT_ERROR: "error (the message says what and where)",
             EXIT_USAGE: "bad command line", **(extra or {}),
             EXIT_INTERRUPTED: "interrupted (Ctrl-C); no partial output file is left"}
    return "exit status:\n" + "".join(f"  {k:<4} {v}\n" for k, v in sorted(codes.items()))


def add_version_option(p: argparse.ArgumentParser) -> None:
    from lghcc import __version__

    p.add_argument("--version", action="version", version=f"%(prog)s {__version__} (lghcc)")


def add_overwrite_options(p: argparse.ArgumentParser, what: str = "output files and folders") -> None:
    """-y/--overwrite (-f/--force: the same) and -n/--no-overwrite: the one overwrite rule of
    every lghcc-* program (OVERWRITE_RULE). Sets ``args.overwrite``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("-y", "--overwrite", "-f", "--force", dest="overwrite", action="store_true",
                   help=f"replace existing {what} (-f/--force: the same)")
    g.add_argument("-n", "--no-overwrite", dest="no_overwrite", action="store_true",
                   help="never replace an existing output: stop with an error (the default, stated)")


def run_cli(prog: str, body, argv, interrupted_note: str = "") -> int:
    """Run ``body(argv)`` -> exit status, turning Ctrl-C into one line and EXIT_INTERRUPTED.
    Outputs are written atomically, so an interrupt leaves no partial file behind."""
    import sys

    try:
        return body(argv)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted" + (f"; {interrupted_note}" if interrupted_note else ""), file=sys.stderr,
              flush=True)
        return EXIT_INTERRUPTED
