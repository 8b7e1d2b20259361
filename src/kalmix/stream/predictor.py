"""The :class:`~kalmix.streaming.TrackPredictor`: one mixture predictor per track, put together from its parts
(:mod:`.bank_runs`, :mod:`.clocks`, :mod:`.row_steps`, :mod:`.table_steps`, :mod:`.state_file`), and what runs
the gap rule alone over tables (:func:`learned_time_unit`)."""

from __future__ import annotations

import numbers
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np

from ..core.engine import Bank
from .bank_runs import BankRuns, check_backend
from .clocks import TrackClocks
from .columns import names_argument
from .config import StreamConfig
from .gaps import GapTracker
from .ids import id_to_json
from .population import PopulationPrior
from .row_steps import RowSteps
from .state_file import StateFile
from .store import TrackStates
from .table_steps import TableSteps
from .times import column_seconds


class TrackPredictor(RowSteps, TableSteps, TrackClocks, BankRuns, PopulationPrior, StateFile):
    """One mixture predictor per track id; tracks appear as they come.

    Parameters
    ----------
    config : StreamConfig, optional
        The settings; by default ``StreamConfig()``, those of ``kalmix predict``.
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
        Whether the next row that :meth:`step_row`, :meth:`step_rows` or :meth:`process_table` skips for its
        time gives a :class:`SkippedRowWarning` (once: then False).
    rows : int
        Rows processed (including skipped ones), counted over saves and resumes.
    output : dict or None
        What the program that saved the state wrote with it (``kalmix predict`` records its
        ``-o`` file there); kept as is by :meth:`save` / :meth:`load`.
    """

    def __init__(self, config: StreamConfig | None = None, position_names=None, *, backend: str = "cpu"):
        import copy

        if config is None:   # the defaults, as kalmix predict runs them
            config = StreamConfig()
        if not isinstance(config, StreamConfig):
            raise TypeError(f"config: expected a StreamConfig, got {type(config).__name__} {config!r:.80}")
        self.backend = check_backend(backend)
        self.config = copy.deepcopy(config)   # the predictor learns its time unit into it: not the caller's
        self.position_names = names_argument(position_names)
        if self.position_names == ():
            raise ValueError("position_names: expected one name per coordinate, got none (None: the names come "
                             "from the first table or labelled row)")
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
        #: track id -> rows it learned, counting the pseudo-rows of the prior it started from (:mod:`.population`)
        self.track_rows: dict = {}
        #: the population priors summarised so far (:mod:`.population`): new tracks start from the last
        self.priors: list = []
        #: summary point -> whether its summary is made, as decided for rows being stepped (.population)
        self.summary_plan: dict = {}

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

        from ..core.compiled import numba_available

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
        tracks = {t: (self.gaps[t].copy() if t in self.gaps else None, self.states.ref(t), self.track_rows.get(t))
                  for t in ids}
        return Checkpoint(self.rows, self.skipped, self.position_names, tracks, self.config.time_unit, self.outliers,
                          (self.config.length_unit, self.axes, self._geo_decided), len(self.priors), self.config.reach,
                          self.config.gap_floor)

    def rollback(self, checkpoint: "Checkpoint") -> None:
        """Undo everything done since ``checkpoint`` was taken."""
        if not isinstance(checkpoint, Checkpoint):
            raise TypeError(f"checkpoint: expected what TrackPredictor.checkpoint() returned, got "
                            f"{type(checkpoint).__name__} {checkpoint!r:.80}")
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
        self.config.gap_floor = checkpoint.gap_floor   # (settled from rows now undone, or as it was)
        if self.config.time_unit != checkpoint.time_unit or self.config.reach != checkpoint.reach:
            # a unit or a reach learned from rows now undone
            self.config.time_unit, self.config.reach = checkpoint.time_unit, checkpoint.reach
            if self.params is not None:
                self.params = self._build(self.params.measurement_dim)
        for track, (gaps, state, rows) in checkpoint.tracks.items():
            if gaps is None:
                self.gaps.pop(track, None)
            else:
                self.gaps[track] = gaps
            self.states.restore(track, state)
            if rows is None:
                self.track_rows.pop(track, None)
            else:
                self.track_rows[track] = rows
        self.summary_plan = {}   # (decided for rows now undone)
        if len(self.priors) != checkpoint.priors:   # summaries made since: new tracks start as they would have
            del self.priors[checkpoint.priors:]
            if self.params is not None:
                self.states.share_as_new(self._fresh())


def learned_time_unit(tables, config: StreamConfig) -> float | None:
    """The time unit :meth:`TrackPredictor.process_table` learns from ``tables`` fed in this order: the median
    time step of the first of them that has a step (:meth:`TrackPredictor.learn_time_unit`), reading on only
    until then. The bank's parameters scale with it, so a run split over several machines fixes it in advance
    to give the numbers of one run. ``None`` when no table has a positive step of a track.

    Parameters
    ----------
    tables : iterable of pandas.DataFrame
        ``track_id`` and ``time`` columns, in the order ``process_table`` would get them.
    config : StreamConfig
        The gap rule's settings (``max_gap``, ``max_gap_factor``); its ``time_unit`` is ignored.
    """
    return learned_sampling(tables, replace(config, time_unit=None))[0]


def learned_sampling(tables, config: StreamConfig, names=None
                     ) -> tuple[float | None, float | str | None, float | str | None]:
    """``(time unit, reach, gap floor)``: :func:`learned_time_unit` (or the config's given unit), and what
    ``reach="auto"`` and ``gap_floor="auto"`` settle at from the same steps (the config's when not ``"auto"``;
    ``"auto"`` still when no table has a step); ``names``: the position columns (default: every other column)."""
    scratch = TrackPredictor(config)   # (a given time unit is the pilot's, as a single machine's)
    for table in tables:
        scratch.learn_time_unit(table, names)
        settled = scratch.config
        if settled.time_unit is not None and "auto" not in (settled.reach, settled.gap_floor):
            break
        for track, time in zip(table["track_id"].to_numpy(), column_seconds(table["time"])):
            scratch._advance(id_to_json(track), float(time))   # (the tracks' last times, for the next table)
    return scratch.config.time_unit, scratch.config.reach, scratch.config.gap_floor


class Checkpoint(NamedTuple):
    """What :meth:`TrackPredictor.checkpoint` returns."""

    rows: int
    skipped: int
    position_names: tuple | None
    tracks: dict   # track id -> (GapTracker copy or None, its state's TrackStates.ref or None, its learned rows)
    time_unit: float | None = None
    outliers: int = 0
    settings: tuple | None = None   # (length_unit, axes, whether the axes are settled)
    priors: int = 0                 # population priors summarised by then
    reach: float | str | None = None  # the reach, "auto" until settled
    gap_floor: float | str | None = None   # the gap floor, "auto" until settled
