"""Views rendered two at a time in threads of one process (informative; the encoder's render loops).

A view's render is a few hundred torch operations, of which the sort, the bincount, the
index_add and the Python between them run on one core: one view at a time used the 2 cores of the
1M-Gaussian encode 1.35x on average (tools/results/scale.md). Two views in two threads fill each
other's gaps (torch lets go of the GIL in its operations).

Each thread runs torch's operations with the caller's intra-op thread count, so every operation
splits its work as it does in the caller, and a view's result has the bits it has when the views
are rendered one after another (tests/test_render_view_threads.py): the results come back in the
views' order and are summed by the caller in that order. Threads, not processes, for that reason:
a worker process would need the caller's thread count too, and the 1M scene's tensors besides.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

T = TypeVar("T")
R = TypeVar("R")

# Views rendered at a time (at most the cores): two leave a view's one-core stretches to the other.
VIEW_THREADS = 2
# The most memory one view's render may take for views to go two at a time (``map_views``): two at
# once take twice a view's memory (the 1M-Gaussian sensitivities 3,139 MiB over the scene's instead
# of 1,600, tools/results/scale.md), and the encoder's peak is to stay at 4 GiB at 1M.
VIEW_MEMORY_BUDGET = 1 << 30


def view_threads() -> int:
    """The threads ``map_views`` renders in: VIEW_THREADS, at most the machine's cores."""
    return max(1, min(VIEW_THREADS, os.cpu_count() or 1))


def map_views(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None,
              view_bytes: float = 0.0) -> Iterator[R]:
    """``fn`` of each item (a view), ``threads`` (default ``view_threads()``; one where a view takes
    more than VIEW_MEMORY_BUDGET, ``view_bytes`` its estimate) at a time, yielded in the items'
    order as each is done; with one thread, one after another in the caller's thread.
    At most 2 ``threads`` views are done or under way beyond the one the caller holds (memory stays
    bounded).
    ``fn`` runs in the grad mode and with the intra-op threads of this call's moment (torch's grad
    mode is per thread: ``torch.no_grad`` around the call reaches the threads)."""
    items = list(items)
    threads = view_threads() if threads is None else max(1, threads)
    if view_bytes > VIEW_MEMORY_BUDGET:
        threads = 1
    if threads == 1 or len(items) <= 1:
        return (fn(x) for x in items)
    intra, grad = torch.get_num_threads(), torch.is_grad_enabled()

    def run(x: T) -> R:
        if torch.get_num_threads() != intra:  # the caller's split of every operation: the same bits
            torch.set_num_threads(intra)
        with torch.set_grad_enabled(grad):
            return fn(x)

    return _in_threads(run, items, threads)


def _in_threads(run: Callable[[T], R], items: list[T], threads: int) -> Iterator[R]:
    window = 2 * threads  # queued beyond the running ones: a thread done before the view in front goes on
    try:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="lghcc-view") as pool:
            pending = [pool.submit(run, x) for x in items[:window]]
            for i in range(len(items)):
                result = pending.pop(0).result()
                if i + window < len(items):
                    pending.append(pool.submit(run, items[i + window]))
                yield result
    finally:
        release_freed_memory()


def release_freed_memory() -> None:
    """Give the memory the view threads freed back to the system (glibc's malloc_trim; elsewhere
    nothing): glibc keeps each thread's freed blocks in that thread's arena, and after the 1M
    scene's contributions two at a time they held 800 MiB that the sensitivities after them could
    not use (peak 2,894 MiB instead of 2,100)."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)


@functools.cache
def _libc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.malloc_trim  # noqa: B018 - glibc only (musl has none)
    except (OSError, AttributeError):
        return None
    return libc
