"""The body of ``kalmix predict``: a file chunk by chunk or stdin batch by batch, each committed whole.

A chunk (file) or the stdin lines that have arrived (a batch; one line when they come one at a
time) are computed by :class:`kalmix.streaming.TrackPredictor`,
then committed: its predictions are written and, every ``--save-every`` rows and at exit,
the state file is saved with the output position it matches (:mod:`._durable`). A chunk
stopped before its commit is rolled back; stdin rows, once read, are finished. So after
SIGINT, SIGTERM or SIGHUP the output and the state file describe the same rows, and the
same command run again continues exactly where the first stopped.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys

import click
import numpy as np

from ._common import silence_stdout
from ._durable import Interrupted, Output, OutputClosed, count_rows
from .predict import _columns, _header, _input_format, _output_columns, _sample

#: A chunk is stepped in pieces of about this many rows (each track's rows split in order,
#: so every piece holds every track of the chunk and the batch stays as wide): the progress
#: bar moves and a stop signal is honoured after each piece, not once per chunk. Each piece
#: costs a fixed share of Python work (stacking and splitting the tracks' states) and ends
#: waiting for the engine's slowest group of targets (:func:`kalmix.core.compiled._threads.group_size`),
#: so larger pieces run faster, with the same output bit for bit; this size keeps the delay of a
#: stop to about a second.
PIECE_ROWS = 65_536
#: Warnings of one kind printed line by line on stdin (rows skipped, time glitches, rows without a time);
#: the rest are counted in the run's summary.
STDIN_WARNINGS = 10
_MAX_PIECES = 64


#: A run whose gap rule splits at least this share of its rows says so (a note with what to do instead).
SPLIT_NOTE = 0.05


def gap_note(max_gap, max_gap_factor, splits: int, rows: int) -> None:
    """Say (on stderr) that the default gap rule split at least :data:`SPLIT_NOTE` of a run's ``rows`` (``splits``
    new segments), and what to do if those steps are the sampling."""
    if max_gap is None and math.isfinite(max_gap_factor) and rows >= 100 and splits >= SPLIT_NOTE * rows:
        click.echo(f"kalmix: note: the gap rule (--max-gap auto: {max_gap_factor:g} x each track's reference "
                   f"interval) started a new segment at {splits} of {rows} rows ({splits / rows:.0%}), and the "
                   "experts start again at each; the rows before them get no calibrated interval. If such steps "
                   "are the sampling (irregular reports), not lost targets, --max-gap none --reach 8 predicts "
                   "across them (documentation, 'Missing data and time gaps')", err=True)


def _gap_splits(engine) -> int:
    """Segments started by the gap rule so far, over the engine's tracks (a track's first is not one)."""
    return 0 if engine is None else sum(max(gaps.segment, 0) for gaps in engine.gaps.values())


class Run:
    """One ``kalmix predict`` run: the engine, its output and its state file, committed together."""

    def __init__(self, guard, engine, state_path, save_every, output, out_fmt):
        self.guard, self.engine, self.state_path, self.save_every = guard, engine, state_path, save_every
        self.output, self.out_fmt = output, out_fmt
        self.resuming = engine is not None  # a state file was loaded
        self.sink: Output | None = None
        self.rows = self.since_save = 0
        self.skipped0 = engine.skipped if engine is not None else 0
        self.glitches0 = engine.time_glitches if engine is not None else 0
        self.outliers0 = engine.outliers if engine is not None else 0
        self.splits0 = _gap_splits(engine)
        self.stopped: Interrupted | None = None
        self.closed = False
        self.measured = 0   # input rows of this run with every position present
        self.untimed = 0   # stdin rows skipped for want of a time
        self.saved = False   # the state file was written by this run
        self.unit = "chunk"

    def open_output(self, fmt=None):
        """Open ``-o`` (checked against the state file's record when resuming) once the input is known good."""
        self.sink = Output(self.output, fmt or self.out_fmt, previous=self.engine.output if self.resuming else None,
                           resuming=self.resuming, state_path=self.state_path,
                           note=lambda text: click.echo(f"kalmix: {text}", err=True))

    def commit(self, rows: int) -> None:
        """``rows`` input rows are written; save the state when due (called inside a deferred section)."""
        self.rows += rows
        self.since_save += rows
        if self.since_save >= self.save_every:
            self.save()

    def save(self) -> None:
        if self.state_path and self.engine is not None and self.engine.params is not None and self.sink is not None:
            self.sink.sync()
            self.engine.output = self.sink.record()
            self.engine.save(self.state_path)
            self.saved = True
        self.since_save = 0

    def finish(self, failed: bool = False) -> None:
        """Close the output and save the state (both reflect the last commit); after a failure, an output file
        this run created and never wrote to is removed."""
        try:
            self.save()
        finally:
            if self.sink is not None:
                self.sink.discard_if_empty() if failed else self.sink.close()

    def report(self) -> None:
        """Summary warnings; on a stop signal or a closed stdout, one line and a non-zero exit."""
        engine = self.engine
        if engine is not None and engine.skipped > self.skipped0:
            click.echo(f"kalmix: warning: skipped {engine.skipped - self.skipped0} row(s) at or before their "
                       "track's last time (already processed or out of order)", err=True)
        if self.untimed:
            click.echo(f"kalmix: warning: skipped {self.untimed} row(s) without a time", err=True)
        if engine is not None and engine.time_glitches > self.glitches0:
            click.echo(f"kalmix: warning: {engine.time_glitches - self.glitches0} row(s) came back in time after "
                       "a jump ahead: the jump's timestamp was taken as wrong and the track went on", err=True)
        if engine is not None and engine.outliers > self.outliers0:
            click.echo(f"kalmix: {engine.outliers - self.outliers0} outlier(s): glitches far from their track's "
                       "extrapolation, not learned (one in a track's first rows: the track started again after it); "
                       "their predictions are still written", err=True)
        if engine is not None:
            gap_note(engine.config.max_gap, engine.config.max_gap_factor, _gap_splits(engine) - self.splits0,
                     self.rows)
        if self.rows and not self.measured and self.stopped is None:
            click.echo(f"kalmix: warning: none of the {self.rows} input row(s) has a position (every value empty "
                       "or NaN): nothing was learned and every prediction is empty", err=True)
        if not self.state_path:
            saved = "no --state, nothing to resume from"
        elif (self.saved or self.resuming) and self.sink is not None and self.sink.fmt == "parquet" and self.output:
            saved = (f"state {'saved to' if self.saved else 'file unchanged:'} {self.state_path}: the same command "
                     f"with a new -o name resumes (a Parquet file cannot be continued: {self.output} keeps the rows "
                     "so far, the new one gets the rest)")
        elif self.saved or self.resuming:
            saved = (f"state {'saved to' if self.saved else 'file unchanged:'} {self.state_path}: the same command "
                     "resumes")
        else:
            saved = f"no state saved to {self.state_path} (no row was stepped): the same command starts again"
        if self.stopped is not None:
            undone = ("the chunk in progress was rolled back" if self.unit == "chunk"
                      else "the rows already read were finished")
            click.echo(f"kalmix: stopped by {self.stopped.name} after {self.rows} input row(s) in this run "
                       f"({undone}); {saved}", err=True)
            raise SystemExit(self.stopped.exit_code)
        if self.closed:
            click.echo(f"kalmix: the output was closed (broken pipe) after {self.rows} input row(s); {saved}",
                       err=True)
            raise SystemExit(1)


def _check_resumed(engine, columns):
    if engine is None:
        return
    if engine.position_names is not None and list(engine.position_names) != list(columns.positions):
        raise ValueError(f"the state file tracks the coordinates {list(engine.position_names)}, the input has "
                         f"{list(columns.positions)} (pass --position to name them, or use a new --state file)")


def _new_engine(settings, unit, positions, backend="cpu"):
    from ..bank import check_automatic_length_unit
    from ..streaming import StreamConfig, TrackPredictor

    check_automatic_length_unit(unit)
    return TrackPredictor(StreamConfig(length_unit=unit, **settings), positions, backend=backend)


def warm_up_meanwhile(run, settings, unit) -> None:
    """Load the compiled kernels in a thread while stdin has nothing for this one (a fraction of a second with
    numba's cache warm, minutes on a fresh install): a live feed's first line is answered sooner. Only a head start: the
    first run waits for the kernels, or loads them itself if this fails (and a bad setting is reported there,
    not here). (Of no use for a file: the main thread is busy too, and the loading needs the GIL.)"""
    import threading

    from ..streaming import StreamConfig, TrackPredictor

    if run.backend != "cpu":
        return
    try:   # built here, not in the thread: the engine's config changes once rows arrive
        probe = (TrackPredictor(run.engine.config) if run.engine is not None
                 else TrackPredictor(StreamConfig(length_unit=1.0 if unit is None else unit, **settings)))
        p = run.engine.params.measurement_dim if run.engine is not None and run.engine.params is not None else 2
    except Exception:   # noqa: BLE001 - reported by the run itself
        return

    def load():
        try:
            probe.warm_up(p)
        except Exception:   # noqa: BLE001 - as above
            pass

    threading.Thread(target=load, name="kalmix-warm-up", daemon=True).start()


# ------------------------------------------------------------------------------------------ files
def pieces(chunk, rows: int | None = None) -> list:
    """Split a chunk (tracks contiguous, each in time order) into pieces that each hold part of every track."""
    import pandas as pd

    rows = PIECE_ROWS if rows is None else rows
    count = min(_MAX_PIECES, -(-len(chunk) // rows))
    if count <= 1:
        return [chunk]
    codes = pd.factorize(chunk["track_id"], sort=False)[0]
    rank = chunk.groupby(codes, sort=False).cumcount().to_numpy()
    part = rank * count // np.bincount(codes)[codes]
    return [chunk[part == k] for k in range(count) if (part == k).any()]


def merge(frames, chunk):
    """The pieces' predictions back in the chunk's row order (tracks in chunk order, then time)."""
    import pandas as pd

    if len(frames) == 1:
        return frames[0]
    out = pd.concat(frames, ignore_index=True)
    codes = pd.Index(pd.unique(chunk["track_id"])).get_indexer(out["track_id"])
    return out.iloc[np.lexsort((out["time"].to_numpy(), codes))].reset_index(drop=True)


def given_rows(frame, chunk, columns, fmt):
    """A chunk's output: ``frame``, the predictions of the chunk rows the engine stepped (in chunk order, as
    :func:`merge` gives them), laid out on the chunk's file rows in file order, each with its id and time as
    the file gave them (:class:`kalmix.io.tables.AsGiven`; the time as :func:`given_times` writes it in
    ``fmt``). A file row not stepped (no time, an earlier row of a repeated time) has empty predictions and
    segment; one a resumed run skips as done before, or that shares such a row's fate, is left out (its run
    wrote it)."""
    import pandas as pd

    given = chunk.attrs["as_given"]
    n = len(chunk)
    if len(frame) == n:   # every row stepped (a resumed run's first chunks skip some)
        frame_row = np.arange(n)
    else:   # the stepped rows of a chunk, in its order: found by (track, time), one row each in a chunk
        keys = pd.MultiIndex.from_arrays([chunk["track_id"], chunk["time"]])
        frame_row = np.full(n, -1, dtype=np.int64)
        frame_row[keys.get_indexer(pd.MultiIndex.from_arrays([frame["track_id"], frame["time"]]))] = np.arange(
            len(frame))
    source = np.full(given.rows, -1, dtype=np.int64)   # each file row's prediction row (-1: none)
    source[given.places] = frame_row
    written = frame_row[given.owner] >= 0
    every = bool(written.all())
    if not every:
        source = source[written]
    out = {}
    if columns.track_id is not None:
        ids = given.ids if every else given.ids[written]
        out[columns.track_id] = ids.reset_index(drop=True)
    if columns.time is None:   # each track's row number: every file row is a chunk row
        number = np.empty(given.rows, dtype=np.float64)
        number[given.places] = chunk["time"].to_numpy()
        out["row"] = (number if every else number[written]).astype(np.int64)
    else:
        times = given.times if every else given.times[written]
        out[columns.time] = given_times(times.reset_index(drop=True), fmt)
    stepped = source >= 0
    whole = bool(stepped.all())
    for name in frame.columns[2:]:
        values = frame[name].to_numpy()
        if whole:
            out[name] = values[source]
        elif name == "segment":
            out[name] = pd.array(np.where(stepped, values[np.maximum(source, 0)], 0), dtype="Int64")
            out[name][~stepped] = pd.NA
        else:
            out[name] = np.where(stepped, values[np.maximum(source, 0)], np.nan)
    return pd.DataFrame(out)


def given_times(times, fmt):
    """A time column as the input gave it, for an output of format ``fmt``: a CSV file's or stdin's text as
    written in a CSV output; in JSON lines and Parquet, text that holds numbers as those numbers (JSON: whole
    numbers as integers, the others as floats; Parquet: float64, one type for every chunk), date-time text as
    it is. Any other column (Parquet's own types) as it is."""
    import pandas as pd

    if fmt == "csv" or not pd.api.types.is_string_dtype(times):
        return times
    numbers = pd.to_numeric(times, errors="coerce")
    if int(numbers.notna().sum()) != int(times.notna().sum()):
        return times   # date-times
    if fmt == "parquet":
        return numbers.astype(np.float64)
    whole = times.str.strip().str.fullmatch(r"[+-]?\d+").fillna(False).to_numpy(bool)
    return pd.Series([int(text) if integer else float(number) for text, number, integer
                      in zip(times.tolist(), numbers.tolist(), whole.tolist())], dtype=object)


def predict_file(run, path, settings, unit, time_column, position_columns, id_column, chunk_rows, progress):
    import pandas as pd
    from tqdm import tqdm

    from ..io import iter_track_chunks, to_arrays
    from ..streaming import _length_unit_rule, next_row_times

    if not os.path.exists(path):
        raise FileNotFoundError(f"INPUT: no such file {path!r}")
    if os.path.isdir(path):
        raise ValueError(f"INPUT: expected a track file (CSV or Parquet), got the directory {path!r}")
    in_fmt = _input_format(path)
    columns = _columns(_header(path, in_fmt), time_column, position_columns, id_column, _sample(path, in_fmt))
    _check_resumed(run.engine, columns)
    run.open_output()
    show = sys.stderr.isatty() if progress is None else progress
    total = None
    if in_fmt == "parquet":
        import pyarrow.parquet as pq
        total = pq.ParquetFile(path).metadata.num_rows
    elif show:
        total = count_rows(path)
    names = list(columns.positions)
    if total is None:
        total_rows = count_rows(path)
    else:
        total_rows = total
    ahead = (_lookahead(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                          ids_as_text=True)) if total_rows > chunk_rows else [])
    with tqdm(total=total, unit="rows", file=sys.stderr, disable=not show,
              desc="kalmix predict", smoothing=0.1) as bar:
        for index, chunk in enumerate(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                                        ids_as_text=True, as_given=True)):
            if run.engine is None:
                chosen, why = (unit, None) if unit is not None else _length_unit_rule(to_arrays(chunk).values)
                if unit is None and why is None:
                    click.echo(f"kalmix: length unit {chosen:.6g} (auto; pass --length-unit to override)", err=True)
                elif unit is None:
                    click.echo(f"kalmix: length unit 1 (auto could not estimate it: the first chunk has {why}; "
                               "pass --length-unit)", err=True)
                run.engine = _new_engine(settings, chosen, columns.positions, run.backend)
            engine = run.engine
            mark = engine.checkpoint(pd.unique(chunk["track_id"]))
            committed = False
            try:
                parts, unit_at, arrived = _unit_parts(engine, chunk)
                frames = []
                for k, (piece, later) in enumerate(zip(parts, next_row_times(parts, ahead[index] if index < len(ahead)
                                                                             else {}))):
                    if k == unit_at:
                        engine.learn_time_unit(arrived)
                    frames.append(engine.process_table(piece, names, later))
                    bar.update(len(piece))
                    if k >= (unit_at or 0):   # the rows before the time unit's step go with the next part
                        run.guard.tick()
                frame = given_rows(merge(frames, chunk), chunk, columns, run.sink.fmt)
                with run.guard.deferred():
                    run.sink.write_frame(frame)
                    committed = True
                    run.commit(len(chunk))
                    run.measured += int(np.isfinite(chunk[names].to_numpy(np.float64)).all(axis=1).sum())
            except BaseException:
                if not committed:
                    with run.guard.deferred(deliver=False):
                        engine.rollback(mark)
                raise
            bar.update(chunk.attrs.get("file_rows", len(chunk)) - len(chunk))


def _unit_parts(engine, chunk):
    """A chunk's parts to step in turn (:func:`pieces`), and, while the time unit is unknown and a step of
    the chunk fixes it, the part before which to fix it and the rows from that step on in file order.

    A stream learns the unit at the first step to arrive, so the rows before that step in file
    order are one part, stepped in file order with the unit unknown; then the unit is fixed
    from that step (:meth:`TrackPredictor.learn_time_unit`), and the rest is stepped track by
    track: the numbers of a stream of the file's rows.
    """
    from ..io import in_file_order

    arrived = in_file_order(chunk[["track_id", "time"]]) if engine.config.time_unit is None else None
    row = None if arrived is None else engine.time_unit_row(arrived)
    if row is None:
        return pieces(chunk), None, None
    if not row:
        return pieces(chunk), 0, arrived
    before = np.zeros(len(chunk), dtype=bool)
    before[arrived.index[:row]] = True
    return [chunk.loc[arrived.index[:row]], *pieces(chunk[~before])], 1, arrived.iloc[row:]


def _lookahead(chunks) -> list[dict]:
    """For each chunk, track id -> time of the track's next row in a later chunk (tracks that have one).

    A first pass over a file of several chunks, so that a track's last row in a chunk is
    forecast for the time of its next row, as in one table. Memory: one entry per (chunk,
    track) pair whose track goes on later.
    """
    import warnings

    found: list[dict] = []
    seen: dict = {}   # track -> index of the chunk it was last seen in
    with warnings.catch_warnings():   # what reading a chunk warns of, the pass that steps it says (once)
        warnings.simplefilter("ignore", RuntimeWarning)
        for index, chunk in enumerate(chunks):
            found.append({})
            for track, first in chunk.groupby("track_id", sort=False)["time"].first().items():
                if track in seen:
                    found[seen[track]][track] = float(first)
                seen[track] = index
    return found


# ------------------------------------------------------------------------------------------ stdin
def _parse_number(text, column, line_number):
    if text is None:
        return math.nan
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
    try:
        return _parse_number(text, column, line_number)
    except ValueError:
        if not isinstance(text, str):
            raise
    return text.strip()


def _dated(rows, column):
    """``rows`` (line, track, time, positions, time as given) with their ISO 8601 time text as seconds since
    1970 UTC, all in one conversion (as in a file: the same bits); cut before the first that is not a
    date-time, with its error."""
    from ..io.tables import iso_seconds

    at = [k for k, row in enumerate(rows) if isinstance(row[2], str)]
    if not at:
        return rows, None
    seconds = iso_seconds([rows[k][2] for k in at], errors="coerce")
    out = list(rows)
    for k, value in zip(at, seconds):
        number, track, text, values, given = rows[k]
        if math.isnan(value):
            return out[:k], ValueError(f"line {number}: column {column!r} must hold a number or an ISO 8601 "
                                       f"date-time (like 2024-05-01T12:00:00.5Z), got {text!r}")
        out[k] = (number, track, float(value), values, given)
    return out, None


def _parse_id(value, column, line_number):
    """A track id as written: CSV text unchanged (``01`` is not ``1``, as in a file), a JSON value as parsed."""
    if value is None or value == "" or isinstance(value, (dict, list)):
        raise ValueError(f"line {line_number}: column {column!r} (track id) must hold an id (text or a number), "
                         f"got {value!r}")
    return value


#: Most stdin lines taken in one batch (see :func:`_line_batches`).
BATCH_LINES = 4096


def _split_lines(partial: list, data: bytes) -> list:
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


def _line_batches(stream, limit: int = BATCH_LINES):
    """Lists of the lines of ``stream`` that have arrived: waits for one, then takes those already there.

    A live stream (rows a while apart) gives batches of one line, as before; a pipe that is
    ahead (a frame of many tracks, a file piped in) gives up to ``limit`` lines at once, which
    :meth:`~kalmix.streaming.TrackPredictor.step_rows` steps with the same results as row by
    row. "Already there" is asked of the operating system (``select``) on the stream's file
    descriptor, read directly (the text layer would hide what it buffered), in the stream's
    encoding when that keeps a newline one byte (UTF-8, ASCII, Latin-1: the bytes are split
    at newlines, then each line is decoded, so a line that does not decode ends its batch and
    raises only after the lines before it). A stream without a descriptor (a test's in-memory
    text, or where ``select`` cannot wait on it) is read a line at a time.
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
            whole = _split_lines(partial, data)
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


def _json_line(raw, number) -> dict:
    """A JSON-lines record, or a ``ValueError`` naming line ``number``."""
    try:
        record = json.loads(raw)
    except (json.JSONDecodeError, RecursionError) as error:
        raise ValueError(f"line {number}: not valid JSON: {error}") from None
    if not isinstance(record, dict):
        raise ValueError(f"line {number}: expected a JSON object, got {raw.strip()[:80]!r}")
    return record


def predict_stream(run, stdin, settings, unit, time_column, position_columns, id_column):
    run.unit = "row"
    if stdin is None:   # the process was started with its standard input closed
        raise ValueError("stdin: closed (INPUT '-' reads the tracks from standard input; give a file name)")
    warm_up_meanwhile(run, settings, unit)
    batches = _line_batches(stdin)
    line_number = 0
    first = None
    rest: list[str] = []
    for batch in batches:
        for position, raw in enumerate(batch):
            line_number += 1
            if line_number == 1:
                raw = raw.lstrip("\ufeff")  # a UTF-8 byte order mark would glue itself to the first column's name
            if raw.strip():
                first, rest = raw, batch[position + 1:]
                break
        if first is not None:
            break
    if first is None:
        raise ValueError("stdin: no input (expected a CSV header line or JSON lines)")
    is_json = first.lstrip().startswith("{")
    if is_json:
        record = _json_line(first, line_number)
        header = list(record)
        pending = [(line_number, record)]
    else:
        try:
            header = next(csv.reader([first]))
        except csv.Error as error:
            raise ValueError(f"line {line_number}: not a CSV header: {error}") from None
        pending = []
    columns = _columns(header, time_column, position_columns, id_column)
    _check_resumed(run.engine, columns)
    words = _IdWatch(columns, header, id_column)
    if run.engine is None:
        if unit is None:
            click.echo("kalmix: length unit 1 (stdin has no sample to estimate it from; pass --length-unit)",
                       err=True)
        run.engine = _new_engine(settings, 1.0 if unit is None else unit, columns.positions, run.backend)
    engine = run.engine
    engine.warn_skipped = False   # skipped rows are said line by line here
    done_before = {track: gaps.last_time for track, gaps in engine.gaps.items()}   # by the runs before this one
    previous_written = [True]   # the last row with a time was written (a row without one shares its fate)
    run.open_output(run.out_fmt if run.output else ("jsonl" if is_json else "csv"))
    index = {name: i for i, name in enumerate(header)}
    counts: dict = {}
    time_kind: dict = {}   # "kind": numbers or date-times, fixed by the first time

    def parse(raw, number):
        if is_json:
            return _json_line(raw, number)
        try:
            row = next(csv.reader([raw]))
        except csv.Error as error:
            raise ValueError(f"line {number}: not a CSV row: {error}") from None
        if len(row) != len(header):
            raise ValueError(f"line {number}: expected {len(header)} fields like the header, got {len(row)}")
        return row

    def get(record, name, number):
        if is_json:
            if name not in record:
                raise ValueError(f"line {number}: key {name!r} missing (keys: {list(record)})")
            return record[name]
        return record[index[name]]

    def row_of(number, record):
        """(line, track, time, positions, time as given) of a record; positions None for a row without a time
        (not stepped)."""
        words.check(number, record, get)
        track = _parse_id(get(record, columns.track_id, number), columns.track_id, number) if columns.track_id else 0
        if columns.time is None:
            time = float(counts.get(track, engine.gaps[track].last_time + 1 if track in engine.gaps else 0))
            counts[track] = time + 1
            given = int(time)
        else:
            given = get(record, columns.time, number)
            time = _parse_time(given, columns.time, number)
            if not isinstance(time, str) and math.isnan(time):   # text: a date-time, see _dated
                return number, track, time, None, given
            kind = "date-time" if isinstance(time, str) else "number"
            if time_kind.setdefault("kind", kind) != kind:   # one or the other, as in a file
                raise ValueError(f"line {number}: column {columns.time!r} holds a {kind} ({time!r}) where the lines "
                                 f"before hold {time_kind['kind']}s; expected one or the other")
        return number, track, time, [_parse_number(get(record, name, number), name, number)
                                     for name in columns.positions], given

    warned: dict[str, int] = {}

    def warn(kind, text):
        """A line's warning; after STDIN_WARNINGS of a kind, one line that says the rest are only counted (a
        replayed feed skips every row already processed: one line each would flood the terminal)."""
        count = warned[kind] = warned.get(kind, 0) + 1
        if count <= STDIN_WARNINGS:
            click.echo(f"kalmix: warning: {text}", err=True)
        if count == STDIN_WARNINGS:
            click.echo("kalmix: (further warnings like the last are only counted: the total comes at the end)",
                       err=True)

    def take(lines, rows):
        """Parse ``lines`` after ``rows``, step and write them, then warn line by line; on a bad line the
        rows before it are stepped, written and warned about, then it raises. Lines read are finished,
        warnings included, whatever signal comes (the signal is raised after them)."""
        nonlocal line_number
        error = None
        with run.guard.deferred():
            try:
                for raw in lines:
                    line_number += 1
                    if raw.strip():
                        rows.append(row_of(line_number, parse(raw, line_number)))
            except Exception as bad:   # noqa: BLE001 - raised below, once the rows before it are done
                error = bad
            rows[:], undated = _dated(rows, columns.time)
            error = undated or error   # an earlier line than the one that stopped the parse
            results = iter(step(rows))
            for number, track, time, values, _ in rows:
                if values is None:
                    run.untimed += 1
                    warn("untimed", f"line {number}: no time, row skipped")
                    continue
                result = next(results)
                if result is None:
                    warn("skipped", f"line {number}: time {time!r} is not after the previous time of track {track!r}; "
                                    "row skipped")
                elif result.time_glitch:
                    warn("glitch", f"line {number}: time {time!r} comes back before the jump ahead of track {track!r}; "
                                   "that jump's timestamp was taken as wrong and the track goes on")
        if rows:
            run.guard.tick()
        if error is not None:
            raise error

    def step(rows) -> list:
        """Step the rows with a time (line, track, time, positions, time as given) and write every row's output
        line in order, committed together: a stepped row's predictions; a row not stepped (no time, a time not
        after its track's last) with empty ones, unless this run found it done before (at or before its
        track's time in the state file it resumed from; a row without a time: if the row with a time before
        it was). The stepped rows' results, in order (None: skipped)."""
        if not rows:
            return []
        timed = [row for row in rows if row[3] is not None]
        values = np.array([row[3] for row in timed], dtype=np.float64).reshape(len(timed), len(columns.positions))
        tracks = [row[1] for row in timed]
        mark = engine.checkpoint(list(dict.fromkeys(tracks)))
        committed = False
        try:
            results = (engine.step_rows(tracks, np.array([row[2] for row in timed]), values) if timed else [])
            prefixes = engine._columns()
            records, answers = [], iter(results)
            for _, track, time, measured, given in rows:
                result = None if measured is None else next(answers)
                if result is not None:
                    written = True
                elif measured is not None:
                    before = done_before.get(_track_key(track))
                    written = before is None or not time <= before
                else:
                    written = previous_written[0]
                if measured is not None:
                    previous_written[0] = written
                if written:
                    time_out = given if is_json else given_time(given, run.sink.fmt)   # JSON: its own value
                    records.append(_row_record(result, track, time_out, columns, prefixes))
            run.sink.write_records(records)
            committed = True
            run.measured += int(np.isfinite(values).all(axis=1).sum())
        except BaseException:
            if not committed:
                engine.rollback(mark)
            raise
        run.commit(len(timed))
        return results

    take(rest, [row_of(number, record) for number, record in pending])
    for batch in batches:
        take(batch, [])
    if run.sink.fmt == "csv" and not run.sink.header_written:   # every row skipped: the header all the same,
        import pandas as pd   # named as a file's run names its columns

        empty = pd.DataFrame(columns=["track_id", "time", "segment", *(
            f"{prefix}{name}" for prefix in engine._columns().values() for name in columns.positions)])
        with run.guard.deferred():
            run.sink.write_header(list(_output_columns(empty, columns, columns.positions).columns))


def _row_record(result, track, time, columns, prefixes):
    """One output record of a stdin row (``prefixes``: :meth:`TrackPredictor._columns`; ``result`` None: a row
    not stepped, its predictions and segment empty)."""
    out = {}
    if columns.track_id is not None:
        out[columns.track_id] = track
    out[columns.time or "row"] = time
    out["segment"] = None if result is None else result.segment
    if result is None:
        for prefix in prefixes.values():
            for name in columns.positions:
                out[f"{prefix}{name}"] = math.nan
        return out
    values = {"pred": result.next, "std": result.next_std, "lead": result.ahead, "lead_std": result.ahead_std}
    for key, prefix in prefixes.items():
        for j, name in enumerate(columns.positions):
            out[f"{prefix}{name}"] = float(values[key][j])
    return out


def given_time(value, fmt):
    """A stdin row's time as given, for an output of format ``fmt``: CSV text as written in CSV; in JSON lines,
    text that holds a number as that number (a whole number as an integer), other text (a date-time) as it
    is; a JSON value, or a row number, as it is."""
    if fmt != "jsonl" or not isinstance(value, str):
        return value
    text = value.strip()
    try:
        number = float(text)
    except ValueError:
        return value
    if not math.isfinite(number):
        return value
    return int(text) if text.lstrip("+-").isdigit() else number


def _track_key(track):
    """A stdin track id as the engine keys its trackers."""
    from ..streaming import _id_to_json

    return _id_to_json(track)


class _IdWatch:
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
                raise ValueError(f"line {number}: no track id column named or detected, and column {name!r} looks "
                                 f"like one (different text values: {shown}). Without an id every row is one "
                                 f"track, the tracks' rows mixed: pass --id {name}, or --id none if the input "
                                 "holds a single track")


def run_predict(guard, engine, settings, unit, input_path, state_path, save_every, output, out_fmt,
                time_column, position_columns, id_column, chunk_rows, progress, backend="cpu"):
    """Run, commit, and on any exit save what was committed; then report."""
    run = Run(guard, engine, state_path, save_every, output, out_fmt)
    run.backend = backend
    failed = False
    try:
        if input_path == "-":
            predict_stream(run, sys.stdin, settings, unit, time_column, position_columns, id_column)
        else:
            predict_file(run, input_path, settings, unit, time_column, position_columns, id_column, chunk_rows,
                         progress)
    except Interrupted as stop:
        run.stopped = stop
    except OutputClosed:
        run.closed = True
        silence_stdout()
    except BaseException:
        failed = True
        raise
    finally:
        with guard.deferred(deliver=False):
            run.finish(failed)
    run.report()
