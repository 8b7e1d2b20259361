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
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._common import linearised_regret, log, normalise_awake

__all__ = ["Params", "State", "init", "weights", "update", "learning_rates"]


class Params(NamedTuple):
    forgetting: float = 1.0   # rho in (0, 1]
    share: float = 0.0        # alpha in [0, 1)
    bound_forgetting: float = 1.0   # beta in (0, 1]
    delay: float = 1.0        # D >= 1: forecasts issued per feedback (the lead head's frames)


class State(NamedTuple):
    regret: np.ndarray     # (N, K) regularised cumulative regret R~
    variance: np.ndarray   # (N, K) V
    bound: np.ndarray      # (N, K) B


def init(params: Params, n_targets: int, n_experts: int) -> State:
    zeros = np.zeros((n_targets, n_experts))
    return State(zeros, zeros.copy(), zeros.copy())


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


def update(params: Params, state: State, experts, measurement, awake, learn) -> State:
    w = weights(params, state, awake)
    r = linearised_regret(w, experts, np.where(learn[:, None], measurement, 0.0), awake)
    rho = params.forgetting
    with np.errstate(over="ignore"):
        variance = rho * state.variance + r * r
    bound = np.maximum(params.bound_forgetting * state.bound, np.abs(r))
    informed = variance > 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.where(informed, np.minimum(1.0 / (2.0 * bound),
                                            np.sqrt(_log_experts(r.shape[-1], params.delay) / variance)), 0.0)
    with np.errstate(invalid="ignore", over="ignore"):
        regret = rho * state.regret + r - eta * r * r
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.isfinite(r * r).all(axis=-1)   # an overflowing regret (errors ~1e77 and up) teaches nothing
    go = (learn & finite)[:, None] & awake
    return State(np.where(go, regret, state.regret), np.where(go, variance, state.variance),
                 np.where(go, bound, state.bound))
