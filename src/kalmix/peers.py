"""Peer predictors from other libraries, tuned fairly, for the comparison tables.

The main peer is filterpy's :class:`~filterpy.kalman.IMMEstimator` (interacting multiple
models) over a constant-velocity (CV) and a constant-acceleration (CA) Kalman filter.
Both models share one state so that the IMM can mix them: per measured coordinate
:math:`[\\text{pos}, \\text{vel}, \\text{acc}]`, the coordinates stacked
(:math:`n = 3p`); the CV model has zero-acceleration dynamics (its acceleration
component is reset to 0 by :math:`F`), the CA model integrates the acceleration.
Units are measurement units (pixels) and frames (:math:`\\Delta t = 1`).

Fair tuning
-----------
Every peer's noise levels are chosen by a small grid search that minimises the
one-step prediction RMS on a **separate tuning scenario**
(``PaperScenario(seed=TUNING_SEED)``, seed 1000), never on the evaluation seeds
(0, 1, 2, ... in ``kalmix reproduce``). :func:`tune` (IMM) and :func:`tune_fixed`
(the CV/CA Kalman peers of :mod:`kalmix.baselines`) run that search; the module
constants :data:`IMM_DEFAULTS`, :data:`CV_DEFAULTS` and :data:`CA_DEFAULTS` hold
their results (re-run ``python -m kalmix.peers [imm] [cv] [ca]`` to reproduce them). The
IMM was searched in three stages of about a hundred runs each, each stage centred on the
previous optimum until it lay inside the grid (:data:`IMM_COARSE_GRID`,
:data:`IMM_FINE_GRID`, :data:`IMM_GRID`); the fixed CV/CA filters over :data:`FIXED_GRID`.
The mixture gets no such search on this scenario: its defaults are the bank recipe of
:func:`kalmix.bank.make_params`, and the single AKF is fixed in advance (:mod:`kalmix.baselines`). The
tuning scenario shares the deterministic curve of the evaluation scenarios (only the
random moves and the pixel noise differ), which if anything favours the tuned peers.

On your own data, tune on a separate part of it: ``imm_predictions(test, **tune(train)["best"])``.

filterpy is an optional dependency (extra ``peers``); it is imported inside the
functions that need it.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

__all__ = [
    "TUNING_SEED",
    "IMM_DEFAULTS",
    "CV_DEFAULTS",
    "CA_DEFAULTS",
    "IMM_COARSE_GRID",
    "IMM_FINE_GRID",
    "IMM_GRID",
    "FIXED_GRID",
    "imm_predictions",
    "tune",
    "tune_fixed",
    "tuning_measurements",
    "one_step_rms",
]

#: Seed of the tuning scenario; the evaluation seeds of ``kalmix reproduce`` start at 0.
TUNING_SEED = 1000

#: Tuned on ``PaperScenario(seed=TUNING_SEED)`` by :func:`tune` in three stages
#: (:data:`IMM_COARSE_GRID`, :data:`IMM_FINE_GRID`, :data:`IMM_GRID`); the last optimum is
#: inside its grid on every axis.
IMM_DEFAULTS: dict[str, float] = {
    "cv_process_noise": 0.3,
    "ca_process_noise": 3.0,
    "measurement_noise": 0.5,
    "switch_probability": 0.03,
}
#: Tuned by :func:`tune_fixed` for :func:`kalmix.baselines.cv_kalman` over :data:`FIXED_GRID`.
#: Optimum at the grid's corner (q/r = 1e5), where the RMS is flat: the limit of a gain of one,
#: i.e. :math:`\hat z_{k+1} = 2 z_k - z_{k-1}`.
CV_DEFAULTS: dict[str, float] = {"process_noise": 1000.0, "measurement_noise": 0.01}
#: Tuned by :func:`tune_fixed` for :func:`kalmix.baselines.ca_kalman` over :data:`FIXED_GRID`.
CA_DEFAULTS: dict[str, float] = {"process_noise": 0.1, "measurement_noise": 0.05}

#: First, coarse stage of the IMM search (4 x 4 x 3 x 3 = 144 runs); its optimum on the
#: tuning seed is cv 1, ca 10, r 1, switch 0.01, on two edges of the grid.
IMM_COARSE_GRID: dict[str, tuple[float, ...]] = {
    "cv_process_noise": (0.1, 1.0, 10.0, 100.0),
    "ca_process_noise": (0.01, 0.1, 1.0, 10.0),
    "measurement_noise": (0.05, 0.25, 1.0),
    "switch_probability": (0.01, 0.05, 0.2),
}
#: Second stage, beyond the coarse optimum (3 x 4 x 4 x 3 = 144 runs); optimum cv 0.3, ca 3,
#: r 0.5, switch 0.03, again on edges.
IMM_FINE_GRID: dict[str, tuple[float, ...]] = {
    "cv_process_noise": (0.3, 1.0, 3.0),
    "ca_process_noise": (3.0, 10.0, 30.0, 100.0),
    "measurement_noise": (0.5, 1.0, 2.0, 4.0),
    "switch_probability": (0.003, 0.01, 0.03),
}
#: Third stage, centred on the second optimum (3 x 3 x 3 x 3 = 81 runs): the grid of :func:`tune`.
IMM_GRID: dict[str, tuple[float, ...]] = {
    "cv_process_noise": (0.1, 0.3, 1.0),
    "ca_process_noise": (1.0, 3.0, 10.0),
    "measurement_noise": (0.25, 0.5, 1.0),
    "switch_probability": (0.01, 0.03, 0.1),
}
#: Grid of :func:`tune_fixed` (13 x 4 = 52 runs per model).
FIXED_GRID: dict[str, tuple[float, ...]] = {
    "process_noise": tuple(float(v) for v in np.geomspace(1e-3, 1e3, 13)),
    "measurement_noise": (0.01, 0.05, 0.25, 1.0),
}


def _check_measurements(measurements) -> np.ndarray:
    array = np.asarray(measurements, dtype=float)
    if array.ndim != 2 or array.shape[1] < 1:
        raise ValueError(f"measurements: expected shape (T, p), got {array.shape}")
    if np.isinf(array).any():
        raise ValueError("measurements: expected finite numbers or NaN (missing), got an infinity")
    return array


def _check_positive(name: str, value) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
    return value


def _models(p: int, cv_process_noise: float, ca_process_noise: float, measurement_noise: float,
            initial_variance: tuple[float, float, float]):
    """The CV and CA filterpy KalmanFilters on the shared state ``[pos, vel, acc] x p``."""
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import KalmanFilter
    from scipy.linalg import block_diag

    f_cv = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    f_ca = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    q_cv = np.zeros((3, 3))
    q_cv[:2, :2] = Q_discrete_white_noise(dim=2, dt=1.0, var=cv_process_noise)
    q_ca = Q_discrete_white_noise(dim=3, dt=1.0, var=ca_process_noise)
    h = np.zeros((p, 3 * p))
    h[np.arange(p), 3 * np.arange(p)] = 1.0
    filters = []
    for f, q in ((f_cv, q_cv), (f_ca, q_ca)):
        kf = KalmanFilter(dim_x=3 * p, dim_z=p)
        kf.F = block_diag(*([f] * p))
        kf.Q = block_diag(*([q] * p))
        kf.H = h.copy()
        kf.R = np.eye(p) * measurement_noise
        kf.P = np.diag(np.tile(initial_variance, p))
        filters.append(kf)
    return filters, h


def imm_predictions(
    measurements,
    *,
    cv_process_noise: float = IMM_DEFAULTS["cv_process_noise"],
    ca_process_noise: float = IMM_DEFAULTS["ca_process_noise"],
    measurement_noise: float = IMM_DEFAULTS["measurement_noise"],
    switch_probability: float = IMM_DEFAULTS["switch_probability"],
    initial_variance: tuple[float, float, float] = (1.0, 100.0, 10.0),
    length_unit: float = 1.0,
    return_mode_probabilities: bool = False,
):
    """One-step predictions of filterpy's IMM over a CV and a CA Kalman filter.

    Parameters
    ----------
    measurements : array_like, shape (T, p)
        A row with a NaN is a missing measurement: the IMM only predicts (and its mode
        probabilities are propagated through the Markov chain).
    cv_process_noise : float
        Variance of the CV model's discrete white-noise acceleration
        (units² / frame⁴, filterpy ``Q_discrete_white_noise(dim=2)``).
    ca_process_noise : float
        Variance of the CA model's discrete white-noise jerk (``Q_discrete_white_noise(dim=3)``).
    measurement_noise : float
        :math:`R = r I` (units²).
    switch_probability : float
        Probability of switching model between frames (the Markov matrix is
        ``[[1 - s, s], [s, 1 - s]]``).
    initial_variance : (float, float, float)
        Initial variances of position, velocity and acceleration (units², per frame).
    length_unit : float
        Scale of the measurement unit relative to the pixels the defaults were tuned on:
        every variance above is multiplied by ``length_unit**2`` (use e.g. 0.001 for
        metre data with millimetre noise).
    return_mode_probabilities : bool
        Also return the predicted mode probabilities ``(T, 2)`` (CV, CA).

    Returns
    -------
    predictions : ndarray, shape (T, p)
        Row ``t`` predicts row ``t + 1`` (NaN before the first measurement). It is the
        IMM's predicted measurement :math:`H \\sum_j \\bar c_j \\hat x_j^-`, weighted by
        the predicted mode probabilities :math:`\\bar c = \\mu M`.
    mode_probabilities : ndarray, shape (T, 2), only if requested
    """
    from filterpy.kalman import IMMEstimator

    z = _check_measurements(measurements)
    unit2 = _check_positive("length_unit", length_unit) ** 2
    cv_q = _check_positive("cv_process_noise", cv_process_noise) * unit2
    ca_q = _check_positive("ca_process_noise", ca_process_noise) * unit2
    r = _check_positive("measurement_noise", measurement_noise) * unit2
    s = float(switch_probability)
    if not 0.0 <= s <= 1.0:
        raise ValueError(f"switch_probability: expected a number in [0, 1], got {switch_probability!r}")
    p0 = tuple(_check_positive("initial_variance", v) * unit2 for v in initial_variance)
    if len(p0) != 3:
        raise ValueError(f"initial_variance: expected 3 variances (pos, vel, acc), got {initial_variance!r}")
    t_count, p = z.shape
    filters, h = _models(p, cv_q, ca_q, r, p0)
    transition = np.array([[1.0 - s, s], [s, 1.0 - s]])
    imm = IMMEstimator(filters, [0.5, 0.5], transition)
    predictions = np.full((t_count, p), np.nan)
    modes = np.full((t_count, 2), np.nan)
    started = False
    for t in range(t_count):
        row = z[t]
        valid = bool(np.isfinite(row).all())
        if not started:
            if not valid:
                continue
            x0 = np.zeros((3 * p, 1))  # filterpy keeps column vectors
            x0[0::3, 0] = row
            for kf in filters:
                kf.x = x0.copy()
                kf.P = np.diag(np.tile(p0, p))
            started = True
        elif valid:
            imm.update(row)
        else:  # missing: the mode probabilities only go through the Markov chain
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
        imm.predict()
        mixed = sum(c * kf.x for c, kf in zip(imm.cbar, filters))
        predictions[t] = (h @ mixed)[:, 0]
        modes[t] = imm.cbar
    return (predictions, modes) if return_mode_probabilities else predictions


def one_step_rms(predictions: np.ndarray, measurements: np.ndarray) -> float:
    """RMS over every coordinate of ``measurements[t + 1] - predictions[t]`` (NaN ignored)."""
    errors = np.asarray(measurements)[1:] - np.asarray(predictions)[:-1]
    errors = errors[np.isfinite(errors)]
    return float(np.sqrt(np.mean(errors**2))) if errors.size else float("nan")


def tuning_measurements(seed: int = TUNING_SEED) -> np.ndarray:
    """Measurements of the paper's scenario on the tuning seed (never an evaluation seed)."""
    from .scenarios import PaperScenario, paper_measurements

    return paper_measurements(PaperScenario(seed=seed))[1].measured


def _grid(grid: dict[str, tuple[float, ...]]):
    names = list(grid)
    for values in itertools.product(*(grid[name] for name in names)):
        yield dict(zip(names, values))


def tune(measurements=None, grid: dict[str, tuple[float, ...]] | None = None, **fixed: Any) -> dict[str, Any]:
    """Grid search of the IMM's noise levels on ``measurements`` (one-step RMS).

    Parameters
    ----------
    measurements : array_like (T, p), optional
        Tuning data; default :func:`tuning_measurements` (the tuning seed). When you
        evaluate on your own data, tune on a separate part of it.
    grid : dict, optional
        Values to try for each keyword of :func:`imm_predictions`; default :data:`IMM_GRID`.
    **fixed
        Other keywords passed to :func:`imm_predictions` unchanged.

    Returns
    -------
    dict
        ``{"best": {parameter: value}, "rms": best RMS, "results": [(parameters, rms), ...]}``;
        pass ``**result["best"]`` to :func:`imm_predictions`.
    """
    z = tuning_measurements() if measurements is None else _check_measurements(measurements)
    grid = IMM_GRID if grid is None else grid
    results = [(candidate, one_step_rms(imm_predictions(z, **candidate, **fixed), z)) for candidate in _grid(grid)]
    best, rms = min(results, key=lambda item: item[1] if np.isfinite(item[1]) else np.inf)
    return {"best": best, "rms": rms, "results": results}


def tune_fixed(model: str, measurements=None, grid: dict[str, tuple[float, ...]] | None = None,
               **options: Any) -> dict[str, Any]:
    """Grid search of a fixed CV or CA Kalman peer (:mod:`kalmix.baselines`) on ``measurements``.

    Parameters
    ----------
    model : {"cv", "ca"}
    measurements, grid
        As for :func:`tune`; default grid :data:`FIXED_GRID`.
    **options
        Passed to :func:`kalmix.baselines.cv_kalman` / :func:`~kalmix.baselines.ca_kalman`.
    """
    from . import baselines

    factories = {"cv": baselines.cv_kalman, "ca": baselines.ca_kalman}
    if model not in factories:
        raise ValueError(f"model: expected 'cv' or 'ca', got {model!r}")
    z = tuning_measurements() if measurements is None else _check_measurements(measurements)
    grid = FIXED_GRID if grid is None else grid
    results = []
    for candidate in _grid(grid):
        predictions = factories[model](**candidate, **options).run(z, diagnostics=False).predictions
        results.append((candidate, one_step_rms(predictions, z)))
    best, rms = min(results, key=lambda item: item[1] if np.isfinite(item[1]) else np.inf)
    return {"best": best, "rms": rms, "results": results}


if __name__ == "__main__":  # pragma: no cover - the tuning run that produced the defaults
    import argparse

    parser = argparse.ArgumentParser(prog="python -m kalmix.peers",
                                     description="Re-run the tuning of the peers' defaults on the paper scenario.")
    parser.add_argument("peers", nargs="*", choices=["imm", "cv", "ca"], default=["imm", "cv", "ca"],
                        help="which peers to tune (default: all three)")
    which = parser.parse_args().peers
    data = tuning_measurements()
    tuners = {"imm": lambda: tune(data), "cv": lambda: tune_fixed("cv", data), "ca": lambda: tune_fixed("ca", data)}
    for name in which:
        result = tuners[name]()
        print(name, result["best"], f"rms {result['rms']:.4f}")
