"""``ucm_llt``: statsmodels' ``UnobservedComponents(level="local linear trend")`` per coordinate.

Frame-based (every row one step; times ignored). The three variances (irregular, level,
trend) are shared by every coordinate and fitted by maximum likelihood (the sum of the
log-likelihoods of every coordinate of the tuning parts, L-BFGS-B on statsmodels'
untransformed parameters) on the tuning parts of the longest segments, at most
:data:`FIT_ROWS` rows in all (longest first, the last one cut). Rows outside the mask are
missing to the fit.

Prediction: statsmodels' Kalman filter with the fitted variances and an exact diffuse
initialisation, on ``(values - first valid row) / unit`` from the first valid row on
(a row with a NaN is missing, which statsmodels handles). Row ``t`` predicts row
``t + horizon`` from the filtered state, ``level + horizon · trend`` (open loop; for one
step it is statsmodels' one-step-ahead forecast). Only filtered (causal) states are used.
"""

from __future__ import annotations

import warnings

import numpy as np

from ._common import check_horizon, check_positive, check_segment, check_segments, one_step_rms, tuning_rows

__all__ = ["FIT_ROWS", "tune", "predict"]

#: Tuning rows used by the maximum-likelihood fit.
FIT_ROWS = 20000
_NAMES = ("sigma2_irregular", "sigma2_level", "sigma2_trend")


def _model(y):
    from statsmodels.tsa.statespace.structural import UnobservedComponents

    return UnobservedComponents(y, level="local linear trend", use_exact_diffuse=True)


def _read(params):
    if not isinstance(params, dict):
        raise ValueError(f"params: expected a dict from tune, got {type(params).__name__}")
    missing = [name for name in _NAMES + ("unit",) if name not in params]
    if missing:
        raise ValueError(f"params: expected keys {', '.join(_NAMES)}, unit, missing {', '.join(missing)}")
    sigma2 = np.array([float(params[name]) for name in _NAMES])
    if not (np.isfinite(sigma2).all() and (sigma2 >= 0).all() and sigma2.sum() > 0):
        raise ValueError(f"params: expected finite variances >= 0, not all 0, for {', '.join(_NAMES)}, "
                         f"got {sigma2.tolist()}")
    return sigma2, check_positive("params['unit']", params["unit"])


def _series(z, unit):
    """Per coordinate: ``(values - first valid) / unit`` from the first valid row, NaN rows missing."""
    valid = np.isfinite(z).all(axis=1)
    if not valid.any():
        return None, []
    first = int(np.argmax(valid))
    y = (z[first:] - z[first]) / unit
    y[~valid[first:]] = np.nan
    return first, [y[:, j].copy() for j in range(z.shape[1])]


def predict(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the filtered local-linear-trend forecast of row ``t + horizon`` from rows ``<= t``."""
    sigma2, unit = _read(params)
    horizon = check_horizon(horizon)
    z, _ = check_segment(values, times)
    out = np.full(z.shape, np.nan)
    first, series = _series(z, unit)
    stop = z.shape[0] - horizon
    if first is None or stop <= first:
        return out
    scaled = sigma2 / unit**2
    for j, y in enumerate(series):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            state = _model(y).filter(scaled).filtered_state
        out[first:stop, j] = (state[0] + horizon * state[1])[:stop - first] * unit + z[first, j]
    return out


def tune(segments, *, unit: float, time_unit: float) -> dict:
    """Maximum-likelihood variances on the tuning parts (at most :data:`FIT_ROWS` rows)."""
    from scipy.optimize import minimize

    unit = check_positive("unit", unit)
    check_positive("time_unit", time_unit)
    pieces = tuning_rows(check_segments(segments))
    models, total = [], 0
    for z, _, mask in sorted(pieces, key=lambda piece: -int(piece[2].sum())):
        if total >= FIT_ROWS:
            break
        z = np.where(mask[:, None], z, np.nan)[:FIT_ROWS - total]
        total += len(z)
        series = _series(z, unit)[1]
        models += [_model(y) for y in series if np.isfinite(y).sum() > 2]
    if not models:
        raise ValueError("segments: expected a tuning part with at least 3 valid rows, got none")
    start = np.median([m.untransform_params(m.start_params) for m in models], axis=0)

    def cost(u):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return -sum(m.loglike(u, transformed=False) for m in models) / total

    fit = minimize(cost, start, method="L-BFGS-B")
    sigma2 = models[0].transform_params(fit.x) * unit**2
    params = {**{name: float(v) for name, v in zip(_NAMES, sigma2)}, "unit": unit}
    check = tuning_rows(pieces)
    params["tuning_rms"] = one_step_rms(check, [predict(z, t, params) for z, t, _ in check])
    return params
