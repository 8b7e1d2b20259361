"""Peer predictors from other libraries, tuned fairly, for the comparison tables.

The main peer is filterpy's :class:`~filterpy.kalman.IMMEstimator` (interacting multiple
models) over a constant-velocity (CV) and a constant-acceleration (CA) Kalman filter.
Both models share one state so that the IMM can mix them: per measured coordinate
:math:`[\\text{pos}, \\text{vel}, \\text{acc}]`, the coordinates stacked
(:math:`n = 3p`); the CV model has zero-acceleration dynamics (its acceleration
component is reset to 0 by :math:`F`), the CA model integrates the acceleration.
Units are measurement units (pixels) and frames (:math:`\\Delta t = 1`).
:func:`imm_predictions` runs filterpy's IMM equations on arrays
(:mod:`kalmix.peer_models._batched`: many candidates and tracks in one pass, one Python
step per row); the test suite checks it against filterpy's ``IMMEstimator`` stepped row by
row (equal within rounding).

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

filterpy (extra ``peers``) is needed only to check :func:`imm_predictions` against it;
``kalmix evaluate`` shows the IMM row to users who have it.
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
    "imm_predictions_many",
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


#: The CV and CA models per coordinate on ``[pos, vel, acc]`` with Δt = 1 frame: ``F`` (the CV model resets the
#: acceleration) and ``Q / variance`` (filterpy's ``Q_discrete_white_noise`` with ``dim=2``, ``dim=3``).
_FRAME_F = np.array([[[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]],
                     [[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]]])
_FRAME_Q = np.array([[[0.25, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 0.0]],
                     [[0.25, 0.5, 0.5], [0.5, 1.0, 1.0], [0.5, 1.0, 1.0]]])


def _frame_models(dt):
    """``(F, Q / variance)`` of the CV and the CA model for each run of a batch (Δt is one frame)."""
    count = len(dt)
    return np.broadcast_to(_FRAME_F, (count, 2, 3, 3)), np.broadcast_to(_FRAME_Q, (count, 2, 3, 3))


def imm_predictions_many(pieces, candidates, length_unit: float = 1.0,
                         initial_variance: tuple[float, float, float] = (1.0, 100.0, 10.0), modes: bool = False):
    """:func:`imm_predictions` of each candidate on each piece, all in one batched pass: ``out[c][i]``.

    ``pieces`` are measurement arrays ``(T, p)`` (the same ``p``); ``candidates`` dicts of
    ``cv_process_noise, ca_process_noise, measurement_noise, switch_probability`` (as
    :func:`imm_predictions` takes them). With ``modes``, ``out[c][i]`` is ``(predictions,
    mode probabilities)``. The numbers are those of :func:`imm_predictions` run once per pair.
    """
    from .peer_models._batched import imm_run
    from .peer_models.kinematic import segment_batches

    pieces = [_check_measurements(z) for z in pieces]
    if len({z.shape[1] for z in pieces}) > 1:
        raise ValueError("measurements: expected the same number of coordinates in every piece, got several")
    _check_positive("length_unit", length_unit)
    for candidate in candidates:
        for name in ("cv_process_noise", "ca_process_noise", "measurement_noise"):
            _check_positive(name, candidate[name])
        if not 0.0 <= float(candidate["switch_probability"]) <= 1.0:
            raise ValueError(f"switch_probability: expected a number in [0, 1], got "
                             f"{candidate['switch_probability']!r}")
    if len(initial_variance) != 3:
        raise ValueError(f"initial_variance: expected 3 variances (pos, vel, acc), got {initial_variance!r}")
    for value in initial_variance:
        _check_positive("initial_variance", value)
    unit2 = float(length_unit) ** 2
    table = np.array([[c["cv_process_noise"] * unit2, c["ca_process_noise"] * unit2,
                       c["measurement_noise"] * unit2, float(c["switch_probability"])] for c in candidates])
    p0 = np.array([v * unit2 for v in initial_variance])
    out = [[None] * len(pieces) for _ in candidates]
    k = len(candidates)
    for batch in segment_batches([len(z) for z in pieces]):
        t_count, s_count = len(pieces[batch[0]]), len(batch)
        z = np.full((t_count, s_count, pieces[batch[0]].shape[1]), np.nan)
        for s, j in enumerate(batch):
            z[:len(pieces[j]), s] = pieces[j]
        column = np.repeat(np.arange(k), s_count)
        lengths = np.tile([len(pieces[j]) for j in batch], k)
        result = imm_run(np.tile(z, (1, k, 1)), lengths, _frame_models, table[column, :2], table[column, 2],
                         table[column, 3], np.broadcast_to(p0, (len(column), 3)), last_row=True, return_modes=modes)
        for c in range(k):
            for s, j in enumerate(batch):
                n, col = len(pieces[j]), c * s_count + s
                out[c][j] = (result[0][:n, col], result[1][:n, col]) if modes else result[:n, col]
    return out


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
    candidate = {"cv_process_noise": cv_process_noise, "ca_process_noise": ca_process_noise,
                 "measurement_noise": measurement_noise, "switch_probability": switch_probability}
    return imm_predictions_many([measurements], [candidate], length_unit, tuple(initial_variance),
                                modes=return_mode_probabilities)[0][0]


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
