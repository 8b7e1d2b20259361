"""Adaptive autoregressive experts on the velocity, in real time (weighted least squares with forgetting).

Per target and coordinate, the velocity of the interval ending at a learned row is
:math:`v = (z - z_{prev}) / \\Delta / u` (``z_prev`` the previous learned row, so a gap is one
interval; :math:`\\Delta` in units of ``time_unit``, :math:`u` the ``length_unit``). Expert
``k`` predicts it from its previous ``order`` velocities (and a constant 1 with ``bias``),
:math:`\\hat v = w \\cdot x`, one weight vector per coordinate, by exponentially weighted
least squares with its own forgetting factor :math:`\\lambda_k` and a ridge toward the
persistence prior :math:`w_0 = (1, 0, \\dots)` (:math:`\\hat v` = the last velocity):

.. math::

    A \\leftarrow \\lambda A + x x^T,\\quad b \\leftarrow \\lambda b + x v,\\quad
    (A + r I)\\, w = b + r\\, w_0,\\quad r = \\rho_k s^2,

where :math:`s^2` is the weighted mean of :math:`v^2` (per coordinate, same forgetting): the
prior weighs as much as :math:`\\rho_k` typical samples whatever the data's scale, so a
regressor much smaller than its target (the first samples of a track, after a stop)
cannot produce a wild slope. The solve is a Cholesky factorisation, ``m`` = ``order`` (+1)
unknowns.

**Forecasts.** The model predicts the velocity of the next row, so a forecast :math:`\\Delta`
time units ahead takes :math:`n = \\max(1, \\lfloor \\Delta + 1/2 \\rfloor)` rows of
:math:`s = \\Delta / n` each (at most :data:`ITERATED_STEPS`): the position moves by
:math:`\\hat v_j s u` for :math:`j = 1 \\dots n`, each predicted velocity entering the regressor
of the next, :math:`\\hat v_{j+1} = w \\cdot [\\hat v_j, \\hat v_{j-1}, \\dots]`. The next row
(:math:`\\Delta < 1.5`) is :math:`z_{prev} + \\hat v_1 \\Delta u`; before a second row, the last
position. So an expert that learned that the motion turns or slows keeps turning or slowing
over a lead of several rows instead of carrying its first velocity in a straight line. An
iterated velocity is clipped (per coordinate) to the largest magnitude of :math:`\\hat v_1`
and the velocities in the regressor: a fit whose recursion is unstable cannot explode over
a long lead. The variance stays the running velocity error times :math:`(\\Delta u)^2`.

**Jumps.** A velocity whose squared error (mean over the coordinates) exceeds
``jump_threshold**2`` times the expert's running mean squared error (about ``window``
samples, starting from one pseudo-sample ``initial_error``) is a *jump*: the position
moves there but the sample is neither fitted nor entered in the history, so a track that
relocates (a broadcast identity switch) keeps its velocity instead of extrapolating the
jump. A second wild sample in a row is a real change of motion and is fitted.

Numbers stay finite for any finite input: velocities and :math:`\\hat v` are clipped to
``max_velocity``, steps to ``max_step``, and the ridge has a floor relative to :math:`A`.
The loops over the regressor are written in the compiled kernel's order
(:mod:`kalmix.core.compiled.ar`), so both give the same numbers.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._libm import ordered_sum
from ..constraints import Boolean, Integer, Levels, Real
from ..kalman import cholesky_solve_rows
from .kinematic import restarted, step_delta   # the same clipped step in time units; the same restart

__all__ = ["ARParams", "ARState", "init_state", "forecast", "update", "expert_name", "one_expert", "ITERATED_STEPS"]

#: Most rows of an iterated forecast (a longer time ahead is cut into this many equal steps).
ITERATED_STEPS = 64


class ARParams(NamedTuple):
    """Constant parameters of one AR family (K experts of one order)."""

    order: int                     # previous velocities in the regressor
    forgetting: np.ndarray         # (K,) lambda in (0, 1]
    length_unit: float             # u: velocities are in length units per time unit
    time_unit: float               # the time step unit (the typical sampling interval)
    ridge: np.ndarray              # (K,) rho: the prior weighs as much as rho typical samples
    persistence: float = 1.0       # prior weight of the last velocity
    bias: bool = False             # a constant regressor (a drift)
    initial_error: float = 1.0     # prior of the running error (one pseudo-sample), (u / time unit)^2
    jump_threshold: float = 10.0   # a velocity error this many RMS errors away is a jump
    window: float = 50.0           # samples of the running error
    max_step: float = 1e6          # longest step, in time units
    max_velocity: float = 1e8      # velocity clip, length units per time unit

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`): ``forgetting`` and ``ridge`` per
    #: expert; the fields with a default are a bank's ``ar_options``.
    CONSTRAINTS = {"order": Integer(ge=1), "forgetting": Levels(Real(gt=0, le=1.0)), "ridge": Levels(Real(gt=0)),
                   "persistence": Real(ge=0), "bias": Boolean(), "initial_error": Real(gt=0),
                   "jump_threshold": Real(gt=0, inf_ok=True, hint="inf: no jump test"), "window": Real(ge=1),
                   "max_step": Real(gt=0), "max_velocity": Real(gt=0)}

    @property
    def n_experts(self) -> int:
        return int(self.forgetting.shape[0])

    @property
    def size(self) -> int:
        return self.order + (1 if self.bias else 0)


class ARState(NamedTuple):
    weights: np.ndarray      # (N, K, p, m) the current fit
    info: np.ndarray         # (N, K, p, m, m) A, the weighted regressors' Gram matrix
    target: np.ndarray       # (N, K, p, m) b, the weighted regressors times the velocity
    history: np.ndarray      # (N, K, p, order) previous velocities, most recent first
    scale: np.ndarray        # (N, K) s2, weighted mean squared velocity (per coordinate)
    weight: np.ndarray       # (N, K) c, the weights' sum in s2
    error: np.ndarray        # (N, K) running mean squared velocity error (per coordinate)
    count: np.ndarray        # (N, K) samples in the running error (capped at window)
    jumps: np.ndarray        # (N, K) jumps in a row
    position: np.ndarray     # (N, p) last learned measurement
    last_time: np.ndarray    # (N,) its time (NaN before the first)
    initialised: np.ndarray  # (N,) bool


def expert_name(params: ARParams, i: int, kind: str = "ar") -> str:
    """Expert ``i``'s name in reports (``ar2(forgetting=0.99, ridge=0.01)``)."""
    return f"{kind}{params.order}(forgetting={params.forgetting[i]:.4g}, ridge={params.ridge[i]:.3g})"


def one_expert(params: ARParams, i: int) -> ARParams:
    """The parameters of expert ``i`` alone."""
    return params._replace(forgetting=params.forgetting[i:i + 1], ridge=params.ridge[i:i + 1])


def prior_weights(params: ARParams) -> np.ndarray:
    w0 = np.zeros(params.size)
    w0[0] = params.persistence
    return w0


def init_state(params: ARParams, n_targets: int, measurement_dim: int) -> ARState:
    k, o, p, m = params.n_experts, params.order, measurement_dim, params.size
    w0 = prior_weights(params)
    return ARState(
        weights=np.broadcast_to(w0, (n_targets, k, p, m)).copy(),
        info=np.zeros((n_targets, k, p, m, m)),
        target=np.zeros((n_targets, k, p, m)),
        scale=np.zeros((n_targets, k)),
        weight=np.zeros((n_targets, k)),
        history=np.zeros((n_targets, k, p, o)),
        error=np.full((n_targets, k), params.initial_error),
        count=np.ones((n_targets, k)),
        jumps=np.zeros((n_targets, k)),
        position=np.zeros((n_targets, p)),
        last_time=np.full(n_targets, np.nan),
        initialised=np.zeros(n_targets, dtype=bool),
    )


def _regressor(params: ARParams, state: ARState) -> np.ndarray:
    """``x = [history, 1]``, ``(N, K, p, m)``."""
    if not params.bias:
        return state.history
    return np.concatenate([state.history, np.ones(state.history.shape[:-1] + (1,))], axis=-1)


def ordered_dot(a, b):
    """Sum of ``a * b`` over the last axis, term by term in order from the first (the kernels' order)."""
    return ordered_sum(a * b, from_zero=False)


def _velocity_forecast(params: ARParams, state: ARState) -> np.ndarray:
    """:math:`\\hat v`, ``(N, K, p)``, clipped to ``max_velocity``."""
    v = ordered_dot(state.weights, _regressor(params, state))
    return np.clip(np.where(np.isnan(v), 0.0, v), -params.max_velocity, params.max_velocity)


def forecast(params: ARParams, state: ARState, time, frames: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Each expert's predicted measurement at ``time (N,)`` and its variance per coordinate (``frames`` is not
    read: a time-based family forecasts at ``time``).

    Returns
    -------
    means : ndarray (N, K, p)
    variances : ndarray (N, K) — the running mean squared velocity error times :math:`(\\Delta u)^2`.
    """
    delta = step_delta(params, state, time)
    u = params.length_unit
    v = _velocity_forecast(params, state)                                            # (N, K, p)
    rows = np.clip(np.floor(delta + 0.5), 1.0, ITERATED_STEPS)                       # (N,)
    step = (delta / rows * u)[:, None, None]
    means = state.position[:, None, :] + v * step
    if (rows > 1).any():
        # the regressor as a list of columns, most recent velocity first (then 1 with a bias); the sum in
        # ordered_dot's order, then NaN -> 0 and one clip: to max_velocity then to the largest velocity seen is
        # the clip to the smaller of the two (the largest velocity seen is inside max_velocity anyway)
        # (fmax: a NaN in a hand-made history is skipped, as the kernel's max does; the engines store none)
        bound = np.minimum(np.fmax(np.abs(v), np.fmax.reduce(np.abs(state.history), axis=-1)), params.max_velocity)
        columns = [state.history[..., i] for i in range(params.order)]
        if params.bias:
            columns.append(np.ones(v.shape))
        w = [state.weights[..., i] for i in range(params.size)]
        for j in range(1, int(rows.max())):
            columns = [v] + columns[:params.order - 1] + columns[params.order:]
            acc = w[0] * columns[0]
            for i in range(1, params.size):
                acc = acc + w[i] * columns[i]
            v = np.minimum(np.maximum(np.where(np.isnan(acc), 0.0, acc), -bound), bound)
            means = np.where((rows > j)[:, None, None], means + v * step, means)
    scale = (delta * u)[:, None]                                                     # (N, 1)
    return means, state.error * scale * scale


def _fit(params: ARParams, state: ARState, x, v):
    """Exponentially weighted least squares with a ridge toward the prior weights.

    ``A <- lam A + x x^T``, ``b <- lam b + x v``, ``s2`` the weighted mean of ``v^2``; the
    weights solve ``(A + r I) w = b + r w0`` with ``r = rho s2`` (plus a tiny relative floor).
    """
    m = x.shape[-1]
    lam = params.forgetting[None, :]                                                 # (1, K)
    rho = params.ridge[None, :, None]
    info = lam[..., None, None, None] * state.info + x[..., :, None] * x[..., None, :]
    target = lam[..., None, None] * state.target + x * v[..., None]
    weight = lam * state.weight + 1.0
    scale = state.scale + (ordered_dot(v, v) / v.shape[-1] - state.scale) / weight
    largest = np.max(np.diagonal(info, axis1=-2, axis2=-1), axis=-1)                # (N, K, p)
    ridge = rho * scale[..., None] + 1e-9 * largest + 1e-12
    # (A + r I) w = b + r w0 by Cholesky, a pivot below 0 (rounding) taken as 0
    rhs = (target + ridge[..., None] * prior_weights(params))[..., None, :]
    weights = cholesky_solve_rows(info + ridge[..., None, None] * np.eye(m), rhs, clamp=True)[..., 0, :]
    # a zero regressor (the first velocity of a track) says nothing about w: keep it exactly (the solve
    # would return it up to rounding, and experts equal to rounding make the rules' regrets chaotic)
    weights = np.where((x == 0.0).all(axis=-1)[..., None], state.weights, weights)
    return info, target, scale, weight, weights


def update(params: ARParams, state: ARState, measurement: np.ndarray, time, learn: np.ndarray, active=None,
           restart=None) -> ARState:
    """Learn ``measurement (N, p)`` at ``time (N,)`` for the targets where ``learn (N,)``.

    A target not yet started (or that ``restart (N,)``s) starts at the measurement (prior weights,
    zero history). Targets outside ``learn`` are unchanged (``active`` is not read).
    """
    state = restarted(state, restart)
    time = np.asarray(time, dtype=np.float64)
    z = np.where(learn[:, None], measurement, 0.0)
    delta = step_delta(params, state, time)
    moved = delta > 0                                                               # (N,)
    with np.errstate(over="ignore", invalid="ignore"):
        v = (z - state.position) / np.where(moved, delta, 1.0)[:, None] / params.length_unit
    v = np.clip(np.where(np.isnan(v), 0.0, v), -params.max_velocity, params.max_velocity)   # (N, p)
    x = _regressor(params, state)
    v_k = np.broadcast_to(v[:, None, :], state.history.shape[:-1])                 # (N, K, p)
    err = v_k - _velocity_forecast(params, state)
    squared = ordered_dot(err, err) / err.shape[-1]                                 # (N, K)
    with np.errstate(invalid="ignore"):
        wild = squared > params.jump_threshold**2 * state.error   # inf x 0 (no test, no error yet): not wild
    jump = wild & (state.jumps < 1)
    info, target, scale, weight, weights = _fit(params, state, x, v_k)
    history = np.concatenate([v_k[..., None], state.history[..., :-1]], axis=-1)
    count = np.minimum(state.count + 1.0, params.window)
    error = state.error + (squared - state.error) / count

    learned = (learn & state.initialised & moved)[:, None]                          # (N, 1)
    go = learned & ~jump                                                            # (N, K)
    start = learn & ~state.initialised
    fresh = init_state(params, len(learn), z.shape[-1])

    def pick(fresh_value, updated, old, mask_k):
        shape = lambda a: a.shape[:2] + (1,) * (a.ndim - 2)  # noqa: E731
        out = np.where(np.broadcast_to(mask_k, old.shape[:2]).reshape(shape(old)), updated, old)
        return np.where(start.reshape((-1,) + (1,) * (old.ndim - 1)), fresh_value, out)

    return ARState(
        weights=pick(fresh.weights, weights, state.weights, go),
        info=pick(fresh.info, info, state.info, go),
        target=pick(fresh.target, target, state.target, go),
        scale=pick(fresh.scale, scale, state.scale, go),
        weight=pick(fresh.weight, weight, state.weight, go),
        history=pick(fresh.history, history, state.history, go),
        error=pick(fresh.error, error, state.error, go),
        count=pick(fresh.count, count, state.count, go),
        jumps=pick(fresh.jumps, np.where(jump, state.jumps + 1.0, 0.0), state.jumps, learned),
        position=np.where(learn[:, None], z, state.position),
        last_time=np.where(learn, time, state.last_time),
        initialised=state.initialised | learn,
    )
