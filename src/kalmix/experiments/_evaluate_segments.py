"""The evaluation's layout of the data (:mod:`kalmix.experiments.evaluate`): tracks cut into segments at time
gaps, one column per segment, and the moves between that layout and one column per track."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..streaming import GapTracker, StreamConfig, gap_floor_for_steps


@dataclass
class Streams:
    """Tracks cut into segments, as dense arrays (one column per segment).

    ``values`` (T, S, p) NaN-padded; ``times`` (T, S); ``lengths`` (S,); ``track_of`` (S,)
    index into ``track_ids``; ``sample_index`` (T, S) the row's index within its track
    (-1 for padding).
    """

    values: np.ndarray
    times: np.ndarray
    lengths: np.ndarray
    track_of: np.ndarray
    track_ids: list
    sample_index: np.ndarray
    position_names: tuple


def split_streams(table, *, max_gap: float | None = None, max_gap_factor: float = 3.0,
                  max_samples: int | None = None) -> Streams:
    """Cut each track of a track table into segments with the ``kalmix predict`` gap rule."""
    names = tuple(c for c in table.columns if c not in ("track_id", "time"))
    steps = table.groupby("track_id", sort=False)["time"].diff().to_numpy(np.float64)
    # the gap floor kalmix predict settles on heavy-tailed sampling (its first chunk's steps; here the table's)
    config = StreamConfig(max_gap=max_gap, max_gap_factor=max_gap_factor,
                          gap_floor=gap_floor_for_steps(steps, max_gap_factor))
    columns, track_ids = [], []
    for track, group in table.groupby("track_id", sort=False):
        if max_samples is not None:
            group = group.iloc[:max_samples]
        gaps = GapTracker()
        times = group["time"].to_numpy(np.float64)
        values = group[list(names)].to_numpy(np.float64)
        starts = []
        for i, t in enumerate(times):
            new = gaps.advance(float(t), config)
            if new is None:
                raise ValueError(f"track {track!r}: times must increase (row {i} at {t}); read the file "
                                 "with kalmix.io.read_tracks, which sorts and de-duplicates")
            if new:
                starts.append(i)
        starts.append(len(times))
        track_ids.append(track)
        for a, b in zip(starts[:-1], starts[1:]):
            columns.append((len(track_ids) - 1, a, values[a:b], times[a:b]))
    if not columns:
        raise ValueError("no rows to evaluate")
    length = max(len(c[2]) for c in columns)
    s, p = len(columns), len(names)
    values = np.full((length, s, p), np.nan)
    times = np.full((length, s), np.nan)
    index = np.full((length, s), -1, dtype=np.int64)
    for j, (_, first, v, t) in enumerate(columns):
        values[:len(v), j], times[:len(v), j] = v, t
        index[:len(v), j] = first + np.arange(len(v))
    return Streams(values, times, np.array([len(c[2]) for c in columns]),
                   np.array([c[0] for c in columns]), track_ids, index, names)


def shift(array, h, fill=np.nan):
    """``out[t] = array[t + h]`` along the first axis (``fill`` past the end)."""
    out = np.full_like(array, fill)
    if h < len(array):
        out[:len(array) - h] = array[h:]
    return out


def track_layout(streams: Streams):
    """Segments joined back into tracks (one column per track), with a restart at each segment start.

    Returns ``(values (L, n, p), times (L, n), lengths (n,), restart (L, n), rows, columns)``:
    segment-layout entry ``[t, j]`` is track-layout entry ``[rows[t, j], columns[j]]``
    (``rows`` is the sample index, -1 on padding). This is how ``kalmix predict`` runs a
    track: the families start again after a gap, the rule and the calibration go on.
    """
    n = len(streams.track_ids)
    lengths = np.zeros(n, dtype=np.int64)
    np.add.at(lengths, streams.track_of, streams.lengths)
    p = streams.values.shape[2]
    values, times = np.full((int(lengths.max()), n, p), np.nan), np.full((int(lengths.max()), n), np.nan)
    restart = np.zeros(times.shape, dtype=bool)
    present = streams.sample_index >= 0
    t_seg, j_seg = np.nonzero(present)
    rows, cols = streams.sample_index[t_seg, j_seg], streams.track_of[j_seg]
    values[rows, cols], times[rows, cols] = streams.values[t_seg, j_seg], streams.times[t_seg, j_seg]
    starts = streams.sample_index[0] > 0   # a segment that is not its track's first
    restart[streams.sample_index[0, starts], streams.track_of[starts]] = True
    return values, times, lengths, restart, streams.sample_index, streams.track_of


def to_segments(array, rows, columns, fill=np.nan):
    """Track-layout ``(L, n, ...)`` back to the segment layout ``(T, S, ...)`` of ``rows, columns``."""
    out = np.full(rows.shape + array.shape[2:], fill, dtype=array.dtype)
    present = rows >= 0
    t_seg, j_seg = np.nonzero(present)
    out[t_seg, j_seg] = array[rows[t_seg, j_seg], columns[j_seg]]
    return out


def to_tracks(array, rows, columns, shape, fill=False):
    out = np.full(shape, fill, dtype=array.dtype)
    present = rows >= 0
    t_seg, j_seg = np.nonzero(present)
    out[rows[t_seg, j_seg], columns[j_seg]] = array[t_seg, j_seg]
    return out
