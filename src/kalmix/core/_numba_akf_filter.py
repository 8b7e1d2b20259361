"""The Kalman filter of the compiled AKF kernel (:mod:`._numba_kernels`), C = [I 0], experts last.

The measurement update in Joseph form (:func:`kalmix.core.kalman.kalman_update`), the start of a fresh
expert, the prediction through a block companion or a general system matrix, the process noise with the
variance cap, and the extrapolation ``H`` frames ahead, each for every expert of one target at once, in the
order of operations of :func:`kalmix.core.mixture.step`.
"""

from __future__ import annotations

import numpy as np

from . import _numba_linalg as la

jit = la.jit


@jit
def kalman_update(mu, cv, features, r, kappa, residual, r_diag, s_work, s_lower, s_lower_inv, s_inv, gain,
                  new_mean, w_block, tmp, acc):
    """Measurement update of every expert (Joseph form, as :func:`kalmix.core.kalman.update`).

    ``K = P C^T S^{-1}``, ``S = C P C^T + R``; ``x <- x + K (z - C x)``;
    ``P <- (I - K C) P (I - K C)^T + K R K^T = P - K P[:p, :] - W K^T`` with
    ``W = (I - K C) P C^T - K R``; the upper triangle is computed and mirrored.
    """
    experts = acc.shape[0]
    n, p = mu.shape[0], r.shape[0]
    for i in range(p):
        for k in range(experts):
            residual[i, k] = features[i] - mu[i, k]
            r_diag[i, k] = r[i, k] / kappa**2
    for a in range(p):
        for b in range(p):
            for k in range(experts):
                s_work[a, b, k] = cv[a, b, k]
        for k in range(experts):
            s_work[a, a, k] += r_diag[a, k]
    la.cholesky_inverse(s_work, p, 1e-12, s_lower, s_lower_inv, s_inv, acc)
    for a in range(n):
        for c in range(p):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(p):
                for k in range(experts):
                    acc[k] += cv[a, l, k] * s_inv[l, c, k]
            for k in range(experts):
                gain[a, c, k] = acc[k]
    for a in range(n):
        for k in range(experts):
            acc[k] = 0.0
        for c in range(p):
            for k in range(experts):
                acc[k] += gain[a, c, k] * residual[c, k]
        for k in range(experts):
            new_mean[a, k] = mu[a, k] + acc[k]
        for c in range(p):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(p):
                for k in range(experts):
                    acc[k] += gain[a, l, k] * cv[l, c, k]
            for k in range(experts):
                w_block[a, c, k] = (cv[a, c, k] - acc[k]) - gain[a, c, k] * r_diag[c, k]
    for a in range(n):
        for k in range(experts):
            mu[a, k] = new_mean[a, k]
    for a in range(n):
        for c in range(a, n):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(p):
                for k in range(experts):
                    acc[k] += gain[a, l, k] * cv[l, c, k] + w_block[a, l, k] * gain[c, l, k]
            for k in range(experts):
                tmp[a, c, k] = cv[a, c, k] - acc[k]
    for a in range(n):
        for c in range(a, n):
            for k in range(experts):
                value = tmp[a, c, k]
                cv[a, c, k] = value
                cv[c, a, k] = value


@jit
def kalman_start(mu, cv, features, order, kappa, initial_variance, initial_velocity, fresh):
    """Start the experts where ``fresh`` at this measurement: lags extrapolated back, P = P0 I."""
    experts = initial_variance.shape[0]
    n, p = mu.shape[0], features.shape[0]
    for lag in range(order):
        for i in range(p):
            for k in range(experts):
                if fresh[k]:
                    mu[lag * p + i, k] = features[i] - lag * (initial_velocity[k, i] / kappa)
    for a in range(n):
        for c in range(n):
            if a == c:
                for k in range(experts):
                    if fresh[k]:
                        cv[a, c, k] = initial_variance[k] / kappa**2
            else:
                for k in range(experts):
                    if fresh[k]:
                        cv[a, c, k] = 0.0


@jit
def predict_companion(mu, cv, trans, off, new_mean, g_block, acc):
    """``x <- A x + u``, ``P <- A P A^T`` for a block companion A = [Theta; I 0].

    ``x <- [Theta x + u_top; x[:n-p]]`` and
    ``P <- [[G Theta^T, G[:, :n-p]], [G[:, :n-p]^T, P[:n-p, :n-p]]]`` with ``G = Theta P``.
    """
    experts = acc.shape[0]
    n, p = mu.shape[0], g_block.shape[0]
    for a in range(p):
        for k in range(experts):
            acc[k] = 0.0
        for c in range(n):
            for k in range(experts):
                acc[k] += trans[a, c, k] * mu[c, k]
        for k in range(experts):
            new_mean[a, k] = acc[k] + off[a, k]
        for c in range(n):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(n):
                for k in range(experts):
                    acc[k] += trans[a, l, k] * cv[l, c, k]
            for k in range(experts):
                g_block[a, c, k] = acc[k]
    for a in range(p, n):
        for k in range(experts):
            new_mean[a, k] = mu[a - p, k] + off[a, k]
    for a in range(n):
        for k in range(experts):
            mu[a, k] = new_mean[a, k]
    for a in range(n - 1, p - 1, -1):  # shift the lower-right block in place
        for c in range(n - 1, a - 1, -1):
            for k in range(experts):
                value = cv[a - p, c - p, k]
                cv[a, c, k] = value
                cv[c, a, k] = value
    for a in range(p):
        for c in range(p, n):
            for k in range(experts):
                value = g_block[a, c - p, k]
                cv[a, c, k] = value
                cv[c, a, k] = value
        for c in range(a, p):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(n):
                for k in range(experts):
                    acc[k] += g_block[a, l, k] * trans[c, l, k]
            for k in range(experts):
                cv[a, c, k] = acc[k]
                cv[c, a, k] = acc[k]


@jit
def predict_full(mu, cv, trans, off, new_mean, tmp, tmp2, acc):
    """``x <- A x + u``, ``P <- (A P A^T + (A P A^T)^T) / 2`` for a general A."""
    experts = acc.shape[0]
    n = mu.shape[0]
    for a in range(n):
        for k in range(experts):
            acc[k] = 0.0
        for c in range(n):
            for k in range(experts):
                acc[k] += trans[a, c, k] * mu[c, k]
        for k in range(experts):
            new_mean[a, k] = acc[k] + off[a, k]
    for a in range(n):  # tmp = A P
        for c in range(n):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(n):
                for k in range(experts):
                    acc[k] += trans[a, l, k] * cv[l, c, k]
            for k in range(experts):
                tmp[a, c, k] = acc[k]
    for a in range(n):  # tmp2 = tmp A^T
        for c in range(n):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(n):
                for k in range(experts):
                    acc[k] += trans[c, l, k] * tmp[a, l, k]
            for k in range(experts):
                tmp2[a, c, k] = acc[k]
    for a in range(n):
        for k in range(experts):
            mu[a, k] = new_mean[a, k]
        for c in range(n):
            for k in range(experts):
                cv[a, c, k] = 0.5 * (tmp2[a, c, k] + tmp2[c, a, k])


@jit
def add_process_noise(cv, q, kappa, state_jitter, max_variance, acc, mu, before):
    """``P += Q + jitter I``, then scale P down where its largest variance exceeds the cap; there the
    expert's mean goes back to ``before`` (its value before the prediction: it stops extrapolating)."""
    experts = acc.shape[0]
    n, p = cv.shape[0], q.shape[0]
    for a in range(n):
        if a < p:
            for k in range(experts):
                cv[a, a, k] += state_jitter + q[a, k] / kappa**2
        else:
            for k in range(experts):
                cv[a, a, k] += state_jitter + 0.0
    for k in range(experts):
        acc[k] = -np.inf
    for a in range(n):
        for k in range(experts):
            acc[k] = max(acc[k], cv[a, a, k])
    capped = False
    for k in range(experts):
        acc[k] = min(1.0, max_variance / acc[k])
        capped = capped or acc[k] != 1.0
    if capped:  # only after very long runs of missing measurements
        for a in range(n):
            for c in range(n):
                for k in range(experts):
                    if acc[k] != 1.0:
                        cv[a, c, k] = cv[a, c, k] * acc[k]
            for k in range(experts):
                if acc[k] != 1.0:
                    mu[a, k] = before[a, k]


@jit
def extrapolate(mu, trans, off, steps, ahead, scratch, acc):
    """``ahead = (x -> A x + u)^steps (mu)`` for every expert."""
    experts = acc.shape[0]
    n = mu.shape[0]
    for a in range(n):
        for k in range(experts):
            ahead[a, k] = mu[a, k]
    for _ in range(steps):
        for a in range(n):
            for k in range(experts):
                acc[k] = 0.0
            for c in range(n):
                for k in range(experts):
                    acc[k] += trans[a, c, k] * ahead[c, k]
            for k in range(experts):
                scratch[a, k] = acc[k] + off[a, k]
        for a in range(n):
            for k in range(experts):
                ahead[a, k] = scratch[a, k]
