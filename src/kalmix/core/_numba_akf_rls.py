"""The RLS fit of the compiled AKF kernel (:mod:`._numba_kernels`) and its spectral-radius guard, experts last.

Forgetting RLS statistics and the ridge solution toward the prior (:func:`kalmix.core.dynamics.rls_update`),
the guard that shrinks a fit toward the prior until its companion matrix is stable
(:func:`kalmix.core.dynamics.guard_theta`), the experts that share one fit, and the statistics moved with a
target's origin (:func:`kalmix.core.mixture.reanchor`). Arrays carry the expert (or fit) index last.
"""

from __future__ import annotations

import math

from . import _numba_linalg as la

jit = la.jit


@jit
def _same_bits(x, y):
    """Equal, and of the same sign (+0.0 and -0.0 differ; NaN equals nothing)."""
    return x == y and math.copysign(1.0, x) == math.copysign(1.0, y)


@jit
def shared_fits(forgetting, ridge, gm, cr, slot, first):
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


@jit
def rls_fit(xi, features, forgetting, ridge, prior, gram, cross, new_gram, shifted, work, theta, acc):
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
    la.cholesky_solve_rows(new_gram, d, shifted, p, work, theta, acc, False)


@jit
def guard(theta, prior, p, order, bound, gammas, fast_guard, trans, off, undecided, candidate,
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
def moves_on(j, n, p, delta, history, gm, miss_limit, feature_limit):
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
