"""``cv_dt`` and ``ca_dt``: constant-velocity / constant-acceleration Kalman filters with the real Δt.

Per coordinate the state is ``[pos, vel]`` (CV) or ``[pos, vel, acc]`` (CA), with

- ``F(Δt)`` the kinematic transition and the continuous white-noise acceleration (CV) or
  jerk (CA) process noise ``Q(Δt) = q [[Δt³/3, Δt²/2], [Δt²/2, Δt]]`` (CV),
  ``q [[Δt⁵/20, Δt⁴/8, Δt³/6], [Δt⁴/8, Δt³/3, Δt²/2], [Δt³/6, Δt²/2, Δt]]`` (CA);
  ``Δt`` is measured in ``time_unit`` (so ``q`` is in data units² per time_unit³ for CV,
  per time_unit⁵ for CA);
- ``R = r I``; the coordinates are independent (block-diagonal ``F``, ``Q``, ``P₀``), so
  the filter runs per coordinate with one shared covariance;
- initial state at the first valid measurement ``z₀``: ``[z₀, 0(, 0)]`` with
  ``P₀ = r · diag(1, V(, V))``, ``V =`` :data:`INITIAL_VARIANCE_RATIO` = 10⁴ (a velocity
  standard deviation of 100 measurement-noise standard deviations per time unit: two
  measurements Δt apart then shrink the measured velocity by only ``2 / (V Δt²)``; a much
  larger ``V`` loses digits in the first updates). ``P₀ ∝ r`` makes the predictions depend on ``q / r`` only, which
  :func:`tune_cv` uses to calibrate the scale;
- the update is filterpy's Joseph form ``P = (I - KH) P (I - KH)ᵀ + K R Kᵀ``.

Written from these equations (not :mod:`kalmix.core`), one numpy pass over every candidate
and every segment at once (arrays ``(K, S, p, n)``; segments sorted by length so that the
active ones are a prefix, in batches padded to at most twice their rows); the test suite
checks it against filterpy's ``KalmanFilter``.
"""

from __future__ import annotations

import numpy as np

from ._common import check_horizon, check_positive, check_segment, check_segments, tuning_rows

__all__ = ["INITIAL_VARIANCE_RATIO", "PROCESS_GRID", "MEASUREMENT_GRID", "tune_cv", "tune_ca", "predict_cv",
           "predict_ca", "predict_many_cv", "predict_many_ca", "transition", "process_noise_shape", "segment_batches"]

#: Initial velocity (and acceleration) variance as a multiple of the measurement noise ``r``.
INITIAL_VARIANCE_RATIO = 1e4
#: Process-noise candidates, multiples of ``unit²`` per ``time_unit³`` (CV) or ``time_unit⁵`` (CA).
PROCESS_GRID = tuple(float(v) for v in np.geomspace(1e-3, 1e5, 17))
#: Measurement-noise candidates, multiples of ``unit²`` (17 x 4 = 68 candidates in all).
MEASUREMENT_GRID = (0.05, 0.25, 1.0, 4.0)


def transition(dt, order: int) -> np.ndarray:
    """``F(Δt)`` for each ``Δt``: shape ``dt.shape + (order, order)``."""
    dt = np.asarray(dt, dtype=float)
    f = np.zeros(dt.shape + (order, order))
    for i in range(order):
        f[..., i, i] = 1.0
    f[..., 0, 1] = dt
    if order == 3:
        f[..., 1, 2] = dt
        f[..., 0, 2] = dt**2 / 2
    return f


def process_noise_shape(dt, order: int) -> np.ndarray:
    """``Q(Δt) / q``: continuous white-noise acceleration (order 2) or jerk (order 3)."""
    dt = np.asarray(dt, dtype=float)[..., None, None]
    if order == 2:
        return np.concatenate([np.concatenate([dt**3 / 3, dt**2 / 2], -1),
                               np.concatenate([dt**2 / 2, dt], -1)], -2)
    rows = [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2], [dt**3 / 6, dt**2 / 2, dt]]
    return np.concatenate([np.concatenate(row, -1) for row in rows], -2)


def segment_batches(lengths):
    """Segment indices, longest first, in batches padded to at most twice their rows."""
    order = np.argsort(-np.asarray(lengths), kind="stable")
    batch, rows = [], 0
    for j in order:
        if batch and lengths[batch[0]] * (len(batch) + 1) > 2 * (rows + lengths[j]):
            yield batch
            batch, rows = [], 0
        batch.append(int(j))
        rows += int(lengths[j])
    if batch:
        yield batch


def _pad(pieces, batch, time_unit, horizon=None):
    """A batch as ``(T, S, p)`` values, ``(T, S)`` Δt to the next row, lengths, masks and τ.

    ``τ[t]`` is the time from row ``t`` to row ``t + horizon`` (NaN where there is none);
    the mask is the third item of each piece, if any.
    """
    lengths = np.array([len(pieces[j][1]) for j in batch])
    t_count, s_count, p = int(lengths[0]), len(batch), pieces[batch[0]][0].shape[1]
    z = np.full((t_count, s_count, p), np.nan)
    dt = np.zeros((t_count, s_count))
    mask = np.zeros((t_count, s_count), dtype=bool)
    tau = None if horizon is None else np.full((t_count, s_count), np.nan)
    for s, j in enumerate(batch):
        values, times = pieces[j][:2]
        z[:len(times), s] = values
        dt[:len(times) - 1, s] = np.diff(times) / time_unit
        if len(pieces[j]) > 2:
            mask[:len(times), s] = pieces[j][2]
        if horizon is not None and len(times) > horizon:
            tau[:len(times) - horizon, s] = (times[horizon:] - times[:-horizon]) / time_unit
    return z, dt, lengths, mask, tau


def _run(z, dt, lengths, q, r, order, *, score=None, tau=None):
    """Filter ``(T, S, p)`` with every candidate ``(q[k], r[k])``; lengths sorted descending.

    With ``tau`` (T, S), returns the predictions ``(T, K, S, p)``, ``H F(τ) x̂``; with
    ``score`` (T, S) bool, the sums of squared one-step errors ``(K,)`` and of normalised
    squared errors ``(K,)``, and the number of errors, over the updates where ``score`` is True.
    """
    t_count, s_count, p = z.shape
    k_count = len(q)
    q, r = np.asarray(q, dtype=float), np.asarray(r, dtype=float)
    x = np.full((k_count, s_count, p, order), np.nan)
    cov = np.zeros((k_count, s_count, order, order))
    p0 = np.diag([1.0] + [INITIAL_VARIANCE_RATIO] * (order - 1)) * r[:, None, None, None]
    eye = np.eye(order)
    started = np.zeros(s_count, dtype=bool)
    out = np.full((t_count, k_count, s_count, p), np.nan) if tau is not None else None
    sse, nis, count = np.zeros(k_count), np.zeros(k_count), 0
    widths = np.searchsorted(-lengths, -np.arange(t_count), side="left")  # segments with length > t
    for t in range(t_count):
        w = int(widths[t])
        zt = z[t, :w]
        valid = np.isfinite(zt).all(axis=1)
        xs, ps = x[:, :w], cov[:, :w]
        upd = valid & started[:w]
        if upd.any():
            u = np.flatnonzero(upd)
            pu = ps[:, u]
            s_ = pu[..., 0, 0] + r[:, None]
            gain = pu[..., :, 0] / s_[..., None]
            innov = zt[u] - xs[..., 0][:, u]
            if score is not None:
                scored = score[t, u]
                sse += np.sum(innov[:, scored] ** 2, axis=(1, 2))
                nis += np.sum(innov[:, scored] ** 2 / s_[:, scored, None], axis=(1, 2))
                count += int(scored.sum()) * p
            xs[:, u] = xs[:, u] + gain[:, :, None, :] * innov[..., None]
            a = np.broadcast_to(eye, pu.shape).copy()
            a[..., :, 0] -= gain
            ps[:, u] = a @ pu @ a.swapaxes(-1, -2) + r[:, None, None, None] * gain[..., :, None] * gain[..., None, :]
        new = valid & ~started[:w]
        if new.any():
            xs[:, new] = 0.0
            xs[..., 0][:, new] = zt[new]
            ps[:, new] = p0
            started[:w] |= new
        if tau is not None:
            ahead = tau[t, :w, None]
            out[t, :, :w] = xs[..., 0] + ahead * xs[..., 1]
            if order == 3:
                out[t, :, :w] += ahead**2 / 2 * xs[..., 2]
        f = transition(dt[t, :w], order)
        xs[:] = (f[:, None] @ xs[..., None])[..., 0]
        ps[:] = f @ ps @ f.swapaxes(-1, -2) + q[:, None, None, None] * process_noise_shape(dt[t, :w], order)
    return out if tau is not None else (sse, nis, count)


def _tune(segments, unit, time_unit, order):
    segments = check_segments(segments)
    unit, time_unit = check_positive("unit", unit), check_positive("time_unit", time_unit)
    pieces = tuning_rows(segments)
    grid = [(qq * unit**2, rr * unit**2) for qq in PROCESS_GRID for rr in MEASUREMENT_GRID]
    q, r = np.array(grid).T
    sse, nis, count = np.zeros(len(grid)), np.zeros(len(grid)), 0
    for batch in segment_batches([len(piece[1]) for piece in pieces]):
        z, dt, lengths, mask, _ = _pad(pieces, batch, time_unit)
        more = _run(z, dt, lengths, q, r, order, score=mask)
        sse, nis, count = sse + more[0], nis + more[1], count + more[2]
    if count == 0:
        raise ValueError("segments: expected tuning rows after a first valid measurement, got none")
    mse = np.where(np.isfinite(sse), sse / count, np.inf)
    best = int(np.argmin(mse))
    if not np.isfinite(mse[best]):
        raise ValueError("segments: every candidate of the grid gave non-finite predictions on the tuning rows")
    # q/r alone sets the predictions (P0 is proportional to r): scale both so that the
    # innovations are calibrated (mean normalised squared error 1); r is then a noise variance.
    scale = float(nis[best] / count)
    if not scale > 0:   # every tuning innovation exactly 0 (a target at rest): nothing to calibrate on
        scale = 1.0
    return {"process_noise": float(q[best] * scale), "measurement_noise": float(r[best] * scale),
            "time_unit": time_unit, "tuning_rms": float(np.sqrt(mse[best]))}


def _params(params):
    if not isinstance(params, dict):
        raise ValueError(f"params: expected a dict from tune, got {type(params).__name__}")
    try:
        return tuple(check_positive(f"params[{name!r}]", params[name])
                     for name in ("process_noise", "measurement_noise", "time_unit"))
    except KeyError as missing:
        raise ValueError(f"params: expected keys process_noise, measurement_noise, time_unit, "
                         f"missing {missing}") from None


def _predict_many(segments, params, horizon, order, single=False):
    q, r, time_unit = _params(params)
    horizon = check_horizon(horizon)
    pieces = [check_segment(v, t, where="" if single else f" of segments[{i}]") for i, (v, t) in enumerate(segments)]
    out = [np.full(z.shape, np.nan) for z, _ in pieces]
    if len({z.shape[1] for z, _ in pieces}) > 1:
        raise ValueError("segments: expected the same number of coordinates in every segment, got several")
    for batch in segment_batches([len(t) for _, t in pieces]):
        z, dt, lengths, _, tau = _pad(pieces, batch, time_unit, horizon)
        predictions = _run(z, dt, lengths, [q], [r], order, tau=tau)[:, 0]
        for s, j in enumerate(batch):
            out[j][:] = predictions[:len(out[j]), s]
    return out


def tune_cv(segments, *, unit: float, time_unit: float) -> dict:
    """Best ``(q, r)`` of the CV filter over :data:`PROCESS_GRID` x :data:`MEASUREMENT_GRID`.

    Scores the one-step RMS at rows whose target is in the mask (every candidate in one
    batched pass), then multiplies the winner's ``q`` and ``r`` by its mean normalised
    squared innovation (same predictions, calibrated variances). Returns
    ``{"process_noise", "measurement_noise", "time_unit", "tuning_rms"}``.
    """
    return _tune(segments, unit, time_unit, 2)


def tune_ca(segments, *, unit: float, time_unit: float) -> dict:
    """As :func:`tune_cv` for the CA filter (``q`` in units² per time_unit⁵)."""
    return _tune(segments, unit, time_unit, 3)


def predict_many_cv(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict_cv` over a list of ``(values, times)`` in one batched pass."""
    return _predict_many(segments, params, horizon, 2)


def predict_many_ca(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict_ca` over a list of ``(values, times)`` in one batched pass."""
    return _predict_many(segments, params, horizon, 3)


def predict_cv(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the CV filter's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    return _predict_many([(values, times)], params, horizon, 2, single=True)[0]


def predict_ca(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the CA filter's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    return _predict_many([(values, times)], params, horizon, 3, single=True)[0]
