"""GPU engine (numba-cuda, fp64): :func:`run` runs any bank on an NVIDIA GPU with the CPU engine's numbers.

Two ways, chosen by :func:`run`:

- **one fused kernel** (:func:`run_fused`) for banks of kinematic families (CV, CA) with no lead
  head: each thread runs its target's rows with the whole row fused (glitch screen, every
  expert's forecast, the rule's weights and mixture, the learning) by calling the **same per-row
  functions** as the CPU engine (:func:`.screen.screen_row`, :func:`.kinematic.step_expert`, the
  rules of :mod:`.rules`). On the device every per-expert array has the target index last
  (``(K, 3, p, N)``), so the threads of a warp read neighbouring addresses.
- **the staged engine** (:mod:`.gpu_staged`) for every other bank (AKF, AR, turn families, the
  lead head, restart rows): each of the CPU engine's stages is a kernel whose thread ``j`` runs
  the CPU driver on target ``j``.

Either way the code that runs is the CPU engine's own, compiled for the GPU, and the contract
tests run it under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) in CI. One difference:
the AKF guard's rare last word on a candidate within its band of the bound uses the Schur-Cohn
test at the bound on the GPU (no eigenvalue routine there), eigenvalues on the CPU.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..calibration import CalibrationState
from ..engine import Bank, BankState, EngineResult
from ..families.kinematic import KinematicState
from ..screen import ScreenState
from . import gpu_staged
from . import kinematic as ckin
from . import rules as crules
from . import screen as cscreen
from .calibration import calibrate_row, learns
from .calibration import pack_params as pack_calibration
from .drivers import driver
from .reach import sleep_beyond, sleep_cold

if not hasattr(np, "row_stack"):  # numba-cuda 0.30 registers an overload of np.row_stack, gone from numpy 2.4+
    np.row_stack = np.vstack
try:  # numba-cuda is optional (the 'gpu' extra)
    from numba import boolean, cuda, float64
except ImportError:  # pragma: no cover - depends on the install
    cuda = None

__all__ = ["run", "gpu_available", "MAX_EXPERTS", "THREADS_PER_BLOCK"]

MAX_EXPERTS = 64
THREADS_PER_BLOCK = 128
_kernel_cache = {}
forecast_expert, step_expert, delta_of = ckin.forecast_expert, ckin.step_expert, ckin.step_delta
screen_row, last_learned = cscreen.screen_row, cscreen.last_learned
forecast_row, write_row, learn_rule, cold_row = crules.forecast_row, crules.write_row, crules.learn_row, crules.cold_row
restart_row, rule_column = crules.restart_row, crules.column


def gpu_available() -> bool:
    """True when numba-cuda finds a GPU (or the CUDA simulator is on)."""
    if cuda is None:
        return False
    return bool(os.environ.get("NUMBA_ENABLE_CUDASIM") == "1" or cuda.is_available())


def _body(experts, expert_state, rule_params, rule_state, screen_params, screen_state, calibration,
          calibration_state, block, outputs):
    """One thread's target through its rows; the arguments are tuples of the parts each stage owns (:func:`run_fused`
    packs them): the experts' parameters and state, the rule's, the glitch screen's, the calibration's, the block's
    rows and the outputs."""
    orders, warm, far, q, r, initial, time_unit, max_step, max_variance, reach = experts
    mean, cov, last_time, initialised = expert_state
    threshold, max_rejects, warmup, window = screen_params
    position, velocity, seen, spread, count, rejects, outliers, points, low, high = screen_state
    cal_window, cal_rate, cal_level, z_level, cal_max_variance, max_log_scale, cal_initial, from_points = calibration
    variance, n_errors, log_scale = calibration_state
    z, times, lengths, learn, ahead_times = block
    out, out_std, out_ahead, out_ahead_std = outputs
    n = cuda.grid(1)
    if n >= z.shape[1]:
        return
    k_count = orders.shape[0]
    p = z.shape[2]
    want_ahead = out_ahead.shape[0] > 0
    x_all = cuda.local.array((MAX_EXPERTS, 3), float64)
    awake_all = cuda.local.array(MAX_EXPERTS, boolean)
    w_all = cuda.local.array(MAX_EXPERTS, float64)
    logw_all = cuda.local.array(MAX_EXPERTS, float64)
    r_all = cuda.local.array(MAX_EXPERTS, float64)
    mix_all = cuda.local.array(3, float64)
    cov_all = cuda.local.array((3, 3), float64)
    m_pred = cuda.local.array((3, 3), float64)
    c_pred = cuda.local.array((3, 3), float64)
    f = cuda.local.array((3, 3), float64)
    work = cuda.local.array((3, 3), float64)
    gain = cuda.local.array(3, float64)
    amat = cuda.local.array((3, 3), float64)
    x = x_all[:k_count, :p]
    awake = awake_all[:k_count]
    w = w_all[:k_count]
    logw = logw_all[:k_count]
    rr = r_all[:k_count]
    mix = mix_all[:p]
    sigma = cov_all[:p, :p]
    rule = rule_column(rule_state, n)   # this target's rule state (the target last on the device)
    ls = log_scale[n:n + 1]
    var_n = variance[:, :, n]
    errors_n = n_errors[:, n]
    for t in range(lengths[n]):
        before = last_learned(seen, points, n)   # the spec's engine.span
        rows = points[n]   # and learned rows (engine.warmed_up)
        code = screen_row(threshold, max_rejects, warmup, window, position, velocity, seen, spread, count,
                          rejects, outliers, points, low, high, n, z[t, n], times[t, n], learn[t, n], False)
        # every expert's forecast of the row, and its learning from the same extrapolation
        learning = code == 1 or code == 2 or code == 4
        fresh = code == 2 or not initialised[n]
        for k in range(k_count):
            delta = delta_of(times[t, n], last_time[n], time_unit[k], max_step)
            step_expert(orders[k], delta, q[k], r[k], initial[k], max_variance, initialised[n], learning, fresh,
                        z[t, n], mean[k, :, :, n], cov[k, :, :, n], x[k], m_pred, c_pred, f, work, gain, amat)
        if learning:
            initialised[n] = True
            last_time[n] = times[t, n]
        sleep_cold(warm, x, rows)
        sleep_beyond(far, x, times[t, n] - before, reach)
        awake_count = forecast_row(rule_params, rule, x, awake, w, logw, rr, mix, var_n, ls[0], cal_max_variance,
                                   sigma)
        write_row(awake_count, mix, sigma, out[t, n], out_std[t, n])
        if code == 1 and awake_count > 0:
            if learns(from_points, rows):
                calibrate_row(x, z[t, n], awake, awake_count, mix, sigma, var_n, errors_n, ls, cal_window, cal_rate,
                              cal_level, z_level, cal_max_variance, max_log_scale)
            learn_rule(rule_params, rule, x, z[t, n], awake, awake_count, w, logw, mix, rr)
        if code == 2:   # a restart: the experts start again, and so does BOA's error scale
            restart_row(rule)
        if code == 4:   # a cold restart: forecast by the old rule and calibration, which start again
            cold_row(rule, var_n, errors_n, ls, cal_initial)
        if want_ahead:
            for k in range(k_count):
                if initialised[n]:
                    delta = delta_of(ahead_times[t, n], last_time[n], time_unit[k], max_step)
                    forecast_expert(orders[k], delta, q[k], r[k], max_variance, mean[k, :, :, n], cov[k, :, :, n], x[k],
                                    m_pred, c_pred, f, work)
                else:
                    for ci in range(p):
                        x[k, ci] = math.nan
            sleep_cold(warm, x, points[n])
            sleep_beyond(far, x, ahead_times[t, n] - last_learned(seen, points, n), reach)
            awake_count = forecast_row(rule_params, rule, x, awake, w, logw, rr, mix, var_n, ls[0], cal_max_variance,
                                       sigma)
            write_row(awake_count, mix, sigma, out_ahead[t, n], out_ahead_std[t, n])


def _kernel():
    """The kernel, compiled on first use (numba-cuda compiles per argument types)."""
    if "kernel" not in _kernel_cache:
        _kernel_cache["kernel"] = cuda.jit(_body)
    return _kernel_cache["kernel"]


def check_bank(bank: Bank) -> None:
    """Raise ``ValueError`` unless the GPU engine can run ``bank``: every family and rule runs there, except
    those its driver's ``check_gpu`` refuses (AKF families whose guard needs eigenvalues, a prior with more
    than ``MAX_CLUSTER`` roots at 1, or whose state is over :data:`.akf_driver.MAX_GPU_STATE`)."""
    for family in bank.families:
        driver(family.kind).check_gpu(family.params)


def fused(bank: Bank, restart=None) -> bool:
    """Whether the one-kernel engine (:func:`run_fused`, faster) runs ``bank``: kinematic families only, at most
    :data:`MAX_EXPERTS` experts, 1 to 3 coordinates, no lead head, no restart rows given."""
    return (all(driver(f.kind) is ckin for f in bank.families) and bank.n_experts <= MAX_EXPERTS
            and bank.measurement_dim <= 3 and bank.lead is None and restart is None)


def run(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, restart=None, timings: dict | None = None) -> EngineResult:
    """:func:`kalmix.core.engine.run` on the GPU (fp64): same arguments and numbers (see the module docstring).

    ``restart (T, N)`` rows start a target's experts again (:func:`kalmix.core.engine.run`'s);
    ``timings``, if given, receives the seconds of the kernels alone (``"kernel"``) and of the
    whole call (``"total"``). ``ValueError`` for a bank the GPU cannot run (:func:`check_bank`),
    ``RuntimeError`` when no GPU is found.
    """
    check_bank(bank)
    if not gpu_available():
        raise RuntimeError("backend 'gpu': no CUDA GPU found (numba-cuda sees none); use the CPU engine")
    if fused(bank, restart):
        return run_fused(bank, measurements, times, state, lengths=lengths, learn=learn, ahead_times=ahead_times,
                         ahead_frames=ahead_frames, timings=timings)
    return gpu_staged.run(bank, measurements, times, state, lengths=lengths, learn=learn, ahead_times=ahead_times,
                          ahead_frames=ahead_frames, restart=restart, timings=timings)


def _pack_families(bank: Bank, states, n: int, p: int):
    k = bank.n_experts
    orders = np.empty(k, np.int64)
    q, r, tu = np.empty(k), np.empty(k), np.empty(k)
    initial = np.zeros((k, 3))
    mean, cov = np.zeros((n, k, 3, p)), np.zeros((n, k, 3, 3))
    columns = bank.slices()
    for family, state, cols in zip(bank.families, states, columns):
        fp, d = family.params, family.params.order
        orders[cols], q[cols], r[cols], tu[cols] = d, fp.process_noise, fp.measurement_noise, fp.time_unit
        initial[cols, :d] = fp.initial_variance
        mean[:, cols, :d], cov[:, cols, :d, :d] = state.mean, state.cov
    first = states[0]
    for state in states[1:]:
        if not (np.array_equal(state.initialised, first.initialised)
                and np.array_equal(state.last_time, first.last_time, equal_nan=True)):
            raise ValueError("backend 'gpu': the kinematic families' clocks differ (a state not made by the engine)")
    params = bank.families[0].params
    return (orders, q, r, initial, tu, float(params.max_step), float(params.max_variance), mean, cov,
            first.last_time.astype(np.float64).copy(), first.initialised.astype(np.bool_).copy())


def _far(bank: Bank) -> np.ndarray:
    """The experts that sleep across a step over the reach (:meth:`~kalmix.core.engine.Bank.far_experts`; none when
    it says none ever does)."""
    far = bank.far_experts()
    return np.zeros(bank.n_experts, dtype=np.bool_) if far is None else far


def _warm(bank: Bank) -> np.ndarray:
    """The experts' warm-up rows (:meth:`~kalmix.core.engine.Bank.warmup_rows`; empty when no expert ever sleeps
    for it)."""
    warm = bank.warmup_rows()
    return np.zeros(0) if warm is None else warm


def run_fused(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, threads_per_block: int = THREADS_PER_BLOCK,
        timings: dict | None = None) -> EngineResult:
    """The one-kernel engine: :func:`kalmix.core.engine.run` for banks where :func:`fused` holds.

    ``timings``, if given, receives the seconds spent in the kernel alone (``"kernel"``)
    and in the whole call with the transfers (``"total"``).
    """
    import time

    start = time.perf_counter()
    from .engine import pack_rule, pack_rule_params, prepare, unpack_rule

    if not fused(bank):
        raise ValueError("run_fused: kinematic banks of at most 64 experts, 1 to 3 coordinates, no lead head")
    z, times, state, lengths, learn = prepare(bank, measurements, times, state, lengths, learn)
    t_count, n, p = z.shape
    (orders, q, r, initial, tu, max_step, max_variance, mean, cov, last_time,
     initialised) = _pack_families(bank, state.families, n, p)
    rule = pack_rule(bank, state.rule)
    scr = [np.array(x, dtype=np.float64, copy=True, order="C") for x in state.screen]
    cal = [np.array(x, dtype=np.float64, copy=True, order="C") for x in state.calibration]
    sp = bank.screen_params
    with_ahead = ahead_times is not None
    ahead_host = (np.ascontiguousarray(np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n)))
                  if with_ahead else np.empty((0, 0)))
    # target index last on the device: neighbouring threads read neighbouring addresses (coalesced)
    soa = lambda array: np.ascontiguousarray(np.moveaxis(array, 0, -1))  # noqa: E731
    # the rule's per-expert arrays (N, K) as (K, N), its per-target ones (N,) as they are
    rule_dev = type(rule)(*(cuda.to_device(soa(a) if a.ndim == 2 else a) for a in rule))
    device = {name: cuda.to_device(value) for name, value in dict(
        orders=orders, warm=_warm(bank), far=_far(bank), q=q, r=r, initial=initial, tu=tu, mean=soa(mean), cov=soa(cov),
        last_time=last_time,
        initialised=initialised, z=z, times=times, lengths=lengths,
        learn=np.ascontiguousarray(learn), ahead_times=ahead_host, variance=soa(cal[0]), n_errors=soa(cal[1]),
        log_scale=cal[2]).items()}
    screen_dev = [cuda.to_device(x) for x in scr]
    out, out_std = cuda.device_array((t_count, n, p)), cuda.device_array((t_count, n, p))
    out_ahead = cuda.device_array((t_count, n, p) if with_ahead else (0, 0, 0))
    out_ahead_std = cuda.device_array((t_count, n, p) if with_ahead else (0, 0, 0))
    blocks = max(1, math.ceil(n / threads_per_block))
    kernel = _kernel()
    cuda.synchronize()
    launched = time.perf_counter()
    kernel[blocks, threads_per_block](
        (device["orders"], device["warm"], device["far"], device["q"], device["r"], device["initial"], device["tu"],
         max_step, max_variance, float(bank.reach)),
        (device["mean"], device["cov"], device["last_time"], device["initialised"]),
        pack_rule_params(bank), rule_dev,
        (float(sp.threshold), float(sp.max_rejects), float(sp.warmup), float(sp.window)), tuple(screen_dev),
        pack_calibration(bank.calibration_params),
        (device["variance"], device["n_errors"], device["log_scale"]),
        (device["z"], device["times"], device["lengths"], device["learn"], device["ahead_times"]),
        (out, out_std, out_ahead, out_ahead_std))
    cuda.synchronize()
    kernel_seconds = time.perf_counter() - launched
    rows = np.arange(t_count)[:, None] < lengths[None, :]
    forecasts, std = out.copy_to_host(), out_std.copy_to_host()
    forecasts[~rows] = std[~rows] = np.nan
    ahead = ahead_std = None
    if with_ahead:
        ahead, ahead_std = out_ahead.copy_to_host(), out_ahead_std.copy_to_host()
        ahead[~rows] = ahead_std[~rows] = np.nan
    aos = lambda array: np.ascontiguousarray(np.moveaxis(array, -1, 0))  # noqa: E731
    mean, cov = aos(device["mean"].copy_to_host()), aos(device["cov"].copy_to_host())
    last_time, initialised = device["last_time"].copy_to_host(), device["initialised"].copy_to_host()
    families = []
    for family, cols in zip(bank.families, bank.slices()):
        dd = family.params.order
        families.append(KinematicState(np.ascontiguousarray(mean[:, cols, :dd]),
                                       np.ascontiguousarray(cov[:, cols, :dd, :dd]), last_time.copy(),
                                       initialised.copy()))
    rule_state = unpack_rule(bank, type(rule)(*(aos(a.copy_to_host()) if a.ndim == 2 else a.copy_to_host()
                                                for a in rule_dev)))
    screen_state = ScreenState(*(x.copy_to_host() for x in screen_dev))
    calibration = CalibrationState(aos(device["variance"].copy_to_host()), aos(device["n_errors"].copy_to_host()),
                                   device["log_scale"].copy_to_host())
    if timings is not None:
        timings.update(kernel=kernel_seconds, total=time.perf_counter() - start)
    return EngineResult(forecasts, BankState(tuple(families), rule_state, screen_state, calibration), ahead,
                        std=std, ahead_std=ahead_std)
