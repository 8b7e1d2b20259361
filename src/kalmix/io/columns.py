"""Which columns of a track file hold the track id, the time and the positions: found by their names
(:func:`detect_columns`), and the notes a user hears about those not found (:func:`column_notes`,
:func:`id_candidates`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .values import MISSING_TEXT, iso_seconds, read_floats

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


def _header_hint(columns) -> str:
    """A hint when the column names look like a line of another format: one name holding another
    separator, or names that are all numbers (a first line of data, no header)."""
    if len(columns) == 1:
        separator = next((name for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars"))
                          if sep in columns[0]), None)
        if separator:
            sep = {"semicolons": "';', decimal=','", "tabs": "'\\t'", "bars": "'|'"}[separator]
            return (f" The header looks separated by {separator}: kalmix reads comma-separated CSV; convert it first "
                    f"(e.g. pandas.read_csv(path, sep={sep}).to_csv('tracks.csv', index=False)).")
    try:
        [float(name) for name in columns]
    except ValueError:
        return ""
    return " The column names are numbers: the first line must be a header (names, then rows)."


def require_columns(columns: Sequence[str], wanted: Sequence[str], what: str) -> None:
    missing = [c for c in wanted if c not in columns]
    if missing:
        raise ValueError(f"{what}: column(s) {missing} not found; available columns: {list(columns)}."
                         + _header_hint(list(columns)))


def match_columns(columns: Sequence[str], wanted: Sequence[str], what: str) -> list[str]:
    """The columns of ``columns`` that the names ``wanted`` (an option's, an argument's) name: a column of that
    exact name, else the one column whose name is that name ignoring case and surrounding spaces, as detection
    matches (``time`` names `` Time ``). ``ValueError`` naming ``what`` for a name that matches no column, or
    two columns only that way."""
    columns = [str(c) for c in columns]
    found, missing = [], []
    for name in map(str, wanted):
        if name in columns:
            found.append(name)
            continue
        key = name.strip().lower()
        matches = list(dict.fromkeys(c for c in columns if c.strip().lower() == key))
        if len(matches) > 1:
            raise ValueError(f"{what}: {name!r} matches the columns {matches[0]!r} and {matches[1]!r} (ignoring case "
                             "and surrounding spaces); name one of them exactly")
        if matches:
            found.append(matches[0])
        else:
            missing.append(name)
    require_columns(columns, missing, what)
    return found


def output_name(position) -> str:
    """The name a position column gives the columns predictions add (``pred_<name>``, ``std_<name>``, ...): its
    name without surrounding spaces (`` X `` gives ``pred_X``)."""
    return str(position).strip()


def check_output_names(columns: "TrackColumns") -> None:
    """``ValueError`` when a column that predictions keep (the id, the time, or ``row`` without a time
    column) has the name of a column they add: ``segment``, ``pred_<position>``, ``std_<position>``,
    ``lead_<position>``, ``lead_std_<position>``, ``pred<H>_<position>``, ``std<H>_<position>``; or when
    the two kept columns would share a name. Either would write two columns of one name."""
    import re

    positions = {output_name(name) for name in columns.positions}
    if len(positions) < len(columns.positions):
        raise ValueError(f"the position columns {list(columns.positions)} differ only by surrounding spaces, and the "
                         "columns predictions add are named from them without those (pred_<name>, ...); rename one in "
                         "the input")
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
    arguments win over detection and must name existing columns: a column of
    that exact name, else the one column that matches it as detection does.

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
        If an explicit name matches no column (or two, ignoring case and
        spaces), or no position columns are found.
    """
    columns = [str(c) for c in columns]
    lookup: dict[str, str] = {}
    for c in columns:
        lookup.setdefault(c.strip().lower(), c)
    if time is not None:
        time = match_columns(columns, [time], f"time={time!r} (--time)")[0]
    if track_id is not None:
        track_id = match_columns(columns, [track_id], f"track_id={track_id!r} (--id)")[0]
    if positions is not None:
        positions = (positions,) if isinstance(positions, str) else tuple(positions)
        positions = tuple(match_columns(columns, positions, f"positions={list(positions)} (--position)"))
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
                "Name them: --position a,b on the command line, position_names=[...] (process_table) or a "
                "TrackColumns(positions=(...)) in Python."
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


#: A column's values must change at least so many times between rows with positions (in the rows read) before
#: the positions' jumps there can say that it holds track ids ...
JUMP_CHANGES = 5
#: ... and the median step across a change be so many times the median step between one value's rows.
JUMP_RATIO = 10.0


def position_jumps(values: pd.Series, positions: np.ndarray, times: np.ndarray | None = None) -> str | None:
    """Why a column of whole numbers (``values``, rows in file order) holds track ids, from the positions
    ``(n, p)`` of the same rows; None when they do not say so. The rows whose value and positions are given are
    read in order: where the value changes (at least :data:`JUMP_CHANGES` times), the median step between
    consecutive rows is :data:`JUMP_RATIO` times the median step between consecutive rows of one value, for
    three in four of the values with three such steps or more (two at least), and likewise the step from a value's
    last row where it comes back, for three in four of the values that come back twice or more (where two do); and
    the values are not one after another (a value comes back after another, or the time goes back where the value
    changes): the rows of several targets, each moving a little, far apart. A status code, a count, a flag or a
    frame number changes where the positions move as usual (or jump to bad fixes that are each somewhere else); a
    trip or leg number of one track goes on in time."""
    missing = values.isna().to_numpy() | values.astype(str).str.strip().str.lower().isin(MISSING_TEXT).to_numpy()
    keep = ~missing & np.isfinite(positions).all(axis=1)
    if keep.sum() < 2 * JUMP_CHANGES:
        return None
    codes = pd.factorize(values[keep].astype(str))[0]
    where = positions[keep]
    steps = np.sqrt(((where[1:] - where[:-1]) ** 2).sum(axis=1))
    changes = codes[1:] != codes[:-1]
    if changes.sum() < JUMP_CHANGES:
        return None
    recurs = changes.sum() + 1 > codes.max() + 1
    if not recurs and times is not None:
        at = np.asarray(times, dtype=np.float64)[keep]
        recurs = bool((at[1:][changes] < at[:-1][changes]).any())
    if not recurs:
        return None
    across = float(np.median(steps[changes]))
    order = np.argsort(codes, kind="stable")   # each value's rows, in file order
    grouped, moved = codes[order], np.sqrt(((where[order][1:] - where[order][:-1]) ** 2).sum(axis=1))
    same = grouped[1:] == grouped[:-1]
    per_value = pd.Series(moved[same]).groupby(grouped[1:][same]).agg(["median", "size"])
    within = per_value.loc[per_value["size"] >= 3, "median"].to_numpy()
    if len(within) < 2 or not across > 0 or 4 * (JUMP_RATIO * within <= across).sum() < 3 * len(within):
        return None
    # where the value comes back, the step from that value's last row: a target's own track goes on there; a flag
    # on bursts of bad fixes (each burst somewhere else) or a count that drops during them does not
    last: dict = {}
    back: dict = {}
    for i, code in enumerate(codes.tolist()):
        if i and code != codes[i - 1] and code in last:
            back.setdefault(code, []).append(float(np.sqrt(((where[i] - where[last[code]]) ** 2).sum())))
        last[code] = i
    again = np.array([np.median(steps_back) for steps_back in back.values() if len(steps_back) >= 2])
    if len(again) >= 2 and 4 * (JUMP_RATIO * again <= across).sum() < 3 * len(again):
        return None

    def amount(step):
        return f"{step:,.0f}" if step >= 100 else f"{step:.3g}"

    return (f"whole numbers that change where the positions jump: a median step of {amount(across)} where the value "
            f"changes, {amount(float(np.median(within)))} between rows of one value")


def id_candidates(columns: TrackColumns, header: Sequence[str], sample: pd.DataFrame | None = None
                  ) -> list[tuple[str, str]]:
    """The columns of ``header`` that ``columns`` leaves unused and that look like a track id, each with why:
    its name (:func:`id_like_name`) or, in ``sample`` (the first rows of the file; None: names only), repeated
    text values (two or more different words, some on several rows), whole numbers that tell apart rows of
    one time (the time column repeats, and far less within each of the column's values), or whole numbers
    whose changes jump the positions (:func:`position_jumps`; ``sample`` holds the positions). Empty when
    ``columns`` has an id."""
    if columns.track_id is not None:
        return []
    found = []
    used = {columns.time, *columns.positions}
    times = None if sample is None or columns.time not in sample.columns else sample[columns.time]
    positions = seconds = None
    if sample is not None and all(name in sample.columns for name in columns.positions):
        positions = np.column_stack([read_floats(sample[name])[0] for name in columns.positions])
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
        elif kind == "integer" and 2 <= distinct < len(values) and times is not None:
            # (every value distinct: a row number, a saved pandas index, not tracks of one row each)
            pairs = pd.DataFrame({"id": column, "time": times}).dropna()
            repeated = int(pairs["time"].duplicated().sum())
            if repeated and 2 * int(pairs.duplicated().sum()) <= repeated:
                found.append((name, "whole numbers that tell apart rows of one time"))
                continue
        if kind == "integer" and distinct >= 2 and positions is not None:
            if seconds is None and times is not None:   # (only to tell whether the time goes back)
                seconds = read_floats(times, dates=True)[0]
            why = position_jumps(column, positions, seconds)
            if why is not None:
                found.append((name, why))
    return found
