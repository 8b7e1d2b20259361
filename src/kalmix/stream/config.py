"""The settings of a :class:`kalmix.streaming.TrackPredictor` (re-exported by :mod:`kalmix.streaming`)."""

from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..bank import ARGUMENT_CONSTRAINTS as BANK_ARGUMENTS
from ..bank import DEFAULT_BANK, check_horizon, check_length_unit, make_bank, make_params, short_lead
from ..core.calibration import CalibrationParams
from ..core.constraints import validate
from ..core.lead import LeadParams

#: How a track's gap threshold is taken from its first steps (:class:`StreamConfig`'s ``gap_reference``).
GAP_REFERENCES = ("spread", "upper quartile", "median")
#: The power of the spread of a track's first steps (upper over lower quartile) in the ``"spread"`` gap rule: a
#: fence on the log of the steps, as Tukey's fence is 1.5 interquartile ranges beyond the upper quartile.
GAP_SPREAD_POWER = 1.5
#: Number of first non-gap time steps whose upper quartile is a track's reference interval.
REFERENCE_INTERVALS = 16


@dataclass
class StreamConfig:
    """Settings of a :class:`TrackPredictor`, saved with its state.

    Parameters
    ----------
    n_experts : int
        Size of the bank's AKF family (40 in the paper); the other families have their own
        sizes (the default bank: 125 experts in all; ``n_experts=5`` gives 90).
    seed : int
        Seed of the bank.
    length_unit : float or "auto"
        Measurement-noise size in data units (metres for geographic data; see
        :func:`auto_length_unit`). ``"auto"`` (the default): estimated as ``kalmix predict`` does,
        by :func:`estimate_length_unit` on the first table :meth:`TrackPredictor.process_table`
        gets; a predictor whose first rows come through :meth:`~TrackPredictor.step_row` or
        :meth:`~TrackPredictor.step_rows` (a live stream, with no sample to estimate from at its
        first row) takes 1, as ``kalmix predict -`` does. Either fallback to 1 gives a
        :class:`LengthUnitWarning`. The predictor keeps the unit it chose in its own copy of the
        settings (``predictor.config.length_unit``), and the state file saves it.
    horizon : int
        Besides the next row, also predict ``horizon`` time units ahead (``horizon`` frames
        for frame-based experts; 1 = only the next row), with its own weights (a lead head).
    lead : float or None
        Also predict ``lead`` time-column units after each row (``RowPrediction.ahead``,
        ``lead_<pos>`` in a table), with weights and intervals learned on lead-``lead`` errors.
    max_gap : float or None
        Absolute gap threshold (time units); ``None`` uses ``max_gap_factor``.
    max_gap_factor : float
        Gap threshold relative to the reference interval; ``inf`` never splits. At the default
        3, a step of more than 3 reference intervals (at 100 Hz, 3 dropped frames) starts a new
        segment: the experts start again (the rule and calibration go on). Pass ``inf`` (or a
        ``max_gap``) where short drops are the sampling and the target did not change course.
    gap_reference : str
        The reference interval, from the track's first 16 steps: ``"spread"`` (the default), their upper
        quartile (the 13th in increasing order) times their spread, the upper quartile over the lower
        quartile (the 5th) to the power :data:`GAP_SPREAD_POWER`: the step itself on regular sampling, and on
        irregular sampling beyond the sampling's own long steps (a fence on the log of the steps), so that
        steps of 10 s to 10 min drawn at random keep a track in one segment; ``"upper quartile"``: the upper
        quartile alone (the rule of state files of format versions 12 to 14, which resume with it);
        ``"median"``: their median (files before version 12).
    gap_min_steps : int
        Steps a track must have before a step is judged a gap (4: the upper quartile of fewer steps is their
        largest, one to three draws of the sampling say little about its spread, and a track sampled every 10 to
        60 minutes would restart at its third row). Files before format version 13 resume with 1.
    population_prior : bool
        Whether a new track's rule starts from what the tracks before it learned
        (:mod:`kalmix.stream.population`), or empty. Files before format version 13 resume without it;
        :func:`kalmix.dask_predict.predict_dask` runs without it.
    lead_prior : bool
        With a lead head (``lead``, ``horizon``) and the population prior: whether the prior also starts a new
        track's lead weights and their blend (a lead head learns each error H rows late: on its own it spends a
        short track learning what the tracks before it showed), or only its one-step rule. Files before format
        version 17 resume without it.
    calibration_prior : bool
        With the population prior: whether it also starts a new track's one-step calibration (the experts' error
        variances and the intervals' scale) from the mean of the tracks before it, or from the length unit.
        Files before format version 18 resume without it.
    calibration_from_points : int
        The calibration learns the errors of forecasts made from at least this many rows of a track's segment
        (2: not a track's first forecast, made from one row; 0: every one, as files before format version 18
        resume; at most 3). See :func:`kalmix.bank.make_bank`.
    options : dict
        Other arguments of :func:`kalmix.bank.make_params` (the AKF family).
    bank : str
        Bank recipe of :func:`kalmix.bank.make_bank` (:data:`kalmix.bank.BANK_KINDS`);
        ``n_experts`` is the size of its AKF family.
    rule : str
        Aggregation rule (``boa``, ``mlpoly``, ``fixed_share``).
    rule_options : dict
        The rule's parameters over :data:`kalmix.bank.DEFAULT_RULE_OPTIONS` (``rule_options`` of
        :func:`kalmix.bank.make_bank`).
    time_unit : float or None
        The typical sampling interval (time-column units) that scales the kinematic
        experts' noise; ``None``: learned from the data, the median time step between
        consecutive rows of a track in the first table :meth:`TrackPredictor.process_table`
        gets that has one (as ``kalmix predict`` on a file's first chunk); rows that come
        one by one (:meth:`~TrackPredictor.step_row`, ``kalmix predict -``) take the first
        time step to arrive.
    reach : float, None or "auto"
        In time units: across a longer step only the CV experts make the one-step forecast
        (``reach`` of :func:`kalmix.bank.make_bank`); None: every expert at every step.
        ``"auto"`` (the default): settled with the time unit, from the same steps
        (:func:`reach_for_steps`): 1.5 time units on heavy-tailed steps, else None; rows
        that come one by one take None.
    gap_floor : float, None or "auto"
        A step not longer than this (time-column units) is no gap, whatever a track's first
        steps were (an absolute ``max_gap`` decides alone). ``"auto"`` (the default): settled
        with the time unit, from the same steps (:func:`gap_floor_for_steps`): on heavy-tailed
        sampling ``max_gap_factor`` times the steps' 90th percentile, else None (rows that come
        one by one: None).
    lead_delay : float or None
        ``lead_delay`` of :func:`kalmix.bank.make_bank` (None: the lead's rows); checked always, used
        only with a lead.
    geographic : bool or None
        Whether the positions are latitude and longitude in degrees (and an altitude in metres):
        then each track is predicted in metres east and north of its first fix
        (:mod:`kalmix.io.geo`), latitudes beyond ±90° or longitudes beyond ±180° are refused, the
        forecasts come back in degrees and their standard deviations in metres (``std_east_m``,
        ``std_north_m``). None (the default): when the position names say so (``lat``/``lon``,
        ``latitude``/``longitude``, ...); True: the positions in the order latitude,
        longitude[, altitude] whatever their names; False: flat numbers.
    """

    n_experts: int = 40
    seed: int = 0
    length_unit: float | str = "auto"
    horizon: int = 1
    max_gap: float | None = None
    max_gap_factor: float = 3.0
    gap_reference: str = "spread"
    gap_min_steps: int = 4
    population_prior: bool = True
    lead_prior: bool = True
    calibration_prior: bool = True
    calibration_from_points: int = CalibrationParams._field_defaults["from_points"]
    options: dict = field(default_factory=dict)
    bank: str = DEFAULT_BANK["kind"]
    rule: str = DEFAULT_BANK["rule"]
    time_unit: float | None = None
    rule_options: dict = field(default_factory=dict)
    lead: float | None = None
    reach: float | str | None = "auto"
    gap_floor: float | str | None = "auto"
    lead_delay: float | None = None
    geographic: bool | None = None

    def __post_init__(self):
        from ..bank import BANK_KINDS

        self.horizon = check_horizon(self.horizon)
        for name in ("reach", "gap_floor"):
            value = getattr(self, name)
            if isinstance(value, str) and value.strip().lower() == "auto":
                setattr(self, name, "auto")
            elif isinstance(value, str):
                raise ValueError(f"{name}: expected a number, None or 'auto', got {value!r}")
        if self.gap_floor not in (None, "auto") and not (isinstance(self.gap_floor, numbers.Real)
                                                          and not isinstance(self.gap_floor, bool)
                                                          and self.gap_floor > 0):
            raise ValueError(f"gap_floor: expected a time step > 0, None or 'auto', got {self.gap_floor!r:.80}")
        for name in ("lead", "time_unit", "max_gap", "max_gap_factor", "reach", "lead_delay"):
            value = getattr(self, name)
            if name == "reach" and value == "auto":
                continue
            if value is not None and (isinstance(value, bool) or not isinstance(value, numbers.Real)):
                raise TypeError(f"{name}: expected a number, got {type(value).__name__} {value!r:.80}")
        if self.bank not in BANK_KINDS:
            raise ValueError(f"bank: expected one of {', '.join(BANK_KINDS)}, got {self.bank!r}")
        if self.lead is not None:
            self.lead = validate("lead", self.lead, LeadParams.CONSTRAINTS["time"])
            if self.horizon > 1:
                raise ValueError(f"lead and horizon: give one of them (a horizon H is the lead of H time units), "
                                 f"got lead={self.lead!r} and horizon={self.horizon!r}")
        if self.lead_delay is not None:
            self.lead_delay = float(self.lead_delay)   # a numpy scalar saves as its own type
        if self.max_gap is not None and not self.max_gap > 0:
            raise ValueError(f"max_gap: expected a time step > 0, got {self.max_gap!r}")
        if not self.max_gap_factor > 1:
            raise ValueError(f"max_gap_factor: expected a number > 1, got {self.max_gap_factor!r}")
        if isinstance(self.gap_min_steps, bool) or not isinstance(self.gap_min_steps, numbers.Integral) or not (
                1 <= self.gap_min_steps <= REFERENCE_INTERVALS):
            raise ValueError(f"gap_min_steps: expected an integer in [1, {REFERENCE_INTERVALS}], got "
                             f"{self.gap_min_steps!r:.80}")
        self.gap_min_steps = int(self.gap_min_steps)
        for name in ("population_prior", "lead_prior", "calibration_prior"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"{name}: expected True or False, got {type(value).__name__} {value!r:.80}")
            setattr(self, name, bool(value))
        if self.gap_reference not in GAP_REFERENCES:
            raise ValueError(f"gap_reference: expected one of {', '.join(map(repr, GAP_REFERENCES))}, got "
                             f"{self.gap_reference!r:.80}")
        if isinstance(self.length_unit, str) and self.length_unit.strip().lower() == "auto":
            self.length_unit = "auto"
        elif isinstance(self.length_unit, str):
            raise ValueError(f"length_unit: expected a number or 'auto', got {self.length_unit!r}")
        else:
            self.length_unit = check_length_unit(self.length_unit)
        if self.geographic is not None and not isinstance(self.geographic, (bool, np.bool_)):
            raise TypeError(f"geographic: expected True, False or None (detected from the position names), got "
                            f"{type(self.geographic).__name__} {self.geographic!r:.80}")
        if self.geographic is not None:
            self.geographic = bool(self.geographic)
        if self.time_unit is not None:
            validate("time_unit", self.time_unit, BANK_ARGUMENTS["time_unit"])
        if not isinstance(self.options, dict):
            raise TypeError(f"options: expected a dict of make_params arguments, got {self.options!r}")
        if not isinstance(self.rule_options, dict):
            raise TypeError(f"rule_options: expected a dict of the rule's parameters, got {self.rule_options!r}")
        # every bank argument is checked now, not at the first row (a lead against a time unit still to be
        # learned is checked when it is learned: here as one unit), on a plane: the coordinates are not known
        # yet, and a bank of the coordinated-turn Kalman filters alone needs two (a track of one is refused then)
        length = self.numeric_length_unit()
        make_params(1, self.n_experts, seed=self.seed, length_unit=length, **self.options)
        why = short_lead(self.lead, self.time_unit)   # (a learned unit comes here too: replace(config, time_unit=))
        if why is not None:
            warnings.warn(why, RuntimeWarning, stacklevel=3)
        unit = self.time_unit if self.time_unit is not None else (self.lead if self.lead is not None else 1.0)
        make_bank(2, self.bank, rule=self.rule, length_unit=length, time_unit=unit,
                  seed=self.seed, n_akf=self.n_experts, akf_options=self.options, lead=self.lead_time(),
                  rule_options=self.rule_options, reach=self.bank_reach(), lead_delay=self.lead_delay,
                  calibration_from_points=self.calibration_from_points)

    def bank_reach(self) -> float | None:
        """``reach`` as the bank takes it: None while it is ``"auto"`` (not settled yet)."""
        return None if self.reach == "auto" else self.reach

    def numeric_length_unit(self) -> float:
        """``length_unit``, or 1 while it is ``"auto"`` (not chosen yet)."""
        return 1.0 if self.length_unit == "auto" else float(self.length_unit)

    def lead_time(self) -> float | None:
        """The lead head's lead in time-column units: ``lead``, or ``horizon`` time units, or None."""
        if self.lead is not None:
            return self.lead
        return self.horizon * (self.time_unit or 1.0) if self.horizon > 1 else None
