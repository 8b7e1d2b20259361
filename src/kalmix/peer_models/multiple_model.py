"""``imm_dt`` and ``mmae_dt``: filterpy's multiple-model estimators with the real Δt.

- ``imm_dt``: filterpy ``IMMEstimator`` over a CV and a CA ``KalmanFilter`` sharing the state
  ``[pos, vel, acc]`` per coordinate (the CV model's ``F`` resets the acceleration to 0 and
  its ``Q`` has no acceleration part, so that the two can be mixed); ``F(Δt)`` and ``Q(Δt)``
  of :mod:`~kalmix.peer_models.kinematic` are rebuilt at every step. Mode probabilities
  start at ½, ½; a missing row only moves them through the Markov chain. The prediction is
  ``H Σⱼ c̄ⱼ x̂ⱼ⁻`` with the predicted mode probabilities ``c̄`` (as :mod:`kalmix.peers`);
  ``horizon`` steps ahead it repeats the IMM's predict step open loop (Markov chain and
  mixing included) on a copy of the state.
- ``mmae_dt``: filterpy ``MMAEFilterBank`` (the classical multiple-model adaptive
  estimator: independent filters, posterior model probabilities ``pᵢ ∝ pᵢ · likelihoodᵢ``)
  over :data:`MMAE_FILTERS` CV filters with ``q · spread^k``, ``k = -2..2``. Prediction
  ``Σᵢ pᵢ H F(τ) x̂ᵢ`` (``τ`` from row ``t`` to row ``t + horizon``).

Both start as the kinematic filters do (first valid measurement, zero velocity and
acceleration, ``P₀ = r diag(1, V, V)``). Measurement noise ``r`` and the centres of the
process-noise grids come from :func:`~kalmix.peer_models.kinematic.tune_cv` (and
``tune_ca``); see :func:`tune_imm` and :func:`tune_mmae`. These are Python loops over
rows (filterpy objects): tuning uses at most :data:`TUNE_ROWS` rows (the first rows of
each segment's tuning part, :func:`~kalmix.peer_models._common.tuning_rows`).
"""

from __future__ import annotations

import numpy as np

from ._common import check_horizon, check_positive, check_segment, check_segments, grid_search, one_step_rms, \
    tuning_rows
from .kinematic import INITIAL_VARIANCE_RATIO, process_noise_shape, transition, tune_ca, tune_cv

__all__ = ["TUNE_ROWS", "MMAE_FILTERS", "tune_imm", "predict_imm", "tune_mmae", "predict_mmae"]

#: Rows of the tuning part scored per candidate (filterpy is a Python loop).
TUNE_ROWS = 3000
#: Number of CV filters in the MMAE bank.
MMAE_FILTERS = 5
_IMM_CV_FACTORS = (0.03, 0.1, 0.3, 1.0)
_IMM_CA_FACTORS = (0.3, 1.0, 3.0, 10.0)
_IMM_SWITCH = (0.02, 0.1)
_MMAE_SPREADS = (3.0, 10.0, 30.0)


def _read(params, names):
    if not isinstance(params, dict):
        raise ValueError(f"params: expected a dict from tune, got {type(params).__name__}")
    missing = [name for name in names if name not in params]
    if missing:
        raise ValueError(f"params: expected keys {', '.join(names)}, missing {', '.join(missing)}")
    return [check_positive(f"params[{name!r}]", params[name]) for name in names]


def _filters(p, order_f, r, z0, count):
    from filterpy.kalman import KalmanFilter

    n = order_f
    h = np.zeros((p, n * p))
    h[np.arange(p), n * np.arange(p)] = 1.0
    x0 = np.zeros((n * p, 1))
    x0[0::n, 0] = z0
    p0 = np.kron(np.eye(p), np.diag([r] + [r * INITIAL_VARIANCE_RATIO] * (n - 1)))
    filters = []
    for _ in range(count):
        kf = KalmanFilter(dim_x=n * p, dim_z=p)
        kf.H, kf.R, kf.x, kf.P = h.copy(), np.eye(p) * r, x0.copy(), p0.copy()
        filters.append(kf)
    return filters, h


def _imm_models(dt, p, q_cv, q_ca):
    """``(F, Q)`` of the CV and the CA model on the shared ``[pos, vel, acc]`` state."""
    f_cv = transition(dt, 3)
    f_cv[1, 2] = f_cv[0, 2] = f_cv[2, 2] = 0.0
    q_shape = np.zeros((3, 3))
    q_shape[:2, :2] = process_noise_shape(dt, 2)
    eye = np.eye(p)
    return ((np.kron(eye, f_cv), np.kron(eye, q_cv * q_shape)),
            (np.kron(eye, transition(dt, 3)), np.kron(eye, q_ca * process_noise_shape(dt, 3))))


def predict_imm(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the IMM's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    from filterpy.kalman import IMMEstimator

    q_cv, q_ca, r, s, time_unit = _read(params, ("cv_process_noise", "ca_process_noise", "measurement_noise",
                                                 "switch_probability", "time_unit"))
    if s >= 1:
        raise ValueError(f"params['switch_probability']: expected a number in (0, 1), got {s!r}")
    horizon = check_horizon(horizon)
    z, times = check_segment(values, times)
    t_count, p = z.shape
    out = np.full(z.shape, np.nan)
    markov = np.array([[1.0 - s, s], [s, 1.0 - s]])
    imm = filters = None
    for t in range(t_count):
        valid = bool(np.isfinite(z[t]).all())
        if imm is None:
            if not valid:
                continue
            filters, h = _filters(p, 3, r, z[t], 2)
            imm = IMMEstimator(filters, [0.5, 0.5], markov)
        elif valid:
            imm.update(z[t][:, None])
        else:  # missing: the mode probabilities only go through the Markov chain
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
        if t + 1 >= t_count:
            break
        for kf, (f, q) in zip(filters, _imm_models((times[t + 1] - times[t]) / time_unit, p, q_cv, q_ca)):
            kf.F, kf.Q = f, q
        imm.predict()
        if t + horizon >= t_count:
            continue
        if horizon == 1:
            out[t] = (h @ sum(c * kf.x for c, kf in zip(imm.cbar, filters)))[:, 0]
            continue
        saved = [(kf.x.copy(), kf.P.copy()) for kf in filters], imm.mu.copy(), imm.cbar.copy(), imm.omega.copy()
        for k in range(t + 1, t + horizon):
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
            for kf, (f, q) in zip(filters, _imm_models((times[k + 1] - times[k]) / time_unit, p, q_cv, q_ca)):
                kf.F, kf.Q = f, q
            imm.predict()
        out[t] = (h @ sum(c * kf.x for c, kf in zip(imm.cbar, filters)))[:, 0]
        for kf, (x, cov) in zip(filters, saved[0]):
            kf.x, kf.P = x, cov
        imm.mu, imm.cbar, imm.omega = saved[1:]
    return out


def tune_imm(segments, *, unit: float, time_unit: float) -> dict:
    """Grid over the CV and CA process noises and the switch probability (32 candidates).

    ``r`` is the tuned CV filter's; the CV noise is the tuned CV filter's ``q`` times
    0.03..1, the CA noise the tuned CA filter's ``q`` (at the same ``q / r``) times 0.3..10,
    the switch probability 0.02 or 0.1; one-step RMS on at most :data:`TUNE_ROWS` tuning rows.
    """
    segments = check_segments(segments)
    cv, ca = tune_cv(segments, unit=unit, time_unit=time_unit), tune_ca(segments, unit=unit, time_unit=time_unit)
    r = cv["measurement_noise"]
    ca_q = ca["process_noise"] * r / ca["measurement_noise"]
    pieces = tuning_rows(segments, TUNE_ROWS)
    grid = {"cv_process_noise": tuple(f * cv["process_noise"] for f in _IMM_CV_FACTORS),
            "ca_process_noise": tuple(f * ca_q for f in _IMM_CA_FACTORS), "switch_probability": _IMM_SWITCH}
    fixed = {"measurement_noise": r, "time_unit": float(time_unit)}
    best, rms = grid_search(grid, lambda c: one_step_rms(
        pieces, [predict_imm(z, t, {**c, **fixed}) for z, t, _ in pieces]))
    return {**best, **fixed, "tuning_rms": rms}


def predict_mmae(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the MMAE bank's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    from filterpy.kalman import MMAEFilterBank

    q, spread, r, time_unit = _read(params, ("process_noise", "spread", "measurement_noise", "time_unit"))
    horizon = check_horizon(horizon)
    z, times = check_segment(values, times)
    t_count, p = z.shape
    out = np.full(z.shape, np.nan)
    qs = q * spread ** (np.arange(MMAE_FILTERS) - MMAE_FILTERS // 2)
    bank = filters = None
    eye = np.eye(p)
    for t in range(t_count):
        valid = bool(np.isfinite(z[t]).all())
        if bank is None:
            if not valid:
                continue
            filters, h = _filters(p, 2, r, z[t], MMAE_FILTERS)
            bank = MMAEFilterBank(filters, np.full(MMAE_FILTERS, 1.0 / MMAE_FILTERS), dim_x=2 * p)
        elif valid:
            bank.update(z[t][:, None])
        if t + horizon < t_count:
            jump = np.kron(eye, transition((times[t + horizon] - times[t]) / time_unit, 2))
            out[t] = (h @ jump @ sum(w * kf.x for w, kf in zip(bank.p, filters)))[:, 0]
        if t + 1 < t_count:
            dt = (times[t + 1] - times[t]) / time_unit
            f, shape = np.kron(eye, transition(dt, 2)), np.kron(eye, process_noise_shape(dt, 2))
            for kf, qi in zip(filters, qs):
                kf.F, kf.Q = f, qi * shape
            bank.predict()
    return out


def tune_mmae(segments, *, unit: float, time_unit: float) -> dict:
    """The tuned CV filter's ``q`` and ``r``; the bank's spread (3, 10 or 30) by one-step RMS."""
    segments = check_segments(segments)
    cv = tune_cv(segments, unit=unit, time_unit=time_unit)
    pieces = tuning_rows(segments, TUNE_ROWS)
    fixed = {"process_noise": cv["process_noise"], "measurement_noise": cv["measurement_noise"],
             "time_unit": float(time_unit)}
    best, rms = grid_search({"spread": _MMAE_SPREADS}, lambda c: one_step_rms(
        pieces, [predict_mmae(z, t, {**c, **fixed}) for z, t, _ in pieces]))
    return {**best, **fixed, "tuning_rms": rms}
