"""Fixed share (Herbster and Warmuth 1998) over Gaussian scores, with a fixed or an online scale.

.. math::

    \\log w_k \\leftarrow \\log w_k - \\frac{\\lVert y - x_k \\rVert^2}{2 \\sigma^2},\\qquad
    w \\leftarrow (1 - \\alpha)\\, \\mathrm{normalise}(w) + \\alpha / K_{awake}.

With ``scale > 0`` the loss scale is fixed, :math:`\\sigma` = ``scale`` (kept for the
ablation: it is exponential weighting with the fixed learning
rate :math:`1/(2\\sigma^2)`, so the result depends on the data's units). With
``scale = 0`` (the default) it is learned online: :math:`\\sigma^2 = c\\, m`, with
:math:`m` the running mean of the mixture's squared error per coordinate and
:math:`c` = ``scale_factor``; before any error is seen the weights stay uniform.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..constraints import Real
from ._common import log, normalise_awake, ordered_sum

__all__ = ["Params", "State", "init", "weights", "update"]


class Params(NamedTuple):
    share: float = 0.02          # alpha
    scale: float = 0.0           # sigma > 0: fixed scale; 0: online scale
    scale_factor: float = 4.0    # c

    #: What each field may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"share": Real(ge=0, lt=1), "scale": Real(ge=0, hint="0: the online scale"),
                   "scale_factor": Real(gt=0)}


class State(NamedTuple):
    log_weights: np.ndarray   # (N, K)
    squared: np.ndarray       # (N,) sum of the mixture's squared errors per coordinate
    count: np.ndarray         # (N,) steps in that sum


def init(params: Params, n_targets: int, n_experts: int) -> State:
    return State(np.zeros((n_targets, n_experts)), np.zeros(n_targets), np.zeros(n_targets))


def weights(params: Params, state: State, awake: np.ndarray) -> np.ndarray:
    return normalise_awake(state.log_weights, awake)


def update(params: Params, state: State, experts, measurement, awake, learn) -> State:
    p = experts.shape[-1]
    z = np.where(learn[:, None], measurement, 0.0)
    w = weights(params, state, awake)
    x = np.where(awake[..., None], experts, 0.0)
    mix = ordered_sum(w[..., None] * x, axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        squared = state.squared + ordered_sum((mix - z) ** 2) / p
        loss = ordered_sum((z[:, None, :] - x) ** 2)
    count = state.count + 1.0
    if params.scale > 0:
        variance = np.full(z.shape[0], params.scale**2)
    else:
        variance = params.scale_factor * squared / count
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(variance[:, None] > 0, loss / (2.0 * variance[:, None]), 0.0)
    scored = normalise_awake(state.log_weights - step, awake)
    count_awake = awake.sum(axis=-1, keepdims=True)
    shared = (1.0 - params.share) * scored + np.where(awake, params.share / np.maximum(count_awake, 1), 0.0)
    with np.errstate(divide="ignore"):
        new_log = np.where(awake, log(shared), state.log_weights)
    finite = np.isfinite(squared) & np.isfinite(np.where(awake, loss, 0.0)).all(axis=-1)
    scored_rows = learn & awake.any(axis=-1) & finite   # an overflowing loss teaches nothing
    return State(np.where(scored_rows[:, None], new_log, state.log_weights),
                 np.where(scored_rows, squared, state.squared), np.where(scored_rows, count, state.count))
