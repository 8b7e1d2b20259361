"""BOA, Bernstein online aggregation (Wintenberger 2017), with the gradient trick.

Parameter-free in the scale of the data: with the linearised regret
:math:`r_{k,t} = 2(\\hat y_t - y_t)\\cdot(\\hat y_t - x_{k,t})`,

.. math::

    V_k \\leftarrow \\rho V_k + r_k^2,\\quad B_k \\leftarrow \\max(\\beta B_k, |r_k|),\\quad
    \\eta_k = \\min\\Big(\\frac{1}{2 B_k}, \\sqrt{\\frac{\\ln K / D}{V_k}}\\Big),

    \\tilde R_k \\leftarrow \\rho \\tilde R_k + r_k - \\eta_k r_k^2,\\qquad
    w_k \\propto \\pi_k\\, \\eta_k \\exp(\\eta_k \\tilde R_k),

over the awake experts, then a fixed-share floor :math:`w \\leftarrow (1-\\alpha) w + \\alpha / K_{awake}`.
:math:`\\rho = \\beta = 1` (no forgetting) and :math:`\\alpha = 0` give the original rule, which
competes with the best convex combination of the experts. :math:`\\beta < 1`
(``bound_forgetting``) lets the range bound :math:`B_k` decay: one huge regret (a kick, a
relocation) otherwise caps :math:`\\eta_k \\le 1/(2B_k)` for the rest of the track and the
weights stay near uniform long after the event. An expert with no regret yet
(:math:`V_k = 0`) takes the largest learning rate of the others (1 when none has one).

:math:`D` (``delay``, 1 by default) is the number of forecasts issued per feedback received: a
forecast H rows ahead is scored H rows after it is made, so the H - 1 forecasts issued in
between use weights that have not yet seen its error. Exponential weights with delayed feedback
keep their regret bound when the learning rate is divided by :math:`\\sqrt{D}`, D = H
(Joulani, György & Szepesvári 2013; Quanrud & Khashabi 2015); the lead head's rule runs with
``delay = frames`` of its lead. Only the second-order rate is scaled: the range bound
:math:`\\eta_k \\le 1/(2 B_k)` keeps :math:`\\eta_k |r_k| \\le 1/2`, which the delay does not change.

``clip`` (:math:`c`, off when infinite) learns the weights on a Huber loss instead of the squared
one: in :math:`\\tilde R_k` and :math:`V_k` the mixture's error :math:`g = \\hat y - y` is shrunk to
the norm :math:`c\\, s` when it is longer, :math:`s^2` the mean squared error norm of the target's
rows so far, over the last :data:`CLIP_MEMORY` rows or so once there are more (an exponential mean
then: :math:`s^2 \\leftarrow s^2 + (\\lVert g \\rVert^2 - s^2) / \\min(n, M)`); the first
:data:`CLIP_WARMUP` rows, and rows while :math:`s = 0`, are not shrunk. The scale starts again where
the experts do (:func:`restart`, a time gap or the screen's restart).
The range bound :math:`B_k` still takes the whole regret. A kick, a relocation, a glitch the
screen let through: an error no expert foresaw says little about which expert to trust, yet on
the squared loss its regrets outweigh hundreds of ordinary rows. With ``clip`` such a row moves the
weights no more than a bad
ordinary row, and only slows the learning for a while (its :math:`B_k`, forgotten at
:math:`\\beta`). :math:`s` takes the whole errors: a lasting change of the error level (a target
that moved 0.5 mm a row and now moves 3 m) raises it within a few rows, so the rule still follows
a real change of motion (a scale of the shrunk errors grows by a few percent a row there). Its
memory bounds how long that takes on a long quiet stream: a plain mean over all rows would take
the more rows the longer the stream was quiet. These choices come from the ablation and ``python -m
benchmarks.clip_variants`` (benchmarks/results/ablation_clip.json, clip_variants.json); ``clip`` 3 is
the default's. A row whose squared error norm overflows
teaches nothing, as a row whose regret overflows.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..constraints import Real
from ._common import log, mixture_and_regret, normalise_awake, ordered_sum

__all__ = ["Params", "State", "init", "weights", "update", "learning_rates", "clip_factor", "restart", "CLIP_WARMUP",
           "CLIP_MEMORY"]


#: Rows of a target learned before its errors are clipped (their running scale is too young before).
CLIP_WARMUP = 10
#: The clip's scale is the mean over about this many of the last rows (its count stops growing here).
CLIP_MEMORY = 1000.0


class Params(NamedTuple):
    forgetting: float = 1.0   # rho in (0, 1]
    share: float = 0.0        # alpha in [0, 1)
    bound_forgetting: float = 1.0   # beta in (0, 1]
    delay: float = 1.0        # D >= 1: forecasts issued per feedback (the lead head's frames)
    clip: float = math.inf    # c > 0: errors longer than c running RMS are shrunk to it (inf: off)

    #: What each field may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"forgetting": Real(gt=0, le=1.0), "share": Real(ge=0, lt=1), "bound_forgetting": Real(gt=0, le=1.0),
                   "delay": Real(ge=1, hint="rows between a forecast and its score"),
                   "clip": Real(gt=0, inf_ok=True, hint="inf: off")}


class State(NamedTuple):
    regret: np.ndarray     # (N, K) regularised cumulative regret R~
    variance: np.ndarray   # (N, K) V
    bound: np.ndarray      # (N, K) B
    error_scale: np.ndarray   # (N,) s^2, the mean squared error norm of the last rows (with clip)
    error_count: np.ndarray   # (N,) rows that made it, at most CLIP_MEMORY


def init(params: Params, n_targets: int, n_experts: int) -> State:
    zeros = np.zeros((n_targets, n_experts))
    return State(zeros, zeros.copy(), zeros.copy(), np.zeros(n_targets), np.zeros(n_targets))


def clip_factor(params: Params, state: State, error):
    """What ``clip`` multiplies the error :math:`g = \\hat y - y` ``(N, p)`` by ``(N,)`` (see the module), and its
    squared norm ``(N,)`` (1 and 0 with ``clip`` off)."""
    n = error.shape[0]
    if not math.isfinite(params.clip):
        return np.ones(n), np.zeros(n)
    with np.errstate(over="ignore", invalid="ignore"):
        squared = ordered_sum(error * error)
        norm = np.sqrt(squared)
        limit = params.clip * np.sqrt(state.error_scale)
        cut = (state.error_count >= CLIP_WARMUP) & (state.error_scale > 0) & (norm > limit)
        factor = np.where(cut, limit / np.where(cut, norm, 1.0), 1.0)
    return factor, squared


def restart(params: Params, state: State, rows) -> State:
    """The error scale of the targets in ``rows (N,)`` starts again (a restart: their experts start again from
    the row, a new segment's errors are not the last one's); the weights' state goes on."""
    return state._replace(error_scale=np.where(rows, 0.0, state.error_scale),
                          error_count=np.where(rows, 0.0, state.error_count))


def _log_experts(n_experts: int, delay: float) -> float:
    """:math:`\\ln K / D`, the numerator of the second-order rate (exactly :math:`\\ln K` for D = 1)."""
    return math.log(max(n_experts, 2)) / delay


def learning_rates(state: State, n_experts: int, delay: float = 1.0) -> np.ndarray:
    """:math:`\\eta_k`, with the uninformed experts at the largest informed rate (1 if none)."""
    informed = state.variance > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.minimum(1.0 / (2.0 * state.bound), np.sqrt(_log_experts(n_experts, delay) / state.variance))
    eta = np.where(informed, eta, 0.0)
    top = eta.max(axis=-1, keepdims=True)
    return np.where(informed, eta, np.where(top > 0, top, 1.0))


def weights(params: Params, state: State, awake: np.ndarray) -> np.ndarray:
    eta = learning_rates(state, state.regret.shape[-1], params.delay)
    w = normalise_awake(log(eta) + eta * state.regret, awake)
    count = awake.sum(axis=-1, keepdims=True)
    floor = np.where(awake, params.share / np.maximum(count, 1), 0.0)
    return (1.0 - params.share) * w + floor


def update(params: Params, state: State, experts, measurement, awake, learn, exact: bool = False) -> State:
    """Learn a row (see the module). ``exact``: the squared loss's own regrets, :math:`\\lVert \\hat y - y
    \\rVert^2 - \\lVert x_k - y \\rVert^2`, instead of the linearised ones (:mod:`.boa_blend`'s second rule)."""
    w = weights(params, state, awake)
    y = np.where(learn[:, None], measurement, 0.0)
    mix, whole = mixture_and_regret(w, experts, y, awake)   # the whole regret: the range bound's
    if exact:   # the linearised regret less the squared distance of the expert from the mixture
        x = np.where(awake[..., None], experts, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            whole = np.where(awake, whole - ordered_sum((x - mix[:, None, :]) * (x - mix[:, None, :])), 0.0)
    factor, squared = clip_factor(params, state, mix - y)
    with np.errstate(over="ignore", invalid="ignore"):
        r = whole * factor[:, None]   # the regret of the clipped error (linear in it)
    rho = params.forgetting
    with np.errstate(over="ignore"):
        variance = rho * state.variance + r * r
    bound = np.maximum(params.bound_forgetting * state.bound, np.abs(whole))
    informed = variance > 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.where(informed, np.minimum(1.0 / (2.0 * bound),
                                            np.sqrt(_log_experts(r.shape[-1], params.delay) / variance)), 0.0)
    with np.errstate(invalid="ignore", over="ignore"):
        regret = rho * state.regret + r - eta * r * r
    with np.errstate(over="ignore", invalid="ignore"):   # an overflowing regret (errors ~1e77 and up) or squared
        finite = np.isfinite(whole * whole).all(axis=-1) & np.isfinite(squared)   # error norm teaches nothing
    go = (learn & finite)[:, None] & awake
    count = np.minimum(state.error_count + 1.0, CLIP_MEMORY)
    scale = state.error_scale + (squared - state.error_scale) / count
    clipping = math.isfinite(params.clip) & learn & finite & awake.any(axis=-1)
    return State(np.where(go, regret, state.regret), np.where(go, variance, state.variance),
                 np.where(go, bound, state.bound), np.where(clipping, scale, state.error_scale),
                 np.where(clipping, count, state.error_count))
