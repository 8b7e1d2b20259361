"""GPU engine for every bank (numba-cuda, fp64): the block driver's stages, one GPU thread per target.

The block driver (:func:`.block.run_rows`) runs a block of rows stage by stage (glitch screen,
each family's experts, the rule, the lead head), each stage a compiled driver
``kernel(lo, hi, ...)`` over a range of targets. This module's backend makes each stage one
kernel launch whose thread ``j`` calls the **same driver** with ``lo, hi = j, j + 1`` and its
own slice of the scratch, so the numbers are the CPU engine's and there is no third copy of the
algorithms. The state stays on the device from block to block; the work arrays (the experts'
forecasts of a block) never leave it. Targets beyond what fits in the device's memory run in chunks.
"""

from __future__ import annotations

import contextlib
import math
import time

import numba as nb
import numpy as np

from ..engine import Bank, BankState, EngineResult, check_restart, check_run_options, tree_map
from ._cache import JIT as _JIT
from .akf_driver import MAX_GPU_STATE
from .block import run_rows
from .drivers import driver
from .engine import prepare

try:  # numba-cuda is optional (the 'gpu' extra)
    from numba import boolean, cuda, float64
except ImportError:  # pragma: no cover - depends on the install
    cuda = None

__all__ = ["run", "GpuBackend", "THREADS_PER_BLOCK", "BUFFER_BYTES", "CHUNK_BYTES"]

_GUARD_ROWS = MAX_GPU_STATE + 1   # the AKF guard's scratch rows (the largest AKF state on the GPU, and one)

if cuda is not None:
    from numba.core.extending import overload

    from .. import _numba_linalg as la

    @overload(la.radius_le_eig, target="cuda")
    def _radius_le_on_gpu(theta, transition, p, n, bound, scratch, coef):
        """The guard's last word on a candidate whose roots lie within its band of the bound: no eigenvalues on
        a GPU, so the Schur-Cohn test on its characteristic polynomial ``coef`` at exactly the bound."""
        def impl(theta, transition, p, n, bound, scratch, coef):
            work = cuda.local.array((_GUARD_ROWS, 1), float64)
            saved = cuda.local.array((_GUARD_ROWS, 1), float64)
            norm = cuda.local.array(1, float64)
            inside = cuda.local.array(1, boolean)
            la.schur_cohn(coef, n, bound, work, saved, norm, inside, 1)
            return inside[0]
        return impl

THREADS_PER_BLOCK = 64
#: Upper bound of a block's expert forecasts on the device (rows x targets x experts x coordinates).
BUFFER_BYTES = 2 * 2**30
#: Upper bound of the device memory a chunk of targets takes (state, scratch, work arrays, outputs).
CHUNK_BYTES = 24 * 2**30
_kernels = {}


def _launcher(driver, n_args: int, n_scratch: int):
    """A kernel whose thread ``j < count`` runs ``driver(j, j + 1, *args)``, or with a scratch ``driver(j, j + 1,
    *args, tuple(s[j] for s in scratch))``, compiled on first use in this process (numba-cuda cannot cache it on
    disk: the AKF driver reshapes arrays, which links a helper file that its cache refuses)."""
    key = (driver, n_args, n_scratch)
    if key not in _kernels:
        names = [f"a{i}" for i in range(n_args)]
        scratch = [f"s{i}" for i in range(n_scratch)]
        own = "(" + "".join(f"{s}[j], " for s in scratch) + ")"   # this thread's scratch, one tuple
        source = (f"def kernel(count, {', '.join(names + scratch)}):\n"
                  "    j = cuda.grid(1)\n"
                  "    if j < count:\n"
                  f"        driver(j, j + 1, {', '.join(names + ([own] if scratch else []))})\n")
        namespace = {"cuda": cuda, "driver": driver}
        exec(compile(source, f"<kalmix gpu kernel of {driver.__name__}>", "exec"), namespace)  # noqa: S102
        _kernels[key] = cuda.jit(namespace["kernel"])
    return _kernels[key]


def _synchronize(name, start, stages):
    """With ``stages``: wait for the kernel just launched and add its seconds under ``name``."""
    if stages is None:
        return
    try:
        cuda.synchronize()
    except Exception as error:   # an error on the device shows at the next synchronisation: name the kernel
        raise RuntimeError(f"GPU kernel {name!r} failed: {error}") from error
    stages[name] = stages.get(name, 0.0) + time.perf_counter() - start


def _launch(driver, n: int, args, scratch=(), stages=None, name=None):
    start = time.perf_counter()
    kernel = _launcher(driver, len(args), len(scratch))
    kernel[max(1, math.ceil(n / THREADS_PER_BLOCK)), THREADS_PER_BLOCK](n, *args, *scratch)
    _synchronize(name or driver.__name__, start, stages)


# ---------------------------------------------------------------- device arrays, filled by drivers like the others
@nb.njit(**_JIT)
def _fill(lo, hi, value, array):
    """``array[:, j] = value`` (a C-contiguous ``(T, N, ...)`` array)."""
    rows, n = array.shape[0], array.shape[1]
    width = array.size // (rows * n)
    flat = array.reshape(array.size)
    for j in range(lo, hi):
        for t in range(rows):
            start = (t * n + j) * width
            for i in range(width):
                flat[start + i] = value


@nb.njit(**_JIT)
def _zero(lo, hi, array):
    """``array[j] = 0`` (a C-contiguous array with the target first, of two or more axes)."""
    for j in range(lo, hi):
        row = array[j]
        flat = row.reshape(row.size)
        for i in range(row.size):
            flat[i] = 0


def _device_array(shape, dtype):
    """An uninitialised device array (the drivers' work arrays: each target's rows written before read)."""
    return cuda.device_array(shape, dtype=dtype)


def _nan(shape, n):
    """A device array of ``shape`` (targets on axis 1) filled with NaN on the device."""
    array = cuda.device_array(shape)
    if array.size:
        _launch(_fill, n, (math.nan, array))
    return array


def _per_target(templates, n):
    """Device arrays ``(n,) + a.shape`` of each template's dtype, zeros (the drivers' scratch, one per target)."""
    arrays = tuple(cuda.device_array((n,) + a.shape, dtype=a.dtype) for a in templates)
    for array in arrays:
        _launch(_zero, n, (array,))
    return arrays


def _dev(tree):
    """Fresh device copies of a (named) tuple of arrays, nested ones too (scalars stay)."""
    return _same_type(tree, [_dev(a) if isinstance(a, tuple) else
                             cuda.to_device(np.ascontiguousarray(a)) if isinstance(a, np.ndarray) else a for a in tree])


def _host(tree):
    return _same_type(tree, [_host(a) if isinstance(a, tuple) else
                             a.copy_to_host() if hasattr(a, "copy_to_host") else a for a in tree])


def _same_type(tree, items):
    """``items`` as a tuple of ``tree``'s type (a named tuple stays one)."""
    return type(tree)(*items) if hasattr(tree, "_fields") else tuple(items)


def bytes_per_target(bank: Bank, t_count: int) -> int:
    """Rough device memory one target takes in one call: its state, the drivers' scratch, its rows of the
    inputs and outputs, its share of a block's forecasts."""
    from ..engine import init_bank_state

    state = init_bank_state(bank, 1)
    total = [0]
    tree_map(lambda a: total.__setitem__(0, total[0] + a.nbytes), state)
    k, p = bank.n_experts, bank.measurement_dim
    for family in bank.families:
        d = driver(family.kind)
        total[0] += sum(a.nbytes for a in d.scratch(family.params, p))
        total[0] += sum(a.nbytes for a in d.work_arrays(t_count, 1, family.params, p, True, _sized))
    return int(total[0] + t_count * (10 * p * 8 + 16) + t_count * k * p * 8 * 2 + 4096)


def _sized(shape, dtype):
    """An array of ``shape`` that takes no memory (for its ``nbytes``)."""
    return np.broadcast_to(np.zeros((), dtype), shape)


def run(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, restart=None, timings: dict | None = None,
        stages: dict | None = None) -> EngineResult:
    """:func:`kalmix.core.engine.run` on the GPU, any bank (see the module docstring); targets in chunks
    that fit :data:`CHUNK_BYTES`. ``timings``, if given, receives the seconds of the kernels alone
    (``"kernel"``) and of the whole call (``"total"``); ``stages`` the seconds of each kernel, by name
    (the launches then wait for each other, which costs a little)."""
    start = time.perf_counter()
    z, times, state, lengths, learn = prepare(bank, measurements, times, state, lengths, learn)
    _, ahead_times, ahead_frames = check_run_options(z.shape[:2], None, ahead_times, ahead_frames)
    t_count, n, _ = z.shape
    gaps = check_restart(restart, (t_count, n))
    if ahead_times is not None:
        ahead_times = np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n))
    chunk = max(1, CHUNK_BYTES // bytes_per_target(bank, t_count))
    clock = {"kernel": 0.0}
    if n <= chunk:
        result = _run_chunk(bank, z, times, state, lengths, learn, ahead_times, ahead_frames, gaps, clock, stages)
    else:
        parts = []
        for begin in range(0, n, chunk):
            g = slice(begin, min(begin + chunk, n))
            cut = lambda a: None if a is None else np.ascontiguousarray(a[:, g])  # noqa: E731
            parts.append(_run_chunk(bank, cut(z), cut(times), tree_map(lambda a: a[g], state), lengths[g],
                                    cut(learn), cut(ahead_times), ahead_frames, cut(gaps), clock, stages))
        fields = {}
        for name in EngineResult._fields:
            axis = 0 if name == "state" else 1
            fields[name] = tree_map(lambda *a: np.concatenate(a, axis=axis), *(getattr(part, name) for part in parts))
        result = EngineResult(**fields)
    if timings is not None:
        timings.update(kernel=clock["kernel"], total=time.perf_counter() - start)
    return result


def _run_chunk(bank, z, times, state, lengths, learn, ahead_times, ahead_frames, gaps, clock, stages) -> EngineResult:
    return run_rows(bank, GpuBackend(z.shape[1], clock, stages), z, times, state, lengths, learn, gaps, ahead_times,
                    ahead_frames)


class GpuBackend:
    """The block driver's backend on the GPU (:class:`.block.Backend`): device arrays; a stage one kernel launch,
    thread ``j`` running the driver on target ``j`` with its own scratch. ``clock["kernel"]`` adds the seconds of
    the block loop; ``stages``, if given, each stage's (the launches then wait for each other)."""

    def __init__(self, n: int, clock: dict, stages: dict | None):
        self.n = n
        self.buffer_bytes = BUFFER_BYTES
        self.block_targets = n
        self.clock, self.stages = clock, stages

    def put(self, tree):
        if isinstance(tree, tuple):
            return _dev(tree)
        return cuda.to_device(np.ascontiguousarray(tree)) if isinstance(tree, np.ndarray) else tree

    def host(self, tree):
        if isinstance(tree, tuple):
            return _host(tree)
        return tree.copy_to_host() if hasattr(tree, "copy_to_host") else tree

    def nan(self, shape):
        return _nan(shape, self.n)

    @staticmethod
    def empty(shape, dtype=np.float64):
        return _device_array(shape, dtype)

    def scratch(self, make):
        return _per_target(make(), self.n)

    def launch(self, name, kernel, args, scratch=None):
        _launch(kernel, self.n, args, () if scratch is None else scratch, self.stages, name)

    @staticmethod
    def each_family(run, costs):
        for i in range(len(costs)):
            run(i)

    @contextlib.contextmanager
    def timed(self):
        cuda.synchronize()
        launched = time.perf_counter()
        yield
        cuda.synchronize()
        self.clock["kernel"] += time.perf_counter() - launched
