"""BOA-blend: BOA on the linearised regrets and BOA on the exact ones, blended by a third BOA.

BOA with the gradient trick (:mod:`.boa`) competes with the best convex combination of the
experts: its regret of expert :math:`k` is the exact one, :math:`\\lVert \\hat y - y \\rVert^2 -
\\lVert x_k - y \\rVert^2`, plus :math:`\\lVert x_k - \\hat y \\rVert^2`, so an expert far from the
mixture keeps weight. That is right where a combination beats every expert (cycling), and wrong
where one expert is right and the others far off at some rows (a constant acceleration at long or
irregular steps, where the other experts' extrapolations miss by many times as much).

This rule runs both: the same BOA (same parameters, its own state and clip scale) on the linearised
regrets, weights :math:`w^{lin}`, and on the exact ones, :math:`w^{ex}`; a third BOA over their two
mixtures :math:`\\hat y^{lin}, \\hat y^{ex}` (linearised regrets against their blend
:math:`\\beta \\hat y^{lin} + (1 - \\beta) \\hat y^{ex}`, no clip, no share) gives :math:`\\beta`, and the
weights are :math:`\\beta w^{lin} + (1 - \\beta) w^{ex}`. Its regret to the better of the two rules
grows as :math:`\\sqrt{T}` at most.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import boa
from ._common import exp, log, ordered_sum

__all__ = ["Params", "State", "init", "weights", "update", "restart"]

#: BOA-blend takes BOA's parameters.
Params = boa.Params


class State(NamedTuple):
    regret: np.ndarray              # (N, K) the linearised rule's
    variance: np.ndarray            # (N, K)
    bound: np.ndarray               # (N, K)
    error_scale: np.ndarray         # (N,)
    error_count: np.ndarray         # (N,)
    exact_regret: np.ndarray        # (N, K) the exact rule's
    exact_variance: np.ndarray      # (N, K)
    exact_bound: np.ndarray         # (N, K)
    exact_error_scale: np.ndarray   # (N,)
    exact_error_count: np.ndarray   # (N,)
    blend_regret: np.ndarray        # (N, 2) the blend's
    blend_variance: np.ndarray      # (N, 2)
    blend_bound: np.ndarray         # (N, 2)


def init(params: Params, n_targets: int, n_experts: int) -> State:
    lin, ex = boa.init(params, n_targets, n_experts), boa.init(params, n_targets, n_experts)
    two = np.zeros((n_targets, 2))
    return State(*lin, *ex, two, two.copy(), two.copy())


def _rules(state: State) -> tuple[boa.State, boa.State]:
    return boa.State(*state[:5]), boa.State(*state[5:10])


def blend_share(params: Params, state: State) -> np.ndarray:
    """:math:`\\beta` ``(N,)``, the blend's weight on the linearised rule."""
    log_2 = math.log(2.0) / params.delay
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = np.where(state.blend_variance > 0,
                       np.minimum(1.0 / (2.0 * state.blend_bound), np.sqrt(log_2 / state.blend_variance)), -1.0)
    top = np.maximum(eta.max(axis=-1, keepdims=True), 0.0)
    eta = np.where(eta >= 0, eta, np.where(top > 0, top, 1.0))
    logits = log(eta) + eta * state.blend_regret
    high = logits.max(axis=-1, keepdims=True)
    high = np.where(np.isfinite(high), high, 0.0)
    e = exp(logits - high)
    total = ordered_sum(e)
    return np.where(total > 0, e[:, 0] / np.where(total > 0, total, 1.0), 0.0)


def weights(params: Params, state: State, awake: np.ndarray) -> np.ndarray:
    lin, ex = _rules(state)
    beta = blend_share(params, state)[:, None]
    return beta * boa.weights(params, lin, awake) + (1.0 - beta) * boa.weights(params, ex, awake)


def update(params: Params, state: State, experts, measurement, awake, learn) -> State:
    lin, ex = _rules(state)
    beta = blend_share(params, state)[:, None]
    y = np.where(learn[:, None], measurement, 0.0)
    x = np.where(awake[..., None], experts, 0.0)
    two = np.stack([ordered_sum(boa.weights(params, rule, awake)[..., None] * x, axis=1) for rule in (lin, ex)],
                   axis=1)   # (N, 2, p) the two rules' mixtures
    both = beta * two[:, 0] + (1.0 - beta) * two[:, 1]
    with np.errstate(over="ignore", invalid="ignore"):
        g = 2.0 * ordered_sum((both - y)[:, None, :] * (both[:, None, :] - two))   # (N, 2)
        finite = np.isfinite(g * g).all(axis=-1)
        rho = params.forgetting
        variance = rho * state.blend_variance + g * g
        bound = np.maximum(params.bound_forgetting * state.blend_bound, np.abs(g))
    log_2 = math.log(2.0) / params.delay
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        eta = np.where(variance > 0, np.minimum(1.0 / (2.0 * bound), np.sqrt(log_2 / variance)), 0.0)
        regret = rho * state.blend_regret + g - eta * g * g
    go = (learn & awake.any(axis=-1) & finite)[:, None]
    lin = boa.update(params, lin, experts, measurement, awake, learn)
    ex = boa.update(params, ex, experts, measurement, awake, learn, exact=True)
    return State(*lin, *ex, np.where(go, regret, state.blend_regret), np.where(go, variance, state.blend_variance),
                 np.where(go, bound, state.blend_bound))


def restart(params: Params, state: State, rows) -> State:
    """Both rules' error scales start again (:func:`.boa.restart`); the weights' states go on."""
    lin, ex = _rules(state)
    return State(*boa.restart(params, lin, rows), *boa.restart(params, ex, rows), *state[10:])
