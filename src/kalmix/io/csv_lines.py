"""Each data row's line in a CSV file, its field count and text, read beside pandas' reader (which does not say
where a row's line is, pads a short row and takes a long one as it is)."""

from __future__ import annotations

import contextlib
import os
from typing import NamedTuple

import numpy as np
import pandas as pd

from .values import UTF16_BOMS, utf16_without_bom


class ChunkLines(NamedTuple):
    """A CSV chunk's rows as :class:`CsvLines` read them: each row's line (counted from 1 with the header),
    field count and, when kept, text; ``width``: the header's field count. ``lines`` and ``fields`` are None
    where the two readers did not agree (rows are then named by their number)."""

    lines: np.ndarray | None
    fields: np.ndarray | None
    width: int
    texts: list | None


class CsvLines:
    """The physical line, field count and (``texts``) text of each data row of a CSV file, read alongside
    pandas' reader with Python's csv module: pandas gives the values, but pads a short row with missing
    values and, reading some columns, takes a long one as it is, and does not say where a row's line is.

    Blank lines are skipped as pandas skips them. Should the two readers ever disagree on the rows (a
    chunk's last row not the same id, or the file ending early here), the lines are dropped from there
    on: rows are then named by their number, and field counts not checked."""

    def __init__(self, path, texts: bool = False, check: int | None = None):
        import csv

        self.handle = _open_text(path, "replace")
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

    def take(self, n: int, checked: pd.Series | None = None) -> ChunkLines:
        """The next ``n`` rows; ``checked``: pandas' values of column :attr:`check` for them (text)."""
        if not self.ok:
            return ChunkLines(None, None, self.width, None)
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
            return ChunkLines(None, None, self.width, None)
        return ChunkLines(lines, fields, self.width, texts)

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


def _open(path, mode: str, **options):
    """A CSV file opened as ``open`` does, through gzip when its name ends in ``.gz``."""
    import gzip

    return (gzip.open if os.fspath(path).lower().endswith(".gz") else open)(path, mode, **options)


def _open_text(path, errors: str):
    """A CSV file (``.gz``: compressed) as UTF-8 text, a byte order mark taken off; ``errors`` as ``open``'s."""
    return _open(path, "rt", encoding="utf-8-sig", errors=errors, newline="")


def _start(path, size: int) -> bytes:
    with _open(path, "rb") as handle:
        return handle.read(size)


def binary(path) -> bool:
    """Whether a file that is not UTF-8 is no text at all (a zero byte in its first 4 KB, as text in UTF-16 has,
    neither after UTF-16's byte order mark nor in every other place as UTF-16 without it has)."""
    start = _start(path, 4096)
    return b"\0" in start and start[:2] not in UTF16_BOMS and utf16_without_bom(start) is None


def utf16_file(path) -> bool:
    """Whether a file's first 4 KB look like UTF-16 without a byte order mark
    (:func:`kalmix.io.values.utf16_without_bom`): read as UTF-8, its every other character is a zero."""
    return utf16_without_bom(_start(path, 4096)) is not None


def _first_not_utf8(path, names):
    """``(line, why, encoding)`` of the first place where a CSV file's header, or a column of ``names`` in its
    rows, holds bytes that are not UTF-8 (:func:`kalmix.io.values.not_utf8`); None where none is found."""
    import csv

    from .values import not_unicode, not_utf8

    with _open_text(path, "surrogateescape") as handle:
        reader = csv.reader(handle)
        try:
            header = next(reader, [])
            for column in header:
                if not_unicode(column):
                    return (1, *not_utf8(column, column, "the header"))
            wanted = [(header.index(column), column) for column in names if column in header]
            before = reader.line_num
            for record in reader:
                for i, column in wanted:
                    if i < len(record) and not_unicode(record[i]):
                        return (before + 1, *not_utf8(column, record[i]))
                before = reader.line_num
        except csv.Error:   # (a field over csv's limit: the search stops there)
            return None
    return None


def not_utf8_error(path, names) -> ValueError:
    """The error of a CSV file whose text is not UTF-8 (for pandas' ``UnicodeDecodeError``, which says neither
    where nor how to fix it): the first line where the header or a column of ``names`` holds bytes that are not
    UTF-8, what they are likely to be, and a command that converts the file."""
    import shlex

    name = os.fspath(path)
    start = _start(path, 4096)
    wide = utf16_without_bom(start)
    found = ((1, "it starts with UTF-16's byte order mark", "utf-16") if start[:2] in UTF16_BOMS else
             (1, f"it looks like {wide.upper()} text without a byte order mark (every other byte is zero)", wide)
             if wide else _first_not_utf8(path, names))
    if found is None:
        return ValueError(f"The track file {name!r} is not UTF-8 text; convert it to UTF-8 first (iconv -f ENCODING "
                          "-t utf-8, or in Python pandas.read_csv(path, encoding=...).to_csv(...))")
    line, why, source = found
    packed = name.lower().endswith(".gz")
    converted = os.path.splitext(name[:-3] if packed else name)[0] + "-utf8.csv"
    command = (f"gunzip -c {shlex.quote(name)} | iconv -f {source} -t utf-8" if packed else
               f"iconv -f {source} -t utf-8 {shlex.quote(name)}") + f" > {shlex.quote(converted)}"
    return ValueError(f"The track file {name!r} is not UTF-8 text: line {line}: {why}. Convert it to UTF-8 first: "
                      f"{command} (in Python: pandas.read_csv(path, encoding={source!r}).to_csv(...))")


def utf8_chunks(chunks, path, names):
    """pandas' chunks of a CSV file as they come; a value that is not UTF-8 in a column read raises
    :func:`not_utf8_error`'s error instead of pandas' ``UnicodeDecodeError``, and a text pandas cannot split into
    fields (a quote never closed) an error that names the file."""
    chunks = iter(chunks)
    while True:
        try:
            chunk = next(chunks)
        except StopIteration:
            return
        except UnicodeDecodeError:
            raise not_utf8_error(path, names) from None
        except pd.errors.ParserError as error:
            raise ValueError(f"The track file {os.fspath(path)!r} cannot be read as CSV: {error} (a quote opened in a "
                             "field and never closed takes the rest of the file into that field)") from None
        yield chunk
