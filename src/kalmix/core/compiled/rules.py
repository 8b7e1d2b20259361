"""Compiled aggregation rules (:mod:`kalmix.core.aggregators`): same formulas, targets in ranges on threads.

Every rule's state is packed into the same five arrays (``a, b, c`` of shape ``(N, K)``,
``d, e`` of shape ``(N,)``) so that one driver, :func:`run_block`, serves them all:

=============  ===============  ===============  =============  ===========  =========
rule           a                b                c              d            e
=============  ===============  ===============  =============  ===========  =========
boa            regret           variance         bound          error_scale  error_count
mlpoly         regret           variance         --             bound        --
fixed_share    log_weights      --               --             squared      count
=============  ===============  ===============  =============  ===========  =========
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..aggregators import boa as _boa
from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache
from .calibration import calibrate_row, moments_row

configure_cache()

#: BOA's rows before its errors are clipped, and the memory of their scale (the spec's).
CLIP_WARMUP = float(_boa.CLIP_WARMUP)
CLIP_MEMORY = float(_boa.CLIP_MEMORY)

#: Rule codes of the driver, in the order of :data:`kalmix.core.aggregators.RULES`.
RULE_CODES = {"boa": 0, "mlpoly": 1, "fixed_share": 2}


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


@nb.njit(**_JIT)
def _weights(rule, forgetting, share, delay, a, b, c, d, awake, count, w, logw):
    k_count = w.shape[0]
    if rule == 0:  # BOA
        top = 0.0
        log_k = math.log(max(k_count, 2)) / delay
        for k in range(k_count):
            if b[k] > 0:
                eta = min(1.0 / (2.0 * c[k]), math.sqrt(log_k / b[k]))
                logw[k] = eta
                if eta > top:
                    top = eta
            else:
                logw[k] = -1.0
        fallback = top if top > 0 else 1.0
        for k in range(k_count):
            eta = logw[k] if logw[k] >= 0 else fallback
            logw[k] = math.log(eta) + eta * a[k]
        _softmax(logw, awake, w)
        _share(w, awake, count, share)
    elif rule == 1:  # ML-Poly
        total = 0.0
        for k in range(k_count):
            denominator = b[k] + d
            if awake[k] and denominator > 0:
                w[k] = max(a[k], 0.0) / denominator
            else:
                w[k] = 0.0
            total += w[k]
        for k in range(k_count):
            if total > 0:
                w[k] = w[k] / total
            else:
                w[k] = 1.0 / max(count, 1) if awake[k] else 0.0
        _share(w, awake, count, share)
    else:  # fixed share: the shared weights are stored
        _softmax(a, awake, w)


@nb.njit(inline="always", **_JIT)
def _mix(x, w, awake, out):
    for ci in range(x.shape[1]):
        acc = 0.0
        for k in range(x.shape[0]):
            if awake[k]:
                acc += w[k] * x[k, ci]
        out[ci] = acc


@nb.njit(**_JIT)
def learn_row(rule, forgetting, share, scale, scale_factor, bound_forgetting, delay, clip, a, b, c, d, e, x, y, awake,
              count, w, mix, r):
    k_count = w.shape[0]
    p = x.shape[1]
    if rule == 0 or rule == 1:
        # BOA's clip (see the spec, kalmix.core.aggregators.boa): the error shrunk to clip x its running RMS
        factor = 1.0
        squared = 0.0
        clipping = rule == 0 and math.isfinite(clip)
        if clipping:
            for ci in range(p):
                squared += (mix[ci] - y[ci]) * (mix[ci] - y[ci])
            if not math.isfinite(squared):
                return  # an overflowing squared error norm teaches nothing
            norm = math.sqrt(squared)
            if e[0] >= CLIP_WARMUP and d[0] > 0:
                limit = clip * math.sqrt(d[0])
                if norm > limit:
                    factor = limit / norm
        biggest = 0.0
        for k in range(k_count):
            if awake[k]:
                acc = 0.0
                for ci in range(p):
                    acc += (mix[ci] - y[ci]) * (mix[ci] - x[k, ci])
                r[k] = 2.0 * acc   # the whole regret (BOA's range bound takes it)
            else:
                r[k] = 0.0
            if not math.isfinite(r[k] * r[k]):
                biggest = np.inf
            elif r[k] * r[k] > biggest:
                biggest = r[k] * r[k]
        if not math.isfinite(biggest):
            return  # an overflowing regret teaches nothing
        if clipping:
            e[0] = min(e[0] + 1.0, CLIP_MEMORY)
            d[0] = d[0] + (squared - d[0]) / e[0]
        rho = forgetting
        if rule == 0:
            log_k = math.log(max(k_count, 2)) / delay
            for k in range(k_count):
                if awake[k]:
                    rk = r[k] * factor   # the regret of the clipped error (the whole one's, scaled)
                    variance = rho * b[k] + rk * rk
                    bound = max(bound_forgetting * c[k], abs(r[k]))
                    eta = min(1.0 / (2.0 * bound), math.sqrt(log_k / variance)) if variance > 0 else 0.0
                    a[k] = rho * a[k] + rk - eta * rk * rk
                    b[k] = variance
                    c[k] = bound
        else:
            for k in range(k_count):
                if awake[k]:
                    a[k] = rho * a[k] + r[k]
                    b[k] = rho * b[k] + r[k] * r[k]
            d[0] = max(rho * d[0], biggest)
    else:
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
        if not math.isfinite(worst) or not math.isfinite(d[0] + sq / p):
            return  # an overflowing loss (or running sum of losses) teaches nothing, as in the spec
        d[0] += sq / p
        e[0] += 1.0
        variance = scale * scale if scale > 0 else scale_factor * d[0] / e[0]
        for k in range(k_count):
            if awake[k]:
                loss = 0.0
                for ci in range(p):
                    loss += (y[ci] - x[k, ci]) ** 2
                r[k] = a[k] - (loss / (2.0 * variance) if variance > 0 else 0.0)
        _softmax(r, awake, w)
        for k in range(k_count):
            if awake[k]:
                a[k] = math.log((1.0 - share) * w[k] + share / count)


@nb.njit(inline="always", **_JIT)
def forecast_row(rule, forgetting, share, delay, a, b, c, d, x, awake, w, logw, mix, variance, log_scale, max_variance,
                 cov):
    """Weights, mixture and covariance of one target's forecasts ``x (K, p)``; returns the awake count."""
    count = _awake(x, awake)
    _weights(rule, forgetting, share, delay, a, b, c, d, awake, count, w, logw)
    _mix(x, w, awake, mix)
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
def restart_row(rule, d, e):
    """A restart row (the experts start again): BOA's error scale starts again (the spec's ``boa.restart``)."""
    if rule == 0:
        d[0] = 0.0
        e[0] = 0.0


@nb.njit(inline="always", **_JIT)
def cold_row(a, b, c, d, e, variance, n_errors, log_scale, initial_variance):
    """One target's rule and calibration as new (every rule's state starts at 0): the screen's cold restart."""
    for k in range(a.shape[0]):
        a[k] = 0.0
        b[k] = 0.0
        c[k] = 0.0
        n_errors[k] = 0.0
        for ci in range(variance.shape[1]):
            variance[k, ci] = initial_variance
    d[0] = 0.0
    e[0] = 0.0
    log_scale[0] = 0.0


def run_block(lo, hi, rule, forgetting, share, scale, scale_factor, bound_forgetting, delay, clip, a, b, c, d, e,
              window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors, log_scale,
              experts, z, lengths, learn, out, out_std, out_cov, out_weights, ahead_experts, out_ahead,
              out_ahead_std, cold, restart, initial_variance):
    """Mixture forecast of every row (weights before the row) and its covariance, then learn the row
    where ``learn`` (the rule and the calibration); ``out_cov`` and the others are optional (size 0).
    A ``cold`` row (the screen's cold restart) is forecast by the old rule and calibration, which then
    start again (the variances at ``initial_variance``) before its ahead forecast; a ``restart`` row (the
    experts start again) starts BOA's error scale again. Targets ``lo .. hi - 1``."""
    _run_block(lo, hi, rule, forgetting, share, scale, scale_factor, bound_forgetting, delay, clip, a, b, c, d, e,
               window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors, log_scale,
               experts, z, lengths, learn, out, out_std, out_cov, out_weights, ahead_experts, out_ahead,
               out_ahead_std, cold, restart, float(initial_variance), *scratch(experts.shape[2], z.shape[2]))


@nb.njit(**KERNEL_JIT)
def _run_block(lo, hi, rule, forgetting, share, scale, scale_factor, bound_forgetting, delay, clip, a, b, c, d, e,
               window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors, log_scale,
               experts, z, lengths, learn, out, out_std, out_cov, out_weights, ahead_experts, out_ahead,
               out_ahead_std, cold, restart, initial_variance, awake, w, logw, r, mix, cov):
    k_count = experts.shape[2]
    want_weights = out_weights.shape[0] > 0
    want_ahead = out_ahead.shape[0] > 0
    want_cov = out_cov.shape[0] > 0
    for n in range(lo, hi):
        dn = d[n:n + 1]
        en = e[n:n + 1]
        ls = log_scale[n:n + 1]
        for t in range(lengths[n]):
            x = experts[t, n]
            count = forecast_row(rule, forgetting, share, delay, a[n], b[n], c[n], dn[0], x, awake, w, logw, mix,
                                 variance[n], ls[0], max_variance, cov)
            write_row(count, mix, cov, out[t, n], out_std[t, n])
            if want_cov:
                copy_matrix(cov, out_cov[t, n])
            if want_weights:
                for k in range(k_count):
                    out_weights[t, n, k] = w[k]
            if learn[t, n] and count > 0:
                calibrate_row(x, z[t, n], awake, count, mix, cov, variance[n], n_errors[n], ls, window, rate,
                              level, z_level, max_variance, max_log_scale)
                learn_row(rule, forgetting, share, scale, scale_factor, bound_forgetting, delay, clip, a[n], b[n], c[n],
                          dn, en, x, z[t, n], awake, count, w, mix, r)
            if restart[t, n]:
                restart_row(rule, dn, en)
            if cold[t, n]:
                cold_row(a[n], b[n], c[n], dn, en, variance[n], n_errors[n], ls, initial_variance)
            if want_ahead:
                count_ahead = forecast_row(rule, forgetting, share, delay, a[n], b[n], c[n], dn[0], ahead_experts[t, n],
                                           awake, w, logw, mix, variance[n], ls[0], max_variance, cov)
                write_row(count_ahead, mix, cov, out_ahead[t, n], out_ahead_std[t, n])
