"""``holt_winters``: river's ``time_series.HoltWinters`` (level and trend, no season) per coordinate.

Frame-based: the times are ignored and every row is one step. Each coordinate has its own
``HoltWinters(alpha, beta)`` fed with ``learn_one(y)`` at every valid row; a missing row
is not learnt, and row ``t`` predicts row ``t + horizon`` with ``forecast(k)[-1]``, ``k``
the rows from the last valid one to ``t + horizon``. river initialises the level and trend
from the first two values; after only one value the prediction is that value.
Tuning: ``alpha x beta`` over a 6 x 7 grid by one-step RMS on at most :data:`TUNE_ROWS`
tuning rows (a Python loop per row and coordinate).
"""

from __future__ import annotations

import numpy as np

from ._common import check_horizon, check_positive, check_segment, check_segments, frame_steps, grid_search, one_step_rms, \
    tuning_rows

__all__ = ["TUNE_ROWS", "GRID", "tune", "predict"]

#: Rows of the tuning part scored per candidate.
TUNE_ROWS = 10000
#: Candidates (river turns ``beta = 0`` into "no trend", so the smallest is 0.02).
GRID = {"alpha": (0.2, 0.4, 0.6, 0.8, 0.9, 1.0), "beta": (0.02, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0)}


def _smoothing(params, name):
    if not isinstance(params, dict) or name not in params:
        raise ValueError(f"params: expected a dict from tune with keys alpha, beta, missing {name!r}")
    value = float(params[name])
    if not 0.0 < value <= 1.0:
        raise ValueError(f"params[{name!r}]: expected a number in (0, 1], got {params[name]!r}")
    return value


def predict(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: river's Holt-Winters forecast of row ``t + horizon`` from rows ``<= t``."""
    from river.time_series import HoltWinters

    alpha, beta = _smoothing(params, "alpha"), _smoothing(params, "beta")
    horizon = check_horizon(horizon)
    z, _ = check_segment(values, times)
    t_count, p = z.shape
    valid = np.isfinite(z).all(axis=1)
    steps = frame_steps(valid, horizon)
    models = [HoltWinters(alpha=alpha, beta=beta) for _ in range(p)]
    out = np.full(z.shape, np.nan)
    seen = 0
    for t in range(t_count - horizon):
        if valid[t]:
            for model, y in zip(models, z[t].tolist()):
                model.learn_one(y)
            seen += 1
            last = z[t]
        if seen == 1:
            out[t] = last
        elif seen > 1:
            out[t] = [model.forecast(int(steps[t]))[-1] for model in models]
    return out


def tune(segments, *, unit: float, time_unit: float) -> dict:
    """Best ``alpha, beta`` of :data:`GRID` (``unit`` and ``time_unit`` are not needed: frame-based)."""
    check_positive("unit", unit), check_positive("time_unit", time_unit)
    pieces = tuning_rows(check_segments(segments), TUNE_ROWS)
    best, rms = grid_search(GRID, lambda c: one_step_rms(pieces, [predict(z, t, c) for z, t, _ in pieces]))
    return {**best, "tuning_rms": rms}
