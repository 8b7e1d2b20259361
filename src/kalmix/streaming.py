"""Many tracks, one mixture predictor each: the engine behind ``kalmix predict``.

Two ways in, the same numbers out:

- :meth:`TrackPredictor.step_row` takes one measurement of one track at a time (the
  stdin streaming mode: a prediction is returned as soon as its measurement arrives);
  :meth:`TrackPredictor.step_rows` takes the rows that have already arrived (of any tracks)
  with the same results bit for bit, through one run of the core;
- :meth:`TrackPredictor.process_table` takes a track table (or one chunk of a big
  file) and steps every track segment present in it at once through the batched core.

Each track segment is an independent stream: batching only changes how the arithmetic
is grouped, and the two paths agree to rounding (tested to 1e-9).

Time gaps
---------
The CV/CA experts run in real time (they predict across any time step); the paper's
AKFs are frame-based (consecutive rows of a track are consecutive frames whatever their
time stamps; a missing frame should be a row with NaN positions). A time step larger
than the *gap threshold* starts a new **segment**: the track's experts start again from
the row after the gap (a halftime, a lost GPS fix, a camera cut: the motion before it
says little about the motion after it), while the aggregation rule and the calibration
keep what they learned on the track (a warm start, :func:`kalmix.core.engine.run`'s
``restart``). The threshold is ``max_gap`` (in the time column's units)
when given, else ``max_gap_factor`` (3) times the track's *reference interval*: the
upper quartile (the 13th in increasing order of 16) of the first (up to 16) positive time
steps of the track (a gap among them too, so that one short first step cannot make every
later step a gap); once it has 16, a gap's step does not change it. On regular sampling it
is the step; on irregular sampling (steps of 5 to 60 s) it is near the long steps, so the
sampling itself is not taken for gaps and the track stays one segment (a median of the 16
steps put some tracks' thresholds below their longest steps and restarted them dozens of
times), while an outage many times the longest usual step still starts a new segment.
The rule is causal (it only looks at rows already seen), so a row-by-row stream and a
whole file give the same segments, and it survives a ``--state`` save and resume.

What is predicted
-----------------
After each row, ``pred_<pos>`` is the forecast for the time of the track's **next row**
and ``std_<pos>`` its calibrated standard deviation (:mod:`kalmix.core.calibration`):
in a table, the next row's time is known (:meth:`TrackPredictor.process_table` takes the
times of the rows that follow the table, ``next_times``); for a track's last row, and
always in :meth:`TrackPredictor.step_row` (which must answer before the next row exists),
it is the time one reference interval later. With a ``lead`` L, ``lead_<pos>`` /
``lead_std_<pos>`` forecast ``time + L`` with weights and intervals learned on lead-L
errors (:mod:`kalmix.core.lead`); a ``horizon`` H > 1 is the lead of H time units
(columns ``pred<H>_<pos>`` / ``std<H>_<pos>``).

A row whose time is not after its track's previous time (out of order or a repeated
timestamp) cannot be undone in a stream: it is skipped and counted in
:attr:`TrackPredictor.skipped`; the first one that :meth:`~TrackPredictor.step_row` or
:meth:`~TrackPredictor.step_rows` skips gives a :class:`SkippedRowWarning` (a sensor clock
that restarts would otherwise skip every later row of its track in silence). (File inputs
are sorted and de-duplicated when read, see :mod:`kalmix.io.tables`.)

One exception keeps a single wrong timestamp from costing the rest of a track: when a
track's previous row *jumped ahead* (a gap, or the track's first row) and the next row
comes back to a time between the time before the jump and the jump, the jump was a wrong
timestamp (a clock glitch, a typo in a feed). The track's first step has no reference
interval to be judged by, so it counts as such a jump only when it is more than
``max_gap_factor`` times the step the next row implies (``0, 1e9, 1``: yes, and its
interval is taken back out of the reference; ``0, 1, 0.5``: no, 0.5 is skipped). The track's
clock goes back to the new row, which continues the jump's segment (no row is skipped),
and the event is counted in :attr:`GapTracker.glitches` (:attr:`TrackPredictor.time_glitches`).
Without this, every later row of the track would be "before its previous time" and skipped.

Transactions
------------
:meth:`~TrackPredictor.step_row` and :meth:`~TrackPredictor.process_table` change the
predictor only when they return: an exception (``KeyboardInterrupt`` included) in the
middle leaves every track, counter and gap tracker as it was.
:meth:`~TrackPredictor.checkpoint` / :meth:`~TrackPredictor.rollback` extend that over
several calls (``kalmix predict`` rolls a whole chunk back when interrupted).
"""

from __future__ import annotations

import datetime
import math
import numbers
import os
import warnings
from collections.abc import Mapping
from dataclasses import asdict, replace
from typing import Any, NamedTuple

import numpy as np

from ._values import measurements as _measurements
from .archive import open_archive, write_archive
from .bank import LENGTH_UNIT_RANGE, make_bank
from .core.engine import Bank, BankState, init_bank_state, tree_leaves, tree_map
from .stream.columns import ColumnNoteWarning, find_columns, guess_id
from .stream.config import GAP_REFERENCES, StreamConfig
from .stream.gaps import REFERENCE_INTERVALS as REFERENCE_INTERVALS
from .stream.gaps import GapTracker, SkippedRowWarning, short_median
from .stream.ids import id_from_meta, id_to_json, id_to_meta, keyable, track_key
from .stream.store import TrackStates
from .stream.units import (LengthUnitWarning, auto_length_unit, auto_time_unit, estimate_length_unit,
                           length_unit_fallback, length_unit_rule)

__all__ = ["StreamConfig", "TrackPredictor", "RowPrediction", "GapTracker", "SkippedRowWarning", "Checkpoint",
           "LengthUnitWarning", "ColumnNoteWarning", "estimate_length_unit", "length_unit_fallback", "find_columns",
           "guess_id", "auto_length_unit", "length_unit_rule", "auto_time_unit", "learned_time_unit", "next_row_times",
           "id_to_json", "with_input_names", "STATE_FORMAT_VERSION", "GAP_REFERENCES"]

#: Format version of the state files :meth:`TrackPredictor.save` writes. :meth:`TrackPredictor.load` reads
#: versions 3 to 12 and resumes each with the settings it was written with (CHANGELOG.md, "State file format
#: versions", says what each version adds).
STATE_FORMAT_VERSION = 12
_READABLE_VERSIONS = (3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
_MAGIC = "kalmix-track-predictor"


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


def _stack(states: list) -> BankState:
    return tree_map(lambda *arrays: np.concatenate(arrays, axis=0), *states)


def _take(state, index):
    return tree_map(lambda a: a[index], state)


def _by_key(index, rows, count) -> list[np.ndarray]:
    """``rows`` grouped by their key ``index[rows]`` (``count`` keys), each group in row order."""
    order = rows[np.argsort(index[rows], kind="stable")]
    edges = np.concatenate([[0], np.cumsum(np.bincount(index[rows], minlength=count))])
    return [order[edges[u]:edges[u + 1]] for u in range(count)]


def _factorize(values) -> tuple[np.ndarray, np.ndarray]:
    """Codes (in order of first appearance) and the distinct values of ``values``."""
    import pandas as pd

    codes, uniques = pd.factorize(values, use_na_sentinel=False)
    return np.asarray(codes, dtype=np.int64), np.asarray(uniques, dtype=object)


def _is_pandas(value, *kinds: str) -> bool:
    """Whether ``value`` is a pandas object of one of these class names (without importing pandas)."""
    return type(value).__name__ in kinds and type(value).__module__.startswith("pandas")


def _is_missing(values) -> np.ndarray:
    """Which of ``values`` are None, NaN, NaT or pandas' NA (no track id)."""
    import pandas as pd

    return np.asarray(pd.isna(np.asarray(values, dtype=object)), dtype=bool)


def _seconds(column) -> np.ndarray:
    """A table's time column as float seconds: datetimes since 1970 UTC, durations in seconds (as
    :func:`kalmix.io.read_tracks` reads them), numbers as they are."""
    import pandas as pd

    if pd.api.types.is_datetime64_any_dtype(column) or pd.api.types.is_timedelta64_dtype(column):
        from .io.tables import to_float

        return to_float(column.reset_index(drop=True), "time", 0)
    return column.to_numpy(np.float64)


def _row_times(times) -> np.ndarray:
    """``step_row`` / ``step_rows`` times as float seconds: numpy or pandas dates since 1970 UTC and durations in
    seconds, as :meth:`TrackPredictor.process_table` and files take them; numbers as they are. ``TypeError`` /
    ``ValueError`` for anything else."""

    import pandas as pd

    if isinstance(times, np.ma.MaskedArray):   # a masked time is missing: the row is skipped, as a NaN time
        times = np.ma.asarray(times, dtype=np.float64).filled(np.nan)
    given = np.asarray(times)
    if given.dtype.kind in "bc" or (isinstance(times, (list, tuple)) and any(isinstance(t, (bool, np.bool_))
                                                                             for t in times)):
        raise TypeError(f"expected numbers or dates, got {times!r:.80}")   # True read as 1.0, 1+1j as 1.0
    if given.dtype.kind in "US" or (given.dtype.kind == "O" and given.size and all(isinstance(t, str)
                                                                                    for t in given.flat)):
        flat = given.reshape(-1).astype(object)
        blank = np.array([not t.strip() for t in flat], dtype=bool)   # an empty time is missing, as in a file
        try:   # text: numbers, or ISO 8601 dates as a file and stdin take them
            return np.where(blank, "nan", flat).astype(np.float64).reshape(given.shape)
        except ValueError:
            from .io.tables import iso_seconds

            return iso_seconds(np.where(blank, None, flat)).reshape(given.shape)
    if given.dtype.kind == "O" and given.size and all(
            isinstance(t, (datetime.datetime, datetime.timedelta, np.datetime64, np.timedelta64)) for t in given.flat):
        given = pd.Series(given.reshape(-1)).infer_objects()
        if not (pd.api.types.is_datetime64_any_dtype(given) or pd.api.types.is_timedelta64_dtype(given)):
            given = pd.to_datetime(given, utc=True)   # dates of several time zones: instants in UTC
        return _seconds(given)
    if given.dtype.kind in "Mm":
        return _seconds(pd.Series(given.reshape(-1)))
    return given.astype(np.float64)


BACKENDS = ("cpu", "gpu")


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and can run here; ``ValueError`` naming it otherwise."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    if backend == "gpu":
        try:
            from .core.compiled import gpu
        except ImportError as error:   # pragma: no cover - numba missing
            raise ValueError(f"backend 'gpu': needs numba and numba-cuda (pip install 'kalmix[gpu]'): {error}") \
                from None
        if gpu.cuda is None:
            raise ValueError("backend 'gpu': numba-cuda is not installed (pip install 'kalmix[gpu]')")
        if not gpu.gpu_available():
            raise ValueError("backend 'gpu': no CUDA GPU found (numba-cuda sees none); use backend 'cpu'")
    return backend


#: Most tracks :meth:`TrackPredictor.process_table` steps in one run of the engine: their states are stacked for
#: the run (~50 kB a track for the default bank) and the run returns as many, so a table of many tracks goes a
#: batch at a time (the same bits), in bounded memory.
TRACK_BATCH = 2048


class TrackPredictor:
    """One mixture predictor per track id; tracks appear as they come.

    Parameters
    ----------
    config : StreamConfig
    position_names : sequence of str, optional
        Names of the measured coordinates (kept in the state file).
    backend : {"cpu", "gpu"}
        Where the engine runs: the compiled CPU engine (the numpy reference without numba), or
        the GPU engine (:mod:`kalmix.core.compiled.gpu`; the ``gpu`` extra and an NVIDIA GPU),
        the same numbers. Not kept in the state file: a state saved on one resumes on the other.

    Attributes
    ----------
    skipped : int
        Rows skipped because their time was not after their track's previous time.
    warn_skipped : bool
        Whether the next row that :meth:`step_row` / :meth:`step_rows` skips for its time gives a
        :class:`SkippedRowWarning` (once: then False).
    rows : int
        Rows processed (including skipped ones), counted over saves and resumes.
    output : dict or None
        What the program that saved the state wrote with it (``kalmix predict`` records its
        ``-o`` file there); kept as is by :meth:`save` / :meth:`load`.
    """

    def __init__(self, config: StreamConfig, position_names=None, *, backend: str = "cpu"):
        import copy

        if not isinstance(config, StreamConfig):
            raise TypeError(f"config: expected a StreamConfig, got {type(config).__name__} {config!r:.80}")
        self.backend = check_backend(backend)
        self.config = copy.deepcopy(config)   # the predictor learns its time unit into it: not the caller's
        if isinstance(position_names, str):
            position_names = (position_names,)
        self.position_names = None if position_names is None else tuple(position_names)
        if self.position_names is not None and len(set(self.position_names)) != len(self.position_names):
            raise ValueError(f"position_names: expected distinct names, got {list(self.position_names)}")
        self.params: Bank | None = None
        #: track id -> its engine state (a mapping of one-target BankStates, kept in shared blocks)
        self.states = TrackStates()
        self.gaps: dict[Any, GapTracker] = {}
        self.skipped = 0
        #: warn (once) when step_row / step_rows skips a row for its time (``kalmix predict`` counts them itself)
        self.warn_skipped = True
        #: the first row the step in progress skipped for its time: (track, its index in the call, time, last time)
        self._late = None
        self.rows = 0
        self.outliers = 0   # rows the glitch screen did not learn (kalmix.core.screen)
        self.output: dict | None = None
        self.loaded_version: int | None = None  # format version of the file :meth:`load` read
        self._plain: tuple | None = None   # (bank, the bank without its lead head), see _without_lead
        self._far: tuple | None = None   # (bank, the bank that forecasts across a gap), see _far_bank
        #: the positions' latitude, longitude and altitude (:class:`kalmix.io.geo.GeoAxes`) when they are
        #: geographic (``config.geographic``), else None
        self.axes = None
        self._geo_decided = False
        self._decide_geographic(self.position_names)
        self._unit_source: tuple | None = None   # (track, unit) the time unit was learned from, until judged

    # -- set-up ---------------------------------------------------------------------
    def _decide_geographic(self, names, dim: int | None = None) -> None:
        """Settle whether the positions are geographic (:attr:`axes`; ``config.geographic`` None: from the
        position ``names``) once the names or the number of coordinates ``dim`` are known (the state file keeps
        the names, so a resumed predictor settles it the same way)."""
        from .io.geo import resolve_axes

        geographic = self.config.geographic
        if self._geo_decided or names is None and dim is None:
            return
        self.axes = resolve_axes(None if names is None else list(names), geographic, dim)
        self._geo_decided = self.axes is not None or names is not None or geographic is not True

    def _resolve_length_unit(self, table, names, where: str) -> None:
        """Fix ``length_unit="auto"`` from ``table`` (:func:`estimate_length_unit`, as ``kalmix predict`` on its
        first chunk; None: a stream's first rows, 1); a fallback to 1 warns (:class:`LengthUnitWarning`)."""
        if self.config.length_unit != "auto":
            return
        from .bank import check_automatic_length_unit

        metres = " m" if self.axes is not None else ""
        if table is None:
            unit, why = 1.0, None
            text = length_unit_fallback(None, where, "length_unit", metres)
        else:
            unit, why = estimate_length_unit(table[["track_id", *names]].assign(time=_seconds(table["time"])), names,
                                             geographic=self.axes is not None)
            text = None if why is None else length_unit_fallback(why, where, "length_unit", metres)
        try:
            self.config.length_unit = check_automatic_length_unit(unit)
        except ValueError as error:
            raise ValueError(str(error).replace("--length-unit", "length_unit")) from None
        if self.params is not None:
            self.params = self._build(self.params.measurement_dim)
        if text is not None:
            warnings.warn(text, LengthUnitWarning, stacklevel=4)

    def use_backend(self, backend: str) -> None:
        """Run on ``backend`` from now on; ``ValueError`` if it cannot run here or cannot run this bank."""
        check_backend(backend)
        if backend == "gpu" and self.params is not None:
            from .core.compiled import gpu

            gpu.check_bank(self.params)
        self.backend = backend

    def _ensure_params(self, measurement_dim: int) -> Bank:
        if self.params is None:
            if self.position_names is not None and len(self.position_names) != measurement_dim:
                raise ValueError(f"measurements: expected {len(self.position_names)} coordinates per row (the position "
                                 f"names {list(self.position_names)}), got {measurement_dim}")
            params = self._build(measurement_dim)
            if self.backend == "gpu":   # a bank the GPU engine cannot run fails here, before any row
                from .core.compiled import gpu

                gpu.check_bank(params)
            self.params = params
        elif self.params.measurement_dim != measurement_dim:
            raise ValueError(f"measurements: expected {self.params.measurement_dim} coordinates per row "
                             f"(as before), got {measurement_dim}")
        return self.params

    def _build(self, measurement_dim: int) -> Bank:
        """The bank; until the time unit is learned, of a unit of 1 (a track's first row does not depend on it), or
        of the lead / MAX_HORIZON for a lead longer than MAX_HORIZON (checked against the unit once learned)."""
        from .bank import MAX_HORIZON

        c = self.config
        # (a hair over lead / MAX_HORIZON: the lead in units must come out at most MAX_HORIZON after rounding)
        interim = 1.0 if c.lead is None else max(1.0, c.lead / MAX_HORIZON * (1.0 + 1e-9))
        return make_bank(measurement_dim, c.bank, rule=c.rule, length_unit=c.length_unit,
                         time_unit=interim if c.time_unit is None else c.time_unit, seed=c.seed, n_akf=c.n_experts,
                         akf_options=c.options, lead=c.lead_time(), rule_options=c.rule_options, reach=c.reach,
                         lead_delay=c.lead_delay)

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

    def _learn_time_unit(self, value: float, track=None) -> None:
        """Fix a learned time unit (the bank's parameters scale with it; states do not).

        Only first rows of tracks come before it (a track's second row has a time step), and
        nothing they leave in a state depends on the unit (the lead head keeps no forecast made
        from a first row), so the order in which those first rows come changes nothing.
        """
        if self.config.time_unit is None and math.isfinite(value) and value > 0:
            try:   # the settings with this unit (a lead in time units is bounded), checked before any change
                learned = replace(self.config, time_unit=float(value))
            except ValueError as error:
                raise ValueError(f"the time unit learned from the data's first step, {value:.6g} time-column units, "
                                 f"does not suit these settings: {error} (pass time_unit, --time-unit on the "
                                 "command line)") from None
            self.config.time_unit = learned.time_unit
            self._unit_source = (track, learned.time_unit)
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

    def _without_lead(self) -> Bank:
        """This predictor's bank without its lead head (kept while the bank is the same: the engine checks a
        state against a bank once per bank)."""
        if self._plain is None or self._plain[0] is not self.params:
            self._plain = (self.params, replace(self.params, lead=None))
        return self._plain[1]

    def _fresh(self) -> BankState:
        return init_bank_state(self.params, 1)

    def _new_states(self, n: int) -> BankState:
        """``n`` new targets' states (the same bits as :meth:`_fresh` each); the store shares their leaves."""
        if not self.states.shares_as_new():
            self.states.share_as_new(self._fresh())
        return init_bank_state(self.params, n)

    def _states_or_fresh(self, tracks) -> BankState:
        """The states of ``tracks`` stacked (a copy), new tracks' as :meth:`_fresh`'s."""
        return self.states.gather(tracks, self._new_states)

    def _run(self, values, times, lengths, state, restart, ahead_times=None, bank=None):
        """The compiled engine (the numpy reference without numba, the GPU engine with ``backend="gpu"``), on
        this predictor's bank or ``bank``."""
        from .core import engine
        from .core.compiled import numba_available

        run = engine.run
        if self.backend == "gpu":
            from .core.compiled import gpu

            run = gpu.run
        elif numba_available():
            from .core.compiled import engine as compiled

            run = compiled.run
        return run(bank or self.params, values, times, state, lengths=lengths, restart=restart,
                   ahead_times=ahead_times)

    def _interval(self, gaps: "GapTracker") -> float:
        """A track's reference interval (median of its first steps), else the time unit, else 1."""
        if gaps.intervals:
            return short_median(gaps.intervals)
        return self.config.time_unit or 1.0

    def _forecast_next(self, state: BankState, times) -> tuple[np.ndarray, np.ndarray]:
        """Mean and standard deviation ``(N, p)`` at ``times (N,)`` from ``state``, nothing learned.

        The engine's forecast of a missing row at those times, made before it: the same
        computation as the forecast of a real next row, so a table's rows give the same bits
        whether their next row is in the table or not (and a stream's, where times agree).
        """
        times = np.asarray(times, dtype=np.float64)
        blank = np.full((1, len(times), self.params.measurement_dim), np.nan)
        result = self._run(blank, times[None, :], None, state, None)
        return result.forecasts[0], result.std[0]

    @property
    def track_ids(self) -> list:
        return list(self.gaps)

    @property
    def time_glitches(self) -> int:
        """Rows that came back before a jump ahead in time (see the module docstring)."""
        return sum(g.glitches for g in self.gaps.values())

    def warm_up(self, measurement_dim: int | None = None) -> None:
        """Load the compiled kernels this predictor's runs use now (or compile them, on a fresh install).

        numba loads a kernel from its cache (or compiles it) at its first call; that takes a
        fraction of a second with a warm cache, and minutes the first time. Call this where
        that wait does no harm: before a live feed starts, or in a thread while the feed is
        silent (``kalmix predict -`` does, until stdin's first rows). It runs a throwaway copy
        of this predictor on a tiny made-up table (two tracks, a missing row, a gap that
        restarts a track), so this predictor does not change. Nothing to do for the numpy
        reference; the GPU engine's kernels compile at its first run instead.

        Parameters
        ----------
        measurement_dim : int, optional
            Coordinates per row; default the predictor's (its position names or bank).
        """
        import pandas as pd

        from .core.compiled import numba_available

        if measurement_dim is not None and (isinstance(measurement_dim, bool) or not isinstance(
                measurement_dim, numbers.Integral) or measurement_dim < 1):
            raise ValueError(f"measurement_dim: expected an integer >= 1 (coordinates per row), "
                             f"got {measurement_dim!r}")
        if self.backend != "cpu" or not numba_available():
            return
        names = list(self.position_names or ())
        p = measurement_dim or len(names) or (self.params.measurement_dim if self.params is not None else 0)
        if p < 1:
            raise ValueError("warm_up: the number of coordinates is not known yet; pass measurement_dim")
        names = names if len(names) == p else [f"x{j}" for j in range(p)]
        config = self.config
        if config.length_unit == "auto":   # (a made-up table: not one to estimate the unit from)
            config = replace(config, length_unit=1.0)
        if config.time_unit is None:   # the made-up rows are 1 apart: not a unit to learn (nor to warn of a lead by)
            config = replace(config, time_unit=config.lead if config.lead is not None else 1.0)
        twin = TrackPredictor(config, names)
        twin.params = self.params if self.params is not None and self.params.measurement_dim == p else None
        rows = 6
        times = np.concatenate([np.arange(rows, dtype=np.float64), np.arange(rows, dtype=np.float64)])
        times[rows + 3:] += 1e6   # a long gap: the second track restarts
        values = np.cumsum(np.random.default_rng(0).normal(size=(2 * rows, p)), axis=0)
        values[2] = np.nan
        table = pd.DataFrame({"track_id": [0] * rows + [1] * rows, "time": times, **dict(zip(names, values.T))})
        twin.process_table(table, names, {0: float(rows)})

    # -- transactions -----------------------------------------------------------------
    def checkpoint(self, track_ids=None) -> "Checkpoint":
        """Snapshot of the counters and of ``track_ids``' trackers and states (all tracks if None).

        :meth:`rollback` returns to it, provided only those tracks were touched in between.
        Cheap: the states are never modified in place, so only references are kept.
        """
        ids = list(self.gaps) if track_ids is None else [id_to_json(t) for t in track_ids]
        tracks = {t: (self.gaps[t].copy() if t in self.gaps else None, self.states.ref(t)) for t in ids}
        return Checkpoint(self.rows, self.skipped, self.position_names, tracks, self.config.time_unit, self.outliers,
                          (self.config.length_unit, self.axes, self._geo_decided))

    def rollback(self, checkpoint: "Checkpoint") -> None:
        """Undo everything done since ``checkpoint`` was taken."""
        self.rows, self.skipped, self.position_names = checkpoint.rows, checkpoint.skipped, checkpoint.position_names
        self.outliers = checkpoint.outliers
        if checkpoint.settings is not None:   # a length unit or geographic setting chosen since
            length_unit, self.axes, self._geo_decided = checkpoint.settings
            if self.config.length_unit != length_unit:
                self.config.length_unit = length_unit
                if length_unit == "auto":
                    self.params = None   # (no track has a state yet: the unit is chosen at the first rows)
                elif self.params is not None:
                    self.params = self._build(self.params.measurement_dim)
        if self.config.time_unit != checkpoint.time_unit:  # a unit learned from rows now undone
            self.config.time_unit = checkpoint.time_unit
            if self.params is not None:
                self.params = self._build(self.params.measurement_dim)
        for track, (gaps, state) in checkpoint.tracks.items():
            if gaps is None:
                self.gaps.pop(track, None)
            else:
                self.gaps[track] = gaps
            self.states.restore(track, state)

    # -- one row at a time ------------------------------------------------------------
    def step_row(self, track_id, time: float, z) -> RowPrediction | None:
        """Learn from one measurement (NaN = missing) and predict; None if the row is skipped (its time at or
        before its track's last time, or NaN or infinite).

        ``z``: the coordinates in the order of :attr:`position_names`, or labelled by them (a pandas
        Series, a dict; a predictor with no names yet takes the first labelled row's labels for them);
        None for a missing row once the predictor knows its number of coordinates.

        All or nothing: the track's tracker and state change only once the step succeeded.
        """
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
            time = float(_row_times([time])[0])
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
            asked, times = times, _row_times(times).reshape(-1)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"times: expected numbers, dates and times (datetime, ISO text) or durations, "
                             f"got {times!r:.80}") from None
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
                from .io.geo import check_degrees

                check_degrees(values, self.axes, names if names is not None else self.position_names,
                              where or (lambda i: f"values[{i}]"))
            self._resolve_length_unit(None, None, "a stream's first row")
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
        the end (but for that unit)."""
        n_rows, p = values.shape
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
            from .io.geo import assign_frames, to_local

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
                from .io.geo import from_local

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
            self.outliers += int(result.state.screen.outliers.sum() - state.screen.outliers.sum())
        self.rows += n_rows
        self.skipped += sum(r is None for r in results)
        return results

    # -- a table (or chunk) at once -----------------------------------------------------
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
        (:func:`estimate_length_unit`, as the command on a file's first chunk). Geographic
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
            lead), one row per input row that was not skipped, in table order. A table whose
            columns were detected keeps its id and time columns' names and values as given
            (no id column: none; no time column: ``row``, each track's row number).
        """
        import pandas as pd

        if not isinstance(table, pd.DataFrame):
            raise TypeError(f"table: expected a pandas DataFrame (track_id, time and position columns), got "
                            f"{type(table).__name__}")
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
            self._decide_geographic(names)
            if self.axes is not None:
                from .io.geo import check_degrees

                check_degrees(table[names].to_numpy(np.float64), self.axes, names,
                              lambda i: f"table: row {i} (counted from 0)")
            self._resolve_length_unit(table, names, "the table")
            frame = self._process_table(table, position_names, next_times or {}, kept=kept)
        except BaseException:
            self.rollback(saved)
            raise
        if columns is None:
            return frame
        rows = np.concatenate(kept) if kept else np.zeros(0, dtype=np.int64)
        if columns.time is not None:   # the time as given (the frame's is in seconds)
            frame["time"] = source[columns.time].iloc[rows].to_numpy()
        if columns.track_id is not None:
            frame["track_id"] = source[columns.track_id].iloc[rows].to_numpy()
        return with_input_names(frame, columns)

    def _front_door(self, table, position_names):
        """``(table, positions, columns)``: a table as :meth:`_process_table` takes it (``track_id``, ``time`` in
        seconds, the positions) and the :class:`kalmix.io.TrackColumns` found (None for a table already in that
        form)."""
        import pandas as pd

        from .io.tables import detect_columns, to_float

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
            codes, uniques = _factorize(ids)
            count = pd.Series(codes).groupby(codes).cumcount().to_numpy(np.float64)
            start = np.array([self.gaps[key].last_time + 1 if key in self.gaps and self.gaps[key].last_time
                              is not None else 0.0 for key in (id_to_json(u) for u in uniques)])
            times = count + (start[codes] if len(start) else 0.0)
        else:
            times = to_float(table[columns.time].reset_index(drop=True), columns.time, 0, dates=True)
        canonical = pd.DataFrame({"track_id": ids, "time": times,
                                  **{name: table[name].to_numpy() for name in columns.positions}})
        return canonical, list(columns.positions), columns

    def _first_step(self, ids, times) -> tuple | None:
        """``(row, track, step)``: the row of these rows, in this order, at which the time unit would be learned,
        its track and the step learned (None: no such row). Nothing is changed."""
        trackers: dict = {}
        for i in range(len(ids)):
            track = id_to_json(ids[i])
            if track not in trackers:
                trackers[track] = self.gaps[track].copy() if track in self.gaps else GapTracker()
            trackers[track].advance(float(times[i]), self.config)
            if trackers[track].intervals:
                return i, track, trackers[track].intervals[0]
        return None

    def _unit_row(self, ids, times) -> int | None:
        """The row of a table at which the time unit would be learned (None: not in this table)."""
        found = self._first_step(ids, times)
        return None if found is None else found[0]

    def time_unit_row(self, table) -> int | None:
        """The position in ``table`` (``track_id`` and ``time`` columns, rows in arrival order, continuing the
        tracks this predictor has seen) of the row whose step fixes the time unit; None if the unit is known
        or no row of the table fixes it. See :meth:`learn_time_unit`."""
        found = self._table_first_step(table)
        return None if found is None else found[0]

    def _table_first_step(self, table) -> tuple | None:
        """:meth:`_first_step` of a table's rows while the time unit is unknown (None once it is known)."""
        if self.config.time_unit is not None:
            return None
        return self._first_step(table["track_id"].to_numpy(), _seconds(table["time"]))

    def learn_time_unit(self, table) -> float | None:
        """Fix the time unit, if it is not known yet, from the first step of a table's rows in arrival order,
        without stepping them; returns the time unit (None: still unknown).

        Stepping the rows one by one learns the unit at that step, and the rows before it run
        with a unit of 1. So this gives the same numbers as stepping the table when every row
        before that step has been stepped already (:meth:`time_unit_row` tells where it is):
        ``kalmix predict`` steps a file's rows track by track (:func:`kalmix.io.iter_track_chunks`
        sorts a chunk), so it steps the rows before that step in file order
        (:func:`kalmix.io.in_file_order`), fixes the unit here, then steps the rest track by
        track: the numbers of a stream of the same rows. (Called before those rows instead, the
        numbers differ where they depend on the unit: a restart before the unit is known, by an
        absolute ``max_gap``, or a ``horizon`` after a time glitch.)

        Parameters
        ----------
        table : pandas.DataFrame
            ``track_id`` and ``time`` columns, in arrival order (later rows continue the tracks
            this predictor has seen).
        """
        found = self._table_first_step(table)
        if found is not None:
            self._learn_time_unit(found[2], found[1])
        return self.config.time_unit

    def _process_table(self, table, position_names, next_times, first_row=0, kept=None):
        """``first_row``: the table's first row in the caller's table (the rows that errors name); ``kept``: a list
        that receives the caller's rows that were stepped (arrays, in order)."""
        import pandas as pd

        if not pd.api.types.is_numeric_dtype(table["time"]):   # dates and durations: seconds, as files are read
            table = table.assign(time=_seconds(table["time"]))

        if self.config.time_unit is None:
            # rows before the time unit is known run with the bank of a unit of 1, as they would row by row
            split = self._unit_row(table["track_id"].to_numpy(), table["time"].to_numpy(np.float64))
            if split:
                head, tail = table.iloc[:split], table.iloc[split:]
                later = {**next_times, **tail.groupby("track_id", sort=False)["time"].first().to_dict()}
                first = self._process_table(head, position_names, later, first_row, kept)
                return pd.concat([first, self._process_table(tail, position_names, next_times, first_row + split,
                                                             kept)], ignore_index=True)
        names = list(position_names)   # (process_table gave the default: every other column)
        if self.position_names is None:
            self.position_names = tuple(names)
        elif set(names) == set(self.position_names):
            names = list(self.position_names)   # the coordinates by name, in the order the predictor learned
        else:
            raise ValueError(f"table: expected the position columns {list(self.position_names)} (as before), got "
                             f"{names}")
        self._decide_geographic(names, len(names))
        try:
            values = table[names].to_numpy(np.float64)
        except (TypeError, ValueError):
            bad = next(name for name in names if not pd.api.types.is_numeric_dtype(table[name]))
            column = table[bad].reset_index(drop=True)
            wrong = column.notna() & pd.to_numeric(column, errors="coerce").isna()
            i = int(np.flatnonzero(wrong.to_numpy())[0]) if wrong.any() else 0
            raise ValueError(f"table: position column {bad!r} must hold numbers, got {column.iloc[i]!r} in row "
                             f"{first_row + i} (counted from 0; {table[bad].dtype} values)") from None
        if np.isinf(values).any():
            i = int(np.flatnonzero(np.isinf(values).any(axis=-1))[0])
            raise ValueError(f"table: expected finite positions (NaN for a missing measurement), got {values[i]!r} "
                             f"in row {first_row + i} (counted from 0)")
        axes = self.axes
        if axes is not None:
            from .io.geo import check_degrees

            check_degrees(values, axes, names, lambda i: f"table: row {first_row + i} (counted from 0)")
        times = table["time"].to_numpy(np.float64)
        ids = table["track_id"].to_numpy()
        self._ensure_params(values.shape[1])
        n_rows, p = values.shape
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
                self.outliers += int(result.state.screen.outliers.sum() - state.screen.outliers.sum())
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
                far = np.array([len(pieces[c]) > wave + 1 or when[k] - times[last[k]] > self.gaps[tracks[c]].threshold(
                    self.config) for k, c in enumerate(columns)], dtype=bool)
                if far.any():   # the next row comes after a gap
                    index = np.flatnonzero(far)
                    out["pred"][last[index]], out["std"][last[index]] = self._forecast_far(
                        _take(result.state, index), when[index])
                if lead:   # none from a track's first row (a single position)
                    out["lead"][rows[active]] = result.lead[active]
                    out["lead_std"][rows[active]] = result.lead_std[active]
                    if wave == 0:
                        first = rows[0, [k for k, c in enumerate(columns) if new_tracks[c]]]
                        out["lead"][first] = out["lead_std"][first] = np.nan
                for k, c in enumerate(columns):
                    where[c] = (result.state, k)
            by_state: dict = {}   # each track's rows stored with the others' of the same state
            for c, track in enumerate(tracks):
                held, k = where[c]
                by_state.setdefault(id(held), (held, [], []))
                by_state[id(held)][1].append(track)
                by_state[id(held)][2].append(k)
            for held, these, columns in by_state.values():
                self.states.put(these, held, columns)
        if origins is not None:   # the forecasts back to degrees, each in the frame of the row it was made after
            from .io.geo import from_local

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
        from .io.geo import REANCHOR_M, assign_frames, chord, origin_of, to_local

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

    def _far_bank(self) -> Bank | None:
        """The bank that forecasts across a time gap: only the constant-velocity experts (a reach of 0), the
        bank itself when it has only those or only frame-based ones, None (no forecast) when it has neither."""
        if self._far is None or self._far[0] is not self.params:
            kinds = {family.kind for family in self.params.families}
            if "cv" in kinds:
                far = replace(self.params, reach=0.0) if kinds != {"cv"} else self.params
            else:
                far = self.params if kinds <= {"akf"} else None
            self._far = (self.params, far)
        return self._far[1]

    def _forecast_far(self, state: BankState, times) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_forecast_next` across a time gap: the constant-velocity experts' extrapolation (weighted as
        the rule weighs them) and its interval, which grows with the step; NaN for a bank without them (whose
        other time-based experts extrapolate fits made on the usual steps)."""
        bank = self._far_bank()
        if bank is None:
            shape = (len(np.atleast_1d(times)), self.params.measurement_dim)
            return np.full(shape, np.nan), np.full(shape, np.nan)
        times = np.asarray(times, dtype=np.float64)
        blank = np.full((1, len(times), self.params.measurement_dim), np.nan)
        result = self._run(blank, times[None, :], None, state, None, bank=bank)
        return result.forecasts[0], result.std[0]

    def _gap_rule(self, ids, times, first_row=0):
        """The gap rule over a table's rows, in row order as :meth:`_advance` row by row.

        Returns the tracks with kept rows (in the order of their first kept row), each one's
        kept rows, every row's segment, which rows start a new segment of a track already
        running (a restart), and which rows are kept (not out of order).
        """
        n_rows = len(ids)
        codes = np.empty(n_rows, dtype=np.int8)
        segments = np.zeros(n_rows, dtype=np.int64)
        index, uniques = _factorize(ids)
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

    def output_columns(self) -> dict:
        """Output key (``pred``, ``std``, ``lead``, ``lead_std``) -> its columns' names: ``pred_<pos>``,
        ``std_<pos>``, ...; for geographic positions the standard deviations are in metres east, north (and
        up): ``std_east_m``, ``std_north_m`` (``lead_std_east_m``, ``std<H>_east_m``)."""
        names = list(self.position_names or ())
        if self.axes is not None:
            from .io.geo import std_names

            spread = list(std_names(self.axes))
        else:
            spread = names
        return {key: [f"{prefix}{name}" for name in (spread if key.endswith("std") else names)]
                for key, prefix in self._columns().items()}

    def _columns(self) -> dict:
        """Output key -> column prefix."""
        columns = {"pred": "pred_", "std": "std_"}
        if self.config.lead is not None:
            columns.update(lead="lead_", lead_std="lead_std_")
        elif self.config.horizon > 1:
            h = self.config.horizon
            columns.update(lead=f"pred{h}_", lead_std=f"std{h}_")
        return columns

    # -- persistence ------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write settings, every track's state and gap bookkeeping to ``path`` (``.npz``).

        Atomic and durable (see :func:`kalmix.archive.write_archive`): a reader sees the old
        file or the new one, never a mixture.
        """
        tracks = list(self.gaps)
        with_state = [t for t in tracks if t in self.states]
        meta = {"magic": _MAGIC, "format_version": STATE_FORMAT_VERSION, "config": asdict(self.config),
                "measurement_dim": None if self.params is None else self.params.measurement_dim,
                "position_names": None if self.position_names is None else list(self.position_names),
                "tracks": [{"id": id_to_meta(t), "gaps": self.gaps[t].to_json(), "state": t in self.states}
                           for t in tracks],
                "rows": self.rows, "skipped": self.skipped, "outliers": self.outliers,
                "output": self.output}
        arrays = {}
        if with_state:
            arrays = dict(tree_leaves(self.states.gather(with_state, self._new_states)))
        write_archive(path, meta, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike, *, backend: str = "cpu") -> "TrackPredictor":
        """Read a file written by :meth:`save` (to run on ``backend``); ``ValueError`` with the reason on a bad
        file."""
        with open_archive(path, magic=_MAGIC, version=_READABLE_VERSIONS, what="kalmix state file",
                          written_by="kalmix predict --state") as archive:
            meta = archive.meta
            try:
                config = dict(meta["config"])
                if config.get("options"):   # older files may hold gate arguments (without effect): drop them
                    from .bank import GATE_OPTIONS
                    config["options"] = {k: v for k, v in config["options"].items() if k not in GATE_OPTIONS}
                if meta["format_version"] < 8:
                    config.setdefault("reach", None)   # files before version 8 ran without a reach
                if meta["format_version"] < 9:
                    config.setdefault("lead_delay", 1.0)   # files before version 9 ran at the one-step rate
                if meta["format_version"] < 5 and config.get("rule") == "boa":
                    config["rule_options"] = {"bound_forgetting": 1.0, **(config.get("rule_options") or {})}
                if meta["format_version"] < 10 and config.get("rule") == "boa":
                    config["rule_options"] = {"clip": math.inf, **(config.get("rule_options") or {})}
                if meta["format_version"] < 11:
                    config.setdefault("geographic", False)   # files before version 11 took positions as flat
                if meta["format_version"] < 12:
                    config.setdefault("gap_reference", "median")   # files before version 12 took the median
                engine = cls(StreamConfig(**config), meta.get("position_names"))
                engine.rows, engine.skipped = int(meta["rows"]), int(meta["skipped"])
                engine.outliers = int(meta.get("outliers", 0))
                engine.output = meta.get("output")
                engine.loaded_version = meta["format_version"]
                if meta["measurement_dim"] is not None:
                    engine._ensure_params(int(meta["measurement_dim"]))
                entries = [(id_from_meta(entry["id"]), GapTracker(**entry["gaps"]), bool(entry["state"]))
                           for entry in meta["tracks"]]
            except (KeyError, TypeError, ValueError) as error:
                settings = meta.get("config") if isinstance(meta, dict) else None
                unit = settings.get("length_unit") if isinstance(settings, dict) else None
                low, high = LENGTH_UNIT_RANGE
                if isinstance(unit, numbers.Real) and not low <= unit <= high:   # older versions had a wider range
                    raise ValueError(f"{path}: the state file's length unit {unit!r} is outside this version's range "
                                     f"[{low:g}, {high:g}] (where the predictions are scale-equivariant); start "
                                     "a new state file with a unit in it") from error
                raise ValueError(f"{path}: the kalmix state file's settings are incomplete or corrupt: "
                                 f"{error!r}") from error
            count = sum(has_state for _, _, has_state in entries)
            stacked, template = None, None
            if count:
                template = engine._fresh()
                version = meta["format_version"]
                fresh = lambda name: ((version == 3 and name.startswith("state/calibration/"))  # noqa: E731
                                      or (version <= 5 and name == "state/lead/issued")
                                  or (version <= 6 and name in ("state/screen/low", "state/screen/high"))
                                  or (version <= 9
                                      and name.startswith(("state/rule/error_", "state/lead/rule/error_"))))
                stacked = {name: (np.broadcast_to(expected, (count, *expected.shape[1:])) if fresh(name)
                                  else archive.array(name, (count, *expected.shape[1:]), expected.dtype, label=name))
                           for name, expected in tree_leaves(template)}
        engine.use_backend(backend)   # outside the checks of the file: a backend that cannot run is not corruption
        for track, gaps, _ in entries:
            engine.gaps[track] = gaps
        if count:
            leaves = iter([np.asarray(value) for value in stacked.values()])
            engine.states.share_as_new(template)
            engine.states.put([track for track, _, has_state in entries if has_state],
                              tree_map(lambda _: next(leaves), template))
        return engine


def learned_time_unit(tables, config: StreamConfig, continued: list | None = None) -> float | None:
    """The time unit :meth:`TrackPredictor.process_table` learns from ``tables`` fed in this order.

    Only the gap rule runs (no bank): the unit is the first interval a track's
    :class:`GapTracker` keeps, in row order, exactly as in ``process_table`` (the bank's
    parameters scale with it, so a run split over several machines fixes it in advance to
    give the numbers of one run). ``None`` when no table has a positive step of a track.

    Parameters
    ----------
    tables : iterable of pandas.DataFrame
        ``track_id`` and ``time`` columns, in the order ``process_table`` would get them.
    config : StreamConfig
        The gap rule's settings (``max_gap``, ``max_gap_factor``); its ``time_unit`` is ignored.
    continued : list, optional
        Receives the tracks that have a row before that step other than their first (a restart by
        an absolute ``max_gap``, a row after a time glitch): such a row's numbers can depend on
        the unit, which a run that steps it before knowing the unit takes as 1.
    """
    from dataclasses import replace

    scratch = TrackPredictor(replace(config, time_unit=None))
    for table in tables:
        for track, time in zip(table["track_id"].to_numpy(), _seconds(table["time"])):
            key = id_to_json(track)
            seen = key in scratch.gaps
            _, new = scratch._advance(key, float(time))
            if scratch.config.time_unit is not None:
                return scratch.config.time_unit
            if seen and new is not None and continued is not None and key not in continued:
                continued.append(key)
    return None


def next_row_times(parts, after: dict | None = None) -> list[dict]:
    """For tables ``parts`` fed to :meth:`TrackPredictor.process_table` in this order, each one's
    ``next_times``: track id -> time of the track's next row after that table (in a later part,
    else ``after``, e.g. a later chunk of a file)."""
    out = []
    upcoming = dict(after or {})
    for part in reversed(parts):
        out.append(dict(upcoming))
        firsts = part.groupby("track_id", sort=False)["time"].first()
        upcoming.update((track, float(t)) for track, t in zip(firsts.index, _seconds(firsts)))
    return out[::-1]


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


class Checkpoint(NamedTuple):
    """What :meth:`TrackPredictor.checkpoint` returns."""

    rows: int
    skipped: int
    position_names: tuple | None
    tracks: dict   # track id -> (GapTracker copy or None, its state's TrackStates.ref or None)
    time_unit: float | None = None
    outliers: int = 0
    settings: tuple | None = None   # (length_unit, axes, whether the axes are settled)
