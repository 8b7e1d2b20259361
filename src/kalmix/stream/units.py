"""Length and time units of tracks: the noise size the bank's grid is scaled to, and the typical sampling interval
(re-exported by :mod:`kalmix.streaming`)."""

from __future__ import annotations

import math

import numpy as np


def auto_length_unit(values, *, minimum_samples: int = 8, times=None) -> float:
    """Typical measurement-noise size of tracks, from their second differences.

    For white measurement noise of standard deviation :math:`\\sigma` on a smooth
    path, :math:`\\Delta^2 z_k = z_{k+1} - 2 z_k + z_{k-1}` has standard deviation
    :math:`\\sqrt 6 \\sigma`; the robust estimate is

    .. math:: u = \\frac{\\operatorname{median} |\\Delta^2 z|}{0.6745 \\sqrt 6}

    pooled over every coordinate and track (NaN-containing triples skipped). Real
    acceleration inflates it, so it is an upper bound of the noise, which is what
    the bank's noise grid needs (its levels span 0.2–2.2 units). Quantised data
    (many exact zeros) can give 0: the fallback is the median of the non-zero
    :math:`|\\Delta^2 z|`, and 1 when the data has no second differences at all.

    With ``times``, a triple whose two steps :math:`h_1, h_2` differ (irregular sampling)
    uses the difference that uniform motion leaves at 0 whatever the steps,
    :math:`h_1 (z_{k+1} - z_k) - h_2 (z_k - z_{k-1})`, scaled to the same noise size
    (times :math:`\\sqrt 6 / \\sqrt{h_1^2 + h_2^2 + (h_1 + h_2)^2}`); a triple of equal steps
    is :math:`|\\Delta^2 z|` as above. (Without it, a target at 5 m/s sampled every 5 to 60 s
    reads its speed times the steps' differences as noise.)

    Parameters
    ----------
    values : ndarray, shape (T, p) or (T, N, p)
        Tracks on their sample index (NaN for missing or padding).
    times : ndarray, shape (T,) or (T, N), optional
        Each sample's time (NaN for padding); None: the samples are taken as evenly spaced.

    Returns
    -------
    float
        The ``length_unit`` to pass to :func:`kalmix.bank.make_params`.
    """
    unit, _ = length_unit_rule(values, minimum_samples, times=times)
    return unit


def length_unit_rule(values, minimum_samples: int = 8, *, times=None) -> tuple[float, str | None]:
    """:func:`auto_length_unit` and, when it fell back to 1, why (else None)."""
    try:
        z = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"values: expected numbers, shape (T, p) or (T, N, p), got {values!r:.80}") from None
    if z.ndim == 2:
        z = z[:, None, :]
    if z.ndim != 3:
        raise ValueError(f"values: expected shape (T, p) or (T, N, p) (rows, [tracks,] coordinates), got {z.shape}")
    if z.shape[0] < 3:
        return 1.0, "fewer than 3 samples of a track to estimate it from"
    with np.errstate(over="ignore", invalid="ignore"):  # values near 1e308: those triples are skipped
        second = np.abs(z[2:] - 2.0 * z[1:-1] + z[:-2])
        if times is not None:
            second = _time_aware(second, z, times)
        second = second.ravel()
    second = second[np.isfinite(second)]
    if second.size < minimum_samples:
        return 1.0, f"only {second.size} second difference(s) to estimate it from (it needs {minimum_samples})"
    scale = 0.6745 * math.sqrt(6.0)
    unit = float(np.median(second)) / scale
    if unit <= 0:
        nonzero = second[second > 0]
        if not nonzero.size:
            return 1.0, "second differences that are all 0 (positions constant, or exactly on a line)"
        unit = float(np.median(nonzero)) / scale
    return unit, None


def _time_aware(second, z, times):
    """:func:`length_unit_rule`'s second differences ``second`` (T-2, N, p) of ``z``, those of triples with unequal
    steps replaced by the time-aware difference (see :func:`auto_length_unit`); a triple without two positive
    finite steps keeps its second difference."""
    try:
        t = np.asarray(times, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"times: expected numbers, shape (T,) or (T, N), got {times!r:.80}") from None
    if t.ndim == 1:
        t = t[:, None]
    if t.shape != z.shape[:2]:
        raise ValueError(f"times: expected shape {z.shape[:2]} (rows, tracks) as the values', got {t.shape}")
    h1, h2 = (t[1:-1] - t[:-2])[..., None], (t[2:] - t[1:-1])[..., None]
    usable = np.isfinite(h1) & np.isfinite(h2) & (h1 > 0) & (h2 > 0)
    equal = np.abs(h1 - h2) <= 1e-9 * np.maximum(h1, h2)
    weighted = (np.abs(h1 * (z[2:] - z[1:-1]) - h2 * (z[1:-1] - z[:-2])) * math.sqrt(6.0)
                / np.sqrt(h1 * h1 + h2 * h2 + (h1 + h2) ** 2))
    return np.where(usable & ~equal, weighted, second)


def auto_time_unit(times) -> float:
    """Typical sampling interval: the median of the positive time steps of every track.

    Parameters
    ----------
    times : ndarray, shape (T,) or (T, N)
        Time stamps of each track on its sample index (NaN for padding).

    Returns
    -------
    float
        The ``time_unit`` of :func:`kalmix.bank.make_bank` (1 when there is no positive step).
    """
    t = np.asarray(times, dtype=np.float64)
    if t.ndim == 1:
        t = t[:, None]
    steps = np.diff(t, axis=0).ravel()
    steps = steps[np.isfinite(steps) & (steps > 0)]
    return float(np.median(steps)) if steps.size else 1.0


#: Time steps are heavy-tailed when the top tenth of them is over this many times their median: reports every few
#: seconds to every few minutes (AIS: about 17; steps log-uniform over a range of 60: 5). Regular sampling, jittered,
#: with gaps, or with frames dropped at random (at most 3.3 for any drop rate) stays under it.
IRREGULAR_TAIL = 4.0
#: Time steps it takes to tell heavy-tailed sampling (fewer: a single silence would be a tenth of them).
IRREGULAR_MIN_STEPS = 50
#: The reach (time units) ``reach="auto"`` takes on heavy-tailed steps; other data: none.
IRREGULAR_REACH = 1.5


def reach_for_steps(steps) -> float | None:
    """The reach ``"auto"`` takes from time steps (positive, any order): :data:`IRREGULAR_REACH` time units when
    they are heavy-tailed (their 90th percentile over :data:`IRREGULAR_TAIL` times their median), else None.

    On tracks reported every few seconds to every few minutes the one-step weights learn mostly on
    the usual steps, where an expert that extrapolates a fitted acceleration, velocity model or
    turn does well, and the same expert misses by orders of magnitude across a step many times
    longer; the reach keeps only the constant-velocity experts there (:func:`kalmix.bank.make_bank`).
    Where the long steps are a few usual ones (frames dropped at random, a gap the gap rule
    restarts at, missed rows), those experts still do better than the constant velocity, so every
    expert is kept.
    """
    return None if heavy_tail(steps) is None else IRREGULAR_REACH


def heavy_tail(steps) -> float | None:
    """The 90th percentile of time steps (positive, any order) when it is over :data:`IRREGULAR_TAIL` times their
    median (heavy-tailed sampling), else None (and with fewer than :data:`IRREGULAR_MIN_STEPS` steps)."""
    steps = np.asarray(steps, dtype=np.float64).ravel()
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if steps.size < IRREGULAR_MIN_STEPS:
        return None
    median, top = np.quantile(steps, [0.5, 0.9])
    return float(top) if top > IRREGULAR_TAIL * median else None


def gap_floor_for_steps(steps, factor: float) -> float | None:
    """The gap floor ``"auto"`` takes from time steps: on heavy-tailed sampling (:func:`heavy_tail`) ``factor``
    (the gap rule's ``max_gap_factor``) times their 90th percentile, a step the sampling itself makes often
    being no gap however short a young track's first steps were; else None (the track's own steps decide)."""
    top = heavy_tail(steps)
    return None if top is None or not math.isfinite(factor) else float(factor * top)


def auto_reach(times) -> float | None:
    """:func:`reach_for_steps` of the positive time steps of every track (``times`` as :func:`auto_time_unit`'s)."""
    t = np.asarray(times, dtype=np.float64)
    if t.ndim == 1:
        t = t[:, None]
    return reach_for_steps(np.diff(t, axis=0))


class LengthUnitWarning(UserWarning):
    """``length_unit="auto"`` fell back to 1: nothing to estimate it from (the text says why, as ``kalmix predict``'s
    note does); pass a ``length_unit``."""


def length_unit_fallback(why: str | None, where: str, option: str, unit: str = "") -> str:
    """The note (``kalmix predict``'s) and warning text (the Python API's) of a length unit that fell back to 1:
    ``why`` the rule could not estimate it from ``where`` (None: ``where`` has no sample at all); ``option``
    the setting to pass; ``unit`` the unit's name after the 1 (`` m`` for geographic data)."""
    if why is None:
        return f"length unit 1{unit} ({where} has no sample to estimate it from; pass {option})"
    return f"length unit 1{unit} (auto could not estimate it: {where} has {why}; pass {option})"


def estimate_length_unit(table, position_names=None, *, geographic: bool | None = None) -> tuple[float, str | None]:
    """The length unit ``auto`` takes from a track table: ``kalmix predict``'s (on a file's first chunk) and
    :meth:`TrackPredictor.process_table`'s (on its first table), one function for both.

    :func:`length_unit_rule` on the table's tracks: for geographic positions (``geographic``, as
    :class:`StreamConfig`'s) in metres, each track in the frame of its first fix
    (:func:`kalmix.io.geo.local_table`).

    Parameters
    ----------
    table : pandas.DataFrame
        ``track_id``, ``time`` and the positions, each track's rows in time order.
    position_names : sequence of str, optional
        Default: every column but ``track_id`` and ``time``.

    Returns
    -------
    (float, str or None)
        The unit, and why it is the fallback 1 (None when it was estimated).
    """
    from ..io.geo import local_table, resolve_axes, std_names
    from ..io.arrays import to_arrays

    names = ([c for c in table.columns if c not in ("track_id", "time")] if position_names is None
             else list(position_names))
    axes = resolve_axes(names, geographic)
    if axes is not None:
        table, names = local_table(table[["track_id", "time", *names]], names, axes), list(std_names(axes))
    arrays = to_arrays(table, names)
    return length_unit_rule(arrays.values, times=arrays.times)
