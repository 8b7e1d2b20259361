"""Data of the paper's Figure 2 from one run of the mixture on the paper's scenario.

Panels: (a) the experts' gating weights :math:`g_{i,k}` over time, (b) the adaptive
learning rate :math:`\\eta_k`, (c) the diagonal elements of every expert's
:math:`Q_{i,k}`, (d) the absolute one-step prediction error of the mixture, pixels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["figure2", "PHASE_NAMES"]

#: Names of :attr:`kalmix.scenarios.Trajectory.phase` values.
PHASE_NAMES = {0: "accelerating curve", 1: "deceleration", 2: "small random moves"}


def figure2(seed: int = 0, *, n_experts: int = 40, scenario=None, **options: Any) -> dict[str, Any]:
    """Run the default mixture once and return the four panels' data.

    Parameters
    ----------
    seed : int
        Seed of the scenario and of the bank.
    n_experts : int
        K.
    scenario : PaperScenario, optional
        Template scenario (its seed is replaced).
    **options
        Other :func:`kalmix.bank.make_params` options (e.g. ``gating="paper"``).

    Returns
    -------
    dict with
        ``times`` (T,) s; ``phase`` (T,) int and ``phase_names``; ``phase_spans``
        [(name, start s, end s)]; ``speed`` (T,) m/s; ``weights`` (T, K);
        ``eta`` (T,); ``process_noise`` (T, K) (diagonal element of :math:`Q_i`, px²;
        the diagonal is the same for every coordinate); ``abs_error`` (T, 3) px, row
        ``t`` the error of the prediction of frame ``t`` (NaN at ``t = 0``);
        ``rms`` {"X", "Y"}; ``options``, ``seed``, ``n_experts``.
    """
    from ..predictor import MixturePredictor
    from .table1 import scenario_measurements

    trajectory, z = scenario_measurements(seed, scenario)
    result = MixturePredictor(n_experts, seed=seed, **options).run(z, diagnostics=True)
    abs_error = np.full(z.shape, np.nan)
    abs_error[1:] = np.abs(z[1:] - result.predictions[:-1])
    spans = []
    times = trajectory.times
    dt = float(times[1] - times[0]) if len(times) > 1 else 1.0
    for value in np.unique(trajectory.phase):
        where = np.flatnonzero(trajectory.phase == value)
        spans.append((PHASE_NAMES.get(int(value), str(value)), float(times[where[0]]), float(times[where[-1]] + dt)))
    x_err, y_err = abs_error[1:, :2], abs_error[1:, 2]
    return {
        "seed": int(seed),
        "n_experts": int(n_experts),
        "options": dict(options),
        "times": times,
        "phase": trajectory.phase,
        "phase_names": PHASE_NAMES,
        "phase_spans": spans,
        "speed": trajectory.speeds,
        "weights": result.weights,
        "eta": result.eta,
        "process_noise": result.process_noise[:, :, 0],
        "abs_error": abs_error,
        "rms": {"X": float(np.sqrt(np.nanmean(x_err**2))), "Y": float(np.sqrt(np.nanmean(y_err**2)))},
    }
