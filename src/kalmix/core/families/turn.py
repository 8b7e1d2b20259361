"""Coordinated-turn experts: the last turn rate and speed carried forward, in real time and any dimension.

Per target, the two last intervals between learned rows give the velocities
:math:`v_1, v_2` (data units per time unit, over steps :math:`\\Delta_1, \\Delta_2` in
units of ``time_unit``). Under a constant turn rate and speed, each is the chord
direction at the middle of its interval, so the heading turns by the angle
:math:`\\theta \\in [0, \\pi]` between them in :math:`(\\Delta_1 + \\Delta_2)/2`: the turn rate is
:math:`\\omega = 2\\theta / (\\Delta_1 + \\Delta_2)`, in the plane of :math:`v_1, v_2`. With
:math:`b = v_2/|v_2|` and :math:`c` the unit vector of that plane orthogonal to :math:`b`
on the side the motion turns to (:math:`c \\propto b \\cos\\theta - v_1/|v_1|`), expert ``k``
carries the fraction :math:`g_k` (``gain``) of the turn rate forward, :math:`\\omega_k = g_k \\omega`,
and integrates the arc over the step :math:`\\Delta` to the forecast's time:

.. math::

    \\hat z = z + s\\, \\Delta\\, \\operatorname{sinc}(\\omega_k \\Delta / 2)
              \\big(b \\cos\\alpha + c \\sin\\alpha\\big),\\qquad
    \\alpha = \\omega_k (\\Delta_2 + \\Delta) / 2,\\qquad
    s = |v_2| / \\operatorname{sinc}(\\omega \\Delta_2 / 2),

the chord of a circular arc at the speed :math:`s` on the arc (a chord is shorter than its
arc; :math:`\\operatorname{sinc} x = \\sin x / x`). Gain 1 forecasts a circle at constant
speed exactly, whatever the sampling; gain 0 goes straight on along the last chord (a
constant-velocity extrapolation where there is no turn); collinear velocities (1-D data, a
reversal) give no turn. With one interval known the
forecast is :math:`z + v_2 \\Delta`, with none it is :math:`z`. The state is per target
(every expert reads the same history); only the running error is per expert.

Why a family of it: on the cycling recording the turn explains what the velocity
models miss across the track (the cross-track error is larger than the along-track one),
and because the rules' weights are convex, gains of 0.5 to 1.5 let the mixture reach
the right fraction of the turn (the ablation: benchmarks/results/ablation_turn.json).

The forecast's variance is the running mean squared velocity error of the expert
(per coordinate, about ``window`` samples, one pseudo-sample of ``length_unit^2`` to
start) times :math:`\\Delta^2`. Numbers stay finite for finite input: velocities are
clipped to ``max_velocity`` length units per time unit and steps to ``max_step``.
The compiled kernel (:mod:`kalmix.core.compiled.turn`) follows these formulas in the
same order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._libm import atan2, cos, sin
from ..constraints import Levels, Real
from .ar import ordered_dot   # a sum over the last axis in the kernel's order
from .kinematic import restarted, step_delta   # the same clipped step in time units; the same restart

__all__ = ["TurnParams", "TurnState", "init_state", "forecast", "update", "expert_name", "one_expert", "turn_geometry"]


class TurnParams(NamedTuple):
    """Constant parameters of one coordinated-turn family (K experts)."""

    gain: np.ndarray               # (K,) g: the fraction of the last turn rate carried forward
    length_unit: float             # u: the velocity clip and the error's prior are in these units
    time_unit: float               # the time step unit (the typical sampling interval)
    window: float = 50.0           # samples of the running error
    max_step: float = 1e6          # longest step, in time units
    max_velocity: float = 1e8      # velocity clip, length units per time unit

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"gain": Levels(Real(ge=0))}

    @property
    def n_experts(self) -> int:
        return int(self.gain.shape[0])


class TurnState(NamedTuple):
    velocity: np.ndarray     # (N, p) v2, of the last interval (data units per time unit)
    previous: np.ndarray     # (N, p) v1, of the interval before
    span: np.ndarray         # (N,) its step Delta_2 (time units)
    previous_span: np.ndarray  # (N,) Delta_1
    known: np.ndarray        # (N,) intervals known since the start: 0, 1 or 2
    error: np.ndarray        # (N, K) running mean squared velocity error (per coordinate)
    count: np.ndarray        # (N,) samples in it (capped at window; the same for every expert)
    position: np.ndarray     # (N, p) last learned measurement
    last_time: np.ndarray    # (N,) its time (NaN before the first)
    initialised: np.ndarray  # (N,) bool


def init_state(params: TurnParams, n_targets: int, measurement_dim: int) -> TurnState:
    k, p = params.n_experts, measurement_dim
    return TurnState(
        velocity=np.zeros((n_targets, p)),
        previous=np.zeros((n_targets, p)),
        span=np.zeros(n_targets),
        previous_span=np.zeros(n_targets),
        known=np.zeros(n_targets),
        error=np.full((n_targets, k), params.length_unit**2),
        count=np.ones(n_targets),
        position=np.zeros((n_targets, p)),
        last_time=np.full(n_targets, np.nan),
        initialised=np.zeros(n_targets, dtype=bool),
    )


def expert_name(params: TurnParams, i: int, kind: str = "turn") -> str:
    """Expert ``i``'s name in reports (``turn(gain=0.5)``)."""
    return f"{kind}(gain={params.gain[i]:.3g})"


def one_expert(params: TurnParams, i: int) -> TurnParams:
    """The parameters of expert ``i`` alone."""
    return params._replace(gain=params.gain[i:i + 1])


def turn_geometry(state: TurnState):
    """``(speed (N,), b (N, p), c (N, p), omega (N,))``: the speed on the arc, the unit vectors of
    the turn's plane, and the turn rate (0 where fewer than two intervals are known or there is no plane).

    The speed is the last chord's length per time over :math:`\\operatorname{sinc}(\\omega\\Delta_2/2)`
    (at most :math:`\\pi/2` times it), so that a circle at constant speed is forecast exactly
    whatever the sampling."""
    s1 = np.sqrt(ordered_dot(state.previous, state.previous))
    s2 = np.sqrt(ordered_dot(state.velocity, state.velocity))
    both = (state.known >= 2) & (s1 > 0) & (s2 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = state.previous / np.where(both, s1, 1.0)[:, None]
        b = state.velocity / np.where(s2 > 0, s2, 1.0)[:, None]
    cosine = np.clip(ordered_dot(a, b), -1.0, 1.0)
    perp = b * cosine[:, None] - a
    sine = np.sqrt(ordered_dot(perp, perp))
    turning = both & (sine > 0)
    c = np.where(turning[:, None], perp / np.where(turning, sine, 1.0)[:, None], 0.0)
    mid = 0.5 * (state.previous_span + state.span)
    omega = np.where(turning, atan2(sine, cosine) / np.where(turning, mid, 1.0), 0.0)
    # the chord of the last interval is shorter than the arc: speed = |v2| / sinc(omega Delta_2 / 2)
    return s2 / _sinc(np.minimum(0.5 * omega * state.span, 0.5 * np.pi)), b, c, omega


def _sinc(x):
    """``sin(x) / x`` (1 at 0)."""
    small = np.abs(x) < 1e-8
    return np.where(small, 1.0, sin(x) / np.where(small, 1.0, x))


def _means(params: TurnParams, state: TurnState, delta) -> np.ndarray:
    """``(N, K, p)`` forecasts ``delta (N,)`` time units after the last learned row."""
    speed, b, c, omega = turn_geometry(state)
    w = params.gain[None, :] * omega[:, None]                                        # (N, K)
    alpha = 0.5 * w * (state.span[:, None] + delta[:, None])
    length = speed[:, None] * delta[:, None] * _sinc(0.5 * w * delta[:, None])       # (N, K)
    direction = b[:, None, :] * cos(alpha)[..., None] + c[:, None, :] * sin(alpha)[..., None]
    moving = (state.known >= 1)[:, None, None]
    return state.position[:, None, :] + np.where(moving, length[..., None] * direction, 0.0)


def forecast(params: TurnParams, state: TurnState, time, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Each expert's predicted measurement at ``time (N,)`` and its variance per coordinate (``frames`` is not
    read: a time-based family forecasts at ``time``).

    Returns
    -------
    means : ndarray (N, K, p)
    variances : ndarray (N, K) — the running mean squared velocity error times :math:`\\Delta^2`.
    """
    delta = step_delta(params, state, time)
    return _means(params, state, delta), state.error * (delta * delta)[:, None]


def update(params: TurnParams, state: TurnState, measurement: np.ndarray, time, learn: np.ndarray, active=None,
           restart=None) -> TurnState:
    """Learn ``measurement (N, p)`` at ``time (N,)`` for the targets where ``learn (N,)``.

    A target not yet started (or that ``restart (N,)``s) starts at the measurement. A row at the
    time of the last one (no step) moves the position and keeps the velocities. Targets outside
    ``learn`` are unchanged (``active`` is not read).
    """
    state = restarted(state, restart)
    time = np.asarray(time, dtype=np.float64)
    z = np.where(learn[:, None], measurement, 0.0)
    delta = step_delta(params, state, time)
    moved = delta > 0
    bound = params.max_velocity * params.length_unit
    with np.errstate(over="ignore", invalid="ignore"):
        v = (z - state.position) / np.where(moved, delta, 1.0)[:, None]
    v = np.clip(np.where(np.isnan(v), 0.0, v), -bound, bound)                        # (N, p)
    # each expert's velocity error: (z - forecast) / delta
    with np.errstate(over="ignore", invalid="ignore"):
        err = (z[:, None, :] - _means(params, state, delta)) / np.where(moved, delta, 1.0)[:, None, None]
    err = np.clip(np.where(np.isnan(err), 0.0, err), -bound, bound)
    squared = ordered_dot(err, err) / err.shape[-1]                                 # (N, K)
    count = np.minimum(state.count + 1.0, params.window)
    error = state.error + (squared - state.error) / count[:, None]

    learned = learn & state.initialised & moved                                     # (N,)
    start = learn & ~state.initialised
    fresh = init_state(params, len(learn), z.shape[-1])

    def pick(fresh_value, updated, old):
        mask = learned.reshape((-1,) + (1,) * (old.ndim - 1))
        out = np.where(mask, updated, old)
        return np.where(start.reshape((-1,) + (1,) * (old.ndim - 1)), fresh_value, out)

    return TurnState(
        velocity=pick(fresh.velocity, v, state.velocity),
        previous=pick(fresh.previous, state.velocity, state.previous),
        span=pick(fresh.span, delta, state.span),
        previous_span=pick(fresh.previous_span, state.span, state.previous_span),
        known=pick(fresh.known, np.minimum(state.known + 1.0, 2.0), state.known),
        error=pick(fresh.error, error, state.error),
        count=pick(fresh.count, count, state.count),
        position=np.where(learn[:, None], z, state.position),
        last_time=np.where(learn, time, state.last_time),
        initialised=state.initialised | learn,
    )
