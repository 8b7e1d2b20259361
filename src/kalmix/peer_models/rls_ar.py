"""``rls_ar``: padasip's ``FilterRLS`` as an adaptive autoregressive model of the velocity.

An AR model of the positions (with a bias) drifts with the track, so the model is on the
increments, divided by their real time step: per coordinate, the velocity of the interval
ending at a valid row, ``v = (z - z_prev) / (Δt / time_unit) / unit`` (``z_prev`` the
previous valid row, so a gap of missing rows is one interval), is predicted from the
previous ``order`` velocities and a constant 1 (a bias: the mean drift). One
``FilterRLS(order + 1, mu=forgetting, w="zeros")`` per coordinate (padasip's default
``eps``, a weak prior) learns at every valid row from the second on; the velocities before
the first interval are 0 (so the first predictions hold the last position).

Row ``t`` predicts row ``t + horizon`` open loop: from the last valid row ``<= t`` the AR
is iterated row by row, each predicted velocity fed back as a regressor and multiplied by
that row's real ``Δt``. Tuning: ``order x forgetting`` over a 4 x 6 grid by one-step RMS on
at most :data:`TUNE_ROWS` tuning rows. padasip's update runs on arrays, every candidate,
segment and coordinate at once (the test suite checks the numbers against padasip's filters
adapted row by row).
"""

from __future__ import annotations

import numpy as np

from ._batched import batched_search, one_candidate, over_candidates
from ._common import check_positive, check_segments, tuning_rows

__all__ = ["TUNE_ROWS", "GRID", "tune", "predict", "predict_many"]

#: Rows of the tuning part scored per candidate.
TUNE_ROWS = 5000
#: Candidates: AR order (previous velocities) and RLS forgetting factor.
GRID = {"order": (1, 2, 3, 5), "forgetting": (0.9, 0.95, 0.98, 0.99, 0.995, 0.999)}


def _read(params):
    if not isinstance(params, dict):
        raise ValueError(f"params: expected a dict from tune, got {type(params).__name__}")
    missing = [k for k in ("order", "forgetting", "unit", "time_unit") if k not in params]
    if missing:
        raise ValueError(f"params: expected keys order, forgetting, unit, time_unit, missing {', '.join(missing)}")
    order = params["order"]
    if float(order) != int(order) or int(order) < 1:
        raise ValueError(f"params['order']: expected an integer >= 1, got {order!r}")
    forgetting = float(params["forgetting"])
    if not 0.0 < forgetting <= 1.0:
        raise ValueError(f"params['forgetting']: expected a number in (0, 1], got {params['forgetting']!r}")
    return (int(order), forgetting, check_positive("params['unit']", params["unit"]),
            check_positive("params['time_unit']", params["time_unit"]))


def _run(z, times, lengths, order, forgetting, unit, time_unit, horizon):
    """padasip's ``FilterRLS`` AR model for every column of ``z (T, B, p)`` at once (one AR ``order``).

    ``forgetting``, ``unit``, ``time_unit`` (B,). padasip's arithmetic, in its order, on
    arrays: ``e = d - w·x``; ``R ← (R - R x xᵀ R / (μ + xᵀ R x)) / μ``; ``w += R x e``,
    starting from ``w = 0``, ``R = I / 0.001`` (padasip's ``eps``).
    """
    t_count, b_count, p = z.shape
    n = order + 1
    lengths = np.asarray(lengths)
    mu = forgetting[:, None, None, None]
    w = np.zeros((b_count, p, n))
    big = 1 / 0.001 * np.identity(n)
    r = np.broadcast_to(big, (b_count, p, n, n)).copy()
    history = np.zeros((b_count, p, n))   # previous velocities, most recent first, then the bias
    history[..., -1] = 1.0
    step = np.zeros((t_count, b_count))
    step[:-1] = np.nan_to_num((times[1:] - times[:-1]) / time_unit, nan=0.0)
    last = np.full(b_count, -1)
    z_last, t_last = np.full((b_count, p), np.nan), np.full(b_count, np.nan)
    out = np.full(z.shape, np.nan)
    columns = np.arange(b_count)
    for t in range(t_count):
        live = t < lengths - horizon
        valid = live & np.isfinite(z[t]).all(axis=1)
        learn = np.flatnonzero(valid & (last >= 0))
        if learn.size:
            velocity = (z[t, learn] - z_last[learn]) / (times[t, learn] - t_last[learn])[:, None] \
                * time_unit[learn, None] / unit[learn, None]
            x, rr, m = history[learn], r[learn], mu[learn]
            e = velocity - (w[learn][..., None, :] @ x[..., :, None])[..., 0, 0]
            r1 = (rr @ (x[..., :, None] * x[..., None, :])) @ rr
            r2 = m + (x[..., None, :] @ rr) @ x[..., :, None]
            rr = 1 / m * (rr - r1 / r2)
            r[learn] = rr
            w[learn] = w[learn] + (rr @ x[..., :, None])[..., 0] * e[..., None]
            history[learn, :, 1:order] = history[learn, :, :order - 1]
            history[learn, :, 0] = velocity
        z_last[valid], t_last[valid], last[valid] = z[t, valid], times[t, valid], t
        ready = np.flatnonzero(live & (last >= 0))
        if not ready.size:
            continue
        position, ahead = z_last[ready].copy(), history[ready].copy()
        count = t + horizon - last[ready]
        for offset in range(int(count.max())):
            going = offset < count
            k = last[ready] + offset
            guess = (w[ready][..., None, :] @ ahead[..., :, None])[..., 0, 0]
            moved = position + guess * step[k, columns[ready]][:, None] * unit[ready, None]
            position = np.where(going[:, None], moved, position)
            shifted = ahead.copy()
            shifted[..., 1:order] = ahead[..., :order - 1]
            shifted[..., 0] = guess
            ahead = np.where(going[:, None, None], shifted, ahead)
        out[t, ready] = position
    return out


def _predict_many(segments, candidates, horizon):
    """Predictions of each candidate ``(order, forgetting, unit, time_unit)`` on each segment."""
    table = np.array(candidates, dtype=float)

    def run(z, times, lengths, column):
        out = np.full(z.shape, np.nan)
        orders = table[column, 0].astype(int)
        for order in np.unique(orders):   # one batched run per AR order
            cols = np.flatnonzero(orders == order)
            out[:, cols] = _run(z[:, cols], times[:, cols], lengths[cols], int(order), table[column[cols], 1],
                                table[column[cols], 2], table[column[cols], 3], horizon)
        return out

    return over_candidates(segments, candidates, run)


def predict(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the RLS AR model's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    candidate = _read(params)
    return one_candidate(_predict_many, candidate, [(values, times)], horizon, single=True)[0]


def predict_many(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict` over a list of ``(values, times)`` in one batched pass."""
    candidate = _read(params)
    return one_candidate(_predict_many, candidate, segments, horizon)


def tune(segments, *, unit: float, time_unit: float) -> dict:
    """Best ``order, forgetting`` of :data:`GRID`; ``unit`` and ``time_unit`` scale the velocities."""
    fixed = {"unit": check_positive("unit", unit), "time_unit": check_positive("time_unit", time_unit)}
    pieces = tuning_rows(check_segments(segments), TUNE_ROWS)
    best, rms = batched_search(GRID, pieces, lambda candidates: _predict_many(
        [(z, t) for z, t, _ in pieces], [_read({**c, **fixed}) for c in candidates], 1))
    return {**best, "order": int(best["order"]), **fixed, "tuning_rms": rms}
