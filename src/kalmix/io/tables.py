"""Reading users' track files into one canonical long table.

A *track table* is a :class:`pandas.DataFrame` with the columns
``['track_id', 'time', *positions]``: one row per measurement, sorted by
``(track_id, time)``, positions as ``float64`` with ``NaN`` for a missing
measurement. :func:`read_tracks` and :func:`iter_track_chunks` produce it from
CSV (optionally gzip-compressed) or Parquet files; :func:`to_arrays` and
:func:`from_arrays` convert it to and from the dense ``(time_steps, tracks, p)``
arrays the batched predictor consumes.

Validation and handling, applied to every table read:

- a requested column that is not in the file: ``ValueError`` listing the
  available columns;
- a value in a time or position column that is not a number: ``ValueError``
  naming the column, the first offending row (counted from 0 after the header)
  and the value. Empty cells and ``nan`` / ``NA`` / ``null`` are allowed and mean
  a missing measurement (``NaN``); a row whose *time* is missing is dropped with
  a ``RuntimeWarning``;
- times that decrease within a track: the track's rows are sorted by time
  (stable) and a ``RuntimeWarning`` gives the count;
- repeated timestamps within a track: the last row (in file order) is kept and a
  ``RuntimeWarning`` gives the count;
- a file without data rows: ``ValueError`` ("no rows");
- more than 3 position columns: ``ValueError``.

Track ids: with ``ids_as_text=True`` (what ``kalmix predict`` and ``kalmix evaluate`` use)
a CSV id column is read as text exactly as written, so ``01`` and ``1`` are two tracks
(as on stdin) and a column whose chunks look numeric in one place and textual in another
keeps one type; tracks then come in order of first appearance instead of sorted by id.
By default pandas infers the type (``01`` and ``1`` both become the integer 1). Parquet
ids keep their column type either way.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

__all__ = [
    "TrackColumns",
    "TrackArrays",
    "BadRows",
    "BadRowWarning",
    "DroppedRowWarning",
    "ON_BAD_ROW",
    "detect_columns",
    "check_output_names",
    "read_tracks",
    "iter_track_chunks",
    "in_file_order",
    "to_arrays",
    "from_arrays",
    "split_on_gaps",
]

_TIME_NAMES = ("time", "t", "timestamp", "seconds", "time_s", "t_s", "sec", "secs", "ts",
               "elapsed", "datetime", "date_time", "frame", "frame_id", "frame_idx",
               "frame_index", "frame_number", "step",
               # AIS (MarineCadastre), storm best tracks (IBTrACS), and other logs
               "basedatetime", "iso_time", "time_utc", "utc", "timestamp_utc", "datetime_utc")
_ID_NAMES = ("track_id", "id", "track", "object_id", "target", "target_id", "trackid",
             "obj_id", "object", "agent_id", "trajectory_id", "traj_id", "player_id",
             "vehicle_id", "ped_id",
             # vessels (AIS), aircraft (ADS-B), storms (IBTrACS), animals (Movebank)
             "mmsi", "imo", "vessel_id", "ship_id", "icao24", "icao", "aircraft_id", "flight_id", "callsign",
             "sid", "storm_id", "individual-local-identifier", "individual_id", "animal_id", "tag_id")
# Axis name sets in order of preference; an optional third axis is taken when present.
_AXES = (("x", "y", "z"), ("u_left", "u_right", "v"), ("u", "v", None), ("east", "north", "up"),
         ("e", "n", "u"), ("lat", "lon", "alt"), ("latitude", "longitude", "altitude"),
         ("lat", "lng", "alt"))
_PREFIXES = ("", "position_", "pos_", "position.", "pos.", "p", "pos", "position")
_SINGLE = ("x", "position", "pos", "value")
MISSING_TEXT = frozenset({"", "nan", "na", "n/a", "nan.0", "null", "none", "<na>", "nat"})
_FORMATS = ("csv", "parquet")


@dataclass(frozen=True)
class TrackColumns:
    """Which columns of a file hold the time, the positions and the track id.

    Parameters
    ----------
    time : str or None
        Time column (seconds, or any numeric clock; datetime and timedelta
        columns, and text of ISO 8601 date-times, are converted to seconds,
        since 1970-01-01 UTC for dates). ``None`` means row order is time:
        each track's k-th row gets time ``k``.
    positions : tuple of str
        One to three position column names, kept as names in the output.
    track_id : str or None
        Track identifier column. ``None`` means the file holds a single track
        (``track_id`` 0).
    """

    time: str | None
    positions: tuple[str, ...]
    track_id: str | None

    def __post_init__(self):
        positions = (self.positions,) if isinstance(self.positions, str) else tuple(self.positions)
        object.__setattr__(self, "positions", positions)
        if not 1 <= len(positions) <= 3:
            raise ValueError(f"Expected 1 to 3 position columns, got {len(positions)}: {list(positions)}")
        named = [c for c in (self.time, self.track_id, *positions) if c is not None]
        if len(set(named)) != len(named):
            raise ValueError(f"Expected distinct time, position and track_id columns, got {named}")

    @property
    def names(self) -> list[str]:
        """All file columns in use: track id, time, positions (``None`` skipped)."""
        return [c for c in (self.track_id, self.time, *self.positions) if c is not None]


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


# --------------------------------------------------------------------------- columns
def _header_hint(columns) -> str:
    """A hint when the column names look like a line of another format: one name holding another
    separator, or names that are all numbers (a first line of data, no header)."""
    if len(columns) == 1:
        separator = next((name for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars"))
                          if sep in columns[0]), None)
        if separator:
            return f" The header looks separated by {separator}: kalmix reads comma-separated CSV."
    try:
        [float(name) for name in columns]
    except ValueError:
        return ""
    return " The column names are numbers: the first line must be a header (names, then rows)."


def _require(columns: Sequence[str], wanted: Sequence[str], what: str) -> None:
    missing = [c for c in wanted if c not in columns]
    if missing:
        raise ValueError(f"{what}: column(s) {missing} not found; available columns: {list(columns)}")


def check_output_names(columns: "TrackColumns") -> None:
    """``ValueError`` when a column that predictions keep (the id, the time, or ``row`` without a time
    column) has the name of a column they add: ``segment``, ``pred_<position>``, ``std_<position>``,
    ``lead_<position>``, ``lead_std_<position>``, ``pred<H>_<position>``, ``std<H>_<position>``; or when
    the two kept columns would share a name. Either would write two columns of one name."""
    import re

    positions = set(columns.positions)
    made = {"segment"} | {prefix + name for name in positions for prefix in ("pred_", "std_", "lead_", "lead_std_")}
    kept = [("the track id column", columns.track_id), ("the time column", columns.time or "row")]
    for what, name in kept:
        horizon = None if name is None else re.fullmatch(r"(?:pred|std)\d+_(.+)", name)
        if name in made or (horizon and horizon.group(1) in positions):
            raise ValueError(f"{what} is named {name!r}, the name of a column the predictions add; rename it in "
                             "the input (or choose another column)")
    if columns.track_id is not None and columns.track_id == (columns.time or "row"):
        raise ValueError(f"the track id column is named {columns.track_id!r}, the name the output gives the row "
                         "number when there is no time column; rename it in the input")


def detect_columns(columns: Sequence[str], *, time: str | None = None,
                   positions: str | Sequence[str] | None = None,
                   track_id: str | None = None) -> TrackColumns:
    """Find the time, position and track id columns among a file's column names.

    Matching is case-insensitive and ignores surrounding spaces. Explicit
    arguments win over detection and must name existing columns.

    - time: first of ``time, t, timestamp, seconds, time_s, ..., frame, step``;
      none found means row order is time.
    - positions: the first axis set found, in the order ``x/y[/z]``,
      ``u_left/u_right/v``, ``u/v``, ``east/north[/up]``, ``e/n[/u]``,
      ``lat/lon[/alt]``, ``latitude/longitude[/altitude]``, ``lat/lng``; each also
      with a prefix ``position_``, ``pos_``, ``position.``, ``pos.``, ``p``
      (``px/py/pz``), ``pos`` or ``position``; failing those a single ``x``,
      ``position``, ``pos`` or ``value`` column (a 1-D track). Latitude/longitude
      are kept in degrees; no conversion is made.
    - track id: first of ``track_id, id, track, object_id, target, ...``; none
      found means a single track.

    Parameters
    ----------
    columns : sequence of str
        Column names of the file.
    time : str, optional
        Explicit time column name.
    track_id : str, optional
        Explicit track id column name.
    positions : str or sequence of str, optional
        Explicit position column names (1 to 3).

    Returns
    -------
    TrackColumns

    Raises
    ------
    ValueError
        If an explicit name is not a column, or no position columns are found.
    """
    columns = [str(c) for c in columns]
    lookup: dict[str, str] = {}
    for c in columns:
        lookup.setdefault(c.strip().lower(), c)
    for name, flag, value in (("time", "--time", time), ("track_id", "--id", track_id)):
        if value is not None:
            _require(columns, [value], f"{name}={value!r} ({flag})")
    if positions is not None:
        positions = (positions,) if isinstance(positions, str) else tuple(positions)
        _require(columns, positions, f"positions={list(positions)} (--position)")
    else:
        for prefix in _PREFIXES:
            for a, b, c in _AXES:
                if prefix + a in lookup and prefix + b in lookup:
                    found = [lookup[prefix + a], lookup[prefix + b]]
                    if c is not None and prefix + c in lookup:
                        found.append(lookup[prefix + c])
                    positions = tuple(found)
                    break
            if positions is not None:
                break
        if positions is None:  # a 1-D track
            positions = next(((lookup[n],) for n in _SINGLE if n in lookup), None)
        if positions is None:
            raise ValueError(
                "Could not detect position columns (expected e.g. x/y[/z], u/v, lat/lon, "
                f"position_x/..., px/py/pz); available columns: {columns}. "
                "Name them: --position a,b on the command line, positions=(...) or a TrackColumns in Python."
                + _header_hint(columns))
    taken = set(positions)

    def first(names, explicit):
        if explicit is not None:
            return explicit
        return next((lookup[n] for n in names if n in lookup and lookup[n] not in taken), None)

    time = first(_TIME_NAMES, time)
    taken.add(time)
    track_id = first(_ID_NAMES, track_id)
    _check_roles(track_id, time, positions)
    return TrackColumns(time=time, positions=positions, track_id=track_id)


def _check_roles(track_id, time, positions) -> None:
    """``ValueError`` for a column in two roles, or a name that clashes with the ones a track table uses inside
    (the id column becomes ``track_id``, the time column ``time``): a position named ``time`` would be read as
    a position while the times came from elsewhere, and the output would mix them up."""
    roles = [("--id", track_id), ("--time", time), *(("--position", name) for name in positions)]
    seen: dict = {}
    for flag, column in roles:
        if column is None:
            continue
        if column in seen and not (flag == "--position" and seen[column] == "--position"):
            raise ValueError(f"column {column!r} is given both as {seen[column]} and as {flag}; expected each "
                             "column in one role")
        seen.setdefault(column, flag)
    inside = {"track_id": ("--id", track_id), "time": ("--time", time)}
    for flag, column in roles:
        if column in inside and inside[column][1] != column:
            role, other = inside[column]
            raise ValueError(f"column {column!r} is used as {flag}, but a track table names its {role[2:]} column "
                             f"{column!r}" + (f" (here {other!r})" if other is not None else "")
                             + "; rename that column in the file")


def column_notes(columns: TrackColumns, header: Sequence[str], single_track: bool = False) -> list[str]:
    """What a user should hear about the columns :func:`detect_columns` found in ``header``: no track id
    column (every row one track; not with ``single_track``, which the user chose) or no time column (row
    order), when the file has columns left unused that may be them. Empty when every column is in use."""
    unused = [str(c) for c in header if str(c) not in {columns.time, columns.track_id, *columns.positions}]
    if not unused:
        return []
    left = ", ".join(repr(c) for c in unused[:8]) + (", ..." if len(unused) > 8 else "")
    notes = []
    if columns.track_id is None and not single_track:
        notes.append(f"no track id column found (looked for {', '.join(_ID_NAMES[:4])}, mmsi, icao24, ...): "
                     f"every row is one track; pass --id COLUMN if the file holds several (unused columns: {left})")
    if columns.time is None:
        notes.append(f"no time column found (looked for {', '.join(_TIME_NAMES[:4])}, frame, ...): rows are "
                     f"one time unit apart, in file order; pass --time COLUMN (unused columns: {left})")
    return notes


#: First words of column names that name what a track follows (``vessel``, ``VesselName``, ``player_id``):
#: an unused column so named is taken as the track id when none is named or detected.
_ID_WORDS = frozenset({"vessel", "ship", "boat", "player", "athlete", "aircraft", "plane", "flight", "callsign",
                       "icao24", "icao", "mmsi", "drone", "uav", "animal", "individual", "bird", "vehicle", "car",
                       "truck", "person", "pedestrian", "ped", "agent", "robot", "object", "obj", "target",
                       "device", "satellite", "storm", "track", "trajectory", "traj"})
#: The words that may follow one of them in such a name.
_ID_TAILS = frozenset({"id", "name", "no", "nr", "num", "number", "code", "key", "ref", "identifier", "uid", "label"})
#: Rows of a file read to tell whether an unused column holds track ids.
ID_SAMPLE_ROWS = 10_000


def id_like_name(name: str) -> bool:
    """Whether a column's name says it holds track ids: a word of :data:`_ID_WORDS` (``vessel``, ``player``,
    ``callsign``, ...), alone or followed by id, name, number, ... (``VesselName``, ``player_id``)."""
    import re

    words = re.findall(r"[a-z]+\d*|\d+", re.sub(r"([a-z])([A-Z])", r"\1 \2", str(name)).lower())
    return bool(words) and words[0] in _ID_WORDS and all(word in _ID_TAILS for word in words[1:])


def _kind_of_values(column: pd.Series) -> str:
    """``"text"`` (words: not numbers, dates or true/false), ``"integer"``, or ``"other"`` for a column of a
    sample (CSV text, or a Parquet column's type)."""
    if isinstance(column.dtype, pd.CategoricalDtype):
        column = column.astype(object)
    if pd.api.types.is_bool_dtype(column) or pd.api.types.is_float_dtype(column) \
            or pd.api.types.is_datetime64_any_dtype(column) or pd.api.types.is_timedelta64_dtype(column):
        return "other"
    if pd.api.types.is_integer_dtype(column):
        return "integer"
    values = column.dropna()
    values = values[values.map(lambda v: isinstance(v, str))].str.strip()
    values = values[~values.str.lower().isin(MISSING_TEXT)]
    if values.empty:
        return "other"
    numbers = pd.to_numeric(values, errors="coerce")
    if numbers.notna().all():
        return "integer" if values.str.fullmatch(r"[+-]?\d+").all() else "other"
    words = values[numbers.isna()]
    if words.str.lower().isin(("true", "false")).all() or not np.isnan(iso_seconds(words, errors="coerce")).any():
        return "other"
    return "text"


def looks_like_a_word(value) -> bool:
    """Whether one value (a stdin field or a JSON value) is text that is not a number, a date or true/false:
    two different such values in an unused column mean tracks, not one."""
    if not isinstance(value, str):
        return False
    text = value.strip()
    if text.lower() in MISSING_TEXT or text.lower() in ("true", "false"):
        return False
    try:
        float(text)
        return False
    except ValueError:
        pass
    if text[:1].isdigit() or text[:1] in "+-":   # a date, maybe (a word does not start so: no pandas call)
        return _kind_of_values(pd.Series([text], dtype=object)) == "text"
    return True


def id_candidates(columns: TrackColumns, header: Sequence[str], sample: pd.DataFrame | None = None
                  ) -> list[tuple[str, str]]:
    """The columns of ``header`` that ``columns`` leaves unused and that look like a track id, each with why:
    its name (:func:`id_like_name`) or, in ``sample`` (the first rows of the file; None: names only), repeated
    text values (two or more different words, some on several rows) or whole numbers that tell apart rows of
    one time (the time column repeats, and far less within each of the column's values). Empty when
    ``columns`` has an id."""
    if columns.track_id is not None:
        return []
    found = []
    used = {columns.time, *columns.positions}
    times = None if sample is None or columns.time not in sample.columns else sample[columns.time]
    for name in map(str, header):
        if name in used:
            continue
        if id_like_name(name):
            found.append((name, "its name"))
            continue
        if sample is None or name not in sample.columns:
            continue
        column = sample[name]
        kind = _kind_of_values(column)
        values = column.dropna()
        distinct = values.nunique()
        if kind == "text" and 2 <= distinct < len(values):
            shown = ", ".join(repr(v) for v in values.unique()[:3])
            found.append((name, f"repeated text values: {shown}, ..."))
        elif kind == "integer" and distinct >= 2 and times is not None:
            pairs = pd.DataFrame({"id": column, "time": times}).dropna()
            repeated = int(pairs["time"].duplicated().sum())
            if repeated and 2 * int(pairs.duplicated().sum()) <= repeated:
                found.append((name, "whole numbers that tell apart rows of one time"))
    return found


# --------------------------------------------------------------------------- validation
def iso_seconds(text, errors: str = "raise") -> np.ndarray:
    """Seconds since 1970-01-01 UTC of a sequence of ISO 8601 date-time texts (no offset = UTC);
    ``ValueError`` naming the first value that is not such text or is outside 1677-2262 (the nanosecond
    clock's range); ``errors="coerce"``: NaN there. Counted in nanoseconds whatever the text's precision, element
    by element, and shared by the file and stdin paths, so both give the same bits for the same text. ``now``
    and ``today``, which pandas reads as the clock's time, are not dates of the data."""
    series = pd.Series(list(text), dtype=object)
    given = series.notna().to_numpy()
    words = series.astype(str).str.strip().str.lower().isin(("now", "today")).to_numpy() & given
    when = pd.to_datetime(series.where(~words), format="ISO8601", utc=True, errors="coerce")
    low, high = pd.Timestamp.min.tz_localize("UTC"), pd.Timestamp.max.tz_localize("UTC")
    outside = ((when < low) | (when > high)).to_numpy()
    bad = given & (when.isna().to_numpy() | outside | words)
    if bad.any() and errors == "raise":
        raise ValueError(f"not an ISO 8601 date-time between 1677 and 2262: {series[int(np.argmax(bad))]!r}")
    when = when.where(~(outside | words)).dt.as_unit("ns")
    return _seconds_of(when - pd.Timestamp(0, tz="UTC"))


def _seconds_of(delta: pd.Series) -> np.ndarray:
    """Float seconds of a Series of durations (NaT: NaN): the whole seconds and their fraction (of the same
    sign), each exact from the column's integer ticks, added: the float nearest the duration, or its neighbour
    where the two roundings meet. Dividing the nanoseconds as one float, as pandas does, loses up to ~2.4e-7 s
    on dates of this century (2^61 ns), enough for a gap rule to split a track of regular date-times where the
    same times as numbers do not."""
    unit = delta.dt.unit   # the column's own unit: converting to ns would overflow beyond 292 years
    per_second = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}[unit]
    missing = delta.isna().to_numpy()
    ticks = np.where(missing, 0, delta.to_numpy(f"timedelta64[{unit}]").view(np.int64))
    # whole seconds and fraction of the same sign (toward zero), so that they add without cancelling
    whole = np.sign(ticks) * (np.abs(ticks) // per_second)
    seconds = whole.astype(np.float64) + (ticks - whole * per_second).astype(np.float64) / per_second
    return np.where(missing, np.nan, seconds)


def _read_floats(s: pd.Series, dates: bool = False, kind: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A column as float64 (NaN where missing or bad) and which of its rows hold a bad value: text that is
    not a number, an infinity; in a time column (``dates``), text that is neither a number nor an ISO 8601
    date-time (read as seconds since 1970 UTC, :func:`iso_seconds`), or a value of the other kind than the
    column's: numbers and date-times do not mix, and the column's first time decides which it holds (kept in
    ``kind["kind"]``, so that a file's later chunks, or a stream's later rows, follow its first)."""
    kind = {} if kind is None else kind
    if pd.api.types.is_datetime64_any_dtype(s):
        epoch = pd.Timestamp(0, tz=getattr(s.dt, "tz", None))
        return _seconds_of(s - epoch), np.zeros(len(s), dtype=bool)
    if pd.api.types.is_timedelta64_dtype(s):
        return _seconds_of(s), np.zeros(len(s), dtype=bool)
    if pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
        out = s.to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
        if dates and "kind" not in kind and (~np.isnan(out)).any():
            kind["kind"] = "number"
        if bad.any():
            out = np.where(bad, np.nan, out)
        return out, bad
    out = pd.to_numeric(s.astype(object), errors="coerce").to_numpy(np.float64, na_value=np.nan)
    bad = np.isinf(out)
    unread = np.isnan(out) & s.notna().to_numpy()
    if unread.any():   # (the text only then: most columns are numbers)
        text = s.astype(str).str.strip().str.lower()
        unread &= ~text.isin(MISSING_TEXT).to_numpy()
    if dates:
        numbers = ~np.isnan(out) & ~bad
        seconds = np.full(len(s), np.nan)
        if unread.any():
            seconds[unread] = iso_seconds(s[unread].astype(object), errors="coerce")
        dated = ~np.isnan(seconds)
        if "kind" not in kind and (numbers | dated).any():
            first = int(np.argmax(numbers | dated))
            kind["kind"] = "number" if numbers[first] else "date-time"
        if kind.get("kind") == "date-time":
            bad |= numbers | (unread & ~dated)
            out = seconds
        else:
            bad |= unread
    else:
        bad |= unread
    if bad.any():
        out = np.where(bad, np.nan, out)
    return out, bad


def _bad_value(s: pd.Series, i: int, name: str, dates: bool = False, kind: dict | None = None) -> str:
    """Why row ``i`` of a column is bad (:func:`_read_floats`), in a few words that name the column and the value."""
    value = s.iloc[i:i + 1].tolist()[0]
    try:
        number = float(str(value).strip())
    except ValueError:
        number = None
    if dates:
        column = (kind or {}).get("kind")
        if column == "date-time" and number is not None and np.isfinite(number):
            return (f"column {name!r} holds a number ({value!r}) where its first time is a date-time; expected one "
                    "or the other")
        if column == "number" and isinstance(value, str) and not np.isnan(iso_seconds([value], errors="coerce")[0]):
            return (f"column {name!r} holds a date-time ({value!r}) where its first time is a number; expected one "
                    "or the other")
        if number is None or column == "date-time":
            return (f"column {name!r} must hold a number or an ISO 8601 date-time (like 2024-05-01T12:00:00.5Z), "
                    f"got {value!r}")
    if number is not None:
        return f"column {name!r} must be finite, got {value!r}"
    return f"column {name!r} must hold a number, got {value!r}"


def to_float(s: pd.Series, name: str, offset: int, dates: bool = False) -> np.ndarray:
    """Column to float64; ValueError at the first value that is not a number. ``dates``: a text column of
    ISO 8601 date-times is read as seconds since 1970 UTC (:func:`iso_seconds`), as a datetime column is."""
    if pd.api.types.is_datetime64_any_dtype(s):
        epoch = pd.Timestamp(0, tz=getattr(s.dt, "tz", None))
        return _seconds_of(s - epoch)
    if pd.api.types.is_timedelta64_dtype(s):
        return _seconds_of(s)
    if pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s):
        out = s.to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
    else:
        out = pd.to_numeric(s.astype(object), errors="coerce").to_numpy(np.float64, na_value=np.nan)
        bad = np.isinf(out)
        unread = np.isnan(out) & s.notna().to_numpy()
        if unread.any():   # (the text only then: most columns are numbers)
            text = s.astype(str).str.strip().str.lower()
            bad |= unread & ~text.isin(MISSING_TEXT).to_numpy()
    if bad.any() and dates and np.isnan(out).all():
        missing = s.isna().to_numpy() | s.astype(str).str.strip().str.lower().isin(MISSING_TEXT).to_numpy()
        text = s.where(~missing).astype(object)
        try:
            return iso_seconds(text)
        except (ValueError, TypeError, OverflowError):   # name the first value that is not a date-time
            undated = np.isnan(iso_seconds(text, errors="coerce")) & ~missing
            bad = undated if undated.any() else bad
    elif bad.any() and dates and not np.isnan(out).all():
        dated = ~np.isnan(iso_seconds(s.where(bad).astype(object), errors="coerce"))
        if dated.any():   # numbers and date-times in one column
            i, j = int(np.argmax(~np.isnan(out))), int(np.argmax(dated))
            raise ValueError(f"Column {name!r} mixes numbers (row {offset + i}: {s.iloc[i]!r}) and ISO 8601 "
                             f"date-times (row {offset + j}: {s.iloc[j]!r}); expected one or the other")
    if bad.any():
        i = int(np.argmax(bad))
        what = "finite numbers (or, for a time column, ISO 8601 date-times like 2024-05-01T12:00:00.5Z)" \
            if dates else "finite numbers"
        raise ValueError(
            f"Column {name!r} must hold {what}; row {offset + i} (counted from 0 after the "
            f"header) holds {s.iloc[i:i + 1].tolist()[0]!r}. Empty cells and 'nan' are read as "
            "missing measurements.")
    return out


def csv_options(cols: TrackColumns, ids_as_text: bool, time_as_text: bool = False) -> dict:
    """``pd.read_csv`` arguments that read the id column as text exactly as written (empty = missing) and, with
    ``time_as_text``, the time column as text (missing as pandas reads it: empty, ``NA``, ``nan``, ...), which
    :func:`to_float` turns into the same numbers as pandas' own reading."""
    text = [name for name, wanted in ((cols.track_id, ids_as_text), (cols.time, time_as_text))
            if wanted and name is not None]
    if not text:
        return {}
    from pandas._libs.parsers import STR_NA_VALUES

    missing = {name: sorted(STR_NA_VALUES) for name in cols.names if name != cols.track_id}
    if cols.track_id is not None:
        missing[cols.track_id] = [""] if ids_as_text else sorted(STR_NA_VALUES)
    return {"dtype": {name: str for name in text}, "keep_default_na": False, "na_values": missing}


def normalise_table(raw: pd.DataFrame, cols: TrackColumns, offset: int = 0,
               counts: dict | None = None, first_appearance: bool = False, as_given: bool = False,
               given_time: pd.Series | None = None, *, on_bad_row: str = "fail", lines: _ChunkLines | None = None,
               time_kind: dict | None = None, where: str = "row", clocks: ClockResets | None = None) -> pd.DataFrame:
    """Validate one raw table (or chunk) into the canonical sorted long table; ``as_given``: with its rows as
    the file gave them in ``attrs["as_given"]`` (:class:`AsGiven`; ``given_time``: the time column's values
    to keep, when not ``raw``'s own).

    A bad row (:data:`ON_BAD_ROW`: a field count not the header's, given in ``lines``; no track id; a time or
    position that is not a finite number, or a date-time for a time) raises a ``ValueError`` naming its line
    (``lines``) or row with ``on_bad_row="fail"``; with ``"skip"`` it is left out of the table, keeps its
    place in ``as_given`` as a row not stepped, and is listed in ``attrs["bad_rows"]`` (:class:`BadRows`).
    ``time_kind``: the time column's kind (numbers or date-times) across a file's chunks. ``clocks``: a
    track's clock that restarts starts a new segment (:class:`ClockResets`) instead of being sorted into the
    rows before it."""
    if len(raw) == 0:
        raise ValueError("The track file has no rows (only a header or nothing at all)")
    if on_bad_row not in ON_BAD_ROW:
        raise ValueError(f"on_bad_row: expected one of {list(ON_BAD_ROW)}, got {on_bad_row!r}")
    n = len(raw)
    bad = np.zeros(n, dtype=bool)
    why: dict[int, str] = {}

    def mark(rows: np.ndarray, reason) -> None:
        for i in np.flatnonzero(rows & ~bad):
            why[int(i)] = reason(int(i))
        bad[rows] = True

    if lines is not None and lines.fields is not None:
        mark(lines.fields != lines.width,
             lambda i: f"expected {lines.width} fields like the header, got {lines.fields[i]}")
    if cols.track_id is None:
        ids = pd.Series(np.zeros(n, dtype=np.int64))
    else:
        ids = raw[cols.track_id].reset_index(drop=True)
        if ids.dtype == np.float16:   # pandas cannot group or index float16: the same values in float32
            ids = ids.astype(np.float32)
        mark(ids.isna().to_numpy(), lambda i: f"column {cols.track_id!r} (track id) is empty")
    out = pd.DataFrame({"track_id": ids})
    if cols.time is None:
        out["time"] = np.nan   # numbered below, once the bad rows are known
    else:
        column = raw[cols.time].reset_index(drop=True)
        kind = {} if time_kind is None else time_kind
        out["time"], wrong = _read_floats(column, dates=True, kind=kind)
        mark(wrong, lambda i: _bad_value(column, i, cols.time, True, kind))
    for p in cols.positions:
        column = raw[p].reset_index(drop=True)
        out[p], wrong = _read_floats(column)
        mark(wrong, lambda i, column=column, p=p: _bad_value(column, i, p))
    named = (lambda i: f"line {lines.lines[i]}") if lines is not None and lines.lines is not None else (
        lambda i: f"row {offset + i} (counted from 0{' after the header' if where == 'row' else ''})")
    if bad.any() and on_bad_row == "fail":
        i = int(np.argmax(bad))
        raise ValueError(f"{named(i)}: {why[i]}")
    if cols.time is None:   # each track's row number, continued across chunks; a bad row takes none
        kept = out[~bad]
        k = kept.groupby("track_id", sort=False).cumcount().to_numpy(np.float64)
        if counts is not None:  # continue each track's row count across chunks
            k += kept["track_id"].map(counts).fillna(0).to_numpy(np.float64)
            for tid, c in kept["track_id"].value_counts().items():
                counts[tid] = counts.get(tid, 0) + int(c)
        times = np.full(n, np.nan)
        times[~bad] = k
        out["time"] = times

    no_time = np.isnan(out["time"].to_numpy()) & ~bad
    if no_time.any():
        warnings.warn(f"{int(no_time.sum())} row(s) have no time in column {cols.time!r}: not predicted (their "
                      "output rows have empty predictions)" if as_given else
                      f"Dropped {int(no_time.sum())} row(s) with a missing time in column {cols.time!r}",
                      DroppedRowWarning, stacklevel=3)
    if no_time.any() or bad.any():
        out = out[~(no_time | bad)]
    if clocks is not None:
        out = clocks.apply(out, named)
    back = int((out.groupby("track_id", sort=False)["time"].diff() < 0).sum())
    if back:
        warnings.warn(f"Times decrease at {back} row(s) within tracks; sorted each track's rows "
                      "by time (stable)", RuntimeWarning, stacklevel=3)
    if first_appearance:
        first = pd.factorize(out["track_id"], sort=False)[0]
        out = out.iloc[np.lexsort((out["time"].to_numpy(), first))]
    else:
        out = out.sort_values(["track_id", "time"], kind="stable")
    # sorted by track, then time: a repeated time is the next row's. What duplicated(keep="last") finds, but
    # cheaper
    codes = pd.factorize(out["track_id"], sort=False)[0]
    stamp = out["time"].to_numpy()
    dup = np.zeros(len(out), dtype=bool)
    dup[:-1] = (codes[:-1] == codes[1:]) & (stamp[:-1] == stamp[1:])
    if dup.any():
        warnings.warn(f"{int(dup.sum())} row(s) repeat a timestamp within their track; " + (
                      "the last row of each repeated time is predicted, the others' output rows have empty "
                      "predictions" if as_given else "kept the last row of each repeated time"),
                      DroppedRowWarning, stacklevel=3)
    sorted_places = out.index.to_numpy()
    if dup.any():
        out = out[~dup]
    out.attrs["file_order"] = _RowOrder(out.index.to_numpy())   # each row's place in the file (read on demand)
    out.attrs["dropped"] = {"untimed": int(no_time.sum()), "repeated": int(dup.sum())}
    if clocks is not None and clocks.found:
        out.attrs["clock_resets"] = list(clocks.found)
    if as_given:
        out.attrs["as_given"] = AsGiven.of(raw, cols, sorted_places, dup, no_time | bad, given_time)
    if bad.any():
        out.attrs["bad_rows"] = BadRows.of(raw, cols, np.flatnonzero(bad), why, offset, lines, named)
    return out.reset_index(drop=True)


class ClockResets:
    """A track's clock that restarts (times 0 .. 49, then 0 .. 49 again), found in file order: sorting its rows
    by time would interleave the two runs (half of them then repeated timestamps), so the rows from the restart
    on are moved past the ones before it instead, by a step of ``step(usual)`` (``usual``: the track's
    median step in the chunk) after the last time before it: a gap that starts a new segment. The output
    keeps the times as given (:class:`AsGiven`); the table's times are the moved ones.

    A restart is a step back by more than :attr:`FACTOR` usual steps, to a time inside the range of the run
    before it (not a block of earlier rows that comes late: those are sorted into place), followed by steps
    forward of at most :attr:`FACTOR` usual steps (at least two, or as many as the chunk holds when a chunk
    follows it: a later chunk cannot move the rows of this one). State across a file's chunks: each track's
    shift, last time and the first time of its current clock (:meth:`resume` takes them from an earlier run).
    ``found``: the chunk's restarts, ``(place, track, time before, time after)``.
    """

    FACTOR = 3.0

    def __init__(self, step):
        self.step = step
        self.tracks: dict = {}   # track -> [shift, last time as given, first time of its current clock]
        self.found: list = []
        self.resumed: set = set()   # tracks of a resumed run's state not yet seen in this one
        self.more = False   # a chunk of the file comes after this one

    def resume(self, track, clock) -> None:
        """Go on with ``track``'s clock ``[shift, last time as given, first time of its current clock]`` saved by
        an earlier run: its rows that go on after that last time are moved by that shift. Its first row in this
        run at or before that time (the file read again from its start) drops it: the restarts are found again."""
        self.tracks[track] = [float(v) for v in clock]
        self.resumed.add(track)

    def apply(self, out: pd.DataFrame, named) -> pd.DataFrame:
        """``out`` (rows in file order, ``out.index`` their rows in the chunk) with each restarted clock's rows
        moved; ``named(row)``: where a row is, for :attr:`found`."""
        self.found = []
        if out.empty:
            return out
        raw = out["time"].to_numpy(np.float64)
        codes, uniques = pd.factorize(out["track_id"], sort=False)
        firsts = np.full(len(uniques), -1, dtype=np.int64)
        firsts[codes[::-1]] = np.arange(len(codes))[::-1]
        steps = pd.Series(raw).groupby(codes, sort=False).diff().to_numpy()
        look = np.zeros(len(uniques), dtype=bool)
        look[codes[steps < 0]] = True
        shift = np.zeros(len(uniques))
        for c, track in enumerate(uniques.tolist()):
            if track in self.resumed:
                self.resumed.discard(track)
                if raw[firsts[c]] <= self.tracks[track][1]:
                    del self.tracks[track]
            known = self.tracks.get(track)
            if known is not None:
                shift[c] = known[0]
                look[c] |= raw[firsts[c]] < known[1]
        moved = raw + shift[codes]
        values = out.drop(columns=["track_id", "time"]).to_numpy(np.float64)
        for c in np.flatnonzero(look):
            rows = np.flatnonzero(codes == c)
            moved[rows] = self._track(uniques[c], raw[rows], values[rows], out.index.to_numpy()[rows], named)
        highest = pd.Series(raw).groupby(codes, sort=False).agg(["min", "max"]).to_numpy()
        for c, track in enumerate(uniques.tolist()):   # each track's last time and current clock, for later chunks
            if look[c]:
                continue
            known = self.tracks.get(track)
            if known is None:
                self.tracks[track] = [0.0, highest[c, 1], highest[c, 0]]
            else:
                known[1], known[2] = max(known[1], highest[c, 1]), min(known[2], highest[c, 0])
        if not self.found and not shift.any():
            return out
        out = out.copy()
        out["time"] = moved
        return out

    def _track(self, track, times, values, places, named) -> np.ndarray:
        """One track's times in a chunk (file order) with its restarts moved; updates its state. Not a restart:
        a track whose rows go back at more than one step in ten (rows in no order, sorted as they are), or a run
        that repeats rows before it (the same time and positions: a block given twice)."""
        shift, last, start = self.tracks.get(track, [0.0, None, None])
        steps = np.diff(times)
        forward = steps[steps > 0]
        usual = float(np.median(forward)) if forward.size and 10 * int((steps < 0).sum()) <= len(times) else None
        out = np.empty(len(times))
        judged = 0   # rows before this are judged (a run of rows that came late is one block, sorted into place)
        for j, time in enumerate(times):
            if j >= judged and last is not None and usual is not None and last - time > self.FACTOR * usual:
                run = j + 1
                while run < len(times) and times[run - 1] < times[run] <= times[run - 1] + self.FACTOR * usual:
                    run += 1
                judged = run
                again = np.flatnonzero(times[:j] == time)
                again = again.size and all(np.array_equal(values[k], values[j], equal_nan=True) for k in again)
                # goes on (two steps forward, or forward up to the chunk's last row of the track when a chunk
                # follows, which cannot move rows already read), inside the earlier clock's range
                if (run > j + 2 or (self.more and run == len(times))) and times[run - 1] >= start and not again:
                    self.found.append((named(int(places[j])), track, float(last), float(time)))
                    shift = last + shift + float(self.step(usual)) - time
                    last = start = time
            out[j] = time + shift
            last = time if last is None else max(last, time)
            start = time if start is None else min(start, time)
        self.tracks[track] = [shift, last, start]
        return out


class _RowOrder:
    """A normalised table's rows' places in the file, in ``DataFrame.attrs``: pandas copies attrs into every
    frame derived from a table, so this one is shared, not copied (it describes only the table it was made
    for: :func:`in_file_order` checks its length and that its index is still the table's 0 .. n - 1)."""

    def __init__(self, places):
        self.places = places

    def __deepcopy__(self, memo):
        return self


class AsGiven:
    """The rows of a chunk as the file gave them (``chunk.attrs["as_given"]`` of a chunk that
    :func:`iter_track_chunks` read with ``as_given=True``): what ``kalmix predict`` writes its output rows from.

    Attributes
    ----------
    rows : int
        File rows the chunk was made from.
    ids, times : pandas.Series or None
        The id and time columns, ``rows`` values in file order, as read: a CSV's text exactly as
        written (a missing time as NaN), a Parquet column's own type (integers nullable). None
        for a column the file does not have.
    places : ndarray of int, shape (len(chunk),)
        Each chunk row's file row (counted from the chunk's first).
    owner : ndarray of int, shape (rows,)
        For each file row, the chunk row whose fate it shares: itself where it is one; for an
        earlier row of a repeated time, the row kept for that time; for a row without a time
        or a bad row, that of the file row before it (or, at the chunk's start, after it); -1
        in a chunk without a row to step. A resumed run writes a file row only if that chunk
        row was stepped (not skipped as already done).
    """

    def __init__(self, rows, ids, times, places, owner):
        self.rows, self.ids, self.times, self.places, self.owner = rows, ids, times, places, owner

    def __deepcopy__(self, memo):   # in attrs, as _RowOrder: shared by the frames pandas derives, not copied
        return self

    @classmethod
    def of(cls, raw, cols, sorted_places, dup, no_time, given_time=None) -> AsGiven:
        """From :func:`normalise_table`'s steps: ``sorted_places`` the file rows with a time sorted by track and time,
        ``dup`` which of them an equal time follows (dropped), ``no_time`` which file rows have no time."""
        n = len(raw)
        kept = np.cumsum(~dup)   # chunk row of a kept sorted row + 1; of a dropped one, the next kept
        owner = np.empty(n, dtype=np.int64)
        owner[sorted_places] = np.where(dup, kept, kept - 1)
        if no_time.all():   # no row stepped (every row bad or without a time): each its own, none stepped
            owner[:] = -1
        elif no_time.any():
            timed = np.flatnonzero(~no_time)
            after = np.searchsorted(timed, np.flatnonzero(no_time))
            owner[no_time] = owner[timed[np.where(after > 0, after - 1, 0)]]
        ids = None if cols.track_id is None else raw[cols.track_id].reset_index(drop=True)
        if given_time is None and cols.time is not None:
            given_time = raw[cols.time]
        times = None if given_time is None else given_time.reset_index(drop=True)
        return cls(n, ids, times, sorted_places[~dup], owner)


#: What a reader does with a bad row: ``"skip"`` it (left out of the table, listed in ``attrs["bad_rows"]``
#: and warned of with a :class:`BadRowWarning`), or ``"fail"``: a ``ValueError`` that names its line.
#: A bad row is one whose field count is not the header's (CSV), whose track id is empty, or whose time or a
#: position is not a finite number (a time may be an ISO 8601 date-time, if the column's first time is one).
#: An empty cell or ``nan`` is not bad: it is a missing measurement (a missing time: a row not predicted).
ON_BAD_ROW = ("skip", "fail")


class DroppedRowWarning(RuntimeWarning):
    """Rows of a file are not in the table read: rows without a time, the earlier rows of a repeated time, and
    (:class:`BadRowWarning`) bad rows; the message counts them."""


class BadRowWarning(DroppedRowWarning):
    """Bad rows were skipped by a reader (``on_bad_row="skip"``): the message counts them and names the first."""


class BadRows:
    """The bad rows a reader skipped in a table or chunk (``attrs["bad_rows"]``).

    Attributes
    ----------
    rows : ndarray of int
        File rows, counted from 0 after the header.
    local : ndarray of int
        The same rows counted from the chunk's first.
    places : list of str
        Where each is: ``line N`` (the CSV file's line, counted from 1 with the header) or ``row N``.
    reasons : list of str
        Why each is bad.
    texts : list of str
        Each row as the file gave it: a CSV line as written (without its line end; "" when the
        lines were not kept), a Parquet row's used columns as a JSON object.
    """

    def __init__(self, rows, places, reasons, texts, local=None):
        self.rows, self.places, self.reasons, self.texts = rows, places, reasons, texts
        self.local = rows if local is None else local

    def __deepcopy__(self, memo):   # in attrs, as _RowOrder
        return self

    def __len__(self) -> int:
        return len(self.rows)

    @classmethod
    def of(cls, raw, cols, rows, why, offset, lines, named) -> BadRows:
        if lines is not None and lines.texts is not None:
            texts = [lines.texts[i] for i in rows]
        elif lines is not None:
            texts = [""] * len(rows)
        else:
            import json

            used = raw[cols.names].iloc[rows]
            texts = [json.dumps({str(k): (None if v is None or (isinstance(v, float) and np.isnan(v)) else
                                          str(v) if isinstance(v, float) and np.isinf(v) else
                                          v if isinstance(v, (int, float, str, bool)) else str(v))
                                 for k, v in record.items()}) for record in used.to_dict("records")]
        return cls(offset + rows, [named(int(i)) for i in rows], [why[int(i)] for i in rows], texts, rows)

    @classmethod
    def concat(cls, parts) -> BadRows | None:
        parts = [part for part in parts if part is not None and len(part)]
        if not parts:
            return None
        return cls(np.concatenate([part.rows for part in parts]), [p for part in parts for p in part.places],
                   [r for part in parts for r in part.reasons], [t for part in parts for t in part.texts])

    def summary(self, shown: int = 10) -> str:
        """``N bad row(s) skipped (line 12: why; line 599, ...)``: the count, the first's reason, the first places."""
        places = ", ".join(self.places[:shown]) + (", ..." if len(self) > shown else "")
        return f"{len(self)} bad row(s) skipped ({places}; the first: {self.reasons[0]})"


class _ChunkLines(NamedTuple):
    """A CSV chunk's rows as :class:`_CsvLines` read them: each row's line (counted from 1 with the header),
    field count and, when kept, text; ``width``: the header's field count. ``lines`` and ``fields`` are None
    where the two readers did not agree (rows are then named by their number)."""

    lines: np.ndarray | None
    fields: np.ndarray | None
    width: int
    texts: list | None


class _CsvLines:
    """The physical line, field count and (``texts``) text of each data row of a CSV file, read alongside
    pandas' reader with Python's csv module: pandas gives the values, but pads a short row with missing
    values and, reading some columns, takes a long one as it is, and does not say where a row's line is.

    Blank lines are skipped as pandas skips them. Should the two readers ever disagree on the rows (a
    chunk's last row not the same id, or the file ending early here), the lines are dropped from there
    on: rows are then named by their number, and field counts not checked."""

    def __init__(self, path, texts: bool = False, check: int | None = None):
        import csv
        import gzip

        opener = gzip.open if os.fspath(path).lower().endswith(".gz") else open
        self.handle = opener(path, "rt", encoding="utf-8-sig", errors="replace", newline="")
        self.keep = texts
        self.pending: list[str] = []
        self.limit = csv.field_size_limit()
        self.reader = csv.reader(self._lines() if texts else self.handle)
        self.check = check   # the column compared with pandas' at each chunk's last row
        self.ok = True
        self.width = 0
        with self._no_field_limit():
            for record in self.reader:
                if not _blank(record):
                    self.width = len(record)
                    break
        self.pending.clear()

    def _lines(self):
        for line in self.handle:
            self.pending.append(line)
            yield line

    @contextlib.contextmanager
    def _no_field_limit(self):
        import csv

        csv.field_size_limit(max(self.limit, 2**31 - 1))   # a long field is pandas' to read (or an unused one)
        try:
            yield
        finally:
            csv.field_size_limit(self.limit)

    def take(self, n: int, checked: pd.Series | None = None) -> _ChunkLines:
        """The next ``n`` rows; ``checked``: pandas' values of column :attr:`check` for them (text)."""
        if not self.ok:
            return _ChunkLines(None, None, self.width, None)
        with self._no_field_limit():
            taken = self._take_texts(n) if self.keep else self._take(n)
        if taken is None:
            self.ok = False
        else:
            lines, fields, texts, last = taken
            if checked is not None and self.check is not None and n:
                value = checked.iloc[-1]
                mine = last[self.check] if self.check < len(last) else None
                if isinstance(value, str) and mine is not None and mine != value:
                    self.ok = False
        if not self.ok:
            self.close()
            return _ChunkLines(None, None, self.width, None)
        return _ChunkLines(lines, fields, self.width, texts)

    def _take(self, n: int):
        """``(lines, fields, None, last record)`` of the next ``n`` rows, or None at an early end: the records read
        in C, each record's first line from the reader's line count (or, where a quoted field holds a line
        break, from the breaks it holds)."""
        import itertools

        reader, records, counts = self.reader, [], []
        before = reader.line_num
        kept = 0
        while kept < n:
            try:
                batch = list(itertools.islice(reader, n - kept))
            except Exception:   # noqa: BLE001 - pandas reads the file; here only lines
                return None
            if not batch:
                return None
            width = np.fromiter(map(len, batch), dtype=np.int64, count=len(batch))
            records += batch
            counts.append(width)
            kept += len(batch) - sum(_blank(batch[i]) for i in np.flatnonzero(width <= 1))
        spans = np.ones(len(records), dtype=np.int64)
        if reader.line_num - before != len(records):   # a quoted field holds a line break: count them
            spans += np.fromiter((sum(field.count("\n") + field.count("\r") - field.count("\r\n")
                                      for field in record) for record in records), dtype=np.int64,
                                 count=len(records))
        starts = before + np.cumsum(spans) - spans + 1
        fields = np.concatenate(counts)
        rows = np.ones(len(records), dtype=bool)
        for i in np.flatnonzero(fields <= 1):
            rows[i] = not _blank(records[i])
        return starts[rows], fields[rows], None, records[int(np.flatnonzero(rows)[-1])]

    def _take_texts(self, n: int):
        """:meth:`_take` keeping each row's text (a file of rejects), a record at a time."""
        lines = np.empty(n, dtype=np.int64)
        fields = np.empty(n, dtype=np.int64)
        texts: list = []
        reader, pending, i = self.reader, self.pending, 0
        last = None
        while i < n:
            before = reader.line_num
            try:
                record = next(reader)
            except (StopIteration, Exception):   # noqa: BLE001 - pandas reads the file; here only lines
                return None
            if _blank(record):
                pending.clear()
                continue
            lines[i], fields[i], last = before + 1, len(record), record
            texts.append("".join(pending).rstrip("\r\n"))
            pending.clear()
            i += 1
        return lines, fields, texts, last

    def close(self) -> None:
        self.handle.close()


def _blank(record) -> bool:
    """A csv record of a line pandas skips (empty, or spaces and tabs only)."""
    return not record or (len(record) == 1 and not record[0].strip(" \t"))


def in_file_order(table: pd.DataFrame) -> pd.DataFrame:
    """A table :func:`read_tracks` or :func:`iter_track_chunks` gave (sorted by track, then time) with its rows
    back in the order the file had them, the order a stream of the same rows arrives in; a track whose times
    went back in the file keeps them sorted, in the places of its rows. Any other table as it is."""
    order = table.attrs.get("file_order")
    if (not isinstance(order, _RowOrder) or len(order.places) != len(table)
            or not table.index.equals(pd.RangeIndex(len(table)))):   # a frame reordered from it, not the table
        return table
    # each track's rows (in time order) take that track's places in the file, in order: a track sorted on
    # reading, or a repeated time dropped, keeps the places of its rows among the others
    codes = pd.factorize(table["track_id"], sort=False)[0]   # non-decreasing: the tracks are contiguous
    places = order.places[np.lexsort((order.places, codes))]
    out = table.iloc[np.argsort(places, kind="stable")]
    del out.attrs["file_order"]   # its own attrs: the order describes ``table``, not ``out``
    return out


# --------------------------------------------------------------------------- reading
def _format_of(source: Any, format: str | None) -> str:
    if format is not None:
        fmt = format.lower().lstrip(".")
        if fmt not in _FORMATS:
            raise ValueError(f"Expected format in {list(_FORMATS)}, got {format!r}")
        return fmt
    name = source if isinstance(source, (str, os.PathLike)) else getattr(source, "name", None)
    if name is None:
        return "csv"  # an unnamed buffer: CSV unless format='parquet'
    name = os.fspath(name).lower()
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith((".csv", ".csv.gz", ".txt", ".txt.gz", ".gz")):
        return "csv"
    raise ValueError(f"Cannot tell the format of {name!r}: expected a .csv, .csv.gz or .parquet "
                     "file, or pass format='csv' or 'parquet'")


def read_header(source: Any, fmt: str) -> list[str]:
    """The column names of a track file (``fmt``: ``"csv"`` or ``"parquet"``), as text; a ``ValueError`` naming
    the file when it is empty (no header, no rows) or, in CSV, not UTF-8 text."""
    if fmt == "parquet":
        import pyarrow.parquet as pq
        with pq.ParquetFile(source) as parquet:
            return list(parquet.schema_arrow.names)
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else getattr(source, "name", "(a buffer)")
    try:
        return [str(c) for c in pd.read_csv(source, nrows=0).columns]
    except pd.errors.EmptyDataError:
        raise ValueError(f"The track file {name!r} is empty (no header, no rows)") from None
    except UnicodeDecodeError as error:
        raise ValueError(f"The track file {name!r} is not a CSV text file (UTF-8 expected; "
                         f"{error.reason} at byte {error.start})") from None


def check_unique_columns(source: Any, fmt: str, cols: TrackColumns) -> None:
    """``ValueError`` when a column used appears more than once in a CSV header (pandas would
    silently rename the copies ``x.1``, ``x.2`` and read the first)."""
    if fmt != "csv":
        return
    first = pd.read_csv(source, nrows=1, header=None, dtype=str, keep_default_na=False)
    written = [str(v) for v in first.iloc[0]] if len(first) else []
    for name in cols.names:
        if written.count(name) > 1:
            raise ValueError(f"Column {name!r} appears {written.count(name)} times in the header of "
                             f"{os.fspath(source)!r}; rename the copies (pandas would read the first)")


def _resolve(header: list[str], columns: TrackColumns | None) -> TrackColumns:
    if columns is None:
        return detect_columns(header)
    if not isinstance(columns, TrackColumns):
        raise ValueError(f"Expected columns to be a TrackColumns or None, got {type(columns).__name__}")
    _require(header, columns.names, f"columns={columns}")
    return columns


def read_tracks(path_or_buffer: str | os.PathLike | io.IOBase, *, columns: TrackColumns | None = None,
                format: str | None = None, ids_as_text: bool = False, on_bad_row: str = "fail") -> pd.DataFrame:
    """Read a CSV (optionally ``.gz``) or Parquet track file into a track table.

    Parameters
    ----------
    path_or_buffer : path or file-like
        The file. The format comes from the extension (``.csv``, ``.csv.gz``,
        ``.parquet``, ``.pq``) or from `format`; an unnamed buffer is CSV unless
        ``format='parquet'``.
    columns : TrackColumns, optional
        Which columns to use; detected with :func:`detect_columns` if omitted.
    format : {'csv', 'parquet'}, optional
        Overrides the extension.
    ids_as_text : bool, default False
        Read a CSV id column as text exactly as written (see the module docstring).
    on_bad_row : {'fail', 'skip'}, default 'fail'
        A bad row (a CSV row whose field count is not the header's, an empty track id, a time or
        position that is not a finite number; see :data:`ON_BAD_ROW`): ``'fail'`` raises a
        ``ValueError`` naming its line (CSV file) or row; ``'skip'`` leaves it out, with a
        :class:`BadRowWarning`, and lists it in ``attrs["bad_rows"]`` (:class:`BadRows`).

    Returns
    -------
    pandas.DataFrame
        Columns ``['track_id', 'time', *columns.positions]``, sorted by
        ``(track_id, time)`` (stable; with ``ids_as_text`` on a CSV file: tracks in order
        of first appearance, then time), time and positions as float64, NaN for a
        missing measurement. See the module docstring for the validation rules.

    Raises
    ------
    ValueError
        Missing columns, non-numeric values, no rows, more than 3 positions.
    """
    fmt = _format_of(path_or_buffer, format)
    is_path = isinstance(path_or_buffer, (str, os.PathLike))
    lines = None
    if is_path:
        cols = _resolve(read_header(path_or_buffer, fmt), columns)
        check_unique_columns(path_or_buffer, fmt, cols)
        if fmt == "parquet":
            import pyarrow.parquet as pq
            raw = pq.read_table(path_or_buffer, columns=cols.names).to_pandas()
        else:
            raw = pd.read_csv(path_or_buffer, usecols=cols.names, **csv_options(cols, ids_as_text))
            if len(raw):
                reader = _CsvLines(path_or_buffer, check=_checked_column(path_or_buffer, cols, ids_as_text))
                try:
                    lines = reader.take(len(raw), raw[cols.track_id] if reader.check is not None else None)
                finally:
                    reader.close()
    else:
        if fmt == "parquet":
            raw = pd.read_parquet(path_or_buffer)
        else:
            try:
                raw = pd.read_csv(path_or_buffer)
            except pd.errors.EmptyDataError:
                raise ValueError("The track file has no rows (it is empty)") from None
        cols = _resolve([str(c) for c in raw.columns], columns)
    table = normalise_table(raw, cols, first_appearance=ids_as_text and fmt == "csv" and is_path,
                       on_bad_row=on_bad_row, lines=lines, where="parquet" if fmt == "parquet" else "row")
    bad = table.attrs.get("bad_rows")
    if table.empty:
        raise ValueError("The track file has no rows with a time" if bad is None else
                         f"The track file has no row to read: {bad.summary()}")
    if bad is not None:
        warnings.warn(bad.summary(), BadRowWarning, stacklevel=2)
    return table


def _checked_column(path, cols: TrackColumns, ids_as_text: bool) -> int | None:
    """The header position of the id column, when pandas reads it as text (:class:`_CsvLines` compares the
    two readers' rows on it); None otherwise."""
    if not ids_as_text or cols.track_id is None:
        return None
    header = read_header(path, "csv")
    return header.index(cols.track_id) if header.count(cols.track_id) == 1 else None


def iter_track_chunks(path: str | os.PathLike, *, columns: TrackColumns | None = None,
                      chunk_rows: int = 1_000_000, format: str | None = None, ids_as_text: bool = False,
                      as_given: bool = False, on_bad_row: str = "fail", bad_texts: bool = False,
                      clock_resets=None) -> Iterator[pd.DataFrame]:
    """Read a huge CSV or Parquet track file in bounded memory, chunk by chunk.

    Chunks of at most `chunk_rows` file rows come in file order (pandas
    ``chunksize`` for CSV, ``pyarrow`` ``iter_batches`` for Parquet), each
    validated and normalised like :func:`read_tracks` (sorted by
    ``(track_id, time)`` *within* the chunk).

    Within a track, rows must come in increasing time order across chunks: a
    chunk cannot reorder rows already yielded, so a track whose time goes back
    (or repeats) across a chunk boundary raises ``ValueError``; sort the file
    first or use :func:`read_tracks`. Disorder inside one chunk is sorted with a
    warning as in :func:`read_tracks`. With ``time=None`` each track's row count
    continues across chunks.

    Parameters
    ----------
    path : path
        CSV (optionally ``.gz``) or Parquet file.
    columns : TrackColumns, optional
        Detected from the header if omitted.
    chunk_rows : int, default 1_000_000
        Maximum file rows per chunk.
    format : {'csv', 'parquet'}, optional
        Overrides the extension.
    ids_as_text : bool, default False
        Read a CSV id column as text exactly as written (see the module docstring).
    as_given : bool, default False
        Also keep each chunk's file rows as the file gave them, in ``chunk.attrs["as_given"]``
        (:class:`AsGiven`): a CSV time column is then read as text (the same numbers).
    on_bad_row : {'fail', 'skip'}, default 'fail'
        As in :func:`read_tracks`: ``'skip'`` leaves a bad row out of its chunk, lists it in
        ``chunk.attrs["bad_rows"]`` (:class:`BadRows`) and warns (:class:`BadRowWarning`) once a
        chunk; a chunk may then be empty.
    bad_texts : bool, default False
        Keep a skipped CSV row's line as written (:attr:`BadRows.texts`), for a file of rejects.
    clock_resets : callable or ClockResets, optional
        ``step(usual)``: a track's clock that restarts (:class:`ClockResets`) goes on after the rows
        before it by this step (a track's usual step given), instead of being sorted into them; the
        chunk lists its restarts in ``chunk.attrs["clock_resets"]``. A :class:`ClockResets`: that one
        (its tracks' clocks read after each chunk). None: sorted (as any disorder).

    Yields
    ------
    pandas.DataFrame
        Track table chunks (``track_id``, ``time``, positions); ``chunk.attrs["file_rows"]``
        is the number of file rows it was made from (a progress count).
    """
    if int(chunk_rows) < 1:
        raise ValueError(f"Expected chunk_rows >= 1, got {chunk_rows}")
    fmt = _format_of(path, format)
    cols = _resolve(read_header(path, fmt), columns)
    check_unique_columns(path, fmt, cols)
    last: dict = {}
    counts: dict | None = {} if cols.time is None else None
    time_kind: dict = {}
    clocks = None if clock_resets is None or cols.time is None else (
        clock_resets if isinstance(clock_resets, ClockResets) else ClockResets(clock_resets))
    offset = kept = skipped = 0
    lines = None
    with contextlib.ExitStack() as stack:
        if fmt == "parquet":
            import pyarrow.parquet as pq
            parquet = stack.enter_context(pq.ParquetFile(path))
            batches = ((b.to_pandas(), _given_column(b, cols.time) if as_given else None) for b in
                       parquet.iter_batches(batch_size=int(chunk_rows), columns=cols.names))
        else:
            reader = stack.enter_context(pd.read_csv(path, usecols=cols.names, chunksize=int(chunk_rows),
                                                     **csv_options(cols, ids_as_text, as_given)))
            batches = ((raw, None) for raw in reader)
            lines = _CsvLines(path, texts=bad_texts, check=_checked_column(path, cols, ids_as_text))
            stack.callback(lines.close)
        batches = iter(batches)
        following = next(batches, None)
        while following is not None:   # one batch ahead: whether a chunk is the file's last
            (raw, given_time), following = following, next(batches, None)
            if clocks is not None:
                clocks.more = following is not None
            if len(raw) == 0:
                continue
            where = None if lines is None else lines.take(
                len(raw), raw[cols.track_id] if lines.check is not None else None)
            chunk = normalise_table(raw, cols, offset, counts, first_appearance=ids_as_text and fmt == "csv",
                               as_given=as_given, given_time=given_time, on_bad_row=on_bad_row, lines=where,
                               time_kind=time_kind, where="parquet" if fmt == "parquet" else "row", clocks=clocks)
            bad = chunk.attrs.get("bad_rows")
            if bad is not None:
                skipped += len(bad)
                warnings.warn(bad.summary(), BadRowWarning, stacklevel=2)
            kept += len(chunk)
            firsts = chunk.groupby("track_id", sort=False)["time"].first()
            prev = firsts.index.map(last).to_numpy(np.float64, na_value=np.nan)
            back = prev >= firsts.to_numpy()
            if back.any():
                i = int(np.argmax(back))
                raise ValueError(
                    f"Track {firsts.index[i:i + 1].tolist()[0]!r}: time {firsts.iloc[i]} in the chunk "
                    f"starting at row {offset} is not after the time {prev[i]} already read; in a "
                    "chunked read each track's rows must come in increasing time order (sort the "
                    "file or use read_tracks)")
            last.update(chunk.groupby("track_id", sort=False)["time"].last().to_dict())
            offset += len(raw)
            chunk.attrs["file_rows"] = len(raw)  # rows read, before dropping rows without a time or repeated
            yield chunk
    if offset == 0:
        raise ValueError(f"The track file {os.fspath(path)!r} has no rows (only a header)")
    if kept == 0:
        raise ValueError(f"The track file {os.fspath(path)!r} has no rows with a time" + (
            f" ({skipped} bad row(s) skipped)" if skipped else ""))


def _given_column(batch, name: str | None) -> pd.Series | None:
    """A Parquet batch's column ``name`` as pandas gives it, but integers with nulls as nullable integers
    (pandas' default makes them floats: a frame number 7 would come back as 7.0); None where it needs no
    other reading than the batch's."""
    import pyarrow as pa

    if name is None:
        return None
    column = batch.column(batch.schema.get_field_index(name))
    if not (pa.types.is_integer(column.type) and column.null_count):
        return None
    return pd.Series(column.to_pandas(types_mapper=lambda kind: pd.api.types.pandas_dtype(
        str(kind).replace("int", "Int").replace("uInt", "UInt")) if pa.types.is_integer(kind) else None))


# --------------------------------------------------------------------------- arrays
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
    _require(list(df.columns), ["track_id", "time", *position_names], "to_arrays")
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
