"""Targets in parallel: a compiled kernel ``kernel(lo, hi, *args)`` over ranges of targets, on threads.

Every kernel of the compiled engine advances targets ``lo .. hi - 1`` of its arrays, and
targets are independent, so ranges run at once on a pool of Python threads (the kernels
are compiled ``nogil``): the same numbers as one call over every target. numba's
``parallel=True`` loops are not used: compiling them would take most of a fresh install's
first run.

The number of threads is numba's (``NUMBA_NUM_THREADS``, :func:`numba.set_num_threads`);
a call over few targets runs in the calling thread.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["over_targets", "splits", "over_groups", "families_in_parallel", "group_size", "MIN_CHUNK"]

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


def splits(n_targets: int) -> bool:
    """Whether :func:`over_targets` spreads ``n_targets`` over threads here (else it runs the kernel in the
    calling thread, as one range)."""
    return n_targets >= 2 * MIN_CHUNK and not getattr(_local, "inline", False) and _threads() > 1


def over_targets(kernel, n_targets: int, *args) -> None:
    """``kernel(lo, hi, *args)`` over ``[0, n_targets)`` in contiguous ranges, on up to numba's thread count."""
    if not splits(n_targets):
        kernel(0, n_targets, *args)
        return
    threads = _threads()
    # a few ranges per thread, taken in turn, so that targets of unequal lengths still share the work; as many
    # for each thread (7 ranges on 2 threads would leave one thread 4/7 of the work), each of at least
    # MIN_CHUNK targets
    per_thread = min(4, n_targets // (MIN_CHUNK * threads))
    pieces = threads * per_thread if per_thread else n_targets // MIN_CHUNK
    edges = [round(i * n_targets / pieces) for i in range(pieces + 1)]
    _drain([(lo, hi) for lo, hi in zip(edges[:-1], edges[1:]) if hi > lo], lambda r: kernel(r[0], r[1], *args),
           threads)


def families_in_parallel(n_targets: int) -> bool:
    """True when :func:`over_targets` would leave threads idle (too few targets to split) and this thread
    is not already one group of several: then a bank's families run side by side instead."""
    return _threads() > 1 and n_targets < 2 * MIN_CHUNK and not getattr(_local, "inline", False)


def group_size(n_targets: int, largest: int) -> int | None:
    """Targets a group for a run over groups of targets, each whole on one thread (:func:`over_groups`); None
    for one pass with each stage split over the threads (:func:`over_targets`).

    More than ``largest`` targets always run in groups of at most ``largest`` (a group's state
    stays in the caches). With several threads and enough targets to split, groups are also
    made small enough for about two a thread: a stage split over the threads waits for its
    slowest range, and the threads idle while this one does the Python work between stages;
    whole groups overlap one group's Python work with the others' kernels. Within a
    group (an ``inline`` thread) only the first rule applies. The groups are of equal size (to a
    target), and of at least :data:`MIN_CHUNK` targets unless ``largest`` is smaller.
    """
    count = -(-n_targets // largest)
    threads = _threads()
    if threads > 1 and not getattr(_local, "inline", False):
        count = max(count, min(2 * threads, n_targets // MIN_CHUNK))
    return -(-n_targets // count) if count > 1 else None


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
    results = [None] * len(groups)

    def one(item):
        results[item[0]] = function(item[1])

    _drain(list(enumerate(groups)), one, threads, inline=True)
    return results


def _drain(items, work, threads: int, inline: bool = False) -> None:
    """``work(item)`` for every item, taken in turn by ``threads`` workers, the calling thread one of them;
    with ``inline``, the workers' own kernels stay on their thread. Re-raises the first error."""
    queue = iter(items)
    take = threading.Lock()

    def worker():
        before = getattr(_local, "inline", False)
        _local.inline = inline or before
        try:
            while True:
                with take:
                    item = next(queue, None)
                if item is None:
                    return
                work(item)
        finally:
            _local.inline = before

    futures = [_executor().submit(worker) for _ in range(min(threads, len(items)) - 1)]
    try:
        worker()
    finally:
        for future in futures:
            future.result()
