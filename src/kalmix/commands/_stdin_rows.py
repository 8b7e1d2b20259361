"""A stdin line of ``kalmix predict -`` as a row: its track, time and positions parsed and checked, or, with
``--on-bad-row skip``, a :class:`BadLine` that says why it is not stepped."""

from __future__ import annotations

import contextlib
import csv
import json
import math

from typing import Any, NamedTuple

import numpy as np

from ..io.values import GZIP_MAGIC, as_bytes, not_unicode, not_utf8, utf16_without_bom
from ._stdin_lines import Unclosed


def _convert(source: str) -> str:
    """How to convert stdin from the encoding ``source`` (``iconv``'s name) to UTF-8."""
    return f"convert the input to UTF-8 first (... | iconv -f {source} -t utf-8 | kalmix predict -)"


def _check_utf8(value, column, line_number) -> None:
    """A ``ValueError`` naming line ``line_number`` when ``value`` is text of bytes that are not UTF-8 (read with
    ``surrogateescape``: a line's other columns may hold such bytes, a column used may not)."""
    if not_unicode(value):
        why, source = not_utf8(column, value)
        raise ValueError(f"line {line_number}: {why}; {_convert(source)}")


def _parse_number(text, column, line_number):
    if text is None:
        return math.nan
    _check_utf8(text, column, line_number)
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        try:
            value = float(text)
        except OverflowError:   # a JSON integer beyond any float
            raise ValueError(f"line {line_number}: column {column!r} must be finite, got an integer of "
                             f"{len(str(abs(text)))} digits") from None
    else:
        stripped = str(text).strip()
        if stripped.lower() in ("", "nan", "na", "n/a", "null", "none", "nat"):
            return math.nan
        try:
            value = float(stripped)
        except ValueError:
            raise ValueError(f"line {line_number}: column {column!r} must hold a number, got {text!r}") from None
    if math.isinf(value):
        raise ValueError(f"line {line_number}: column {column!r} must be finite, got {text!r}")
    return value


def _parse_time(text, column, line_number):
    """A row's time: a number, or text left for :func:`_dated` (ISO 8601 date-times, converted together)."""
    _check_utf8(text, column, line_number)
    try:
        return _parse_number(text, column, line_number)
    except ValueError:
        if not isinstance(text, str):
            raise
    return text.strip()


def _dated(rows, column, bad=None):
    """``rows`` (line, track, time, positions, time as given) with their ISO 8601 time text as seconds since
    1970 UTC, all in one conversion (as in a file: the same bits); cut before the first that is not a
    date-time, with its error, or with ``bad(row, reason)`` each such row replaced by what it gives."""
    from ..io.tables import iso_seconds

    at = [k for k, row in enumerate(rows) if isinstance(row[2], str)]
    if not at:
        return rows, None
    seconds = iso_seconds([rows[k][2] for k in at], errors="coerce")
    out = list(rows)
    for k, value in zip(at, seconds):
        number, track, text, values, given = rows[k][:5]
        if math.isnan(value):
            reason = (f"column {column!r} must hold a number or an ISO 8601 date-time (like "
                      f"2024-05-01T12:00:00.5Z), got {text!r}")
            if bad is not None:
                out[k] = bad(rows[k], reason)
                continue
            return out[:k], ValueError(f"line {number}: {reason}")
        out[k] = (number, track, float(value), values, given)
    return out, None


def _parse_id(value, column, line_number):
    """A track id as written: CSV text unchanged (``01`` is not ``1``, as in a file), a JSON value as parsed."""
    if value is None or value == "" or isinstance(value, (dict, list, bool)):   # (true would be track 1)
        raise ValueError(f"line {line_number}: column {column!r} (track id) must hold an id (text or a number), "
                         f"got {json.dumps(value) if isinstance(value, bool) else repr(value)}")
    _check_utf8(value, column, line_number)
    return value


def json_line(raw, number) -> dict:
    """A JSON-lines record, or a ``ValueError`` naming line ``number``."""
    try:
        record = json.loads(raw)
    except (json.JSONDecodeError, RecursionError) as error:
        raise ValueError(f"line {number}: not valid JSON: {error}") from None
    if not isinstance(record, dict):
        raise ValueError(f"line {number}: expected a JSON object, got {raw.strip()[:80]!r}")
    return record


class BadLine(NamedTuple):
    """A stdin line skipped as bad (``--on-bad-row skip``): its row's first five fields as :meth:`RowReader.row_of`'s
    (positions None: not stepped; track and time as given, where they could be read), why, and its text."""

    line: int
    track: Any
    time: float
    values: None
    given: Any
    reason: str
    text: str


class IdColumnError(ValueError):
    """The input has a column that looks like track ids but none is named: the run stops (not a bad row)."""


def _csv_line(fields) -> str:
    """CSV fields as one line (without its end)."""
    import io

    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="").writerow(fields)
    return buffer.getvalue()


def _is_date(text) -> bool:
    """Whether a stdin time's text is an ISO 8601 date-time (:func:`kalmix.io.tables.iso_seconds`)."""
    from ..io.tables import iso_seconds

    return not math.isnan(iso_seconds([text], errors="coerce")[0])


class _IdColumnWatch:
    """On stdin, whose rows are not there to be read ahead: without an id column (none named, detected or
    taken from its name), an unused column whose first rows show two different words (text that is not a
    number, a date or true/false) stops the run with the error a file gives, at the line that shows the
    second word, before it is stepped: the rows before it were all one word's, one track."""

    ROWS = 1_000   # lines watched

    def __init__(self, columns, header, id_column):
        single = id_column is not None and id_column.strip().lower() == "none" and id_column not in header
        used = {columns.time, *columns.positions}
        self.names = [] if columns.track_id is not None or single else [name for name in header if name not in used]
        self.seen: dict = {}   # column -> the words seen in it
        self.other: set = set()   # values that are not words
        self.left = self.ROWS

    def check(self, number, record, get):
        if not self.names or self.left <= 0:
            return
        from ..io.tables import looks_like_a_word

        self.left -= 1
        for name in self.names:
            try:
                value = get(record, name, number)
            except (ValueError, IndexError):
                continue
            if not isinstance(value, str) or value in self.seen.get(name, ()) or value in self.other:
                continue
            if not looks_like_a_word(value):
                if len(self.other) < self.ROWS:
                    self.other.add(value)   # (each value judged once: a date repeated on every line)
                continue
            words = self.seen.setdefault(name, [])
            words.append(value)
            if len(words) >= 2:
                shown = ", ".join(repr(word) for word in words[:3])
                raise IdColumnError(f"line {number}: no track id column named or detected, and column {name!r} "
                                    f"looks like one (different text values: {shown}). Without an id every row is "
                                    f"one track, the tracks' rows mixed: pass --id {name}, or --id none if the "
                                    "input holds a single track")


def header_of(first, number):
    """What stdin's first line ``first`` (line ``number``) says: whether the lines are JSON, the column names (a CSV
    header's, or the keys of a JSON-lines record), and the rows it already holds as ``(line, record)`` (a JSON
    record is the first row; a CSV header none)."""
    start = as_bytes(first)
    if start.startswith(GZIP_MAGIC):
        raise ValueError(f"line {number}: the input looks gzip-compressed (it starts with the bytes 1f 8b); "
                         "decompress it first (zcat FILE | kalmix predict -), or pass the .gz file's path, which "
                         "kalmix reads directly")
    wide = utf16_without_bom(start) if "\0" in first else None
    if wide:
        raise ValueError(f"line {number}: the input looks like {wide.upper()} text without a byte order mark "
                         f"(every other byte is zero); {_convert(wide)}")
    is_json = first.lstrip().startswith("{")
    if is_json:
        record = json_line(first, number)
        header, rows = list(record), [(number, record)]
    else:
        try:
            header, rows = next(csv.reader([first])), []
        except csv.Error as error:
            raise ValueError(f"line {number}: not a CSV header: {error}") from None
    for name in header:   # (the names come back in the output: a file's header must be UTF-8 too)
        if not_unicode(name):
            why, source = not_utf8(name, name, "a key" if is_json else "the header")
            raise ValueError(f"line {number}: {why}; {_convert(source)}")
    return is_json, header, rows


class RowReader:
    """Stdin's lines as rows ``(line, track, time, positions, time as given)``, by the header's ``columns``.

    A line that does not parse, or whose values are not an id, a time and positions, raises a
    ``ValueError`` naming it, or with ``skip`` (``--on-bad-row skip``) gives a :class:`BadLine`.
    ``axes``: the positions' geographic axes (latitudes and longitudes are checked), or None;
    ``engine`` numbers the rows of a track without a time column on from a resumed state's;
    ``ids`` (:class:`._predict_notes.IdWatch`) sees every track id read.
    """

    def __init__(self, columns, header, is_json, id_column, axes, engine, ids, skip):
        self.columns, self.header, self.is_json = columns, header, is_json
        self.axes, self.engine, self.ids, self.skip = axes, engine, ids, skip
        self.index = {name: i for i, name in enumerate(header)}
        self.counts: dict = {}   # a track's next row number (no time column)
        self.time_kind: dict = {}   # "kind": numbers or date-times, fixed by the first time
        self.dated_texts: dict = {}   # line -> record of a row whose time is text, for a rejects file
        self.words = _IdColumnWatch(columns, header, id_column)

    def parse(self, raw, number):
        if self.is_json:
            return json_line(raw, number)
        if isinstance(raw, Unclosed):   # (a record that goes on to the next lines comes whole: CsvRecords)
            raise ValueError(f"line {number}: a quoted field is not closed (a stray '\"'?)")
        try:
            row = next(csv.reader([raw]))
        except csv.Error as error:
            raise ValueError(f"line {number}: not a CSV row: {error}") from None
        if len(row) != len(self.header):
            raise ValueError(f"line {number}: expected {len(self.header)} fields like the header, got {len(row)}")
        return row

    def get(self, record, name, number):
        if self.is_json:
            if name not in record:
                raise ValueError(f"line {number}: key {name!r} missing (keys: {list(record)})")
            return record[name]
        return record[self.index[name]]

    def row_of(self, number, record):
        """(line, track, time, positions, time as given) of a record; positions None for a row without a time
        (not stepped). A ``ValueError`` for a bad row (which takes no row number, and does not fix the time
        column's kind)."""
        columns, get, counts, time_kind = self.columns, self.get, self.counts, self.time_kind
        track = _parse_id(get(record, columns.track_id, number), columns.track_id, number) if columns.track_id else 0
        self.ids.see(track)
        if columns.time is None:
            values = [_parse_number(get(record, name, number), name, number) for name in columns.positions]
            if self.axes is not None:
                self.check_degrees(values, number)
            gaps = self.engine.gaps
            time = float(counts.get(track, gaps[track].last_time + 1 if track in gaps else 0))
            counts[track] = time + 1
            return number, track, time, values, int(time)
        given = get(record, columns.time, number)
        time = _parse_time(given, columns.time, number)
        if not isinstance(time, str) and math.isnan(time):   # text: a date-time, see _dated
            return number, track, time, None, given
        kind = "date-time" if isinstance(time, str) else "number"
        if time_kind.get("kind", kind) != kind:   # one or the other, as in a file
            raise ValueError(f"line {number}: column {columns.time!r} holds a {kind} ({given!r}) where its first "
                             f"time is a {time_kind['kind']}; expected one or the other")
        if kind == "date-time" and "kind" not in time_kind and not _is_date(time):   # (later ones: _dated)
            raise ValueError(f"line {number}: column {columns.time!r} must hold a number or an ISO 8601 date-time "
                             f"(like 2024-05-01T12:00:00.5Z), got {time!r}")
        values = [_parse_number(get(record, name, number), name, number) for name in columns.positions]
        if self.axes is not None:
            self.check_degrees(values, number)
        time_kind.setdefault("kind", kind)
        if kind == "date-time" and self.skip:
            self.dated_texts[number] = record   # for a rejects file, should _dated find it is no date
        return number, track, time, values, given

    def check_degrees(self, values, number) -> None:
        """A ``ValueError`` naming line ``number`` when its latitude is beyond ±90° or its longitude beyond ±180°."""
        from ..io.geo import check_degrees

        check_degrees(np.array([values]), self.axes, self.columns.positions, lambda i: f"line {number}")

    def read(self, number, raw, record=None):
        """A line's row (:meth:`row_of`), or with --on-bad-row skip its :class:`BadLine`; ``record``: the line
        parsed already."""
        try:
            if record is None:
                record = self.parse(raw, number)
            self.words.check(number, record, self.get)   # (a column that looks like ids: not a bad row, the input's)
            return self.row_of(number, record)
        except ValueError as bad:
            if not self.skip or isinstance(bad, IdColumnError):
                raise
            return self.bad_row(number, raw, record, bad)

    def bad_row(self, number, raw, record, error) -> BadLine:
        """A bad line's row: not stepped, its id and time as given where they can be read (else empty)."""
        columns = self.columns
        track = given = None
        if record is not None:
            with contextlib.suppress(ValueError, IndexError, KeyError, TypeError):
                track = _parse_id(self.get(record, columns.track_id, number), columns.track_id, number) \
                    if columns.track_id else 0
            with contextlib.suppress(ValueError, IndexError, KeyError, TypeError):
                given = self.get(record, columns.time, number) if columns.time else None
            given = None if not_unicode(given) else given   # (not written: no UTF-8 output can hold it)
        reason = str(error)
        prefix = f"line {number}: "
        text = str(raw).rstrip("\r\n")
        if not_unicode(text):   # its bytes that are not UTF-8 as \xe9, in a rejects file
            text = as_bytes(text).decode("utf-8", "backslashreplace")
        return BadLine(number, track, math.nan, None, given, reason[len(prefix):] if reason.startswith(prefix)
                       else reason, text)

    def undated_row(self, row, reason) -> BadLine:
        """The :class:`BadLine` of a row whose time text is not a date-time after all (:func:`_dated`)."""
        record = self.dated_texts.get(row[0])
        text = "" if record is None else json.dumps(record) if self.is_json else _csv_line(record)
        return BadLine(row[0], row[1], math.nan, None, row[4], reason, text)

    def dates(self, rows):
        """``rows`` with their date-time texts as seconds (:func:`_dated`): with ``skip``, a text that is not one
        makes its row a :class:`BadLine`; else the rows are cut before it, and its error returned with them."""
        out = _dated(rows, self.columns.time, self.undated_row if self.skip else None)
        self.dated_texts.clear()
        return out
