"""The ``-o`` file (or stdout) of ``kalmix predict``, written one committed piece at a time.

:class:`Output` keeps the byte and line count of the last commit, which the state file
records (:mod:`._durable`); a resumed run checks the file against that record and continues
it. The text of a piece: :func:`csv_text` and :func:`jsonl_text` for a table, :func:`csv_value`
and :func:`json_value` for one value.
"""

from __future__ import annotations

import contextlib
import decimal
import json
import math
import os
import stat
import sys

import numpy as np

__all__ = ["json_value", "csv_value", "jsonl_text", "csv_text", "OutputClosed", "Output"]


def json_value(value):
    """A prediction value for JSON lines: NaN/inf as null, numpy scalars as Python numbers, dates, times and
    durations (Parquet id columns) in ISO 8601 (NaT and pandas' NA as null), decimals as their text, bytes as
    UTF-8 text (a byte that is not UTF-8 as ``\\xe9``)."""
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(value) else float(value)
    if isinstance(value, (np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (np.datetime64, np.timedelta64)):
        import pandas as pd

        value = (pd.Timestamp if isinstance(value, np.datetime64) else pd.Timedelta)(value)
    if hasattr(value, "isoformat"):
        return None if value != value else value.isoformat()   # NaT is not equal to itself
    if isinstance(value, bytes):
        return value.decode("utf-8", "backslashreplace")
    if isinstance(value, decimal.Decimal):
        return str(value)
    if type(value).__name__ == "NAType":   # pandas' missing value of text and nullable columns
        return None
    return value


def csv_value(value) -> str:
    """A prediction value for a CSV line: NaN and None as an empty field, floats round-tripping, text quoted."""
    if value is None:
        return ""
    if isinstance(value, (float, np.floating)):
        return "" if math.isnan(value) else repr(float(value))
    text = str(value)
    if any(c in text for c in ',"\n\r'):
        text = '"' + text.replace('"', '""') + '"'
    return text


def _arrow_writes_as_pandas(frame) -> bool:
    """True when Arrow's CSV text of ``frame`` reads back as pandas' would: two columns or more (a lone
    empty field would be a blank line), each float64, integer, bool or text (not dates, bytes, objects)."""
    from pandas.api.types import infer_dtype

    if frame.shape[1] < 2:
        return False
    for name in frame.columns:
        kind = frame[name].dtype.kind
        if kind in "iub" or frame[name].dtype == np.float64:
            continue
        if kind in "OU" or str(frame[name].dtype).startswith("string"):
            if infer_dtype(frame[name], skipna=True) in ("string", "empty"):
                continue
        return False
    return True


def _json_column(column) -> list[str]:
    """A column's values as JSON text, each as ``json.dumps(json_value(value))`` writes the record's value
    (pandas' Python scalars): numpy floats as their ``repr`` (what ``json`` writes) or ``null``, numpy
    integers as digits, any other column value by value."""
    if isinstance(column.dtype, np.dtype) and column.dtype.kind in "fiu":
        values = column.to_numpy()
        if values.dtype.kind in "iu":
            return [str(v) for v in values.tolist()]
        values = values.astype(np.float64)
        return [repr(v) if ok else "null" for v, ok in zip(values.tolist(), np.isfinite(values).tolist())]
    return [json.dumps(json_value(v)) for v in column.tolist()]


def jsonl_text(frame) -> str:
    """``frame`` as JSON lines, the text ``json.dumps`` gives each record (its ``json_value`` of each value),
    built column by column (faster than record by record)."""
    if frame.shape[1] == 0:
        return "{}\n" * len(frame)
    keys = [json.dumps({name: 0})[1:-4] + ": " for name in frame.columns]   # a key as json writes it
    columns = [[key + text for text in _json_column(frame.iloc[:, i])] for i, key in enumerate(keys)]
    return "".join("{" + ", ".join(row) + "}\n" for row in zip(*columns))


def _bytes_as_text(frame):
    """``frame`` with its columns of bytes (a Parquet file's binary ids) as the text JSON lines write
    (:func:`json_value`: UTF-8), not Python's ``b'...'``."""
    from pandas.api.types import infer_dtype

    binary = [i for i in range(frame.shape[1]) if frame.iloc[:, i].dtype == object
              and infer_dtype(frame.iloc[:, i], skipna=True) == "bytes"]
    if binary:
        frame = frame.copy()
        for i in binary:
            frame.isetitem(i, frame.iloc[:, i].map(json_value, na_action="ignore"))
    return frame


def csv_text(frame, header: bool) -> str:
    """``frame`` as CSV lines (``header`` first): Arrow's writer (much faster than pandas' ``to_csv``), floats
    round-tripping, NaN as an empty field; pandas' writer when a value or name needs quotes, or for
    columns Arrow writes otherwise (dates, other objects); bytes as JSON lines write them (:func:`json_value`)."""
    import pyarrow as pa
    import pyarrow.compute as pa_compute
    import pyarrow.csv as pa_csv

    frame = _bytes_as_text(frame)
    if not _arrow_writes_as_pandas(frame):
        return frame.to_csv(None, index=False, header=header, lineterminator="\n")
    head = ",".join(csv_value(name) for name in frame.columns) + "\n" if header else ""
    try:
        columns = []
        for name in frame.columns:
            if not isinstance(frame[name].dtype, np.dtype) and frame[name].dtype.kind in "iub":
                # a nullable integer (the segment of a row not stepped): numpy would make it floats
                columns.append(pa.array(frame[name]))
                continue
            values = frame[name].to_numpy()
            column = pa.array(values, from_pandas=True)
            if values.dtype.kind == "f" and np.any(np.isfinite(values) & (values == np.round(values))):
                # Arrow writes 1.0 as "1", which a reader would take for an integer: "1.0" as Python does
                text = pa_compute.cast(column, pa.string())
                plain = pa_compute.invert(pa_compute.match_substring_regex(text, "[.eEn]"))
                column = pa_compute.if_else(plain, pa_compute.binary_join_element_wise(text, ".0", ""), text)
            columns.append(column)
        sink = pa.BufferOutputStream()
        table = pa.table({str(i): column for i, column in enumerate(columns)})
        pa_csv.write_csv(table, sink,
                         pa_csv.WriteOptions(include_header=False, quoting_style="none"))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):   # text with , " or a line end
        return frame.to_csv(None, index=False, header=header, lineterminator="\n")
    return head + sink.getvalue().to_pybytes().decode("utf-8")


def _typed(table, types):
    """A Parquet piece that fits ``types``: a schema (the file's, once written), whose types a column of the piece
    with another takes (a column without values, Arrow's null type, as nulls of that type; any other cast as Arrow
    casts safely, left as it is where it cannot be), or a dict of types by name, which only columns without
    values take. So a piece whose id or time happens to have no value, or a value read otherwise, fits the file
    instead of failing it midway."""
    import pyarrow as pa

    every = isinstance(types, pa.Schema)
    for name in types.names if every else list(types):
        i = table.schema.get_field_index(name)
        want = types.field(name).type if every else types[name]
        if i < 0 or table.schema.field(i).type == want or not (every or pa.types.is_null(table.schema.field(i).type)):
            continue
        column = table.column(i)
        try:
            column = pa.nulls(len(column), want) if pa.types.is_null(column.type) else column.cast(want)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
            continue
        table = table.set_column(i, table.schema.field(i).with_type(want), column)
    return table


class OutputClosed(Exception):
    """The reader of stdout went away (broken pipe)."""


def _count_newlines(path: str, upto: int | None = None) -> int:
    count, left = 0, upto
    with open(path, "rb") as handle:
        while left is None or left > 0:
            block = handle.read(1 << 20 if left is None else min(1 << 20, left))
            if not block:
                break
            count += block.count(b"\n")
            if left is not None:
                left -= len(block)
    return count


class Output:
    """``-o`` (or stdout) written one committed piece at a time; see the module docstring.

    Parameters
    ----------
    path : str or None
        Output file; None for stdout.
    fmt : {"csv", "jsonl", "parquet"}
    previous : dict or None
        What the state file recorded about its output (:meth:`record` of the run that saved it).
    resuming : bool
        A state file was loaded: an existing non-empty ``path`` must be the output it recorded,
        which is then checked and continued; otherwise ``path`` is written from scratch.
    state_path : str or None
        For messages.
    note : callable
        Prints a one-line note to the user.
    """

    def __init__(self, path, fmt, *, previous=None, resuming=False, state_path=None, note=print):
        self.path, self.fmt = path, fmt
        self.bytes = self.lines = self.rows = 0
        self.header_written = False
        self._handle = None
        self._parquet = None
        self._parquet_empty = None   # an empty table, written at close if no rows come (see write_frame)
        #: Parquet: the types of columns a piece may give without one (every value missing, in a column of
        #: Python objects), by name: the input's own, for its id and time columns
        self.types: dict = {}
        self._regular = False
        self._failed = False
        self._created = False
        self._empty_first = False
        if path is None:
            self._handle = sys.stdout
            return
        start = self._resume_point(previous, state_path, note) if resuming else None
        if fmt == "parquet":
            return  # the writer opens with the first chunk, when the schema is known
        self._created = start is None and not os.path.lexists(path)   # removed again if nothing is written
        try:
            if start is None:   # an existing file is emptied at the first write: a run that fails before keeps it
                self._handle = open(path, "ab")
                self._empty_first = True
            else:
                self._handle = open(path, "r+b")
                self._handle.truncate(start[0])
                self._handle.seek(start[0])
                self.bytes, self.lines = start
                self.header_written = start[0] > 0
        except OSError as error:
            raise ValueError(f"--output: cannot open {path!r}: {error.strerror or error}") from None
        self._regular = stat.S_ISREG(os.fstat(self._handle.fileno()).st_mode)

    def _resume_point(self, previous, state_path, note):
        """(bytes, lines) to continue ``path`` from, or None to write it from scratch."""
        path = self.path
        regular = os.path.isfile(path)
        recorded = isinstance(previous, dict) and previous.get("path") == os.path.realpath(path)
        if not regular or (os.path.getsize(path) == 0 and not (recorded and previous.get("bytes"))):
            if recorded and not os.path.exists(path) and previous.get("lines"):
                note(f"{path} (recorded in {state_path}) is gone; writing a new file from the rows still to come")
            return None
        if not recorded:
            was = previous.get("path") if isinstance(previous, dict) else None
            raise ValueError(f"--output: {path!r} exists and is not the output recorded in the state file "
                             f"{state_path!r} (that is {was or 'stdout'}); give a new -o name, remove the file, "
                             "or use a new --state file")
        if self.fmt == "parquet" or previous.get("format") == "parquet":
            raise ValueError(f"--output: a Parquet file cannot be continued ({path!r} was written before with "
                             f"{state_path!r}); give a new -o name (or CSV / JSON lines, which are continued)")
        want_bytes, want_lines = int(previous.get("bytes", 0)), int(previous.get("lines", 0))
        size = os.path.getsize(path)
        if size < want_bytes:
            raise ValueError(f"--output: {path!r} holds {size} bytes but the state file {state_path!r} recorded "
                             f"{want_bytes} written: the file was truncated or replaced; give a new -o name")
        lines = _count_newlines(path, want_bytes)
        if lines != want_lines:
            raise ValueError(f"--output: {path!r} holds {lines} lines in its first {want_bytes} bytes but the state "
                             f"file {state_path!r} recorded {want_lines}: the file was modified; give a new -o name")
        if size > want_bytes:
            extra = _count_newlines(path) - lines
            note(f"{path}: dropped the last {extra} line(s), written after the last state save; they are "
                 "computed again")
        return want_bytes, want_lines

    # -- writing ------------------------------------------------------------------------
    def write_frame(self, frame) -> None:
        """Write a table of predictions as one piece (all of it, or on failure nothing)."""
        if self.fmt == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq
            table = _typed(pa.Table.from_pandas(frame, preserve_index=False),
                           self.types if self._parquet is None else self._parquet.schema)
            if self._parquet is None and not len(frame):
                # no rows (a resumed run's chunks already done): its empty columns have no type, and a writer made
                # from them would refuse the first real rows ("schema does not match"); the file is made at the
                # first rows, or from this at close if none come
                self._parquet_empty = table
                return
            try:
                if self._parquet is None:
                    self._parquet = pq.ParquetWriter(self.path, table.schema)
                self._parquet.write_table(table)
            except OSError as error:
                self._failed = True
                raise ValueError(f"--output: cannot write {self.path!r}: {error}") from None
            self.rows += len(frame)
            return
        if self.fmt == "jsonl":
            text = jsonl_text(frame)
        else:
            text = csv_text(frame, header=not self.header_written)
        self._write(text, len(frame))

    def write_records(self, records: list[dict]) -> None:
        """Write prediction rows (dicts with the same keys) as one piece."""
        if not records:
            return
        if self.fmt == "jsonl":
            text = "".join(json.dumps({k: json_value(v) for k, v in record.items()}) + "\n" for record in records)
        else:
            head = "" if self.header_written else ",".join(csv_value(k) for k in records[0]) + "\n"
            text = head + "".join(",".join(csv_value(v) for v in record.values()) + "\n" for record in records)
        self._write(text, len(records))

    def write_header(self, names) -> None:
        """A CSV header line alone (a run that wrote no row)."""
        self._write(",".join(csv_value(name) for name in names) + "\n", 0)

    def _write(self, text: str, rows: int) -> None:
        if not text:
            return
        data = text if self._handle is sys.stdout else text.encode("utf-8")
        try:
            if self._empty_first:
                if self._regular:
                    self._handle.truncate(0)
                self._empty_first = False
            self._handle.write(data)
            self._handle.flush()
        except BrokenPipeError:
            self._failed = True
            raise OutputClosed() from None
        except OSError as error:
            self._failed = True
            self._undo()
            name = "stdout" if self.path is None else repr(self.path)
            raise ValueError(f"--output: cannot write {name}: {error.strerror or error}") from None
        self.bytes += len(data)
        self.lines += text.count("\n")
        self.rows += rows
        self.header_written = True

    def _undo(self) -> None:
        """After a failed write: cut a regular file back to the last commit (best effort)."""
        if self._regular:
            with contextlib.suppress(OSError, ValueError):
                self._handle.seek(self.bytes)
                self._handle.truncate(self.bytes)

    def sync(self) -> None:
        """Flush and fsync a regular output file, so a state saved next never claims more than is on disk."""
        if self._regular and not self._failed:
            try:
                self._handle.flush()
                os.fsync(self._handle.fileno())
            except OSError as error:
                self._failed = True
                raise ValueError(f"--output: cannot write {self.path!r}: {error.strerror or error}") from None

    def record(self) -> dict | None:
        """What the state file keeps about this output (None for stdout)."""
        if self.path is None:
            return None
        entry = {"path": os.path.realpath(self.path), "format": self.fmt, "rows": self.rows}
        if self.fmt != "parquet":
            entry.update(bytes=self.bytes, lines=self.lines)
        return entry

    def discard_if_empty(self) -> None:
        """Close after a failure: a file this run created and wrote nothing to is removed, a file that was there
        before and not written to yet is left as it was (a run that fails before its first row changes nothing)."""
        self._empty_first = False
        self._parquet_empty = None
        self.close()
        if self._created and self.bytes == 0:
            with contextlib.suppress(OSError):
                os.unlink(self.path)

    def close(self) -> None:
        if self._empty_first and self._regular:   # nothing written: the file holds this run's nothing
            with contextlib.suppress(OSError):
                self._handle.truncate(0)
        self._empty_first = False
        if self._parquet is None and self._parquet_empty is not None and not self._failed:
            import pyarrow.parquet as pq

            try:
                pq.write_table(self._parquet_empty, self.path)
            except OSError as error:
                raise ValueError(f"--output: cannot write {self.path!r}: {error}") from None
            self._parquet_empty = None
        if self._parquet is not None:
            with contextlib.suppress(OSError) if self._failed else contextlib.nullcontext():
                self._parquet.close()
        if self._handle is not None and self._handle is not sys.stdout:
            try:
                self._handle.close()
            except OSError as error:
                if not self._failed:
                    raise ValueError(f"--output: cannot write {self.path!r}: {error.strerror or error}") from None
