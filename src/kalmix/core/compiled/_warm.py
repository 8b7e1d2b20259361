"""A fresh install's first run: the AKF kernel compiles in a second process while this one compiles the rest.

numba compiles a kernel the first time it is called, one kernel after another, in one
process; a fresh install (or a new kalmix version, whose sources key a new cache) pays
all of it on its first run. The AKF family's driver (:mod:`kalmix.core.compiled.akf`, which
inlines :mod:`kalmix.core._numba_kernels`' kernel) is most of that for the
default bank. numba holds a lock while it compiles, so threads cannot share the work;
processes can, through the cache: they write the same cache directory.

:func:`compile_ahead`, called by :func:`kalmix.core.compiled.engine.run` (which passes itself), does
this once per process when a bank has families whose drivers compile apart (their ``COMPILE_APART``:
the AKF's and the coordinated turns') and whose kernels are not in the cache yet, and the machine has at
least two cores: a child process compiles those kernels (each on one tiny track, with the family's
parameters) while this process compiles the other kernels of the bank (one tiny run of the bank without
the families that compile apart); then this process waits for the child and loads the kernels from the
cache. Every kernel is compiled once. If the child fails, this process compiles the kernels itself.
``KALMIX_BACKGROUND_COMPILE=0`` switches it off.

The child compiles at LLVM's ``-O2`` (``NUMBA_OPT=2``, unless ``NUMBA_OPT`` is set): the AKF kernel, most of
LLVM's work, compiles markedly faster there and runs as fast, to the same bits, as at numba's default ``-O3``
(the changelog has the figures). The other kernels are mostly numba's own passes, where ``-O2`` saves little,
so they keep the default. What compiles apart is chosen to balance the two processes' shares: with the AKF
kernel alone, this process had the longer one.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import os
import pickle
import subprocess
import sys
import threading

import numpy as np

from ._notice import compiling

__all__ = ["compile_ahead", "kernel_cached"]

#: Longest wait for the child (seconds); past it this process compiles the kernel itself.
WAIT_SECONDS = 600.0

_done = False
_lock = threading.RLock()   # the tiny run below calls the engine, which calls compile_ahead again
_children: set = set()   # running children, ended at exit (see _end_children)


@atexit.register
def _end_children() -> None:
    """A process that exits while its child still compiles (a thread waiting for it dies with the process:
    ``kalmix predict -`` warms up in one, and stdin may end at once) ends the child too, rather than leave it
    compiling for a minute after the command returned. numba writes a cache file whole, or not at all."""
    for child in list(_children):
        with contextlib.suppress(OSError):
            child.kill()


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def _kernel(family):
    from .drivers import driver

    return driver(family.kind).kernel


def _apart(family) -> bool:
    from .drivers import driver

    return driver(family.kind).COMPILE_APART


def kernel_cached(dispatcher) -> bool:
    """True when numba's cache holds an index for this dispatcher (or when that cannot be told)."""
    try:
        index = dispatcher._cache._cache_file._index_path
    except AttributeError:   # numba without a cache for it, or other internals: do nothing
        return True
    return os.path.exists(index)


def _eligible(bank) -> tuple:
    """The bank's families that compile apart (the AKF, the coordinated turns) whose kernels a child process should
    compile: those not in the cache yet; empty when no child should run."""
    if os.environ.get("KALMIX_BACKGROUND_COMPILE", "1") == "0" or os.environ.get("NUMBA_DISABLE_JIT") == "1":
        return ()
    apart = [f for f in bank.families if _apart(f)]
    if not apart or len(apart) == len(bank.families) or _cores() < 2:
        return ()
    kernels = {}
    for f in apart:   # a kernel once: its argument types do not depend on the family's sizes
        kernel = _kernel(f)
        if kernel not in kernels and not kernel_cached(kernel):
            kernels[kernel] = f
    return tuple(kernels.values())


def compile_ahead(bank, run) -> int | None:
    """Once per process: compile the kernels of the families that compile apart (the AKF's, the coordinated
    turns') in a child while this process compiles the others.

    ``run`` is the compiled engine's :func:`kalmix.core.compiled.engine.run`: this process compiles the bank's
    other kernels by running it on a tiny track. Returns the child's exit status (0: the kernel is in the cache),
    or None when no child ran.
    """
    global _done
    with _lock:
        if _done:
            return None
        _done = True
        families = _eligible(bank)
        if not families:
            return None
        try:
            child = subprocess.Popen([sys.executable, "-c", "from kalmix.core.compiled._warm import _child; _child()"],
                                     stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                     env={"NUMBA_OPT": "2", **os.environ})
            child.stdin.write(pickle.dumps(([(f.kind, f.params) for f in families], bank.measurement_dim)))
            child.stdin.close()
        except (OSError, pickle.PicklingError):
            return None
        _children.add(child)
        with compiling():   # the wait for the child is compile time too (the notice, ._notice)
            try:
                _tiny_run(dataclasses.replace(bank, families=tuple(f for f in bank.families if not _apart(f))), run)
            except Exception:   # noqa: BLE001 - only a warm-up: the real run compiles what is missing, and reports
                pass
            except BaseException:   # Ctrl-C or a stop signal: stop now, not after the child's compile
                _end(child)
                raise
            try:
                status = child.wait(timeout=WAIT_SECONDS)
            except subprocess.TimeoutExpired:
                status = _end(child)
            except BaseException:   # interrupted while waiting
                _end(child)
                raise
        _children.discard(child)
        return status


def _end(child) -> int:
    """Kill the child and reap it; its exit status. (numba writes a cache file whole, or not at all.)"""
    with contextlib.suppress(OSError):
        child.kill()
    status = child.wait()
    _children.discard(child)
    return status


def _reset() -> None:
    """Forget that :func:`compile_ahead` ran in this process (tests)."""
    global _done
    with _lock:
        _done = False


def _tiny_track(p: int, rows: int = 4):
    z = np.cumsum(np.random.default_rng(0).normal(size=(rows, 1, p)), axis=0)
    return z, np.arange(float(rows))[:, None]


def _tiny_run(bank, run) -> None:
    """The bank on a 4-row track through ``run``: compiles its kernels (the engine's argument types do not depend
    on sizes)."""
    z, t = _tiny_track(bank.measurement_dim)
    run(bank, z, t, ahead_times=None if bank.lead is not None else t + 1.0)


def _child() -> None:
    """The child process: families (their kinds and parameters, pickled on stdin with the measurement dimension)
    through their compiled drivers, as the engine runs them, one after another."""
    from ..families import parts
    from .drivers import driver
    from .stage import FamilyOut, family_rows

    families, p = pickle.loads(sys.stdin.buffer.read())
    z, t = _tiny_track(p)
    rows = len(z)
    block = family_rows(z, t, np.array([rows], dtype=np.int64), np.ones((rows, 1), dtype=bool),
                        np.zeros((rows, 1), dtype=bool), np.empty((0, 0)), 1)
    for kind, params in families:
        d, k = driver(kind), params.n_experts
        state = d.pack(params, parts(kind).spec.init_state(params, 1, p))
        d.kernel(0, 1, d.constants(params), state, block, FamilyOut(np.full((rows, 1, k, p), np.nan), 0,
                                                                     np.empty((0, 0, 0, 0))),
                 d.work_arrays(rows, 1, params, p, False), d.scratch(params, p))
