"""A target's experts in the compiled AKF kernel (:mod:`._numba_kernels`): their state copied in and out with
the expert index last, and a target's origin moved (:func:`kalmix.core.mixture.reanchor`) or its mixture
started again (:func:`kalmix.core.mixture.restart`)."""

from __future__ import annotations

import numpy as np

from . import _numba_linalg as la
from ._numba_akf_rls import translate_statistics

jit = la.jit


@jit
def load_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                 expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, with_rls):
    """Copy target j's expert state (N, K, ...) into the experts-last working arrays (..., K)."""
    n, d, p = mu.shape[0], gm.shape[0], q.shape[0]
    for k in range(mu.shape[1]):
        for a in range(n):
            mu[a, k] = mean[j, k, a]
            off[a, k] = offset[j, k, a]
            for c in range(n):
                cv[a, c, k] = cov[j, k, a, c]
                trans[a, c, k] = transition[j, k, a, c]
        for i in range(p):
            q[i, k] = process_noise[j, k, i]
            r[i, k] = measurement_noise[j, k, i]
            ep[i, k] = expert_predictions[j, k, i]
        if with_rls:
            for a in range(d):
                for c in range(d):
                    gm[a, c, k] = gram[j, k, a, c]
            for i in range(p):
                for c in range(d):
                    cr[i, c, k] = cross[j, k, i, c]


@jit
def store_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                  expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, with_rls):
    """Inverse of :func:`load_experts`."""
    n, d, p = mu.shape[0], gm.shape[0], q.shape[0]
    for k in range(mu.shape[1]):
        for a in range(n):
            mean[j, k, a] = mu[a, k]
            offset[j, k, a] = off[a, k]
            for c in range(n):
                cov[j, k, a, c] = cv[a, c, k]
                transition[j, k, a, c] = trans[a, c, k]
        for i in range(p):
            process_noise[j, k, i] = q[i, k]
            measurement_noise[j, k, i] = r[i, k]
            expert_predictions[j, k, i] = ep[i, k]
        if with_rls:
            for a in range(d):
                for c in range(d):
                    gram[j, k, a, c] = gm[a, c, k]
            for i in range(p):
                for c in range(d):
                    cross[j, k, i, c] = cr[i, c, k]


@jit
def _prior_dynamics(k_count, n, p, prior, trans, off):
    """The prior's companion matrix and drift for every expert (experts last)."""
    for a in range(n):
        for c in range(n):
            value = prior[a, c] if a < p else (1.0 if c == a - p else 0.0)
            for k in range(k_count):
                trans[a, c, k] = value
        value = prior[a, n] if a < p else 0.0
        for k in range(k_count):
            off[a, k] = value


@jit
def reanchor_target(j, k_count, n, p, order, z, delta, prior, origin, history, gram, cross, mu, gm, cr,
                    trans, off, translate):
    """:func:`kalmix.core.mixture.reanchor` of target j: the origin moves to ``z`` (features ``delta``),
    the means with it; with ``translate`` (:func:`kalmix.core.mixture.translates`), the history too and
    the statistics (the working copies ``gm``, ``cr``, one per fit) and drifts as
    :func:`kalmix.core.mixture._translated` moves them, in its order of operations; otherwise RLS
    statistics zero (working copies and state), prior dynamics, no history."""
    for i in range(p):
        origin[j, i] = z[i]
        for lag in range(order):
            for k in range(k_count):
                mu[lag * p + i, k] = mu[lag * p + i, k] - delta[i]
    if not translate:
        gram[j] = 0.0
        cross[j] = 0.0
        gm[:] = 0.0
        cr[:] = 0.0
        for i in range(p):
            for lag in range(order):
                history[j, lag, i] = np.nan
        _prior_dynamics(k_count, n, p, prior, trans, off)
        return
    for lag in range(order):
        for i in range(p):
            history[j, lag, i] = history[j, lag, i] - delta[i]
    for u in range(gm.shape[2]):
        translate_statistics(gm[:, :, u], cr[:, :, u], n, p, delta)
    for i in range(p):   # drift u + (sum_j A_j - I) delta
        for k in range(k_count):
            acc = off[i, k]
            for column in range(n):
                acc = acc + trans[i, column, k] * delta[column % p]
            off[i, k] = acc - delta[i]


@jit
def restart_target(j, k_count, n, p, prior, process_init, measurement_init, initialised, origin, history,
                   gram, cross, gm, cr, trans, off, q, r, ep, gate_weights, gate_input, weights,
                   responsibilities, eta):
    """:func:`kalmix.core.mixture.restart` of target j: everything as before its first measurement,
    counters kept (the Kalman mean and covariance are set by the start that follows). The RLS
    statistics are zeroed in the working copies and in the state (stored back only for rls)."""
    gram[j] = 0.0
    cross[j] = 0.0
    initialised[j] = False
    for i in range(p):
        origin[j, i] = 0.0
    for lag in range(history.shape[1]):
        for i in range(p):
            history[j, lag, i] = np.nan
    gm[:] = 0.0
    cr[:] = 0.0
    _prior_dynamics(k_count, n, p, prior, trans, off)
    for i in range(p):
        for k in range(k_count):
            q[i, k] = process_init[k, i]
            r[i, k] = measurement_init[k, i]
            ep[i, k] = 0.0
    for k in range(k_count):
        for i in range(gate_weights.shape[2]):
            gate_weights[j, k, i] = 0.0
        weights[j, k] = 1.0 / k_count
        responsibilities[j, k] = 1.0 / k_count
    for i in range(gate_input.shape[1]):
        gate_input[j, i] = 0.0
    eta[j] = 0.0
