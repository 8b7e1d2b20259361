"""One raw table (or chunk) of a file checked into the canonical sorted long track table: bad rows failed on or
skipped (:class:`BadRows`), rows without a time and repeated times dropped (:class:`DroppedRowWarning`), each
track's rows sorted by time, and the rows as the file gave them kept beside it (:class:`AsGiven`,
:func:`in_file_order`)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from .clock_resets import ClockResets
from .columns import TrackColumns
from .csv_lines import ChunkLines
from .values import bad_value, read_floats


def normalise_table(raw: pd.DataFrame, cols: TrackColumns, offset: int = 0,
               counts: dict | None = None, first_appearance: bool = False, as_given: bool = False,
               given_time: pd.Series | None = None, *, on_bad_row: str = "fail", lines: ChunkLines | None = None,
               time_kind: dict | None = None, where: str = "row", clocks: ClockResets | None = None,
               after: dict | None = None, geographic=None) -> pd.DataFrame:
    """Validate one raw table (or chunk) into the canonical sorted long table; ``as_given``: with its rows as
    the file gave them in ``attrs["as_given"]`` (:class:`AsGiven`; ``given_time``: the time column's values
    to keep, when not ``raw``'s own).

    A bad row (:data:`ON_BAD_ROW`: a field count not the header's, given in ``lines``; no track id; a time or
    position that is not a finite number, or a date-time for a time) raises a ``ValueError`` naming its line
    (``lines``) or row with ``on_bad_row="fail"``; with ``"skip"`` it is left out of the table, keeps its
    place in ``as_given`` as a row not stepped, and is listed in ``attrs["bad_rows"]`` (:class:`BadRows`).
    ``time_kind``: the time column's kind (numbers or date-times) across a file's chunks. ``clocks``: a
    track's clock that restarts starts a new segment (:class:`ClockResets`) instead of being sorted into the
    rows before it. ``after``: each track's last time in a file's chunks before this one; a row at or before it
    (a late row, which the chunks read cannot be reordered with) is left out like a row without a time, kept in
    ``as_given`` as a row not stepped, and counted in ``attrs["dropped"]["late"]``. ``geographic``: the positions'
    :class:`~kalmix.io.geo.GeoAxes`, whose latitude beyond ±90° or longitude beyond ±180° makes a bad row."""
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
    kind = {} if time_kind is None else time_kind
    read_times = None   # the times read, in file order (NaN: missing or bad)
    if cols.time is None:
        out["time"] = np.nan   # numbered below, once the bad rows are known
    else:
        column = raw[cols.time].reset_index(drop=True)
        read_times, wrong = read_floats(column, dates=True, kind=kind)
        out["time"] = read_times.copy()   # (the table's own: its times may be moved, those read are kept)
        mark(wrong, lambda i: bad_value(column, i, cols.time, True, kind))
    for p in cols.positions:
        column = raw[p].reset_index(drop=True)
        out[p], wrong = read_floats(column)
        mark(wrong, lambda i, column=column, p=p: bad_value(column, i, p))
    if geographic is not None:
        from .geo import beyond_degrees, degrees_problem

        degrees = out[list(cols.positions)].to_numpy(np.float64)
        mark(beyond_degrees(degrees, geographic), lambda i: degrees_problem(degrees[i], geographic, cols.positions))
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
    late = np.zeros(n, dtype=bool)
    if after:
        before = out["track_id"].map(after).to_numpy(np.float64, na_value=np.nan)
        behind = before >= out["time"].to_numpy()
        if behind.any():
            late[out.index.to_numpy()[behind]] = True
            out = out[~behind]
            warnings.warn(f"{int(behind.sum())} row(s) at or before their track's last time in the rows read "
                          "before: not predicted" + (" (their output rows have empty predictions)" if as_given else
                                                     ""), DroppedRowWarning, stacklevel=3)
    decreasing = (out["time"].groupby(out["track_id"], sort=False).diff() < 0).to_numpy()
    back = int(decreasing.sum())
    if back:
        first = out["track_id"].iloc[int(np.argmax(decreasing))]
        first = first.item() if isinstance(first, np.generic) else first   # 3, not np.int64(3)
        where = f" (the first in track {first!r})" if out["track_id"].nunique() > 1 else ""
        warnings.warn(f"Times decrease at {back} row(s) within tracks{where}; sorted each "
                      "track's rows by time (stable)", RuntimeWarning, stacklevel=3)
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
    out.attrs["dropped"] = {"untimed": int(no_time.sum()), "repeated": int(dup.sum()), "late": int(late.sum())}
    if clocks is not None and clocks.found:
        out.attrs["clock_resets"] = list(clocks.found)
    if as_given:
        out.attrs["as_given"] = AsGiven.of(raw, cols, sorted_places, dup, no_time | bad | late, given_time,
                                           read_times, kind.get("kind"))
    if bad.any():
        out.attrs["bad_rows"] = BadRows.of(raw, cols, np.flatnonzero(bad), why, offset, lines, named)
    return out.reset_index(drop=True)


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
        written (an empty time as NaN; ``NA`` as ``NA``), a Parquet column's own type (integers
        nullable). None for a column the file does not have.
    read_times : ndarray of float or None
        The times as read, ``rows`` values in file order: numbers, or a date-time's seconds since 1970
        UTC; NaN for a time that is missing or bad. None without a time column.
    time_kind : str or None
        The file's time column's kind, ``"number"`` or ``"date-time"``, as its first time that could be
        read (in this chunk or an earlier one) decided it; None before any, or for Parquet datetimes.
    places : ndarray of int, shape (len(chunk),)
        Each chunk row's file row (counted from the chunk's first).
    owner : ndarray of int, shape (rows,)
        For each file row, the chunk row whose fate it shares: itself where it is one; for an
        earlier row of a repeated time, the row kept for that time; for a row without a time
        or a bad row, that of the file row before it (or, at the chunk's start, after it); -1
        in a chunk without a row to step. A resumed run writes a file row only if that chunk
        row was stepped (not skipped as already done).
    """

    def __init__(self, rows, ids, times, places, owner, read_times=None, time_kind=None):
        self.rows, self.ids, self.times, self.places, self.owner = rows, ids, times, places, owner
        self.read_times, self.time_kind = read_times, time_kind

    def __deepcopy__(self, memo):   # in attrs, as _RowOrder: shared by the frames pandas derives, not copied
        return self

    @classmethod
    def of(cls, raw, cols, sorted_places, dup, no_time, given_time=None, read_times=None, time_kind=None) -> AsGiven:
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
        return cls(n, ids, times, sorted_places[~dup], owner, read_times, time_kind)


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
