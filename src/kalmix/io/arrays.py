"""A track table as the dense ``(time_steps, tracks, p)`` arrays a batched predictor takes, and back; segments
of tracks split at their time gaps."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pandas as pd

from .columns import require_columns


class TrackArrays(NamedTuple):
    """Dense form of a track table, each track aligned on its own sample index.

    Attributes
    ----------
    values : ndarray, shape (T, N, p)
        ``values[k, j]`` is the k-th sample of track j; NaN past its length.
    track_ids : ndarray, shape (N,)
        Track identifiers in table order.
    times : ndarray, shape (T, N)
        Sample times, NaN padding.
    lengths : ndarray of int, shape (N,)
        Number of samples of each track.
    position_names : tuple of str
        Names of the ``p`` position columns.
    """

    values: np.ndarray
    track_ids: np.ndarray
    times: np.ndarray
    lengths: np.ndarray
    position_names: tuple[str, ...] = ()


def to_arrays(df: pd.DataFrame, position_names: Sequence[str] | None = None) -> TrackArrays:
    """Pivot a track table into dense ``(time_steps, n_tracks, p)`` arrays.

    Each track is aligned on its own sample index: row ``k`` of track ``j`` is
    its k-th sample, whatever its time; shorter tracks are padded with NaN.
    Tracks keep their table order (sorted by id after :func:`read_tracks`).

    Parameters
    ----------
    df : pandas.DataFrame
        Track table with ``track_id``, ``time`` and position columns, each
        track's rows in time order.
    position_names : sequence of str, optional
        Position columns; default all columns but ``track_id`` and ``time``.

    Returns
    -------
    TrackArrays
        ``values`` (T, N, p) float64, ``track_ids`` (N,), ``times`` (T, N) with
        NaN padding, ``lengths`` (N,), ``position_names``.
    """
    if position_names is None:
        position_names = [c for c in df.columns if c not in ("track_id", "time")]
    position_names = tuple([position_names] if isinstance(position_names, str) else position_names)
    require_columns(list(df.columns), ["track_id", "time", *position_names], "to_arrays")
    if len(df) == 0:
        raise ValueError("Expected a track table with at least one row, got 0 rows")
    codes, ids = pd.factorize(df["track_id"], sort=False)
    k = df.groupby(codes, sort=False).cumcount().to_numpy()
    lengths = np.bincount(codes, minlength=len(ids))
    T, N, p = int(lengths.max()), len(ids), len(position_names)
    values = np.full((T, N, p), np.nan)
    times = np.full((T, N), np.nan)
    values[k, codes] = df[list(position_names)].to_numpy(np.float64)
    times[k, codes] = df["time"].to_numpy(np.float64)
    return TrackArrays(values, np.asarray(ids), times, lengths, position_names)


def from_arrays(arrays: TrackArrays, predictions: np.ndarray, prefix: str = "pred_") -> pd.DataFrame:
    """Turn ``(T, N, p)`` predictions back into a long table, dropping padding.

    Parameters
    ----------
    arrays : TrackArrays
        The arrays the predictions were made from (gives ids, times, lengths).
    predictions : array_like, shape (T, N, q)
        ``predictions[k, j]`` is attached to the k-th sample (and its time) of
        track j.
    prefix : str, default "pred_"
        Column name prefix; columns are ``prefix + position name`` when
        ``q == p``, else ``prefix + '0'``, ``prefix + '1'``, ...

    Returns
    -------
    pandas.DataFrame
        Columns ``['track_id', 'time', *prediction columns]`` ordered by track,
        then sample.
    """
    predictions = np.asarray(predictions, dtype=np.float64)
    T, N = arrays.times.shape
    if predictions.ndim != 3 or predictions.shape[:2] != (T, N):
        raise ValueError(f"Expected predictions of shape ({T}, {N}, q), got {predictions.shape}")
    q = predictions.shape[2]
    names = arrays.position_names if len(arrays.position_names) == q else [str(i) for i in range(q)]
    keep = (np.arange(T)[:, None] < np.asarray(arrays.lengths)[None, :]).T  # (N, T), track-major
    out = pd.DataFrame({"track_id": np.repeat(arrays.track_ids, arrays.lengths),
                        "time": arrays.times.T[keep]})
    flat = predictions.transpose(1, 0, 2)[keep]
    for i, name in enumerate(names):
        out[prefix + name] = flat[:, i]
    return out


def split_on_gaps(times: Sequence[float], max_gap_factor: float = 3.0, *,
                  track_ids: Sequence | None = None) -> np.ndarray:
    """Segment ids that start a new segment after an unusually long time gap.

    A new segment begins at sample ``i`` when ``times[i] - times[i-1]`` exceeds
    ``max_gap_factor`` times the track's median sampling interval (median of
    its positive steps). The prediction CLI restarts the filter state at each
    segment rather than predicting across a gap where the motion model's
    one-step dynamics no longer hold (a halftime, a lost GPS fix, a camera cut);
    within a segment NaN rows remain ordinary missing measurements.

    Parameters
    ----------
    times : array_like, shape (n,)
        Sample times, increasing within each track.
    max_gap_factor : float, default 3.0
        Gap threshold in units of the median interval; must be > 1.
    track_ids : array_like, shape (n,), optional
        When given, each track (consecutive rows with the same id) gets its own
        median and segments numbered from 0.

    Returns
    -------
    ndarray of int64, shape (n,)
        Segment index of each sample, 0, 1, 2, ... within each track.
    """
    if not max_gap_factor > 1:
        raise ValueError(f"Expected max_gap_factor > 1, got {max_gap_factor}")
    t = np.asarray(times, dtype=np.float64)
    if t.ndim != 1:
        raise ValueError(f"Expected a 1-D array of times, got shape {t.shape}")
    if track_ids is not None:
        ids = pd.Series(np.asarray(track_ids))
        if len(ids) != len(t):
            raise ValueError(f"Expected {len(t)} track ids (one per time), got {len(ids)}")
        out = np.zeros(len(t), dtype=np.int64)
        for _, idx in ids.groupby(ids, sort=False).indices.items():
            out[idx] = split_on_gaps(t[idx], max_gap_factor)
        return out
    dt = np.diff(t)
    steps = dt[dt > 0]
    if steps.size == 0:
        return np.zeros(len(t), dtype=np.int64)
    gap = dt > max_gap_factor * np.median(steps)
    return np.concatenate([[0], np.cumsum(gap)]).astype(np.int64)
