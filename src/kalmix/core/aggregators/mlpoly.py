"""ML-Poly, polynomially weighted averages with multiple learning rates (Gaillard et al. 2014).

Parameter-free; with the linearised regret :math:`r_k` (see :mod:`.boa`):

.. math::

    R_k \\leftarrow \\rho R_k + r_k,\\quad V_k \\leftarrow \\rho V_k + r_k^2,\\quad
    B \\leftarrow \\max(\\rho B, \\max_k r_k^2),\\quad
    \\eta_k = \\frac{1}{V_k + B},\\qquad w_k \\propto \\eta_k (R_k)_+

over the awake experts (uniform over them while every :math:`(R_k)_+` is zero), then the
fixed-share floor :math:`\\alpha`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..constraints import Real
from ._common import linearised_regret, ordered_sum

__all__ = ["Params", "State", "init", "weights", "update"]


class Params(NamedTuple):
    forgetting: float = 1.0   # rho in (0, 1]
    share: float = 0.0        # alpha in [0, 1)

    #: What each field may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"forgetting": Real(gt=0, le=1.0), "share": Real(ge=0, lt=1)}


class State(NamedTuple):
    regret: np.ndarray     # (N, K) R
    variance: np.ndarray   # (N, K) V
    bound: np.ndarray      # (N,) B


def init(params: Params, n_targets: int, n_experts: int) -> State:
    return State(np.zeros((n_targets, n_experts)), np.zeros((n_targets, n_experts)), np.zeros(n_targets))


def weights(params: Params, state: State, awake: np.ndarray) -> np.ndarray:
    denominator = state.variance + state.bound[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.where(awake & (denominator > 0), np.maximum(state.regret, 0.0) / denominator, 0.0)
    total = ordered_sum(score, keepdims=True)
    count = awake.sum(axis=-1, keepdims=True)
    uniform = np.where(awake, 1.0 / np.maximum(count, 1), 0.0)
    w = np.where(total > 0, score / np.where(total > 0, total, 1.0), uniform)
    return (1.0 - params.share) * w + params.share * uniform


def update(params: Params, state: State, experts, measurement, awake, learn) -> State:
    w = weights(params, state, awake)
    r = linearised_regret(w, experts, np.where(learn[:, None], measurement, 0.0), awake)
    rho = params.forgetting
    with np.errstate(over="ignore", invalid="ignore"):
        squared = r * r
    finite = np.isfinite(squared).all(axis=-1)   # an overflowing regret teaches nothing
    go = (learn & finite)[:, None] & awake
    regret = np.where(go, rho * state.regret + r, state.regret)
    variance = np.where(go, rho * state.variance + squared, state.variance)
    scored_rows = learn & finite & awake.any(axis=-1)
    largest = np.where(np.isfinite(squared), squared, 0).max(axis=-1)
    bound = np.where(scored_rows, np.maximum(rho * state.bound, largest), state.bound)
    return State(regret, variance, bound)
