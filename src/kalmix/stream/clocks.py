"""Every track's clock in a :class:`~kalmix.streaming.TrackPredictor`: the gap rule row by row and over a
table's rows (:class:`~kalmix.stream.gaps.GapTracker`), and the time unit learned from the data: the median step of the
first table with one, or, row by row, the first step."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from .gaps import GapTracker, short_median
from .ids import factorize_ids, id_to_json, keyable
from .times import column_seconds
from .units import gap_floor_for_steps, reach_for_steps

#: Rows of a table the automatic reach is tried on (:meth:`TrackClocks._pilot_reach`).
PILOT_ROWS = 5_000


def _by_key(index, rows, count) -> list[np.ndarray]:
    """``rows`` grouped by their key ``index[rows]`` (``count`` keys), each group in row order."""
    order = rows[np.argsort(index[rows], kind="stable")]
    edges = np.concatenate([[0], np.cumsum(np.bincount(index[rows], minlength=count))])
    return [order[edges[u]:edges[u + 1]] for u in range(count)]


def _is_missing(values) -> np.ndarray:
    """Which of ``values`` are None, NaN, NaT or pandas' NA (no track id)."""
    import pandas as pd

    return np.asarray(pd.isna(np.asarray(values, dtype=object)), dtype=bool)


class TrackClocks:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that keeps its tracks' clocks (``gaps``: track id ->
    :class:`~kalmix.stream.gaps.GapTracker`) and its time unit."""

    def _unit_step_taken_back(self, track, gaps: GapTracker) -> None:
        """Warn once when the step the time unit was learned from (a track's first) is taken back: a row came
        back before it, so that step's timestamp was wrong, and so is the unit (the bank stays as it is)."""
        source = self._unit_source
        if source is not None and source[0] == track and gaps.glitches and (
                not gaps.intervals or gaps.intervals[0] != source[1]):
            self._unit_source = None
            warnings.warn(f"the time unit, {source[1]:.6g} time-column units, was learned from the first step of "
                          f"track {track!r}, which a later row showed to be a wrong timestamp; the kinematic "
                          "experts' noise and the lead's frames scale with it: pass time_unit (--time-unit) to set it",
                          RuntimeWarning, stacklevel=4)

    def _learn_time_unit(self, value: float, track=None, where: str = "the data's first step") -> None:
        """Fix a learned time unit, to 12 significant digits (the bank's parameters scale with it; states do not);
        ``track``: the track whose first step it is (None: a table's median step, see :meth:`learn_time_unit`).

        Only first rows of tracks come before it (a track's second row has a time step), and
        nothing they leave in a state depends on the unit (the lead head keeps no forecast made
        from a first row), so the order in which those first rows come changes nothing.
        """
        if self.config.time_unit is None and math.isfinite(value) and value > 0:
            # to 12 digits: a file's median step and a stream's first step of regular rows agree even where the
            # times' last bits differ (0.04 and 0.039999999999999994)
            step, value = value, float(f"{value:.12g}")
            try:   # the settings with this unit (a lead in time units is bounded), checked before any change
                learned = replace(self.config, time_unit=float(value))
            except ValueError as error:
                raise ValueError(f"the time unit learned from {where}, {value:.6g} time-column units, "
                                 f"does not suit these settings: {error} (pass time_unit, --time-unit on the "
                                 "command line)") from None
            self.config.time_unit = learned.time_unit
            self._unit_source = None if track is None else (track, step)
            if track is not None:   # a stream's first step: no steps to judge the sampling by
                self.settle_reach(None)
                self.settle_gap_floor(None)
            if self.params is not None:
                self.params = self._build(self.params.measurement_dim)

    def settle_gap_floor(self, value: float | None) -> None:
        """Fix ``gap_floor="auto"`` at ``value`` (time-column units, None: none); nothing if it is set already."""
        if self.config.gap_floor == "auto":
            self.config.gap_floor = value

    def settle_reach(self, value: float | None) -> None:
        """Fix ``reach="auto"`` at ``value`` (time units, None: no reach); nothing if it is set already."""
        if self.config.reach == "auto":
            self.config.reach = value
            if self.params is not None:
                self.params = self._build(self.params.measurement_dim)

    def _advance(self, track, time: float) -> tuple[GapTracker, bool | None]:
        """The gap rule for one row of a table (a new track gets a tracker); learns the time unit."""
        gaps = self.gaps.get(track)
        if gaps is None:
            gaps = self.gaps[track] = GapTracker()
        new = gaps.advance(time, self.config)
        if self.config.time_unit is None and gaps.intervals:
            self._learn_time_unit(gaps.intervals[0], track)
        self._unit_step_taken_back(track, gaps)
        return gaps, new

    def _interval(self, gaps: "GapTracker") -> float:
        """A track's reference interval (median of its first steps), else the time unit, else 1."""
        if gaps.intervals:
            return short_median(gaps.intervals)
        return self.config.time_unit or 1.0

    @property
    def track_ids(self) -> list:
        return list(self.gaps)

    @property
    def time_glitches(self) -> int:
        """Rows that came back before a jump ahead in time (see the module docstring)."""
        return sum(g.glitches for g in self.gaps.values())

    def stepped_rows(self, ids, times) -> np.ndarray:
        """``(n,)`` bool: which of these rows, in this order and continuing the tracks seen, the gap rule would
        step rather than skip (a time not after its track's last, or not finite). Nothing is changed."""
        times = np.asarray(times, dtype=np.float64)
        if not isinstance(ids, np.ndarray):   # (a stream's keys)
            ids, given = np.empty(len(ids), dtype=object), ids
            ids[:] = given
        index, uniques = factorize_ids(ids)
        keep = np.ones(len(times), dtype=bool)
        for u, rows in enumerate(_by_key(index, np.arange(len(times)), len(uniques))):
            known = self.gaps.get(id_to_json(uniques[u]))
            gaps = GapTracker() if known is None else known.copy()
            keep[rows] = gaps.advance_many(times[rows], self.config)[0] >= 0
        return keep

    def table_steps(self, ids, times) -> np.ndarray:
        """The positive time steps between consecutive rows of each track among these rows (in this order, going
        on from the tracks' last times seen); nothing is changed."""
        times = np.asarray(times, dtype=np.float64)
        index, uniques = factorize_ids(np.asarray(ids, dtype=object) if not isinstance(ids, np.ndarray) else ids)
        steps = []
        for u, rows in enumerate(_by_key(index, np.arange(len(times)), len(uniques))):
            known = self.gaps.get(id_to_json(uniques[u]))
            last = None if known is None else known.last_time
            t = times[rows] if last is None else np.concatenate([[last], times[rows]])
            step = np.diff(t[np.isfinite(t)])
            steps.append(step[step > 0])
        return np.concatenate(steps) if steps else np.zeros(0)

    def learn_time_unit(self, table, names=None) -> float | None:
        """Fix the time unit, if it is not known yet, from a table's rows without stepping them: the median of the
        positive time steps between consecutive rows of each of its tracks (going on from the rows seen
        before); returns the time unit (None: still unknown, the table has no such step).

        A ``reach="auto"`` and a ``gap_floor="auto"`` are settled from the same steps, the given unit
        or not (:func:`~kalmix.stream.units.reach_for_steps`, :func:`~kalmix.stream.units.gap_floor_for_steps`:
        on heavy-tailed steps 1.5 time units, and 3 times their 90th percentile; else None). :meth:`process_table`
        calls it on each table it gets while either is unknown (the first table with a step fixes
        them), and ``kalmix predict`` on each chunk of a file, before any of its rows is stepped, so
        that every row runs with the same bank. Rows stepped one by one
        (:meth:`step_row`, :meth:`step_rows`, ``kalmix predict -``) have no table to look at: the
        first step to arrive fixes the unit there, so a stream and a file of the same rows give the
        same numbers when the unit is given (``time_unit``, ``--time-unit``), or when the first
        step is the median one (regular sampling).

        Parameters
        ----------
        table : pandas.DataFrame
            ``track_id`` and ``time`` columns, each track's rows in time order (later rows continue
            the tracks this predictor has seen), and the positions.
        names : sequence of str, optional
            The position columns (default: every other column).
        """
        if self.config.time_unit is None or "auto" in (self.config.reach, self.config.gap_floor):
            steps = self.table_steps(table["track_id"].to_numpy(), column_seconds(table["time"]))
            if steps.size:
                self.settle_gap_floor(gap_floor_for_steps(steps, self.config.max_gap_factor))
                self._learn_time_unit(float(np.median(steps)), where="the median time step of the table")
                if self.config.reach == "auto":
                    reach = reach_for_steps(steps)
                    self.settle_reach(None if reach is None else self._pilot_reach(table, names, reach))
        return self.config.time_unit

    def _pilot_reach(self, table, names, reach: float) -> float | None:
        """``reach`` or None, whichever predicts the first :data:`PILOT_ROWS` rows of ``table`` better (one-step
        RMS of each row's forecast of its track's next row there), by two throwaway predictors with this one's
        settings: on heavy-tailed steps keeping only the constant-velocity experts across the long steps is right
        for a vessel's drifting course and wrong for an accelerating target, which the data tell."""
        import pandas as pd

        from ..io.columns import output_name

        names = list(names) if names is not None else [c for c in table.columns if c not in ("track_id", "time")]
        sample = table[["track_id", "time", *names]].iloc[:PILOT_ROWS].reset_index(drop=True)
        sample = sample.assign(time=column_seconds(sample["time"]))   # (the pilot's output times are seconds)
        numbers = sample[names].apply(pd.to_numeric, errors="coerce")   # (bad values: the pilot's run names them)
        later = numbers.groupby(sample["track_id"], sort=False).shift(-1).to_numpy(np.float64)
        scores = []
        for candidate in (reach, None):
            pilot = type(self)(replace(self.config, reach=candidate), backend=self.backend)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out = pilot.process_table(sample, names)
            columns = [f"pred_{output_name(name)}" for name in names]
            if len(out) == len(sample):
                pred = out[columns].to_numpy(np.float64)
            else:   # (rows skipped for their time: each sample row's forecast by its track and time, if any)
                kept = out.drop_duplicates(["track_id", "time"], keep="last")[["track_id", "time", *columns]]
                pred = sample[["track_id", "time"]].merge(kept, how="left", on=["track_id", "time"])[columns]
                pred = pred.to_numpy(np.float64)
            error = (pred - later)[np.isfinite(pred - later).all(axis=1)]
            scores.append(float(np.sqrt(np.mean(error ** 2))) if len(error) else np.inf)
        return reach if scores[0] < scores[1] else None

    def _gap_rule(self, ids, times, first_row=0):
        """The gap rule over a table's rows, in row order as :meth:`_advance` row by row.

        Returns the tracks with kept rows (in the order of their first kept row), each one's
        kept rows, every row's segment, which rows start a new segment of a track already
        running (a restart), and which rows are kept (not out of order).
        """
        n_rows = len(ids)
        codes = np.empty(n_rows, dtype=np.int8)
        segments = np.zeros(n_rows, dtype=np.int64)
        index, uniques = factorize_ids(ids)
        missing = np.flatnonzero(_is_missing(uniques))
        if len(missing):
            row = int(np.flatnonzero(index == missing[0])[0])
            raise ValueError(f"table: expected a track id in every row, got a missing value "
                             f"({uniques[missing[0]]!r}) in row {first_row + row} (counted from 0)")
        keys = [id_to_json(u) for u in uniques]
        for u, key in enumerate(keys):   # a tuple, say: step_row refuses it, and the state file could not give it back
            if not keyable(key):
                row = int(np.flatnonzero(index == u)[0])
                raise TypeError(f"table: expected a track id (text, a number, or a date) in every row, got "
                                f"{type(uniques[u]).__name__} {uniques[u]!r:.80} in row {first_row + row} (counted "
                                "from 0)")
        had_state = np.array([key in self.states for key in keys], dtype=bool)
        start = 0
        while start < n_rows and self.config.time_unit is None:   # until a step fixes the time unit
            gaps, new = self._advance(keys[index[start]], float(times[start]))
            codes[start], segments[start] = -1 if new is None else int(new), gaps.segment
            start += 1
        # then track by track (tracks are independent once the unit is known)
        for key, rows in zip(keys, _by_key(index, np.arange(start, n_rows), len(keys))):
            if len(rows):
                gaps = self.gaps.get(key)
                if gaps is None:
                    gaps = self.gaps[key] = GapTracker()
                codes[rows], segments[rows] = gaps.advance_many(times[rows], self.config)
                self._unit_step_taken_back(key, gaps)
        keep = codes >= 0
        self.skipped += int(n_rows - keep.sum())
        runs = _by_key(index, np.flatnonzero(keep), len(keys))
        present = sorted((u for u in range(len(keys)) if len(runs[u])), key=lambda u: runs[u][0])
        first_kept = np.array([runs[u][0] for u in present], dtype=np.int64)
        gap_rows = codes == 1
        gap_rows[first_kept] &= had_state[index[first_kept]]
        return [keys[u] for u in present], [runs[u] for u in present], segments, gap_rows, keep
