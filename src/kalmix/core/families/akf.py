"""The paper's state-model adaptive Kalman filters (AKF) as a family of a bank.

The experts are those of :mod:`kalmix.core.mixture` (``rls`` / ``literal`` / ``fixed``
dynamics, each with its own noise levels); only their predictions leave the family,
so it has no gate: :func:`kalmix.bank.make_bank` builds it with ``gating="none"``
(nothing is scored or learned for a gate, which would only cost time) and
``adapt_noise=False`` (the paper's eq. 11/12 feedback from the gate belongs to the
paper's own mixture, :func:`kalmix.core.mixture.step`).

The AKF is frame-based: a row is one frame, whatever its time stamp, and a present
but not learned row (missing, or rejected as a glitch) advances the filters one frame
without learning. It takes the arguments every family takes and reads the frame clock
in them: ``forecast`` ignores ``time`` and gives the prediction ``frames`` frames ahead
of the last row; ``update`` ignores ``time`` and advances the ``active`` targets (those
with a row) one frame.
"""

from __future__ import annotations

import numpy as np

from ..mixture import MixtureParams, MixtureState, init_state as _init, predict, step

__all__ = ["init_state", "forecast", "update", "expert_name", "one_expert"]


def init_state(params: MixtureParams, n_targets: int, measurement_dim: int) -> MixtureState:
    return _init(params, n_targets, stream_ids=np.zeros(n_targets, dtype=np.int64))


def forecast(params: MixtureParams, state: MixtureState, time, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Experts' predictions ``frames`` ahead ``(N, K, p)`` and their variances ``(N, K, p)`` (``time`` is not
    read: a frame-based family counts rows).

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


def update(params: MixtureParams, state: MixtureState, measurement, time, learn, active,
           restart=None) -> MixtureState:
    """One frame for the ``active`` targets: learn ``measurement`` where ``learn``, else predict only
    (``time`` is not read). A target that ``restart (N,)``s starts again as new at this frame."""
    if restart is not None and restart.any():
        fresh = init_state(params, len(restart), measurement.shape[-1])
        state = MixtureState(*(np.where(restart.reshape(_column(o)), f, o) for f, o in zip(fresh, state)))
    z = np.where(learn[:, None], measurement, np.nan)
    new, _ = step(params, state, z)
    return MixtureState(*(np.where(active.reshape(_column(n)), n, o) for n, o in zip(new, state)))


def expert_name(params: MixtureParams, i: int, kind: str = "akf") -> str:
    """Expert ``i``'s name in reports (``akf[3]``)."""
    return f"{kind}[{i}]"


def one_expert(params: MixtureParams, i: int) -> MixtureParams:
    """The parameters of expert ``i`` alone."""
    from dataclasses import replace

    return replace(params, **{name: getattr(params, name)[i:i + 1] for name in (
        "forgetting", "ridge", "process_noise", "measurement_noise", "initial_variance", "initial_velocity",
        "expert_scale")})


def _column(array) -> tuple:
    """The shape that broadcasts a per-target ``(N,)`` mask over ``array (N, ...)``."""
    return (-1,) + (1,) * (array.ndim - 1)
