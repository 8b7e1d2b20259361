"""Track ids: the predictor's keys, and how the state file keeps them (re-exported by :mod:`kalmix.streaming`)."""

from __future__ import annotations

import datetime
import decimal

import numpy as np


def id_to_json(value):
    """A track id as the state file keeps it: numpy scalars as Python numbers, bools and text, numpy dates and
    durations as pandas'; anything else as it is."""
    if isinstance(value, (np.datetime64, np.timedelta64)):   # (numpy's timedelta64 is an integer type)
        import pandas as pd

        return (pd.Timestamp if isinstance(value, np.datetime64) else pd.Timedelta)(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.str_):
        return str(value)
    return value


#: What a track id may be: what the state file keeps (:func:`id_to_meta`).
_ID_TYPES = (str, int, float, bytes, decimal.Decimal, datetime.date, datetime.time, datetime.timedelta)


def keyable(key) -> bool:
    """Whether ``key`` (from :func:`id_to_json`) can be a track id: one the state file keeps (text, a number, a
    date, time or duration, a decimal, bytes). Others (a UUID, a Period, a tuple) are refused at the row rather
    than by ``save`` at the end of a long stream."""
    return isinstance(key, _ID_TYPES)


def factorize_ids(values) -> tuple[np.ndarray, np.ndarray]:
    """Codes (in order of first appearance) and the distinct values of ``values`` (a table's track ids)."""
    import pandas as pd

    codes, uniques = pd.factorize(values, use_na_sentinel=False)
    return np.asarray(codes, dtype=np.int64), np.asarray(uniques, dtype=object)


def track_key(value, where: str):
    """A track id as the predictor's key (numpy scalars as Python ones, as :meth:`TrackPredictor.process_table`
    and the state file hold them); ``TypeError``/``ValueError`` for what cannot be an id."""
    import pandas as pd

    try:
        missing = value is None or bool(pd.isna(value))   # None, NaN, NaT, pd.NA
    except (TypeError, ValueError):
        missing = False
    if missing:
        raise ValueError(f"{where}: expected a track id (text or a number), got {value!r}")
    if isinstance(value, (bool, np.bool_)):   # True == 1 as a key: it would continue track 1
        raise TypeError(f"{where}: expected a track id (text or a number), got {value!r}: a bool is not one (True "
                        "and 1 would be the same track)")
    key = id_to_json(value)
    if not keyable(key):
        raise TypeError(f"{where}: expected a track id (text, a number, or a date), got {type(value).__name__} "
                        f"{value!r:.80}")
    return key


def id_to_meta(track):
    """A track id as the state file's JSON holds it: JSON values as they are; dates, times, durations,
    decimals and bytes (Parquet id columns) tagged, so that :func:`id_from_meta` gives back an equal key."""

    import pandas as pd

    if isinstance(track, (pd.Timestamp, datetime.datetime)):
        return {"datetime": pd.Timestamp(track).isoformat()}
    if isinstance(track, (pd.Timedelta, datetime.timedelta)):
        return {"timedelta_ns": int(pd.Timedelta(track).value)}
    if isinstance(track, datetime.date):
        return {"date": track.isoformat()}
    if isinstance(track, datetime.time):
        return {"time": track.isoformat()}
    if isinstance(track, decimal.Decimal):
        return {"decimal": str(track)}
    if isinstance(track, bytes):
        return {"bytes": track.hex()}
    return track


def id_from_meta(value):
    """The inverse of :func:`id_to_meta`."""
    if not isinstance(value, dict):
        return value

    import pandas as pd

    (kind, text), = value.items()
    decode = {"datetime": pd.Timestamp, "timedelta_ns": lambda ns: pd.Timedelta(int(ns), unit="ns"),
              "date": datetime.date.fromisoformat, "time": datetime.time.fromisoformat,
              "decimal": decimal.Decimal, "bytes": bytes.fromhex}
    return decode[kind](text)
