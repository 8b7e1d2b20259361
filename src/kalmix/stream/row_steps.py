"""Rows one at a time, or the rows that have already arrived, through a
:class:`~kalmix.streaming.TrackPredictor`: :meth:`~RowSteps.step_row` and :meth:`~RowSteps.step_rows`, the same
numbers bit for bit (a stream's answer to each row is made before the next row exists)."""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from .._values import measurements as _measurements
from .gaps import GapTracker, SkippedRowWarning
from .ids import track_key
from .times import row_times


class RowPrediction(NamedTuple):
    """What :meth:`TrackPredictor.step_row` returns for one measurement."""

    track_id: Any
    time: float
    segment: int
    next: np.ndarray              # (p,) prediction one reference interval ahead (the next row)
    #: (p,) prediction ``lead`` (or ``horizon`` time units) ahead (NaN until the track has a forecast), or None
    #: without a lead or horizon
    ahead: np.ndarray | None
    #: (p,) calibrated standard deviations of ``next`` as a forecast of the next *measurement* (its noise
    #: included: an interval for where the next reading falls, wider than one for the true position)
    next_std: np.ndarray | None = None
    ahead_std: np.ndarray | None = None  # (p,) of ``ahead``
    time_glitch: bool = False     # the row came back before its track's jump ahead (that timestamp was wrong)


def _is_pandas(value, *kinds: str) -> bool:
    """Whether ``value`` is a pandas object of one of these class names (without importing pandas)."""
    return type(value).__name__ in kinds and type(value).__module__.startswith("pandas")


class RowSteps:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that steps rows as they arrive."""

    def step_row(self, track_id, time: float, z) -> RowPrediction | None:
        """Learn from one measurement (NaN = missing) and predict; None if the row is skipped (its time at or
        before its track's last time, or NaN or infinite).

        ``z``: the coordinates in the order of :attr:`position_names`, or labelled by them (a pandas
        Series, a dict; a predictor with no names yet takes the first labelled row's labels for them);
        None for a missing row once the predictor knows its number of coordinates.

        All or nothing: the track's tracker and state change only once the step succeeded.
        """
        if isinstance(z, (str, bytes)):   # ("12" would be read as the one coordinate 12)
            raise TypeError(f"z: expected the coordinates (numbers, NaN for a missing one), got the text {z!r:.80}")
        z, names = self._by_name(z, "z", self.position_names, self._may_adopt())
        if z is None:   # the whole row missing: as many NaN as the predictor has coordinates
            if self.params is None:
                raise ValueError("z: None (a missing row) needs the number of coordinates, which the predictor "
                                 "learns from its first row; give NaN for each coordinate")
            z = [np.nan] * self.params.measurement_dim
        try:
            given = _measurements(z)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"z: expected numbers (NaN for a missing measurement), got {z!r:.80}") from None
        if given.ndim > 1 and given.shape[:-1] != (1,) * (given.ndim - 1):
            raise ValueError(f"z: expected one row of coordinates, shape (p,), got shape {given.shape}")
        z = given.reshape(-1)
        if np.isinf(z).any():
            raise ValueError(f"z: expected finite numbers (NaN for a missing measurement), got {z!r:.80}")
        asked = time
        try:
            time = float(row_times([time])[0])
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"time: expected a number, a date and time (datetime, ISO text) or a duration, "
                             f"got {time!r:.80}") from None
        out = self._step_checked([track_key(track_id, "track_id")], np.array([time]), z[None, :], names,
                                 lambda i: "z")[0]
        self._committed(names, [asked])
        return out

    def _may_adopt(self) -> bool:
        """Whether a labelled row may give the predictor its :attr:`position_names`: none yet, and no row taken
        by position before (a row labelled y, x after rows of x, y would swap them)."""
        return self.position_names is None and self.rows == 0 and not self.states

    def _by_name(self, values, where: str, names=None, adopt: bool = False):
        """Labelled coordinates (a pandas Series or a mapping for one row, a DataFrame's columns for rows) in the
        order of ``names`` (:attr:`position_names`), as :meth:`process_table` takes a table's columns by name
        (not in their own order, which would silently swap coordinates). With no names yet and
        ``adopt``, a row's text labels become them (as a table's columns do). Returns the values (unlabelled
        ones as given; a mapping's values as a list) and the names."""
        if isinstance(values, Mapping):
            labels = list(values.keys())
        elif _is_pandas(values, "Series", "DataFrame"):
            labels = list(values.index if _is_pandas(values, "Series") else values.columns)
            if all(isinstance(label, (int, np.integer)) for label in labels):   # positions, not names
                return values, names
        else:
            return values, names
        if names is None:
            if not adopt:
                raise ValueError(f"{where}: coordinates by name ({labels}) need the predictor's position_names: "
                                 "rows were already taken by position (label every row from the first, or give "
                                 "position_names)")
            if not all(isinstance(label, str) for label in labels) or len(set(labels)) != len(labels):
                raise ValueError(f"{where}: coordinates by name need distinct text labels, or the predictor's "
                                 f"position_names, got {labels}")
            names = tuple(labels)
        if set(labels) != set(names) or len(labels) != len(names):
            raise ValueError(f"{where}: expected the coordinates {list(names)} (position_names), got {labels}")
        if isinstance(values, Mapping):
            return [values[name] for name in names], names
        return (values[list(names)] if _is_pandas(values, "Series") else values.loc[:, list(names)]), names

    def _rows_by_name(self, values, names):
        """:meth:`step_rows`' values by name: a DataFrame's columns, a mapping of columns, or a list of rows some
        of which are labelled (Series, mappings)."""
        adopt = self._may_adopt()
        if isinstance(values, Mapping):   # columns, as a DataFrame's
            columns, names = self._by_name(values, "values", names, adopt)
            try:
                columns = [_measurements(column) for column in columns]
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"values: expected a column of numbers per coordinate, got {values!r:.80}") from None
            if any(column.ndim != 1 for column in columns) or len({len(column) for column in columns}) > 1:
                raise ValueError(f"values: expected columns of one length (one value per row), got shapes "
                                 f"{[column.shape for column in columns]}")
            return np.column_stack(columns), names
        labelled = [isinstance(row, Mapping) or _is_pandas(row, "Series") for row in values] \
            if isinstance(values, (list, tuple)) else []
        if not any(labelled):
            return self._by_name(values, "values", names, adopt)
        if names is None and not all(labelled):
            raise ValueError("values: rows labelled by name (Series, dicts) among rows by position need the "
                             "predictor's position_names")
        rows = []
        for i, row in enumerate(values):
            row, names = self._by_name(row, f"values[{i}]", names, adopt)
            rows.append(row.tolist() if _is_pandas(row, "Series") else row)
        return rows, names

    def _committed(self, names, given) -> None:
        """After a step that succeeded: the names it took its rows by, and the warning of a row it skipped (its
        time as ``given``, the call's times, and in seconds where that is not a number)."""
        self.position_names = names
        late, self._late = self._late, None
        if late is not None and self.warn_skipped:
            self.warn_skipped = False
            track, index, seconds, last = late
            shown = np.asarray(given, dtype=object).reshape(-1)[index]
            if last is None:   # a time that is None or NaN
                warnings.warn(f"track {track!r}: a row without a time ({shown!r}) was skipped (nothing to place it "
                              "by); TrackPredictor.skipped counts skipped rows; this is said once",
                              SkippedRowWarning, stacklevel=3)
                return
            if isinstance(shown, numbers.Real) and not isinstance(shown, bool):
                said = f"time {seconds!r} is not after the track's last time {last!r}"
            else:
                said = f"time {shown!r} ({seconds!r} s) is not after the track's last time ({last!r} s)"
            warnings.warn(f"track {track!r}: {said}, so the "
                          "row was skipped (a stream cannot go back: a clock that restarts skips every later row of "
                          "the track); TrackPredictor.skipped counts skipped rows; this is said once",
                          SkippedRowWarning, stacklevel=3)

    def step_rows(self, track_ids, times, values) -> list[RowPrediction | None]:
        """Rows that have already arrived, as :meth:`step_row` on each in turn, through one run of the core.

        The same results bit for bit as row by row: each row's prediction is made after that
        row and before the next (for one reference interval on, as :meth:`step_row`), never
        from a later row; only the work is shared (the rows of a frame of many tracks in one
        call, a track's rows in one pass). All or nothing: an exception leaves the predictor
        as it was. Rows before the time unit is known go row by row.

        Parameters
        ----------
        track_ids : sequence
            One hashable id per row.
        times : array_like ``(n,)``
        values : array_like ``(n, p)``
            Measurements (NaN = missing); or labelled by :attr:`position_names`: a DataFrame with
            those columns, or a list of rows some of which are Series or dicts (as in :meth:`step_row`).

        Returns
        -------
        list
            Per row, its :class:`RowPrediction`, or None for a skipped row (at or before its
            track's last time).
        """
        if isinstance(track_ids, (str, bytes)):   # its letters would be taken for the rows' ids
            raise TypeError(f"track_ids: expected a sequence of track ids, one per row, got the text {track_ids!r:.80} "
                            "(one row: step_row)")
        try:
            ids = list(track_ids)
        except TypeError:
            raise TypeError(f"track_ids: expected a sequence of track ids, one per row, got {track_ids!r:.80} "
                            "(one row: step_row)") from None
        if np.ndim(times) > 1:
            raise ValueError(f"times: expected one time per row, a 1-D sequence, got shape {np.shape(times)}")
        try:
            asked, times = times, row_times(times).reshape(-1)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"times: expected numbers, dates and times (datetime, ISO text) or durations, "
                             f"got {times!r:.80}") from None
        if isinstance(values, (str, bytes)):
            raise TypeError(f"values: expected a (n, p) array of coordinates, got the text {values!r:.80}")
        values, names = self._rows_by_name(values, self.position_names)
        try:
            values = _measurements(values, None if self.params is None else self.params.measurement_dim)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"values: expected numbers (NaN for a missing measurement), got {values!r:.80}") from None
        if values.ndim != 2 or len(values) != len(ids) or len(times) != len(ids):
            raise ValueError(f"step_rows: expected {len(ids)} times and a ({len(ids)}, p) array of values (one row "
                             f"per track id), got {len(times)} times and values of shape {values.shape}")
        if np.isinf(values).any():
            i = int(np.flatnonzero(np.isinf(values).any(axis=-1))[0])
            raise ValueError(f"values[{i}]: expected finite numbers (NaN for a missing measurement), got {values[i]!r}")
        out = self._step_checked([track_key(track, f"track_ids[{i}]") for i, track in enumerate(ids)], times, values,
                                 names, lambda i: f"values[{i}]")
        self._committed(names, asked)
        return out

    def _step_checked(self, ids, times, values, names=None, where=None) -> list[RowPrediction | None]:
        """:meth:`step_rows` on arguments already checked: all or nothing, row by row until the time unit is known.
        ``names``: the position names the rows come by (adopted when the predictor has none); ``where(i)``: how
        an error names row ``i``."""
        self._late = None
        if not ids:
            return []
        saved = self.checkpoint(list(dict.fromkeys(ids)))
        try:
            out = []
            start = 0
            self._decide_geographic(names if names is not None else self.position_names, values.shape[1])
            if self.axes is not None:
                from ..io.geo import check_degrees, without_not_available

                values = without_not_available(values, self.axes)   # AIS's latitude 91 / longitude 181: no fix
                check_degrees(values, self.axes, names if names is not None else self.position_names,
                              where or (lambda i: f"values[{i}]"))
            self._resolve_length_unit(None, None, "a stream's first row")
            self.settle_reach(None)   # (no table of steps to judge the sampling by)
            self.settle_gap_floor(None)
            self._ensure_params(values.shape[1])
            while start < len(ids) and self.config.time_unit is None:   # one row at a time until it is known
                out.extend(self._step_batch(ids[start:start + 1], times[start:start + 1], values[start:start + 1],
                                            start))
                start += 1
            if start < len(ids):
                out.extend(self._step_batch(ids[start:], times[start:], values[start:], start))
            return out
        except BaseException:
            self.rollback(saved)
            raise

    def _step_batch(self, ids, times, values, first: int = 0) -> list[RowPrediction | None]:
        """:meth:`step_rows` (and :meth:`step_row`, one row): the gap rule row by row, then one run of the core with
        every row's forecast one reference interval on (its ``ahead``: the same computation as
        :meth:`_forecast_next` from the state after the row). A bank with a lead takes its ``ahead`` for
        the lead, so there the forecasts one interval on come from a second run over the same rows of
        the bank without its lead head, which nothing else reads (the families, rule, screen and
        calibration learn the same bits). Until the time unit is known, rows come one at a time: a row
        that fixes it runs with the bank it fixes, as the rows after it. Changes the predictor only at
        the end (but for that unit). A summary of the population prior due inside the rows splits them there
        (:mod:`.population`: the rows before it are stepped, then summarised)."""
        n_rows, p = values.shape
        cuts = self.summary_cuts(ids, times)
        if cuts:   # (found once: each part ends at a summary point, so none is cut again)
            out = []
            for a, b in zip([0, *cuts], [*cuts, n_rows]):
                out.extend(self._step_batch(ids[a:b], times[a:b], values[a:b], first + a))
            return out
        trackers: dict = {}
        runs: dict = {}          # track -> [(row, restart, next time)]
        outcome = [None] * n_rows
        for i in range(n_rows):
            track = ids[i]
            gaps = trackers.get(track)
            if gaps is None:
                known = self.gaps.get(track)
                gaps = trackers[track] = GapTracker() if known is None else known.copy()
            glitches, last = gaps.glitches, gaps.last_time
            new = gaps.advance(float(times[i]), self.config)
            if new is None:
                if self._late is None and last is not None and math.isfinite(times[i]):
                    self._late = (track, first + i, float(times[i]), last)   # said once the step succeeded
                elif self._late is None and not math.isfinite(times[i]):
                    self._late = (track, first + i, float(times[i]), None)   # no time
                continue
            if self.config.time_unit is None and gaps.intervals:
                self._learn_time_unit(gaps.intervals[0], track)
            self._unit_step_taken_back(track, gaps)
            run = runs.setdefault(track, [])
            fresh = not run and track not in self.states
            run.append((i, bool(new) and not fresh, float(times[i]) + self._interval(gaps)))
            outcome[i] = (gaps.segment, gaps.glitches > glitches)
        results: list[RowPrediction | None] = [None] * n_rows
        tracks = list(runs)
        origins = None
        if self.axes is not None and tracks:   # each row in its track's frame (kalmix.io.geo), metres
            from ..io.geo import assign_frames, to_local

            origins = np.full((n_rows, 3), np.nan)
            local = np.full((n_rows, self.axes.dim), np.nan)
            for track in tracks:
                rows = np.array([r for r, _, _ in runs[track]], dtype=np.int64)
                gaps = trackers[track]
                origins[rows], anchored, gaps.origin = assign_frames(values[rows], gaps.origin, self.axes)
                for k in np.flatnonzero(anchored):   # a fix far from its frame: a new segment, in a new frame
                    r, restarts, when = runs[track][k]
                    if restarts:   # (a gap's row restarts already)
                        continue
                    runs[track][k] = (r, True, when)
                    gaps.segment += 1
                    for m in rows[k:]:
                        outcome[m] = (outcome[m][0] + 1, outcome[m][1])
                local[rows] = to_local(values[rows], origins[rows], self.axes)
            values = local
        if tracks:
            lengths = np.array([len(runs[t]) for t in tracks], dtype=np.int64)
            shape = (int(lengths.max()), len(tracks))
            dense = np.full(shape + (p,), np.nan)
            dense_times, ahead_times = np.full(shape, np.nan), np.full(shape, np.nan)
            restart = np.zeros(shape, dtype=bool)
            for c, track in enumerate(tracks):
                rows = np.array([r for r, _, _ in runs[track]], dtype=np.int64)
                dense[:len(rows), c] = values[rows]
                dense_times[:len(rows), c] = times[rows]
                restart[:len(rows), c] = [gap for _, gap, _ in runs[track]]
                ahead_times[:len(rows), c] = [when for _, _, when in runs[track]]
            state = self._states_or_fresh(tracks)
            if self.params.lead is None:
                result = nxt = self._run(dense, dense_times, lengths, state, restart, ahead_times)
            else:
                result = self._run(dense, dense_times, lengths, state, restart)
                nxt = self._run(dense, dense_times, lengths, state._replace(lead=None), restart, ahead_times,
                                bank=self._without_lead())
            nexts = np.full((n_rows, p), np.nan)
            leads = np.full((n_rows, p), np.nan) if result.lead is not None else None
            for c, track in enumerate(tracks):
                for j, (r, _, _) in enumerate(runs[track]):
                    nexts[r] = nxt.ahead[j, c]
                    if leads is not None and not (j == 0 and track not in self.states):
                        leads[r] = result.lead[j, c]   # none from a track's first row (a single position)
            if origins is not None:   # back to degrees, each in the frame of its row
                from ..io.geo import from_local

                nexts = from_local(nexts, origins, self.axes, p)
                leads = None if leads is None else from_local(leads, origins, self.axes, p)
            for c, track in enumerate(tracks):
                for j, (r, _, _) in enumerate(runs[track]):
                    segment, glitch = outcome[r]
                    ahead = ahead_std = None
                    if result.lead is not None:
                        first = j == 0 and track not in self.states
                        ahead = leads[r]
                        ahead_std = np.full(p, np.nan) if first else result.lead_std[j, c]
                    results[r] = RowPrediction(track, float(times[r]), segment, nexts[r], ahead,
                                               nxt.ahead_std[j, c], ahead_std, glitch)
            for track in tracks:
                self.gaps[track] = trackers[track]
            self.states.put(tracks, result.state)
            self.count_rows(tracks, lengths)
            self.outliers += int(result.state.screen.outliers.sum() - state.screen.outliers.sum())
        before = self.stepped
        self.rows += n_rows
        self.skipped += sum(r is None for r in results)
        self.summarise_if_due(before)
        return results
