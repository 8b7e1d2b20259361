"""How sure a mixture is: its predictive covariance, recalibrated online (reference).

For the weights :math:`w_k` and the awake experts' forecasts :math:`y_k` of one target,

.. math::

    \\Sigma = s^2 \\sum_k w_k \\big(\\operatorname{diag}(V_k) + (y_k - \\bar y)(y_k - \\bar y)^\\top\\big),
    \\qquad \\bar y = \\sum_k w_k y_k,

where :math:`V_k` is expert :math:`k`'s running mean squared error per coordinate (over
its last ~``window`` learned rows; ``initial_variance`` before the first, and counted as one more
error until there are ``window`` of them, so that a coordinate an expert has foreseen exactly once
does not get an interval of width zero) and :math:`s` a running scale. Neither learns the error of a
forecast made from fewer than ``from_points`` rows of its segment (2: not the first forecast of a track,
or of a segment after a restart, made from one row: the experts had no velocity then, and that miss,
the target's whole displacement, is no measure of later rows' errors, and would keep a dozen-row track's
intervals several times too wide). The variances are the
experts' own errors, measured the same way for every family, so the covariance needs nothing from
the experts but their forecasts.

The scale keeps the intervals honest (adaptive conformal inference, Gibbs & Candès
2021): after each learned row, with ``miss`` the fraction of coordinates outside
:math:`\\bar y \\pm z_{level} \\sigma` (:math:`\\sigma` the square roots of the
diagonal of :math:`\\Sigma`),

.. math::  \\log s \\leftarrow \\log s + \\gamma\\, (\\text{miss} - (1 - \\text{level})),

so the long-run share of coordinates outside the central ``level`` interval is
``1 - level`` whatever the shape of the errors. Numbers are kept finite: an error
whose square overflows teaches nothing, variances are capped at ``max_variance``,
:math:`\\log s` stays within ``±max_log_scale``.
"""

from __future__ import annotations

from statistics import NormalDist
from typing import NamedTuple

import numpy as np

from ._libm import exp, ordered_sum
from .constraints import Integer, Real
from .screen import MAX_POINTS

__all__ = ["CalibrationParams", "CalibrationState", "init", "moments", "update", "learns", "z_score"]


class CalibrationParams(NamedTuple):
    initial_variance: float = 1.0   # V before an expert's first error (length unit squared)
    window: float = 100.0           # V is the mean of about the last ``window`` squared errors
    rate: float = 0.05              # gamma: step of log s
    level: float = 0.95             # the central interval whose coverage is calibrated
    max_variance: float = 1e300
    max_log_scale: float = 30.0
    from_points: int = 2            # learn from forecasts made from at least this many rows of a segment (0: all)

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"level": Real(gt=0, lt=1, noun="a probability"),
                   # (the screen counts a segment's rows up to MAX_POINTS: more would learn no row)
                   "from_points": Integer(ge=0, le=int(MAX_POINTS))}


class CalibrationState(NamedTuple):
    variance: np.ndarray    # (N, K, p) V
    count: np.ndarray       # (N, K) learned errors in V, capped at window
    log_scale: np.ndarray   # (N,) log s


def z_score(params: CalibrationParams) -> float:
    """:math:`z` of the central ``level`` interval of a normal law (1.96 for 95 %)."""
    return NormalDist().inv_cdf(0.5 + 0.5 * params.level)


def init(params: CalibrationParams, n_targets: int, n_experts: int, measurement_dim: int) -> CalibrationState:
    return CalibrationState(np.full((n_targets, n_experts, measurement_dim), float(params.initial_variance)),
                            np.zeros((n_targets, n_experts)), np.zeros(n_targets))


def moments(params: CalibrationParams, state: CalibrationState, weights, experts, awake):
    """The mixture's mean ``(N, p)`` and covariance ``(N, p, p)`` (NaN where no expert is awake)."""
    x = np.where(awake[..., None], experts, 0.0)
    w = np.where(awake, weights, 0.0)
    mean = ordered_sum(w[..., None] * x, axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        dev = np.where(awake[..., None], x - mean[:, None, :], 0.0)
        cov = ordered_sum(w[..., None, None] * (dev[..., :, None] * dev[..., None, :]), axis=1)
        diagonal = ordered_sum(w[..., None] * np.where(awake[..., None], state.variance, 0.0), axis=1)
        cov = cov + diagonal[:, :, None] * np.eye(mean.shape[-1])
        cov = exp(2.0 * state.log_scale)[:, None, None] * cov
    cov = np.clip(np.nan_to_num(cov, nan=params.max_variance, posinf=params.max_variance,
                                 neginf=-params.max_variance), -params.max_variance, params.max_variance)
    some = awake.any(axis=-1)
    return np.where(some[:, None], mean, np.nan), np.where(some[:, None, None], cov, np.nan)


def learns(params: CalibrationParams, points) -> np.ndarray:
    """Which rows the calibration may learn, by the learned rows of their segment before them (``points (N,)``,
    the glitch screen's): those whose forecast was made from at least ``params.from_points`` rows."""
    points = np.asarray(points)
    return np.ones(points.shape, dtype=bool) if params.from_points <= 0 else points >= params.from_points


def update(params: CalibrationParams, state: CalibrationState, weights, experts, awake, measurement,
           learn, issued=None) -> CalibrationState:
    """Learn a row where ``learn (N,)``: the scale from the mixture's miss, each awake expert's V.

    ``issued (N, 2, p)``, for forecasts made rows earlier (the lead head), is the interval then
    issued (its mean and standard deviations): the miss is that interval's, as adaptive conformal
    inference with delayed feedback asks (the current interval where it is NaN).
    """
    mean, cov = moments(params, state, weights, experts, awake)
    z = np.where(learn[:, None], measurement, 0.0)
    std = np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    center, spread = mean, std
    if issued is not None:
        then = ~np.isnan(issued[:, 0])
        center, spread = np.where(then, issued[:, 0], mean), np.where(then, issued[:, 1], std)
    with np.errstate(invalid="ignore", over="ignore"):
        miss = (np.abs(z - center) > z_score(params) * spread).mean(axis=-1)
    go = learn & awake.any(axis=-1) & np.isfinite(z - mean).all(axis=-1)
    log_scale = np.clip(state.log_scale + params.rate * (miss - (1.0 - params.level)),
                        -params.max_log_scale, params.max_log_scale)
    with np.errstate(over="ignore", invalid="ignore"):
        squared = (z[:, None, :] - experts) ** 2
    learn_k = go[:, None] & awake & np.isfinite(squared).all(axis=-1)
    count = np.where(learn_k, np.minimum(state.count + 1.0, params.window), state.count)
    step = 1.0 / np.minimum(count + 1.0, params.window)   # the initial variance one more error, up to the window
    with np.errstate(over="ignore", invalid="ignore"):
        variance = np.minimum(state.variance + step[..., None] * (squared - state.variance), params.max_variance)
    return CalibrationState(np.where(learn_k[..., None], variance, state.variance), count,
                            np.where(go, log_scale, state.log_scale))
