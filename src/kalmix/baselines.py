"""Baselines in the same engine, so that every row of a comparison is computed alike.

Each factory returns a :class:`~kalmix.predictor.MixturePredictor`; the single AKF (the
paper's baseline) is fixed before any result was seen: the bank recipe with K = 1, i.e. the
middle of the noise grid, with eq. (11)/(12) off.
"""

from __future__ import annotations

import numpy as np

from .predictor import MixturePredictor

__all__ = [
    "softmax_mixture",
    "single_akf",
    "random_mixture",
    "cv_kalman",
    "ca_kalman",
    "no_prediction",
    "best_expert_in_hindsight",
]


def softmax_mixture(n_experts: int = 40, *, seed: int = 0, **options) -> MixturePredictor:
    """The default mixture of K adaptive Kalman experts."""
    return MixturePredictor(n_experts, seed=seed, **options)


def single_akf(*, seed: int = 0, **options) -> MixturePredictor:
    """One state-model AKF: the middle expert of the bank, no Q/R adaptation."""
    options.setdefault("adapt_noise", False)
    return MixturePredictor(1, seed=seed, **options)


def random_mixture(n_experts: int = 40, *, seed: int = 0, **options) -> MixturePredictor:
    """The same bank with gating weights drawn at random each frame (no gate learning)."""
    return MixturePredictor(n_experts, seed=seed, gating="random", **options)


def _fixed(order: int, degree: int, process_noise: float, measurement_noise: float, **options):
    options.setdefault("length_unit", 1.0)
    unit = options["length_unit"]
    return MixturePredictor(
        1, dynamics="fixed", order=order, prior_degree=degree, adapt_noise=False,
        process_noise_range=(process_noise / unit**2,) * 2,
        measurement_noise_range=(measurement_noise / unit**2,) * 2, **options)


def cv_kalman(process_noise: float = 1.0, measurement_noise: float = 0.25, **options) -> MixturePredictor:
    """Fixed constant-velocity Kalman filter, :math:`s_{k+1} = 2 s_k - s_{k-1} + w_k`.

    ``process_noise`` and ``measurement_noise`` are variances in measurement units squared.
    """
    return _fixed(2, 1, process_noise, measurement_noise, **options)


def ca_kalman(process_noise: float = 1.0, measurement_noise: float = 0.25, **options) -> MixturePredictor:
    """Fixed constant-acceleration Kalman filter, :math:`s_{k+1} = 3 s_k - 3 s_{k-1} + s_{k-2} + w_k`."""
    return _fixed(3, 2, process_noise, measurement_noise, **options)


def no_prediction(measurements: np.ndarray) -> np.ndarray:
    """Repeat the last measurement (carrying the last one forward over missing rows).

    Returns an array like ``measurements`` where row ``t`` predicts row ``t + 1``.
    """
    array = np.asarray(measurements, dtype=float)
    out = array.copy()
    for t in range(1, len(out)):
        missing = np.isnan(out[t])
        out[t][missing] = out[t - 1][missing]
    return out


def best_expert_in_hindsight(expert_predictions: np.ndarray, measurements: np.ndarray, horizon: int = 1):
    """The single expert with the lowest RMS error over the whole run (an oracle).

    Parameters
    ----------
    expert_predictions : ndarray, shape (T, K, p)
        Row ``t`` predicts ``measurements[t + horizon]``.
    measurements : ndarray, shape (T, p)

    Returns
    -------
    index : int
    predictions : ndarray, shape (T, p)
    """
    errors = expert_predictions[:-horizon] - measurements[horizon:, None, :]
    squared = np.nanmean(np.sum(errors**2, axis=-1), axis=0)
    index = int(np.nanargmin(squared))
    return index, expert_predictions[:, index]
