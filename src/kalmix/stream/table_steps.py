"""A table (or a chunk of a big file) at once through a :class:`~kalmix.streaming.TrackPredictor`: its columns
found, every track segment in it stepped through the batched engine, the forecasts written beside its rows."""

from __future__ import annotations

import warnings

import numpy as np

from ..core.engine import BankState, tree_map
from .columns import ColumnNoteWarning, find_columns, names_argument
from .gaps import SkippedRowWarning
from .ids import factorize_ids, id_to_json
from .times import column_seconds, next_row_times

#: Most tracks :meth:`TrackPredictor.process_table` steps in one run of the engine: their states are stacked for
#: the run and the run returns as many, so a table of many tracks goes a batch at a time (the same bits), in
#: bounded memory (as :data:`kalmix.dask_predict.BATCH_TRACKS`).
TRACK_BATCH = 1024


def _stack(states: list) -> BankState:
    return tree_map(lambda *arrays: np.concatenate(arrays, axis=0), *states)


def _take(state, index):
    return tree_map(lambda a: a[index], state)


def with_input_names(frame, columns):
    """A :meth:`TrackPredictor.process_table` output with the input's column names: ``time`` renamed to the time
    column's name (``row`` when the input had none) and ``track_id`` to the id column's, or dropped when the input
    had none. ``columns`` names them (a :class:`kalmix.io.TrackColumns`)."""
    renames = {"time": columns.time or "row"}
    if columns.track_id is not None:
        renames["track_id"] = columns.track_id
    else:
        frame = frame.drop(columns="track_id")
    return frame.rename(columns=renames)


def position_values(table, names, first_row: int = 0) -> np.ndarray:
    """``table[names]`` as float64 ``(n, p)``; a ``ValueError`` naming the column and row (counted from ``first_row``)
    of the first value that is not a number."""
    import pandas as pd

    try:
        return table[names].to_numpy(np.float64)
    except (TypeError, ValueError):
        bad = next(name for name in names if not pd.api.types.is_numeric_dtype(table[name]))
        column = table[bad].reset_index(drop=True)
        wrong = column.notna() & pd.to_numeric(column, errors="coerce").isna()
        i = int(np.flatnonzero(wrong.to_numpy())[0]) if wrong.any() else 0
        raise ValueError(f"table: position column {bad!r} must hold numbers, got {column.iloc[i]!r} in row "
                         f"{first_row + i} (counted from 0; {table[bad].dtype} values)") from None


class TableSteps:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that steps tables."""

    def process_table(self, table, position_names=None, next_times=None):
        """Step every track of a track table through the batched core.

        The columns are found as ``kalmix predict`` finds them in a file: a table with columns
        named ``track_id`` and ``time`` is taken as it is (the positions: ``position_names``, else
        those :func:`kalmix.io.detect_columns` detects among the other columns, else all of
        them); any other table goes through :func:`find_columns`, the command's detection (an
        id column such as ``mmsi`` or ``icao24``, a time column of numbers, datetimes or ISO 8601
        text such as ``BaseDateTime``, positions such as ``lat``/``lon``; no id column: one
        track; no time column: row order), whose notes come as :class:`ColumnNoteWarning`.
        With ``length_unit="auto"`` the first table also fixes the length unit
        (:func:`estimate_length_unit`, as the command on a file's first chunk), and with
        ``time_unit=None`` the first table with a time step fixes the time unit, the median step
        (:meth:`learn_time_unit`, as the command on a file's first chunk). Geographic
        positions (:class:`StreamConfig`'s ``geographic``) are predicted in metres and come back
        in degrees, their standard deviations in metres (``std_east_m``, ``std_north_m``).

        All or nothing: an exception in the middle leaves the predictor as it was.

        Parameters
        ----------
        table : pandas.DataFrame
            Track rows, each track's rows in time order (as :func:`kalmix.io.read_tracks` /
            :func:`~kalmix.io.iter_track_chunks` give, or as a feed delivers them, tracks
            interleaved). Rows continue the tracks already seen (a chunk of a big file).
        position_names : sequence of str, optional
            Position columns; default: detected (see above), or those of the tables before.
        next_times : mapping, optional
            Track id -> time of the track's next row after this table (a later chunk). A
            track's last row in the table is forecast for that time; without one, one
            reference interval later (as :meth:`step_row`).

        Returns
        -------
        pandas.DataFrame
            ``track_id, time, segment, pred_<pos>..., std_<pos>...`` (and ``pred<H>_<pos>``,
            ``std<H>_<pos>`` for a horizon H > 1, or ``lead_<pos>``, ``lead_std_<pos>`` with a
            lead), one row per input row that was not skipped (a row without a time, or not after its
            track's last time: the first gives a :class:`SkippedRowWarning`), in table order. A table whose
            columns were detected keeps its id and time columns' names and values as given
            (no id column: none; no time column: ``row``, each track's row number).
        """
        import pandas as pd

        if not isinstance(table, pd.DataFrame):
            raise TypeError(f"table: expected a pandas DataFrame (track_id, time and position columns), got "
                            f"{type(table).__name__}")
        position_names = names_argument(position_names)
        source, table, position_names, columns = table, *self._front_door(table, position_names)
        if next_times is not None:
            try:
                next_times = {track: float(when) for track, when in dict(next_times).items()}
            except (TypeError, ValueError):
                raise ValueError(f"next_times: expected a mapping of track id -> time (a number), got "
                                 f"{next_times!r:.80}") from None
        position_names = (list(position_names) if position_names
                          else [c for c in table.columns if c not in ("track_id", "time")])
        if not position_names:
            raise ValueError(f"table: expected 1 to 3 position columns beside track_id and time, got none "
                             f"(columns: {list(table.columns)})")
        missing = [c for c in ("track_id", "time", *position_names) if c not in table.columns]
        if missing:
            raise ValueError(f"table: expected the columns track_id, time and the positions, missing {missing} "
                             f"(columns: {list(table.columns)})")
        used = ("track_id", "time", *position_names)
        twice = sorted({str(c) for c in table.columns[table.columns.duplicated()] if c in used})
        if twice:
            raise ValueError(f"table: expected each of the columns track_id, time and the positions once, got {twice} "
                             f"more than once (columns: {list(table.columns)})")
        saved = self.checkpoint(pd.unique(table["track_id"]))
        kept: list = []
        try:
            names = list(position_names)
            if self.position_names is not None and set(names) == set(self.position_names):
                names = list(self.position_names)
            decided = self._geo_decided
            self._decide_geographic(names)
            if self.axes is not None and not decided and self.config.geographic is None:   # from the names: said
                from ..io.geo import geographic_note

                warnings.warn(geographic_note(names, self.axes, "geographic=False"), ColumnNoteWarning, stacklevel=2)
            if self.axes is not None:
                from ..io.geo import check_degrees

                check_degrees(table[names].to_numpy(np.float64), self.axes, names,
                              lambda i: f"table: row {i} (counted from 0)")
            if self.config.length_unit == "auto":   # (text in a position named before the unit's estimate reads it)
                position_values(table, names)
            self._resolve_length_unit(table, names, "the table")
            self.learn_time_unit(table, names)
            frame = self._process_table(table, position_names, next_times or {}, kept=kept)
        except BaseException:
            self.rollback(saved)
            raise
        rows = np.concatenate(kept) if kept else np.zeros(0, dtype=np.int64)
        if len(rows) < len(table) and self.warn_skipped:
            self._warn_skipped_rows(table, rows)
        if columns is None:
            return frame
        if columns.time is not None:   # the time as given (the frame's is in seconds)
            frame["time"] = source[columns.time].iloc[rows].to_numpy()
        if columns.track_id is not None:
            frame["track_id"] = source[columns.track_id].iloc[rows].to_numpy()
        return with_input_names(frame, columns)

    def _warn_skipped_rows(self, table, kept) -> None:
        """Once (:attr:`warn_skipped`), as :meth:`step_row` warns: rows of ``table`` not stepped (not in ``kept``) for
        their time, at or before their track's last time, or none."""
        self.warn_skipped = False
        skipped = np.ones(len(table), dtype=bool)
        skipped[kept] = False
        i = int(np.flatnonzero(skipped)[0])
        track, time = id_to_json(table["track_id"].iloc[i]), id_to_json(table["time"].iloc[i])
        warnings.warn(f"table: {int(skipped.sum())} row(s) skipped, the first in row {i} (counted from 0; track "
                      f"{track!r}, time {time!r}): a row without a time, or not after its track's last time, is "
                      "skipped (a stream cannot go back: a clock that restarts skips every later row of the track); "
                      "the output has a row per row kept; TrackPredictor.skipped counts skipped rows; this is said "
                      "once", SkippedRowWarning, stacklevel=3)

    def _front_door(self, table, position_names):
        """``(table, positions, columns)``: a table as :meth:`_process_table` takes it (``track_id``, ``time`` in
        seconds, the positions) and the :class:`kalmix.io.TrackColumns` found (None for a table already in that
        form)."""
        import pandas as pd

        from ..io.columns import detect_columns
        from ..io.values import to_float

        given = list(position_names) if position_names else None
        if "track_id" in table.columns and "time" in table.columns:
            if given is not None:
                return table, given, None
            if self.position_names is not None and all(name in table.columns for name in self.position_names):
                return table, list(self.position_names), None
            others = [c for c in table.columns if c not in ("track_id", "time")]
            try:
                return table, list(detect_columns([str(c) for c in others]).positions), None
            except ValueError:
                return table, others, None
        if not all(isinstance(c, str) for c in table.columns):
            raise ValueError(f"table: expected column names (text) to detect the id, time and position columns in, "
                             f"got {list(table.columns)[:8]}; or name them track_id and time")
        if given is None and self.position_names is not None and all(n in table.columns for n in self.position_names):
            given = list(self.position_names)
        columns, notes = find_columns(list(table.columns), positions=given,
                                      sample=lambda names, rows: table[list(names)].head(rows))
        for note in notes:
            warnings.warn(note, ColumnNoteWarning, stacklevel=4)
        n = len(table)
        if columns.track_id is None:
            ids = np.zeros(n, dtype=np.int64)
        else:
            ids = table[columns.track_id].to_numpy()
        if columns.time is None:   # each track's rows in order: 0, 1, 2, ... continuing the rows seen before
            codes, uniques = factorize_ids(ids)
            count = pd.Series(codes).groupby(codes).cumcount().to_numpy(np.float64)
            start = np.array([self.gaps[key].last_time + 1 if key in self.gaps and self.gaps[key].last_time
                              is not None else 0.0 for key in (id_to_json(u) for u in uniques)])
            times = count + (start[codes] if len(start) else 0.0)
        else:
            times = to_float(table[columns.time].reset_index(drop=True), columns.time, 0, dates=True)
        canonical = pd.DataFrame({"track_id": ids, "time": times,
                                  **{name: table[name].to_numpy() for name in columns.positions}})
        return canonical, list(columns.positions), columns

    def _process_table(self, table, position_names, next_times, first_row=0, kept=None):
        """``first_row``: the table's first row in the caller's table (the rows that errors name); ``kept``: a list
        that receives the caller's rows that were stepped (arrays, in order)."""
        import pandas as pd

        if not pd.api.types.is_numeric_dtype(table["time"]):   # dates and durations: seconds, as files are read
            table = table.assign(time=column_seconds(table["time"]))

        # the rows before each summary of the population prior (.population), then the summary
        cuts = self.summary_cuts(table["track_id"].to_numpy(), table["time"].to_numpy(np.float64))
        if cuts:   # (found once: each part ends at a summary point, so none is cut again)
            bounds = [0, *cuts, len(table)]
            parts = [table.iloc[a:b] for a, b in zip(bounds, bounds[1:])]
            return pd.concat([self._process_table(part, position_names, later, first_row + a, kept)
                              for part, later, a in zip(parts, next_row_times(parts, next_times), bounds)],
                             ignore_index=True)
        names = list(position_names)   # (process_table gave the default: every other column)
        if self.position_names is None:
            self.position_names = tuple(names)
        elif set(names) == set(self.position_names):
            names = list(self.position_names)   # the coordinates by name, in the order the predictor learned
        else:
            raise ValueError(f"table: expected the position columns {list(self.position_names)} (as before), got "
                             f"{names}")
        self._decide_geographic(names, len(names))
        values = position_values(table, names, first_row)
        if np.isinf(values).any():
            i = int(np.flatnonzero(np.isinf(values).any(axis=-1))[0])
            raise ValueError(f"table: expected finite positions (NaN for a missing measurement), got {values[i]!r} "
                             f"in row {first_row + i} (counted from 0)")
        axes = self.axes
        if axes is not None:
            from ..io.geo import check_degrees, without_not_available

            values = without_not_available(values, axes)   # AIS's latitude 91 / longitude 181: no fix
            check_degrees(values, axes, names, lambda i: f"table: row {first_row + i} (counted from 0)")
        times = table["time"].to_numpy(np.float64)
        ids = table["track_id"].to_numpy()
        self._ensure_params(values.shape[1])
        n_rows, p = values.shape
        before = self.stepped
        self.rows += n_rows

        tracks, runs, segments, gap_rows, keep = self._gap_rule(ids, times, first_row)
        if kept is not None:
            kept.append(first_row + np.flatnonzero(keep))
        restart, origins = gap_rows, None
        if axes is not None:   # each track's rows in its frame: metres east, north (and up)
            values, origins, restart = self._to_frames(tracks, runs, values, segments, gap_rows)

        shape = (n_rows, p)
        out = {"pred": np.full(shape, np.nan), "std": np.full(shape, np.nan)}
        lead = self.params.lead is not None
        if lead:
            out["lead"], out["lead_std"] = np.full(shape, np.nan), np.full(shape, np.nan)
        # the tracks a batch at a time (they are independent: the same bits): the stacked states and the engine's
        # results stay a bounded size however many tracks the table holds
        every_track, every_run = tracks, runs
        for begin in range(0, len(every_track), TRACK_BATCH):
            tracks, runs = every_track[begin:begin + TRACK_BATCH], every_run[begin:begin + TRACK_BATCH]
            new_tracks = [track not in self.states for track in tracks]
            stacked = self._states_or_fresh(tracks)
            where = [(stacked, c) for c in range(len(tracks))]   # each track's state: (a stacked state, its column)
            del stacked   # (``where`` alone holds the states: each run's input is freed as soon as it has run)
            # a track's rows are stepped in pieces that end before a time gap: the forecast across the gap is made
            # by _forecast_far (only the constant-velocity experts extrapolate so far), the rest as in one run
            pieces = [np.split(run, np.flatnonzero(gap_rows[run[1:]]) + 1) for run in runs]
            for wave in range(max(len(piece) for piece in pieces)):
                columns = [c for c in range(len(tracks)) if len(pieces[c]) > wave]
                wave_runs = [pieces[c][wave] for c in columns]
                lengths = np.array([len(run) for run in wave_runs])
                held = [where[c] for c in columns]
                if all(h[0] is held[0][0] for h in held) and [h[1] for h in held] == list(
                        range(len(held[0][0].screen.time))):
                    state = held[0][0]   # every track of one state, in order (the first piece, or the only one)
                else:
                    state = _stack([_take(h[0], slice(h[1], h[1] + 1)) for h in held])
                rows = np.zeros((int(lengths.max()), len(columns)), dtype=np.int64)
                active = np.zeros(rows.shape, dtype=bool)
                for k, run in enumerate(wave_runs):
                    rows[:lengths[k], k] = run
                    active[:lengths[k], k] = True
                dense = np.where(active[..., None], values[rows], np.nan)
                dense_times = np.where(active, times[rows], np.nan)
                result = self._run(dense, dense_times, lengths, state, active & restart[rows])
                self.count_rows([tracks[c] for c in columns], lengths)
                self.outliers += int(result.state.screen.outliers.sum() - state.screen.outliers.sum())
                for k, c in enumerate(columns):
                    where[c] = (result.state, k)
                state = held = None   # (before the forecasts' runs below)
                # a row's next-row forecast is the forecast of the next row, made before it
                inner = active.copy()
                inner[lengths - 1, np.arange(len(columns))] = False
                out["pred"][rows[inner]] = result.forecasts[1:][inner[:-1]]
                out["std"][rows[inner]] = result.std[1:][inner[:-1]]
                # each piece's last row: for the time of its next row (after a gap, a later table), or one
                # reference interval on
                last = rows[lengths - 1, np.arange(len(columns))]
                when = np.array([next_times.get(tracks[c], np.nan) if len(pieces[c]) == wave + 1
                                 else times[pieces[c][wave + 1][0]] for c in columns], dtype=np.float64)
                guess = times[last] + np.array([self._interval(self.gaps[tracks[c]]) for c in columns])
                when = np.where(np.isfinite(when) & (when > times[last]), when, guess)
                out["pred"][last], out["std"][last] = self._forecast_next(result.state, when)
                thresholds = np.array([self.gaps[tracks[c]].threshold(self.config) for c in columns])
                far = np.array([len(pieces[c]) > wave + 1 for c in columns], dtype=bool) | (
                    when - times[last] > thresholds)
                if far.any():   # the next row comes after a gap
                    index = np.flatnonzero(far)
                    out["pred"][last[index]], out["std"][last[index]] = self._forecast_far(
                        _take(result.state, index), when[index], thresholds[index])
                if lead:   # none from a track's first row (a single position)
                    out["lead"][rows[active]] = result.lead[active]
                    out["lead_std"][rows[active]] = result.lead_std[active]
                    if wave == 0:
                        first = rows[0, [k for k, c in enumerate(columns) if new_tracks[c]]]
                        out["lead"][first] = out["lead_std"][first] = np.nan
            by_state: dict = {}   # each track's rows stored with the others' of the same state
            for c, track in enumerate(tracks):
                held, k = where[c]
                by_state.setdefault(id(held), (held, [], []))
                by_state[id(held)][1].append(track)
                by_state[id(held)][2].append(k)
            for held, these, columns in by_state.values():
                self.states.put(these, held, columns)
        self.summarise_if_due(before)
        if origins is not None:   # the forecasts back to degrees, each in the frame of the row it was made after
            from ..io.geo import from_local

            for key in ("pred", "lead"):
                if key in out:
                    out[key] = from_local(out[key], origins, axes, p)
        frame = pd.DataFrame({"track_id": ids[keep], "time": times[keep], "segment": segments[keep]})
        for key, column_names in self.output_columns().items():
            for j, name in enumerate(column_names):
                frame[name] = out[key][keep, j]
        return frame

    def _to_frames(self, tracks, runs, values, segments, gap_rows):
        """Geographic rows in their tracks' frames (:func:`kalmix.io.geo.assign_frames`): the values in metres
        (east, north[, up]), each row's frame origin ``(n, 3)`` (NaN for rows not stepped or before their
        track's first fix), and the rows that restart their track (the gap rule's and those that start a new
        frame; ``segments`` and the trackers count the latter as new segments)."""
        from ..io.geo import REANCHOR_M, assign_frames, chord, origin_of, to_local

        axes = self.axes
        n = len(values)
        origins = np.full((n, 3), np.nan)
        restart = gap_rows.copy()
        lengths = np.array([len(run) for run in runs])
        rows = np.concatenate(runs)
        owner = np.repeat(np.arange(len(tracks)), lengths)
        valid = np.isfinite(values[rows]).all(axis=1)
        known = np.full((len(tracks), 3), np.nan)
        for c, track in enumerate(tracks):
            if self.gaps[track].origin is not None:
                known[c] = self.gaps[track].origin
        # a track without a frame yet: its first fix here (the rows before it have none)
        fresh = np.isnan(known[:, 0])
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        position = np.arange(len(rows)) - starts[owner]
        first = np.full(len(tracks), np.iinfo(np.int64).max)
        if valid.any():
            ids, at = np.unique(owner[valid], return_index=True)
            first[ids] = position[np.flatnonzero(valid)[at]]
        for c in np.flatnonzero(fresh & (first < np.iinfo(np.int64).max)):
            known[c] = origin_of(values[runs[c][first[c]]], axes)
        per_row = np.where((fresh[owner] & (position < first[owner]))[:, None], np.nan, known[owner])
        with np.errstate(invalid="ignore"):
            far = valid & (chord(values[rows], per_row, axes) > REANCHOR_M)
        for c in np.flatnonzero(fresh & (first < np.iinfo(np.int64).max)):
            self.gaps[tracks[c]].origin = tuple(float(v) for v in known[c])
        for c in np.unique(owner[far]):   # a track that goes far from its frame: frame by frame, in order
            gaps = self.gaps[tracks[c]]
            run = runs[c]
            block = slice(starts[c], starts[c] + lengths[c])
            start = None if fresh[c] else gaps.origin
            per_row[block], anchored, gaps.origin = assign_frames(values[run], start, axes)
            for k in np.flatnonzero(anchored & ~restart[run]):   # (a gap's row restarts already)
                restart[run[k]] = True
                segments[run[k:]] += 1
                gaps.segment += 1
        origins[rows] = per_row
        local = np.full((n, axes.dim), np.nan)
        local[rows] = to_local(values[rows], per_row, axes)
        return local, origins, restart
