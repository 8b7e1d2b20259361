"""Validation, scoring and row budgets shared by every peer of :mod:`kalmix.peer_models`."""

from __future__ import annotations

import itertools
import math
from typing import Callable, Iterable

import numpy as np

__all__ = ["check_segment", "check_segments", "check_horizon", "check_positive", "row_budget",
           "tuning_rows", "one_step_rms", "grid_search", "frame_steps"]


def check_segment(values, times, *, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """``values`` (T, p), p in 1..3, finite or NaN; ``times`` (T,) finite, strictly increasing."""
    z = np.asarray(values, dtype=float)
    if z.ndim == 1:
        z = z[:, None]
    if z.ndim != 2 or not 1 <= z.shape[1] <= 3:
        raise ValueError(f"values{where}: expected shape (T, p) with p in 1..3, got {np.shape(values)}")
    if np.isinf(z).any():
        raise ValueError(f"values{where}: expected finite numbers or NaN (missing), got an infinity")
    t = np.asarray(times, dtype=float)
    if t.shape != (z.shape[0],):
        raise ValueError(f"times{where}: expected shape ({z.shape[0]},) like values, got {np.shape(times)}")
    if not np.isfinite(t).all():
        raise ValueError(f"times{where}: expected finite numbers, got NaN or infinity")
    if t.size > 1 and not (np.diff(t) > 0).all():
        row = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ValueError(f"times{where}: expected strictly increasing times, got {float(t[row])!r} at row {row} "
                         f"after {float(t[row - 1])!r}")
    return z, t


def check_segments(segments) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A list of ``(values, times, mask)``; every segment has the same number of coordinates."""
    if isinstance(segments, (str, bytes)) or not isinstance(segments, Iterable):
        raise ValueError(f"segments: expected a list of (values, times, mask), got {type(segments).__name__}")
    out = []
    for i, segment in enumerate(segments):
        if len(segment) != 3:
            raise ValueError(f"segments[{i}]: expected (values, times, mask), got {len(segment)} items")
        z, t = check_segment(segment[0], segment[1], where=f" of segments[{i}]")
        mask = np.asarray(segment[2])
        if mask.shape != t.shape or mask.dtype != bool:
            raise ValueError(f"mask of segments[{i}]: expected a bool array of shape {t.shape}, "
                             f"got {mask.dtype} {mask.shape}")
        if out and z.shape[1] != out[0][0].shape[1]:
            raise ValueError(f"values of segments[{i}]: expected {out[0][0].shape[1]} coordinates like "
                             f"segments[0], got {z.shape[1]}")
        out.append((z, t, mask))
    if not out or not any(m[1:].any() for _, _, m in out):
        raise ValueError("segments: expected at least one tuning row (mask True) after a segment's first row, got none")
    return out


def check_horizon(horizon) -> int:
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise ValueError(f"horizon: expected an integer >= 1, got {horizon!r}")
    return int(horizon)


def check_positive(name: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}") from None
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
    return number


def row_budget(lengths, max_rows: int | None) -> np.ndarray:
    """Rows to keep from the start of each segment so that at most ``max_rows`` are kept in all.

    Deterministic: the first ``n`` rows of every segment (all of a shorter one), ``n`` the
    largest count whose total stays within ``max_rows``. ``None`` keeps everything.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    if max_rows is None or lengths.sum() <= max_rows:
        return lengths.copy()
    low, high = 0, int(lengths.max())
    while low < high:  # largest n with sum(min(lengths, n)) <= max_rows
        mid = (low + high + 1) // 2
        low, high = (mid, high) if np.minimum(lengths, mid).sum() <= max_rows else (low, mid - 1)
    return np.minimum(lengths, low)


def tuning_rows(segments, max_rows: int | None = None):
    """Each segment cut after its last tuning row, then :func:`row_budget` over what is left."""
    cut = [(z[:n], t[:n], m[:n]) for z, t, m in segments
           for n in [int(np.flatnonzero(m).max()) + 1 if m.any() else 0] if n > 1]
    keep = row_budget([len(t) for _, t, _ in cut], max_rows)
    return [(z[:n], t[:n], m[:n]) for (z, t, m), n in zip(cut, keep) if n > 1]


def one_step_rms(segments, predictions) -> float:
    """RMS of ``values[t + 1] - predictions[t]`` over rows ``t + 1`` in the mask (inf if any is NaN)."""
    total, count = 0.0, 0
    for (z, _, mask), pred in zip(segments, predictions):
        target = mask[1:] & np.isfinite(z[1:]).all(axis=1)
        errors = z[1:][target] - pred[:-1][target]
        started = np.isfinite(z).all(axis=1).cumsum()[:-1][target] > 0  # a prediction exists
        errors = errors[started]
        if not np.isfinite(errors).all():
            return math.inf
        total += float(np.sum(errors**2))
        count += errors.size
    return math.sqrt(total / count) if count else math.inf


def grid_search(grid: dict[str, tuple[float, ...]], score: Callable[[dict], float]) -> tuple[dict, float]:
    """The candidate (product of ``grid``'s values) with the lowest finite ``score``; first wins ties."""
    names = list(grid)
    best, best_score = None, math.inf
    for values in itertools.product(*(grid[name] for name in names)):
        candidate = {name: float(value) for name, value in zip(names, values)}
        value = score(candidate)
        if best is None or value < best_score:
            best, best_score = candidate, value
    if not math.isfinite(best_score):
        raise ValueError("segments: every candidate of the grid gave non-finite predictions on the tuning rows")
    return best, best_score


def frame_steps(valid: np.ndarray, horizon: int) -> np.ndarray:
    """For each row ``t``: rows from the last valid row ``<= t`` to ``t + horizon`` (-1 before any)."""
    rows = np.arange(valid.size)
    last = np.maximum.accumulate(np.where(valid, rows, -1))
    return np.where(last >= 0, rows + horizon - last, -1)
