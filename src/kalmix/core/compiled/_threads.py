"""Targets in parallel: a compiled kernel ``kernel(lo, hi, *args)`` over ranges of targets, on threads.

Every kernel of the compiled engine advances targets ``lo .. hi - 1`` of its arrays, and
targets are independent, so ranges run at once on a pool of Python threads (the kernels
are compiled ``nogil``): the same numbers as one call over every target. This replaces
numba's ``parallel=True`` loops, whose compilation took more than half of a fresh
install's first run (103 s of the 1,000-row ``kalmix predict``, 48 s without them).

The number of threads is numba's (``NUMBA_NUM_THREADS``, :func:`numba.set_num_threads`);
a call over few targets runs in the calling thread.
"""

from __future__ import annotations

import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["over_targets", "over_groups", "MIN_CHUNK"]

#: Fewest targets a thread is given: below twice this, the kernel runs in the calling thread.
MIN_CHUNK = 16
_pool: ThreadPoolExecutor | None = None
_lock = threading.Lock()
_local = threading.local()   # ``inline``: this thread runs one group of targets; its kernels stay on it


def _threads() -> int:
    try:
        import numba

        return max(1, int(numba.get_num_threads()))
    except ImportError:  # pragma: no cover - the kernels need numba anyway
        return os.cpu_count() or 1


def _executor() -> ThreadPoolExecutor:
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=os.cpu_count() or 1, thread_name_prefix="kalmix-targets")
        return _pool


def over_targets(kernel, n_targets: int, *args) -> None:
    """``kernel(lo, hi, *args)`` over ``[0, n_targets)`` in contiguous ranges, on up to numba's thread count."""
    threads = _threads()
    if threads == 1 or n_targets < 2 * MIN_CHUNK or getattr(_local, "inline", False):
        kernel(0, n_targets, *args)
        return
    # a few ranges per thread, taken in turn, so that targets of unequal lengths still share the work;
    # ``threads`` workers (the calling thread is one) drain one queue of ranges
    pieces = min(4 * threads, math.ceil(n_targets / MIN_CHUNK))
    edges = [round(i * n_targets / pieces) for i in range(pieces + 1)]
    ranges = iter([(lo, hi) for lo, hi in zip(edges[:-1], edges[1:]) if hi > lo])
    take = threading.Lock()

    def drain():
        while True:
            with take:
                piece = next(ranges, None)
            if piece is None:
                return
            kernel(piece[0], piece[1], *args)

    futures = [_executor().submit(drain) for _ in range(min(threads, pieces) - 1)]
    try:
        drain()
    finally:
        for future in futures:
            future.result()


def over_groups(function, groups) -> list:
    """``[function(g) for g in groups]``, the groups on up to numba's thread count of threads at once.

    Each group runs whole on one thread (its kernels do not split it further), so a group's
    Python work (masks, copies) overlaps with the other groups' kernels. Results are in the
    order of ``groups``.
    """
    groups = list(groups)
    threads = min(_threads(), len(groups))
    if threads <= 1 or getattr(_local, "inline", False):
        return [function(group) for group in groups]

    def one(group):
        _local.inline = True
        try:
            return function(group)
        finally:
            _local.inline = False

    return list(_executor().map(one, groups))
