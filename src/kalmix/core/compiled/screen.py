"""Compiled glitch screen (:mod:`kalmix.core.screen`): same formulas, targets in ranges on threads.

:func:`screen_row` is the whole test for one target and one row; the block driver's stage
:func:`screen_block` and the fused GPU kernel (:mod:`.gpu`) both call it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from ..screen import MAX_POINTS, ZERO
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache

configure_cache()

#: :func:`screen_row` results (GAP: a restart asked for on a missing row; COLD: an accepted row that ends a
#: warm-up which held a glitch: it is forecast by the rule and the calibration, which then start again without
#: learning it; the families start again at the next present row, a RESTART).
SKIP, ACCEPT, RESTART, GAP, COLD = 0, 1, 2, 3, 4


@nb.njit(inline="always", **_JIT)
def screen_row(threshold, max_rejects, warmup, window, position, velocity, last_time, scale, count, rejects,
               outliers, points, low, high, n, z, time, present, gap):
    """Screen target ``n``'s row ``z`` at ``time``: SKIP (missing or outlier), ACCEPT, RESTART (the screen's or
    a ``gap``), GAP (a gap on a missing row: start again from the next row) or COLD (see above)."""
    p = z.shape[0]
    pending = points[n] < 0   # the warm-up held a glitch: the families start again at the next present row
    if gap or (pending and present):
        for c in range(p):
            velocity[n, c] = 0.0
        rejects[n] = 0.0
        if not present:
            if not pending:
                points[n] = 0.0
            return GAP
        points[n] = 1.0
        for c in range(p):
            position[n, c] = z[c]
        last_time[n] = time
        return RESTART
    if not present:
        return SKIP
    started = points[n] >= 1
    moving = points[n] >= 2
    dt = time - last_time[n] if started else 0.0
    if not (math.isfinite(dt) and dt > 0):
        dt = 0.0
    acc = 0.0
    for c in range(p):
        diff = z[c] - (position[n, c] + velocity[n, c] * dt)
        acc += diff * diff
    distance = math.sqrt(acc)
    size = 0.0
    if moving:
        for c in range(p):
            size = max(size, abs(position[n, c]))
    tiny = ZERO * size   # a distance below it is rounding: 0
    reference = scale[n]
    if not reference > tiny:   # no error to judge by (exact motion): threshold x the distance moved in the step
        acc = 0.0
        for c in range(p):
            step = velocity[n, c] * dt
            acc += step * step
        reference = threshold * math.sqrt(acc)
    wild = moving and count[n] >= warmup and reference > tiny and not (distance <= threshold * reference)
    rejected = 0.0
    if wild:
        rejected = rejects[n] + 1.0
    is_restart = wild and rejected >= max_rejects
    if wild and not is_restart:
        rejects[n] = rejected
        outliers[n] += 1.0
        return SKIP
    if is_restart:
        for c in range(p):
            velocity[n, c] = 0.0
        points[n] = 1.0
    else:
        glitch = False
        if moving and math.isfinite(distance):
            count[n] = min(count[n] + 1.0, window)
            scale[n] = scale[n] + (distance - scale[n]) / count[n]
            if not math.isnan(high[n]):   # the warm-up audit (see kalmix.core.screen)
                if distance > tiny:
                    low[n] = min(low[n], distance)
                high[n] = max(high[n], distance)
                if count[n] >= warmup:
                    glitch = high[n] > threshold * low[n]
                    low[n] = np.nan
                    high[n] = np.nan
        elif moving and not math.isnan(high[n]):   # a distance that overflowed: a glitch beyond 1e154
            high[n] = np.inf
        if started and dt > 0:
            for c in range(p):
                velocity[n, c] = (z[c] - position[n, c]) / dt
        points[n] = min(points[n] + 1.0, MAX_POINTS)
        if glitch:   # the warm-up held a glitch: learn the scale again; restart cold
            count[n] = 0.0
            scale[n] = 0.0
            outliers[n] += 1.0
            points[n] = -1.0
            low[n] = np.inf   # the next warm-up is audited too
            high[n] = 0.0
    rejects[n] = 0.0
    for c in range(p):
        position[n, c] = z[c]
    last_time[n] = time
    if is_restart:
        return RESTART
    return COLD if points[n] < 0 else ACCEPT


@nb.njit(inline="always", **_JIT)
def last_learned(last_time, points, n):
    """The time of target ``n``'s last learned row, NaN while it has fewer than two since its (re)start: what the
    spec's :func:`kalmix.core.engine.span` measures from."""
    return last_time[n] if points[n] >= 2.0 else np.nan


class Constants(NamedTuple):
    """The screen's parameters (:class:`kalmix.core.screen.ScreenParams`) as :func:`screen_block` takes them."""

    threshold: float
    max_rejects: float
    warmup: float
    window: float


def constants(params) -> Constants:
    """``params`` (:class:`kalmix.core.screen.ScreenParams`) as :func:`screen_block` takes them."""
    return Constants(float(params.threshold), float(params.max_rejects), float(params.warmup), float(params.window))


class Rows(NamedTuple):
    """A block's rows as :func:`screen_block` reads them."""

    z: np.ndarray         # (B, N, p)
    times: np.ndarray     # (B, N)
    lengths: np.ndarray   # (N,)
    present: np.ndarray   # (B, N) rows to screen (the others are missing)
    gaps: np.ndarray      # (B, N) rows a gap restarts


class Verdicts(NamedTuple):
    """What :func:`screen_block` writes for each row of a block, ``(B, N)`` each."""

    accept: np.ndarray    # the row is learned
    restart: np.ndarray   # the families start again (from it, or from the next present row)
    started: np.ndarray   # the target had an accepted row (since a restart) before it
    cold: np.ndarray      # a COLD row: the rule and the calibration start again once it is forecast
    before: np.ndarray    # the time of the last accepted row before it (NaN while fewer than two: the spec's
    after: np.ndarray     # :func:`kalmix.core.engine.span`), and after it
    points_before: np.ndarray   # the screen's ``points`` (accepted rows since the (re)start) before it,
    points_after: np.ndarray    # and after it (:func:`kalmix.core.engine.warmed_up`)


@nb.njit(**KERNEL_JIT)
def screen_block(lo, hi, params, state, rows, verdicts):
    """Every row of a block, targets ``lo .. hi - 1``: ``params`` (:class:`Constants`), ``state`` (the spec's
    :class:`kalmix.core.screen.ScreenState`, advanced in place), ``rows`` (:class:`Rows`), ``verdicts``
    (:class:`Verdicts`, written)."""
    threshold, max_rejects, warmup, window = params
    position, velocity, last_time, scale, count, rejects, outliers, points, low, high = state
    z, times, lengths, present, gaps = rows
    accept, restart, started, cold, before, after, points_before, points_after = verdicts
    for n in range(lo, hi):
        for t in range(lengths[n]):
            started[t, n] = points[n] >= 1.0
            before[t, n] = last_learned(last_time, points, n)
            points_before[t, n] = points[n]
            code = screen_row(threshold, max_rejects, warmup, window, position, velocity, last_time, scale, count,
                              rejects, outliers, points, low, high, n, z[t, n], times[t, n], present[t, n],
                              gaps[t, n])
            accept[t, n] = code == ACCEPT or code == RESTART or code == COLD
            restart[t, n] = code == RESTART or code == GAP
            cold[t, n] = code == COLD
            after[t, n] = last_learned(last_time, points, n)
            points_after[t, n] = points[n]
