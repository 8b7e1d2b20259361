"""Compiled coordinated-turn Kalman family (:mod:`kalmix.core.families.ct`): same formulas in the same order.

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

from ..families.ct import LOST_NIS, PLANE, SMALL_TURN
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .kinematic import sandwich, step_delta, symmetrise   # the same products, clipped step and symmetrising
# the parts every time-based family's driver shares
from .kinematic import check_gpu as check_gpu, pack as pack, unpack as unpack, work_arrays as work_arrays

configure_cache()
#: :func:`.kinematic.sandwich` inlined here, so that its size (5) is a constant of the loops, which LLVM unrolls:
#: the same operations in the same order (the same bits), the family's rows in a fifth less time.
_sandwich = nb.njit(inline="always", **_JIT)(getattr(sandwich, "py_func", sandwich))   # (a function without numba)

#: Relative cost of an expert's row (the engine hands the costliest family to a thread first).
COST = 4.0
#: The GPU staged engine's name for this family's stage.
NAME = "ct"
#: Whether a fresh install compiles the kernel in a second process (:mod:`._warm`): not this one.
COMPILE_APART = False


class Constants(NamedTuple):
    """The family's parameters as :func:`kernel` takes them."""

    q: np.ndarray    # (K,) process noise (a white acceleration on each axis)
    qw: np.ndarray   # (K,) turn noise q_j, a lateral jerk (the turn rate's is q_j / (|v|^2 + q_j))
    r: np.ndarray    # (K,) measurement noise
    v0: np.ndarray   # (K,) velocity variance before the filters start
    length_unit: float
    time_unit: float
    initial_turn_variance: float
    max_step: float
    max_variance: float
    max_velocity: float


def constants(params) -> Constants:
    """The family's parameters as :func:`kernel` takes them."""
    return Constants(np.asarray(params.process_noise), np.asarray(params.turn_noise),
                     np.asarray(params.measurement_noise), np.asarray(params.initial_variance),
                     float(params.length_unit), float(params.time_unit), float(params.initial_turn_variance),
                     float(params.max_step), float(params.max_variance), float(params.max_velocity))


def scratch(params, p: int) -> tuple:
    """One target's scratch of :func:`kernel`: the predicted state (mean, cov, further coordinates' mean and
    cov), the Jacobian, three work matrices, the two gain columns and a velocity."""
    square = lambda: np.empty((5, 5))  # noqa: E731
    return (np.empty(5), square(), np.empty((2, p - PLANE)), np.empty((2, 2)), square(), square(), square(),
            square(), np.empty(5), np.empty(5), np.empty(p))


@nb.njit(inline="always", **_JIT)
def _clip(x, bound):
    """``x`` within ``+-bound`` (NaN stays NaN, as numpy's clip)."""
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@nb.njit(**_JIT)
def predict_expert(d, q, qw, mean, cov, extra_mean, extra_cov, m_out, c_out, em_out, ec_out, jac, work, noise):
    """One expert's state extrapolated by ``d`` time units into ``m_out``, ``c_out``, ``em_out``, ``ec_out``."""
    x = mean[0]
    y = mean[1]
    vx = mean[2]
    vy = mean[3]
    w = mean[4]
    u = w * d
    half = 0.5 * u
    sinc_half = 1.0 if half == 0.0 else math.sin(half) / half
    c_half = math.cos(half)
    s_half = math.sin(half)
    along = sinc_half * c_half
    across = s_half * sinc_half
    c_u = math.cos(u)
    s_u = math.sin(u)
    if abs(u) < SMALL_TURN:
        along_slope = -u / 3.0 + u * u * u / 30.0
        across_slope = 0.5 - u * u / 8.0 + u * u * u * u / 144.0
    else:
        along_slope = (c_u - along) / u
        across_slope = (s_u - across) / u
    a1 = d * along
    a2 = d * across
    d2 = d * d
    for i in range(5):
        for j in range(5):
            jac[i, j] = 1.0 if i == j else 0.0
            noise[i, j] = 0.0
    jac[0, 2] = a1
    jac[0, 3] = -a2
    jac[0, 4] = d2 * (along_slope * vx - across_slope * vy)
    jac[1, 2] = a2
    jac[1, 3] = a1
    jac[1, 4] = d2 * (across_slope * vx + along_slope * vy)
    jac[2, 2] = c_u
    jac[2, 3] = -s_u
    jac[2, 4] = d * (-s_u * vx - c_u * vy)
    jac[3, 2] = s_u
    jac[3, 3] = c_u
    jac[3, 4] = d * (c_u * vx - s_u * vy)
    m_out[0] = x + a1 * vx - a2 * vy
    m_out[1] = y + a2 * vx + a1 * vy
    m_out[2] = c_u * vx - s_u * vy
    m_out[3] = s_u * vx + c_u * vy
    m_out[4] = w
    _sandwich(5, jac, cov, c_out, work)
    s2 = vx * vx + vy * vy
    qw = qw / (s2 + qw)   # the turn rate's noise: the lateral jerk's over the speed squared
    d3 = d2 * d
    for i in range(2):   # a white acceleration of density q on each axis
        noise[i, i] = q * d3 / 3.0
        noise[i, i + 2] = q * d2 / 2.0
        noise[i + 2, i] = q * d2 / 2.0
        noise[i + 2, i + 2] = q * d
    noise[4, 4] = qw * d
    for i in range(5):
        for j in range(5):
            c_out[i, j] = c_out[i, j] + noise[i, j]
    symmetrise(5, c_out)
    for c in range(extra_mean.shape[1]):
        em_out[0, c] = extra_mean[0, c] + d * extra_mean[1, c]
        em_out[1, c] = extra_mean[1, c]
    a00 = extra_cov[0, 0] + d * extra_cov[1, 0]
    a01 = extra_cov[0, 1] + d * extra_cov[1, 1]
    a10 = extra_cov[1, 0]
    a11 = extra_cov[1, 1]
    c00 = a00 + a01 * d + q * d3 / 3.0
    c01 = a01 + q * d2 / 2.0
    c10 = a10 + a11 * d + q * d2 / 2.0
    c11 = a11 + q * d
    off = 0.5 * (c01 + c10)
    ec_out[0, 0] = c00
    ec_out[0, 1] = off
    ec_out[1, 0] = off
    ec_out[1, 1] = c11


@nb.njit(**_JIT)
def _start_expert(k, n, z, position, d, r, bound, initial_turn_variance, mean, cov, extra_mean, extra_cov, velocity):
    """Expert ``k`` of target ``n`` started from its last learned row and ``z (p,)``, ``d`` > 0 time units later."""
    p = z.shape[0]
    for c in range(p):
        velocity[c] = _clip((z[c] - position[n, c]) / d, bound)
        if velocity[c] != velocity[c]:
            velocity[c] = 0.0
    mean[n, k, 0] = z[0]
    mean[n, k, 1] = z[1]
    mean[n, k, 2] = velocity[0]
    mean[n, k, 3] = velocity[1]
    mean[n, k, 4] = 0.0
    cross = r / d
    speed_variance = 2.0 * r / (d * d)
    for i in range(5):
        for j in range(5):
            cov[n, k, i, j] = 0.0
    for i in range(2):
        cov[n, k, i, i] = r
        cov[n, k, i, i + 2] = cross
        cov[n, k, i + 2, i] = cross
        cov[n, k, i + 2, i + 2] = speed_variance
    cov[n, k, 4, 4] = initial_turn_variance
    for c in range(p - PLANE):
        extra_mean[n, k, 0, c] = z[PLANE + c]
        extra_mean[n, k, 1, c] = velocity[PLANE + c]
    extra_cov[n, k, 0, 0] = r
    extra_cov[n, k, 0, 1] = cross
    extra_cov[n, k, 1, 0] = cross
    extra_cov[n, k, 1, 1] = speed_variance


@nb.njit(**_JIT)
def _update_expert(k, n, z, r, bound, max_variance, mean, cov, extra_mean, extra_cov, m, c_pred, em, ec, a,
                   new_cov, work, g0, g1):
    """Expert ``k`` of target ``n``: the EKF update of its predicted state (``m``, ``c_pred``, ``em``, ``ec``)
    with ``z (p,)``, written to the state; returns False (the state unchanged) where the innovation's NIS is beyond
    ``LOST_NIS``."""
    y0 = z[0] - m[0]
    y1 = z[1] - m[1]
    s00 = c_pred[0, 0] + r
    s01 = c_pred[0, 1]
    s10 = c_pred[1, 0]
    s11 = c_pred[1, 1] + r
    det = s00 * s11 - s01 * s10
    i00 = s11 / det
    i01 = -s01 / det
    i10 = -s10 / det
    i11 = s00 / det
    nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
    if not (nis <= LOST_NIS):
        return False
    for i in range(5):
        g0[i] = c_pred[i, 0] * i00 + c_pred[i, 1] * i10
        g1[i] = c_pred[i, 0] * i01 + c_pred[i, 1] * i11
    for i in range(5):
        mean[n, k, i] = m[i] + (g0[i] * y0 + g1[i] * y1)
    mean[n, k, 2] = _clip(mean[n, k, 2], bound)
    mean[n, k, 3] = _clip(mean[n, k, 3], bound)
    mean[n, k, 4] = _clip(mean[n, k, 4], math.pi)
    for i in range(5):
        for j in range(5):
            a[i, j] = 1.0 if i == j else 0.0
        a[i, 0] = a[i, 0] - g0[i]
        a[i, 1] = a[i, 1] - g1[i]
    _sandwich(5, a, c_pred, new_cov, work)
    for i in range(5):
        for j in range(5):
            new_cov[i, j] = new_cov[i, j] + r * (g0[i] * g0[j] + g1[i] * g1[j])
    symmetrise(5, new_cov)
    excess = 0.5 * (new_cov[0, 0] + new_cov[1, 1]) / max_variance
    if excess <= 1.0:
        excess = 1.0
    for i in range(5):
        for j in range(5):
            cov[n, k, i, j] = new_cov[i, j] / excess
    se = ec[0, 0] + r
    k0 = ec[0, 0] / se
    k1 = ec[1, 0] / se
    for c in range(em.shape[1]):
        innovation = z[PLANE + c] - em[0, c]
        extra_mean[n, k, 0, c] = em[0, c] + k0 * innovation
        extra_mean[n, k, 1, c] = em[1, c] + k1 * innovation
    f00 = ec[0, 0] - k0 * ec[0, 0]
    f01 = ec[0, 1] - k0 * ec[0, 1]
    f10 = ec[1, 0] - k1 * ec[0, 0]
    f11 = ec[1, 1] - k1 * ec[0, 1]
    off = 0.5 * (f01 + f10)
    extra_cov[n, k, 0, 0] = f00
    extra_cov[n, k, 0, 1] = off
    extra_cov[n, k, 1, 0] = off
    extra_cov[n, k, 1, 1] = f11
    return True


@nb.njit(**_JIT)
def _write_forecast(k, n, d, params, state, out_row, m, c_pred, em, ec, jac, work, noise):
    """Expert ``k``'s forecast of target ``n`` ``d`` time units after its last learned row into ``out_row (p,)``
    (NaN before the target's start), its predicted state left in the scratch."""
    q, qw = params[0], params[1]
    mean, cov, extra_mean, extra_cov, position, known, _, initialised = state
    p = out_row.shape[0]
    if not initialised[n]:
        for i in range(p):
            out_row[i] = np.nan
    elif known[n] >= 2:
        predict_expert(d, q[k], qw[k], mean[n, k], cov[n, k], extra_mean[n, k], extra_cov[n, k], m, c_pred, em, ec,
                       jac, work, noise)
        out_row[0] = m[0]
        out_row[1] = m[1]
        for c in range(p - PLANE):
            out_row[PLANE + c] = em[0, c]
    else:
        for i in range(p):
            out_row[i] = position[n, i]


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, rows, forecasts, work, scratch):
    """The driver: targets ``lo .. hi - 1`` through their rows of the block (:mod:`.kinematic` lists the
    arguments; ``rows.horizon``, the frame-based families' clock, is not read)."""
    q, qw, r, v0, length_unit, time_unit, initial_turn_variance, max_step, max_variance, max_velocity = params
    mean, cov, extra_mean, extra_cov, position, known, last_time, initialised = state
    z, times, lengths, learn, restart, ahead_times, _ = rows
    out, offset, out_ahead = forecasts
    m, c_pred, em, ec, jac, mat_a, mat_b, noise, g0, g1, velocity = scratch
    k_count = q.shape[0]
    p = z.shape[2]
    bound = max_velocity * length_unit
    want_ahead = out_ahead.shape[0] > 0
    for n in range(lo, hi):
        for t in range(lengths[n]):
            started = initialised[n]
            delta = step_delta(times[t, n], last_time[n], time_unit, max_step)
            running = started and known[n] >= 2 and learn[t, n] and not restart[t, n]
            for k in range(k_count):
                # the expert's forecast of this row, then its learning (its predicted state is in the scratch)
                _write_forecast(k, n, delta, params, state, out[t, n, offset + k], m, c_pred, em, ec, jac, mat_a,
                                noise)
                if running:
                    updated = _update_expert(k, n, z[t, n], r[k], bound, max_variance, mean, cov,
                                             extra_mean, extra_cov, m, c_pred, em, ec, mat_a, mat_b, noise, g0, g1)
                    if not updated and delta > 0:   # a lost expert starts again
                        _start_expert(k, n, z[t, n], position, delta, r[k], bound, initial_turn_variance, mean, cov,
                                      extra_mean, extra_cov, velocity)
                elif learn[t, n] and started and not restart[t, n] and known[n] == 1 and delta > 0:
                    _start_expert(k, n, z[t, n], position, delta, r[k], bound, initial_turn_variance, mean, cov,
                                  extra_mean, extra_cov, velocity)
            if learn[t, n]:
                if restart[t, n] or not started:
                    known[n] = 1.0
                elif known[n] == 1 and delta > 0:
                    known[n] = 2.0
                for i in range(p):
                    position[n, i] = z[t, n, i]
                last_time[n] = times[t, n]
                initialised[n] = True
            elif restart[t, n]:  # a restart on a missing row: start from the next present one
                initialised[n] = False
            # forecast made after this row, for a later time
            if want_ahead:
                ahead = step_delta(ahead_times[t, n], last_time[n], time_unit, max_step)
                for k in range(k_count):
                    _write_forecast(k, n, ahead, params, state, out_ahead[t, n, offset + k], m, c_pred, em, ec, jac,
                                    mat_a, noise)
