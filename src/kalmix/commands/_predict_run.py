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

import contextlib
import csv
import json
import math
import os
import sys
import warnings

from typing import Any, NamedTuple

import click
import numpy as np

from ._common import silence_stdout
from ._durable import Interrupted, count_rows
from ._output import Output, OutputClosed
from ._input import input_columns, input_format, sample_reader

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


class BadRowLog:
    """The bad rows a run skipped (``--on-bad-row skip``): counted, the first few places kept for the summary,
    each written to the ``--rejects`` file (its place, why, and the row as given) as its output row is."""

    SHOWN = 10   # places named in the summary

    def __init__(self, path: str | None = None):
        self.path, self.handle, self.writer = path, None, None
        self.count = 0
        self.places: list[str] = []
        self.first: str | None = None

    def open(self, kind: str, append: bool) -> None:
        """Open the rejects file (``kind``: ``line`` or ``row``, the name of its first column); ``append``: a
        resumed run adds to the file an earlier run wrote."""
        if self.path is None or self.handle is not None:
            return
        append = append and os.path.exists(self.path) and os.path.getsize(self.path) > 0
        try:
            self.handle = open(self.path, "a" if append else "w", newline="", encoding="utf-8",
                               errors="backslashreplace")   # (a line of stdin's that is not UTF-8)
        except OSError as error:
            raise ValueError(f"--rejects: cannot write {self.path!r}: {error.strerror or error}") from None
        self.writer = csv.writer(self.handle)
        if not append:
            self.writer.writerow([kind, "reason", "input"])
            self.handle.flush()

    def add(self, places, reasons, texts) -> None:
        """Rows skipped, each with its place (``line 12``, ``row 5``), reason and text."""
        if not len(places):
            return
        if self.first is None:
            self.first = reasons[0]
        self.count += len(places)
        self.places.extend(places[:max(0, self.SHOWN - len(self.places))])
        if self.writer is not None:
            self.writer.writerows([place.split(" ", 1)[1].split(" ", 1)[0], reason, text]
                                  for place, reason, text in zip(places, reasons, texts))

    def flush(self) -> None:
        if self.handle is not None:
            self.handle.flush()

    def close(self) -> None:
        if self.handle is not None:
            self.handle.close()

    def summary(self) -> str | None:
        """The run's line: ``N bad row(s) skipped (lines 12, 599; ...)``; None when there were none."""
        if not self.count:
            return None
        kind = self.places[0].split(" ", 1)[0]
        numbers = ", ".join(place.split(" ", 1)[1].split(" ", 1)[0] for place in self.places)
        more = ", ..." if self.count > len(self.places) else ""
        where = f"{kind}{'s' if self.count > 1 else ''} {numbers}{more}"
        if kind == "row" and " after the header" in self.places[0]:
            where += ", counted from 0 after the header"
        elif kind == "row":
            where += ", counted from 0"
        if self.path is not None:
            where += f"; see --rejects {self.path}"
        elif self.count == 1:
            where += f": {self.first}; --rejects FILE keeps such rows"
        else:
            where += f"; the first: {self.first}; --rejects FILE lists each with its reason"
        return f"{self.count} bad row(s) skipped ({where}): their output rows have empty predictions"


class IdWatch:
    """Says once (on stderr) when two track ids are written differently but would be read as one by eye: ids
    that differ only by the spaces around them (``' 7'`` and ``'7'``) or in how a number is written
    (``'1.0'`` and ``'1'``, ``'007'`` and ``'7'``): ids are read as written, so they are two tracks; and ids
    equal as numbers but of different types (``1`` and ``1.0`` in JSON lines, an integer and a float column
    of two Parquet files of a resumed run), which continue one track. ``known``: the ids of a resumed
    state file's tracks."""

    def __init__(self, known=()):
        self.seen: set = set()
        self.forms: dict = {}
        self.warned: set = set()
        for track in known:
            self.see(track, warn=False)

    @staticmethod
    def _form(value):
        if isinstance(value, bool):
            return None
        if isinstance(value, (int, float, np.integer, np.floating)):
            return ("number", float(value))
        if not isinstance(value, str):
            return None
        text = value.strip()
        try:
            number = float(text)
        except ValueError:
            return ("text", text)
        return ("number", number) if math.isfinite(number) else ("text", text)

    def see_many(self, values) -> None:
        for value in values:
            self.see(value)

    def see(self, value, warn: bool = True) -> None:
        key = (type(value).__name__, value)
        if key in self.seen:
            return
        self.seen.add(key)
        form = self._form(value)
        if form is None:
            return
        other = self.forms.setdefault(form, value)
        if other is value or not warn:
            return
        if isinstance(other, str) and isinstance(value, str) and other.strip() == value.strip():
            kind, text = "spaces", (f"track ids {other!r} and {value!r} differ only by the spaces around them: they "
                                    "are two tracks (ids are read as written); remove the spaces in the input if "
                                    "they are one")
        elif other == value:
            kind, text = "types", (f"track ids {other!r} ({type(other).__name__}) and {value!r} "
                                   f"({type(value).__name__}) are equal numbers of two types: they continue one track")
        else:
            kind, text = "numbers", (f"track ids {other!r} and {value!r} differ only in how a number is written: "
                                     "they are two tracks (ids are read as written)")
        if kind not in self.warned:
            self.warned.add(kind)
            click.echo(f"kalmix: warning: {text}; this is said once", err=True)


class UnitWatch:
    """Says once (on stderr) when the learned time unit, the first step of the first track to have one, is far
    from that track's usual step (the median of its first :data:`~kalmix.streaming.REFERENCE_INTERVALS` steps,
    or of those it has at the end): a 1 ms first step among 1 s steps made the unit 1 ms, the experts' noise
    scaled with it, and the first forecasts wild. The unit stays (it is fixed at that step, so that a file and
    a stream of its rows give the same numbers); the line gives the --time-unit to pass."""

    FACTOR = 3.0   # "far": more than this many times larger or smaller

    def __init__(self):
        self.done = False

    def check(self, engine, final: bool = False) -> None:
        if self.done or engine is None or engine.config.time_unit is None:
            return
        from ..streaming import REFERENCE_INTERVALS, short_median

        source = getattr(engine, "_unit_source", None)
        if source is None:   # given, resumed from a state file, or taken back as a wrong timestamp (warned)
            self.done = True
            return
        track, unit = source
        gaps = engine.gaps.get(track)
        steps = [] if gaps is None else list(gaps.intervals)
        if len(steps) < REFERENCE_INTERVALS and not final:
            return
        self.done = True
        if len(steps) < 3:
            return
        usual = short_median(steps)
        if usual > self.FACTOR * unit or unit > self.FACTOR * usual:
            click.echo(f"kalmix: warning: the time unit, {unit:.6g} time-column units, was learned from the first "
                       f"step of track {track!r}, whose usual step is {usual:.6g} (the median of its first "
                       f"{len(steps)}): the experts' noise, --horizon and --reach scale with the unit, and the first "
                       f"forecasts suffer; pass --time-unit {usual:.6g}", err=True)


class Run:
    """One ``kalmix predict`` run: the engine, its output and its state file, committed together."""

    def __init__(self, guard, engine, state_path, save_every, output, out_fmt, on_bad_row="skip", rejects=None):
        self.guard, self.engine, self.state_path, self.save_every = guard, engine, state_path, save_every
        self.output, self.out_fmt = output, out_fmt
        self.on_bad_row = on_bad_row
        self.bad = BadRowLog(rejects)
        self.ids = IdWatch(engine.gaps if engine is not None else ())
        self.units = UnitWatch()
        self.resets = 0   # tracks' clocks that restarted
        self.dropped = {"untimed": 0, "repeated": 0}   # a file's rows not predicted, by why
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

    def clock_reset(self, place, track, before, after) -> None:
        """Say (the first :data:`STDIN_WARNINGS`) that a track's clock restarted at ``place``, and count it."""
        self.resets += 1
        if self.resets <= STDIN_WARNINGS:
            click.echo(f"kalmix: note: track {track!r}: its time goes back from {before:g} to {after:g} at {place} and "
                       "goes on from there (a clock that restarted?): a new segment starts there, the rows before "
                       "and after it kept (the output gives their times as given)", err=True)
        if self.resets == STDIN_WARNINGS:
            click.echo("kalmix: (further clock restarts are only counted: the total comes at the end)", err=True)

    def commit(self, rows: int) -> None:
        """``rows`` input rows are written; save the state when due (called inside a deferred section)."""
        self.bad.flush()
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
            self.bad.close()
            if self.sink is not None:
                self.sink.discard_if_empty() if failed else self.sink.close()

    def report(self) -> None:
        """Summary warnings; on a stop signal or a closed stdout, one line and a non-zero exit."""
        engine = self.engine
        if self.stopped is None:
            self.units.check(engine, final=True)
        bad = self.bad.summary()
        if bad is not None:
            click.echo(f"kalmix: error: {bad}", err=True)
        if engine is not None and engine.skipped > self.skipped0:
            fate = ("their output rows have empty predictions" if self.unit == "row" else   # stdin's rows
                    "not written (a file's rows skipped are left out of the output)")
            click.echo(f"kalmix: error: skipped {engine.skipped - self.skipped0} row(s) at or before their "
                       f"track's last time (already processed or out of order); {fate}", err=True)
        if self.untimed:
            click.echo(f"kalmix: error: skipped {self.untimed} row(s) without a time; their output rows have empty "
                       "predictions", err=True)
        if self.dropped["untimed"]:
            click.echo(f"kalmix: error: {self.dropped['untimed']} row(s) have no time: not predicted (their output "
                       "rows have empty predictions)", err=True)
        if self.resets > STDIN_WARNINGS:
            click.echo(f"kalmix: note: {self.resets} clock restart(s) started a new segment of their track", err=True)
        if self.dropped["repeated"]:
            click.echo(f"kalmix: error: {self.dropped['repeated']} row(s) repeat a timestamp within their track: "
                       "the last row of each repeated time is predicted, the others' output rows have empty "
                       "predictions", err=True)
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


def _geographic(engine, settings, columns):
    """The positions' :class:`kalmix.io.geo.GeoAxes` when they are geographic (a resumed state's setting, else
    --geographic / --no-geographic, else their names), told on stderr; None when they are flat."""
    from ..io.geo import resolve_axes, std_names

    if engine is not None:
        axes = engine.axes
    else:
        axes = resolve_axes(list(columns.positions), settings.get("geographic"))
    if axes is not None:
        lat, lon = columns.positions[axes.lat], columns.positions[axes.lon]
        spread = ", ".join(f"std_{name}" for name in std_names(axes))
        click.echo(f"kalmix: geographic coordinates ({lat!r} latitude, {lon!r} longitude"
                   + (f", {columns.positions[axes.alt]!r} altitude in metres" if axes.alt is not None else "")
                   + f"): predicted in metres in each track's local frame; pred_ columns in degrees, {spread} in "
                   "metres (--no-geographic: flat numbers)", err=True)
    return axes


def _check_degrees(chunk, names, axes, offset) -> None:
    """A ``ValueError`` naming the first file row of a chunk (``offset``: the file rows before it) whose latitude is
    beyond ±90° or longitude beyond ±180°."""
    from ..io.geo import check_degrees

    given = chunk.attrs.get("as_given")
    places = np.asarray(given.places) if given is not None else np.arange(len(chunk))
    order = np.argsort(places, kind="stable")   # file order: the first such row of the file is named
    check_degrees(chunk[names].to_numpy(np.float64)[order], axes, names,
                  lambda i: f"row {offset + int(places[order[i]])} (counted from 0 after the header)")


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


def given_rows(frame, chunk, columns, fmt, kept: list | None = None):
    """A chunk's output: ``frame``, the predictions of the chunk rows the engine stepped (in chunk order, as
    :func:`merge` gives them), laid out on the chunk's file rows in file order, each with its id and time as
    the file gave them (:class:`kalmix.io.tables.AsGiven`; the time as :func:`given_times` writes it in
    ``fmt``). A file row not stepped (no time, an earlier row of a repeated time) has empty predictions and
    segment; one a resumed run skips as done before, or that shares such a row's fate, is left out (its run
    wrote it). ``kept``: given a list, receives which file rows are written (a boolean array)."""
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
    # a row with no chunk row to share the fate of (a chunk without one: every row bad or without a time) is
    # this run's
    written = np.where(given.owner >= 0, frame_row[np.maximum(given.owner, 0)] >= 0, True) if n else np.ones(
        given.rows, dtype=bool)
    if kept is not None:
        kept.append(written)
    every = bool(written.all())
    if not every:
        source = source[written]
    out = {}
    if columns.track_id is not None:
        ids = given.ids if every else given.ids[written]
        out[columns.track_id] = ids.reset_index(drop=True)
    if columns.time is None:   # each track's row number (none for a bad row, which is no chunk row)
        number = np.full(given.rows, np.nan)
        number[given.places] = chunk["time"].to_numpy()
        number = number if every else number[written]
        out["row"] = (number.astype(np.int64) if not np.isnan(number).any()
                      else pd.array(np.where(np.isnan(number), 0, number).astype(np.int64), dtype="Int64"))
        if isinstance(out["row"], pd.arrays.IntegerArray):
            out["row"][np.isnan(number)] = pd.NA
    else:
        times = given.times if every else given.times[written]
        out[columns.time] = given_times(times.reset_index(drop=True), fmt)
    stepped = source >= 0
    whole = bool(stepped.all())
    for name in frame.columns[2:]:
        values = frame[name].to_numpy()
        if not len(values):   # no row stepped (a chunk of bad rows): any place will do, each is masked
            values = np.zeros(1, dtype=np.int64 if name == "segment" else np.float64)
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

    from ..io import iter_track_chunks
    from ..io.tables import DroppedRowWarning, read_header
    from ..streaming import estimate_length_unit, length_unit_fallback, next_row_times

    if not os.path.exists(path):
        raise FileNotFoundError(f"INPUT: no such file {path!r}")
    if os.path.isdir(path):
        raise ValueError(f"INPUT: expected a track file (CSV or Parquet), got the directory {path!r}")
    in_fmt = input_format(path)
    columns = input_columns(read_header(path, in_fmt), time_column, position_columns, id_column,
                            sample_reader(path, in_fmt))
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
    run.bad.open("row" if in_fmt == "parquet" else "line", append=run.resuming)
    axes = _geographic(run.engine, settings, columns)
    offset = 0   # file rows before the chunk
    clocks = _clocks(run.engine, settings)
    ahead = (_lookahead(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                          ids_as_text=True, on_bad_row=run.on_bad_row,
                                          clock_resets=_clocks(run.engine, settings)))
             if total_rows > chunk_rows else [])
    with tqdm(total=total, unit="rows", file=sys.stderr, disable=not show,
              desc="kalmix predict", smoothing=0.1) as bar, warnings.catch_warnings():
        warnings.simplefilter("ignore", DroppedRowWarning)   # counted here and said at the end (Run.report)
        for index, chunk in enumerate(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                                        ids_as_text=True, as_given=True, on_bad_row=run.on_bad_row,
                                                        bad_texts=run.bad.path is not None,
                                                        clock_resets=clocks)):
            for why, count in chunk.attrs.get("dropped", {}).items():
                run.dropped[why] += count
            run.ids.see_many(pd.unique(chunk["track_id"]).tolist())
            for place, track, before, after in chunk.attrs.get("clock_resets", ()):
                run.clock_reset(place, track, before, after)
            offset += chunk.attrs.get("file_rows", len(chunk))
            if axes is not None:
                _check_degrees(chunk, names, axes, offset - chunk.attrs.get("file_rows", len(chunk)))
            if not len(chunk):   # every row bad or without a time: their output rows, nothing to step
                _write_unstepped(run, chunk, columns, settings)
                bar.update(chunk.attrs.get("file_rows", 0))
                continue
            if run.engine is None:
                chosen, why = (unit, None) if unit is not None else estimate_length_unit(
                    chunk, names, geographic=axes is not None)
                metres = " m" if axes is not None else ""
                if unit is None and why is None:
                    click.echo(f"kalmix: length unit {chosen:.6g}{metres} (auto; pass --length-unit to override)",
                               err=True)
                elif unit is None:
                    click.echo(f"kalmix: {length_unit_fallback(why, 'the first chunk', '--length-unit', metres)}",
                               err=True)
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
                _keep_clocks(engine, clocks, pd.unique(chunk["track_id"]))
                written: list = []
                frame = given_rows(merge(frames, chunk), chunk, columns, run.sink.fmt, written)
                with run.guard.deferred():
                    run.sink.write_frame(frame)
                    _log_bad_rows(run, chunk, written[0])
                    committed = True
                    run.commit(len(chunk))
                    run.measured += int(np.isfinite(chunk[names].to_numpy(np.float64)).all(axis=1).sum())
            except BaseException:
                if not committed:
                    with run.guard.deferred(deliver=False):
                        engine.rollback(mark)
                raise
            bar.update(chunk.attrs.get("file_rows", len(chunk)) - len(chunk))
            run.units.check(run.engine)


def _clocks(engine, settings):
    """A file's :class:`kalmix.io.tables.ClockResets`, going on with the clocks a resumed state file saved."""
    from ..io.tables import ClockResets

    clocks = ClockResets(reset_step(settings))
    for key, gaps in ({} if engine is None else engine.gaps).items():
        if gaps.clock is not None:
            clocks.resume(key, gaps.clock)   # a file's ids are text, or numbers its own key
    return clocks


def _keep_clocks(engine, clocks, tracks) -> None:
    """Keep in the engine's state (saved with it, rolled back with it) the clock of each of ``tracks`` that
    restarted, for a resumed run to go on moving its times."""
    for track in tracks:
        clock = clocks.tracks.get(track)
        gaps = engine.gaps.get(_track_key(track))
        if gaps is not None and (clock is not None and clock[0] or gaps.clock is not None):
            gaps.clock = None if clock is None else list(clock)


def reset_step(settings):
    """``step(usual)``: the step a track's clock that restarts is taken to make (:class:`kalmix.io.tables.ClockResets`):
    twice the gap threshold, so that the gap rule starts a new segment there (with ``--max-gap none``, which never
    splits, one usual step: the track goes on)."""
    gap, factor = settings.get("max_gap"), settings.get("max_gap_factor", 3.0)
    if gap is not None:
        return lambda usual: 2.0 * gap
    if math.isinf(factor):
        return lambda usual: usual
    return lambda usual: 2.0 * factor * usual


def _log_bad_rows(run, chunk, written) -> None:
    """Count a chunk's bad rows, and write them to --rejects: those whose output rows are written (a resumed run
    leaves out the rows an earlier run wrote, bad ones included)."""
    bad = chunk.attrs.get("bad_rows")
    if bad is None:
        return
    keep = written[bad.local]
    run.bad.add([p for p, k in zip(bad.places, keep) if k], [r for r, k in zip(bad.reasons, keep) if k],
                [t for t, k in zip(bad.texts, keep) if k])


def _write_unstepped(run, chunk, columns, settings) -> None:
    """Write the output rows of a chunk without a row to step (every row bad or without a time): the id and time
    as given, empty predictions."""
    import pandas as pd

    from ..streaming import StreamConfig, TrackPredictor

    engine = run.engine if run.engine is not None else TrackPredictor(StreamConfig(length_unit=1.0, **settings),
                                                                      columns.positions)
    frame = pd.DataFrame({"track_id": pd.Series(dtype=object), "time": pd.Series(dtype=np.float64),
                          "segment": pd.Series(dtype=np.int64), **{
                              name: pd.Series(dtype=np.float64)
                              for names in engine.output_columns().values() for name in names}})
    written: list = []
    out = given_rows(frame, chunk, columns, run.sink.fmt, written)
    with run.guard.deferred():
        run.sink.write_frame(out)
        _log_bad_rows(run, chunk, written[0])
        run.commit(0)


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


def _line_batches(stream, limit: int = BATCH_LINES, undecodable: bool = False):
    """Lists of the lines of ``stream`` that have arrived: waits for one, then takes those already there.

    A live stream (rows a while apart) gives batches of one line, as before; a pipe that is
    ahead (a frame of many tracks, a file piped in) gives up to ``limit`` lines at once, which
    :meth:`~kalmix.streaming.TrackPredictor.step_rows` steps with the same results as row by
    row. "Already there" is asked of the operating system (``select``) on the stream's file
    descriptor, read directly (the text layer would hide what it buffered), in the stream's
    encoding when that keeps a newline one byte (UTF-8, ASCII, Latin-1: the bytes are split
    at newlines, then each line is decoded, so a line that does not decode ends its batch and
    raises only after the lines before it; with ``undecodable``, it is given as an
    :class:`_Undecodable` line instead, decoded with replacement characters). A stream without a
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
                    why = f"not valid {encoding} ({error.reason} at its byte {error.start})"
                    if undecodable:
                        text = _Undecodable(line.decode(encoding, "replace"))
                        text.reason = f"the line is {why}"
                        texts.append(text)
                        continue
                    if texts:
                        yield texts
                    raise ValueError(f"stdin: a line is {why}: {line[:80]!r}") from None
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
    skip = run.on_bad_row == "skip"
    batches = _line_batches(stdin, undecodable=skip)
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
    columns = input_columns(header, time_column, position_columns, id_column)
    _check_resumed(run.engine, columns)
    words = _IdWatch(columns, header, id_column)
    from ..io.geo import check_degrees

    axes = _geographic(run.engine, settings, columns)
    if run.engine is None:
        if unit is None:
            from ..streaming import length_unit_fallback

            click.echo(f"kalmix: {length_unit_fallback(None, 'stdin', '--length-unit', ' m' if axes else '')}",
                       err=True)
        run.engine = _new_engine(settings, 1.0 if unit is None else unit, columns.positions, run.backend)
    engine = run.engine
    engine.warn_skipped = False   # skipped rows are said line by line here
    done_before = {track: gaps.last_time for track, gaps in engine.gaps.items()}   # by the runs before this one
    previous_written = [True]   # the last row with a time was written (a row without one shares its fate)
    run.open_output(run.out_fmt if run.output else ("jsonl" if is_json else "csv"))
    run.bad.open("line", append=run.resuming)
    index = {name: i for i, name in enumerate(header)}
    counts: dict = {}
    time_kind: dict = {}   # "kind": numbers or date-times, fixed by the first time

    def parse(raw, number):
        if isinstance(raw, _Undecodable):
            raise ValueError(f"line {number}: {raw.reason}")
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
        (not stepped). A ``ValueError`` for a bad row (which takes no row number, and does not fix the time
        column's kind)."""
        track = _parse_id(get(record, columns.track_id, number), columns.track_id, number) if columns.track_id else 0
        run.ids.see(track)
        if columns.time is None:
            values = [_parse_number(get(record, name, number), name, number) for name in columns.positions]
            if axes is not None:
                check_degrees(np.array([values]), axes, columns.positions, lambda i: f"line {number}")
            time = float(counts.get(track, engine.gaps[track].last_time + 1 if track in engine.gaps else 0))
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
        if axes is not None:
            check_degrees(np.array([values]), axes, columns.positions, lambda i: f"line {number}")
        time_kind.setdefault("kind", kind)
        if kind == "date-time" and skip:
            dated_texts[number] = record   # for a rejects file, should _dated find it is no date
        return number, track, time, values, given

    dated_texts: dict = {}

    def undated_row(row, reason) -> _BadLine:
        record = dated_texts.get(row[0])
        text = "" if record is None else json.dumps(record) if is_json else _csv_line(record)
        return _BadLine(row[0], row[1], math.nan, None, row[4], reason, text)

    def read(number, raw, record=None):
        """A line's row (:func:`row_of`), or with --on-bad-row skip its :class:`_BadLine`; ``record``: the line
        parsed already."""
        try:
            if record is None:
                record = parse(raw, number)
            words.check(number, record, get)   # (a column that looks like ids: not a bad row, the input's columns)
            return row_of(number, record)
        except ValueError as bad:
            if not skip or isinstance(bad, _IdError):
                raise
            return bad_row(number, raw, record, bad)

    def bad_row(number, raw, record, error) -> _BadLine:
        """A bad line's row: not stepped, its id and time as given where they can be read (else empty)."""
        track = given = None
        if record is not None:
            with contextlib.suppress(ValueError, IndexError, KeyError, TypeError):
                track = _parse_id(get(record, columns.track_id, number), columns.track_id, number) \
                    if columns.track_id else 0
            with contextlib.suppress(ValueError, IndexError, KeyError, TypeError):
                given = get(record, columns.time, number) if columns.time else None
        reason = str(error)
        prefix = f"line {number}: "
        return _BadLine(number, track, math.nan, None, given, reason[len(prefix):] if reason.startswith(prefix)
                        else reason, str(raw).rstrip("\r\n"))

    empties = _EmptyWatch(columns.positions if position_columns is None else ())
    clocks = _StreamClocks(engine, reset_step(settings), run.clock_reset)
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
        """Parse ``lines`` after ``rows``, step and write them, then warn line by line. A bad line (one that
        does not parse, or whose values are not an id, a time and positions) is, with ``--on-bad-row skip``,
        a row not stepped, warned of and counted; with ``fail``, the rows before it are stepped, written and
        warned about, then it raises. Lines read are finished, warnings included, whatever signal comes (the
        signal is raised after them)."""
        nonlocal line_number
        error = None
        with run.guard.deferred():
            try:
                for raw in lines:
                    line_number += 1
                    if raw.strip():
                        rows.append(read(line_number, raw))
            except Exception as bad:   # noqa: BLE001 - raised below, once the rows before it are done
                error = bad
            rows[:], undated = _dated(rows, columns.time, undated_row if skip else None)
            dated_texts.clear()
            error = undated or error   # an earlier line than the one that stopped the parse
            if columns.time is not None:
                rows[:] = clocks.adjust(rows)
            results = iter(step(rows))
            for row in rows:
                number, track, time, values = row[:4]
                if isinstance(row, _BadLine):
                    warn("bad", f"line {number}: bad row skipped: {row.reason}")
                    continue
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
        run.units.check(engine)
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
        timed = [row for row in rows if row[3] is not None]   # (not a bad row, nor one without a time)
        values = np.array([row[3] for row in timed], dtype=np.float64).reshape(len(timed), len(columns.positions))
        tracks = [row[1] for row in timed]
        mark = engine.checkpoint(list(dict.fromkeys(tracks)))
        committed = False
        try:
            results = (engine.step_rows(tracks, np.array([row[2] for row in timed]), values) if timed else [])
            prefixes = engine.output_columns()
            records, answers, rejected = [], iter(results), []
            for row in rows:
                _, track, time, measured, given = row[:5]
                result = None if measured is None else next(answers)
                if result is not None:
                    written = True
                elif measured is not None:
                    before = done_before.get(_track_key(track))
                    written = before is None or not time <= before
                else:   # a row without a time, or a bad row: shares the fate of the last row with a time
                    written = previous_written[0]
                if measured is not None:
                    previous_written[0] = written
                if written:
                    time_out = given if is_json else given_time(given, run.sink.fmt)   # JSON: its own value
                    records.append(_row_record(result, track, time_out, columns, prefixes))
                    if isinstance(row, _BadLine):
                        rejected.append(row)
            run.sink.write_records(records)
            run.bad.add([f"line {row.line}" for row in rejected], [row.reason for row in rejected],
                        [row.text for row in rejected])
            committed = True
            run.measured += int(np.isfinite(values).all(axis=1).sum())
            empties.see(values)
        except BaseException:
            if not committed:
                engine.rollback(mark)
            raise
        run.commit(len(timed))
        return results

    take(rest, [read(number, first, record) for number, record in pending])
    for batch in batches:
        take(batch, [])
    if run.sink.fmt == "csv" and not run.sink.header_written:   # every row skipped: the header all the same,
        import pandas as pd   # named as a file's run names its columns

        from ..streaming import with_input_names

        empty = pd.DataFrame(columns=["track_id", "time", "segment", *(
            name for names in engine.output_columns().values() for name in names)])
        with run.guard.deferred():
            run.sink.write_header(list(with_input_names(empty, columns).columns))


class _BadLine(NamedTuple):
    """A stdin line skipped as bad (``--on-bad-row skip``): its row's first five fields as :func:`row_of`'s
    (positions None: not stepped; track and time as given, where they could be read), why, and its text."""

    line: int
    track: Any
    time: float
    values: None
    given: Any
    reason: str
    text: str


class _Undecodable(str):
    """A stdin line that is not text in the stream's encoding (decoded with replacement characters), with why."""

    reason = ""


class _IdError(ValueError):
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


def _row_record(result, track, time, columns, prefixes):
    """One output record of a stdin row (``prefixes``: :meth:`TrackPredictor.output_columns`, each output's column
    names; ``result`` None: a row not stepped, its predictions and segment empty)."""
    out = {}
    if columns.track_id is not None:
        out[columns.track_id] = track
    out[columns.time or "row"] = time
    out["segment"] = None if result is None else result.segment
    if result is None:
        for names in prefixes.values():
            for name in names:
                out[name] = math.nan
        return out
    values = {"pred": result.next, "std": result.next_std, "lead": result.ahead, "lead_std": result.ahead_std}
    for key, names in prefixes.items():
        for j, name in enumerate(names):
            out[name] = float(values[key][j])
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
    from ..streaming import id_to_json

    return id_to_json(track)


class _StreamClocks:
    """On stdin, a track's clock that restarts (times 0 .. 49, then 0 .. 49 again; see
    :class:`kalmix.io.tables.ClockResets` for a file's): a row that goes back by more than
    :attr:`FACTOR` usual steps, to a time inside the track's clock so far, is skipped as any row not after its
    track's last; if the track's next row goes on from it (forward by at most :attr:`FACTOR` usual steps),
    the clock restarted there: that row and the track's later ones are moved past the rows before, by
    ``step(usual)`` (a gap, so a new segment starts), instead of each being skipped until the time passes the
    old clock's last. A stream cannot wait: the row that went back stays skipped. The tracks of a resumed
    state file are not judged: a feed replayed from its start is skipped up to where the earlier run stopped."""

    FACTOR = 3.0

    def __init__(self, engine, step, said):
        self.engine, self.step, self.said = engine, step, said
        self.tracks: dict = {}   # track -> [shift, last time as given, first time of its clock, the row that went back]

    def adjust(self, rows) -> list:
        """``rows`` (line, track, time, positions, time as given) with the times of restarted clocks moved."""
        from ..streaming import REFERENCE_INTERVALS, short_median

        out = []
        for row in rows:
            number, track, time, values = row[:4]
            if values is None or not math.isfinite(time):
                out.append(row)
                continue
            state = self.tracks.get(track)
            if state is None:   # a new track; one of a resumed state file is not judged (a feed replayed is
                gaps = self.engine.gaps.get(_track_key(track))   # skipped up to where it stopped, not a restart)
                state = self.tracks[track] = [0.0, None, time, None, []] if gaps is None else None
            if state is None:
                out.append(row)
                continue
            shift, last, start, back, steps = state
            usual = short_median(steps) if steps else None
            state[3] = None
            if back is not None and usual is not None and back[0] < time <= back[0] + self.FACTOR * usual:
                shift = state[0] = last + shift + float(self.step(usual)) - time
                self.said(f"line {back[1]} (that line skipped)", track, last, back[0])
                last, start = time, back[0]
            elif last is not None and usual is not None and last - time > self.FACTOR * usual and time >= start:
                state[3] = (time, number)   # skipped (not after its track's last): the next row tells if it restarted
            if state[3] is None:
                if last is not None and time > last and len(steps) < REFERENCE_INTERVALS:
                    steps.append(time - last)
                state[1] = time if last is None else max(last, time)
                state[2] = min(start, time)
            out.append((number, track, time + shift, values, *row[4:]) if shift else row)
        return out


class _EmptyWatch:
    """On stdin, whose rows are not there to be sampled: a detected position column empty on each of the first
    :attr:`ROWS` rows while another has values (an exported ``z`` of 2-D tracks) makes every row a missing
    measurement and every prediction empty; said once, with the --position that leaves it out."""

    ROWS = 100

    def __init__(self, positions):
        self.positions = list(positions)
        self.rows = 0
        self.filled = np.zeros(len(self.positions), dtype=bool)

    def see(self, values) -> None:
        if len(self.positions) < 2 or self.rows >= self.ROWS or not len(values):
            return
        self.filled |= np.isfinite(values[:self.ROWS - self.rows]).any(axis=0)
        self.rows += min(len(values), self.ROWS - self.rows)
        if self.rows >= self.ROWS and self.filled.any() and not self.filled.all():
            empty = [name for name, filled in zip(self.positions, self.filled) if not filled]
            kept = [name for name, filled in zip(self.positions, self.filled) if filled]
            click.echo(f"kalmix: warning: the position column(s) {', '.join(map(repr, empty))} have been empty on each "
                       f"of the first {self.ROWS} rows: every row is a missing measurement and every prediction "
                       f"empty; --position {','.join(kept)} predicts from the others", err=True)


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
                raise _IdError(f"line {number}: no track id column named or detected, and column {name!r} looks "
                                 f"like one (different text values: {shown}). Without an id every row is one "
                                 f"track, the tracks' rows mixed: pass --id {name}, or --id none if the input "
                                 "holds a single track")


def run_predict(guard, engine, settings, unit, input_path, state_path, save_every, output, out_fmt,
                time_column, position_columns, id_column, chunk_rows, progress, backend="cpu", *,
                on_bad_row="skip", rejects=None):
    """Run, commit, and on any exit save what was committed; then report."""
    run = Run(guard, engine, state_path, save_every, output, out_fmt, on_bad_row, rejects)
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
