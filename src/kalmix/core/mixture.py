"""The mixture of state-model adaptive Kalman filters: parameters, state and one step.

Functional and batched: ``state, out = step(params, state, z)`` advances ``N`` targets
by one frame, each with the same bank of ``K`` experts, using array operations over
the ``(N, K, ...)`` axes only (no Python loop over targets or experts).

One frame, for every target whose measurement :math:`z_k` is present:

1. score the predictions :math:`y_{i,k-1}` made at the previous frame (eq. 10) and form
   the adaptive learning rate :math:`\\eta_k`;
2. learn the gate (eq. 9, or the fixed-share rule), adapt :math:`Q_i, R_i` (eq. 11/12);
3. re-estimate each expert's system matrix (eq. 6/7 or RLS, see :mod:`.dynamics`);
4. Kalman update of :math:`\\hat x_{k|k-1}`; predict :math:`\\hat x_{k+1|k}`;
5. gate the experts' predictions: :math:`y_k = \\sum_i g_{i,k} y_{i,k}` (eq. 8).

A target whose measurement row holds a NaN only predicts (steps 1-3 are skipped).

Extreme input keeps every number finite, the same way in the compiled kernels:

- a measurement more than ``feature_limit`` feature units from the target's origin (100
  ``feature_scale`` = 1e4 length units by default) moves the origin there (:func:`reanchor`):
  the experts' means move with it; a target that moved on keeps its dynamics (translated,
  :func:`translates`), one that jumped (or whose statistics hold data from far back) starts them
  again from the prior. The RLS fit of a regressor that far from its origin is ill-conditioned
  (the engines drift apart and, further out, its Cholesky fails), and squared features overflow
  near 1e154. Where the distance itself overflows, the target restarts (:func:`restart`);
- an expert whose prediction misses the measurement by more than ``miss_limit`` feature units
  (1000 length units by default; after a long run of missing measurements its extrapolation can
  run off by any amount) starts again from it, rather than being pulled back by a Kalman update
  that cancels all but a few digits of its state;
- an expert whose :math:`P` reaches ``max_variance`` (only after very long runs of missing
  measurements) stops extrapolating: its mean is held, and stays finite however long the gap;
- scores whose squares overflow floor the log-likelihoods (:func:`kalmix.core.gating.posterior`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import dynamics as dyn
from . import gating as gate
from ._libm import first_max, ordered_matmul, ordered_sum
from .constraints import Boolean, Choice, Integer, Levels, Real
from .kalman import cholesky_inverse

__all__ = ["MixtureParams", "MixtureState", "StepOutput", "RunResult", "init_state", "step", "predict",
           "observation_matrix", "MAX_SEED"]

DYNAMICS = ("rls", "literal", "fixed")
GATINGS = ("fixed_share", "paper", "random", "none")
#: Largest seed: the compiled kernels hold it in a signed 64-bit integer.
MAX_SEED = 2**63 - 1


@dataclass(frozen=True, eq=False)
class MixtureParams:
    """Constant parameters of a bank of K adaptive Kalman experts and their gate.

    Build it with :func:`kalmix.bank.make_params`, which validates every field; the
    fields are documented there. Per-expert arrays have K on their first axis.
    Noise levels, scales and velocities are in measurement units (pixels for the
    paper's experiment); the filters themselves work in normalised features
    :math:`s = (z - c)/\\kappa` with :math:`\\kappa` = ``feature_scale``.
    """

    measurement_dim: int
    order: int
    dynamics: str
    gating: str
    gating_input: str
    feature_scale: float
    velocity_scale: float
    forgetting: np.ndarray
    ridge: np.ndarray
    prior_theta: np.ndarray
    spectral_radius_bound: float
    process_noise: np.ndarray
    measurement_noise: np.ndarray
    initial_variance: np.ndarray
    initial_velocity: np.ndarray
    expert_scale: np.ndarray
    temperature: float
    gate_share: float
    eta_initial: float
    eta_minimum: float
    eta_decay_steps: float
    eta_sensitivity: float
    adapt_noise: bool
    process_noise_shrink: float
    measurement_noise_shrink: float
    noise_floor: float
    noise_reinflation: float
    random_seed: int
    state_jitter: float = 1e-10
    max_variance: float = 1e8       # cap of P's largest variance (normalised features^2)
    feature_limit: float = 100.0    # |s| beyond it moves the origin (normalised features)
    miss_limit: float = 10.0        # an expert missing a measurement by more restarts (features)

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`); ``forgetting`` and ``ridge`` per expert.
    CONSTRAINTS = {
        "measurement_dim": Integer(ge=1), "order": Integer(ge=1), "dynamics": Choice(DYNAMICS),
        "gating": Choice(GATINGS), "gating_input": Choice(gate.GATING_INPUTS), "adapt_noise": Boolean(),
        "feature_scale": Real(gt=0), "forgetting": Levels(Real(gt=0, le=1.0)), "ridge": Levels(Real(gt=0)),
        "random_seed": Integer(ge=0, le=MAX_SEED),
        **dict.fromkeys(("velocity_scale", "spectral_radius_bound", "temperature", "eta_decay_steps"), Real(gt=0)),
        **dict.fromkeys(("eta_initial", "eta_minimum", "eta_sensitivity", "process_noise_shrink",
                         "measurement_noise_shrink"), Real(ge=0)),
        **dict.fromkeys(("gate_share", "noise_floor", "noise_reinflation"), Real(ge=0, le=1.0)),
    }

    @property
    def n_experts(self) -> int:
        return int(self.forgetting.shape[0])

    @property
    def state_dim(self) -> int:
        return self.order * self.measurement_dim

    @property
    def regressor_dim(self) -> int:
        return self.state_dim + 1

    @property
    def gate_dim(self) -> int:
        return gate.gating_input_size(self.gating_input, self.measurement_dim)


class MixtureState(NamedTuple):
    """Everything that changes over time, batched over N targets and K experts.

    Normalised-feature quantities are relative to each target's ``origin`` (its first
    measurement) and divided by ``feature_scale``.
    """

    steps: np.ndarray               # (N,) frames seen, measurements present or not
    valid_steps: np.ndarray         # (N,) measurements seen
    initialised: np.ndarray         # (N,) bool, a measurement has arrived
    stream_ids: np.ndarray          # (N,) int, keys the random-gating draw
    origin: np.ndarray              # (N, p) feature centre c
    history: np.ndarray             # (N, o, p) s_{k-1} ... s_{k-o}, NaN where unknown
    mean: np.ndarray                # (N, K, n) x_{k+1|k}
    cov: np.ndarray                 # (N, K, n, n) P_{k+1|k}
    gram: np.ndarray                # (N, K, d, d) RLS S_k
    cross: np.ndarray               # (N, K, p, d) RLS M_k
    transition: np.ndarray          # (N, K, n, n) A_k
    offset: np.ndarray              # (N, K, n) drift u_k
    process_noise: np.ndarray       # (N, K, p) diag Q_i (measurement units^2)
    measurement_noise: np.ndarray   # (N, K, p) diag R_i (measurement units^2)
    gate_weights: np.ndarray        # (N, K, m) a_i (paper gate)
    gate_input: np.ndarray          # (N, m) x that produced `weights`
    weights: np.ndarray             # (N, K) g_{i,k} used for the current prediction
    responsibilities: np.ndarray    # (N, K) h_{i,k} of the last scored step
    expert_predictions: np.ndarray  # (N, K, p) y_{i,k}: each expert's prediction of the next frame
    eta: np.ndarray                 # (N,) last adaptive learning rate eta_k


class StepOutput(NamedTuple):
    """What one step returns, all for the *next* frame unless stated."""

    prediction: np.ndarray          # (N, p) mixture prediction y_k (NaN before the first measurement)
    expert_predictions: np.ndarray  # (N, K, p)
    weights: np.ndarray             # (N, K) g_k
    responsibilities: np.ndarray    # (N, K) h_k (posterior of this frame's scoring)
    eta: np.ndarray                 # (N,) eta_k


class RunResult(NamedTuple):
    """Outputs of :func:`kalmix.core.run.run_core`; row ``t`` is what was known after measurement ``t``.

    ``predictions[t]`` is the prediction of frame ``t + horizon`` (for ``horizon = 1``
    the next frame), so ``predictions[t]`` is scored against ``measurements[t + horizon]``.
    Diagnostics are ``None`` unless requested.
    """

    predictions: np.ndarray                 # (T, N, p)
    state: MixtureState                     # final state (resume from it)
    weights: np.ndarray | None = None       # (T, N, K) g_k
    eta: np.ndarray | None = None           # (T, N)
    process_noise: np.ndarray | None = None  # (T, N, K, p) diag Q
    measurement_noise: np.ndarray | None = None  # (T, N, K, p) diag R
    expert_predictions: np.ndarray | None = None  # (T, N, K, p), same horizon as predictions


def observation_matrix(params: MixtureParams) -> np.ndarray:
    """:math:`C = [I_p\\ 0 \\cdots 0]`, shape ``(p, n)``."""
    c = np.zeros((params.measurement_dim, params.state_dim))
    c[:, : params.measurement_dim] = np.eye(params.measurement_dim)
    return c


def _initial_mean(params: MixtureParams, features: np.ndarray) -> np.ndarray:
    """:math:`\\hat x_0 = [s; s - v_i; s - 2 v_i; \\dots]` per expert, ``(N, K, n)``."""
    velocity = params.initial_velocity / params.feature_scale  # (K, p)
    lags = np.arange(params.order)[:, None, None]  # (o, 1, 1)
    blocks = features[:, None, None, :] - lags[None] * velocity[None, None, :, :]  # (N, o, K, p)
    return np.moveaxis(blocks, 1, 2).reshape(features.shape[0], params.n_experts, params.state_dim)


def init_state(params: MixtureParams, n_targets: int, stream_ids=None) -> MixtureState:
    """State of ``n_targets`` streams that have seen nothing yet."""
    n, k, p, o = n_targets, params.n_experts, params.measurement_dim, params.order
    dim, d, m = params.state_dim, params.regressor_dim, params.gate_dim
    ids = np.arange(n) if stream_ids is None else np.asarray(stream_ids, dtype=np.int64)
    transition, offset = dyn.companion_from_theta(params.prior_theta, o)
    p0 = params.initial_variance[:, None, None] / params.feature_scale**2 * np.eye(dim)
    return MixtureState(
        steps=np.zeros(n, dtype=np.int64),
        valid_steps=np.zeros(n, dtype=np.int64),
        initialised=np.zeros(n, dtype=bool),
        stream_ids=ids,
        origin=np.zeros((n, p)),
        history=np.full((n, o, p), np.nan),
        mean=np.zeros((n, k, dim)),
        cov=np.broadcast_to(p0, (n, k, dim, dim)).copy(),
        gram=np.zeros((n, k, d, d)),
        cross=np.zeros((n, k, p, d)),
        transition=np.broadcast_to(transition, (n, k, dim, dim)).copy(),
        offset=np.broadcast_to(offset, (n, k, dim)).copy(),
        process_noise=np.broadcast_to(params.process_noise, (n, k, p)).copy(),
        measurement_noise=np.broadcast_to(params.measurement_noise, (n, k, p)).copy(),
        gate_weights=np.zeros((n, k, m)),
        gate_input=np.zeros((n, m)),
        weights=np.full((n, k), 1.0 / k),
        responsibilities=np.full((n, k), 1.0 / k),
        expert_predictions=np.zeros((n, k, p)),
        eta=np.zeros(n),
    )


def _where(mask: np.ndarray, new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Select per target: ``mask`` is ``(N,)`` and broadcasts over trailing axes."""
    return np.where(mask.reshape(mask.shape + (1,) * (new.ndim - 1)), new, old)


# ---------------------------------------------------------------- the experts' Kalman filter
# C = [I 0]: the measurement is the first p state entries. Written in the compiled kernel's operations and
# order (kalmix.core._numba_akf_filter: kalman_update, predict_companion / predict_full, add_process_noise;
# kalmix.core.kalman.cholesky_inverse), vectorised over targets and experts, so that both engines give
# the same bits; kalmix.core.kalman holds the general batched filter.
def _mirror_upper(matrix: np.ndarray) -> np.ndarray:
    """The upper triangle (diagonal included) kept, the lower one its mirror image."""
    upper = np.triu(np.ones(matrix.shape[-2:], dtype=bool))
    return np.where(upper, matrix, np.swapaxes(matrix, -1, -2))


def _filter_update(mean: np.ndarray, cov: np.ndarray, features: np.ndarray, measurement_noise: np.ndarray,
                   kappa: float) -> tuple[np.ndarray, np.ndarray]:
    r"""Measurement update of every expert, Joseph form.

    .. math:: K = P C^T S^{-1},\ S = C P C^T + R; \quad \hat x \leftarrow \hat x + K (s - C \hat x); \quad
              P \leftarrow (I - K C) P (I - K C)^T + K R K^T = P - K P_{:p} - W K^T,\
              W = (I - K C) P C^T - K R

    ``mean (N, K, n)``, ``cov (N, K, n, n)``, ``features (N, p)``, ``measurement_noise (N, K, p)``.
    """
    p = features.shape[-1]
    residual = features[:, None, :] - mean[..., :p]
    r_diagonal = measurement_noise / kappa**2
    innovation = cov[..., :p, :p].copy()
    innovation[..., np.arange(p), np.arange(p)] += r_diagonal
    gain = ordered_matmul(cov[..., :, :p], cholesky_inverse(innovation, 1e-12)[0])          # (N, K, n, p)
    new_mean = mean + ordered_matmul(gain, residual[..., None])[..., 0]
    w = (cov[..., :, :p] - ordered_matmul(gain, cov[..., :p, :p])) - gain * r_diagonal[..., None, :]
    correction = np.zeros_like(cov)
    for l in range(p):
        correction = correction + (gain[..., :, l:l + 1] * cov[..., l:l + 1, :]
                                   + w[..., :, l:l + 1] * gain[..., None, :, l])
    return new_mean, _mirror_upper(cov - correction)


def _filter_predict(params: MixtureParams, mean: np.ndarray, cov: np.ndarray, transition: np.ndarray,
                    offset: np.ndarray, process_noise: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`\hat x \leftarrow A \hat x + u`, :math:`P \leftarrow A P A^T + Q + \epsilon I`, then the variance cap.

    For a companion A = [Theta; I 0] (rls and fixed dynamics) only its first p rows are multiplied:
    :math:`P \leftarrow [[G \Theta^T, G_{:, :n-p}], [G_{:, :n-p}^T, P_{:n-p, :n-p}]]`, :math:`G = \Theta P`;
    a general A (literal dynamics) gives :math:`(A P A^T + (A P A^T)^T) / 2`. An expert whose P reaches the
    cap (:func:`_cap_variance`) stops extrapolating: its mean is held (it stays finite).
    """
    p, n = params.measurement_dim, params.state_dim
    with np.errstate(over="ignore", invalid="ignore"):
        if params.dynamics != "literal":
            theta = transition[..., :p, :]
            top = ordered_matmul(theta, mean[..., None])[..., 0] + offset[..., :p]
            new_mean = np.concatenate([top, mean[..., :n - p] + offset[..., p:]], axis=-1)
            g = ordered_matmul(theta, cov)
            new_cov = np.empty_like(cov)
            new_cov[..., :p, :p] = _mirror_upper(ordered_matmul(g, np.swapaxes(theta, -1, -2)))
            new_cov[..., :p, p:] = g[..., :n - p]
            new_cov[..., p:, :p] = np.swapaxes(g[..., :n - p], -1, -2)
            new_cov[..., p:, p:] = _mirror_upper(cov[..., :n - p, :n - p])
        else:
            new_mean = ordered_matmul(transition, mean[..., None])[..., 0] + offset
            spread = ordered_matmul(ordered_matmul(transition, cov), np.swapaxes(transition, -1, -2))
            new_cov = 0.5 * (spread + np.swapaxes(spread, -1, -2))
        added = np.full(mean.shape, params.state_jitter + 0.0)
        added[..., :p] = params.state_jitter + process_noise / params.feature_scale**2
        new_cov[..., np.arange(n), np.arange(n)] += added
        new_cov, held = _cap_variance(new_cov, params.max_variance)
    return np.where(held[..., None], mean, new_mean), new_cov


def _cap_variance(cov: np.ndarray, max_variance: float) -> tuple[np.ndarray, np.ndarray]:
    """Scale :math:`P` down where its largest variance exceeds ``max_variance``; also return where.

    Only reached after very long runs of missing measurements, where the prediction
    is meaningless anyway; it keeps every number finite and :math:`P` positive definite.
    """
    diagonal = np.diagonal(cov, axis1=-2, axis2=-1)
    largest = np.max(np.where(np.isnan(diagonal), -np.inf, diagonal), axis=-1)   # the kernels skip a NaN
    factor = np.minimum(1.0, max_variance / largest)
    return cov * factor[..., None, None], factor != 1.0


def _missed(params: MixtureParams, mean: np.ndarray, features: np.ndarray) -> np.ndarray:
    """``(N, K)``: the experts whose predicted features miss ``features`` by more than ``miss_limit``."""
    residual = features[:, None, :] - mean[..., : params.measurement_dim]
    return ~(np.abs(residual) <= params.miss_limit).all(axis=-1)


def _far(params: MixtureParams, state: MixtureState, z: np.ndarray, valid: np.ndarray):
    """``(far, delta)``: started targets whose measurement lies more than ``feature_limit`` feature
    units (``feature_limit * feature_scale`` measurement units) from their origin, or overflows
    there, and its features :math:`\\delta = (z - c)/\\kappa` ``(N, p)``."""
    with np.errstate(over="ignore", invalid="ignore"):
        delta = (z - state.origin) / params.feature_scale
    return valid & state.initialised & ~(np.abs(delta) <= params.feature_limit).all(axis=-1), delta


def translates(params: MixtureParams, state: MixtureState, delta: np.ndarray) -> np.ndarray:
    """Per target, whether a re-anchor by ``delta (N, p)`` keeps the dynamics, translated (:func:`reanchor`):
    ``rls`` dynamics, a target that moved on (its step from the last learned measurement within
    ``miss_limit``: dynamics that learned a jump forecast worse than a restart), and data the statistics
    still hold near it (the weighted mean of every expert's regressors within ``feature_limit`` of the new
    origin: with little forgetting they keep data from far back, whose translated statistics would grow
    until the solve fails). Otherwise they start again."""
    n = params.order * params.measurement_dim
    previous = state.history[:, 0, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        moved_on = (np.abs(delta - previous) <= params.miss_limit).all(axis=-1)
        weight = state.gram[..., n, n]                                     # (N, K)
        centre = state.gram[..., n, :n] / weight[..., None]                # weighted mean of the regressors
        near = (np.abs(centre - np.tile(delta, params.order)[:, None, :]) <= params.feature_limit).all(axis=-1)
    return (params.dynamics == "rls") & moved_on & (~(weight > 0) | near).all(axis=-1)


def reanchor(params: MixtureParams, state: MixtureState, mask: np.ndarray, z: np.ndarray,
             delta: np.ndarray) -> MixtureState:
    """Move the origin of the targets in ``mask`` to their measurement ``z`` (features ``delta``).

    The experts' means move with it (:math:`\\hat x \\leftarrow \\hat x - [\\delta; \\dots; \\delta]`;
    :math:`P`, the noise levels and the gate are kept). Where :func:`translates` (a target that moved on)
    nothing is lost: the history moves too, and the RLS statistics and the drift are those of the same
    data in the new coordinates (:func:`_translated`), so a target moving steadily, which crosses
    ``feature_limit`` every 1e4 length units by default, keeps forecasting well there. Otherwise the
    dynamics start again (RLS statistics zero, :math:`A, u` the prior's, no history).
    """
    with np.errstate(invalid="ignore"):  # inf where the distance overflowed (those are not in mask)
        step = np.where(mask[:, None], delta, 0.0)
        shift = np.tile(step, params.order)  # (N, n)
    kept = mask & translates(params, state, step)
    mean = state.mean - shift[:, None, :]
    transition, offset = dyn.companion_from_theta(params.prior_theta, params.order)
    fresh = state._replace(
        origin=z, history=np.full_like(state.history, np.nan), mean=mean,
        gram=np.zeros_like(state.gram), cross=np.zeros_like(state.cross),
        transition=np.broadcast_to(transition, state.transition.shape),
        offset=np.broadcast_to(offset, state.offset.shape))
    if kept.any():
        moved = np.where(kept[:, None], step, 0.0)
        gram, cross, offset = _translated(state.gram, state.cross, state.transition, state.offset, moved,
                                          params.measurement_dim, params.order)
        translated = state._replace(origin=z, history=state.history - moved[:, None, :], mean=mean, gram=gram,
                                    cross=cross, offset=offset)
        fresh = MixtureState(*(_where(kept, a, b) for a, b in zip(translated, fresh)))
    return MixtureState(*(_where(mask, f, o) for f, o in zip(fresh, state)))


def _translated(gram, cross, transition, offset, delta, p, order):
    """RLS statistics and drift for features moved by ``-delta (N, p)``, exactly (the kernels' order of operations).

    The regressor :math:`\\xi = [s_{k-1}; \\dots; s_{k-o}; 1]` becomes :math:`M \\xi`, :math:`M = I - \\bar\\delta
    e_d^T`, :math:`\\bar\\delta = [\\delta; \\dots; \\delta; 0]`, and the target :math:`s_k` becomes
    :math:`s_k - \\delta`; with the constant's weighted sums :math:`r = S_{d,\\cdot}`:
    :math:`S \\leftarrow M S M^T`, :math:`M_{xy} \\leftarrow (M_{xy} - \\delta r) M^T`; the model's drift
    :math:`u \\leftarrow u + (\\sum_j A_j - I)\\delta` (its :math:`A_j` are unchanged).
    """
    n = order * p
    bar = np.concatenate([np.tile(delta, order), np.zeros((delta.shape[0], 1))], axis=1)[:, None, :]  # (N, 1, d)
    row = gram[..., n, :]                      # (N, K, d): S_{d, b}
    col = gram[..., :, n]                      # (N, K, d): S_{a, d}
    corner = gram[..., n, n]                   # (N, K)
    bar_a, bar_b = bar[..., :, None], bar[..., None, :]
    new_gram = (((gram - bar_a * row[..., None, :]) - col[..., :, None] * bar_b)
                + (bar_a * bar_b) * corner[..., None, None])
    moved = cross - delta[:, None, :, None] * row[..., None, :]          # (N, K, p, d)
    new_cross = moved - moved[..., :, n][..., None] * bar_b
    drift = offset[..., :p]
    for column in range(n):
        drift = drift + transition[..., :p, column] * bar[..., column][..., None]
    new_offset = offset.copy()
    new_offset[..., :p] = drift - delta[:, None, :]
    return new_gram, new_cross, new_offset


def restart(params: MixtureParams, state: MixtureState, mask: np.ndarray) -> MixtureState:
    """The targets in ``mask`` forget everything (as before their first measurement); counters are kept."""
    fresh = init_state(params, mask.shape[0], state.stream_ids)._replace(
        steps=state.steps, valid_steps=state.valid_steps)
    return MixtureState(*(_where(mask, f, o) for f, o in zip(fresh, state)))


def _update_dynamics(params, state, features, learn):
    """Re-estimate every expert's system matrix where ``learn``; returns (gram, cross, A, u)."""
    if params.dynamics == "fixed":
        return state.gram, state.cross, state.transition, state.offset
    if params.dynamics == "literal":
        previous = state.history[:, 0]
        ok = learn & np.isfinite(previous).all(axis=-1)
        # eq. (6)/(7) (dyn.literal_transition) with C = [I 0], so G = I: A = [s_k s_{k-1}^T / (|s_{k-1}|^2 + eps), 0;
        # 0, 0], in the kernels' order
        previous = np.where(ok[:, None], previous, 1.0)
        with np.errstate(over="ignore", invalid="ignore"):
            denominator = ordered_sum(previous * previous, axis=-1) + 1e-12
            top = features[:, :, None] * previous[:, None, :] / denominator[:, None, None]
        p = params.measurement_dim
        matrix = np.zeros(state.transition.shape)
        matrix[..., :p, :p] = top[:, None]
        return state.gram, state.cross, _where(ok, matrix, state.transition), state.offset
    ok = learn & np.isfinite(state.history).all(axis=(-1, -2))
    xi = dyn.regressor(np.where(ok[:, None, None], state.history, 0.0))  # (N, d)
    gram, cross = dyn.rls_accumulate(state.gram, state.cross, xi[:, None, :], features[:, None, :], params.forgetting)
    theta = dyn.rls_solve(gram, cross, params.ridge, params.prior_theta)
    theta = dyn.guard_theta(theta, params.prior_theta, params.order, params.spectral_radius_bound)
    transition, offset = dyn.companion_from_theta(theta, params.order)
    return (
        _where(ok, gram, state.gram),
        _where(ok, cross, state.cross),
        _where(ok, transition, state.transition),
        _where(ok, offset, state.offset),
    )


def _expert_outputs(params, origin, mean):
    """Experts' predicted measurements :math:`y_i = c + \\kappa C \\hat x_i`, ``(N, K, p)``."""
    return origin[:, None, :] + params.feature_scale * mean[..., : params.measurement_dim]


def step(params: MixtureParams, state: MixtureState, measurement: np.ndarray) -> tuple[MixtureState, StepOutput]:
    """Advance every target by one frame.

    Parameters
    ----------
    params : MixtureParams
    state : MixtureState
        State after frame :math:`k-1` (holds the predictions :math:`y_{i,k-1}`).
    measurement : ndarray, shape (N, p)
        :math:`z_k` in measurement units; a row with a NaN is a missing measurement.

    Returns
    -------
    state : MixtureState
        State after frame :math:`k`.
    out : StepOutput
        Predictions of frame :math:`k+1` and the gate's diagnostics.
    """
    kappa = params.feature_scale
    valid = np.isfinite(measurement).all(axis=-1)
    z = np.where(valid[:, None], measurement, 0.0)
    far, delta = _far(params, state, z, valid)
    if far.any():  # far from the origin: move it here (restart where the distance overflows)
        finite = np.isfinite(delta).all(axis=-1)
        state = restart(params, reanchor(params, state, far & finite, z, delta), far & ~finite)
    start = valid & ~state.initialised
    learn = valid & state.initialised
    origin = _where(start, z, state.origin)
    features = (z - origin) / kappa

    # 1. score the previous predictions (eq. 10) and the adaptive learning rate; 2. gate learning (eq. 9 or
    # fixed share). Without a gate ("none": a bank's AKF family, whose rule combines the experts) the weights,
    # responsibilities and rate stay as they were.
    gate_weights, weights = state.gate_weights, state.weights
    responsibilities, eta = state.responsibilities, state.eta
    rate = np.zeros(state.eta.shape)
    if params.gating != "none":
        with np.errstate(over="ignore"):  # squares of errors near 1e154 and beyond: see gate.posterior
            errors = z[:, None, :] - state.expert_predictions
            log_lik = gate.log_expert_likelihood(errors, params.expert_scale)
            responsibilities = gate.posterior(state.weights, log_lik)
            dominant = first_max(state.weights)
            dominant_error = np.take_along_axis(errors, dominant[:, None, None], axis=1)[:, 0]
            eta = gate.learning_rate(
                state.valid_steps, ordered_sum(dominant_error**2, axis=-1),
                params.eta_initial, params.eta_minimum, params.eta_decay_steps, params.eta_sensitivity,
            )
        rate = np.where(learn, eta, 0.0)
    if params.gating == "paper":
        gate_weights = gate.paper_gate_update(gate_weights, rate, responsibilities, state.weights, state.gate_input)
    elif params.gating == "fixed_share":
        with np.errstate(over="ignore"):
            shared = gate.fixed_share_update(state.weights, log_lik, params.temperature, params.gate_share)
        weights = _where(learn, shared, state.weights)

    # noise adaptation (eq. 11/12)
    process_noise, measurement_noise = state.process_noise, state.measurement_noise
    if params.adapt_noise:
        process_noise = _where(learn, gate.adapt_noise(
            process_noise, params.process_noise, rate, responsibilities,
            params.process_noise_shrink, params.noise_floor, params.noise_reinflation), process_noise)
        measurement_noise = _where(learn, gate.adapt_noise(
            measurement_noise, params.measurement_noise, rate, responsibilities,
            params.measurement_noise_shrink, params.noise_floor, params.noise_reinflation), measurement_noise)

    # 3. system matrix of each expert
    gram, cross, transition, offset = _update_dynamics(params, state, features, learn)

    # 4. Kalman update of x_{k|k-1}, (re)start, predict x_{k+1|k}
    with np.errstate(all="ignore"):   # targets that do not learn are computed, then left as they were
        updated_mean, updated_cov = _filter_update(state.mean, state.cov, features, measurement_noise, kappa)
    mean = _where(learn, updated_mean, state.mean)
    cov = _where(learn, updated_cov, state.cov)
    n = params.state_dim
    p0 = np.where(np.eye(n, dtype=bool), (params.initial_variance / kappa**2)[:, None, None], 0.0)
    fresh = start[:, None] | (learn[:, None] & _missed(params, state.mean, features))  # (N, K)
    mean = np.where(fresh[..., None], _initial_mean(params, features), mean)
    cov = np.where(fresh[..., None, None], np.broadcast_to(p0, cov.shape), cov)
    mean, cov = _filter_predict(params, mean, cov, transition, offset, process_noise)
    initialised = state.initialised | start
    expert_predictions = _where(initialised, _expert_outputs(params, origin, mean), state.expert_predictions)

    # 5. gate for the new prediction (eq. 8)
    previous = state.history[:, 0]
    velocity = np.where(np.isfinite(previous), features - np.nan_to_num(previous), 0.0)
    gate_input = _where(valid, gate.gating_features(params.gating_input, features, velocity, params.velocity_scale),
                        state.gate_input)
    if params.gating == "paper":
        weights = _where(valid, gate.softmax_gate(gate_weights, gate_input, params.temperature), state.weights)
    elif params.gating == "random":
        weights = gate.random_weights(params.random_seed, state.stream_ids, state.steps, params.n_experts)

    pushed = np.where(valid[:, None], features, np.nan)
    history = np.concatenate([pushed[:, None, :], state.history[:, :-1]], axis=1)
    new_state = MixtureState(
        steps=state.steps + 1,
        valid_steps=state.valid_steps + valid,
        initialised=initialised,
        stream_ids=state.stream_ids,
        origin=origin,
        history=history,
        mean=mean,
        cov=cov,
        gram=gram,
        cross=cross,
        transition=transition,
        offset=offset,
        process_noise=process_noise,
        measurement_noise=measurement_noise,
        gate_weights=gate_weights,
        gate_input=gate_input,
        weights=weights,
        responsibilities=_where(learn, responsibilities, state.responsibilities),
        expert_predictions=expert_predictions,
        eta=_where(learn, eta, state.eta),
    )
    return new_state, _output(new_state)


def _output(state: MixtureState) -> StepOutput:
    prediction = ordered_sum(state.weights[..., None] * state.expert_predictions, axis=1)
    prediction = np.where(state.initialised[:, None], prediction, np.nan)
    return StepOutput(prediction, state.expert_predictions, state.weights, state.responsibilities, state.eta)


def predict(params: MixtureParams, state: MixtureState, horizon: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """H-step-ahead prediction :math:`C A_k^{H-1} \\hat x_{k+1|k}` (plus drift), gated.

    Parameters
    ----------
    horizon : int
        :math:`H \\ge 1` frames ahead of the last measurement.

    Returns
    -------
    prediction : ndarray, shape (N, p)
    expert_predictions : ndarray, shape (N, K, p)
    """
    mean = state.mean
    for _ in range(horizon - 1):
        mean = ordered_matmul(state.transition, mean[..., None])[..., 0] + state.offset
    experts = _expert_outputs(params, state.origin, mean)
    prediction = ordered_sum(state.weights[..., None] * experts, axis=1)
    prediction = np.where(state.initialised[:, None], prediction, np.nan)
    return prediction, experts
