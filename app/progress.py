"""Progress of long steps, on a terminal and in logs (informative; no effect on any output).

``progress_bar`` takes tqdm's arguments. When stderr is a terminal it is tqdm's bar. When it
is not (a log file, a batch job, a pipe), a bar redrawn with carriage returns would reach the
log as one endless line or, with tqdm's defaults, nothing useful for minutes; there it prints
plain lines instead, at most one every ``LGHCC_PROGRESS_INTERVAL`` seconds (default 10), e.g.

    lghcc: fit GG-Conv: 40% (600/1500 step), 52 s elapsed, about 78 s left

and a last line when the step ends, if it printed any. ``disable=True`` prints nothing either way.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any, Iterable, Iterator

DEFAULT_INTERVAL_S = 10.0


def log_interval() -> float:
    """Seconds between two progress lines in a log (``LGHCC_PROGRESS_INTERVAL``, default 10)."""
    try:
        v = float(os.environ.get("LGHCC_PROGRESS_INTERVAL", DEFAULT_INTERVAL_S))
    except ValueError:
        return DEFAULT_INTERVAL_S
    return v if v >= 0 else DEFAULT_INTERVAL_S


def _seconds(s: float) -> str:
    s = max(0.0, s)
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


class LogProgress:
    """The part of tqdm's interface lghcc uses, printing plain lines (see the module doc)."""

    def __init__(self, iterable: Iterable | None = None, total: float | None = None, desc: str = "",
                 unit: str = "it", initial: float = 0, file: Any = None, interval: float | None = None,
                 **_ignored: Any) -> None:
        self.iterable = iterable
        if total is None and iterable is not None:
            try:
                total = len(iterable)  # type: ignore[arg-type]
            except TypeError:
                total = None
        self.total, self.desc, self.unit = total, desc, unit
        self.n = initial
        self._start_n = initial
        self.file = file
        self.interval = log_interval() if interval is None else interval
        self._t0 = self._last = time.monotonic()
        self._printed = False
        self._postfix = ""
        self._closed = False

    # -- tqdm's interface ----------------------------------------------------------------
    def __iter__(self) -> Iterator:
        try:
            for x in self.iterable or ():
                yield x
                self.update(1)
        finally:
            self.close()

    def __enter__(self) -> "LogProgress":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def update(self, n: float = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            self._emit(now)

    def set_postfix(self, ordered_dict: dict | None = None, refresh: bool = True, **kwargs: Any) -> None:
        items = {**(ordered_dict or {}), **kwargs}
        self._postfix = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self._postfix = str(s)

    def set_description(self, desc: str | None = None, refresh: bool = True) -> None:
        self.desc = desc or ""

    def write(self, s: str, file: Any = None, end: str = "\n") -> None:
        print(s, file=file or self._out(), end=end, flush=True)

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._printed:
            self._emit(time.monotonic(), done=True)

    # -------------------------------------------------------------------------------------
    def _out(self) -> Any:
        return self.file or sys.stderr

    def _emit(self, now: float, done: bool = False) -> None:
        elapsed = now - self._t0
        if self.total:
            frac = min(max(self.n / self.total, 0.0), 1.0)
            line = f"{self.desc}: {100 * frac:.0f}% ({self.n:g}/{self.total:g} {self.unit}), {_seconds(elapsed)} elapsed"
            done_here = self.n - self._start_n
            if not done and 0 < done_here and frac < 1:
                left = elapsed / done_here * (self.total - self.n)
                line += f", about {_seconds(left)} left"
        else:
            line = f"{self.desc}: {self.n:g} {self.unit}, {_seconds(elapsed)} elapsed"
        if done:
            line += ", done"
        if self._postfix:
            line += f" [{self._postfix}]"
        print(f"lghcc: {line}", file=self._out(), flush=True)
        self._printed = True


def _is_terminal(file: Any) -> bool:
    try:
        return bool(file.isatty())
    except (AttributeError, ValueError):
        return False


def progress_bar(iterable: Iterable | None = None, *, disable: bool = False, file: Any = None, **kwargs: Any) -> Any:
    """tqdm's bar on a terminal, ``LogProgress`` lines elsewhere, nothing with ``disable``."""
    from tqdm import tqdm

    if disable:
        return tqdm(iterable, disable=True, **kwargs)
    if _is_terminal(file or sys.stderr):
        return tqdm(iterable, file=file, **kwargs)
    return LogProgress(iterable, file=file, **kwargs)
