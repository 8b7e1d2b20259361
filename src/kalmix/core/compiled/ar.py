"""Compiled AR family (:mod:`kalmix.core.families.ar`): same formulas in the same order, targets in ranges on threads.

:func:`kernel` advances every target through its rows of a block: at each row it
writes every expert's forecast of the row into the bank's shared buffer at the family's
column ``offset``, then learns the row (a ``restart`` row starts the experts again from it);
with ``ahead_times`` it also writes the forecast made after the row for that time. The
module has the parts of every family's driver (:mod:`.kinematic` lists them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from .. import _numba_linalg as la
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .kinematic import step_delta   # the same clipped step in time units
# the parts every time-based family's driver shares
from .kinematic import check_gpu as check_gpu, pack as pack, unpack as unpack, work_arrays as work_arrays

configure_cache()

#: Relative cost of an expert's row (the engine hands the costliest family to a thread first).
COST = 2.0
#: The GPU staged engine's name for this family's stage.
NAME = "ar"
#: Whether a fresh install compiles the kernel in a second process (:mod:`._warm`): not this one.
COMPILE_APART = False


@nb.njit(**_JIT)
def bounded(value, bound):
    if math.isnan(value):
        return 0.0
    return min(max(value, -bound), bound)


@nb.njit(**_JIT)
def _regressor(order, bias, history_kc, x):
    for i in range(order):
        x[i] = history_kc[i]
    if bias:
        x[order] = 1.0


@nb.njit(**_JIT)
def _velocity(m, weights_kc, x, max_velocity):
    """:math:`\\hat v` of one expert and coordinate (the regressor already in ``x``)."""
    acc = weights_kc[0] * x[0]
    for j in range(1, m):
        acc = acc + weights_kc[j] * x[j]
    return bounded(acc, max_velocity)


#: Most rows of an iterated forecast (the spec's ``ITERATED_STEPS``; a test keeps them equal).
ITERATED_STEPS = 64


@nb.njit(**_JIT)
def _forecast(order, bias, m, delta, length_unit, max_velocity, weights_k, history_k, position_n, out, x, h):
    """Expert ``k``'s forecast ``delta`` time units ahead into ``out (p,)``: ``n`` rows of ``delta / n`` (``n``
    the rows in ``delta``), the model iterated (each velocity fed back, clipped to the largest one seen)."""
    rows = int(min(max(math.floor(delta + 0.5), 1.0), ITERATED_STEPS))
    step = delta / rows * length_unit
    for c in range(out.shape[0]):
        _regressor(order, bias, history_k[c], x)
        v = _velocity(m, weights_k[c], x, max_velocity)
        position = position_n[c] + v * step
        if rows > 1:
            bound = abs(v)
            for i in range(order):
                h[i] = history_k[c, i]
                bound = max(bound, abs(h[i]))
            for j in range(1, rows):
                for i in range(order - 1, 0, -1):
                    h[i] = h[i - 1]
                h[0] = v
                _regressor(order, bias, h, x)
                v = min(max(_velocity(m, weights_k[c], x, max_velocity), -bound), bound)
                position = position + v * step
        out[c] = position


@nb.njit(**KERNEL_JIT)
def _start(order, m, persistence, initial_error, weights_k, info_k, target_k, history_k, scale, weight, error,
           count, jumps, n, k):
    """Fresh expert: prior weights, zero statistics and history, the error's pseudo-sample."""
    for c in range(weights_k.shape[0]):
        for i in range(m):
            weights_k[c, i] = persistence if i == 0 else 0.0
            target_k[c, i] = 0.0
            for j in range(m):
                info_k[c, i, j] = 0.0
        for i in range(order):
            history_k[c, i] = 0.0
    scale[n, k] = 0.0
    weight[n, k] = 0.0
    error[n, k] = initial_error
    count[n, k] = 1.0
    jumps[n, k] = 0.0


@nb.njit(**KERNEL_JIT)
def _learn(order, bias, m, forgetting, ridge, persistence, jump_threshold, window, max_velocity, v, weights_n,
           info_n, target_n, history_n, scale, weight, error, count, jumps, n, x, a, rhs, low, sol, acc, go,
           new_scale, informative):
    """Every expert of target ``n`` learns the velocity ``v (p,)``: the jump test, then the fit (or not).

    Each expert's arithmetic is the spec's, in its order; the experts are only interleaved: first each one's
    jump test and running statistics, then, coordinate by coordinate, the information matrices of those that
    learn and one Cholesky solve over all of them (:func:`kalmix.core._numba_linalg.cholesky_solve_rows`, a
    pivot below 0 taken as 0)."""
    p = v.shape[0]
    k_count = forgetting.shape[0]
    vv = v[0] * v[0]
    for c in range(1, p):
        vv = vv + v[c] * v[c]
    for k in range(k_count):
        squared = 0.0
        for c in range(p):
            _regressor(order, bias, history_n[k, c], x)
            err = v[c] - _velocity(m, weights_n[k, c], x, max_velocity)
            squared = err * err if c == 0 else squared + err * err
        squared = squared / p
        wild = squared > jump_threshold**2 * error[n, k]   # inf x 0 (no test, no error yet): not wild
        jump = wild and jumps[n, k] < 1
        jumps[n, k] = jumps[n, k] + 1.0 if jump else 0.0
        go[k] = not jump
        if jump:
            continue
        new_weight = forgetting[k] * weight[n, k] + 1.0
        new_scale[k] = scale[n, k] + (vv / p - scale[n, k]) / new_weight
        scale[n, k] = new_scale[k]
        weight[n, k] = new_weight
        new_count = min(count[n, k] + 1.0, window)
        error[n, k] = error[n, k] + (squared - error[n, k]) / new_count
        count[n, k] = new_count
    for c in range(p):
        for k in range(k_count):
            informative[k] = False
            if not go[k]:  # a harmless system, solved and thrown away
                for i in range(m):
                    for j in range(m):
                        a[i, j, k] = 1.0 if i == j else 0.0
                    rhs[0, i, k] = 0.0
                continue
            lam = forgetting[k]
            info_kc = info_n[k, c]
            target_kc = target_n[k, c]
            _regressor(order, bias, history_n[k, c], x)
            largest = 0.0
            for i in range(m):
                for j in range(m):
                    info_kc[i, j] = lam * info_kc[i, j] + x[i] * x[j]
                target_kc[i] = lam * target_kc[i] + x[i] * v[c]
                largest = info_kc[i, i] if i == 0 else max(largest, info_kc[i, i])
            ridge_k = ridge[k] * new_scale[k] + 1e-9 * largest + 1e-12
            for i in range(m):
                for j in range(m):
                    a[i, j, k] = info_kc[i, j] + (ridge_k if i == j else 0.0)
                rhs[0, i, k] = target_kc[i] + ridge_k * (persistence if i == 0 else 0.0)
                informative[k] = informative[k] or x[i] != 0.0
        la.cholesky_solve_rows(a, m, rhs, 1, low, sol, acc, True)
        for k in range(k_count):
            if not go[k]:
                continue
            if informative[k]:  # a zero regressor keeps the weights exactly (the spec's note)
                for i in range(m):
                    weights_n[k, c, i] = sol[0, i, k]
            for i in range(order - 1, 0, -1):
                history_n[k, c, i] = history_n[k, c, i - 1]
            history_n[k, c, 0] = v[c]


class Constants(NamedTuple):
    """The family's parameters as :func:`kernel` takes them."""

    order: int
    bias: bool
    forgetting: np.ndarray   # (K,)
    ridge: np.ndarray        # (K,)
    length_unit: float
    time_unit: float
    persistence: float
    initial_error: float
    jump_threshold: float
    window: float
    max_step: float
    max_velocity: float


def constants(params) -> Constants:
    """The family's parameters as :func:`kernel` takes them."""
    return Constants(int(params.order), bool(params.bias), np.asarray(params.forgetting), np.asarray(params.ridge),
                     float(params.length_unit), float(params.time_unit), float(params.persistence),
                     float(params.initial_error), float(params.jump_threshold), float(params.window),
                     float(params.max_step), float(params.max_velocity))


def scratch(params, p: int) -> tuple:
    """One target's scratch of :func:`kernel`: x, v, h and :func:`_learn`'s for the experts of ``m`` weights
    (a, rhs, low, sol, acc, go, new_scale, informative)."""
    order, k_count = params.order, params.n_experts
    m = order + (1 if params.bias else 0)
    return (np.empty(m), np.empty(p), np.empty(order), np.empty((m, m, k_count)), np.empty((1, m, k_count)),
            np.zeros((m, m, k_count)), np.empty((1, m, k_count)), np.empty(k_count),
            np.empty(k_count, dtype=np.bool_), np.empty(k_count), np.empty(k_count, dtype=np.bool_))


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, rows, forecasts, work, scratch):
    """The driver: targets ``lo .. hi - 1`` through their rows of the block (:mod:`.kinematic` lists the
    arguments; ``rows.horizon``, the frame-based families' clock, is not read)."""
    # The default bank's orders as constants of the compiled loops, so that LLVM unrolls them (the helpers are
    # not inlined by numba: its inlining of _learn into five copies would multiply the compile time; LLVM
    # inlines them); other orders and the bias as they come. The same operations in the same order: the same
    # bits.
    order, bias = params.order, params.bias
    if not bias and order == 1:
        _drive(lo, hi, 1, False, params, state, rows, forecasts, scratch)
    elif not bias and order == 2:
        _drive(lo, hi, 2, False, params, state, rows, forecasts, scratch)
    elif not bias and order == 3:
        _drive(lo, hi, 3, False, params, state, rows, forecasts, scratch)
    elif not bias and order == 5:
        _drive(lo, hi, 5, False, params, state, rows, forecasts, scratch)
    else:
        _drive(lo, hi, order, bias, params, state, rows, forecasts, scratch)


@nb.njit(inline="always", **_JIT)
def _drive(lo, hi, order, bias, params, state, rows, forecasts, scratch):
    (_, _, forgetting, ridge, length_unit, time_unit, persistence, initial_error, jump_threshold, window, max_step,
     max_velocity) = params
    weights, info, target, history, scale, weight, error, count, jumps, position, last_time, initialised = state
    z, times, lengths, learn, restart, ahead_times, _ = rows
    out, offset, out_ahead = forecasts
    x, v, h, a, rhs, low, sol, acc, go, new_scale, informative = scratch
    k_count = forgetting.shape[0]
    p = z.shape[2]
    m = order + (1 if bias else 0)
    want_ahead = out_ahead.shape[0] > 0
    for n in range(lo, hi):
        for t in range(lengths[n]):
            # every expert's forecast of this row, then its learning (a restart row starts it again)
            started = initialised[n]
            delta = step_delta(times[t, n], last_time[n], time_unit, max_step)
            for k in range(k_count):
                if started:
                    _forecast(order, bias, m, delta, length_unit, max_velocity, weights[n, k], history[n, k],
                              position[n], out[t, n, offset + k], x, h)
                else:
                    for c in range(p):
                        out[t, n, offset + k, c] = np.nan
            if learn[t, n]:
                if restart[t, n] or not started:
                    for k in range(k_count):
                        _start(order, m, persistence, initial_error, weights[n, k], info[n, k], target[n, k],
                               history[n, k], scale, weight, error, count, jumps, n, k)
                elif delta > 0:
                    for c in range(p):
                        v[c] = bounded((z[t, n, c] - position[n, c]) / delta / length_unit, max_velocity)
                    _learn(order, bias, m, forgetting, ridge, persistence, jump_threshold, window, max_velocity, v,
                           weights[n], info[n], target[n], history[n], scale, weight, error, count, jumps, n, x, a, rhs,
                           low, sol, acc, go, new_scale, informative)
                for c in range(p):
                    position[n, c] = z[t, n, c]
                last_time[n] = times[t, n]
                initialised[n] = True
            elif restart[t, n]:  # a restart on a missing row: start from the next present one
                initialised[n] = False
            # forecast made after this row, for a later time
            if want_ahead:
                ahead_delta = step_delta(ahead_times[t, n], last_time[n], time_unit, max_step)
                for k in range(k_count):
                    if initialised[n]:
                        _forecast(order, bias, m, ahead_delta, length_unit, max_velocity, weights[n, k],
                                  history[n, k], position[n], out_ahead[t, n, offset + k], x, h)
                    else:
                        for c in range(p):
                            out_ahead[t, n, offset + k, c] = np.nan
