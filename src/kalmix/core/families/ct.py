"""Coordinated-turn Kalman experts: an extended Kalman filter of velocity and turn rate, in real time.

Each expert is an extended Kalman filter (EKF) on the state :math:`[x, y, v_x, v_y, \\omega]` of the plane of
the first two coordinates: position, velocity and turn rate (radians per time unit), the target moving on a
circular arc at constant speed and turn rate over a step :math:`\\Delta` (in units of ``time_unit``), the
velocity turning by :math:`u = \\omega\\Delta`:

.. math::

    \\begin{bmatrix} x' \\\\ y' \\end{bmatrix} = \\begin{bmatrix} x \\\\ y \\end{bmatrix}
        + \\Delta \\begin{bmatrix} s & -c \\\\ c & s \\end{bmatrix}
          \\begin{bmatrix} v_x \\\\ v_y \\end{bmatrix},\\quad
    \\begin{bmatrix} v_x' \\\\ v_y' \\end{bmatrix} = \\begin{bmatrix} \\cos u & -\\sin u \\\\ \\sin u & \\cos u
        \\end{bmatrix} \\begin{bmatrix} v_x \\\\ v_y \\end{bmatrix},\\quad
    s = \\frac{\\sin u}{u},\\ c = \\frac{1 - \\cos u}{u}

(:math:`s` and :math:`c` computed from :math:`\\sin(u/2)` without the quotients' cancellation on a nearly
straight track; in Cartesian velocity the filter has no singularity at rest, where a heading would have one),
with the Jacobian of that map for the covariance, and the process noise of a white acceleration on each axis
(density ``process_noise`` :math:`q`, length^2 per time_unit^3: the CV model's blocks
:math:`q[\\Delta^3/3, \\Delta^2/2; \\Delta^2/2, \\Delta]`) and of a turn rate that drifts as a random walk of density
:math:`q_\\omega = q_j / (|v|^2 + q_j)` (rad^2 per time_unit^3, at most 1): a white lateral jerk of density
``turn_noise`` :math:`q_j` (length^2 per time_unit^5) over the speed squared, so that a fast target's heading is
not taken to swing with every noisy row (a vessel sampled every half hour moves thousands of noise sizes a
step). The measurement is the position with :math:`R = r I`; the update is in Joseph form. A third and further
coordinate (an altitude) is a constant-velocity Kalman filter of the same :math:`q` and :math:`r` (as
:mod:`.kinematic`'s, the coordinates sharing one covariance).

Why a family of it: a mixture of filters each of fixed motion cannot follow a target that switches between
straight runs and turns, since each filter's velocity lags the change; an interacting multiple-model filter
mixes its filters' states at every step, which a rule over separate experts cannot. A filter whose state holds
the turn rate follows both (the model zoo's switching scenario, ``benchmarks/results/model_zoo.json``). Its
experts span the process and turn noise (:data:`kalmix.bank.CT_PROCESS_LEVELS`, :data:`kalmix.bank.CT_TURN_LEVELS`).

A target's first learned row sets its position; its second (a step later) starts every expert: the velocity
from the two, turn rate 0, with each axis' covariance of a two-point start (``r``, ``r/Δ``, ``2r/Δ²``) and the
turn rate's variance ``initial_turn_variance``. Before it, an expert forecasts the last position with the
variance :math:`r + v_0 \\Delta^2` (``initial_variance`` :math:`v_0`). A row at the time of the last one (no step)
is one more measurement of the same state (before the second row, it replaces the position held). The velocity
is clipped to ``max_velocity`` length units per time unit and the turn rate to :math:`\\pm\\pi` per time unit;
steps are clipped to ``max_step`` and the position variance scaled down to ``max_variance``, so that numbers
stay finite for finite input. A measurement more than 10 standard deviations from an expert's forecast
(:data:`LOST_NIS`) starts that expert again from the last two rows: after an abrupt manoeuvre a filter of little
noise can take the change for a growing oscillation of its turn rate, spinning ever faster, confident and off the
track, with no single innovation beyond the other families' 1e6 standard deviations. The compiled kernel
(:mod:`kalmix.core.compiled.ct`) follows these formulas in the same order.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._libm import cos, sin
from .._libm import ordered_matmul as _matmul
from ..constraints import Levels, Real
from .kinematic import restarted, step_delta, symmetrise   # the same clipped step, restart and symmetrising

__all__ = ["CTParams", "CTState", "init_state", "forecast", "update", "expert_name", "one_expert", "PLANE",
           "SMALL_TURN", "LOST_NIS"]

#: The coordinates the turn is in: the first two (east and north of a geographic track; x and y).
PLANE = 2
#: An innovation whose NIS (squared distance in its own standard deviations, over the plane's two coordinates) is
#: above this, 10 standard deviations, starts the expert again from the last two rows: under its own model it never
#: comes (a probability of e^-50), and a filter lost after a manoeuvre comes back at once.
LOST_NIS = 100.0
#: Below a turn of this many radians over a step, the slopes of the turn's terms are their series (the quotients
#: cancel).
SMALL_TURN = 1e-3


class CTParams(NamedTuple):
    """Constant parameters of one coordinated-turn Kalman family (K experts)."""

    process_noise: np.ndarray       # (K,) q, length^2 per time_unit^3 (a white acceleration on each axis)
    turn_noise: np.ndarray          # (K,) q_j, a lateral jerk: length^2 per time_unit^5
    measurement_noise: np.ndarray   # (K,) r, length^2
    initial_variance: np.ndarray    # (K,) v0: the velocity's variance before a target's second row
    length_unit: float              # u: the velocity clip is in these units
    time_unit: float                # the time step unit (the typical sampling interval)
    initial_turn_variance: float = 0.1   # w0, rad^2 per time_unit^2
    max_step: float = 1e6           # longest step, in time units
    max_variance: float = 1e300     # position-variance cap (length^2)
    max_velocity: float = 1e8       # velocity clip, length units per time unit

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`): the noise levels, per expert.
    CONSTRAINTS = {"process_noise": Levels(Real(gt=0)), "turn_noise": Levels(Real(gt=0)),
                   "measurement_noise": Levels(Real(gt=0))}

    @property
    def n_experts(self) -> int:
        return int(self.process_noise.shape[0])


class CTState(NamedTuple):
    mean: np.ndarray         # (N, K, 5) filtered [x, y, vx, vy, omega] at last_time
    cov: np.ndarray          # (N, K, 5, 5)
    extra_mean: np.ndarray   # (N, K, 2, p - 2) position and velocity of each further coordinate
    extra_cov: np.ndarray    # (N, K, 2, 2)
    position: np.ndarray     # (N, p) last learned measurement
    known: np.ndarray        # (N,) learned rows since the start, at most 2 (2: the filters run)
    last_time: np.ndarray    # (N,) its time (NaN before the first)
    initialised: np.ndarray  # (N,) bool


def init_state(params: CTParams, n_targets: int, measurement_dim: int) -> CTState:
    if measurement_dim < PLANE:
        raise ValueError(f"measurement_dim: a coordinated-turn family needs at least {PLANE} coordinates (a "
                         f"plane to turn in), got {measurement_dim}")
    k, e = params.n_experts, measurement_dim - PLANE
    return CTState(mean=np.zeros((n_targets, k, 5)), cov=np.zeros((n_targets, k, 5, 5)),
                   extra_mean=np.zeros((n_targets, k, 2, e)), extra_cov=np.zeros((n_targets, k, 2, 2)),
                   position=np.zeros((n_targets, measurement_dim)), known=np.zeros(n_targets),
                   last_time=np.full(n_targets, np.nan), initialised=np.zeros(n_targets, dtype=bool))


def expert_name(params: CTParams, i: int, kind: str = "ct") -> str:
    """Expert ``i``'s name in reports (``ct(q=0.1, q_turn=0.01, r=1)``: ``q_turn`` is the lateral jerk)."""
    return (f"{kind}(q={params.process_noise[i]:.3g}, q_turn={params.turn_noise[i]:.3g}, "
            f"r={params.measurement_noise[i]:.3g})")


def one_expert(params: CTParams, i: int) -> CTParams:
    """The parameters of expert ``i`` alone."""
    return params._replace(process_noise=params.process_noise[i:i + 1], turn_noise=params.turn_noise[i:i + 1],
                           measurement_noise=params.measurement_noise[i:i + 1],
                           initial_variance=params.initial_variance[i:i + 1])


def _turn_terms(u):
    """For the turn :math:`u = \\omega\\Delta` of a step: ``sin u / u``, ``(1 - cos u) / u`` and their slopes,
    ``cos u``, ``sin u``, free of the cancellation of the quotients on a nearly straight track."""
    half = 0.5 * u
    zero = half == 0.0
    sinc_half = np.where(zero, 1.0, sin(half) / np.where(zero, 1.0, half))
    c_half = cos(half)
    s_half = sin(half)
    along = sinc_half * c_half                                    # sin u / u
    across = s_half * sinc_half                                   # (1 - cos u) / u
    c_u = cos(u)
    s_u = sin(u)
    series = np.abs(u) < SMALL_TURN
    safe = np.where(series, 1.0, u)
    along_slope = np.where(series, -u / 3.0 + u * u * u / 30.0, (c_u - along) / safe)
    across_slope = np.where(series, 0.5 - u * u / 8.0 + u * u * u * u / 144.0, (s_u - across) / safe)
    return along, across, along_slope, across_slope, c_u, s_u


def _predict(params: CTParams, state: CTState, delta):
    """Every expert's state extrapolated by ``delta (N,)`` time units: ``(mean, cov, extra_mean, extra_cov)``
    (the kernel's operations, in its order)."""
    d = np.broadcast_to(delta[:, None], state.mean.shape[:2])                      # (N, K)
    x, y, vx, vy, w = (state.mean[..., i] for i in range(5))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        along, across, along_slope, across_slope, c_u, s_u = _turn_terms(w * d)
        a1 = d * along
        a2 = d * across
        d2 = d * d
        jac = np.zeros(state.cov.shape)
        for i in range(5):
            jac[..., i, i] = 1.0
        jac[..., 0, 2] = a1
        jac[..., 0, 3] = -a2
        jac[..., 0, 4] = d2 * (along_slope * vx - across_slope * vy)
        jac[..., 1, 2] = a2
        jac[..., 1, 3] = a1
        jac[..., 1, 4] = d2 * (across_slope * vx + along_slope * vy)
        jac[..., 2, 2] = c_u
        jac[..., 2, 3] = -s_u
        jac[..., 2, 4] = d * (-s_u * vx - c_u * vy)
        jac[..., 3, 2] = s_u
        jac[..., 3, 3] = c_u
        jac[..., 3, 4] = d * (c_u * vx - s_u * vy)
        mean = np.stack([x + a1 * vx - a2 * vy, y + a2 * vx + a1 * vy, c_u * vx - s_u * vy, s_u * vx + c_u * vy, w],
                        axis=-1)
        cov = _matmul(_matmul(jac, state.cov), np.swapaxes(jac, -1, -2))
        q = params.process_noise[None, :]
        jerk = params.turn_noise[None, :]
        s2 = vx * vx + vy * vy
        qw = jerk / (s2 + jerk)   # the turn rate's noise: the lateral jerk's over the speed squared
        d3 = d2 * d
        noise = np.zeros(state.cov.shape)
        for i in range(2):   # a white acceleration of density q on each axis (the CV model's blocks)
            noise[..., i, i] = q * d3 / 3.0
            noise[..., i, i + 2] = q * d2 / 2.0
            noise[..., i + 2, i] = q * d2 / 2.0
            noise[..., i + 2, i + 2] = q * d
        noise[..., 4, 4] = qw * d
        cov = symmetrise(cov + noise)
        # the further coordinates: constant velocity
        em, ec = state.extra_mean, state.extra_cov
        extra_mean = np.stack([em[..., 0, :] + d[..., None] * em[..., 1, :], em[..., 1, :]], axis=-2)
        a00 = ec[..., 0, 0] + d * ec[..., 1, 0]
        a01 = ec[..., 0, 1] + d * ec[..., 1, 1]
        a10 = ec[..., 1, 0]
        a11 = ec[..., 1, 1]
        c00 = a00 + a01 * d + q * d3 / 3.0
        c01 = a01 + q * d2 / 2.0
        c10 = a10 + a11 * d + q * d2 / 2.0
        c11 = a11 + q * d
        off = 0.5 * (c01 + c10)
        extra_cov = np.stack([np.stack([c00, off], -1), np.stack([off, c11], -1)], -2)
    return mean, cov, extra_mean, extra_cov


def _variance(params: CTParams, cov):
    """The forecast's variance per coordinate (of the plane's): the mean of its position variances, capped, + r."""
    return np.minimum(0.5 * (cov[..., 0, 0] + cov[..., 1, 1]), params.max_variance) + params.measurement_noise


def forecast(params: CTParams, state: CTState, time, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Each expert's predicted measurement at ``time (N,)`` and its variance per coordinate (``frames`` is not
    read: a time-based family forecasts at ``time``).

    Returns
    -------
    means : ndarray (N, K, p)
    variances : ndarray (N, K)
    """
    delta = step_delta(params, state, time)
    mean, cov, extra_mean, _ = _predict(params, state, delta)
    running = (state.known >= 2)[:, None, None]
    means = np.concatenate([mean[..., :PLANE], extra_mean[..., 0, :]], axis=-1)
    held = np.broadcast_to(state.position[:, None, :], means.shape)
    with np.errstate(over="ignore", invalid="ignore"):
        waiting = np.minimum(params.measurement_noise[None, :] + params.initial_variance[None, :]
                             * (delta * delta)[:, None], params.max_variance)
    return np.where(running, means, held), np.where(running[..., 0], _variance(params, cov), waiting)


def _started(params: CTParams, state: CTState, z, delta):
    """Every expert started from the last learned row and ``z (N, p)``, ``delta (N,)`` time units later (> 0):
    ``(mean, cov, extra_mean, extra_cov)``."""
    n, k = state.mean.shape[:2]
    r = np.broadcast_to(params.measurement_noise[None, :], (n, k))
    bound = params.max_velocity * params.length_unit
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        dd = np.where(delta > 0, delta, 1.0)
        velocity = np.clip((z - state.position) / dd[:, None], -bound, bound)          # (N, p)
        velocity = np.where(np.isnan(velocity), 0.0, velocity)
        mean = np.zeros((n, k, 5))
        mean[..., 0] = z[:, None, 0]
        mean[..., 1] = z[:, None, 1]
        mean[..., 2] = velocity[:, None, 0]
        mean[..., 3] = velocity[:, None, 1]
        cross = r / dd[:, None]
        speed_variance = 2.0 * r / (dd * dd)[:, None]
        cov = np.zeros((n, k, 5, 5))
        for i in range(2):   # the two-point start of each axis: the velocity shares the last measurement's error
            cov[..., i, i] = r
            cov[..., i, i + 2] = cross
            cov[..., i + 2, i] = cross
            cov[..., i + 2, i + 2] = speed_variance
        cov[..., 4, 4] = params.initial_turn_variance
        extra_mean = np.stack([np.broadcast_to(z[:, None, PLANE:], (n, k, z.shape[1] - PLANE)),
                               np.broadcast_to(velocity[:, None, PLANE:], (n, k, z.shape[1] - PLANE))], axis=-2)
        extra_cov = np.stack([np.stack([r, cross], -1), np.stack([cross, speed_variance], -1)], -2)
    return mean, cov, extra_mean, extra_cov


def update(params: CTParams, state: CTState, measurement: np.ndarray, time, learn: np.ndarray, active=None,
           restart=None) -> CTState:
    """Learn ``measurement (N, p)`` at ``time (N,)`` for the targets where ``learn (N,)``.

    A target not yet started (or that ``restart (N,)``s) starts at the measurement; its next row a step later
    starts the filters (the module); the filters of a running target get the EKF update of the extrapolated
    state. Targets outside ``learn`` are unchanged (``active`` is not read).
    """
    state = restarted(state, restart)
    time = np.asarray(time, dtype=np.float64)
    z = np.where(learn[:, None], measurement, 0.0)
    delta = step_delta(params, state, time)
    mean, cov, extra_mean, extra_cov = _predict(params, state, delta)
    r = params.measurement_noise[None, :]                                          # (1, K)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        y0 = z[:, None, 0] - mean[..., 0]
        y1 = z[:, None, 1] - mean[..., 1]
        s00 = cov[..., 0, 0] + r
        s01 = cov[..., 0, 1]
        s10 = cov[..., 1, 0]
        s11 = cov[..., 1, 1] + r
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        gain0 = cov[..., :, 0] * i00[..., None] + cov[..., :, 1] * i10[..., None]     # (N, K, 5)
        gain1 = cov[..., :, 0] * i01[..., None] + cov[..., :, 1] * i11[..., None]
        new_mean = mean + (gain0 * y0[..., None] + gain1 * y1[..., None])
        bound = params.max_velocity * params.length_unit
        new_mean[..., 2] = np.clip(new_mean[..., 2], -bound, bound)
        new_mean[..., 3] = np.clip(new_mean[..., 3], -bound, bound)
        new_mean[..., 4] = np.clip(new_mean[..., 4], -math.pi, math.pi)
        a = np.broadcast_to(np.eye(5), cov.shape).copy()                            # A = I - K H
        a[..., :, 0] = a[..., :, 0] - gain0
        a[..., :, 1] = a[..., :, 1] - gain1
        outer = gain0[..., :, None] * gain0[..., None, :] + gain1[..., :, None] * gain1[..., None, :]
        new_cov = _matmul(_matmul(a, cov), np.swapaxes(a, -1, -2)) + r[..., None, None] * outer
        new_cov = symmetrise(new_cov)
        excess = np.maximum(0.5 * (new_cov[..., 0, 0] + new_cov[..., 1, 1]) / params.max_variance, 1.0)
        new_cov = new_cov / excess[..., None, None]
        nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
        # the further coordinates
        e00, e01, e10, e11 = (extra_cov[..., i, j] for i in range(2) for j in range(2))
        se = e00 + r
        k0, k1 = e00 / se, e10 / se
        innovation = z[:, None, PLANE:] - extra_mean[..., 0, :]                    # (N, K, p - 2)
        new_extra = np.stack([extra_mean[..., 0, :] + k0[..., None] * innovation,
                              extra_mean[..., 1, :] + k1[..., None] * innovation], axis=-2)
        f00 = e00 - k0 * e00
        f01 = e01 - k0 * e01
        f10 = e10 - k1 * e00
        f11 = e11 - k1 * e01
        off = 0.5 * (f01 + f10)
        new_extra_cov = np.stack([np.stack([f00, off], -1), np.stack([off, f11], -1)], -2)
    running = learn & state.initialised & (state.known >= 2)                       # (N,)
    absurd = ~(nis <= LOST_NIS)                                                     # (N, K)
    begin = learn & state.initialised & (delta > 0) & (state.known == 1)
    fresh = _started(params, state, z, delta)
    again = (begin[:, None] | (running[:, None] & absurd & (delta > 0)[:, None]))    # (N, K)
    go = running[:, None] & ~absurd

    def pick(started, updated, old):
        shape = again.shape + (1,) * (old.ndim - 2)
        return np.where(again.reshape(shape), started, np.where(go.reshape(shape), updated, old))

    first = learn & ~state.initialised
    known = np.where(first, 1.0, np.where(begin, 2.0, state.known))
    return CTState(mean=pick(fresh[0], new_mean, state.mean), cov=pick(fresh[1], new_cov, state.cov),
                   extra_mean=pick(fresh[2], new_extra, state.extra_mean),
                   extra_cov=pick(fresh[3], new_extra_cov, state.extra_cov),
                   position=np.where(learn[:, None], z, state.position), known=known,
                   last_time=np.where(learn, time, state.last_time), initialised=state.initialised | learn)
