"""filterpy's IMM and MMAE equations in numpy, many runs at once (candidates x segments).

filterpy's ``IMMEstimator`` and ``MMAEFilterBank`` step one filter object at a time in
Python; tuning one on a grid runs them once per candidate and segment. This module writes
the same equations, in the same order, on arrays with a leading batch axis, so that a whole
grid and every segment advance together, one Python step per row:

- ``KalmanFilter.update``: ``y = z - Hx``, ``S = HPHᵀ + R``, ``K = PHᵀ S⁻¹`` (``np.linalg.inv``),
  ``x += Ky``, Joseph form ``P = (I - KH) P (I - KH)ᵀ + K R Kᵀ``; ``predict``: ``x = Fx``,
  ``P = FPFᵀ + Q``;
- the likelihood of an update: scipy's ``multivariate_normal.logpdf(y, cov=S,
  allow_singular=True)`` (eigenvalues below ``10⁶ ε · max`` dropped, as scipy does), its
  ``exp``, and ``sys.float_info.min`` where that is 0 (filterpy's ``likelihood``);
- ``IMMEstimator``: ``c̄ = μM``, ``ωᵢⱼ = Mᵢⱼ μᵢ / c̄ⱼ``; update ``μ = c̄ · likelihood``,
  normalised; predict mixes ``x⁰ⱼ = Σᵢ ωᵢⱼ xᵢ``, ``P⁰ⱼ = Σᵢ ωᵢⱼ ((xᵢ - x⁰ⱼ)(xᵢ - x⁰ⱼ)ᵀ + Pᵢ)``
  and predicts each filter from its mixture;
- ``MMAEFilterBank``: ``pᵢ ← pᵢ · likelihoodᵢ``, normalised.

The states are ``[pos, vel(, acc)]`` per coordinate, coordinates stacked
(``kron(I_p, ·)`` matrices, ``H`` picks each coordinate's position), as the filterpy
objects of :mod:`kalmix.peers` and :mod:`kalmix.peer_models.multiple_model` hold them.
The test suite checks these runs against filterpy's objects (differences at rounding level).
"""

from __future__ import annotations

import itertools
import sys

import numpy as np

from ._common import check_horizon, check_segment, grid_search, one_step_rms
from .kinematic import segment_batches

__all__ = ["block_diagonal", "log_likelihood", "likelihood", "imm_run", "mmae_run", "over_candidates", "batched_search",
           "steps"]

_LOG_2PI = np.log(2 * np.pi)
_EPS_FACTOR = 1e6 * np.finfo(np.float64).eps   # scipy's cut for a "zero" eigenvalue of a covariance


def block_diagonal(blocks: np.ndarray, p: int) -> np.ndarray:
    """``kron(I_p, block)`` for each block of ``blocks (..., m, m)``: shape ``(..., m p, m p)``."""
    m = blocks.shape[-1]
    out = np.zeros(blocks.shape[:-2] + (m * p, m * p))
    for c in range(p):
        out[..., c * m:(c + 1) * m, c * m:(c + 1) * m] = blocks
    return out


def log_likelihood(y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """scipy's ``multivariate_normal.logpdf(y, cov=S, allow_singular=True)`` for each row of a batch.

    ``y (B, p)``, ``s (B, p, p)``. As scipy: ``ValueError`` when an eigenvalue of a ``S``
    is below ``-10⁶ ε · max``, eigenvalues within that of 0 are left out (pseudo-determinant,
    rank), and ``y`` outside the support of a singular ``S`` has ``-inf``.
    """
    values, vectors = np.linalg.eigh(s)
    eps = _EPS_FACTOR * np.max(np.abs(values), axis=-1, keepdims=True)
    if (values < -eps).any():
        raise ValueError("The input matrix must be symmetric positive semidefinite.")
    keep = values > eps
    with np.errstate(divide="ignore"):
        inverse = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
        logs = np.where(keep, np.log(np.where(keep, values, 1.0)), 0.0)
    whiten = vectors * np.sqrt(inverse)[..., None, :]
    maha = np.sum(np.square((y[..., None, :] @ whiten)[..., 0, :]), axis=-1)
    rank = keep.sum(axis=-1)
    out = -0.5 * (rank * _LOG_2PI + np.sum(logs, axis=-1) + maha)
    singular = rank < y.shape[-1]
    if singular.any():
        null = np.where(keep[..., None, :], 0.0, vectors)
        residual = np.linalg.norm((y[..., None, :] @ null)[..., 0, :], axis=-1)
        out = np.where(singular & ~(residual < 1e3 * eps[..., 0]), -np.inf, out)
    return out


def likelihood(y: np.ndarray, s: np.ndarray) -> np.ndarray:
    """filterpy's ``KalmanFilter.likelihood``: ``exp(log_likelihood)``, at least ``sys.float_info.min``."""
    value = np.exp(log_likelihood(y, s))
    return np.where(value == 0, sys.float_info.min, value)


def _update(x, cov, z, r, positions):
    """filterpy's ``KalmanFilter.update`` on ``x (B, n)``, ``P (B, n, n)``, ``z (B, p)``, ``R = r I``.

    Returns ``x, P, y, S``; ``positions`` are the indices ``H`` picks.
    """
    n = x.shape[-1]
    y = z - x[..., positions]
    pht = cov[..., :, positions]
    s = pht[..., positions, :] + r[..., None, None] * np.eye(len(positions))
    gain = pht @ np.linalg.inv(s)
    x = x + (gain @ y[..., None])[..., 0]
    i_kh = np.broadcast_to(np.eye(n), cov.shape).copy()
    i_kh[..., :, positions] -= gain
    cov = (i_kh @ cov) @ i_kh.swapaxes(-1, -2) + (gain * r[..., None, None]) @ gain.swapaxes(-1, -2)
    return x, cov, y, s


def _mixing(mu, markov):
    """``c̄ = μ M`` and ``ω[i, j] = M[i, j] μ[i] / c̄[j]`` (``IMMEstimator._compute_mixing_probabilities``)."""
    cbar = (mu[..., None, :] @ markov)[..., 0, :]
    return cbar, markov * mu[..., :, None] / cbar[..., None, :]


def _imm_predict(x, cov, omega, f, q):
    """``IMMEstimator.predict``: mix each model's start from every model, then predict it with ``F``, ``Q``."""
    mixed = x[..., 0, None, :] * omega[..., 0, :, None]
    for i in range(1, x.shape[-2]):
        mixed = mixed + x[..., i, None, :] * omega[..., i, :, None]
    mixed_cov = None
    for i in range(x.shape[-2]):
        d = x[..., i, None, :] - mixed                          # (B, j, n): model i's state less model j's mixture
        term = omega[..., i, :, None, None] * (d[..., :, None] * d[..., None, :] + cov[..., i, None, :, :])
        mixed_cov = term if mixed_cov is None else mixed_cov + term
    x = (f @ mixed[..., None])[..., 0]
    cov = (f @ mixed_cov) @ f.swapaxes(-1, -2) + q
    return x, cov


def _weighted_sum(weights, x):
    """``Σᵢ wᵢ xᵢ`` in filterpy's order (``sum(w * kf.x ...)``) over axis -2 of ``x``."""
    total = 0.0 + weights[..., 0, None] * x[..., 0, :]
    for i in range(1, x.shape[-2]):
        total = total + weights[..., i, None] * x[..., i, :]
    return total


def imm_run(z, lengths, models, q, r, switch, initial_variance, *, dt=None, horizon=1, last_row=False,
            return_modes=False):
    """filterpy's IMM over two Kalman filters on a shared ``[pos, vel, acc]`` state, for a batch of runs.

    Parameters
    ----------
    z : (T, B, p)
        Measurements; column ``b`` is a run of ``lengths[b]`` rows (a row with a NaN is missing:
        the mode probabilities only go through the Markov chain).
    models : callable
        ``models(dt (b,)) -> (F, Q_shape)``, each ``(b, 2, 3, 3)`` per coordinate;
        ``Q = q · Q_shape`` per model.
    q : (B, 2)
        Process-noise scales of the two models. ``r`` (B,): ``R = r I``; ``switch`` (B,): the
        Markov matrix ``[[1 - s, s], [s, 1 - s]]``; ``initial_variance`` (B, 3): ``P₀``'s
        diagonal per coordinate, the state starting at the first valid row with zero
        velocity and acceleration.
    dt : (T, B), optional
        ``dt[t]`` is the step from row ``t`` to row ``t + 1`` given to ``models`` (default 1).
    horizon : int
        Row ``t`` predicts row ``t + horizon``: after row ``t``'s predict step, the IMM's
        predict (with the Markov chain's mixing) is repeated open loop.
    last_row : bool
        Also predict after a run's last row (:func:`kalmix.peers.imm_predictions` does; the
        real-Δt peer has no step to the row after).
    return_modes : bool
        Also return the predicted mode probabilities ``c̄`` ``(T, B, 2)``.

    Returns
    -------
    (T, B, p)
        ``H Σⱼ c̄ⱼ x̂ⱼ⁻`` for row ``t + horizon`` (NaN before a run's first valid row and where
        there is no target row); with ``return_modes``, also ``c̄``.
    """
    t_count, b_count, p = z.shape
    lengths = np.asarray(lengths)
    q, r, switch = np.asarray(q, float), np.asarray(r, float), np.asarray(switch, float)
    n = 3 * p
    positions = 3 * np.arange(p)
    markov = np.stack([np.stack([1.0 - switch, switch], -1), np.stack([switch, 1.0 - switch], -1)], -2)
    dt = np.ones((t_count, b_count)) if dt is None else np.asarray(dt, float)
    x = np.zeros((b_count, 2, n))
    cov = np.zeros((b_count, 2, n, n))
    mu = np.full((b_count, 2), 0.5)
    cbar, omega = _mixing(mu, markov)
    p0 = block_diagonal(np.eye(3) * np.asarray(initial_variance, float)[:, None, :], p)
    started = np.zeros(b_count, dtype=bool)
    out = np.full(z.shape, np.nan)
    modes = np.full((t_count, b_count, 2), np.nan) if return_modes else None

    def step_models(rows, cols):
        f, shape = models(dt[rows, cols])
        return block_diagonal(f, p), q[cols, :, None, None] * block_diagonal(shape, p)

    for t in range(t_count):
        active = t < lengths
        valid = active & np.isfinite(z[t]).all(axis=1)
        new = valid & ~started
        if new.any():
            x[new] = 0.0
            x[new, :, 0::3] = z[t, new, None, :]
            cov[new] = p0[new, None]
            mu[new] = 0.5
            cbar[new], omega[new] = _mixing(mu[new], markov[new])
        learn = np.flatnonzero(valid & started)
        if learn.size:
            xs, covs, y, s = _update(x[learn], cov[learn], z[t, learn, None, :], r[learn, None], positions)
            weight = cbar[learn] * likelihood(y, s)
            weight = weight / (weight[:, 0] + weight[:, 1])[:, None]
            x[learn], cov[learn], mu[learn] = xs, covs, weight
            cbar[learn], omega[learn] = _mixing(weight, markov[learn])
        blind = np.flatnonzero(active & ~valid & started)
        if blind.size:
            mu[blind] = cbar[blind]
            cbar[blind], omega[blind] = _mixing(mu[blind], markov[blind])
        started |= new
        go = np.flatnonzero(started & (t + 1 < lengths if not last_row else active))
        if not go.size:
            continue
        f, qq = step_models(np.full(go.size, t), go)
        x[go], cov[go] = _imm_predict(x[go], cov[go], omega[go], f, qq)
        ahead = go[t + horizon < lengths[go]] if not last_row else go
        if not ahead.size:
            continue
        xs, covs, weights = x[ahead], cov[ahead], cbar[ahead]
        for k in range(t + 1, t + horizon):   # open loop: the chain moves, the filters predict from their mixture
            weights, omega_k = _mixing(weights, markov[ahead])
            f, qq = step_models(np.full(ahead.size, k), ahead)
            xs, covs = _imm_predict(xs, covs, omega_k, f, qq)
        out[t, ahead] = _weighted_sum(weights, xs)[:, positions]
        if return_modes:
            modes[t, ahead] = weights
    return (out, modes) if return_modes else out


def mmae_run(z, lengths, q, r, initial_variance, transition, noise_shape, *, dt, tau):
    """filterpy's MMAE bank of CV Kalman filters (independent, ``pᵢ ∝ pᵢ · likelihoodᵢ``) for a batch of runs.

    ``z (T, B, p)``, ``lengths (B,)``; ``q (B, m)`` the process noise of each of the ``m``
    filters, ``r (B,)``, ``initial_variance (B, 2)`` per coordinate; ``transition(dt)`` and
    ``noise_shape(dt)`` give ``F`` and ``Q / q`` per coordinate ``(b, 2, 2)``. ``dt[t]`` is
    the step from row ``t`` to ``t + 1``, ``tau[t]`` the time to the target row (NaN: none).
    Returns ``(T, B, p)``: ``H F(τ) Σᵢ pᵢ x̂ᵢ`` at each row ``t`` with a target.
    """
    t_count, b_count, p = z.shape
    m = q.shape[1]
    n = 2 * p
    positions = 2 * np.arange(p)
    lengths = np.asarray(lengths)
    x = np.zeros((b_count, m, n))
    cov = np.zeros((b_count, m, n, n))
    weight = np.full((b_count, m), 1.0 / m)
    p0 = block_diagonal(np.eye(2) * np.asarray(initial_variance, float)[:, None, :], p)
    started = np.zeros(b_count, dtype=bool)
    out = np.full(z.shape, np.nan)
    for t in range(t_count):
        active = t < lengths
        valid = active & np.isfinite(z[t]).all(axis=1)
        new = valid & ~started
        learn = np.flatnonzero(valid & started)
        if new.any():
            x[new] = 0.0
            x[new, :, 0::2] = z[t, new, None, :]
            cov[new] = p0[new, None]
            weight[new] = 1.0 / m
            started |= new
        if learn.size:
            xs, covs, y, s = _update(x[learn], cov[learn], z[t, learn, None, :], r[learn, None], positions)
            w = weight[learn] * likelihood(y, s)
            total = 0.0 + w[:, 0]
            for i in range(1, m):
                total = total + w[:, i]
            x[learn], cov[learn], weight[learn] = xs, covs, w / total[:, None]
        live = np.flatnonzero(started & active)
        if not live.size:
            continue
        target = live[np.isfinite(tau[t, live])]
        if target.size:
            jump = block_diagonal(transition(tau[t, target]), p)
            mixed = _weighted_sum(weight[target], x[target])
            out[t, target] = (jump[:, positions] @ mixed[..., None])[..., 0]
        go = live[t + 1 < lengths[live]]
        if go.size:
            f = block_diagonal(transition(dt[t, go]), p)[:, None]
            qq = q[go, :, None, None] * block_diagonal(noise_shape(dt[t, go]), p)[:, None]
            x[go] = (f @ x[go][..., None])[..., 0]
            cov[go] = (f @ cov[go]) @ f.swapaxes(-1, -2) + qq
    return out


def over_candidates(segments, candidates, run):
    """``run(z, times, lengths, column)`` over every candidate and segment, in batches of segments.

    ``segments`` are checked ``(values, times)``; ``candidates`` a list of parameter tuples.
    ``run`` gets the batch's columns (each segment once per candidate): ``z (T, B, p)`` and
    ``times (T, B)`` NaN-padded, ``lengths (B,)`` and ``column (B,)`` the candidate's index.
    Returns ``out[c][i]``: candidate ``c``'s predictions ``(T_i, p)`` on segment ``i``.
    """
    out = [[np.full(z.shape, np.nan) for z, _ in segments] for _ in candidates]
    if len({z.shape[1] for z, _ in segments}) > 1:
        raise ValueError("segments: expected the same number of coordinates in every segment, got several")
    k = len(candidates)
    for batch in segment_batches([len(t) for _, t in segments]):
        t_count, s_count = len(segments[batch[0]][1]), len(batch)
        z = np.full((t_count, s_count, segments[batch[0]][0].shape[1]), np.nan)
        times = np.full((t_count, s_count), np.nan)
        for s, j in enumerate(batch):
            z[:len(segments[j][1]), s], times[:len(segments[j][1]), s] = segments[j]
        lengths = np.array([len(segments[j][1]) for j in batch])
        predictions = run(np.tile(z, (1, k, 1)), np.tile(times, (1, k)), np.tile(lengths, k),
                          np.repeat(np.arange(k), s_count))
        for c in range(k):
            for s, j in enumerate(batch):
                out[c][j][:] = predictions[:len(out[c][j]), c * s_count + s]
    return out


def steps(times, horizon=None):
    """``times[t + 1] - times[t]`` (0 past the end), or with ``horizon`` ``times[t + horizon] - times[t]`` (NaN)."""
    if horizon is None:
        out = np.zeros_like(times)
        out[:-1] = np.nan_to_num(times[1:] - times[:-1], nan=0.0)
        return out
    out = np.full_like(times, np.nan)
    out[:-horizon] = times[horizon:] - times[:-horizon]
    return out


def batched_search(grid, pieces, predict_many):
    """:func:`grid_search` over ``grid`` with every candidate's predictions computed in one batched pass."""
    names = list(grid)
    candidates = [dict(zip(names, map(float, values))) for values in itertools.product(*grid.values())]
    predictions = predict_many(candidates)
    scores = {tuple(c.values()): one_step_rms(pieces, p) for c, p in zip(candidates, predictions)}
    return grid_search(grid, lambda c: scores[tuple(c.values())])


def one_candidate(run_many, candidate, segments, horizon, *, single: bool = False) -> list[np.ndarray]:
    """The predictions of one tuned ``candidate`` on ``segments`` (``(values, times)`` pairs), each checked,
    through ``run_many(pieces, candidates, horizon)``; ``single``: one segment, whose errors name no index."""
    horizon = check_horizon(horizon)
    pieces = [check_segment(v, t, where="" if single else f" of segments[{i}]") for i, (v, t) in enumerate(segments)]
    return run_many(pieces, [candidate], horizon)[0]
