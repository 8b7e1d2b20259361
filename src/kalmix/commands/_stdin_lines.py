"""The lines of ``kalmix predict -``'s standard input, in batches of those that have arrived."""

from __future__ import annotations

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


def line_batches(stream, limit: int = BATCH_LINES, undecodable: bool = False):
    """Lists of the lines of ``stream`` that have arrived: waits for one, then takes those already there.

    A live stream (rows a while apart) gives batches of one line; a pipe that is
    ahead (a frame of many tracks, a file piped in) gives up to ``limit`` lines at once, which
    :meth:`~kalmix.streaming.TrackPredictor.step_rows` steps with the same results as row by
    row. "Already there" is asked of the operating system (``select``) on the stream's file
    descriptor, read directly (the text layer would hide what it buffered), in the stream's
    encoding when that keeps a newline one byte (UTF-8, ASCII, Latin-1: the bytes are split
    at newlines, then each line is decoded, so a line that does not decode ends its batch and
    raises only after the lines before it; with ``undecodable``, it is given as an
    :class:`Undecodable` line instead, decoded with replacement characters). A stream without a
    descriptor (a test's in-memory text, or where ``select`` cannot wait on it) is read a line
    at a time.
    """
    import codecs

    try:
        import select

        encoding = getattr(stream, "encoding", None) or "utf-8"
        if codecs.lookup(encoding).name not in ("utf-8", "ascii", "latin-1", "iso8859-1", "cp1252"):
            raise ValueError(encoding)
        fd = stream.fileno()
        select.select([fd], [], [], 0)
    except (AttributeError, OSError, ValueError, LookupError, ImportError):
        yield from ([line] for line in iter(stream.readline, ""))
        return
    errors = getattr(stream, "errors", None) or "strict"
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
                    why = f"not valid {encoding} ({error.reason} at its byte {error.start})"
                    if undecodable:
                        text = Undecodable(line.decode(encoding, "replace"))
                        text.reason = f"the line is {why}"
                        texts.append(text)
                        continue
                    if texts:
                        yield texts
                    raise ValueError(f"stdin: a line is {why}: {line[:80]!r}") from None
            yield texts


class Undecodable(str):
    """A stdin line that is not text in the stream's encoding (decoded with replacement characters), with why."""

    reason = ""


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
