"""Compiled aggregation rules (:mod:`kalmix.core.aggregators`): same formulas, targets in ranges on threads.

Each rule has its own parameters and state as the kernels take them, named tuples with the
spec's names (BOA's and BOA-blend's in :mod:`.boa`, :class:`MLPolyParams` / :class:`MLPolyState`,
:class:`FixedShareParams` / :class:`FixedShareState`; :data:`COMPILED_RULES` maps a rule's name to
them), and its row functions: its weights, its learning, what a restart and a cold restart change.
One driver, :func:`kernel`, serves them all: it calls :func:`weights_row`, :func:`learn_row`,
:func:`restart_row`, :func:`cold_row` and :func:`target`, which numba resolves by the state's type
when it compiles (an ``overload`` each), so each rule has its own compiled driver and no branch on
a rule code; with the JIT off (the CUDA simulator) they dispatch in Python.

A per-target state (:func:`target`) is the rule's state class holding one target's views: the
``(K,)`` rows of the ``(N, K)`` arrays and one-element slices of the ``(N,)`` ones (written in place).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np
from numba.extending import overload

from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .boa import (BoaBlendState, BoaParams, BoaState, boa_blend_cold, boa_blend_column, boa_blend_learn,
                  boa_blend_restart, boa_blend_target, boa_blend_weights, boa_cold, boa_column, boa_learn, boa_restart,
                  boa_target, boa_weights)
from .calibration import calibrate_row, learns, moments_row
from .rule_rows import awake_of, mix_of, regrets, share_floor, softmax

configure_cache()

class MLPolyParams(NamedTuple):
    """ML-Poly's parameters (:class:`kalmix.core.aggregators.mlpoly.Params`)."""

    forgetting: float
    share: float


class MLPolyState(NamedTuple):
    """ML-Poly's state (:class:`kalmix.core.aggregators.mlpoly.State`)."""

    regret: np.ndarray     # (N, K)
    variance: np.ndarray   # (N, K)
    bound: np.ndarray      # (N,)


class FixedShareParams(NamedTuple):
    """Fixed share's parameters (:class:`kalmix.core.aggregators.fixed_share.Params`)."""

    share: float
    scale: float
    scale_factor: float


class FixedShareState(NamedTuple):
    """Fixed share's state (:class:`kalmix.core.aggregators.fixed_share.State`)."""

    log_weights: np.ndarray   # (N, K)
    squared: np.ndarray       # (N,)
    count: np.ndarray         # (N,)


class CompiledRule(NamedTuple):
    """A rule's parameters and state classes as its kernels take them."""

    params: type
    state: type


#: Each rule's compiled parameters and state, by its name in :data:`kalmix.core.aggregators.RULES`.
COMPILED_RULES = {"boa": CompiledRule(BoaParams, BoaState), "boa_blend": CompiledRule(BoaParams, BoaBlendState),
                  "mlpoly": CompiledRule(MLPolyParams, MLPolyState),
                  "fixed_share": CompiledRule(FixedShareParams, FixedShareState)}


# ---------------------------------------------------------------------------------------------------- ML-Poly
@nb.njit(inline="always", **_JIT)
def mlpoly_target(state, n):
    return MLPolyState(state.regret[n], state.variance[n], state.bound[n:n + 1])


@nb.njit(inline="always", **_JIT)
def mlpoly_column(state, n):
    return MLPolyState(state.regret[:, n], state.variance[:, n], state.bound[n:n + 1])


@nb.njit(**_JIT)
def mlpoly_weights(params, s, awake, count, w, logw, r):
    k_count = w.shape[0]
    total = 0.0
    for k in range(k_count):
        denominator = s.variance[k] + s.bound[0]
        if awake[k] and denominator > 0:
            w[k] = max(s.regret[k], 0.0) / denominator
        else:
            w[k] = 0.0
        total += w[k]
    for k in range(k_count):
        if total > 0:
            w[k] = w[k] / total
        else:
            w[k] = 1.0 / max(count, 1) if awake[k] else 0.0
    share_floor(w, awake, count, params.share)


@nb.njit(**_JIT)
def mlpoly_learn(params, s, x, y, awake, count, w, logw, mix, r):
    biggest = regrets(x, y, mix, awake, r, False)
    if not math.isfinite(biggest):
        return  # an overflowing regret teaches nothing
    rho = params.forgetting
    for k in range(w.shape[0]):
        if awake[k]:
            s.regret[k] = rho * s.regret[k] + r[k]
            s.variance[k] = rho * s.variance[k] + r[k] * r[k]
    s.bound[0] = max(rho * s.bound[0], biggest)


@nb.njit(inline="always", **_JIT)
def mlpoly_restart(s):
    """The experts start again: ML-Poly keeps its state."""


@nb.njit(inline="always", **_JIT)
def mlpoly_cold(s):
    for k in range(s.regret.shape[0]):
        s.regret[k] = 0.0
        s.variance[k] = 0.0
    s.bound[0] = 0.0


# ---------------------------------------------------------------------------------------------------- fixed share
@nb.njit(inline="always", **_JIT)
def fixed_share_target(state, n):
    return FixedShareState(state.log_weights[n], state.squared[n:n + 1], state.count[n:n + 1])


@nb.njit(inline="always", **_JIT)
def fixed_share_column(state, n):
    return FixedShareState(state.log_weights[:, n], state.squared[n:n + 1], state.count[n:n + 1])


@nb.njit(**_JIT)
def fixed_share_weights(params, s, awake, count, w, logw, r):
    softmax(s.log_weights, awake, w)   # the shared weights are stored


@nb.njit(**_JIT)
def fixed_share_learn(params, s, x, y, awake, count, w, logw, mix, r):
    k_count = w.shape[0]
    p = x.shape[1]
    if count == 0:
        return
    sq = 0.0
    for ci in range(p):
        sq += (mix[ci] - y[ci]) ** 2
    worst = sq
    for k in range(k_count):
        if awake[k]:
            loss = 0.0
            for ci in range(p):
                loss += (y[ci] - x[k, ci]) ** 2
            if not math.isfinite(loss):
                worst = np.inf
            worst = max(worst, loss)
    if not math.isfinite(worst) or not math.isfinite(s.squared[0] + sq / p):
        return  # an overflowing loss (or running sum of losses) teaches nothing, as in the spec
    s.squared[0] += sq / p
    s.count[0] += 1.0
    scale = params.scale
    variance = scale * scale if scale > 0 else params.scale_factor * s.squared[0] / s.count[0]
    for k in range(k_count):
        if awake[k]:
            loss = 0.0
            for ci in range(p):
                loss += (y[ci] - x[k, ci]) ** 2
            r[k] = s.log_weights[k] - (loss / (2.0 * variance) if variance > 0 else 0.0)
    softmax(r, awake, w)
    for k in range(k_count):
        if awake[k]:
            s.log_weights[k] = math.log((1.0 - params.share) * w[k] + params.share / count)


@nb.njit(inline="always", **_JIT)
def fixed_share_restart(s):
    """The experts start again: fixed share keeps its state."""


@nb.njit(inline="always", **_JIT)
def fixed_share_cold(s):
    for k in range(s.log_weights.shape[0]):
        s.log_weights[k] = 0.0
    s.squared[0] = 0.0
    s.count[0] = 0.0


class _Rows(NamedTuple):
    """A rule's row functions."""

    target: object   # (state, n) -> target n's state (views of the (N, ...) arrays)
    column: object   # the same for a state with the target last ((K, N) arrays: the fused GPU kernel's)
    weights: object  # (params, s, awake, count, w, logw, r): the weights of the awake experts into w (logw, r: the
    #                  rule's scratch, which it may leave for its learn of the same row)
    learn: object    # (params, s, x, y, awake, count, w, logw, mix, r): learn a row's forecasts x and measurement y,
    #                  right after the weights of the same row and state (w, logw, r as they left them, mix their
    #                  mixture)
    restart: object  # (s): what a restart row (the experts start again) changes
    cold: object     # (s): the state as new (the screen's cold restart)


_ROWS = {BoaState: _Rows(boa_target, boa_column, boa_weights, boa_learn, boa_restart, boa_cold),
         BoaBlendState: _Rows(boa_blend_target, boa_blend_column, boa_blend_weights, boa_blend_learn,
                              boa_blend_restart, boa_blend_cold),
         MLPolyState: _Rows(mlpoly_target, mlpoly_column, mlpoly_weights, mlpoly_learn, mlpoly_restart,
                            mlpoly_cold),
         FixedShareState: _Rows(fixed_share_target, fixed_share_column, fixed_share_weights, fixed_share_learn,
                                fixed_share_restart, fixed_share_cold)}


def _rows(state_type):
    """The row functions of a rule's state type (a numba type when compiling, a class in Python)."""
    return _ROWS[getattr(state_type, "instance_class", state_type)]


# The generic row functions: in Python (the JIT off) they call the state's rule's; compiled, numba resolves the
# call by the state's type (each overload returns that rule's function).
def target(state, n):
    """Target ``n``'s state: the rule's state class holding views of its rows."""
    return _rows(type(state)).target(state, n)


def column(state, n):
    """:func:`target` for a state with the target last (``(K, N)`` arrays)."""
    return _rows(type(state)).column(state, n)


def weights_row(params, s, awake, count, w, logw, r):
    """The rule's weights of one target's awake experts into ``w (K,)`` (``logw``, ``r``: scratch (K,))."""
    _rows(type(s)).weights(params, s, awake, count, w, logw, r)


def learn_row(params, s, x, y, awake, count, w, logw, mix, r):
    """The rule learns one target's row: the experts' forecasts ``x (K, p)``, the measurement ``y (p,)``; called
    right after :func:`weights_row` of the same state and row, with ``w``, ``logw``, ``r`` as it left them."""
    _rows(type(s)).learn(params, s, x, y, awake, count, w, logw, mix, r)


def restart_row(s):
    """A restart row (the experts start again): what it changes in the rule (BOA's error scale starts again)."""
    _rows(type(s)).restart(s)


def rule_cold_row(s):
    """One target's rule state as new (every rule's state starts at 0)."""
    _rows(type(s)).cold(s)


@overload(target, jit_options=_JIT)
def _target(state, n):
    function = _rows(state).target
    return lambda state, n: function(state, n)


@overload(column, jit_options=_JIT)
def _column(state, n):
    function = _rows(state).column
    return lambda state, n: function(state, n)


@overload(weights_row, jit_options=_JIT)
def _weights_row(params, s, awake, count, w, logw, r):
    function = _rows(s).weights
    return lambda params, s, awake, count, w, logw, r: function(params, s, awake, count, w, logw, r)


@overload(learn_row, jit_options=_JIT)
def _learn_row(params, s, x, y, awake, count, w, logw, mix, r):
    function = _rows(s).learn
    return lambda params, s, x, y, awake, count, w, logw, mix, r: function(params, s, x, y, awake, count, w, logw,
                                                                           mix, r)


@overload(restart_row, jit_options=_JIT)
def _restart_row(s):
    function = _rows(s).restart
    return lambda s: function(s)


@overload(rule_cold_row, jit_options=_JIT)
def _rule_cold_row(s):
    function = _rows(s).cold
    return lambda s: function(s)


@nb.njit(inline="always", **_JIT)
def weigh_row(params, s, x, awake, w, logw, r, mix):
    """Weights and mixture of one target's forecasts ``x (K, p)``; returns the awake count."""
    count = awake_of(x, awake)
    weights_row(params, s, awake, count, w, logw, r)
    mix_of(x, w, awake, mix)
    return count


@nb.njit(inline="always", **_JIT)
def forecast_row(params, s, x, awake, w, logw, r, mix, variance, log_scale, max_variance, cov):
    """Weights, mixture and covariance of one target's forecasts ``x (K, p)``; returns the awake count."""
    count = weigh_row(params, s, x, awake, w, logw, r, mix)
    moments_row(x, w, awake, count, mix, variance, log_scale, max_variance, cov)
    return count


@nb.njit(inline="always", **_JIT)
def copy_matrix(source, out):
    """``out[:] = source`` without a temporary (the drivers run without the runtime that allocates one)."""
    for i in range(source.shape[0]):
        for j in range(source.shape[1]):
            out[i, j] = source[i, j]


@nb.njit(inline="always", **_JIT)
def write_row(count, mix, cov, out, out_std):
    """One target's forecast (NaN if no expert is awake) and its standard deviations."""
    for ci in range(mix.shape[0]):
        out[ci] = mix[ci] if count > 0 else np.nan
        out_std[ci] = math.sqrt(cov[ci, ci])


def scratch(k_count: int, p: int):
    """A target's scratch of :func:`forecast_row` and :func:`learn_row`: awake, w, logw, r, mix, cov."""
    return (np.empty(k_count, dtype=np.bool_), np.empty(k_count), np.empty(k_count), np.empty(k_count),
            np.empty(p), np.empty((p, p)))


@nb.njit(inline="always", **_JIT)
def cold_row(s, variance, n_errors, log_scale, initial_variance):
    """One target's rule and calibration as new (the variances at ``initial_variance``): the screen's cold
    restart."""
    rule_cold_row(s)
    for k in range(n_errors.shape[0]):
        n_errors[k] = 0.0
        for ci in range(variance.shape[1]):
            variance[k, ci] = initial_variance
    log_scale[0] = 0.0


class Rows(NamedTuple):
    """A block's rows as :func:`kernel` reads them."""

    experts: np.ndarray         # (B, N, K, p) the experts' forecasts of each row (NaN: asleep)
    ahead_experts: np.ndarray   # (B, N, K, p) their forecasts made after each row, or (0, 0, 0, 0)
    z: np.ndarray               # (B, N, p)
    lengths: np.ndarray         # (N,)
    learn: np.ndarray           # (B, N) rows the rule and the calibration learn
    points: np.ndarray          # (B, N) learned rows of the segment before each (the calibration's from_points)
    cold: np.ndarray            # (B, N) the screen's cold restarts
    restart: np.ndarray         # (B, N) the experts' restarts


class Out(NamedTuple):
    """The mixture's forecasts :func:`kernel` writes (an optional one an empty array)."""

    mean: np.ndarray        # (B, N, p)
    std: np.ndarray         # (B, N, p)
    cov: np.ndarray         # (B, N, p, p) or (0, 0, 0, 0)
    weights: np.ndarray     # (B, N, K) or (0, 0, 0)
    ahead: np.ndarray       # (B, N, p) the forecast for the ahead time, or (0, 0, 0)
    ahead_std: np.ndarray   # (B, N, p) or (0, 0, 0)


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, cal, cal_state, rows, out, scratch):
    """Mixture forecast of every row (weights before the row) and its covariance, then learn the row
    where ``rows.learn`` (the rule, and the calibration where it :func:`.calibration.learns`). ``params`` /
    ``state``: the rule's (:data:`COMPILED_RULES`); ``cal`` / ``cal_state``: the calibration's
    (:class:`.calibration.Constants`, :class:`kalmix.core.calibration.CalibrationState`); ``rows``
    (:class:`Rows`), ``out`` (:class:`Out`), ``scratch`` (:func:`scratch`). A ``cold`` row (the
    screen's cold restart) is forecast by the old rule and calibration, which then start again (the
    variances at ``cal.initial_variance``) before its ahead forecast; a ``restart`` row (the experts
    start again) changes what :func:`restart_row` says (BOA's error scale starts again). Targets
    ``lo .. hi - 1`` (one GPU thread runs it with ``lo, hi = j, j + 1``)."""
    window, rate, level, z_level, max_variance, max_log_scale, initial_variance, from_points = cal
    variance, n_errors, log_scale = cal_state
    experts, ahead_experts, z, lengths, learn, points, cold, restart = rows
    out_mean, out_std, out_cov, out_weights, out_ahead, out_ahead_std = out
    awake, w, logw, r, mix, cov = scratch
    k_count = experts.shape[2]
    want_weights = out_weights.shape[0] > 0
    want_ahead = out_ahead.shape[0] > 0
    want_cov = out_cov.shape[0] > 0
    for n in range(lo, hi):
        s = target(state, n)
        ls = log_scale[n:n + 1]
        for t in range(lengths[n]):
            x = experts[t, n]
            count = forecast_row(params, s, x, awake, w, logw, r, mix, variance[n], ls[0], max_variance, cov)
            write_row(count, mix, cov, out_mean[t, n], out_std[t, n])
            if want_cov:
                copy_matrix(cov, out_cov[t, n])
            if want_weights:
                for k in range(k_count):
                    out_weights[t, n, k] = w[k]
            if learn[t, n] and count > 0:
                if learns(from_points, points[t, n]):
                    calibrate_row(x, z[t, n], awake, count, mix, cov, variance[n], n_errors[n], ls, window, rate,
                                  level, z_level, max_variance, max_log_scale)
                learn_row(params, s, x, z[t, n], awake, count, w, logw, mix, r)
            if restart[t, n]:
                restart_row(s)
            if cold[t, n]:
                cold_row(s, variance[n], n_errors[n], ls, initial_variance)
            if want_ahead:
                count_ahead = forecast_row(params, s, ahead_experts[t, n], awake, w, logw, r, mix, variance[n], ls[0],
                                           max_variance, cov)
                write_row(count_ahead, mix, cov, out_ahead[t, n], out_ahead_std[t, n])
