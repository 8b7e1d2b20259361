"""Helpers shared by the rules."""

import numpy as np

from .._libm import exp, log, ordered_sum  # noqa: F401 - the kernels' arithmetic, for the rules


def normalise_awake(log_weights, awake):
    """Softmax of ``log_weights (N, K)`` over the awake experts; rows with none awake are zero."""
    masked = np.where(awake, log_weights, -np.inf)
    top = masked.max(axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    w = np.where(awake, exp(np.where(awake, masked - top, 0.0)), 0.0)
    total = ordered_sum(w, keepdims=True)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0)


def mixture_and_regret(weights, experts, measurement, awake):
    """The mixture :math:`\\hat y = \\sum_k w_k x_k` over the awake experts ``(N, p)`` and the regret of the
    gradient trick :math:`r_k = 2 (\\hat y - y) \\cdot (\\hat y - x_k)` ``(N, K)``, zero for sleeping experts."""
    x = np.where(awake[..., None], experts, 0.0)
    mix = ordered_sum(weights[..., None] * x, axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        r = 2.0 * ordered_sum((mix - measurement)[:, None, :] * (mix[:, None, :] - x))
    return mix, np.where(awake, r, 0.0)


def linearised_regret(weights, experts, measurement, awake):
    """:math:`r_k = 2 (\\hat y - y) \\cdot (\\hat y - x_k)`, the regret of the gradient trick, ``(N, K)``
    (:func:`mixture_and_regret`'s)."""
    return mixture_and_regret(weights, experts, measurement, awake)[1]
