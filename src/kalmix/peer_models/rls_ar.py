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
at most :data:`TUNE_ROWS` tuning rows (a Python loop per row and coordinate).
"""

from __future__ import annotations

import numpy as np

from ._common import check_horizon, check_positive, check_segment, check_segments, grid_search, one_step_rms, \
    tuning_rows

__all__ = ["TUNE_ROWS", "GRID", "tune", "predict"]

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


def predict(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the RLS AR model's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    from padasip.filters import FilterRLS

    order, forgetting, unit, time_unit = _read(params)
    horizon = check_horizon(horizon)
    z, times = check_segment(values, times)
    t_count, p = z.shape
    steps = np.diff(times) / time_unit
    filters = [FilterRLS(order + 1, mu=forgetting, w="zeros") for _ in range(p)]
    history = np.zeros((p, order + 1))  # previous velocities, most recent first, then the bias
    history[:, -1] = 1.0
    out = np.full(z.shape, np.nan)
    last = None
    for t in range(t_count - horizon):
        if np.isfinite(z[t]).all():
            if last is not None:
                velocity = (z[t] - z[last]) / (times[t] - times[last]) * time_unit / unit
                for j, rls in enumerate(filters):
                    rls.adapt(velocity[j], history[j])
                history[:, 1:order] = history[:, :order - 1]
                history[:, 0] = velocity
            last = t
        if last is None:
            continue
        position, ahead = z[last].copy(), history.copy()
        for k in range(last, t + horizon):
            guess = np.array([rls.predict(ahead[j]) for j, rls in enumerate(filters)])
            position += guess * steps[k] * unit
            ahead[:, 1:order] = ahead[:, :order - 1]
            ahead[:, 0] = guess
        out[t] = position
    return out


def tune(segments, *, unit: float, time_unit: float) -> dict:
    """Best ``order, forgetting`` of :data:`GRID`; ``unit`` and ``time_unit`` scale the velocities."""
    fixed = {"unit": check_positive("unit", unit), "time_unit": check_positive("time_unit", time_unit)}
    pieces = tuning_rows(check_segments(segments), TUNE_ROWS)
    best, rms = grid_search(GRID, lambda c: one_step_rms(
        pieces, [predict(z, t, {**c, **fixed}) for z, t, _ in pieces]))
    return {**best, "order": int(best["order"]), **fixed, "tuning_rms": rms}
