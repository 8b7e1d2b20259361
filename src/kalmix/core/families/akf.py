"""The paper's state-model adaptive Kalman filters (AKF) as a family of a bank.

The experts are those of :mod:`kalmix.core.mixture` (``rls`` / ``literal`` / ``fixed``
dynamics, each with its own noise levels); only their predictions leave the family,
so it has no gate: :func:`kalmix.bank.make_bank` builds it with ``gating="none"``
(nothing is scored or learned for a gate, which would only cost time) and
``adapt_noise=False`` (the paper's eq. 11/12 feedback from the gate belongs to the
paper's own mixture, :func:`kalmix.core.mixture.step`).

The AKF is frame-based: a row is one frame, whatever its time stamp, and a present
but not learned row (missing, or rejected as a glitch) advances the filters one frame
without learning. ``forecast`` ignores ``time`` and gives the prediction ``frames``
frames ahead of the last row.
"""

from __future__ import annotations

import numpy as np

from ..mixture import MixtureParams, MixtureState, init_state as _init, predict, step

__all__ = ["init_state", "forecast", "update"]


def init_state(params: MixtureParams, n_targets: int, measurement_dim: int) -> MixtureState:
    return _init(params, n_targets, stream_ids=np.zeros(n_targets, dtype=np.int64))


def forecast(params: MixtureParams, state: MixtureState, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Experts' predictions ``frames`` ahead ``(N, K, p)`` and their variances ``(N, K, p)``.

    The variance is that of the next frame's innovation, :math:`\\kappa^2 P_{11} + R`.
    """
    if frames == 1:
        means = state.expert_predictions
    else:
        means = predict(params, state, frames)[1]
    p = params.measurement_dim
    variances = params.feature_scale**2 * np.diagonal(state.cov, axis1=-2, axis2=-1)[..., :p] \
        + state.measurement_noise
    return means, variances


def update(params: MixtureParams, state: MixtureState, measurement, learn, active) -> MixtureState:
    """One frame for the ``active`` targets: learn ``measurement`` where ``learn``, else predict only."""
    z = np.where(learn[:, None], measurement, np.nan)
    new, _ = step(params, state, z)
    shape = lambda a: (-1,) + (1,) * (a.ndim - 1)  # noqa: E731
    return MixtureState(*(np.where(active.reshape(shape(n)), n, o) for n, o in zip(new, state)))
