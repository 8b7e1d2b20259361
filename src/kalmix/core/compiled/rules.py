"""Compiled aggregation rules (:mod:`kalmix.core.aggregators`): same formulas, targets in ranges on threads.

Each rule has its own parameters and state as the kernels take them, named tuples with the
spec's names (:class:`BoaParams` / :class:`BoaState`, :class:`MLPolyParams` / :class:`MLPolyState`,
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

from ..aggregators import boa as _boa
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .calibration import calibrate_row, moments_row

configure_cache()

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


@nb.njit(inline="always", **_JIT)
def _awake(x, awake):
    """Which experts' forecasts ``x (K, p)`` are finite; returns how many."""
    count = 0
    for k in range(x.shape[0]):
        ok = True
        for c in range(x.shape[1]):
            if not math.isfinite(x[k, c]):
                ok = False
        awake[k] = ok
        if ok:
            count += 1
    return count


@nb.njit(inline="always", **_JIT)
def _softmax(logw, awake, w):
    top = -np.inf
    for k in range(w.shape[0]):
        if awake[k] and logw[k] > top:
            top = logw[k]
    if not math.isfinite(top):
        top = 0.0
    total = 0.0
    for k in range(w.shape[0]):
        w[k] = math.exp(logw[k] - top) if awake[k] else 0.0
        total += w[k]
    for k in range(w.shape[0]):
        w[k] = w[k] / total if total > 0 else 0.0


@nb.njit(inline="always", **_JIT)
def _share(w, awake, count, share):
    if share > 0:
        for k in range(w.shape[0]):
            w[k] = (1.0 - share) * w[k] + (share / max(count, 1) if awake[k] else 0.0)


@nb.njit(inline="always", **_JIT)
def _mix(x, w, awake, out):
    for ci in range(x.shape[1]):
        acc = 0.0
        for k in range(x.shape[0]):
            if awake[k]:
                acc += w[k] * x[k, ci]
        out[ci] = acc


@nb.njit(inline="always", **_JIT)
def _regrets(x, y, mix, awake, r, exact):
    """The linearised regrets ``r (K,)`` of the awake experts (0 for the others), or with ``exact`` the squared
    loss's own (:math:`\\lVert \\hat y - y \\rVert^2 - \\lVert x_k - y \\rVert^2`, the linearised one less
    :math:`\\lVert x_k - \\hat y \\rVert^2`); returns the largest squared one (inf if one overflows)."""
    biggest = 0.0
    for k in range(r.shape[0]):
        if awake[k]:
            acc = 0.0
            for ci in range(x.shape[1]):
                acc += (mix[ci] - y[ci]) * (mix[ci] - x[k, ci])
            r[k] = 2.0 * acc   # the whole regret (BOA's range bound takes it)
            if exact:
                far = 0.0
                for ci in range(x.shape[1]):
                    far += (x[k, ci] - mix[ci]) * (x[k, ci] - mix[ci])
                r[k] = r[k] - far
        else:
            r[k] = 0.0
        if not math.isfinite(r[k] * r[k]):
            biggest = np.inf
        elif r[k] * r[k] > biggest:
            biggest = r[k] * r[k]
    return biggest


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
    _softmax(logw, awake, w)
    _share(w, awake, count, params.share)


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
    biggest = _regrets(x, y, mix, awake, r, exact)
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
def boa_weights(params, s, awake, count, w, logw):
    _boa_weights(params, s.regret, s.variance, s.bound, awake, count, w, logw)


@nb.njit(**_JIT)
def boa_learn(params, s, x, y, awake, count, w, mix, r):
    _boa_learn(params, s.regret, s.variance, s.bound, s.error_scale, s.error_count, x, y, awake, mix, r, False)


@nb.njit(inline="always", **_JIT)
def boa_restart(s):
    """The experts start again: so does the error scale (the spec's ``boa.restart``)."""
    s.error_scale[0] = 0.0
    s.error_count[0] = 0.0


@nb.njit(inline="always", **_JIT)
def boa_cold(s):
    for k in range(s.regret.shape[0]):
        s.regret[k] = 0.0
        s.variance[k] = 0.0
        s.bound[k] = 0.0
    s.error_scale[0] = 0.0
    s.error_count[0] = 0.0


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
def boa_blend_weights(params, s, awake, count, w, logw):
    beta = _blend_share(params, s)
    _boa_weights(params, s.regret, s.variance, s.bound, awake, count, w, logw)
    _boa_weights(params, s.exact_regret, s.exact_variance, s.exact_bound, awake, count, logw, logw)
    for k in range(w.shape[0]):
        w[k] = beta * w[k] + (1.0 - beta) * logw[k]


@nb.njit(**_JIT)
def boa_blend_learn(params, s, x, y, awake, count, w, mix, r):
    k_count = x.shape[0]
    p = x.shape[1]
    beta = _blend_share(params, s)
    _boa_weights(params, s.regret, s.variance, s.bound, awake, count, w, r)   # w: the linearised rule's
    _boa_weights(params, s.exact_regret, s.exact_variance, s.exact_bound, awake, count, r, r)   # r: the exact's
    g0 = 0.0
    g1 = 0.0
    for ci in range(p):
        lin = 0.0
        ex = 0.0
        for k in range(k_count):
            if awake[k]:
                lin += w[k] * x[k, ci]
                ex += r[k] * x[k, ci]
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
    _mix(x, w, awake, mix)
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
    for k in range(s.regret.shape[0]):
        s.regret[k] = 0.0
        s.variance[k] = 0.0
        s.bound[k] = 0.0
        s.exact_regret[k] = 0.0
        s.exact_variance[k] = 0.0
        s.exact_bound[k] = 0.0
    for j in range(2):
        s.blend_regret[j] = 0.0
        s.blend_variance[j] = 0.0
        s.blend_bound[j] = 0.0
    boa_blend_restart(s)


# ---------------------------------------------------------------------------------------------------- ML-Poly
@nb.njit(inline="always", **_JIT)
def mlpoly_target(state, n):
    return MLPolyState(state.regret[n], state.variance[n], state.bound[n:n + 1])


@nb.njit(inline="always", **_JIT)
def mlpoly_column(state, n):
    return MLPolyState(state.regret[:, n], state.variance[:, n], state.bound[n:n + 1])


@nb.njit(**_JIT)
def mlpoly_weights(params, s, awake, count, w, logw):
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
    _share(w, awake, count, params.share)


@nb.njit(**_JIT)
def mlpoly_learn(params, s, x, y, awake, count, w, mix, r):
    biggest = _regrets(x, y, mix, awake, r, False)
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
def fixed_share_weights(params, s, awake, count, w, logw):
    _softmax(s.log_weights, awake, w)   # the shared weights are stored


@nb.njit(**_JIT)
def fixed_share_learn(params, s, x, y, awake, count, w, mix, r):
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
    _softmax(r, awake, w)
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
    weights: object  # (params, s, awake, count, w, logw): the weights of the awake experts into w
    learn: object    # (params, s, x, y, awake, count, w, mix, r): learn a row's forecasts x and measurement y
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


def weights_row(params, s, awake, count, w, logw):
    """The rule's weights of one target's awake experts into ``w (K,)``."""
    _rows(type(s)).weights(params, s, awake, count, w, logw)


def learn_row(params, s, x, y, awake, count, w, mix, r):
    """The rule learns one target's row: the experts' forecasts ``x (K, p)``, the measurement ``y (p,)``."""
    _rows(type(s)).learn(params, s, x, y, awake, count, w, mix, r)


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
def _weights_row(params, s, awake, count, w, logw):
    function = _rows(s).weights
    return lambda params, s, awake, count, w, logw: function(params, s, awake, count, w, logw)


@overload(learn_row, jit_options=_JIT)
def _learn_row(params, s, x, y, awake, count, w, mix, r):
    function = _rows(s).learn
    return lambda params, s, x, y, awake, count, w, mix, r: function(params, s, x, y, awake, count, w, mix, r)


@overload(restart_row, jit_options=_JIT)
def _restart_row(s):
    function = _rows(s).restart
    return lambda s: function(s)


@overload(rule_cold_row, jit_options=_JIT)
def _rule_cold_row(s):
    function = _rows(s).cold
    return lambda s: function(s)


@nb.njit(inline="always", **_JIT)
def weigh_row(params, s, x, awake, w, logw, mix):
    """Weights and mixture of one target's forecasts ``x (K, p)``; returns the awake count."""
    count = _awake(x, awake)
    weights_row(params, s, awake, count, w, logw)
    _mix(x, w, awake, mix)
    return count


@nb.njit(inline="always", **_JIT)
def forecast_row(params, s, x, awake, w, logw, mix, variance, log_scale, max_variance, cov):
    """Weights, mixture and covariance of one target's forecasts ``x (K, p)``; returns the awake count."""
    count = weigh_row(params, s, x, awake, w, logw, mix)
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
    where ``rows.learn`` (the rule and the calibration). ``params`` / ``state``: the rule's
    (:data:`COMPILED_RULES`); ``cal`` / ``cal_state``: the calibration's
    (:class:`.calibration.Constants`, :class:`kalmix.core.calibration.CalibrationState`); ``rows``
    (:class:`Rows`), ``out`` (:class:`Out`), ``scratch`` (:func:`scratch`). A ``cold`` row (the
    screen's cold restart) is forecast by the old rule and calibration, which then start again (the
    variances at ``cal.initial_variance``) before its ahead forecast; a ``restart`` row (the experts
    start again) changes what :func:`restart_row` says (BOA's error scale starts again). Targets
    ``lo .. hi - 1`` (one GPU thread runs it with ``lo, hi = j, j + 1``)."""
    window, rate, level, z_level, max_variance, max_log_scale, initial_variance = cal
    variance, n_errors, log_scale = cal_state
    experts, ahead_experts, z, lengths, learn, cold, restart = rows
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
            count = forecast_row(params, s, x, awake, w, logw, mix, variance[n], ls[0], max_variance, cov)
            write_row(count, mix, cov, out_mean[t, n], out_std[t, n])
            if want_cov:
                copy_matrix(cov, out_cov[t, n])
            if want_weights:
                for k in range(k_count):
                    out_weights[t, n, k] = w[k]
            if learn[t, n] and count > 0:
                calibrate_row(x, z[t, n], awake, count, mix, cov, variance[n], n_errors[n], ls, window, rate,
                              level, z_level, max_variance, max_log_scale)
                learn_row(params, s, x, z[t, n], awake, count, w, mix, r)
            if restart[t, n]:
                restart_row(s)
            if cold[t, n]:
                cold_row(s, variance[n], n_errors[n], ls, initial_variance)
            if want_ahead:
                count_ahead = forecast_row(params, s, ahead_experts[t, n], awake, w, logw, mix, variance[n], ls[0],
                                           max_variance, cov)
                write_row(count_ahead, mix, cov, out_ahead[t, n], out_ahead_std[t, n])
