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


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1, with a message naming what was given."""
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if x < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return x


def jobs_arg(text: str) -> int | None:
    """argparse type: 'auto' (None: as many workers as pay, up to the CPUs) or an integer >= 1 (at
    most that many)."""
    return None if text.strip().lower() == "auto" else positive_int(text)


def box_arg(text: str):
    """argparse type: a box x0,y0,z0,x1,y1,z1 in world coordinates (lghcc-dec --box), each a finite
    number and x0 <= x1, y0 <= y1, z0 <= z1."""
    from ..common.tiles import Box

    parts = text.split(",")
    if len(parts) != 6:
        raise argparse.ArgumentTypeError(f"expected six numbers x0,y0,z0,x1,y1,z1, got {len(parts)} in {text!r}")
    try:
        v = [float(x) for x in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected six numbers x0,y0,z0,x1,y1,z1, got {text!r}") from None
    if not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"the box's numbers must be finite, got {text!r}")
    bad = [a for a, lo, hi in zip("xyz", v[:3], v[3:]) if lo > hi]
    if bad:
        raise argparse.ArgumentTypeError(f"the box's minimum is above its maximum on {', '.join(bad)} in {text!r} "
                                         "(x0,y0,z0 is the low corner, x1,y1,z1 the high one)")
    return Box(tuple(v[:3]), tuple(v[3:]))


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


def add_deprecated_alias(p: argparse.ArgumentParser, old: str, new: str, **kwargs) -> None:
    """``old``: a hidden spelling of the option ``new`` (same destination, type and value) kept for
    one release; using it warns (an InputWarning naming ``new``) and then acts as ``new``."""

    class Alias(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            import warnings

            from ..common.errors import InputWarning
            warnings.warn(InputWarning(f"{old} is deprecated and will be removed: use {new}"), stacklevel=2)
            setattr(namespace, self.dest, values)

    p.add_argument(old, dest=new.lstrip("-").replace("-", "_"), action=Alias, help=argparse.SUPPRESS, **kwargs)


def run_cli(prog: str, body, argv, interrupted_note: str = "") -> int:
    """Run ``body(argv)`` -> exit status under lghcc.app.cli_common's rule: an LghccError, a MemoryError
    or Ctrl-C raised inside becomes one line on stderr and its exit status (``exit_code_for``: 1, 3
    for an invalid stream, 4 for a resource limit, 130 interrupted). Outputs are written atomically,
    so an interrupt leaves no partial file behind. Other exceptions are bugs and propagate. An
    InputWarning (the input was read, with a caveat) is one line on stderr, each time it is raised."""
    import sys
    import warnings

    from .cli_common import report
    from ..common.errors import InputWarning, LghccError

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, InputWarning):
            print(f"{prog}: warning: {message}", file=sys.stderr, flush=True)
        else:
            shown(message, category, filename, lineno, file, line)

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", InputWarning)
            shown, warnings.showwarning = warnings.showwarning, show
            return body(argv)
    except (LghccError, MemoryError, KeyboardInterrupt) as e:
        return report(prog, e, "interrupted" + (f"; {interrupted_note}" if interrupted_note else ""))
