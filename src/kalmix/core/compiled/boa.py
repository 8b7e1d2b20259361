"""Compiled BOA and BOA-blend (:mod:`kalmix.core.aggregators.boa`, :mod:`kalmix.core.aggregators.boa_blend`):
their parameters and states as the kernels take them, and their row functions (:mod:`.rules` dispatches to them
by the state's type)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from ..aggregators import boa as _boa
from ._cache import JIT as _JIT
from ._cache import configure_cache
from .rule_rows import mix_of, regrets, share_floor, softmax

configure_cache()

__all__ = ["CLIP_WARMUP", "CLIP_MEMORY", "BoaParams", "BoaState", "BoaBlendState", "boa_target", "boa_column",
           "boa_weights", "boa_learn", "boa_restart", "boa_cold", "boa_blend_target", "boa_blend_column",
           "boa_blend_weights", "boa_blend_learn", "boa_blend_restart", "boa_blend_cold"]

#: BOA's rows before its errors are clipped, and the memory of their scale (the spec's).
CLIP_WARMUP = float(_boa.CLIP_WARMUP)
CLIP_MEMORY = float(_boa.CLIP_MEMORY)


class BoaParams(NamedTuple):
    """BOA's parameters as its kernel reads them (:class:`kalmix.core.aggregators.boa.Params`)."""

    forgetting: float
    share: float
    bound_forgetting: float
    delay: float
    clip: float


class BoaState(NamedTuple):
    """BOA's state (:class:`kalmix.core.aggregators.boa.State`)."""

    regret: np.ndarray        # (N, K)
    variance: np.ndarray      # (N, K)
    bound: np.ndarray         # (N, K)
    error_scale: np.ndarray   # (N,)
    error_count: np.ndarray   # (N,)


class BoaBlendState(NamedTuple):
    """BOA-blend's state (:class:`kalmix.core.aggregators.boa_blend.State`)."""

    regret: np.ndarray              # (N, K) the linearised rule's
    variance: np.ndarray            # (N, K)
    bound: np.ndarray               # (N, K)
    error_scale: np.ndarray         # (N,)
    error_count: np.ndarray         # (N,)
    exact_regret: np.ndarray        # (N, K) the exact rule's
    exact_variance: np.ndarray      # (N, K)
    exact_bound: np.ndarray         # (N, K)
    exact_error_scale: np.ndarray   # (N,)
    exact_error_count: np.ndarray   # (N,)
    blend_regret: np.ndarray        # (N, 2) the blend's, over the two rules' mixtures
    blend_variance: np.ndarray      # (N, 2)
    blend_bound: np.ndarray         # (N, 2)


# ---------------------------------------------------------------------------------------------------- BOA
@nb.njit(inline="always", **_JIT)
def boa_target(state, n):
    return BoaState(state.regret[n], state.variance[n], state.bound[n], state.error_scale[n:n + 1],
                    state.error_count[n:n + 1])


@nb.njit(inline="always", **_JIT)
def boa_column(state, n):
    return BoaState(state.regret[:, n], state.variance[:, n], state.bound[:, n], state.error_scale[n:n + 1],
                    state.error_count[n:n + 1])


@nb.njit(inline="always", **_JIT)
def _boa_weights(params, regret, variance, bound, awake, count, w, logw):
    """BOA's weights of the awake experts into ``w (K,)`` from its arrays ``regret, variance, bound (K,)``
    (``logw`` scratch; it may be ``w`` itself)."""
    k_count = w.shape[0]
    top = 0.0
    log_k = math.log(max(k_count, 2)) / params.delay
    for k in range(k_count):
        if variance[k] > 0:
            eta = min(1.0 / (2.0 * bound[k]), math.sqrt(log_k / variance[k]))
            logw[k] = eta
            if eta > top:
                top = eta
        else:
            logw[k] = -1.0
    fallback = top if top > 0 else 1.0
    for k in range(k_count):
        eta = logw[k] if logw[k] >= 0 else fallback
        logw[k] = math.log(eta) + eta * regret[k]
    softmax(logw, awake, w)
    share_floor(w, awake, count, params.share)


@nb.njit(inline="always", **_JIT)
def _boa_learn(params, regret, variance, bound, error_scale, error_count, x, y, awake, mix, r, exact):
    """BOA learns a row (the experts' forecasts ``x (K, p)``, their mixture ``mix``, the measurement ``y``) into
    its arrays: ``regret, variance, bound (K,)``, the clip's ``error_scale, error_count (1,)``; ``r`` scratch;
    ``exact``: the squared loss's regrets instead of the linearised ones."""
    k_count = x.shape[0]
    p = x.shape[1]
    # the clip (see the spec, kalmix.core.aggregators.boa): the error shrunk to clip x its running RMS
    factor = 1.0
    squared = 0.0
    clipping = math.isfinite(params.clip)
    if clipping:
        for ci in range(p):
            squared += (mix[ci] - y[ci]) * (mix[ci] - y[ci])
        if not math.isfinite(squared):
            return  # an overflowing squared error norm teaches nothing
        norm = math.sqrt(squared)
        if error_count[0] >= CLIP_WARMUP and error_scale[0] > 0:
            limit = params.clip * math.sqrt(error_scale[0])
            if norm > limit:
                factor = limit / norm
    biggest = regrets(x, y, mix, awake, r, exact)
    if not math.isfinite(biggest):
        return  # an overflowing regret teaches nothing
    if clipping:
        error_count[0] = min(error_count[0] + 1.0, CLIP_MEMORY)
        error_scale[0] = error_scale[0] + (squared - error_scale[0]) / error_count[0]
    rho = params.forgetting
    log_k = math.log(max(k_count, 2)) / params.delay
    for k in range(k_count):
        if awake[k]:
            rk = r[k] * factor   # the regret of the clipped error (the whole one's, scaled)
            v = rho * variance[k] + rk * rk
            b = max(params.bound_forgetting * bound[k], abs(r[k]))
            eta = min(1.0 / (2.0 * b), math.sqrt(log_k / v)) if v > 0 else 0.0
            regret[k] = rho * regret[k] + rk - eta * rk * rk
            variance[k] = v
            bound[k] = b


@nb.njit(**_JIT)
def boa_weights(params, s, awake, count, w, logw, r):
    _boa_weights(params, s.regret, s.variance, s.bound, awake, count, w, logw)


@nb.njit(**_JIT)
def boa_learn(params, s, x, y, awake, count, w, logw, mix, r):
    _boa_learn(params, s.regret, s.variance, s.bound, s.error_scale, s.error_count, x, y, awake, mix, r, False)


@nb.njit(inline="always", **_JIT)
def boa_restart(s):
    """The experts start again: so does the error scale (the spec's ``boa.restart``)."""
    s.error_scale[0] = 0.0
    s.error_count[0] = 0.0


@nb.njit(inline="always", **_JIT)
def _as_new(regret, variance, bound):
    """A BOA's weights' state as new (every array at 0)."""
    for k in range(regret.shape[0]):
        regret[k] = 0.0
        variance[k] = 0.0
        bound[k] = 0.0


@nb.njit(inline="always", **_JIT)
def boa_cold(s):
    _as_new(s.regret, s.variance, s.bound)
    boa_restart(s)


# ---------------------------------------------------------------------------------------------------- BOA-blend
@nb.njit(inline="always", **_JIT)
def boa_blend_target(state, n):
    return BoaBlendState(state.regret[n], state.variance[n], state.bound[n], state.error_scale[n:n + 1],
                         state.error_count[n:n + 1], state.exact_regret[n], state.exact_variance[n],
                         state.exact_bound[n], state.exact_error_scale[n:n + 1], state.exact_error_count[n:n + 1],
                         state.blend_regret[n], state.blend_variance[n], state.blend_bound[n])


@nb.njit(inline="always", **_JIT)
def boa_blend_column(state, n):
    return BoaBlendState(state.regret[:, n], state.variance[:, n], state.bound[:, n], state.error_scale[n:n + 1],
                         state.error_count[n:n + 1], state.exact_regret[:, n], state.exact_variance[:, n],
                         state.exact_bound[:, n], state.exact_error_scale[n:n + 1], state.exact_error_count[n:n + 1],
                         state.blend_regret[:, n], state.blend_variance[:, n], state.blend_bound[:, n])


@nb.njit(inline="always", **_JIT)
def _blend_eta(variance, bound, log_2):
    return min(1.0 / (2.0 * bound), math.sqrt(log_2 / variance)) if variance > 0 else -1.0


@nb.njit(inline="always", **_JIT)
def _blend_share(params, s):
    """The blend's weight on the linearised rule (BOA over the two rules' mixtures, without a share)."""
    log_2 = math.log(2.0) / params.delay
    eta0 = _blend_eta(s.blend_variance[0], s.blend_bound[0], log_2)
    eta1 = _blend_eta(s.blend_variance[1], s.blend_bound[1], log_2)
    top = max(max(eta0, eta1), 0.0)
    fallback = top if top > 0 else 1.0
    eta0 = eta0 if eta0 >= 0 else fallback
    eta1 = eta1 if eta1 >= 0 else fallback
    l0 = math.log(eta0) + eta0 * s.blend_regret[0]
    l1 = math.log(eta1) + eta1 * s.blend_regret[1]
    high = max(l0, l1)
    if not math.isfinite(high):
        high = 0.0
    a = math.exp(l0 - high)
    total = 0.0 + a + math.exp(l1 - high)
    return a / total if total > 0 else 0.0


@nb.njit(**_JIT)
def boa_blend_weights(params, s, awake, count, w, logw, r):
    """The blend's weights into ``w``; the linearised rule's stay in ``r`` and the exact rule's in ``logw``, for
    :func:`boa_blend_learn` of the same row (the state is the same then: it does not compute them again)."""
    beta = _blend_share(params, s)
    _boa_weights(params, s.regret, s.variance, s.bound, awake, count, r, r)
    _boa_weights(params, s.exact_regret, s.exact_variance, s.exact_bound, awake, count, logw, logw)
    for k in range(w.shape[0]):
        w[k] = beta * r[k] + (1.0 - beta) * logw[k]


@nb.njit(**_JIT)
def boa_blend_learn(params, s, x, y, awake, count, w, logw, mix, r):
    k_count = x.shape[0]
    p = x.shape[1]
    beta = _blend_share(params, s)
    for k in range(k_count):   # w: the linearised rule's weights, r free for the regrets; logw: the exact rule's
        w[k] = r[k]
    g0 = 0.0
    g1 = 0.0
    for ci in range(p):
        lin = 0.0
        ex = 0.0
        for k in range(k_count):
            if awake[k]:
                lin += w[k] * x[k, ci]
                ex += logw[k] * x[k, ci]
        both = beta * lin + (1.0 - beta) * ex
        g0 += (both - y[ci]) * (both - lin)
        g1 += (both - y[ci]) * (both - ex)
        mix[ci] = ex
    g0 = 2.0 * g0
    g1 = 2.0 * g1
    if math.isfinite(g0 * g0) and math.isfinite(g1 * g1):   # (an overflowing regret teaches nothing)
        rho = params.forgetting
        log_2 = math.log(2.0) / params.delay
        for j in range(2):
            rj = g0 if j == 0 else g1
            v = rho * s.blend_variance[j] + rj * rj
            b = max(params.bound_forgetting * s.blend_bound[j], abs(rj))
            eta = min(1.0 / (2.0 * b), math.sqrt(log_2 / v)) if v > 0 else 0.0
            s.blend_regret[j] = rho * s.blend_regret[j] + rj - eta * rj * rj
            s.blend_variance[j] = v
            s.blend_bound[j] = b
    _boa_learn(params, s.exact_regret, s.exact_variance, s.exact_bound, s.exact_error_scale, s.exact_error_count,
               x, y, awake, mix, r, True)
    mix_of(x, w, awake, mix)
    _boa_learn(params, s.regret, s.variance, s.bound, s.error_scale, s.error_count, x, y, awake, mix, r, False)


@nb.njit(inline="always", **_JIT)
def boa_blend_restart(s):
    """The experts start again: so do both rules' error scales."""
    s.error_scale[0] = 0.0
    s.error_count[0] = 0.0
    s.exact_error_scale[0] = 0.0
    s.exact_error_count[0] = 0.0


@nb.njit(inline="always", **_JIT)
def boa_blend_cold(s):
    _as_new(s.regret, s.variance, s.bound)
    _as_new(s.exact_regret, s.exact_variance, s.exact_bound)
    _as_new(s.blend_regret, s.blend_variance, s.blend_bound)
    boa_blend_restart(s)
