"""Compiled calibration (:mod:`kalmix.core.calibration`): per-row functions, one target at a time.

Shared by the rule's and the lead head's drivers (:mod:`.rules`, :mod:`.lead`) and the fused GPU kernel; the
arrays are one target's: forecasts ``x (K, p)``, weights ``w (K,)``, ``variance (K, p)``, ``count (K,)``;
``log_scale`` is a length-1 view. The parameters come as :class:`Constants`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from ..calibration import CalibrationParams, z_score
from ._cache import JIT as _JIT
from ._cache import configure_cache

configure_cache()

__all__ = ["Constants", "pack_params", "learns", "moments_row", "calibrate_row", "calibrate_issued_row"]


class Constants(NamedTuple):
    """The calibration's parameters as the compiled rule and lead head take them."""

    window: float
    rate: float
    level: float
    z_level: float          # z of the central ``level`` interval
    max_variance: float
    max_log_scale: float
    initial_variance: float   # of a cold restart
    from_points: float        # learn from forecasts made from at least this many rows of a segment (0: all)


def pack_params(params: CalibrationParams) -> Constants:
    """``params`` as :class:`Constants`."""
    return Constants(float(params.window), float(params.rate), float(params.level), float(z_score(params)),
                     float(params.max_variance), float(params.max_log_scale), float(params.initial_variance),
                     float(params.from_points))


@nb.njit(inline="always", **_JIT)
def learns(from_points, points):
    """Whether the calibration learns a row whose forecast was made from ``points`` learned rows of its segment
    (the spec's :func:`kalmix.core.calibration.learns`)."""
    return from_points <= 0 or points >= from_points


@nb.njit(inline="always", **_JIT)
def moments_row(x, w, awake, count, mix, variance, log_scale, max_variance, cov):
    """``cov (p, p)`` of the mixture ``mix`` (already :func:`.rule_rows.mix_of`); NaN if no expert is awake."""
    p = x.shape[1]
    factor = math.exp(2.0 * log_scale)
    for i in range(p):
        for j in range(p):
            if count == 0:
                cov[i, j] = np.nan
                continue
            acc = 0.0
            for k in range(x.shape[0]):
                if awake[k]:
                    acc += w[k] * ((x[k, i] - mix[i]) * (x[k, j] - mix[j]))
            if i == j:
                diagonal = 0.0
                for k in range(x.shape[0]):
                    if awake[k]:
                        diagonal += w[k] * variance[k, i]
                acc = acc + diagonal
            value = factor * acc
            if math.isnan(value):
                value = max_variance
            cov[i, j] = min(max(value, -max_variance), max_variance)


@nb.njit(inline="always", **_JIT)
def calibrate_row(x, y, awake, count, mix, cov, variance, n_errors, log_scale, window, rate, level, z,
                  max_variance, max_log_scale):
    """Learn one row: ``log_scale[0]`` from the mixture's miss, each awake expert's variance."""
    _calibrate(x, y, awake, count, mix, cov, cov, False, variance, n_errors, log_scale, window, rate, level, z,
               max_variance, max_log_scale)


@nb.njit(inline="always", **_JIT)
def calibrate_issued_row(x, y, awake, count, mix, cov, issued, variance, n_errors, log_scale, window, rate, level,
                         z, max_variance, max_log_scale):
    """:func:`calibrate_row` for a forecast issued rows ago (the lead head): the miss is that of the
    interval then issued, ``issued[0] ± z issued[1]`` (its mean and standard deviations), as adaptive
    conformal inference with delayed feedback asks; ``mix`` and ``cov`` (today's) where it is NaN."""
    _calibrate(x, y, awake, count, mix, cov, issued, True, variance, n_errors, log_scale, window, rate, level, z,
               max_variance, max_log_scale)


@nb.njit(inline="always", **_JIT)
def _calibrate(x, y, awake, count, mix, cov, issued, use_issued, variance, n_errors, log_scale, window, rate, level,
               z, max_variance, max_log_scale):
    p = x.shape[1]
    if count == 0:
        return
    misses = 0.0
    for c in range(p):
        e = y[c] - mix[c]
        if not math.isfinite(e):
            return
        if use_issued and not math.isnan(issued[0, c]):
            miss = abs(y[c] - issued[0, c]) > z * issued[1, c]
        else:
            miss = abs(e) > z * math.sqrt(cov[c, c])
        if miss:
            misses += 1.0
    value = log_scale[0] + rate * (misses / p - (1.0 - level))
    log_scale[0] = min(max(value, -max_log_scale), max_log_scale)
    for k in range(x.shape[0]):
        if not awake[k]:
            continue
        ok = True
        for c in range(p):
            if not math.isfinite((y[c] - x[k, c]) ** 2):
                ok = False
        if not ok:
            continue
        n_errors[k] = min(n_errors[k] + 1.0, window)
        step = 1.0 / min(n_errors[k] + 1.0, window)   # the initial variance one more error (the spec's)
        for c in range(p):
            variance[k, c] = min(variance[k, c] + step * ((y[c] - x[k, c]) ** 2 - variance[k, c]), max_variance)
