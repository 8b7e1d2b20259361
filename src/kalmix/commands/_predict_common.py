"""What the two readers of ``kalmix predict`` (a file, stdin) share: the :class:`Run` that commits the
engine, its output and its state file together and reports at the end, and the engine's set-up."""

from __future__ import annotations

import math

import click

from ._durable import Interrupted
from ._output import Output
from ._predict_notes import STDIN_WARNINGS, BadRowLog, IdWatch, UnitWatch, gap_note, gap_splits


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
        self.dropped = {"untimed": 0, "repeated": 0, "late": 0}   # a file's rows not predicted, by why
        self.resuming = engine is not None  # a state file was loaded
        self.sink: Output | None = None
        self.rows = self.since_save = 0
        self.skipped0 = engine.skipped if engine is not None else 0
        self.glitches0 = engine.time_glitches if engine is not None else 0
        self.outliers0 = engine.outliers if engine is not None else 0
        self.splits0 = gap_splits(engine)
        self.stopped: Interrupted | None = None
        self.closed = False
        self.measured = 0   # input rows of this run with every position present
        self.untimed = 0   # stdin rows skipped for want of a time
        self.saved = False   # the state file was written by this run
        self.unit = "chunk"
        self.one_track = False   # a file without a track id column: every row is one track's

    def open_output(self, fmt=None):
        """Open ``-o`` (checked against the state file's record when resuming) once the input is known good."""
        self.sink = Output(self.output, fmt or self.out_fmt, previous=self.engine.output if self.resuming else None,
                           resuming=self.resuming, state_path=self.state_path,
                           note=lambda text: click.echo(f"kalmix: {text}", err=True))

    def clock_reset(self, place, track, before, after) -> None:
        """Say (the first :data:`STDIN_WARNINGS`) that a track's clock restarted at ``place``, and count it."""
        self.resets += 1
        track = track.item() if hasattr(track, "item") else track   # 3, not np.int64(3)
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
        this run created and never wrote to is removed (a file's rows are held until its first row to step:
        :func:`._predict_file.predict_file`)."""
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
            click.echo(f"kalmix: warning: {bad}", err=True)
        if engine is not None and engine.skipped > self.skipped0:
            fate = ("not written (a file's rows skipped are left out of the output)" if self.unit != "row" else
                    "those the state file had done are left out of the output, the others' output rows have empty "
                    "predictions" if self.resuming else "their output rows have empty predictions")   # stdin's rows
            click.echo(f"kalmix: warning: skipped {engine.skipped - self.skipped0} row(s) at or before their "
                       f"track's last time (already processed or out of order); {fate}", err=True)
        if self.untimed:
            click.echo(f"kalmix: warning: skipped {self.untimed} row(s) without a time; their output rows have empty "
                       "predictions", err=True)
        if self.dropped["untimed"]:
            click.echo(f"kalmix: warning: {self.dropped['untimed']} row(s) have no time: not predicted (their output "
                       "rows have empty predictions)", err=True)
        if self.resets > STDIN_WARNINGS:
            click.echo(f"kalmix: note: {self.resets} clock restart(s) started a new segment of their track", err=True)
        if self.dropped["repeated"]:
            click.echo(f"kalmix: warning: {self.dropped['repeated']} row(s) repeat a timestamp within their track: "
                       "the last row of each repeated time is predicted, the others' output rows have empty "
                       "predictions" + ("; no track id column was found, so every row is taken as one target's: "
                                        "rows of several targets need an id column (--id names one not recognised)"
                                        if self.one_track else ""), err=True)
        if self.dropped["late"]:
            click.echo(f"kalmix: warning: {self.dropped['late']} row(s) came at or before their track's last time in "
                       "the rows read before them (a file is read a chunk at a time, see --chunk-rows, and rows cannot "
                       "be reordered across chunks): not predicted (their output rows have empty predictions); sort "
                       "the file by track and time to predict them", err=True)
        if engine is not None and engine.time_glitches > self.glitches0:
            click.echo(f"kalmix: warning: {engine.time_glitches - self.glitches0} row(s) came back in time after "
                       "a jump ahead: the jump's timestamp was taken as wrong and the track went on", err=True)
        if engine is not None and engine.outliers > self.outliers0:
            click.echo(f"kalmix: {engine.outliers - self.outliers0} outlier(s): glitches far from their track's "
                       "extrapolation, not learned (one in a track's first rows: the track started again after it); "
                       "their predictions are still written", err=True)
        if engine is not None:
            gap_note(engine.config.max_gap, engine.config.max_gap_factor, gap_splits(engine) - self.splits0,
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


def check_resumed(engine, columns):
    """A ``ValueError`` when a resumed state file's coordinates are not the input's position columns."""
    if engine is None:
        return
    if engine.position_names is not None and list(engine.position_names) != list(columns.positions):
        raise ValueError(f"the state file tracks the coordinates {list(engine.position_names)}, the input has "
                         f"{list(columns.positions)} (pass --position to name them, or use a new --state file)")


def geographic_axes(engine, settings, columns):
    """The positions' :class:`kalmix.io.geo.GeoAxes` when they are geographic (a resumed state's setting, else
    --geographic / --no-geographic, else their names), told on stderr; None when they are flat."""
    from ..io.geo import geographic_note, resolve_axes

    if engine is not None:
        axes = engine.axes
    else:
        axes = resolve_axes(list(columns.positions), settings.get("geographic"))
    if axes is not None:
        click.echo(f"kalmix: {geographic_note(list(columns.positions), axes, '--no-geographic')}", err=True)
    return axes


def new_engine(settings, unit, positions, backend="cpu"):
    """The engine of a run that starts (no state file), with length unit ``unit``, on ``backend``."""
    from ..bank import check_automatic_length_unit
    from ..streaming import StreamConfig, TrackPredictor

    check_automatic_length_unit(unit)
    return TrackPredictor(StreamConfig(length_unit=unit, **settings), positions, backend=backend)


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


def track_key(track):
    """A track id as read (stdin's, or a file's text) as the engine keys its trackers."""
    from ..streaming import id_to_json

    return id_to_json(track)
