"""GPU engine for every bank (numba-cuda, fp64): the CPU engine's stages, one GPU thread per target.

The CPU engine (:mod:`.engine`) runs a block of rows stage by stage (glitch screen, each
family's experts, the rule, the lead head), each stage a driver ``kernel(lo, hi, ...)``
over a range of targets. Here each stage is one kernel launch whose thread ``j`` calls the
**same driver** with ``lo, hi = j, j + 1`` and its own slice of the scratch, so the numbers
are the CPU engine's and there is no third copy of the algorithms. The state stays on the
device from block to block; the work arrays (the experts' forecasts of a block) never leave it.

The glue between stages (which rows learn, the experts asleep across a long step) is done
by small kernels below. Targets beyond what fits in the device's memory run in chunks.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..calibration import CalibrationState
from ..engine import Bank, BankState, EngineResult, check_restart, check_run_options, tree_map
from ..lead import LeadState
from ..screen import ScreenState
from . import lead as clead
from . import reach as creach
from . import rules as crules
from . import screen as cscreen
from ._cache import JIT as _JIT
from .akf_driver import MAX_GPU_STATE
from .calibration import pack_params as pack_calibration
from .drivers import driver
from .engine import pack_rule, pack_rule_params, prepare, unpack_rule, with_lead

try:  # numba-cuda is optional (the 'gpu' extra)
    from numba import boolean, cuda, float64
except ImportError:  # pragma: no cover - depends on the install
    cuda = None

__all__ = ["run", "THREADS_PER_BLOCK", "BUFFER_BYTES", "CHUNK_BYTES"]

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
    """A kernel whose thread ``j < count`` runs ``driver(j, j + 1, *args, *(s[j] for s in scratch))``, compiled
    on first use in this process (numba-cuda cannot cache it on disk: the AKF driver reshapes arrays, which
    links a helper file that its cache refuses)."""
    key = (driver, n_args, n_scratch)
    if key not in _kernels:
        names = [f"a{i}" for i in range(n_args)]
        scratch = [f"s{i}" for i in range(n_scratch)]
        source = (f"def kernel(count, {', '.join(names + scratch)}):\n"
                  "    j = cuda.grid(1)\n"
                  "    if j < count:\n"
                  f"        driver(j, j + 1, {', '.join(names + [s + '[j]' for s in scratch])})\n")
        namespace = {"cuda": cuda, "driver": driver}
        exec(compile(source, f"<kalmix gpu kernel of {driver.__name__}>", "exec"), namespace)  # noqa: S102
        _kernels[key] = cuda.jit(namespace["kernel"])
    return _kernels[key]


def _synchronize(name, start, stages):
    """With ``stages``: wait for the kernel just launched and add its seconds under ``name``."""
    if stages is None:
        return
    import time

    try:
        cuda.synchronize()
    except Exception as error:   # an error on the device shows at the next synchronisation: name the kernel
        raise RuntimeError(f"GPU kernel {name!r} failed: {error}") from error
    stages[name] = stages.get(name, 0.0) + time.perf_counter() - start


def _launch(driver, n: int, args, scratch=(), stages=None, name=None):
    import time

    start = time.perf_counter()
    kernel = _launcher(driver, len(args), len(scratch))
    kernel[max(1, math.ceil(n / THREADS_PER_BLOCK)), THREADS_PER_BLOCK](n, *args, *scratch)
    _synchronize(name or driver.__name__, start, stages)


# ---------------------------------------------------------------- the glue between stages, drivers like the others
@nb.njit(**_JIT)
def _glue(lo, hi, learn, accept, restart, cold, lengths, learned, go):
    """The rows the experts learn (``learned``) and the rules learn (``go``): the CPU engine's ``learn & accept``
    and ``learned & ~restart & ~cold``."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            learned[t, j] = learn[t, j] and accept[t, j]
            go[t, j] = learned[t, j] and not restart[t, j] and not cold[t, j]


@nb.njit(**_JIT)
def _both(lo, hi, a, b, lengths, out):
    """``out = a & b`` on the targets' rows."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            out[t, j] = a[t, j] and b[t, j]


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
    import time

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
    import time

    t_count, n, p = z.shape
    k = bank.n_experts
    lead = bank.lead
    ahead_times, ahead_frames = with_lead(bank, times, ahead_times, ahead_frames)
    with_ahead = ahead_times is not None
    horizon = ahead_frames if with_ahead else 1
    if gaps is None:
        gaps = np.zeros((t_count, n), dtype=bool)
    d_z, d_times = cuda.to_device(z), cuda.to_device(np.ascontiguousarray(times))
    d_learn, d_gaps = cuda.to_device(np.ascontiguousarray(learn)), cuda.to_device(np.ascontiguousarray(gaps))
    d_ahead_times = cuda.to_device(np.ascontiguousarray(ahead_times)) if with_ahead else cuda.device_array((0, 0))

    drivers = [driver(family.kind) for family in bank.families]
    constants = [_dev(d.constants(family.params)) for d, family in zip(drivers, bank.families)]
    families = [_dev(d.pack(family.params, fstate)) for d, family, fstate in zip(drivers, bank.families,
                                                                                  state.families)]
    scratch = [_per_target(d.scratch(family.params, p), n) for d, family in zip(drivers, bank.families)]
    rule = _dev(pack_rule(bank, state.rule))
    rule_params = pack_rule_params(bank)
    rule_scratch = _per_target(crules.scratch(k, p), n)
    cal_args = pack_calibration(bank.calibration_params)
    initial_variance = float(bank.calibration_params.initial_variance)
    cal = _dev(state.calibration)
    if lead is not None:
        lead_rule = _dev(pack_rule(bank, state.lead.rule))
        lead_params = pack_rule_params(bank, bank.lead_rule_params)
        lead_cal = _dev(state.lead.calibration)
        slots = _dev((state.lead.due, state.lead.pending, state.lead.issued, state.lead.candidates))
        blend = _dev(pack_rule(bank, state.lead.blend))
        blend_params = pack_rule_params(bank, bank.blend_rule_params)
        blend_scratch = _per_target(clead.blend_scratch(p), n)
    scr = _dev(state.screen)
    sp = bank.screen_params
    screen_args = (float(sp.threshold), float(sp.max_rejects), float(sp.warmup), float(sp.window))

    forecasts, std = _nan((t_count, n, p), n), _nan((t_count, n, p), n)
    ahead, ahead_std = (_nan((t_count, n, p), n), _nan((t_count, n, p), n)) if with_ahead else (None, None)
    lead_out, lead_std = (_nan((t_count, n, p), n), _nan((t_count, n, p), n)) if lead is not None else (None, None)
    empty4, empty3, empty2 = cuda.device_array((0, 0, 0, 0)), cuda.device_array((0, 0, 0)), cuda.device_array((0, 0))
    offsets = [cols.start for cols in bank.slices()]
    far = bank.far_experts()
    d_far = cuda.to_device(far) if far is not None else None
    per_row = n * k * p * 8 * (2 if with_ahead else 1)
    block = int(max(1, min(t_count, BUFFER_BYTES // max(per_row, 1))))
    flags = {name: cuda.device_array((block, n), dtype=np.bool_)
             for name in ("accept", "restart", "started", "cold", "learned", "go")}
    spans = {name: cuda.device_array((block, n)) for name in ("before", "after")}
    cuda.synchronize()
    launched = time.perf_counter()
    for begin in range(0, t_count, block):
        end = min(begin + block, t_count)
        rows = end - begin
        lens = cuda.to_device(np.clip(lengths - begin, 0, rows).astype(np.int64))
        zb, tb = d_z[begin:end], d_times[begin:end]
        f = {name: a[:rows] for name, a in flags.items()}
        before, after = spans["before"][:rows], spans["after"][:rows]
        _launch(cscreen.screen_block, n, (*screen_args, *scr, zb, tb, lens, d_learn[begin:end], d_gaps[begin:end],
                                          f["accept"], f["restart"], f["started"], f["cold"], before, after),
                stages=stages, name="screen")
        _launch(_glue, n, (d_learn[begin:end], f["accept"], f["restart"], f["cold"], lens, f["learned"], f["go"]),
                stages=stages)
        lb = f["learned"]
        buffer = _nan((rows, n, k, p), n)
        ahead_buffer = _nan((rows, n, k, p), n) if with_ahead else empty4
        ahead_b = d_ahead_times[begin:end] if with_ahead else empty2
        for i, (d, family) in enumerate(zip(drivers, bank.families)):
            work = d.work_arrays(rows, n, family.params, p, horizon > 1, _device_array)
            _launch(d.kernel, n, (*constants[i], *families[i], zb, tb, lens, lb, f["restart"], buffer, offsets[i],
                                  ahead_b, ahead_buffer, horizon, *work), scratch[i], stages=stages, name=d.NAME)
        mixed, mixed_ahead = buffer, ahead_buffer
        if far is not None:
            mixed = cuda.device_array(buffer.shape)
            _launch(creach.kernel, n, (d_far, float(bank.reach), buffer, tb, before, lens, mixed), stages=stages,
                    name="reach")
            if with_ahead:
                mixed_ahead = cuda.device_array(buffer.shape)
                _launch(creach.kernel, n, (d_far, float(bank.reach), ahead_buffer, ahead_b, after, lens, mixed_ahead),
                        stages=stages, name="reach")
        _launch(crules.kernel, n, (rule_params, rule, *cal_args, *cal, mixed, zb, lens, f["go"],
                                       forecasts[begin:end], std[begin:end], empty4, empty3, mixed_ahead,
                                       ahead[begin:end] if with_ahead else empty3,
                                       ahead_std[begin:end] if with_ahead else empty3, f["cold"], f["restart"],
                                       initial_variance),
                rule_scratch, stages=stages, name="rules")
        if lead is not None:
            keep = cuda.device_array(lb.shape, dtype=np.bool_)
            _launch(_both, n, (lb, f["started"], lens, keep), stages=stages)
            _launch(clead.kernel, n, (lead_params, lead_rule, blend_params, blend, *cal_args, *lead_cal, ahead_b,
                                      float(lead.tolerance), *slots, ahead_buffer, ahead[begin:end], zb, tb, lens,
                                      f["go"], keep, f["restart"], lead_out[begin:end], lead_std[begin:end], empty4,
                                      f["cold"], initial_variance),
                    (*rule_scratch, *blend_scratch), stages=stages, name="lead")
    cuda.synchronize()
    clock["kernel"] += time.perf_counter() - launched
    out = [d.unpack(_host(fs), fstate) for d, fs, fstate in zip(drivers, families, state.families)]
    head = None
    if lead is not None:
        due, pending, issued, candidates = _host(slots)
        head = LeadState(unpack_rule(bank, _host(lead_rule)), CalibrationState(*_host(lead_cal)), due, pending,
                         issued, unpack_rule(bank, _host(blend)), candidates)
    final = BankState(tuple(out), unpack_rule(bank, _host(rule)), ScreenState(*_host(scr)),
                      CalibrationState(*_host(cal)), head)
    get = lambda a: None if a is None else a.copy_to_host()  # noqa: E731
    return EngineResult(get(forecasts), final, get(ahead), None, None, None, get(std), get(ahead_std), get(lead_out),
                        get(lead_std), None, None)
