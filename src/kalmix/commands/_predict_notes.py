"""What a ``kalmix predict`` run tells the user on stderr besides its output: the bad rows it skipped (and
the ``--rejects`` file), track ids that look alike, a time unit learned from an odd first step, and a gap
rule that splits many rows."""

from __future__ import annotations

import csv
import math
import os

import click
import numpy as np


#: Warnings of one kind printed line by line on stdin (rows skipped, time glitches, rows without a time);
#: the rest are counted in the run's summary.
STDIN_WARNINGS = 10


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


def gap_splits(engine) -> int:
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
        self.writer = csv.writer(self.handle, lineterminator="\n")   # (as the output: csv's own is "\r\n")
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
    """Says once (on stderr) when a time unit learned on stdin, the first step of the first track to have one, is
    far from that track's usual step (the median of its first :data:`~kalmix.streaming.REFERENCE_INTERVALS` steps,
    or of those it has at the end): a 1 ms first step among 1 s steps makes the unit 1 ms, the experts' noise
    scales with it, and the first forecasts are wild. The unit stays (a stream cannot wait for more steps); the line
    gives the --time-unit to pass. (A file's unit is its first chunk's median step, not warned about.)"""

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
