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

# The exit statuses and the --help table that lists them are lghcc.app.cli_common's (one rule for every
# program; README "Exit status", the conformance docs); re-exported here for the programs' convenience.
from .cli_common import (EXIT_ERROR, EXIT_INTERRUPTED, EXIT_INVALID_STREAM, EXIT_OK,  # noqa: E402,F401
                              EXIT_RESOURCE_LIMIT, EXIT_USAGE, exit_status_epilog)

OVERWRITE_RULE = textwrap.fill("Outputs: a file or a non-empty folder that exists is never overwritten unless -y (--overwrite) "
                  "is given; the program then stops before any work (as ffmpeg -n; -n says so explicitly). "
                  "Every file is written whole or not at all (a temporary file, renamed into place).", 88)


def add_version_option(p: argparse.ArgumentParser) -> None:
    from .. import __version__

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
    """Run ``body(argv)`` -> exit status under lghcc.app.cli_common's rule: an LghccError, a MemoryError
    or Ctrl-C raised inside becomes one line on stderr and its exit status (``exit_code_for``: 1, 3
    for an invalid stream, 4 for a resource limit, 130 interrupted). Outputs are written atomically,
    so an interrupt leaves no partial file behind. Other exceptions are bugs and propagate."""
    from .cli_common import report
    from ..common.errors import LghccError

    try:
        return body(argv)
    except (LghccError, MemoryError, KeyboardInterrupt) as e:
        return report(prog, e, "interrupted" + (f"; {interrupted_note}" if interrupted_note else ""))
