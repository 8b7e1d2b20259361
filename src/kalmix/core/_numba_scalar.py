"""Numba kernel for small banks (K < 8 experts): one expert at a time, scalar loops.

The experts-last kernel (:mod:`kalmix.core._numba_kernels`) vectorises across the
experts; with fewer experts than fill a few vectors its unit-stride loops are mostly
overhead, and this kernel, which advances each expert with scalar loops on small
matrices and keeps its running sums in registers, is faster there. Same operations as the numpy reference
(:func:`kalmix.core.mixture.step`), same numbers to rounding; :func:`run_targets` has
the signature of the other kernel's.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import _numba_linalg as la
from .compiled._cache import JIT as _JIT
from ._numba_kernels import (held_near, learn_gate, learning_rate, next_gate, posterior, stepped_on,
                             translate_statistics)

jit = la.jit
jit_inline = nb.njit(inline="always", **_JIT)


# ---------------------------------------------------------------- small dense algebra
@jit_inline
def _cholesky_lower(source, m, work):
    """Cholesky factor of the leading ``m x m`` block of ``source`` into the lower triangle of ``work``.

    ``source`` may be ``work`` itself (each entry is read before it is overwritten).
    """
    for j in range(m):
        acc = source[j, j]
        for k in range(j):
            acc -= work[j, k] * work[j, k]
        diag = math.sqrt(acc)
        work[j, j] = diag
        for i in range(j + 1, m):
            acc = source[i, j]
            for k in range(j):
                acc -= work[i, k] * work[j, k]
            work[i, j] = acc / diag


@jit_inline
def _chol_inverse(spd, m, jitter, work, lower_inv, inverse):
    """``cholesky_inverse`` of the top-left m x m block of ``spd`` (the log-determinant is not needed)."""
    scale = 0.0
    for i in range(m):
        scale += spd[i, i]
    scale = scale / m
    boost = jitter * scale
    for i in range(m):
        for j in range(m):
            work[i, j] = 0.5 * (spd[i, j] + spd[j, i])
        work[i, i] += boost
    _cholesky_lower(work, m, work)  # lower triangle in place
    # L^{-1} by forward substitution
    for c in range(m):
        for i in range(m):
            if i < c:
                lower_inv[i, c] = 0.0
                continue
            acc = 1.0 if i == c else 0.0
            for k in range(c, i):
                acc -= work[i, k] * lower_inv[k, c]
            lower_inv[i, c] = acc / work[i, i]
    # S^{-1} = L^{-T} L^{-1}
    for i in range(m):
        for j in range(i, m):
            acc = 0.0
            for k in range(j, m):
                acc += lower_inv[k, i] * lower_inv[k, j]
            inverse[i, j] = acc
            inverse[j, i] = acc


@jit_inline
def _cholesky_solve_rows(spd, m, rhs, rows, work, out):
    """``out[r] = spd^{-1} rhs[r]`` for r < rows (``spd`` symmetric positive definite)."""
    _cholesky_lower(spd, m, work)
    # the right-hand sides are solved together so the inner loops are independent
    for i in range(m):  # L y = b
        for r in range(rows):
            acc = rhs[r, i]
            for k in range(i):
                acc -= work[i, k] * out[r, k]
            out[r, i] = acc / work[i, i]
    for i in range(m - 1, -1, -1):  # L^T x = y
        for r in range(rows):
            acc = out[r, i]
            for k in range(i + 1, m):
                acc -= work[k, i] * out[r, k]
            out[r, i] = acc / work[i, i]


@jit_inline
def _poly_mul_add(a, b, degree, sign, out):
    """``out += sign * a * b`` for polynomials of ``degree + 1`` coefficients (low order first)."""
    for i in range(degree + 1):
        ai = sign * a[i]
        for k in range(degree + 1):
            out[i + k] += ai * b[k]


@jit_inline
def _char_poly_small(theta, p, order, entries, minor, coef):
    """det(lambda I - A) of the block companion of ``theta`` for p <= 3, by cofactors.

    :math:`\\det(\\lambda I - A) = \\det(\\lambda^o I - \\sum_l \\Theta_l \\lambda^{o-l})`,
    a p x p determinant of polynomials of degree o.
    """
    n = order * p
    for i in range(p):
        for c in range(p):
            for e in range(order + 1):
                entries[i, c, e] = 0.0
            entries[i, c, order] = 1.0 if i == c else 0.0
            for lag in range(1, order + 1):
                entries[i, c, order - lag] -= theta[i, (lag - 1) * p + c]
    for e in range(n + 1):
        coef[e] = 0.0
    if p == 1:
        for e in range(order + 1):
            coef[e] = entries[0, 0, e]
    elif p == 2:
        _poly_mul_add(entries[0, 0], entries[1, 1], order, 1.0, coef)
        _poly_mul_add(entries[0, 1], entries[1, 0], order, -1.0, coef)
    else:
        for col in range(3):
            c1 = 1 if col == 0 else 0
            c2 = 1 if col == 2 else 2
            for e in range(2 * order + 1):
                minor[e] = 0.0
            _poly_mul_add(entries[1, c1], entries[2, c2], order, 1.0, minor)
            _poly_mul_add(entries[1, c2], entries[2, c1], order, -1.0, minor)
            sign = -1.0 if col == 1 else 1.0
            for i in range(order + 1):
                value = sign * entries[0, col, i]
                for e in range(2 * order + 1):
                    coef[i + e] += value * minor[e]


@jit_inline
def _schur_step_test(coef, n, radius, work, saved):
    """Schur-Cohn: every root of ``sum coef[k] x^k`` lies strictly inside ``|x| < radius``."""
    scale = 1.0
    for k in range(n + 1):
        work[k] = coef[k] * scale
        scale *= radius
    m = n
    while m > 0:
        a0 = work[0]
        am = work[m]
        if not abs(a0) < abs(am):
            return False
        for i in range(m + 1):
            saved[i] = work[i]
        norm = 1.0 / (abs(am) + abs(a0))
        for i in range(m):
            work[i] = (am * saved[i + 1] - a0 * saved[m - 1 - i]) * norm
        m -= 1
    return True


@jit_inline
def _radius_le(theta, transition, p, n, bound, power, product, coef, work, saved, entries, minor):
    """Spectral radius of the block companion ``transition`` <= ``bound``.

    Same answer as ``max |eigvals(A)| <= bound``: a Schur-Cohn test on the
    characteristic polynomial accepts when every root is inside ``bound (1 - band)``
    and rejects when one is outside ``bound (1 + band)``; only in between (or when
    the test is not conclusive numerically) are the eigenvalues computed.
    """
    if p <= 3:
        _char_poly_small(theta, p, n // p, entries, minor, coef)
    else:
        la.companion(theta, p, n, transition, coef)  # coef is only scratch for the drift here
        la.char_poly(transition, p, n, power, product, coef)
    if _schur_step_test(coef, n, bound * (1.0 - la.GUARD_BAND), work, saved):
        return True
    if not _schur_step_test(coef, n, bound * (1.0 + la.GUARD_BAND), work, saved):
        return False
    # the eigenvalues (rarely reached) in a separate, not inlined, function
    return la.radius_le_eig(theta, transition, p, n, bound, work, coef)


# ---------------------------------------------------------------- one target, all steps
@jit
def _advance_target(j, measurements, lengths, horizon, params, state, records):
    """Target ``j`` through its steps; ``params``, ``state`` (mutated in place) and ``records`` are the
    tuples of :func:`kalmix.core.fast.run_fast`, unpacked here as in :mod:`._numba_kernels`."""
    (dynamics, gating, gating_input, p, order, kappa, velocity_scale, forgetting, ridge, prior,
     bound, process_init, measurement_init, initial_variance, initial_velocity, expert_scale,
     temperature, share, eta_initial, eta_minimum, eta_decay, eta_sensitivity, adapt,
     q_shrink, r_shrink, floor, reinflation, seed, state_jitter, guard_gammas, max_variance, fast_guard,
     feature_limit, miss_limit) = params
    (steps, valid_steps, initialised, stream_ids, origin, history, mean, cov, gram, cross,
     transition, offset, process_noise, measurement_noise, gate_weights, gate_input, weights,
     responsibilities, expert_predictions, eta) = state
    (out_predictions, record_diagnostics, out_weights, out_eta, out_q, out_r,
     record_experts, out_experts) = records
    t_count = min(measurements.shape[0], lengths[j])
    k_count = weights.shape[1]
    n = order * p
    d = n + 1
    z = np.empty(p)
    features = np.empty(p)
    errors = np.empty((k_count, p))
    log_lik = np.empty(k_count)
    resp = np.empty(k_count)
    joint = np.empty(k_count)
    old_weights = np.empty(k_count)
    log_weights = np.empty(k_count)
    xi = np.empty(d)
    new_gram = np.empty((d, d))
    shifted = np.empty((p, d))
    work = np.empty((d, d))
    theta = np.empty((p, d))
    candidate = np.empty((p, d))
    cand_a = np.empty((n, n))
    cand_u = np.empty(n)
    power = np.empty((n, n))
    product = np.empty((n, n))
    coef = np.empty(n + 1)
    entries = np.empty((p, p, order + 1))
    minor = np.empty(2 * order + 1)
    poly_work = np.empty(n + 1)
    poly_saved = np.empty(n + 1)
    gain = np.empty((n, p))
    w_block = np.empty((n, p))
    g_block = np.empty((p, n))
    s_inv = np.empty((p, p))
    s_lower = np.empty((p, p))
    s_work = np.empty((p, p))
    residual = np.empty(p)
    r_diag = np.empty(p)
    row = np.empty(n)
    companion = dynamics != 1
    tmp = np.empty((n, n))
    tmp2 = np.empty((n, n))
    new_mean = np.empty(n)
    ahead = np.empty(n)
    ahead2 = np.empty(n)
    velocity = np.empty(p)
    logits = np.empty(k_count)
    rw = np.empty(k_count)
    log_scale = np.empty(k_count)
    before = np.empty(n)
    delta = np.empty(p)
    for k in range(k_count):
        log_scale[k] = p * math.log(expert_scale[k])

    for t in range(t_count):
        valid = True
        for i in range(p):
            z[i] = measurements[t, j, i]
            if not math.isfinite(z[i]):
                valid = False
        if not valid:
            for i in range(p):
                z[i] = 0.0
        if valid and initialised[j]:  # far from the origin: move it here (mixture.reanchor / restart)
            far = False
            finite = True
            for i in range(p):
                delta[i] = (z[i] - origin[j, i]) / kappa
                far = far or not abs(delta[i]) <= feature_limit
                finite = finite and math.isfinite(delta[i])
            if far and finite:
                translate = dynamics == 0 and _moves_on(j, n, p, delta, history, gram, miss_limit, feature_limit)
                _reanchor_target(j, n, p, order, z, delta, prior, origin, history, mean, gram, cross, transition,
                                 offset, translate)
            elif far:
                _restart_target(j, n, p, prior, process_init, measurement_init, initialised, origin, history,
                                gram, cross, transition, offset, process_noise, measurement_noise,
                                expert_predictions, gate_weights, gate_input, weights, responsibilities, eta)
        start = valid and not initialised[j]
        learn = valid and initialised[j]
        if start:
            for i in range(p):
                origin[j, i] = z[i]
        for i in range(p):
            features[i] = (z[i] - origin[j, i]) / kappa

        # 1. scoring (eq. 10) and the adaptive rate; 2. gate learning (none without a gate: a bank's AKF family)
        eta_now = 0.0
        rate = 0.0
        if gating != 3:
            for k in range(k_count):
                squared = 0.0
                for i in range(p):
                    e = z[i] - expert_predictions[j, k, i]
                    errors[k, i] = e
                    squared += e * e
                log_lik[k] = -log_scale[k] - squared / (2.0 * expert_scale[k] ** 2)
            dominant = posterior(j, log_lik, weights, old_weights, log_weights, joint, resp)
            dom_err = 0.0
            for i in range(p):
                dom_err += errors[dominant, i] ** 2
            eta_now = learning_rate(valid_steps[j], dom_err, eta_initial, eta_minimum, eta_decay, eta_sensitivity)
            rate = eta_now if learn else 0.0

            learn_gate(j, gating, learn, rate, resp, old_weights, log_weights, log_lik, temperature, share,
                       gate_weights, gate_input, weights, joint, logits)
        if adapt and learn:
            for k in range(k_count):
                factor = max(1.0 - q_shrink * rate * resp[k], 0.0)
                for i in range(p):
                    value = process_noise[j, k, i] * factor
                    value = value + reinflation * (process_init[k, i] - value)
                    process_noise[j, k, i] = max(value, floor * process_init[k, i])
                factor = max(1.0 - r_shrink * rate * resp[k], 0.0)
                for i in range(p):
                    value = measurement_noise[j, k, i] * factor
                    value = value + reinflation * (measurement_init[k, i] - value)
                    measurement_noise[j, k, i] = max(value, floor * measurement_init[k, i])

        # 3. system matrices
        if dynamics == 1:
            ok = learn
            for i in range(p):
                if not math.isfinite(history[j, 0, i]):
                    ok = False
            if ok:
                denominator = 0.0
                for i in range(p):
                    denominator += history[j, 0, i] * history[j, 0, i]
                denominator += 1e-12
                for k in range(k_count):
                    for r in range(n):
                        for c in range(n):
                            transition[j, k, r, c] = 0.0
                    for r in range(p):
                        for c in range(p):
                            transition[j, k, r, c] = features[r] * history[j, 0, c] / denominator
        elif dynamics == 0:
            ok = learn
            for lag in range(order):
                for i in range(p):
                    if not math.isfinite(history[j, lag, i]):
                        ok = False
            if ok:
                for lag in range(order):
                    for i in range(p):
                        xi[lag * p + i] = history[j, lag, i]
                xi[n] = 1.0
                for k in range(k_count):
                    lam = forgetting[k]
                    rho = ridge[k]
                    for r in range(d):
                        for c in range(d):
                            value = lam * gram[j, k, r, c] + xi[r] * xi[c]
                            gram[j, k, r, c] = value
                            new_gram[r, c] = value + (rho if r == c else 0.0)
                    for r in range(p):
                        for c in range(d):
                            value = lam * cross[j, k, r, c] + features[r] * xi[c]
                            cross[j, k, r, c] = value
                            shifted[r, c] = value + rho * prior[r, c]
                    _cholesky_solve_rows(new_gram, d, shifted, p, work, theta)
                    # guard: largest gamma whose companion has spectral radius <= bound
                    for g in range(guard_gammas.shape[0]):
                        gamma = guard_gammas[g]
                        for r in range(p):
                            for c in range(d):
                                candidate[r, c] = prior[r, c] + gamma * (theta[r, c] - prior[r, c])
                        if g == guard_gammas.shape[0] - 1:
                            break
                        if fast_guard:
                            if _radius_le(candidate, cand_a, p, n, bound, power, product, coef, poly_work,
                                          poly_saved, entries, minor):
                                break
                        elif la.radius_le_eig(candidate, cand_a, p, n, bound, cand_u, coef):
                            break
                    la.companion(candidate, p, n, cand_a, cand_u)
                    for r in range(n):
                        offset[j, k, r] = cand_u[r]
                        for c in range(n):
                            transition[j, k, r, c] = cand_a[r, c]

        # 4. Kalman update, (re)start, predict, using C = [I 0] and, for rls / fixed
        # dynamics, the companion form of A (only its first p rows are free).
        for k in range(k_count):
            cv = cov[j, k]
            mu = mean[j, k]
            a = transition[j, k]
            off = offset[j, k]
            # an expert whose prediction misses this measurement by more than miss_limit starts again here
            fresh = start
            if learn:
                for i in range(p):
                    fresh = fresh or not abs(features[i] - mu[i]) <= miss_limit
                for i in range(p):
                    residual[i] = features[i] - mu[i]
                    r_diag[i] = measurement_noise[j, k, i] / kappa ** 2
                for r in range(p):
                    for c in range(p):
                        s_work[r, c] = cv[r, c]
                    s_work[r, r] += r_diag[r]
                _chol_inverse(s_work, p, 1e-12, s_lower, tmp, s_inv)
                # K = P C^T S^-1 (n, p); W = (I - K C) P C^T - K R (n, p)
                for r in range(n):
                    for c in range(p):
                        acc = 0.0
                        for l in range(p):
                            acc += cv[r, l] * s_inv[l, c]
                        gain[r, c] = acc
                for r in range(n):
                    acc = 0.0
                    for c in range(p):
                        acc += gain[r, c] * residual[c]
                    new_mean[r] = mu[r] + acc
                    for c in range(p):
                        acc = 0.0
                        for l in range(p):
                            acc += gain[r, l] * cv[l, c]
                        w_block[r, c] = (cv[r, c] - acc) - gain[r, c] * r_diag[c]
                # Joseph form (I - K C) P (I - K C)^T + K R K^T = P - K P[:p, :] - W K^T,
                # symmetric: the upper triangle is computed and mirrored
                for r in range(n):
                    mu[r] = new_mean[r]
                for r in range(n):
                    for c in range(r, n):
                        acc = 0.0
                        for l in range(p):
                            acc += gain[r, l] * cv[l, c] + w_block[r, l] * gain[c, l]
                        tmp[r, c] = cv[r, c] - acc
                for r in range(n):
                    for c in range(r, n):
                        cv[r, c] = tmp[r, c]
                        cv[c, r] = tmp[r, c]
            if fresh:
                p0 = initial_variance[k] / kappa ** 2
                for lag in range(order):
                    for i in range(p):
                        mu[lag * p + i] = features[i] - lag * (initial_velocity[k, i] / kappa)
                for r in range(n):
                    for c in range(n):
                        cv[r, c] = p0 if r == c else 0.0
            for r in range(n):
                before[r] = mu[r]
            # predict: x <- A x + u, P <- A P A^T + Q
            if companion:
                # A = [Theta; I 0]: x <- [Theta x + u_top; x[:n-p]],
                # P <- [[G Theta^T, G[:, :n-p]], [G[:, :n-p]^T, P[:n-p, :n-p]]], G = Theta P
                for r in range(p):
                    acc = 0.0
                    for c in range(n):
                        acc += a[r, c] * mu[c]
                    new_mean[r] = acc + off[r]
                    for c in range(n):
                        acc = 0.0
                        for l in range(n):
                            acc += a[r, l] * cv[l, c]
                        g_block[r, c] = acc
                for r in range(p, n):
                    new_mean[r] = mu[r - p] + off[r]
                for r in range(n - 1, -1, -1):
                    mu[r] = new_mean[r]
                for r in range(n - 1, p - 1, -1):  # shift the lower-right block in place
                    for c in range(n - 1, r - 1, -1):
                        value = cv[r - p, c - p]
                        cv[r, c] = value
                        cv[c, r] = value
                for r in range(p):
                    for c in range(p, n):
                        value = g_block[r, c - p]
                        cv[r, c] = value
                        cv[c, r] = value
                    for c in range(r, p):
                        acc = 0.0
                        for l in range(n):
                            acc += g_block[r, l] * a[c, l]
                        cv[r, c] = acc
                        cv[c, r] = acc
            else:
                for r in range(n):
                    acc = 0.0
                    for c in range(n):
                        acc += a[r, c] * mu[c]
                    new_mean[r] = acc + off[r]
                for r in range(n):  # tmp = A P
                    for c in range(n):
                        row[c] = 0.0
                    for l in range(n):
                        value = a[r, l]
                        for c in range(n):
                            row[c] += value * cv[l, c]
                    for c in range(n):
                        tmp[r, c] = row[c]
                # tmp2 = tmp A^T, computed as (A tmp^T)^T: tmp2[r, c] = sum_l a[c, l] tmp[r, l]
                for c in range(n):
                    for r in range(n):
                        row[r] = 0.0
                    for l in range(n):
                        value = a[c, l]
                        for r in range(n):
                            row[r] += value * tmp[r, l]
                    for r in range(n):
                        tmp2[r, c] = row[r]
                for r in range(n):
                    mu[r] = new_mean[r]
                    for c in range(n):
                        cv[r, c] = 0.5 * (tmp2[r, c] + tmp2[c, r])
            largest = -np.inf
            for r in range(n):
                cv[r, r] += state_jitter + (process_noise[j, k, r] / kappa ** 2 if r < p else 0.0)
                largest = max(largest, cv[r, r])
            # cap the variance (only reached after very long runs of missing measurements); the
            # mean of a capped expert goes back to before the prediction (it stops extrapolating)
            factor = min(1.0, max_variance / largest)
            if factor != 1.0:
                for r in range(n):
                    mu[r] = before[r]
                    for c in range(n):
                        cv[r, c] = cv[r, c] * factor
        if start:
            initialised[j] = True
        if initialised[j]:
            for k in range(k_count):
                for i in range(p):
                    expert_predictions[j, k, i] = origin[j, i] + kappa * mean[j, k, i]

        # 5. gate for the new prediction, bookkeeping
        next_gate(j, valid, learn, features, resp, eta_now, gating, gating_input, velocity_scale, temperature,
                  seed, history, gate_input, gate_weights, weights, stream_ids, steps, valid_steps,
                  responsibilities, eta, velocity, logits, rw)

        # outputs
        for i in range(p):
            out_predictions[t, j, i] = 0.0
        for k in range(k_count):
            for r in range(n):
                ahead[r] = mean[j, k, r]
            for h in range(horizon - 1):
                for r in range(n):
                    acc = 0.0
                    for c in range(n):
                        acc += transition[j, k, r, c] * ahead[c]
                    ahead2[r] = acc + offset[j, k, r]
                for r in range(n):
                    ahead[r] = ahead2[r]
            for i in range(p):
                value = expert_predictions[j, k, i] if horizon == 1 else origin[j, i] + kappa * ahead[i]
                out_predictions[t, j, i] += weights[j, k] * value
                if record_experts:
                    out_experts[t, j, k, i] = value
        if not initialised[j]:
            for i in range(p):
                out_predictions[t, j, i] = np.nan
        if record_diagnostics:
            out_eta[t, j] = eta[j]
            for k in range(k_count):
                out_weights[t, j, k] = weights[j, k]
                for i in range(p):
                    out_q[t, j, k, i] = process_noise[j, k, i]
                    out_r[t, j, k, i] = measurement_noise[j, k, i]


@jit
def _prior_dynamics(j, k, n, p, prior, transition, offset):
    """Expert k of target j gets the prior's companion matrix and drift."""
    for a in range(n):
        for c in range(n):
            transition[j, k, a, c] = prior[a, c] if a < p else (1.0 if c == a - p else 0.0)
        offset[j, k, a] = prior[a, n] if a < p else 0.0


@jit
def _reanchor_target(j, n, p, order, z, delta, prior, origin, history, mean, gram, cross, transition, offset,
                     translate):
    """:func:`kalmix.core.mixture.reanchor` of target j: the origin moves to ``z`` (features ``delta``),
    the means with it; with ``translate`` the history too and each expert's statistics and drift as
    :func:`kalmix.core.mixture._translated` moves them (its order of operations); otherwise RLS
    statistics zero, prior dynamics, no history."""
    for i in range(p):
        origin[j, i] = z[i]
    for k in range(mean.shape[1]):
        for lag in range(order):
            for i in range(p):
                mean[j, k, lag * p + i] = mean[j, k, lag * p + i] - delta[i]
    if not translate:
        gram[j] = 0.0
        cross[j] = 0.0
        for i in range(p):
            for lag in range(order):
                history[j, lag, i] = np.nan
        for k in range(mean.shape[1]):
            _prior_dynamics(j, k, n, p, prior, transition, offset)
        return
    for lag in range(order):
        for i in range(p):
            history[j, lag, i] = history[j, lag, i] - delta[i]
    for k in range(mean.shape[1]):
        translate_statistics(gram[j, k], cross[j, k], n, p, delta)
        for i in range(p):   # drift u + (sum_j A_j - I) delta
            acc = offset[j, k, i]
            for column in range(n):
                acc = acc + transition[j, k, i, column] * delta[column % p]
            offset[j, k, i] = acc - delta[i]


@jit
def _moves_on(j, n, p, delta, history, gram, miss_limit, feature_limit):
    """:func:`kalmix.core.mixture.translates` of target j (rls), its experts' statistics ``gram (N, K, d, d)``."""
    if not stepped_on(j, p, delta, history, miss_limit):
        return False
    for k in range(gram.shape[1]):
        if not held_near(gram[j, k], n, p, delta, feature_limit):
            return False
    return True


@jit
def _restart_target(j, n, p, prior, process_init, measurement_init, initialised, origin, history, gram, cross,
                    transition, offset, process_noise, measurement_noise, expert_predictions, gate_weights,
                    gate_input, weights, responsibilities, eta):
    """:func:`kalmix.core.mixture.restart` of target j: everything as before its first measurement,
    counters kept (the Kalman mean and covariance are set by the start that follows)."""
    k_count = weights.shape[1]
    initialised[j] = False
    for i in range(p):
        origin[j, i] = 0.0
        for lag in range(history.shape[1]):
            history[j, lag, i] = np.nan
    for i in range(gate_input.shape[1]):
        gate_input[j, i] = 0.0
    eta[j] = 0.0
    for k in range(k_count):
        for a in range(gram.shape[2]):
            for c in range(gram.shape[3]):
                gram[j, k, a, c] = 0.0
        for a in range(p):
            for c in range(cross.shape[3]):
                cross[j, k, a, c] = 0.0
        _prior_dynamics(j, k, n, p, prior, transition, offset)
        for i in range(p):
            process_noise[j, k, i] = process_init[k, i]
            measurement_noise[j, k, i] = measurement_init[k, i]
            expert_predictions[j, k, i] = 0.0
        for i in range(gate_weights.shape[2]):
            gate_weights[j, k, i] = 0.0
        weights[j, k] = 1.0 / k_count
        responsibilities[j, k] = 1.0 / k_count


@nb.njit(**_JIT)
def run_targets(lo, hi, measurements, lengths, horizon, params, state, records):
    """Advance targets ``lo .. hi - 1`` (each ``j`` through its first ``lengths[j]`` steps)."""
    for j in range(lo, hi):
        _advance_target(j, measurements, lengths, horizon, params, state, records)
