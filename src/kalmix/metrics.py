"""Prediction-error tables: mean of |e|, standard deviation, maximum and RMS."""

from __future__ import annotations

import numpy as np

__all__ = ["prediction_errors", "error_summary", "paper_axes_summary"]


def prediction_errors(predictions: np.ndarray, measurements: np.ndarray, horizon: int = 1) -> np.ndarray:
    """Errors ``measurements[t + H] - predictions[t]``, shape ``(T - H, ...)``; NaN where either is missing."""
    return measurements[horizon:] - predictions[:-horizon]


def error_summary(errors: np.ndarray) -> dict[str, float]:
    """Summary of the absolute errors, pooling every finite entry of ``errors``.

    Returns ``{"mean_abs", "std", "max", "rms", "count"}``; ``std`` is the standard
    deviation of the absolute error (what the paper's Table 1 reports).
    """
    values = np.abs(np.asarray(errors, dtype=float)).ravel()
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"mean_abs": float("nan"), "std": float("nan"), "max": float("nan"), "rms": float("nan"), "count": 0}
    with np.errstate(over="ignore", invalid="ignore"):
        summary = {"mean_abs": float(values.mean()), "std": float(values.std()), "max": float(values.max()),
                   "rms": float(np.sqrt(np.mean(values**2))), "count": int(values.size)}
        top = summary["max"]
        if top > 0 and not all(np.isfinite(summary[k]) for k in ("mean_abs", "std", "rms")):
            # errors near 1e300 (a glitch): their squares (or sums) overflow to inf, though the figures do not;
            # taken on the errors / their largest (only then: elsewhere the plain formulas' bits)
            scaled = values / top
            summary.update(mean_abs=float(top * scaled.mean()), std=float(top * scaled.std()),
                           rms=float(top * np.sqrt(np.mean(scaled**2))))
    return summary


def paper_axes_summary(errors: np.ndarray) -> dict[str, dict[str, float]]:
    """Table-1 summary of stereo feature errors ``(..., 3)``: X pools u_left and u_right, Y is v."""
    return {"X": error_summary(errors[..., :2]), "Y": error_summary(errors[..., 2])}
