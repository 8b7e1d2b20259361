"""Kinematic experts: constant-velocity (CV) and constant-acceleration (CA) Kalman filters in real time.

Each expert is a Kalman filter on the state :math:`[x, \\dot x]` (CV) or
:math:`[x, \\dot x, \\ddot x]` (CA) of every coordinate, with the transition and the
process noise of the continuous white-noise acceleration (CV) or jerk (CA) model over
the real time step :math:`\\Delta` (in units of ``time_unit``, the typical sampling
interval, so that noise levels do not depend on the clock's units):

.. math::

    F_{CV} = \\begin{bmatrix} 1 & \\Delta \\\\ 0 & 1 \\end{bmatrix},\\quad
    Q_{CV} = q \\begin{bmatrix} \\Delta^3/3 & \\Delta^2/2 \\\\ \\Delta^2/2 & \\Delta \\end{bmatrix},

    F_{CA} = \\begin{bmatrix} 1 & \\Delta & \\Delta^2/2 \\\\ 0 & 1 & \\Delta \\\\ 0 & 0 & 1 \\end{bmatrix},\\quad
    Q_{CA} = q \\begin{bmatrix} \\Delta^5/20 & \\Delta^4/8 & \\Delta^3/6 \\\\ \\Delta^4/8 & \\Delta^3/3 & \\Delta^2/2
             \\\\ \\Delta^3/6 & \\Delta^2/2 & \\Delta \\end{bmatrix},

and :math:`R = r I`. The coordinates share :math:`F, Q, R` and are observed together
(a row is present or missing as a whole), so their covariances are equal: the state is
``mean (N, K, d, p)`` and one ``cov (N, K, d, d)`` per expert, ``d`` = 2 or 3.

The family keeps the *filtered* state at the time of its last measurement.
:func:`forecast` extrapolates it to any later time without changing it (a missing
measurement changes nothing); :func:`update` extrapolates to the measurement's time and
applies the Joseph-form update. The first measurement starts the filter at
``[z, 0, 0]`` with covariance ``diag(r, v0, a0)`` (``initial_variance``).

A restart (after a time gap, or the glitch screen's) starts the filter at the measurement too, but
keeps what the track's motion says: the velocity is the mean velocity across the gap, the displacement from
the old position estimate over the gap's length, with a variance that covers the old position's error, the
measurement's and how far the current velocity may have drifted from the mean one under the expert's own
model (:func:`carried_start`); the acceleration starts again as at a first measurement. Where the old state is
not finite, or the measurement's NIS against the expert's forecast across the gap is above :data:`CARRY_NIS`
per coordinate (a jump, a new identity), the restart is a first measurement.

Time steps are clipped to ``max_step`` intervals so that an absurd gap cannot overflow
the covariance; the variance cap keeps every number finite after very long gaps. A
measurement more than 1e6 standard deviations from an expert's forecast (:data:`RESTART_NIS`)
restarts that expert at it, as a first measurement, once the expert has learned a velocity (its
velocity variance is below the initial one; the second row after a start is not judged) and when
the miss is at least half the motion it forecast: a glitch the filter took in cannot leave it a
slope it would keep for thousands of rows, and a filter lagging a very fast target (in small
length units) is not restarted.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._libm import ordered_matmul as _matmul
from .._libm import ordered_sum
from ..constraints import Levels, Real

__all__ = ["KinematicParams", "KinematicState", "init_state", "forecast", "update", "transition", "process_noise",
           "RESTART_NIS", "CARRY_NIS", "restarted", "carried_start", "expert_name", "one_expert", "symmetrise"]


class KinematicParams(NamedTuple):
    """Constant parameters of one kinematic family (K experts of one order)."""

    order: int                      # d = 2 (CV) or 3 (CA)
    process_noise: np.ndarray       # (K,) q, length^2 per time_unit^(2d-3)
    measurement_noise: np.ndarray   # (K,) r, length^2
    initial_variance: np.ndarray    # (K, d) diagonal of the first covariance (r, v0[, a0])
    time_unit: float                # the time step unit (the typical sampling interval)
    max_step: float = 1e6           # longest step, in time units
    max_variance: float = 1e300     # position-variance cap (length^2)

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`): the noise levels, per expert.
    CONSTRAINTS = {"process_noise": Levels(Real(gt=0)), "measurement_noise": Levels(Real(gt=0))}

    @property
    def n_experts(self) -> int:
        return int(self.process_noise.shape[0])


class KinematicState(NamedTuple):
    mean: np.ndarray         # (N, K, d, p) filtered state at last_time
    cov: np.ndarray          # (N, K, d, d)
    last_time: np.ndarray    # (N,) time of the last measurement (NaN before the first)
    initialised: np.ndarray  # (N,) bool


#: An innovation whose NIS (squared distance in its own standard deviations) exceeds this, 1e6 standard
#: deviations, restarts the filter at the measurement, so that a glitch it took in (before the glitch
#: screen's warm-up is over) cannot leave it a slope (of 1e10, say) that a filter of low process noise
#: would keep for thousands of rows. Real motion never comes near it.
RESTART_NIS = 1e12
#: A restart keeps the mean velocity across the gap (:func:`carried_start`) when the measurement's NIS against
#: the expert's forecast across the gap is at most this per coordinate (5 standard deviations): where the
#: expert's own model could have taken the target, so that the variance it gives the velocity covers it. A
#: target that jumped (the glitch screen's relocation) is far beyond it.
CARRY_NIS = 25.0


def init_state(params: KinematicParams, n_targets: int, measurement_dim: int) -> KinematicState:
    k, d = params.n_experts, params.order
    return KinematicState(
        mean=np.zeros((n_targets, k, d, measurement_dim)),
        cov=np.broadcast_to(np.eye(d) * params.initial_variance[:, None, :], (n_targets, k, d, d)).copy(),
        last_time=np.full(n_targets, np.nan),
        initialised=np.zeros(n_targets, dtype=bool),
    )


def expert_name(params: KinematicParams, i: int, kind: str = "cv") -> str:
    """Expert ``i``'s name in reports (``cv(q=0.1, r=1)``)."""
    return f"{kind}(q={params.process_noise[i]:.3g}, r={params.measurement_noise[i]:.3g})"


def one_expert(params: KinematicParams, i: int) -> KinematicParams:
    """The parameters of expert ``i`` alone."""
    return params._replace(process_noise=params.process_noise[i:i + 1],
                           measurement_noise=params.measurement_noise[i:i + 1],
                           initial_variance=params.initial_variance[i:i + 1])


def step_delta(params: KinematicParams, state: KinematicState, time) -> np.ndarray:
    """Steps from the last measurement to ``time`` in time units, ``(N,)``, clipped to [0, max_step]."""
    delta = (np.asarray(time, dtype=np.float64) - state.last_time) / params.time_unit
    return np.clip(np.where(np.isfinite(delta), delta, 0.0), 0.0, params.max_step)


def transition(order: int, delta: np.ndarray) -> np.ndarray:
    """:math:`F(\\Delta)`, ``(..., d, d)`` for steps ``delta (...)``."""
    f = np.zeros(delta.shape + (order, order))
    for i in range(order):
        f[..., i, i] = 1.0
        if i + 1 < order:
            f[..., i, i + 1] = delta
    if order == 3:
        f[..., 0, 2] = 0.5 * delta * delta
    return f


def _noise_terms(order: int):
    """``(m, denominator)``, ``(d, d)``: entry ``(i, j)`` of :math:`Q(\\Delta)/q` is :math:`\\Delta^{m} /
    (m\\, a!\\, b!)`, ``a = d - 1 - i``, ``b = d - 1 - j``, ``m = a + b + 1`` (the integral of the white noise
    through ``a`` and ``b`` integrations); the denominator as the kernel multiplies it, ``(m * a!) * b!``."""
    a = np.arange(order - 1, -1, -1)
    fact = np.array([1.0, 1.0, 2.0])[a]
    m = np.add.outer(a, a) + 1
    return m, m * fact[:, None] * fact[None, :]


def _powers(delta: np.ndarray, order: int) -> np.ndarray:
    """``delta ** k`` for ``k = 0 .. 2d - 1`` on a last axis, as the kernel computes them (repeated squaring)."""
    return np.stack([_power(delta, k) for k in range(2 * order)], axis=-1)


def process_noise(order: int, delta: np.ndarray) -> np.ndarray:
    """:math:`Q(\\Delta)/q`, ``(..., d, d)`` (see :func:`_noise_terms`)."""
    m, denominator = _noise_terms(order)
    return _powers(np.asarray(delta, dtype=np.float64), order)[..., m] / denominator


def _power(x, m: int):
    """``x ** m`` for an integer ``m >= 0`` as the compiled kernel computes it (by repeated squaring)."""
    out = np.ones_like(x)
    while m:
        if m & 1:
            out = out * x
        m >>= 1
        x = x * x
    return out


def symmetrise(cov):
    """Off-diagonal pairs replaced by their mean; the diagonal kept as it is."""
    out = cov.copy()
    for i in range(cov.shape[-1]):
        for j in range(i + 1, cov.shape[-1]):
            out[..., i, j] = out[..., j, i] = 0.5 * (cov[..., i, j] + cov[..., j, i])
    return out


def _predict(params: KinematicParams, state: KinematicState, delta: np.ndarray):
    """Mean and covariance extrapolated by ``delta (N,)`` steps (the kernel's operations, in its order)."""
    f = transition(params.order, delta)[:, None]                                   # (N, 1, d, d)
    mean = _matmul(f, state.mean)                                                  # (N, K, d, p)
    cov = _matmul(_matmul(f, state.cov), np.swapaxes(f, -1, -2))
    m, denominator = _noise_terms(params.order)   # entry (i, j) gains (q * delta**m) / denominator, in that order
    with np.errstate(over="ignore", invalid="ignore"):
        cov = cov + params.process_noise[None, :, None, None] * _powers(delta, params.order)[:, None, m] / denominator
    return mean, symmetrise(cov)


def forecast(params: KinematicParams, state: KinematicState, time, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Each expert's predicted measurement at ``time (N,)`` and its variance per coordinate (``frames``, the
    frame-based families' horizon, is not read: a time-based family forecasts at ``time``).

    Returns
    -------
    means : ndarray (N, K, p)
    variances : ndarray (N, K) — :math:`P_{00} + r`, the same for every coordinate.
    """
    mean, cov = _predict(params, state, step_delta(params, state, time))
    variance = np.minimum(cov[..., 0, 0], params.max_variance) + params.measurement_noise
    return mean[..., 0, :], variance


def restarted(state, restart):
    """A time-based family's ``state`` with the targets that ``restart (N,)`` (or None) as not started: each
    starts again at its next learned row (this one, if learned)."""
    if restart is None or not restart.any():
        return state
    return state._replace(initialised=state.initialised & ~restart)


def carried_start(params: KinematicParams, state: KinematicState, z, delta, nis):
    """The start at ``z (N, p)`` of a filter that restarts ``delta (N,)`` time units after its ``state``, keeping
    the mean velocity across the gap: ``(mean (N, K, d, p), cov (N, K, d, d), ok (N, K))``.

    The position is the measurement, with the start's variance :math:`r_0` (``initial_variance[:, 0]``); the
    velocity is :math:`\\bar v = (z - \\hat x)/\\Delta`, with :math:`\\hat x` the old position, the
    mean velocity over the gap up to the old position's error and the noise; the acceleration (CA) starts as
    at a first measurement. The velocity's variance is :math:`(P_{00} + r_0)/\\Delta^2` plus the spread of
    the current velocity about the mean one under the expert's own model: :math:`q\\Delta/3` for CV (white
    acceleration); for CA (white jerk, the old acceleration's mean not carried)
    :math:`\\Delta^2 P_{22}/4 - P_{02} + 2q\\Delta^3/15`. The position and velocity share the measurement's
    error: their covariance is :math:`r_0/\\Delta`. ``ok`` where the step is positive, everything is finite
    and the measurement's NIS against the expert's forecast across the gap (``nis (N, K)``, summed over the
    coordinates) is at most :data:`CARRY_NIS` per coordinate: a target that jumped (a relocation, a new
    identity) starts as at a first measurement.
    """
    t = delta[:, None]                                                             # (N, 1)
    r0 = params.initial_variance[None, :, 0]                                       # (1, K)
    q = params.process_noise[None, :]
    old = state.cov
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        variance = (old[..., 0, 0] + r0) / (t * t)
        if params.order == 2:
            variance = variance + q * t / 3.0
        else:
            variance = variance - old[..., 0, 2] + t * t / 4.0 * old[..., 2, 2] + 2.0 * q * t * t * t / 15.0
        velocity = (z[:, None, :] - state.mean[..., 0, :]) / t[..., None]          # (N, K, p)
        cross = r0 / t
    ok = (t > 0.0) & np.isfinite(variance) & np.isfinite(cross) & np.isfinite(velocity).all(axis=-1) \
        & (nis <= CARRY_NIS * z.shape[-1])
    mean = np.zeros_like(state.mean)
    mean[..., 0, :] = z[:, None, :]
    mean[..., 1, :] = velocity
    cov = np.broadcast_to(np.eye(params.order) * params.initial_variance[:, None, :], old.shape).copy()
    cov[..., 1, 1] = variance
    cov[..., 0, 1] = cov[..., 1, 0] = cross
    return mean, cov, ok


def update(params: KinematicParams, state: KinematicState, measurement: np.ndarray, time, learn: np.ndarray,
           active=None, restart=None) -> KinematicState:
    """Assimilate ``measurement (N, p)`` at ``time (N,)`` for the targets where ``learn (N,)``.

    A target not yet started starts at the measurement; one that ``restart (N,)``s there too, keeping the
    mean velocity across the gap where it can (:func:`carried_start`); the others get the Joseph-form Kalman
    update of the extrapolated state. Targets outside ``learn`` are unchanged (``active`` is not read: a row
    not learned changes nothing in a time-based family).
    """
    carry = learn & state.initialised & (np.zeros_like(learn) if restart is None else np.asarray(restart, bool))
    old = state
    state = restarted(state, restart)
    time = np.asarray(time, dtype=np.float64)
    z = np.where(learn[:, None], measurement, 0.0)
    delta = step_delta(params, state, time)
    mean, cov = _predict(params, state, delta)
    r = params.measurement_noise[None, :]                                          # (1, K)
    s = cov[..., 0, 0] + r                                                         # (N, K)
    gain = cov[..., :, 0] / s[..., None]                                           # (N, K, d)
    innovation = z[:, None, :] - mean[..., 0, :]                                   # (N, K, p)
    new_mean = mean + gain[..., :, None] * innovation[..., None, :]
    a = np.broadcast_to(np.eye(params.order), cov.shape).copy()                     # A = I - g e0^T
    a[..., :, 0] = a[..., :, 0] - gain
    new_cov = _matmul(_matmul(a, cov), np.swapaxes(a, -1, -2)) \
        + r[..., None, None] * gain[..., :, None] * gain[..., None, :]
    new_cov = symmetrise(new_cov)
    excess = np.maximum(new_cov[..., 0, 0] / params.max_variance, 1.0)
    new_cov = new_cov / excess[..., None, None]

    # an innovation more than 1e6 of its standard deviations away (a glitch the filter took in) restarts it
    # asked once the filter has learned a velocity (its velocity variance below the initial one: the second row
    # after a start is judged against the initial velocity spread, which a fast target in small units exceeds),
    # and only when the miss is at least half the forecast motion (a glitch, or the slope one left; not the lag
    # of a filter behind a very fast target)
    with np.errstate(over="ignore", invalid="ignore"):
        squared = innovation * innovation
        nis, miss = ordered_sum(squared / s[..., None]), ordered_sum(squared)
        motion = mean[..., 0, :] - state.mean[..., 0, :]
        move = ordered_sum(motion * motion)
    learned = state.cov[..., 1, 1] < params.initial_variance[None, :, 1]
    absurd = learned & ~(nis <= RESTART_NIS) & ~(miss <= 0.25 * move)            # (N, K)
    start = (learn & ~state.initialised)[:, None] | ((learn & state.initialised)[:, None] & absurd)
    go = (learn & state.initialised)[:, None] & ~absurd
    first_mean = np.zeros_like(state.mean)
    first_mean[..., 0, :] = z[:, None, :]
    first_cov = np.broadcast_to(np.eye(params.order) * params.initial_variance[:, None, :], state.cov.shape)
    # a restart after a gap keeps the mean velocity across it (the old state is read: restarted() keeps it)
    if carry.any():
        kept_mean, kept_cov, kept = carried_start(params, old, z, delta, nis)
        kept = kept & carry[:, None]
        first_mean = np.where(kept[..., None, None], kept_mean, first_mean)
        first_cov = np.where(kept[..., None, None], kept_cov, first_cov)

    def pick(fresh, updated, old):
        shape = start.shape + (1,) * (old.ndim - 2)
        return np.where(start.reshape(shape), fresh, np.where(go.reshape(shape), updated, old))

    return KinematicState(
        mean=pick(first_mean, new_mean, state.mean),
        cov=pick(first_cov, new_cov, state.cov),
        last_time=np.where(learn, time, state.last_time),
        initialised=state.initialised | learn,
    )
