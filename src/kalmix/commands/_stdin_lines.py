"""The lines of ``kalmix predict -``'s standard input, in batches of those that have arrived."""

from __future__ import annotations

import contextlib
import os


#: Most stdin lines taken in one batch (see :func:`line_batches`).
BATCH_LINES = 4096


def split_lines(partial: list, data: bytes) -> list:
    """The lines that ``data`` completes (each with its newline); the rest of it joins ``partial``, the pieces
    of the unfinished line (kept as pieces: a long line costs time linear in its length)."""
    if b"\n" not in data:
        partial.append(data)
        return []
    parts = (b"".join(partial) + data).split(b"\n")
    tail = parts.pop()
    partial[:] = [tail] if tail else []
    return [part + b"\n" for part in parts]


def _line_ending(partial: list, data: bytes):
    """Whether a stream's lines end in a lone ``\\r`` (old Mac text), told by its first line's end:
    ``None`` while that is not there yet (``partial``, the pieces read before ``data``, holds no line end,
    or only a ``\\r`` at its very end, which a ``\\n`` may follow)."""
    if partial and partial[-1].endswith(b"\r"):
        return not data.startswith(b"\n")
    ends = [i for i in (data.find(b"\r"), data.find(b"\n")) if i >= 0]
    if not ends:
        return None
    end = min(ends)
    if data[end:end + 1] == b"\n":
        return False
    return None if end + 1 == len(data) else data[end + 1:end + 2] != b"\n"


def line_batches(stream, limit: int = BATCH_LINES, encoding: str | None = None, errors: str | None = None):
    """Lists of the lines of ``stream`` that have arrived: waits for one, then takes those already there.

    A live stream (rows a while apart) gives batches of one line; a pipe that is
    ahead (a frame of many tracks, a file piped in) gives up to ``limit`` lines at once, which
    :meth:`~kalmix.streaming.TrackPredictor.step_rows` steps with the same results as row by
    row. "Already there" is asked of the operating system (``select``) on the stream's file
    descriptor, read directly (the text layer would hide what it buffered), in ``encoding`` with
    ``errors`` (None: the stream's) when that encoding keeps a newline one byte (UTF-8, ASCII, Latin-1:
    the bytes are split at newlines, then each line is decoded, so a line that does not decode
    ends its batch and raises only after the lines before it). A stream without a descriptor (a
    test's in-memory text, or where ``select`` cannot wait on it) is read a line at a time: through
    its bytes (``buffer``) in ``encoding`` with ``errors`` where it has them, else as its text.
    """
    import codecs

    encoding = encoding or getattr(stream, "encoding", None) or "utf-8"
    errors = errors or getattr(stream, "errors", None) or "strict"
    try:
        one_byte = codecs.lookup(encoding).name in ("utf-8", "ascii", "latin-1", "iso8859-1", "cp1252")
    except LookupError:
        one_byte = False
    try:
        import select

        if not one_byte:
            raise ValueError(encoding)
        fd = stream.fileno()
        select.select([fd], [], [], 0)
    except (AttributeError, OSError, ValueError, ImportError):
        yield from _text_lines(stream, encoding, errors, one_byte)
        return
    partial: list[bytes] = []   # the pieces of an unfinished line
    carriage = None   # lines end in a lone "\r" (old Mac text): known at the first line's end
    done = False
    while not done:
        lines: list[bytes] = []
        wait = None   # block for the first bytes of a batch, then take only what is there
        while len(lines) < limit:
            if not select.select([fd], [], [], wait)[0]:
                break
            try:
                data = os.read(fd, 1 << 16)
            except BlockingIOError:   # a descriptor left non-blocking, ready after all: wait again
                continue
            if not data:
                done = True
                break
            if carriage is None:
                carriage = _line_ending(partial, data)
                if carriage is None:
                    partial.append(data)
                    continue
                if carriage:
                    partial[:] = [piece.replace(b"\r", b"\n") for piece in partial]
            if carriage:
                data = data.replace(b"\r", b"\n")
            whole = split_lines(partial, data)
            if whole:
                lines.extend(whole)
                wait = 0
        if done and partial:
            lines.append(b"".join(partial))
            partial.clear()
        for begin in range(0, len(lines), limit):
            texts = []
            for line in lines[begin:begin + limit]:
                try:
                    texts.append(line.decode(encoding, errors))
                except UnicodeDecodeError as error:
                    if texts:
                        yield texts
                    raise ValueError(f"stdin: a line is not valid {encoding} ({error.reason} at its byte "
                                     f"{error.start}): {line[:80]!r}") from None
            yield texts


def _text_lines(stream, encoding, errors, one_byte):
    """:func:`line_batches` of a stream without a descriptor: a line at a time."""
    import io

    buffer = getattr(stream, "buffer", None)
    if not one_byte or buffer is None or (getattr(stream, "encoding", None), getattr(stream, "errors", None)) == (
            encoding, errors):
        yield from ([line] for line in iter(stream.readline, ""))
        return
    text = io.TextIOWrapper(buffer, encoding=encoding, errors=errors)   # (nothing read from the stream yet)
    try:
        yield from ([line] for line in iter(text.readline, ""))
    finally:
        with contextlib.suppress(ValueError):   # (closed already: a generator left unfinished, closed late)
            text.detach()   # the stream's bytes stay open, as the stream is


def first_line(batches):
    """The first line of ``batches`` (:func:`line_batches`) that is not blank, a byte order mark taken off the
    stream's first line: its number, the line, and the lines after it in its batch (the later batches are
    still to come from ``batches``). ``ValueError`` when there is none."""
    line_number = 0
    for batch in batches:
        for position, raw in enumerate(batch):
            line_number += 1
            if line_number == 1:
                raw = raw.lstrip("\ufeff")  # a UTF-8 byte order mark would glue itself to the first column's name
            if raw.strip():
                return line_number, raw, batch[position + 1:]
    raise ValueError("stdin: no input (expected a CSV header line or JSON lines)")


#: A CSV record whose quoted field is still open after this many characters goes on no further: it is taken as it
#: is (a bad row), so that a stray quote does not hold every later line (csv's own field size limit).
RECORD_LIMIT = 131_072


def ends_quoted(text: str, inside: bool = False) -> bool:
    """Whether CSV ``text`` ends inside a quoted field (``inside``: it starts in one), read as Python's csv
    module reads (dialect ``excel``): a field quoted from its first character, a quote inside it doubled. A
    record whose line ends so goes on on the next line (RFC 4180)."""
    i = 0
    if not inside:
        if '"' not in text:
            return False
        inside = text.startswith('"')
        i = int(inside)
    while True:
        if inside:
            j = text.find('"', i)
            if j < 0:
                return True
            if text.startswith('"', j + 1):   # a doubled quote: one quote in the field
                i = j + 2
                continue
            inside, i = False, j + 1
        j = text.find(",", i)   # the rest of the field, unquoted
        if j < 0:
            return False
        i = j + 1
        if text.startswith('"', i):
            inside, i = True, i + 1


class CsvRecords:
    """Stdin's CSV lines as records: a line that ends inside a quoted field (:func:`ends_quoted`) is joined with
    the lines after it until the field closes, as a file's reader does, so that each record is one row."""

    def __init__(self, limit: int = RECORD_LIMIT):
        self.limit = limit
        self.pieces: list[str] = []   # an unfinished record's lines
        self.first = 0   # its first line's number
        self.size = 0

    def add(self, number: int, line: str):
        """``(first line's number, record)`` when line ``number`` ends a record; None while the record goes on."""
        if not self.pieces:
            if not ends_quoted(line):
                return number, line
            self.pieces, self.first, self.size = [line], number, len(line)
            return None if self.size <= self.limit else self.rest()
        self.pieces.append(line)
        self.size += len(line)
        if not ends_quoted(line, inside=True):
            record = (self.first, "".join(self.pieces))
            self.pieces, self.size = [], 0
            return record
        return None if self.size <= self.limit else self.rest()

    def rest(self):
        """The unfinished record (at the input's end, or once over the limit), as :class:`Unclosed` text, or
        None."""
        if not self.pieces:
            return None
        record = (self.first, Unclosed("".join(self.pieces)))
        self.pieces, self.size = [], 0
        return record


class Unclosed(str):
    """A CSV record whose quoted field was never closed (:meth:`CsvRecords.rest`)."""
