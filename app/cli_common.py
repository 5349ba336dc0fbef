"""What every lghcc command-line program does with a failure (informative, not part of the spec):
one line on stderr, never a traceback, and an exit status that tells the kind of failure apart,
so that scripts and conformance harnesses can act on it without parsing messages.

One rule for lghcc-enc, lghcc-dec, lghcc-conformance, lghcc-train and lghcc-view (``exit_code_for``):

    0    success
    1    error in the input or the environment: an input file that cannot be read or used, an
         output that cannot be written, a bad option value found after parsing (LghccError,
         InputError)
    2    usage error: the command line is wrong (argparse), or wrong for this input (UsageError:
         lghcc-dec --level 1 on a stream without the hierarchy, which has no preview)
    3    invalid stream: the bitstream is malformed, unsupported or does not decode to its own
         hash (BitstreamError and its subclasses UnsupportedStreamError, HashMismatchError)
    4    resource limit: the work needs more than this run may use (ResourceLimitError from
         --max-memory or --max-points; a MemoryError from the system)
    130  interrupted (Ctrl-C); outputs are written atomically (lghcc.app.fileio), so an
         interrupted run leaves no partial file behind

lghcc-conformance uses 1 for its verdict (a stream FAILed); see its --help.
"""

from __future__ import annotations

import functools
import sys
from typing import Callable

from ..common.errors import BitstreamError, LghccError, ResourceLimitError, UsageError

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_INVALID_STREAM = 3
EXIT_RESOURCE_LIMIT = 4
EXIT_INTERRUPTED = 130

EXIT_CODES = {EXIT_OK: "success", EXIT_ERROR: "error in the input or the environment (a file, an option value)",
              EXIT_USAGE: "usage error (the command line is wrong)",
              EXIT_INVALID_STREAM: "invalid stream (malformed, unsupported, or its decoded-scene hash does not match)",
              EXIT_RESOURCE_LIMIT: "resource limit (--max-memory, --max-points, or the system ran out of memory)",
              EXIT_INTERRUPTED: "interrupted (Ctrl-C); no partial output is left"}


def exit_status_epilog(overrides: dict[int, str] | None = None, codes: tuple[int, ...] | None = None) -> str:
    """The 'exit status' paragraph of a program's --help (``codes``: the ones it can return;
    ``overrides``: program-specific meanings)."""
    table = dict(EXIT_CODES)
    table.update(overrides or {})
    lines = ["exit status:"] + [f"  {c:<4} {table[c]}" for c in (codes or tuple(table))]
    return "\n".join(lines)


def exit_code_for(exc: BaseException) -> int:
    """The exit status of a failure (module docstring); EXIT_ERROR for any other LghccError."""
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED
    if isinstance(exc, (ResourceLimitError, MemoryError)):
        return EXIT_RESOURCE_LIMIT
    if isinstance(exc, BitstreamError):
        return EXIT_INVALID_STREAM
    if isinstance(exc, UsageError):
        return EXIT_USAGE
    return EXIT_ERROR


def exit_code_for_class(name: str) -> int:
    """The exit status of an error class named in lghcc.common.errors (as a conformance test.yaml
    names it): what an external decoder following this rule exits with for it."""
    from ..common import errors

    cls = getattr(errors, name, None)
    if not (isinstance(cls, type) and issubclass(cls, LghccError)):
        raise ValueError(f"{name!r} is not an error class of lghcc.common.errors")
    return exit_code_for(cls("probe"))


def message_for(exc: BaseException) -> str:
    """The one-line message of a failure."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, MemoryError):
        return "out of memory (the system refused an allocation); try a smaller input or --max-memory"
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def with_prefix(exc: LghccError, prefix: str) -> LghccError:
    """The same error class with ``prefix: `` before its message (e.g. the stream's path), so that
    adding context never changes the exit status."""
    try:
        out = type(exc)(f"{prefix}: {exc}")
    except TypeError:  # a subclass with another constructor: keep the class, message as is
        return exc
    if hasattr(exc, "condition"):  # a BitstreamError keeps the clause-8.2 condition it names
        out.condition = exc.condition
    return out


def report(prog: str, exc: BaseException, interrupted: str | None = None) -> int:
    """Print the one line for ``exc`` on stderr and return its exit status."""
    msg = (interrupted or "interrupted") if isinstance(exc, KeyboardInterrupt) else message_for(exc)
    print(f"{prog}: error: {msg}" if not isinstance(exc, KeyboardInterrupt) else f"{prog}: {msg}",
          file=sys.stderr, flush=True)
    return exit_code_for(exc)


def guarded(prog: str, interrupted: str | None = None) -> Callable:
    """Decorator for a ``main(argv) -> int``: an LghccError, a MemoryError or Ctrl-C raised inside
    becomes one line on stderr and its exit status (``exit_code_for``); ``interrupted`` replaces
    the word 'interrupted' (e.g. with how to resume). Other exceptions are bugs and propagate."""
    def wrap(main: Callable) -> Callable:
        @functools.wraps(main)
        def run(*args, **kwargs) -> int:
            try:
                return main(*args, **kwargs)
            except (LghccError, MemoryError, KeyboardInterrupt) as e:
                return report(prog, e, interrupted)
        return run
    return wrap


_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_memory_size(text: str) -> int | None:
    """A memory amount as a user writes it: '512M', '8G', '1.5GiB', '4096' (bytes), 'none' or '0'
    (no bound, None). Binary units: K = 2^10 ... T = 2^40; a trailing 'B' or 'iB' is allowed.
    ValueError with the text otherwise."""
    t = text.strip().upper().replace(" ", "")
    if t in ("NONE", "0", "UNLIMITED"):
        return None
    for suffix in ("IB", "B"):
        if t.endswith(suffix) and len(t) > len(suffix) and t[-len(suffix) - 1] in "KMGT0123456789.":
            t = t[:-len(suffix)]
            break
    unit = t[-1:] if t[-1:] in "KMGT" else ""
    number = t[:-1] if unit else t
    try:
        value = float(number)
    except ValueError:
        raise ValueError(f"expected a memory amount such as 512M, 8G or 4096 (bytes), got {text!r}") from None
    if not value > 0 or value != value or value == float("inf"):
        raise ValueError(f"a memory amount must be positive, got {text!r}")
    return int(value * _UNITS[unit])


def memory_size(text: str) -> int | None:
    """argparse type of --max-memory (``parse_memory_size``), a usage error when malformed."""
    import argparse

    try:
        return parse_memory_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def format_bytes(n: int) -> str:
    """1.5 GiB, 512.0 MiB, 4,096 bytes: an amount as a message shows it."""
    for unit, size in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:,} bytes"
