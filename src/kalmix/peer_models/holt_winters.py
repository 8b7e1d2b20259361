"""``holt_winters``: river's ``time_series.HoltWinters`` (level and trend, no season) per coordinate.

Frame-based: the times are ignored and every row is one step. Each coordinate has its own
``HoltWinters(alpha, beta)`` fed with ``learn_one(y)`` at every valid row; a missing row
is not learnt, and row ``t`` predicts row ``t + horizon`` with ``forecast(k)[-1]``, ``k``
the rows from the last valid one to ``t + horizon``. river initialises the level and trend
from the first two values; after only one value the prediction is that value.
Tuning: ``alpha x beta`` over a 6 x 7 grid by one-step RMS on at most :data:`TUNE_ROWS`
tuning rows. The recursions run on arrays, every candidate, segment and coordinate at once
(river's arithmetic in river's order: the test suite checks the numbers against river's
objects fed row by row).
"""

from __future__ import annotations

import numpy as np

from ._batched import batched_search, one_candidate, over_candidates
from ._common import check_positive, check_segments, tuning_rows

__all__ = ["TUNE_ROWS", "GRID", "tune", "predict", "predict_many"]

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


def _run(z, lengths, alpha, beta, horizon):
    """river's ``HoltWinters.learn_one`` / ``forecast`` for every column of ``z (T, B, p)`` at once.

    ``alpha``, ``beta`` (B,); column ``b`` is a segment of ``lengths[b]`` rows. The same
    arithmetic as river's, in the same order (element by element, so the same numbers):
    after two values the level is their mean and the trend their difference; then
    ``level = α y + (1 - α)(level + trend)``, ``trend = β (level - previous level) + (1 - β) trend``;
    the forecast ``k`` rows ahead is ``level + k · trend``.
    """
    t_count, b_count, p = z.shape
    alpha, beta = alpha[:, None], beta[:, None]
    seen = np.zeros(b_count, dtype=np.int64)
    first, last = np.full((b_count, p), np.nan), np.full((b_count, p), np.nan)
    level, trend = np.full((b_count, p), np.nan), np.full((b_count, p), np.nan)
    since = np.zeros(b_count, dtype=np.int64)   # rows from the last valid one to the current row
    out = np.full(z.shape, np.nan)
    for t in range(t_count):
        live = t < np.asarray(lengths) - horizon
        valid = live & np.isfinite(z[t]).all(axis=1)
        y = z[t]
        learn = valid & (seen >= 2)
        if learn.any():
            previous = level[learn]
            level[learn] = alpha[learn] * y[learn] + (1 - alpha[learn]) * (previous + trend[learn])
            trend[learn] = beta[learn] * (level[learn] - previous) + (1 - beta[learn]) * trend[learn]
        second = valid & (seen == 1)
        if second.any():
            level[second] = (first[second] + y[second]) / 2   # statistics.mean of the first two
            trend[second] = y[second] - first[second]
        first[valid & (seen == 0)] = y[valid & (seen == 0)]
        last[valid] = y[valid]
        seen += valid
        since = np.where(valid, 0, since + 1)
        out[t, live & (seen == 1)] = last[live & (seen == 1)]
        ahead = live & (seen > 1)
        if ahead.any():
            k = (since[ahead] + horizon).astype(float)[:, None]
            out[t, ahead] = level[ahead] + k * trend[ahead] + 0
    return out


def _predict_many(segments, candidates, horizon):
    table = np.array(candidates, dtype=float)

    def run(z, times, lengths, column):
        return _run(z, lengths, table[column, 0], table[column, 1], horizon)

    return over_candidates(segments, candidates, run)


def predict(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: river's Holt-Winters forecast of row ``t + horizon`` from rows ``<= t``."""
    candidate = (_smoothing(params, "alpha"), _smoothing(params, "beta"))
    return one_candidate(_predict_many, candidate, [(values, times)], horizon, single=True)[0]


def predict_many(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict` over a list of ``(values, times)`` in one batched pass."""
    candidate = (_smoothing(params, "alpha"), _smoothing(params, "beta"))
    return one_candidate(_predict_many, candidate, segments, horizon)


def tune(segments, *, unit: float, time_unit: float) -> dict:
    """Best ``alpha, beta`` of :data:`GRID` (``unit`` and ``time_unit`` are not needed: frame-based)."""
    check_positive("unit", unit), check_positive("time_unit", time_unit)
    pieces = tuning_rows(check_segments(segments), TUNE_ROWS)
    best, rms = batched_search(GRID, pieces, lambda candidates: _predict_many(
        [(z, t) for z, t, _ in pieces], [(c["alpha"], c["beta"]) for c in candidates], 1))
    return {**best, "tuning_rms": rms}
