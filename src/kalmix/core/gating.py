"""Gating network of the mixture of experts (paper eq. 8-10) and its alternatives.

All functions are pure and batched: leading axes are targets, the last axis (or the
second to last for gate parameters) indexes the K experts.
"""

from __future__ import annotations

import numpy as np

from . import _libm

__all__ = [
    "gating_features",
    "softmax_gate",
    "log_expert_likelihood",
    "posterior",
    "paper_gate_update",
    "fixed_share_update",
    "learning_rate",
    "adapt_noise",
    "random_weights",
]

GATING_INPUTS = ("bias", "position", "velocity")


def gating_features(kind: str, features: np.ndarray, velocity: np.ndarray, velocity_scale: float) -> np.ndarray:
    """Input :math:`x_k` of the gating network.

    ``bias``: :math:`[1]`; ``position``: :math:`[1; s_k]`; ``velocity``:
    :math:`[1; s_k; \\Delta s_k / v_0]`, all of order one.

    Parameters
    ----------
    kind : {"bias", "position", "velocity"}
    features : ndarray, shape (..., p)
        Normalised features :math:`s_k`.
    velocity : ndarray, shape (..., p)
        :math:`\\Delta s_k = s_k - s_{k-1}`.
    velocity_scale : float
        :math:`v_0`.
    """
    ones = np.ones(features.shape[:-1] + (1,))
    if kind == "bias":
        return ones
    if kind == "position":
        return np.concatenate([ones, features], axis=-1)
    return np.concatenate([ones, features, velocity / velocity_scale], axis=-1)


def gating_input_size(kind: str, measurement_dim: int) -> int:
    """Length of the gating input for ``kind``."""
    return {"bias": 1, "position": 1 + measurement_dim, "velocity": 1 + 2 * measurement_dim}[kind]


def softmax_gate(gate_weights: np.ndarray, inputs: np.ndarray, temperature: float) -> np.ndarray:
    """Eq. (8): :math:`g_i = e^{u_i/T} / \\sum_j e^{u_j/T}`, :math:`u_i = x^T a_i`.

    Parameters
    ----------
    gate_weights : ndarray, shape (..., K, m)
        Synaptic weights :math:`a_i`.
    inputs : ndarray, shape (..., m)
    temperature : float
    """
    logits = _libm.ordered_sum(gate_weights * inputs[..., None, :], axis=-1) / temperature
    top = np.take_along_axis(logits, _libm.first_max(logits)[..., None], axis=-1)   # the kernels' running max
    scores = _libm.exp(logits - top)
    return scores / _libm.ordered_sum(scores, axis=-1, keepdims=True)


def log_expert_likelihood(errors: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Log of the Gaussian score of eq. (10) for each expert.

    .. math:: \\ell_i = -p \\log \\sigma_i - \\frac{\\|d_k - y_{i,k-1}\\|^2}{2 \\sigma_i^2}

    Parameters
    ----------
    errors : ndarray, shape (..., K, p)
        :math:`d_k - y_{i,k-1}`, the error of the prediction made at :math:`k-1`.
    scale : ndarray, shape (K,) or (..., K)
        :math:`\\sigma_i`.
    """
    p = errors.shape[-1]
    squared = _libm.ordered_sum(errors * errors, axis=-1)
    return -p * _libm.log(scale) - squared / (2.0 * scale**2)


#: Floor of the log joint scores of :func:`posterior`: an error whose square overflows
#: (values near 1e154 and beyond) scores -inf, and -inf everywhere has no posterior.
LOG_FLOOR = -1e300
#: Largest squared error fed to :func:`learning_rate` (an overflowed one is inf).
ERROR_CAP = 1e300


def posterior(weights: np.ndarray, log_likelihood: np.ndarray) -> np.ndarray:
    r"""Eq. (10) in log space: :math:`h_i \propto g_i\, e^{\ell_i}`.

    Finite and normalised even when every likelihood underflows in linear space, and when
    squared errors overflow (log scores are floored at :data:`LOG_FLOOR`). The largest score
    is split out first, so that the normalisation does not round at the scores' magnitude
    (scores of -1e12 would leave the weights off by 1e-4):
    :math:`h_i = e_i / (1 + \sum_{j \ne top} e_j)`, :math:`e_i = e^{a_i - a_{top}}`, the
    compiled kernels' operations in their order (and the C library's ``exp`` and ``log``).
    """
    log_joint = np.maximum(_libm.log(np.maximum(weights, 1e-300)) + log_likelihood, LOG_FLOOR)
    top = _libm.first_max(log_joint)[..., None]
    scores = _libm.exp(log_joint - np.take_along_axis(log_joint, top, axis=-1))
    k = np.arange(log_joint.shape[-1])
    rest = _libm.ordered_sum(np.where(k == top, 0.0, scores), axis=-1, keepdims=True)
    return scores * (1.0 / (1.0 + rest))


def paper_gate_update(gate_weights, rate, responsibilities, weights, inputs):
    """Eq. (9): :math:`a_i \\leftarrow a_i + \\eta_k (h_i - g_i) x_k`.

    Parameters
    ----------
    gate_weights : ndarray, shape (..., K, m)
    rate : ndarray, shape (...)
        :math:`\\eta_k`.
    responsibilities, weights : ndarray, shape (..., K)
        :math:`h` and the :math:`g` that produced the scored prediction.
    inputs : ndarray, shape (..., m)
        The :math:`x` that produced :math:`g`.
    """
    step = (rate[..., None] * (responsibilities - weights))[..., :, None] * inputs[..., None, :]
    return gate_weights + step


def fixed_share_update(weights, log_likelihood, temperature: float, share: float):
    """Tracking-the-best-expert gate (fixed share), a softmax over running log-scores.

    .. math::
        \\tilde g_i \\propto g_i\\, e^{\\ell_i / T}, \\qquad
        g_i \\leftarrow (1 - \\alpha_s) \\tilde g_i + \\alpha_s / K

    The logits of this softmax are the experts' discounted log-likelihoods; the share
    :math:`\\alpha_s` lets weight flow back to an expert that was poor in an earlier
    regime, so the gate follows whichever expert is best *now*.
    """
    tempered = posterior(weights, log_likelihood / temperature)
    k = weights.shape[-1]
    return (1.0 - share) * tempered + share / k


def learning_rate(valid_steps, last_error, initial: float, minimum: float, decay_steps: float, sensitivity: float):
    """Adaptive rate :math:`\\eta_k = \\eta(t)(1 - e^{-\\alpha \\varepsilon})`.

    .. math:: \\eta(t) = \\eta_{min} + (\\eta_0 - \\eta_{min}) e^{-t/\\tau}

    Parameters
    ----------
    valid_steps : ndarray (...)
        :math:`t`, the number of measurements seen so far.
    last_error : ndarray (...)
        :math:`\\varepsilon`, squared prediction error (summed over coordinates) of the
        currently dominant expert.
    """
    base = minimum + (initial - minimum) * _libm.exp(-np.asarray(valid_steps, dtype=np.float64) / decay_steps)
    return base * -_libm.expm1(-sensitivity * np.minimum(last_error, ERROR_CAP))


def adapt_noise(noise, initial, rate, responsibilities, shrink: float, floor: float, reinflation: float):
    """Eq. (11)/(12) with an optional floor and re-inflation.

    .. math::
        Q_i \\leftarrow Q_i (1 - \\beta \\eta_k h_i), \\quad
        Q_i \\leftarrow Q_i + \\gamma (Q_{i,0} - Q_i), \\quad
        Q_i \\leftarrow \\max(Q_i, \\phi Q_{i,0})

    With :math:`\\gamma = 0` and :math:`\\phi = 0` this is exactly the paper's rule.

    Parameters
    ----------
    noise : ndarray, shape (..., K, p)
        Diagonal of :math:`Q_i` (or :math:`R_i`).
    initial : ndarray, shape (K, p)
    rate : ndarray (...)
    responsibilities : ndarray (..., K)
    shrink : float
        :math:`\\beta` (or :math:`\\beta'`).
    floor : float
        :math:`\\phi`.
    reinflation : float
        :math:`\\gamma`.
    """
    factor = 1.0 - shrink * rate[..., None] * responsibilities
    noise = noise * np.maximum(factor, 0.0)[..., None]
    noise = noise + reinflation * (initial - noise)
    return np.maximum(noise, floor * initial)


_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        x = (x + np.uint64(0x9E3779B97F4A7C15)) & _MASK64
        x = ((x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & _MASK64
        x = ((x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & _MASK64
        return x ^ (x >> np.uint64(31))


def random_weights(seed: int, stream_ids: np.ndarray, steps: np.ndarray, n_experts: int) -> np.ndarray:
    """Random gating weights for the random-gating baseline, normalised to sum to one.

    Counter-based (a hash of seed, stream, step and expert), so the draw needs no
    random-generator state: a saved and resumed run, and a stream run alone or inside
    a batch, see the same weights.

    Returns
    -------
    ndarray, shape (len(stream_ids), n_experts)
    """
    with np.errstate(over="ignore"):
        key = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(0x51ED))
        key = _splitmix64(key ^ np.asarray(stream_ids, dtype=np.uint64)[:, None])
        key = _splitmix64(key ^ (np.asarray(steps, dtype=np.uint64)[:, None] * np.uint64(0x9E37)))
        key = _splitmix64(key ^ np.arange(n_experts, dtype=np.uint64)[None, :])
    uniform = (key >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53)) + 1e-12
    return uniform / _libm.ordered_sum(uniform, axis=-1, keepdims=True)
