"""Times as the predictor takes them: float seconds from numbers, dates and durations (datetimes since 1970 UTC,
as :func:`kalmix.io.read_tracks` reads them)."""

from __future__ import annotations

import datetime

import numpy as np


def column_seconds(column) -> np.ndarray:
    """A table's time column as float seconds: datetimes since 1970 UTC, durations in seconds (as
    :func:`kalmix.io.read_tracks` reads them), numbers as they are, ISO 8601 text as datetimes; ``ValueError``
    naming the first value that is none of them."""
    import pandas as pd

    if pd.api.types.is_datetime64_any_dtype(column) or pd.api.types.is_timedelta64_dtype(column):
        from ..io.values import to_float

        return to_float(column.reset_index(drop=True), "time", 0)
    try:
        return column.to_numpy(np.float64)
    except (TypeError, ValueError):   # text: ISO 8601 date-times, as step_row, a file and a detected column take them
        from ..io.values import to_float

        name = column.name if isinstance(column.name, str) else "time"
        return to_float(column.reset_index(drop=True), name, 0, dates=True)


def row_times(times) -> np.ndarray:
    """``step_row`` / ``step_rows`` times as float seconds: numpy or pandas dates since 1970 UTC and durations in
    seconds, as :meth:`TrackPredictor.process_table` and files take them; numbers as they are. ``TypeError`` /
    ``ValueError`` for anything else."""

    import pandas as pd

    if isinstance(times, np.ma.MaskedArray):   # a masked time is missing: the row is skipped, as a NaN time
        times = np.ma.asarray(times, dtype=np.float64).filled(np.nan)
    given = np.asarray(times)
    if given.dtype.kind in "bc" or (isinstance(times, (list, tuple)) and any(isinstance(t, (bool, np.bool_))
                                                                             for t in times)):
        raise TypeError(f"expected numbers or dates, got {times!r:.80}")   # True read as 1.0, 1+1j as 1.0
    if given.dtype.kind in "US" or (given.dtype.kind == "O" and given.size and all(isinstance(t, str)
                                                                                    for t in given.flat)):
        flat = given.reshape(-1).astype(object)
        blank = np.array([not t.strip() for t in flat], dtype=bool)   # an empty time is missing, as in a file
        try:   # text: numbers, or ISO 8601 dates as a file and stdin take them
            return np.where(blank, "nan", flat).astype(np.float64).reshape(given.shape)
        except ValueError:
            from ..io.values import iso_seconds

            return iso_seconds(np.where(blank, None, flat)).reshape(given.shape)
    if given.dtype.kind == "O" and given.size and all(
            isinstance(t, (datetime.datetime, datetime.timedelta, np.datetime64, np.timedelta64)) for t in given.flat):
        given = pd.Series(given.reshape(-1)).infer_objects()
        if not (pd.api.types.is_datetime64_any_dtype(given) or pd.api.types.is_timedelta64_dtype(given)):
            given = pd.to_datetime(given, utc=True)   # dates of several time zones: instants in UTC
        return column_seconds(given)
    if given.dtype.kind in "Mm":
        return column_seconds(pd.Series(given.reshape(-1)))
    return given.astype(np.float64)


def next_row_times(parts, after: dict | None = None) -> list[dict]:
    """For tables ``parts`` fed to :meth:`TrackPredictor.process_table` in this order, each one's
    ``next_times``: track id -> time of the track's next row after that table (in a later part,
    else ``after``, e.g. a later chunk of a file)."""
    out = []
    upcoming = dict(after or {})
    for part in reversed(parts):
        out.append(dict(upcoming))
        firsts = part.groupby("track_id", sort=False)["time"].first()
        upcoming.update((track, float(t)) for track, t in zip(firsts.index, column_seconds(firsts)))
    return out[::-1]
