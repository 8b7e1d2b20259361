"""Compiled coordinated-turn family (:mod:`kalmix.core.families.turn`): same formulas in the same order.

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

from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .ar import bounded   # NaN -> 0, then clipped to +-bound
from .kinematic import step_delta   # the same clipped step in time units
# the parts every time-based family's driver shares
from .kinematic import check_gpu as check_gpu, pack as pack, unpack as unpack, work_arrays as work_arrays

configure_cache()

#: Relative cost of an expert's row (the engine hands the costliest family to a thread first).
COST = 1.0
#: The GPU staged engine's name for this family's stage.
NAME = "turn"
#: Whether a fresh install compiles the kernel in a second process (:mod:`._warm`): yes, after the AKF's, which
#: leaves the two processes' shares balanced.
COMPILE_APART = True


@nb.njit(inline="always", **_JIT)
def _norm(v):
    acc = v[0] * v[0]
    for c in range(1, v.shape[0]):
        acc = acc + v[c] * v[c]
    return math.sqrt(acc)


@nb.njit(inline="always", **_JIT)
def _sinc(x):
    if abs(x) < 1e-8:
        return 1.0
    return math.sin(x) / x


@nb.njit(**_JIT)
def geometry(velocity_n, previous_n, span, previous_span, known, b, c):
    """The spec's ``turn_geometry`` for one target: fills ``b``, ``c`` (p,), returns ``(speed, omega)``."""
    p = b.shape[0]
    s1 = _norm(previous_n)
    s2 = _norm(velocity_n)
    both = known >= 2 and s1 > 0 and s2 > 0
    cosine = 0.0
    for i in range(p):
        a_i = previous_n[i] / (s1 if both else 1.0)
        b[i] = velocity_n[i] / (s2 if s2 > 0 else 1.0)
        cosine = a_i * b[i] if i == 0 else cosine + a_i * b[i]
    cosine = min(max(cosine, -1.0), 1.0)
    sine = 0.0
    for i in range(p):
        c[i] = b[i] * cosine - previous_n[i] / (s1 if both else 1.0)
        sine = c[i] * c[i] if i == 0 else sine + c[i] * c[i]
    sine = math.sqrt(sine)
    turning = both and sine > 0
    for i in range(p):
        c[i] = c[i] / sine if turning else 0.0
    omega = math.atan2(sine, cosine) / (0.5 * (previous_span + span)) if turning else 0.0
    return s2 / _sinc(min(0.5 * omega * span, 0.5 * math.pi)), omega


@nb.njit(inline="always", **_JIT)
def forecast_expert(gain, speed, omega, span, known, delta, position_n, b, c, out):
    """Expert of gain ``gain``: its forecast ``delta`` time units after the last learned row into ``out (p,)``."""
    w = gain * omega
    alpha = 0.5 * w * (span + delta)
    length = speed * delta * _sinc(0.5 * w * delta)
    cos_a = math.cos(alpha)
    sin_a = math.sin(alpha)
    for i in range(out.shape[0]):
        out[i] = position_n[i] + (length * (b[i] * cos_a + c[i] * sin_a) if known >= 1 else 0.0)


class Constants(NamedTuple):
    """The family's parameters as :func:`kernel` takes them."""

    gain: np.ndarray   # (K,)
    length_unit: float
    time_unit: float
    window: float
    max_step: float
    max_velocity: float


def constants(params) -> Constants:
    """The family's parameters as :func:`kernel` takes them."""
    return Constants(np.asarray(params.gain), float(params.length_unit), float(params.time_unit),
                     float(params.window), float(params.max_step), float(params.max_velocity))


def scratch(params, p: int) -> tuple:
    """One target's scratch of :func:`kernel`: b, c, v."""
    return np.empty(p), np.empty(p), np.empty(p)


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, rows, forecasts, work, scratch):
    """The driver: targets ``lo .. hi - 1`` through their rows of the block (:mod:`.kinematic` lists the
    arguments; ``rows.horizon``, the frame-based families' clock, is not read)."""
    gain, length_unit, time_unit, window, max_step, max_velocity = params
    velocity, previous, span, previous_span, known, error, count, position, last_time, initialised = state
    z, times, lengths, learn, restart, ahead_times, _ = rows
    out, offset, out_ahead = forecasts
    b, c, v = scratch
    k_count = gain.shape[0]
    p = z.shape[2]
    bound = max_velocity * length_unit
    want_ahead = out_ahead.shape[0] > 0
    for n in range(lo, hi):
        for t in range(lengths[n]):
            # every expert's forecast of this row, then its learning (a restart row starts it again)
            started = initialised[n]
            delta = step_delta(times[t, n], last_time[n], time_unit, max_step)
            speed, omega = geometry(velocity[n], previous[n], span[n], previous_span[n], known[n], b, c)
            for k in range(k_count):
                if started:
                    forecast_expert(gain[k], speed, omega, span[n], known[n], delta, position[n], b, c,
                                    out[t, n, offset + k])
                else:
                    for i in range(p):
                        out[t, n, offset + k, i] = np.nan
            if learn[t, n]:
                if restart[t, n] or not started:
                    for i in range(p):
                        velocity[n, i] = 0.0
                        previous[n, i] = 0.0
                    span[n] = 0.0
                    previous_span[n] = 0.0
                    known[n] = 0.0
                    for k in range(k_count):
                        error[n, k] = length_unit * length_unit
                    count[n] = 1.0
                elif delta > 0:
                    new_count = min(count[n] + 1.0, window)
                    for k in range(k_count):   # the velocity error of the forecast just written
                        squared = 0.0
                        for i in range(p):
                            e = bounded((z[t, n, i] - out[t, n, offset + k, i]) / delta, bound)
                            squared = e * e if i == 0 else squared + e * e
                        error[n, k] = error[n, k] + (squared / p - error[n, k]) / new_count
                    count[n] = new_count
                    for i in range(p):
                        v[i] = bounded((z[t, n, i] - position[n, i]) / delta, bound)
                        previous[n, i] = velocity[n, i]
                        velocity[n, i] = v[i]
                    previous_span[n] = span[n]
                    span[n] = delta
                    known[n] = min(known[n] + 1.0, 2.0)
                for i in range(p):
                    position[n, i] = z[t, n, i]
                last_time[n] = times[t, n]
                initialised[n] = True
            elif restart[t, n]:  # a restart on a missing row: start from the next present one
                initialised[n] = False
            # forecast made after this row, for a later time
            if want_ahead:
                ahead = step_delta(ahead_times[t, n], last_time[n], time_unit, max_step)
                if initialised[n]:
                    speed, omega = geometry(velocity[n], previous[n], span[n], previous_span[n], known[n], b, c)
                for k in range(k_count):
                    if initialised[n]:
                        forecast_expert(gain[k], speed, omega, span[n], known[n], ahead, position[n], b, c,
                                        out_ahead[t, n, offset + k])
                    else:
                        for i in range(p):
                            out_ahead[t, n, offset + k, i] = np.nan
