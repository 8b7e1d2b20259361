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
``tune_ca``); see :func:`tune_imm` and :func:`tune_mmae`. Tuning uses at most
:data:`TUNE_ROWS` rows (the first rows of each segment's tuning part,
:func:`~kalmix.peer_models._common.tuning_rows`).

filterpy's objects step one filter at a time in Python; here their equations run on arrays
(:mod:`~kalmix.peer_models._batched`), every grid candidate and every segment in one pass
with one Python step per row. The test suite checks the predictions against filterpy's
``IMMEstimator`` and ``MMAEFilterBank`` stepped row by row (equal within rounding) and the
tuning's choice against a grid search over them.
"""

from __future__ import annotations

import numpy as np

from ._batched import batched_search, imm_run, mmae_run, one_candidate, over_candidates, steps
from ._common import check_positive, check_segments, tuning_rows
from .kinematic import INITIAL_VARIANCE_RATIO, process_noise_shape, transition, tune_ca, tune_cv

__all__ = ["TUNE_ROWS", "MMAE_FILTERS", "tune_imm", "predict_imm", "predict_many_imm", "tune_mmae", "predict_mmae",
           "predict_many_mmae"]

#: Rows of the tuning part scored per candidate.
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


def _imm_models(dt):
    """Per coordinate, ``(F, Q / q)`` of the CV and the CA model on the shared ``[pos, vel, acc]`` state:
    each ``(len(dt), 2, 3, 3)``."""
    f_cv = transition(dt, 3)
    f_cv[..., 1, 2] = f_cv[..., 0, 2] = f_cv[..., 2, 2] = 0.0
    shape_cv = np.zeros(np.shape(dt) + (3, 3))
    shape_cv[..., :2, :2] = process_noise_shape(dt, 2)
    return (np.stack([f_cv, transition(dt, 3)], axis=-3),
            np.stack([shape_cv, process_noise_shape(dt, 3)], axis=-3))


def _imm_params(params):
    q_cv, q_ca, r, s, time_unit = _read(params, ("cv_process_noise", "ca_process_noise", "measurement_noise",
                                                 "switch_probability", "time_unit"))
    if s >= 1:
        raise ValueError(f"params['switch_probability']: expected a number in (0, 1), got {s!r}")
    return q_cv, q_ca, r, s, time_unit


def _predict_imm_many(segments, candidates, horizon):
    """IMM predictions of each candidate ``(q_cv, q_ca, r, s, time_unit)`` on each segment
    (:func:`~._batched.over_candidates`)."""
    table = np.array(candidates, dtype=float)

    def run(z, times, lengths, column):
        q_cv, q_ca, r, s, time_unit = table[column].T
        initial = r[:, None] * np.array([1.0, INITIAL_VARIANCE_RATIO, INITIAL_VARIANCE_RATIO])
        return imm_run(z, lengths, _imm_models, np.stack([q_cv, q_ca], -1), r, s, initial,
                       dt=steps(times) / time_unit, horizon=horizon)

    return over_candidates(segments, candidates, run)


def predict_imm(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the IMM's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    candidate = _imm_params(params)
    return one_candidate(_predict_imm_many, candidate, [(values, times)], horizon, single=True)[0]


def predict_many_imm(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict_imm` over a list of ``(values, times)`` in one batched pass."""
    candidate = _imm_params(params)
    return one_candidate(_predict_imm_many, candidate, segments, horizon)


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
    best, rms = batched_search(grid, pieces, lambda candidates: _predict_imm_many(
        [(z, t) for z, t, _ in pieces], [_imm_params({**c, **fixed}) for c in candidates], 1))
    return {**best, **fixed, "tuning_rms": rms}


def _mmae_params(params):
    return tuple(_read(params, ("process_noise", "spread", "measurement_noise", "time_unit")))


def _predict_mmae_many(segments, candidates, horizon):
    """MMAE predictions of each candidate ``(q, spread, r, time_unit)`` on each segment
    (:func:`~._batched.over_candidates`)."""
    table = np.array(candidates, dtype=float)
    qs = np.array([q * spread ** (np.arange(MMAE_FILTERS) - MMAE_FILTERS // 2) for q, spread, _, _ in candidates])

    def run(z, times, lengths, column):
        r, time_unit = table[column, 2], table[column, 3]
        initial = r[:, None] * np.array([1.0, INITIAL_VARIANCE_RATIO])
        return mmae_run(z, lengths, qs[column], r, initial, lambda d: transition(d, 2),
                        lambda d: process_noise_shape(d, 2), dt=steps(times) / time_unit,
                        tau=steps(times, horizon) / time_unit)

    return over_candidates(segments, candidates, run)


def predict_mmae(values, times, params: dict, horizon: int = 1) -> np.ndarray:
    """Row ``t``: the MMAE bank's open-loop prediction of row ``t + horizon`` from rows ``<= t``."""
    candidate = _mmae_params(params)
    return one_candidate(_predict_mmae_many, candidate, [(values, times)], horizon, single=True)[0]


def predict_many_mmae(segments, params: dict, horizon: int = 1) -> list[np.ndarray]:
    """:func:`predict_mmae` over a list of ``(values, times)`` in one batched pass."""
    candidate = _mmae_params(params)
    return one_candidate(_predict_mmae_many, candidate, segments, horizon)


def tune_mmae(segments, *, unit: float, time_unit: float) -> dict:
    """The tuned CV filter's ``q`` and ``r``; the bank's spread (3, 10 or 30) by one-step RMS."""
    segments = check_segments(segments)
    cv = tune_cv(segments, unit=unit, time_unit=time_unit)
    pieces = tuning_rows(segments, TUNE_ROWS)
    fixed = {"process_noise": cv["process_noise"], "measurement_noise": cv["measurement_noise"],
             "time_unit": float(time_unit)}
    best, rms = batched_search({"spread": _MMAE_SPREADS}, pieces, lambda candidates: _predict_mmae_many(
        [(z, t) for z, t, _ in pieces], [_mmae_params({**c, **fixed}) for c in candidates], 1))
    return {**best, **fixed, "tuning_rms": rms}
