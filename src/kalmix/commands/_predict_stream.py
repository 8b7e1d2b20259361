"""``kalmix predict -``: the rows of standard input stepped batch by batch as they arrive, each batch's
output lines written and committed together (:class:`._predict_common.Run`)."""

from __future__ import annotations

import math

import click
import numpy as np

from ._input import input_columns
from ._predict_common import check_resumed, geographic_axes, new_engine, reset_step, track_key
from ._predict_notes import STDIN_WARNINGS
from ._stdin_lines import CsvRecords, first_line, line_batches
from ._stdin_rows import BadLine, RowReader, header_of


def warm_up_meanwhile(run, settings, unit) -> None:
    """Load the compiled kernels in a thread while stdin has nothing for this one (quick with numba's cache
    warm, long on a fresh install): a live feed's first line is answered sooner. Only a head start: the
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


def predict_stream(run, stdin, settings, unit, time_column, position_columns, id_column):
    """Predict the rows of ``stdin`` (CSV, header first, or JSON lines) as they arrive, into ``run``."""
    run.unit = "row"
    if stdin is None:   # the process was started with its standard input closed
        raise ValueError("stdin: closed (INPUT '-' reads the tracks from standard input; give a file name)")
    warm_up_meanwhile(run, settings, unit)
    skip = run.on_bad_row == "skip"
    # UTF-8 whatever the locale, as a file; bytes that are not UTF-8 kept (as lone surrogates) for the columns
    # used to refuse, so that those of a column not used (a vessel's name in Windows-1252) cost no row
    batches = line_batches(stdin, encoding="utf-8", errors="surrogateescape")
    line_number, first, rest = first_line(batches)
    is_json, header, pending = header_of(first, line_number)
    columns = input_columns(header, time_column, position_columns, id_column)
    check_resumed(run.engine, columns)
    axes = geographic_axes(run.engine, settings, columns)
    if run.engine is None:
        if unit is None:
            from ..streaming import length_unit_fallback

            click.echo(f"kalmix: {length_unit_fallback(None, 'stdin', '--length-unit', ' m' if axes else '')}",
                       err=True)
        run.engine = new_engine(settings, 1.0 if unit is None else unit, columns.positions, run.backend)
    run.engine.warn_skipped = False   # skipped rows are said line by line here
    reader = RowReader(columns, header, is_json, id_column, axes, run.engine, run.ids, skip)
    batch = _Batches(run, reader, line_number, position_columns, settings)
    run.open_output(run.out_fmt if run.output else ("jsonl" if is_json else "csv"))
    run.bad.open("line", append=run.resuming)
    batch.take(rest, [reader.read(number, first, record) for number, record in pending])
    for lines in batches:
        batch.take(lines, [])
    batch.take([], [], end=True)
    batch.finish()


class _Batches:
    """Stdin's batches of lines, each parsed (:class:`RowReader`), stepped, written and committed together,
    then warned of line by line; ``line_number``: the lines read before the first batch."""

    def __init__(self, run, reader, line_number, position_columns, settings):
        self.run, self.reader, self.line_number = run, reader, line_number
        self.engine, self.columns = run.engine, reader.columns
        # by the runs before this one
        self.done_before = {track: gaps.last_time for track, gaps in self.engine.gaps.items()}
        self.previous_written = True   # the last row with a time was written (a row without one shares its fate)
        self.empties = _EmptyWatch(self.columns.positions if position_columns is None else ())
        self.clocks = _StreamClocks(self.engine, reset_step(settings), run.clock_reset)
        self.warned: dict[str, int] = {}
        self.records = None if reader.is_json else CsvRecords()   # a CSV record may go on over lines

    def warn(self, kind, text):
        """A line's warning; after STDIN_WARNINGS of a kind, one line that says the rest are only counted (a
        replayed feed skips every row already processed: one line each would flood the terminal)."""
        count = self.warned[kind] = self.warned.get(kind, 0) + 1
        if count <= STDIN_WARNINGS:
            click.echo(f"kalmix: warning: {text}", err=True)
        if count == STDIN_WARNINGS:
            click.echo("kalmix: (further warnings like the last are only counted: the total comes at the end)",
                       err=True)

    def take(self, lines, rows, end: bool = False):
        """Parse ``lines`` after ``rows``, step and write them, then warn line by line. A bad line (one that
        does not parse, or whose values are not an id, a time and positions) is, with ``--on-bad-row skip``,
        a row not stepped, warned of and counted; with ``fail``, the rows before it are stepped, written and
        warned about, then it raises. A CSV record whose quoted field holds a line break is one row, of its
        first line, once its last line is there (``end``: the input's end, where an unfinished one is taken as
        it is). Lines read are finished, warnings included, whatever signal comes (the signal is raised after
        them)."""
        run, warn = self.run, self.warn
        error = None
        with run.guard.deferred():
            try:
                for raw in lines:
                    self.line_number += 1
                    record = (self.line_number, raw) if self.records is None else self.records.add(
                        self.line_number, raw)
                    if record is not None and record[1].strip():
                        rows.append(self.reader.read(*record))
                last = None if self.records is None or not end else self.records.rest()
                if last is not None:
                    rows.append(self.reader.read(*last))
            except Exception as bad:   # noqa: BLE001 - raised below, once the rows before it are done
                error = bad
            rows[:], undated = self.reader.dates(rows)
            error = undated or error   # an earlier line than the one that stopped the parse
            if self.columns.time is not None:
                rows[:] = self.clocks.adjust(rows)
            results = iter(self.step(rows))
            for row in rows:
                number, track, time, values = row[:4]
                if isinstance(row, BadLine):
                    warn("bad", f"line {number}: bad row skipped: {row.reason}")
                    continue
                if values is None:
                    run.untimed += 1
                    warn("untimed", f"line {number}: no time, row skipped")
                    continue
                result = next(results)
                shown = row[4] if len(row) > 4 and row[4] is not None else time   # the time as written
                if result is None:
                    warn("skipped", f"line {number}: time {shown!r} is not after the previous time of track "
                                    f"{track!r}; row skipped")
                elif result.time_glitch:
                    warn("glitch", f"line {number}: time {shown!r} comes back before the jump ahead of track "
                                   f"{track!r}; that jump's timestamp was taken as wrong and the track goes on")
        run.units.check(self.engine)
        if rows:
            run.guard.tick()
        if error is not None:
            raise error

    def step(self, rows) -> list:
        """Step the rows with a time (line, track, time, positions, time as given) and write every row's output
        line in order, committed together: a stepped row's predictions; a row not stepped (no time, a time not
        after its track's last) with empty ones, unless this run found it done before (at or before its
        track's time in the state file it resumed from; a row without a time: if the row with a time before
        it was). The stepped rows' results, in order (None: skipped)."""
        if not rows:
            return []
        run, engine, columns = self.run, self.engine, self.columns
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
                    before = self.done_before.get(track_key(track))
                    written = before is None or not time <= before
                else:   # a row without a time, or a bad row: shares the fate of the last row with a time
                    written = self.previous_written
                if measured is not None:
                    self.previous_written = written
                if written:
                    time_out = given if self.reader.is_json else given_time(   # JSON: its own
                        given, run.sink.fmt, measured is not None, self.reader.time_kind.get("kind"))
                    records.append(_row_record(result, track, time_out, columns, prefixes))
                    if isinstance(row, BadLine):
                        rejected.append(row)
            run.sink.write_records(records)
            run.bad.add([f"line {row.line}" for row in rejected], [row.reason for row in rejected],
                        [row.text for row in rejected])
            committed = True
            run.measured += int(np.isfinite(values).all(axis=1).sum())
            self.empties.see(values)
        except BaseException:
            if not committed:
                engine.rollback(mark)
            raise
        run.commit(len(timed))
        return results

    def finish(self) -> None:
        """A CSV output whose every row was skipped: its header all the same, named as a file's run names its
        columns."""
        run = self.run
        if run.sink.fmt != "csv" or run.sink.header_written:
            return
        import pandas as pd

        from ..streaming import with_input_names

        empty = pd.DataFrame(columns=["track_id", "time", "segment", *(
            name for names in self.engine.output_columns().values() for name in names)])
        with run.guard.deferred():
            run.sink.write_header(list(with_input_names(empty, self.columns).columns))


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


def given_time(value, fmt, read=True, kind=None):
    """A stdin row's time as given, for an output of format ``fmt``: CSV text as written in CSV; in JSON lines,
    as a file's (:func:`._predict_file.given_times`): text that holds a number as that number (a whole number as
    an integer), a date-time as its text, by the column's kind (``kind``, None before a time was read), and a
    time missing or bad (``read`` False: a row not stepped, whose time may still be one) as null; a JSON value,
    or a row number, as it is."""
    if fmt != "jsonl" or not isinstance(value, str):
        return value
    text = value.strip()
    try:
        number = float(text)
    except ValueError:
        number = None
    if number is not None:
        if not math.isfinite(number) or kind == "date-time":
            return None
        return int(text) if text.lstrip("+-").isdigit() else number
    if read or kind == "number":
        return value if read else None
    from ..io.values import iso_seconds

    return None if math.isnan(iso_seconds([value], errors="coerce")[0]) else value


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
                gaps = self.engine.gaps.get(track_key(track))   # skipped up to where it stopped, not a restart)
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
