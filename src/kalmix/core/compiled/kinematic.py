"""Compiled kinematic family (:mod:`kalmix.core.families.kinematic`): same formulas, targets in ranges on threads.

:func:`kernel` advances every target through its rows of a block: at each row it
writes every expert's forecast of the row into the bank's shared buffer at the family's
column ``offset``, then learns the row (a ``restart`` row starts the filters again from it, keeping the mean
velocity across the gap where the spec does);
with ``ahead_times`` it also writes the forecast made after the row for that time.

A family's driver module (this one, :mod:`.ar`, :mod:`.turn`, :mod:`.akf_driver`; the registry
:data:`kalmix.core.families.KINDS` names it) has the same parts, which the CPU engine, the GPU
staged engine and the compile warm-up use alike:

- ``constants(params)``: the parameters as :func:`kernel` takes them (this module's :class:`Constants`);
- ``pack(params, state)`` / ``unpack(packed, like)``: the state as the kernel advances it in place
  (fresh copies, the spec's state class) and back;
- ``scratch(params, p)``: one target's scratch (a tuple); ``work_arrays(rows, n, params, p, later, allocate)``:
  a block's work arrays (a tuple; none here);
- ``kernel(lo, hi, params, state, rows, out, work, scratch)``: targets ``lo .. hi - 1`` through the block's
  ``rows`` (:class:`.stage.FamilyRows`), writing their experts' forecasts into ``out``
  (:class:`.stage.FamilyOut`), allocating nothing (one GPU thread runs it with ``lo, hi = j, j + 1``; a
  time-based family ignores ``rows.horizon``, a frame-based one the times);
- ``check_gpu(params)``: ``ValueError`` if the GPU cannot run the family; ``COST``: the relative
  cost of an expert's row; ``NAME``: the GPU stage's name; ``COMPILE_APART``: the kernel compiles
  in a second process on a fresh install (:mod:`._warm`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from ..families import kinematic as _spec
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache

configure_cache()
_FACT = (1.0, 1.0, 2.0)

#: Relative cost of an expert's row (the engine hands the costliest family to a thread first).
COST = 1.0
#: The GPU staged engine's name for this family's stage.
NAME = "kinematic"
#: Whether a fresh install compiles the kernel in a second process (:mod:`._warm`): not this one.
COMPILE_APART = False


@nb.njit(**_JIT)
def sandwich(order, left, middle, out, work):
    """``out = left @ middle @ left.T`` on the leading ``order x order`` block."""
    for i in range(order):
        for j in range(order):
            acc = 0.0
            for l in range(order):
                acc += left[i, l] * middle[l, j]
            work[i, j] = acc
    for i in range(order):
        for j in range(order):
            acc = 0.0
            for l in range(order):
                acc += work[i, l] * left[j, l]
            out[i, j] = acc


@nb.njit(**_JIT)
def symmetrise(order, matrix):
    for i in range(order):
        for j in range(i + 1, order):
            s = 0.5 * (matrix[i, j] + matrix[j, i])
            matrix[i, j] = s
            matrix[j, i] = s


@nb.njit(**_JIT)
def _extrapolate(order, delta, q, mean, cov, m_out, c_out, f, work):
    """``m_out = F mean``; ``c_out = F cov F^T + q Q(delta)`` (symmetrised), for one expert."""
    p = mean.shape[1]
    for i in range(order):
        for j in range(order):
            f[i, j] = 0.0
        f[i, i] = 1.0
        if i + 1 < order:
            f[i, i + 1] = delta
    if order == 3:
        f[0, 2] = 0.5 * delta * delta
    for i in range(order):
        for c in range(p):
            acc = 0.0
            for j in range(order):
                acc += f[i, j] * mean[j, c]
            m_out[i, c] = acc
    sandwich(order, f, cov, c_out, work)
    for i in range(order):
        for j in range(order):
            a = order - 1 - i
            b = order - 1 - j
            m = a + b + 1
            c_out[i, j] = c_out[i, j] + q * delta**m / (m * _FACT[a] * _FACT[b])
    symmetrise(order, c_out)


@nb.njit(inline="always", **_JIT)
def step_delta(time, last, time_unit, max_step):
    delta = (time - last) / time_unit
    if not math.isfinite(delta):
        return 0.0
    return min(max(delta, 0.0), max_step)


@nb.njit(inline="always", **_JIT)
def forecast_expert(order, delta, q, r, max_variance, mean_k, cov_k, out, m_pred, c_pred, f, work):
    """Expert ``k``'s forecast ``delta`` steps after its state into ``out (p,)``; returns its variance."""
    _extrapolate(order, delta, q, mean_k, cov_k, m_pred, c_pred, f, work)
    for c in range(out.shape[0]):
        out[c] = m_pred[0, c]
    return min(c_pred[0, 0], max_variance) + r


#: The spec's restart threshold on the innovation's NIS (1e6 standard deviations).
RESTART_NIS = float(_spec.RESTART_NIS)
#: The spec's bound on the NIS of a restart that keeps the mean velocity across the gap.
CARRY_NIS = float(_spec.CARRY_NIS)


@nb.njit(**_JIT)
def _absurd(z, mean_k, m_pred, s):
    """The measurement is more than 1e6 standard deviations from the forecast (or the forecast is not finite).
    Asked only once the filter has learned a velocity (its velocity variance below the initial one): the second
    row after a start is judged against the initial velocity spread, which a fast target in small length units
    exceeds by far, and it would restart on every row. And only when the miss is at least half the motion the
    filter forecast (``m_pred - mean_k``): a glitch, or the slope one left, is; the lag of a filter behind a
    very fast target in small units is a small part of its motion."""
    nis = 0.0
    miss = 0.0
    move = 0.0
    for c in range(z.shape[0]):
        e = z[c] - m_pred[0, c]
        nis = nis + e * e / s
        miss = miss + e * e
        d = m_pred[0, c] - mean_k[0, c]
        move = move + d * d
    return not nis <= RESTART_NIS and not miss <= 0.25 * move


@nb.njit(**_JIT)
def _start(order, initial_k, z, mean_k, cov_k):
    for i in range(order):
        for c in range(z.shape[0]):
            mean_k[i, c] = z[c] if i == 0 else 0.0
        for j in range(order):
            cov_k[i, j] = initial_k[i] if i == j else 0.0


@nb.njit(**_JIT)
def _carry(order, delta, q, initial_k, z, mean_k, cov_k, m_pred, s):
    """A restart ``delta`` steps after ``mean_k, cov_k`` (extrapolated to ``m_pred``, innovation variance
    ``s``) that keeps the mean velocity across the gap (the spec's ``carried_start``): writes it and returns
    True, or returns False (the state unchanged) where the spec starts as at a first measurement."""
    if not delta > 0.0:
        return False
    nis = 0.0
    for c in range(z.shape[0]):
        e = z[c] - m_pred[0, c]
        nis = nis + e * e / s
    r0 = initial_k[0]
    variance = (cov_k[0, 0] + r0) / (delta * delta)
    if order == 2:
        variance = variance + q * delta / 3.0
    else:
        variance = variance - cov_k[0, 2] + delta * delta / 4.0 * cov_k[2, 2] + 2.0 * q * delta * delta * delta / 15.0
    cross = r0 / delta
    if not (math.isfinite(variance) and math.isfinite(cross) and nis <= CARRY_NIS * z.shape[0]):
        return False
    for c in range(z.shape[0]):
        if not math.isfinite((z[c] - mean_k[0, c]) / delta):
            return False
    for c in range(z.shape[0]):
        velocity = (z[c] - mean_k[0, c]) / delta
        for i in range(order):
            mean_k[i, c] = z[c] if i == 0 else (velocity if i == 1 else 0.0)
    for i in range(order):
        for j in range(order):
            cov_k[i, j] = initial_k[i] if i == j else 0.0
    cov_k[1, 1] = variance
    cov_k[0, 1] = cross
    cov_k[1, 0] = cross
    return True


@nb.njit(**_JIT)
def _update(order, r, max_variance, z, mean_k, cov_k, m_pred, c_pred, work, gain, a):
    """Joseph-form update of the extrapolated ``m_pred, c_pred`` with ``z`` into ``mean_k, cov_k``."""
    p = z.shape[0]
    s = c_pred[0, 0] + r
    for i in range(order):
        gain[i] = c_pred[i, 0] / s
    for c in range(p):
        innovation = z[c] - m_pred[0, c]
        for i in range(order):
            mean_k[i, c] = m_pred[i, c] + gain[i] * innovation
    # Joseph form: A P A^T + r g g^T, A = I - g e0^T
    for i in range(order):
        for j in range(order):
            a[i, j] = (1.0 if i == j else 0.0) - (gain[i] if j == 0 else 0.0)
    sandwich(order, a, c_pred, cov_k, work)
    for i in range(order):
        for j in range(order):
            cov_k[i, j] = cov_k[i, j] + r * gain[i] * gain[j]
    symmetrise(order, cov_k)
    excess = cov_k[0, 0] / max_variance
    if excess > 1.0:
        for i in range(order):
            for j in range(order):
                cov_k[i, j] /= excess


@nb.njit(inline="always", **_JIT)
def step_expert(order, delta, q, r, initial_k, max_variance, started, learn, fresh, z, mean_k, cov_k, out,
                m_pred, c_pred, f, work, gain, a):
    """One row for expert ``k``: its forecast into ``out (p,)`` (NaN before its start), then, if ``learn``,
    the update with ``z`` from that same extrapolation (or a fresh start at ``z``). Returns the forecast's
    variance (NaN before the start)."""
    variance = np.nan
    if started:
        _extrapolate(order, delta, q, mean_k, cov_k, m_pred, c_pred, f, work)
        for c in range(out.shape[0]):
            out[c] = m_pred[0, c]
        variance = min(c_pred[0, 0], max_variance) + r
    else:
        for c in range(out.shape[0]):
            out[c] = np.nan
    if learn:
        if fresh and started:   # a restart: the mean velocity across the gap kept where it can be
            if not _carry(order, delta, q, initial_k, z, mean_k, cov_k, m_pred, c_pred[0, 0] + r):
                _start(order, initial_k, z, mean_k, cov_k)
        elif fresh or not started or (cov_k[1, 1] < initial_k[1] and _absurd(z, mean_k, m_pred, c_pred[0, 0] + r)):
            _start(order, initial_k, z, mean_k, cov_k)
        else:
            _update(order, r, max_variance, z, mean_k, cov_k, m_pred, c_pred, work, gain, a)
    return variance


class Constants(NamedTuple):
    """The family's parameters as :func:`kernel` takes them."""

    order: int              # 2: constant velocity, 3: constant acceleration
    q: np.ndarray           # (K,) process noise
    r: np.ndarray           # (K,) measurement noise
    initial: np.ndarray     # (K, order) initial variances
    time_unit: float
    max_step: float
    max_variance: float


def constants(params) -> Constants:
    """The family's parameters as :func:`kernel` takes them."""
    return Constants(int(params.order), np.asarray(params.process_noise), np.asarray(params.measurement_noise),
                     np.asarray(params.initial_variance), float(params.time_unit), float(params.max_step),
                     float(params.max_variance))


def pack(params, state):
    """A time-based family's state as its kernel advances it in place: fresh C-contiguous copies of its arrays, as
    the spec's state class."""
    return type(state)(*(np.array(a, copy=True, order="C") for a in state))


def unpack(packed, like):
    """The state :func:`pack` packed, as the family's state class (that of ``like``)."""
    return type(like)(*packed)


def work_arrays(rows: int, n: int, params, p: int, later: bool, allocate=np.empty) -> tuple:
    """A time-based family's kernel has no work arrays of a block."""
    return ()


def check_gpu(params) -> None:
    """The GPU runs every time-based family."""


def scratch(params, p: int) -> tuple:
    """One target's scratch of :func:`kernel`: m_pred, c_pred, f, work, gain, a."""
    order = params.order
    square = lambda: np.empty((order, order))  # noqa: E731
    return np.empty((order, p)), square(), square(), square(), np.empty(order), square()


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, rows, out, work, scratch):
    """The driver: targets ``lo .. hi - 1`` through their rows of the block (module docstring)."""
    # The order (2: CV, 3: CA; kalmix.core.engine.Family refuses others) as a constant of the compiled loops, so
    # that LLVM unrolls them (the helpers are not inlined by numba, whose inlining of two copies would triple the
    # compile time; LLVM inlines them). The same operations in the same order: the same bits.
    if params.order == 2:
        _drive(lo, hi, 2, params, state, rows, out, scratch)
    else:
        _drive(lo, hi, 3, params, state, rows, out, scratch)


@nb.njit(inline="always", **_JIT)
def _drive(lo, hi, order, params, state, rows, out, scratch):
    _, q, r, initial, time_unit, max_step, max_variance = params
    mean, cov, last_time, initialised = state
    z, times, lengths, learn, restart, ahead_times, _ = rows
    experts, offset, out_ahead = out
    m_pred, c_pred, f, work, gain, a = scratch
    k_count = q.shape[0]
    p = z.shape[2]
    want_ahead = out_ahead.shape[0] > 0
    for n in range(lo, hi):
        for t in range(lengths[n]):
            # every expert's forecast of this row, then its learning (a restart row starts it again)
            learning = learn[t, n]
            fresh = restart[t, n] or not initialised[n]
            delta = step_delta(times[t, n], last_time[n], time_unit, max_step)
            for k in range(k_count):
                step_expert(order, delta, q[k], r[k], initial[k], max_variance, initialised[n], learning, fresh,
                            z[t, n], mean[n, k], cov[n, k], experts[t, n, offset + k], m_pred, c_pred, f, work, gain,
                            a)
            if learning:
                initialised[n] = True
                last_time[n] = times[t, n]
            elif restart[t, n]:  # a restart on a missing row: start from the next present one
                initialised[n] = False
            # forecast made after this row, for a later time
            if want_ahead:
                if initialised[n]:
                    delta = step_delta(ahead_times[t, n], last_time[n], time_unit, max_step)
                    for k in range(k_count):
                        forecast_expert(order, delta, q[k], r[k], max_variance, mean[n, k], cov[n, k],
                                        out_ahead[t, n, offset + k], m_pred, c_pred, f, work)
                else:
                    for k in range(k_count):
                        for c in range(p):
                            out_ahead[t, n, offset + k, c] = np.nan
