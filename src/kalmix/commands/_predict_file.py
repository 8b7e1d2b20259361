"""``kalmix predict`` on a file: read chunk by chunk, each chunk stepped in pieces, its output rows laid
out as the file gave them, then committed whole (:class:`._predict_common.Run`)."""

from __future__ import annotations

import gzip
import os
import sys
import warnings

import click
import numpy as np

from ._input import track_file
from ._predict_common import check_resumed, geographic_axes, new_engine, reset_step, track_key


#: A chunk is stepped in pieces of about this many rows (each track's rows split in order,
#: so every piece holds every track of the chunk and the batch stays as wide): the progress
#: bar moves and a stop signal is honoured after each piece, not once per chunk. Each piece
#: costs a fixed share of Python work (stacking and splitting the tracks' states) and ends
#: waiting for the engine's slowest group of targets (:func:`kalmix.core.compiled._threads.group_size`),
#: so larger pieces run faster, with the same output bit for bit; this size keeps a stop prompt.
PIECE_ROWS = 65_536
_MAX_PIECES = 64


def _say_not_available(chunk, names, axes, offset, said: bool = False) -> bool:
    """A warning, once (``said``: already), at a chunk's first file row (``offset``: the file rows before it) with
    AIS's latitude 91 or longitude 181 ("not available": a missing position). Returns whether it was said. (A
    latitude beyond ±90° or a longitude beyond ±180° otherwise is a bad row, left out of the chunk by the reader.)"""
    from ..io.geo import not_available

    given = chunk.attrs.get("as_given")
    places = np.asarray(given.places) if given is not None else np.arange(len(chunk))
    order = np.argsort(places, kind="stable")   # file order: the first such row of the file is named
    values = chunk[names].to_numpy(np.float64)[order]
    gone = np.flatnonzero(not_available(values, axes))
    if len(gone) and not said:
        row = offset + int(places[order[gone[0]]])
        click.echo(f"kalmix: warning: latitude 91 or longitude 181 (AIS: no position) is a missing position, as an "
                   f"empty cell: the row keeps its place and is predicted (first at row {row}, counted from 0 after "
                   "the header); this is said once", err=True)
        return True
    return said


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


def given_rows(frame, chunk, columns, fmt, kept: list | None = None, time_kind: str | None = None):
    """A chunk's output: ``frame``, the predictions of the chunk rows the engine stepped (in chunk order, as
    :func:`merge` gives them), laid out on the chunk's file rows in file order, each with its id and time as
    the file gave them (:class:`kalmix.io.tables.AsGiven`; the time as :func:`given_times` writes it in
    ``fmt``). A file row not stepped (no time, an earlier row of a repeated time) has empty predictions and
    segment; one a resumed run skips as done before, or that shares such a row's fate, is left out (its run
    wrote it). ``kept``: given a list, receives which file rows are written (a boolean array). ``time_kind``:
    the file's time kind where the rows read so far have not decided it (a first pass over the file found it)."""
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
        times, read = (given.times, given.read_times) if every else (given.times[written], given.read_times[written])
        out[columns.time] = given_times(times.reset_index(drop=True), fmt, read, given.time_kind or time_kind)
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


def given_times(times, fmt, read, kind):
    """A time column as the input gave it, for an output of format ``fmt``: a CSV file's or stdin's text as
    written in a CSV output; in JSON lines and Parquet, text by the file's time kind (``kind``, None before a
    time could be read), one type for every chunk of the file: numbers as the numbers read (``read``, NaN where
    a time is missing or bad; JSON: whole numbers as integers, the others as floats; Parquet: float64),
    date-times as their text, and a time missing or bad (neither a number nor a date-time of the column's kind)
    as null. Any other column (Parquet's own types) as it is."""
    import pandas as pd

    if fmt == "csv" or not pd.api.types.is_string_dtype(times):
        return times
    unread = np.isnan(read)
    if kind == "date-time":
        return times.mask(unread)
    if fmt == "parquet":
        return pd.Series(read, dtype=np.float64)
    whole = times.str.strip().str.fullmatch(r"[+-]?\d+").fillna(False).to_numpy(bool)
    return pd.Series([None if missing else int(text) if integer else number for text, number, integer, missing
                      in zip(times.tolist(), read.tolist(), whole.tolist(), unread.tolist())], dtype=object)


def predict_file(run, path, settings, unit, time_column, position_columns, id_column, chunk_rows, progress):
    """Predict the rows of the track file ``path`` (CSV or Parquet) chunk by chunk, into ``run``."""
    import pandas as pd
    from tqdm import tqdm

    from ..io import iter_track_chunks
    from ..io.tables import DroppedRowWarning

    in_fmt, columns = track_file(path, time_column, position_columns, id_column)
    run.one_track = columns.track_id is None and id_column is None   # none found (not --id none)
    check_resumed(run.engine, columns)
    run.open_output()
    show = sys.stderr.isatty() if progress is None else progress
    total = None
    if in_fmt == "parquet":
        import pyarrow.parquet as pq
        with pq.ParquetFile(path) as parquet:
            total = parquet.metadata.num_rows
            schema = parquet.schema_arrow
        # a chunk whose ids (or times) are all missing has Python objects without a type: the input's, in Parquet
        run.sink.types = {name: schema.field(name).type for name in (columns.track_id, columns.time)
                          if name is not None}
    elif show:
        total = count_rows(path)
    names = list(columns.positions)
    if total is None:
        total_rows = count_rows(path)
    else:
        total_rows = total
    run.bad.open("row" if in_fmt == "parquet" else "line", append=run.resuming)
    axes = geographic_axes(run.engine, settings, columns)
    offset = 0   # file rows before the chunk
    said_unavailable = False
    clocks = _clocks(run.engine, settings)
    kind: dict = {}   # the time column's kind, as the first pass over a file of several chunks finds it
    ahead = (_lookahead(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                          ids_as_text=True, on_bad_row=run.on_bad_row,
                                          clock_resets=_clocks(run.engine, settings), late_rows="skip",
                                          time_kind=kind, geographic=axes))
             if total_rows > chunk_rows else [])
    # the chunks before the first row to step (every row bad or without a time) are written with it, sharing its
    # fate: a file with no row to step fails at its end and leaves the output as it was (a new file not made, an old
    # one unchanged), and a resumed run leaves them out where that row was done before (its run wrote them)
    pending: list = []
    stepping = False
    with tqdm(total=total, unit="rows", file=sys.stderr, disable=not show,
              desc="kalmix predict", smoothing=0.1) as bar, warnings.catch_warnings():
        warnings.simplefilter("ignore", DroppedRowWarning)   # counted here and said at the end (Run.report)
        for index, chunk in enumerate(iter_track_chunks(path, columns=columns, chunk_rows=chunk_rows, format=in_fmt,
                                                        ids_as_text=True, as_given=True, on_bad_row=run.on_bad_row,
                                                        bad_texts=run.bad.path is not None,
                                                        clock_resets=clocks, late_rows="skip", geographic=axes)):
            for why, count in chunk.attrs.get("dropped", {}).items():
                run.dropped[why] += count
            run.ids.see_many(pd.unique(chunk["track_id"]).tolist())
            for place, track, before, after in chunk.attrs.get("clock_resets", ()):
                run.clock_reset(place, track, before, after)
            offset += chunk.attrs.get("file_rows", len(chunk))
            if axes is not None:
                said_unavailable = _say_not_available(chunk, names, axes,
                                                      offset - chunk.attrs.get("file_rows", len(chunk)),
                                                      said_unavailable)
            if not len(chunk):   # every row bad or without a time: their output rows, nothing to step
                if not stepping:
                    pending.append(chunk)
                else:
                    _write_unstepped(run, chunk, columns, settings, kind.get("kind"))
                bar.update(chunk.attrs.get("file_rows", 0))
                continue
            if run.engine is None:
                run.engine = _first_engine(chunk, names, unit, axes, settings, columns.positions, run.backend)
            if pending and not (run.resuming and _done_before(run.engine, chunk)):
                for held in pending:
                    _write_unstepped(run, held, columns, settings, kind.get("kind"))
            else:   # done before: neither written nor counted again
                for held in pending:
                    for why, count in held.attrs.get("dropped", {}).items():
                        run.dropped[why] -= count
            pending.clear()
            stepping = True
            _step_chunk(run, chunk, names, ahead[index] if index < len(ahead) else {}, clocks, columns, bar,
                        kind.get("kind"))
            bar.update(chunk.attrs.get("file_rows", len(chunk)) - len(chunk))
            run.units.check(run.engine)


def _done_before(engine, chunk) -> bool:
    """Whether the chunk's first row in file order is one a resumed run skips as done before (its time not after
    its track's last in the state file)."""
    first = int(np.argmin(chunk.attrs["as_given"].places))
    ids = np.empty(1, dtype=object)
    ids[0] = chunk["track_id"].iloc[first]
    return not bool(engine.stepped_rows(ids, chunk["time"].to_numpy()[first:first + 1])[0])


def _first_engine(chunk, names, unit, axes, settings, positions, backend):
    """The engine of a run that starts (no state file), its length unit given or estimated on the first chunk (said
    on stderr)."""
    from ..streaming import estimate_length_unit, length_unit_fallback

    chosen, why = (unit, None) if unit is not None else estimate_length_unit(
        chunk, names, geographic=axes is not None)
    metres = " m" if axes is not None else ""
    if unit is None and why is None:
        click.echo(f"kalmix: length unit {chosen:.6g}{metres} (auto; pass --length-unit to override)",
                   err=True)
    elif unit is None:
        click.echo(f"kalmix: {length_unit_fallback(why, 'the first chunk', '--length-unit', metres)}",
                   err=True)
    return new_engine(settings, chosen, positions, backend)


def _step_chunk(run, chunk, names, later, clocks, columns, bar, time_kind=None) -> None:
    """Step a chunk piece by piece (``later``: :func:`_lookahead`'s next times of its tracks), then write its
    output rows (``time_kind``: as :func:`given_rows`) and commit; rolled back if stopped before the commit."""
    import pandas as pd

    from ..streaming import next_row_times

    engine = run.engine
    engine.warn_skipped = False   # skipped rows are counted and said at the end (Run.report)
    mark = engine.checkpoint(pd.unique(chunk["track_id"]))
    committed = False
    try:
        if engine.config.time_unit is None or "auto" in (engine.config.reach, engine.config.gap_floor):
            _learn_sampling(engine, chunk, names)
        parts, summaries = _parts(engine, chunk)
        frames = []
        for k, (piece, times) in enumerate(zip(parts, next_row_times(parts, later))):
            frames.append(engine.process_table(piece, names, times))
            bar.update(len(piece))
            if k not in summaries:   # a unit of work done (a stop may come here), but for a part cut at a summary
                run.guard.tick()
        _keep_clocks(engine, clocks, pd.unique(chunk["track_id"]))
        written: list = []
        frame = given_rows(merge(frames, chunk), chunk, columns, run.sink.fmt, written, time_kind)
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


def _learn_sampling(engine, chunk, names) -> None:
    """Fix the time unit and an automatic reach from the chunk's steps (the first chunk that has one); a reach
    settled on irregular steps is said on stderr."""
    automatic = engine.config.reach == "auto"
    engine.learn_time_unit(chunk, names)
    if automatic and engine.config.reach not in ("auto", None):
        unit = engine.config.time_unit
        click.echo(f"kalmix: the time steps are heavy-tailed: across a step over {engine.config.reach:g} time units "
                   f"({engine.config.reach * unit:.6g}; the time unit {unit:.6g} is the median step) only the "
                   "constant-velocity experts predict (auto; pass --reach to override)", err=True)


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
        gaps = engine.gaps.get(track_key(track))
        if gaps is not None and (clock is not None and clock[0] or gaps.clock is not None):
            gaps.clock = None if clock is None else list(clock)


def _log_bad_rows(run, chunk, written) -> None:
    """Count a chunk's bad rows, and write them to --rejects: those whose output rows are written (a resumed run
    leaves out the rows an earlier run wrote, bad ones included)."""
    bad = chunk.attrs.get("bad_rows")
    if bad is None:
        return
    keep = written[bad.local]
    run.bad.add([p for p, k in zip(bad.places, keep) if k], [r for r, k in zip(bad.reasons, keep) if k],
                [t for t, k in zip(bad.texts, keep) if k])


def _write_unstepped(run, chunk, columns, settings, time_kind=None) -> None:
    """Write the output rows of a chunk without a row to step (every row bad or without a time): the id and time
    as given (``time_kind``: as :func:`given_rows`), empty predictions."""
    import pandas as pd

    from ..streaming import StreamConfig, TrackPredictor

    engine = run.engine if run.engine is not None else TrackPredictor(StreamConfig(length_unit=1.0, **settings),
                                                                      columns.positions)
    frame = pd.DataFrame({"track_id": pd.Series(dtype=object), "time": pd.Series(dtype=np.float64),
                          "segment": pd.Series(dtype=np.int64), **{
                              name: pd.Series(dtype=np.float64)
                              for names in engine.output_columns().values() for name in names}})
    written: list = []
    out = given_rows(frame, chunk, columns, run.sink.fmt, written, time_kind)
    with run.guard.deferred():
        run.sink.write_frame(out)
        _log_bad_rows(run, chunk, written[0])
        run.commit(0)


def _parts(engine, chunk):
    """A chunk's parts to step in turn (each cut into :func:`pieces`), and the parts that end where a population
    summary falls.

    A stream summarises its population prior after fixed counts of rows in its arrival order
    (:mod:`kalmix.stream.population`). So the chunk is cut in file order there, and every row before
    a cut is stepped (track by track) before any after it: the numbers of a stream of the file's
    rows.
    """
    from ..io import in_file_order
    from ..stream.times import column_seconds

    if not engine.summary_within(len(chunk)):
        return pieces(chunk), set()
    arrived = in_file_order(chunk[["track_id", "time"]])
    cuts = engine.summary_cuts(arrived["track_id"].to_numpy(), column_seconds(arrived["time"]))
    if not cuts:
        return pieces(chunk), set()
    parts, ends = [], set()
    for begin, end in zip([0, *cuts], [*cuts, len(chunk)]):
        mask = np.zeros(len(chunk), dtype=bool)
        mask[arrived.index[begin:end]] = True
        parts.extend(pieces(chunk[mask]))
        if end in cuts:
            ends.add(len(parts) - 1)
    return parts, ends


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


def count_rows(path: str) -> int:
    """Data rows of a CSV (``.gz`` too) file: its lines minus the header, in one fast pass."""
    opener = gzip.open if os.fspath(path).lower().endswith(".gz") else open
    count, last = 0, b"\n"
    with opener(path, "rb") as handle:
        while block := handle.read(1 << 20):
            count += block.count(b"\n")
            last = block[-1:]
    return max(0, count - 1 + (last != b"\n"))
