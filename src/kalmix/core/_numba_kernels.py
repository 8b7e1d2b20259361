"""Numba kernels of :mod:`kalmix.core.fast` (imported only when numba is present).

One compiled function advances one target through the whole time loop with the same
operations as the numpy reference (:func:`kalmix.core.mixture.step`); :func:`run_targets`
advances targets ``lo .. hi - 1``; :func:`kalmix.core.compiled._threads.over_targets` runs ranges
of targets on threads. Every target is independent, so the threads never synchronise.

Within a target, all K experts advance together: their state is copied once per call
into arrays with the expert index last (``cov[r, c, k]``), so that every inner loop of
the filter, the RLS fit and the guard runs over the experts with unit stride and is
vectorised by the compiler (:mod:`kalmix.core._numba_linalg`), and copied back at the
end of the call.

Mode codes: dynamics 0 = rls, 1 = literal, 2 = fixed; gating 0 = fixed_share,
1 = paper, 2 = random, 3 = none; gating input 0 = bias, 1 = position, 2 = velocity.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import _numba_linalg as la
from .compiled._cache import JIT as _JIT

jit = la.jit

#: :data:`kalmix.core.gating.LOG_FLOOR` and :data:`kalmix.core.gating.ERROR_CAP` (a test checks
#: that they agree; literals here so that the compiled cache, keyed on this file, follows them).
LOG_FLOOR = -1e300
ERROR_CAP = 1e300


# ---------------------------------------------------------------- random gate (splitmix64)
@jit
def _splitmix64(x):
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@jit
def _random_weights(seed, stream_id, step, out):
    key = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(0x51ED))
    key = _splitmix64(key ^ np.uint64(stream_id))
    key = _splitmix64(key ^ (np.uint64(step) * np.uint64(0x9E37)))
    total = 0.0
    for k in range(out.shape[0]):
        draw = _splitmix64(key ^ np.uint64(k))
        out[k] = float(draw >> np.uint64(11)) * (1.0 / 9007199254740992.0) + 1e-12
    total = np.sum(out)
    for k in range(out.shape[0]):
        out[k] = out[k] / total


# ---------------------------------------------------------------- expert state, experts last
@jit
def _load_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
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
def _store_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                   expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, with_rls):
    """Inverse of :func:`_load_experts`."""
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


# ---------------------------------------------------------------- shared fits
@jit
def _same_bits(x, y):
    """Equal, and of the same sign (+0.0 and -0.0 differ; NaN equals nothing)."""
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)


@jit
def _shared_fits(forgetting, ridge, gm, cr, slot, first):
    """Experts whose RLS fits are the same computation: same forgetting and ridge, and the same bits in
    their statistics. They learn from the same regressors (a target's history), so they stay equal and
    their fit, and the guard on it, is done once. ``slot[k]`` is expert k's fit; ``first[u]`` the expert
    whose statistics fit u starts from. Returns the number of fits."""
    experts = slot.shape[0]
    d, p = gm.shape[0], cr.shape[0]
    count = 0
    for k in range(experts):
        slot[k] = -1
        for u in range(count):
            r = first[u]
            same = forgetting[r] == forgetting[k] and ridge[r] == ridge[k]
            for a in range(d):
                for c in range(d):
                    same = same and _same_bits(gm[a, c, r], gm[a, c, k])
            for i in range(p):
                for c in range(d):
                    same = same and _same_bits(cr[i, c, r], cr[i, c, k])
            if same:
                slot[k] = u
                break
        if slot[k] < 0:
            first[count] = k
            slot[k] = count
            count += 1
    return count


# ---------------------------------------------------------------- system matrices
@jit
def _rls_fit(xi, features, forgetting, ridge, prior, gram, cross, new_gram, shifted, work, theta, acc):
    """Forgetting RLS statistics and the ridge solution toward the prior, every expert at once.

    ``S <- lambda S + xi xi^T``, ``M <- lambda M + s xi^T``,
    ``Theta = (M + rho Theta_0) (S + rho I)^{-1}`` (as :func:`kalmix.core.dynamics.rls_update`).
    """
    experts = acc.shape[0]
    d, p = gram.shape[0], cross.shape[0]
    for a in range(d):
        for c in range(d):
            x = xi[a] * xi[c]
            for k in range(experts):
                value = forgetting[k] * gram[a, c, k] + x
                gram[a, c, k] = value
                new_gram[a, c, k] = value
        for k in range(experts):
            new_gram[a, a, k] = gram[a, a, k] + ridge[k]
    for a in range(p):
        for c in range(d):
            x = features[a] * xi[c]
            prior_value = prior[a, c]
            for k in range(experts):
                value = forgetting[k] * cross[a, c, k] + x
                cross[a, c, k] = value
                shifted[a, c, k] = value + ridge[k] * prior_value
    la.cholesky_solve_rows(new_gram, d, shifted, p, work, theta, acc)


@jit
def _guard(theta, prior, p, order, bound, gammas, fast_guard, trans, off, undecided, candidate,
           entries, minor, coef, poly_work, poly_saved, norm, inside_low, inside_high,
           one_theta, one_a, one_u, power, product, one_coef):
    """Largest shrink toward the prior whose companion has spectral radius <= ``bound``, per expert.

    Candidates ``prior + gamma (theta - prior)`` for gamma in ``gammas`` (the last, 0,
    is always accepted) are tested for the still-undecided experts, packed into the
    first columns of the work arrays: a Schur-Cohn test on the characteristic
    polynomial accepts inside ``bound (1 - band)`` and rejects outside
    ``bound (1 + band)``; in between, and when ``fast_guard`` is off, the eigenvalues
    decide (the numpy reference's test). The chosen candidate becomes the first p rows
    of ``trans`` and ``off``; the rows below are the companion's shift.
    """
    experts = trans.shape[2]
    n = order * p
    d = n + 1
    last = gammas.shape[0] - 1
    count = experts
    for k in range(experts):
        undecided[k] = k
    for g in range(last + 1):
        gamma = gammas[g]
        for a in range(p):
            for c in range(d):
                prior_value = prior[a, c]
                if count == experts:
                    for i in range(count):
                        candidate[a, c, i] = prior_value + gamma * (theta[a, c, i] - prior_value)
                else:
                    for i in range(count):
                        candidate[a, c, i] = prior_value + gamma * (theta[a, c, undecided[i]] - prior_value)
        if g < last and fast_guard:
            if p <= 3:
                la.char_poly_small(candidate, p, order, entries, minor, coef, count)
            else:
                for i in range(count):
                    for a in range(p):
                        for c in range(d):
                            one_theta[a, c] = candidate[a, c, i]
                    la.companion(one_theta, p, n, one_a, one_u)
                    la.char_poly(one_a, p, n, power, product, one_coef)
                    for e in range(n + 1):
                        coef[e, i] = one_coef[e]
            la.schur_cohn(coef, n, bound * (1.0 - la.GUARD_BAND), poly_work, poly_saved, norm, inside_low, count)
            failed = False
            for i in range(count):
                failed = failed | (not inside_low[i])
            if failed:
                la.schur_cohn(coef, n, bound * (1.0 + la.GUARD_BAND), poly_work, poly_saved, norm, inside_high, count)
        remaining = 0
        for i in range(count):
            if g == last or (fast_guard and inside_low[i]):
                accept = True
            elif fast_guard and not inside_high[i]:
                accept = False
            else:
                for a in range(p):
                    for c in range(d):
                        one_theta[a, c] = candidate[a, c, i]
                accept = la.radius_le_eig(one_theta, one_a, p, n, bound, one_u, coef[:, i:i + 1])
            k = undecided[i]
            if accept:
                for a in range(p):
                    for c in range(n):
                        trans[a, c, k] = candidate[a, c, i]
                    off[a, k] = candidate[a, n, i]
            else:
                undecided[remaining] = k
                remaining += 1
        count = remaining
        if count == 0:
            break
    for a in range(p, n):  # the shift rows of the companion
        for c in range(n):
            one = 1.0 if c == a - p else 0.0
            for k in range(experts):
                trans[a, c, k] = one
        for k in range(experts):
            off[a, k] = 0.0


# ---------------------------------------------------------------- Kalman filter, C = [I 0]
@jit
def _kalman_update(mu, cv, features, r, kappa, residual, r_diag, s_work, s_lower, s_lower_inv, s_inv, gain,
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
def _kalman_start(mu, cv, features, order, kappa, initial_variance, initial_velocity, fresh):
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
def _reanchor_target(j, k_count, n, p, order, z, delta, prior, origin, history, gram, cross, mu, gm, cr,
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
def stepped_on(j, p, delta, history, miss_limit):
    """Target j's step from its last learned features to ``delta`` is within ``miss_limit`` (it moved on)."""
    for i in range(p):
        if not abs(delta[i] - history[j, 0, i]) <= miss_limit:
            return False
    return True


@jit
def held_near(gm, n, p, delta, feature_limit):
    """One fit's statistics ``gm (d, d)`` hold their data (the weighted mean regressor) within
    ``feature_limit`` of the new origin ``delta`` (no data: True)."""
    weight = gm[n, n]
    if weight > 0:
        for a in range(n):
            if not abs(gm[n, a] / weight - delta[a % p]) <= feature_limit:
                return False
    return True


@jit
def _moves_on(j, n, p, delta, history, gm, miss_limit, feature_limit):
    """:func:`kalmix.core.mixture.translates` of target j (rls), its fits' statistics ``gm (d, d, fits)``."""
    if not stepped_on(j, p, delta, history, miss_limit):
        return False
    for u in range(gm.shape[2]):
        if not held_near(gm[:, :, u], n, p, delta, feature_limit):
            return False
    return True


@jit
def translate_statistics(gm, cr, n, p, delta):
    """One fit's statistics ``gm (d, d)``, ``cr (p, d)`` for features moved by ``-delta``, in place, each entry
    from the old values in the spec's order: ``S <- M S M^T``, ``M_xy <- (M_xy - delta r) M^T``
    (:func:`kalmix.core.mixture._translated`)."""
    corner = gm[n, n]
    for i in range(p):   # the cross statistics first: they read the old constant row of S
        moved = cr[i, n] - delta[i] * corner
        for b in range(n + 1):
            bar_b = delta[b % p] if b < n else 0.0
            cr[i, b] = (cr[i, b] - delta[i] * gm[n, b]) - moved * bar_b
    for a in range(n):   # inside, then column n, then row n, then the corner: each reads only old values
        for b in range(n):
            gm[a, b] = ((gm[a, b] - delta[a % p] * gm[n, b]) - gm[a, n] * delta[b % p]) + (
                delta[a % p] * delta[b % p]) * corner
    for a in range(n):
        gm[a, n] = ((gm[a, n] - delta[a % p] * corner) - gm[a, n] * 0.0) + (delta[a % p] * 0.0) * corner
    for b in range(n):
        gm[n, b] = ((gm[n, b] - 0.0 * gm[n, b]) - corner * delta[b % p]) + (0.0 * delta[b % p]) * corner
    gm[n, n] = ((corner - 0.0 * corner) - corner * 0.0) + (0.0 * 0.0) * corner


@jit
def _restart_target(j, k_count, n, p, prior, process_init, measurement_init, initialised, origin, history,
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


@jit
def _predict_companion(mu, cv, trans, off, new_mean, g_block, acc):
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
def _predict_full(mu, cv, trans, off, new_mean, tmp, tmp2, acc):
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
def _add_process_noise(cv, q, kappa, state_jitter, max_variance, acc, mu, before):
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


# ---------------------------------------------------------------- gate
@jit
def posterior(j, log_lik, weights, old_weights, log_weights, joint, resp):
    """Eq. 10: responsibilities ``h`` from the prior weights and the log-likelihoods.

    Keeps the prior weights and their logs (the fixed-share gate reuses them) and
    returns the index of the dominant expert (largest prior weight).
    """
    for k in range(log_lik.shape[0]):
        old_weights[k] = weights[j, k]
        log_weights[k] = math.log(max(old_weights[k], 1e-300))
        joint[k] = log_weights[k] + log_lik[k]
    _normalise_log(joint, resp)
    dominant = 0
    for k in range(1, log_lik.shape[0]):
        if old_weights[k] > old_weights[dominant]:
            dominant = k
    return dominant


@jit
def learning_rate(valid_steps, dominant_error, eta_initial, eta_minimum, eta_decay, eta_sensitivity):
    """Adaptive rate ``eta_k = eta(t) (1 - exp(-alpha e^2))`` from the dominant expert's squared error."""
    base = eta_minimum + (eta_initial - eta_minimum) * math.exp(-float(valid_steps) / eta_decay)
    return base * -math.expm1(-eta_sensitivity * min(dominant_error, ERROR_CAP))


@jit
def learn_gate(j, gating, learn, rate, resp, old_weights, log_weights, log_lik, temperature, share,
               gate_weights, gate_input, weights, joint, logits):
    """Eq. 9 (paper gate: gradient step on the gate weights) or the fixed-share update of the weights."""
    k_count = log_lik.shape[0]
    if gating == 1:
        for k in range(k_count):
            delta = rate * (resp[k] - old_weights[k])
            for i in range(gate_input.shape[1]):
                gate_weights[j, k, i] = gate_weights[j, k, i] + delta * gate_input[j, i]
    elif gating == 0 and learn:
        for k in range(k_count):
            joint[k] = log_weights[k] + log_lik[k] / temperature
        _normalise_log(joint, logits)
        for k in range(k_count):
            weights[j, k] = (1.0 - share) * logits[k] + share / k_count


@jit
def next_gate(j, valid, learn, features, resp, eta_now, gating, gating_input, velocity_scale, temperature,
              seed, history, gate_input, gate_weights, weights, stream_ids, steps, valid_steps,
              responsibilities, eta, velocity, logits, rw):
    """Gate weights for the next prediction (eq. 8 or the random gate), then the step's bookkeeping:
    the measurement history shifts, the counters advance, and the scores are kept."""
    p, order = features.shape[0], history.shape[1]
    k_count = weights.shape[1]
    for i in range(p):
        previous = history[j, 0, i]
        velocity[i] = features[i] - previous if math.isfinite(previous) else 0.0
    if valid:
        gate_input[j, 0] = 1.0
        if gating_input >= 1:
            for i in range(p):
                gate_input[j, 1 + i] = features[i]
        if gating_input == 2:
            for i in range(p):
                gate_input[j, 1 + p + i] = velocity[i] / velocity_scale
    if gating == 1 and valid:
        for k in range(k_count):
            value = 0.0
            for i in range(gate_input.shape[1]):
                value += gate_weights[j, k, i] * gate_input[j, i]
            logits[k] = value / temperature
        top = logits[0]
        for k in range(1, k_count):
            top = max(top, logits[k])
        for k in range(k_count):
            rw[k] = math.exp(logits[k] - top)
        total = np.sum(rw)
        for k in range(k_count):
            weights[j, k] = rw[k] / total
    elif gating == 2:
        _random_weights(seed, stream_ids[j], steps[j], rw)
        for k in range(k_count):
            weights[j, k] = rw[k]

    for lag in range(order - 1, 0, -1):
        for i in range(p):
            history[j, lag, i] = history[j, lag - 1, i]
    for i in range(p):
        history[j, 0, i] = features[i] if valid else np.nan
    steps[j] += 1
    if valid:
        valid_steps[j] += 1
    if learn and gating != 3:   # without a gate (3) they stay as they were
        for k in range(k_count):
            responsibilities[j, k] = resp[k]
        eta[j] = eta_now


@jit
def _adapt_noise(noise, initial, rate, resp, floor, reinflation, factor):
    """Eq. 11/12 with a floor and re-inflation: ``noise <- noise max(1 - rate h_i, 0)``, pulled back
    toward ``initial`` by ``reinflation`` and kept above ``floor initial``."""
    experts = factor.shape[0]
    for k in range(experts):
        factor[k] = max(1.0 - rate * resp[k], 0.0)
    for i in range(noise.shape[0]):
        for k in range(experts):
            value = noise[i, k] * factor[k]
            value = value + reinflation * (initial[i, k] - value)
            noise[i, k] = max(value, floor * initial[i, k])


@jit
def _normalise_log(log_joint, out):
    """``exp(a - logsumexp(a))``, the max split out as scipy does: ``e_k / (1 + sum_{k != top} e_k)``
    with ``e_k = exp(a_k - max a)`` (one exponential per entry); ``a`` is first floored at
    ``LOG_FLOOR`` (in place), as :func:`kalmix.core.gating.posterior` does."""
    for k in range(log_joint.shape[0]):
        log_joint[k] = max(log_joint[k], LOG_FLOOR)
    top = 0
    for k in range(1, log_joint.shape[0]):
        if log_joint[k] > log_joint[top]:
            top = k
    a_max = log_joint[top]
    rest = 0.0
    for k in range(log_joint.shape[0]):
        out[k] = math.exp(log_joint[k] - a_max)
        if k != top:
            rest += out[k]
    inverse = 1.0 / (1.0 + rest)
    for k in range(log_joint.shape[0]):
        out[k] = out[k] * inverse


# ---------------------------------------------------------------- one target, all steps
# Inlined into its one caller (run_targets): numba re-optimises a callee inside each caller's module, so this
# saves a compile pass over the largest function.
@jit
def _take(buffer, position, shape):
    """The next ``shape`` of ``buffer`` from ``position`` (a C-contiguous view), and the position after it."""
    size = 1
    for extent in shape:
        size *= extent
    return buffer[position:position + size].reshape(shape), position + size


@jit
def scratch_size(k_count, p, order):
    """Sizes of the float, int and bool buffers :func:`advance_target` takes its scratch from (one target;
    an undersized buffer makes ``reshape`` fail, so the AKF tests check these sums)."""
    n = order * p
    d = n + 1
    state = n + 2 * n * n + d * d + p * d + n + 3 * p
    fits = 3 + d * d + p * d + n * n + n
    work = (7 + p + 2 * d * d + 3 * p * d + 1 + p * p * (order + 1) + 2 * order + 1 + 3 * (n + 1) + 2 * p
            + 4 * p * p + 3 * n * p + n + 2 * n * n + n + 2 + 2 * p + n)
    fixed = 4 * p + d + p * d + 3 * n * n + n + n + 1
    return k_count * (state + fits + work) + fixed, 3 * k_count, 3 * k_count


@nb.njit(inline="always", **_JIT)
def advance_target(j, measurements, lengths, horizon, params, state, records, out_one, fbuf, ibuf, bbuf):
    """Target ``j`` through its steps; ``params``, ``state`` (mutated in place) and ``records`` are the
    tuples of :func:`kalmix.core.fast.run_fast` (unpacked here: one call with three tuples compiles much
    faster than one with ~60 arguments). ``out_one (T, N, K, p)``, if not empty, receives every expert's
    next-frame prediction after each step whatever the ``horizon`` (the bank engine's AKF family,
    :mod:`kalmix.core.compiled.akf`). The scratch comes from ``fbuf``, ``ibuf`` and ``bbuf`` (sizes:
    :func:`scratch_size`), so that this runs where nothing can be allocated (a GPU thread)."""
    (dynamics, gating, gating_input, p, order, kappa, velocity_scale, forgetting, ridge, prior, bound,
     process_init, measurement_init, initial_variance, initial_velocity, expert_scale, temperature, share,
     eta_initial, eta_minimum, eta_decay, eta_sensitivity, adapt, q_shrink, r_shrink, floor, reinflation, seed,
     state_jitter, guard_gammas, max_variance, fast_guard, feature_limit, miss_limit) = params
    (steps, valid_steps, initialised, stream_ids, origin, history, mean, cov, gram, cross, transition, offset,
     process_noise, measurement_noise, gate_weights, gate_input, weights, responsibilities, expert_predictions,
     eta) = state
    (out_predictions, record_diagnostics, out_weights, out_eta, out_q, out_r, record_experts, out_experts) = records
    t_count = min(measurements.shape[0], lengths[j])
    k_count = weights.shape[1]
    n = order * p
    d = n + 1
    rls = dynamics == 0
    record_one = out_one.shape[0] > 0
    fpos = 0
    ipos = 0
    bpos = 0
    # this target's expert state, experts last
    mu, fpos = _take(fbuf, fpos, (n, k_count))
    cv, fpos = _take(fbuf, fpos, (n, n, k_count))
    gm, fpos = _take(fbuf, fpos, (d, d, k_count))
    cr, fpos = _take(fbuf, fpos, (p, d, k_count))
    trans, fpos = _take(fbuf, fpos, (n, n, k_count))
    off, fpos = _take(fbuf, fpos, (n, k_count))
    q, fpos = _take(fbuf, fpos, (p, k_count))
    r, fpos = _take(fbuf, fpos, (p, k_count))
    ep, fpos = _take(fbuf, fpos, (p, k_count))
    _load_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                  expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, rls)
    # experts of one fit learn as one (rls): its statistics, solution and guarded dynamics, ``fits`` wide
    slot, ipos = _take(ibuf, ipos, (k_count,))
    first, ipos = _take(ibuf, ipos, (k_count,))
    fits = _shared_fits(forgetting, ridge, gm, cr, slot, first) if rls else k_count
    fit_forgetting, fpos = _take(fbuf, fpos, (fits,))
    fit_ridge, fpos = _take(fbuf, fpos, (fits,))
    fit_gm, fpos = _take(fbuf, fpos, (d, d, fits))
    fit_cr, fpos = _take(fbuf, fpos, (p, d, fits))
    fit_trans, fpos = _take(fbuf, fpos, (n, n, fits))
    fit_off, fpos = _take(fbuf, fpos, (n, fits))
    fit_acc, fpos = _take(fbuf, fpos, (fits,))
    if rls:
        for u in range(fits):
            k = first[u]
            fit_forgetting[u] = forgetting[k]
            fit_ridge[u] = ridge[k]
            for a in range(d):
                for c in range(d):
                    fit_gm[a, c, u] = gm[a, c, k]
            for i in range(p):
                for c in range(d):
                    fit_cr[i, c, u] = cr[i, c, k]
    # scratch
    acc, fpos = _take(fbuf, fpos, (k_count,))
    z, fpos = _take(fbuf, fpos, (p,))
    features, fpos = _take(fbuf, fpos, (p,))
    errors, fpos = _take(fbuf, fpos, (p, k_count))
    log_lik, fpos = _take(fbuf, fpos, (k_count,))
    resp, fpos = _take(fbuf, fpos, (k_count,))
    joint, fpos = _take(fbuf, fpos, (k_count,))
    old_weights, fpos = _take(fbuf, fpos, (k_count,))
    logits, fpos = _take(fbuf, fpos, (k_count,))
    rw, fpos = _take(fbuf, fpos, (k_count,))
    xi, fpos = _take(fbuf, fpos, (d,))
    new_gram, fpos = _take(fbuf, fpos, (d, d, k_count))
    shifted, fpos = _take(fbuf, fpos, (p, d, k_count))
    work, fpos = _take(fbuf, fpos, (d, d, k_count))
    theta, fpos = _take(fbuf, fpos, (p, d, k_count))
    candidate, fpos = _take(fbuf, fpos, (p, d, k_count))
    undecided, ipos = _take(ibuf, ipos, (k_count,))
    norm, fpos = _take(fbuf, fpos, (k_count,))
    inside_low, bpos = _take(bbuf, bpos, (k_count,))
    inside_high, bpos = _take(bbuf, bpos, (k_count,))
    entries, fpos = _take(fbuf, fpos, (p, p, order + 1, k_count))
    minor, fpos = _take(fbuf, fpos, (2 * order + 1, k_count))
    coef, fpos = _take(fbuf, fpos, (n + 1, k_count))
    poly_work, fpos = _take(fbuf, fpos, (n + 1, k_count))
    poly_saved, fpos = _take(fbuf, fpos, (n + 1, k_count))
    one_theta, fpos = _take(fbuf, fpos, (p, d))
    one_a, fpos = _take(fbuf, fpos, (n, n))
    one_u, fpos = _take(fbuf, fpos, (n,))
    power, fpos = _take(fbuf, fpos, (n, n))
    product, fpos = _take(fbuf, fpos, (n, n))
    one_coef, fpos = _take(fbuf, fpos, (n + 1,))
    residual, fpos = _take(fbuf, fpos, (p, k_count))
    r_diag, fpos = _take(fbuf, fpos, (p, k_count))
    s_work, fpos = _take(fbuf, fpos, (p, p, k_count))
    s_lower, fpos = _take(fbuf, fpos, (p, p, k_count))
    s_lower_inv, fpos = _take(fbuf, fpos, (p, p, k_count))
    s_inv, fpos = _take(fbuf, fpos, (p, p, k_count))
    gain, fpos = _take(fbuf, fpos, (n, p, k_count))
    w_block, fpos = _take(fbuf, fpos, (n, p, k_count))
    g_block, fpos = _take(fbuf, fpos, (p, n, k_count))
    new_mean, fpos = _take(fbuf, fpos, (n, k_count))
    tmp, fpos = _take(fbuf, fpos, (n, n, k_count))
    tmp2, fpos = _take(fbuf, fpos, (n, n, k_count))
    ahead, fpos = _take(fbuf, fpos, (n, k_count))
    velocity, fpos = _take(fbuf, fpos, (p,))
    log_scale, fpos = _take(fbuf, fpos, (k_count,))
    log_weights, fpos = _take(fbuf, fpos, (k_count,))
    q_init, fpos = _take(fbuf, fpos, (p, k_count))
    r_init, fpos = _take(fbuf, fpos, (p, k_count))
    before, fpos = _take(fbuf, fpos, (n, k_count))
    fresh, bpos = _take(bbuf, bpos, (k_count,))
    delta, fpos = _take(fbuf, fpos, (p,))
    for k in range(k_count):
        log_scale[k] = p * math.log(expert_scale[k])
        for i in range(p):
            q_init[i, k] = process_init[k, i]
            r_init[i, k] = measurement_init[k, i]

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
                translate = rls and _moves_on(j, n, p, delta, history, fit_gm, miss_limit, feature_limit)
                _reanchor_target(j, k_count, n, p, order, z, delta, prior, origin, history, gram, cross, mu, fit_gm,
                                 fit_cr, trans, off, translate)
            elif far:
                _restart_target(j, k_count, n, p, prior, process_init, measurement_init, initialised, origin,
                                history, gram, cross, fit_gm, fit_cr, trans, off, q, r, ep, gate_weights, gate_input,
                                weights, responsibilities, eta)
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
                acc[k] = 0.0
            for i in range(p):
                for k in range(k_count):
                    e = z[i] - ep[i, k]
                    errors[i, k] = e
                    acc[k] += e * e
            for k in range(k_count):
                log_lik[k] = -log_scale[k] - acc[k] / (2.0 * expert_scale[k] ** 2)
            dominant = posterior(j, log_lik, weights, old_weights, log_weights, joint, resp)
            dom_err = 0.0
            for i in range(p):
                dom_err += errors[i, dominant] ** 2
            eta_now = learning_rate(valid_steps[j], dom_err, eta_initial, eta_minimum, eta_decay, eta_sensitivity)
            rate = eta_now if learn else 0.0

            learn_gate(j, gating, learn, rate, resp, old_weights, log_weights, log_lik, temperature, share,
                       gate_weights, gate_input, weights, joint, logits)
        if adapt and learn:
            _adapt_noise(q, q_init, q_shrink * rate, resp, floor, reinflation, acc)
            _adapt_noise(r, r_init, r_shrink * rate, resp, floor, reinflation, acc)

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
                for a in range(n):
                    for c in range(n):
                        value = features[a] * history[j, 0, c] / denominator if a < p and c < p else 0.0
                        for k in range(k_count):
                            trans[a, c, k] = value
        elif rls:
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
                _rls_fit(xi, features, fit_forgetting, fit_ridge, prior, fit_gm, fit_cr, new_gram, shifted, work,
                         theta, fit_acc)
                _guard(theta, prior, p, order, bound, guard_gammas, fast_guard, fit_trans, fit_off, undecided,
                       candidate, entries, minor, coef, poly_work, poly_saved, norm, inside_low, inside_high,
                       one_theta, one_a, one_u, power, product, one_coef)
                for a in range(n):
                    for c in range(n):
                        for k in range(k_count):
                            trans[a, c, k] = fit_trans[a, c, slot[k]]
                    for k in range(k_count):
                        off[a, k] = fit_off[a, slot[k]]

        # 4. Kalman update, (re)start, predict, using C = [I 0] and, for rls / fixed
        # dynamics, the companion form of A (only its first p rows are free).
        # an expert whose prediction misses this measurement by more than miss_limit starts again here
        any_fresh = start
        for k in range(k_count):
            fresh[k] = start
        if learn:
            for i in range(p):
                for k in range(k_count):
                    fresh[k] = fresh[k] or not abs(features[i] - mu[i, k]) <= miss_limit
            for k in range(k_count):
                any_fresh = any_fresh or fresh[k]
            _kalman_update(mu, cv, features, r, kappa, residual, r_diag, s_work, s_lower, s_lower_inv, s_inv,
                           gain, new_mean, w_block, tmp, acc)
        if any_fresh:
            _kalman_start(mu, cv, features, order, kappa, initial_variance, initial_velocity, fresh)
        for a in range(n):
            for k in range(k_count):
                before[a, k] = mu[a, k]
        if dynamics != 1:
            _predict_companion(mu, cv, trans, off, new_mean, g_block, acc)
        else:
            _predict_full(mu, cv, trans, off, new_mean, tmp, tmp2, acc)
        _add_process_noise(cv, q, kappa, state_jitter, max_variance, acc, mu, before)
        if start:
            initialised[j] = True
        if initialised[j]:
            for i in range(p):
                for k in range(k_count):
                    ep[i, k] = origin[j, i] + kappa * mu[i, k]

        # 5. gate for the new prediction, bookkeeping
        next_gate(j, valid, learn, features, resp, eta_now, gating, gating_input, velocity_scale, temperature,
                  seed, history, gate_input, gate_weights, weights, stream_ids, steps, valid_steps,
                  responsibilities, eta, velocity, logits, rw)

        # outputs
        if horizon > 1:
            _extrapolate(mu, trans, off, horizon - 1, ahead, new_mean, acc)
        for i in range(p):
            out_predictions[t, j, i] = 0.0
        for k in range(k_count):
            for i in range(p):
                value = ep[i, k] if horizon == 1 else origin[j, i] + kappa * ahead[i, k]
                out_predictions[t, j, i] += weights[j, k] * value
                if record_experts:
                    out_experts[t, j, k, i] = value
                if record_one:
                    out_one[t, j, k, i] = ep[i, k]
        if not initialised[j]:
            for i in range(p):
                out_predictions[t, j, i] = np.nan
        if record_diagnostics:
            out_eta[t, j] = eta[j]
            for k in range(k_count):
                out_weights[t, j, k] = weights[j, k]
                for i in range(p):
                    out_q[t, j, k, i] = q[i, k]
                    out_r[t, j, k, i] = r[i, k]
    if rls:
        for k in range(k_count):
            for a in range(d):
                for c in range(d):
                    gm[a, c, k] = fit_gm[a, c, slot[k]]
            for i in range(p):
                for c in range(d):
                    cr[i, c, k] = fit_cr[i, c, slot[k]]
    _store_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                   expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, rls)


@jit
def _extrapolate(mu, trans, off, steps, ahead, scratch, acc):
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


@nb.njit(**_JIT)
def run_targets(lo, hi, measurements, lengths, horizon, params, state, records):
    """Advance targets ``lo .. hi - 1`` (each ``j`` through its first ``lengths[j]`` steps)."""
    floats, ints, bools = scratch_size(state[16].shape[1], params[3], params[4])
    fbuf = np.empty(floats)
    ibuf = np.empty(ints, dtype=np.int64)
    bbuf = np.empty(bools, dtype=np.bool_)
    out_one = np.empty((0, 0, 0, 0))
    for j in range(lo, hi):
        advance_target(j, measurements, lengths, horizon, params, state, records, out_one, fbuf, ibuf, bbuf)
