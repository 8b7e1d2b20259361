"""The gate of the compiled AKF kernel (:mod:`._numba_kernels`): eq. 8-10, the fixed-share and random gates, and
the noise feedback of eq. 11/12.

Each function does, for one target, the operations of :mod:`kalmix.core.gating` in the same order
(the log-sum-exp with the largest score split out, the C library's exp / expm1 / log, the splitmix64
random gate), so that the compiled mixture gives the numpy reference's bits.
"""

from __future__ import annotations

import math

import numpy as np

from . import _numba_linalg as la

jit = la.jit

#: :data:`kalmix.core.gating.LOG_FLOOR` and :data:`kalmix.core.gating.ERROR_CAP` (a test checks
#: that they agree; literals here so that the compiled cache, keyed on this file, follows them).
LOG_FLOOR = -1e300
ERROR_CAP = 1e300


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
def adapt_noise(noise, initial, rate, resp, floor, reinflation, factor):
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
