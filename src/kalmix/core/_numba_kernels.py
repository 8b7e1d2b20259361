"""The compiled AKF kernel of :mod:`kalmix.core.fast` and the AKF family (imported only when numba is present).

:func:`advance_target` advances one target through the whole time loop with the same operations as the numpy
reference (:func:`kalmix.core.mixture.step`); :func:`run_targets` advances targets ``lo .. hi - 1``;
:func:`kalmix.core.compiled._threads.over_targets` runs ranges of targets on threads. Every target is
independent, so the threads never synchronise. The bank's AKF family (:mod:`kalmix.core.compiled.akf`) runs
:func:`advance_target` too, on the CPU and on a GPU thread.

Within a target, all K experts advance together: their state is copied once per call into arrays with the
expert index last (``cov[r, c, k]``), so that every inner loop of the filter, the RLS fit and the guard runs
over the experts with unit stride and is vectorised by the compiler (:mod:`kalmix.core._numba_linalg`), and
copied back at the end of the call. The parts: :mod:`._numba_akf_gate` (scores, rate and gate, eq. 8-12),
:mod:`._numba_akf_rls` (RLS fit and guard), :mod:`._numba_akf_filter` (Kalman update and prediction),
:mod:`._numba_akf_target` (a target's experts in and out, its origin moved, its restart).

Mode codes: dynamics 0 = rls, 1 = literal, 2 = fixed; gating 0 = fixed_share,
1 = paper, 2 = random, 3 = none; gating input 0 = bias, 1 = position, 2 = velocity.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from . import _numba_linalg as la
from ._numba_akf_filter import (add_process_noise, extrapolate, kalman_start, kalman_update, predict_companion,
                                predict_full)
from ._numba_akf_gate import adapt_noise, learn_gate, learning_rate, next_gate, posterior
from ._numba_akf_rls import guard, moves_on, rls_fit, shared_fits
from ._numba_akf_target import load_experts, reanchor_target, restart_target, store_experts
from .compiled._cache import JIT as _JIT

jit = la.jit


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


# Inlined into its callers (run_targets, the AKF family's driver): numba re-optimises a callee inside each
# caller's module, so this saves a compile pass over the largest function.
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
    load_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                 expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, rls)
    # experts of one fit learn as one (rls): its statistics, solution and guarded dynamics, ``fits`` wide
    slot, ipos = _take(ibuf, ipos, (k_count,))
    first, ipos = _take(ibuf, ipos, (k_count,))
    fits = shared_fits(forgetting, ridge, gm, cr, slot, first) if rls else k_count
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
                translate = rls and moves_on(j, n, p, delta, history, fit_gm, miss_limit, feature_limit)
                reanchor_target(j, k_count, n, p, order, z, delta, prior, origin, history, gram, cross, mu, fit_gm,
                                fit_cr, trans, off, translate)
            elif far:
                restart_target(j, k_count, n, p, prior, process_init, measurement_init, initialised, origin,
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
            adapt_noise(q, q_init, q_shrink * rate, resp, floor, reinflation, acc)
            adapt_noise(r, r_init, r_shrink * rate, resp, floor, reinflation, acc)

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
                rls_fit(xi, features, fit_forgetting, fit_ridge, prior, fit_gm, fit_cr, new_gram, shifted, work,
                        theta, fit_acc)
                guard(theta, prior, p, order, bound, guard_gammas, fast_guard, fit_trans, fit_off, undecided,
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
            kalman_update(mu, cv, features, r, kappa, residual, r_diag, s_work, s_lower, s_lower_inv, s_inv,
                          gain, new_mean, w_block, tmp, acc)
        if any_fresh:
            kalman_start(mu, cv, features, order, kappa, initial_variance, initial_velocity, fresh)
        for a in range(n):
            for k in range(k_count):
                before[a, k] = mu[a, k]
        if dynamics != 1:
            predict_companion(mu, cv, trans, off, new_mean, g_block, acc)
        else:
            predict_full(mu, cv, trans, off, new_mean, tmp, tmp2, acc)
        add_process_noise(cv, q, kappa, state_jitter, max_variance, acc, mu, before)
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
            extrapolate(mu, trans, off, horizon - 1, ahead, new_mean, acc)
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
    store_experts(j, mean, cov, gram, cross, transition, offset, process_noise, measurement_noise,
                  expert_predictions, mu, cv, gm, cr, trans, off, q, r, ep, rls)


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
