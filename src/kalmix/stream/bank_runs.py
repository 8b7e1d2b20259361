"""A :class:`~kalmix.streaming.TrackPredictor`'s bank and its runs of the engine: the bank built for the settings
(the length and time units, geographic positions, the backend), the tracks' states gathered for a run, and the
forecasts made from a state without learning (the next row's, and across a time gap's)."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from ..bank import make_bank
from ..core.engine import Bank, BankState, init_bank_state
from .gaps import silence_variance
from .times import column_seconds
from .units import LengthUnitWarning, estimate_length_unit, length_unit_fallback

BACKENDS = ("cpu", "gpu")


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and can run here; ``ValueError`` naming it otherwise."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    if backend == "gpu":
        try:
            from ..core.compiled import gpu
        except ImportError as error:   # pragma: no cover - numba missing
            raise ValueError(f"backend 'gpu': needs numba and numba-cuda (pip install 'kalmix[gpu]'): {error}") \
                from None
        if gpu.cuda is None:
            raise ValueError("backend 'gpu': numba-cuda is not installed (pip install 'kalmix[gpu]')")
        if not gpu.gpu_available():
            raise ValueError("backend 'gpu': no CUDA GPU found (numba-cuda sees none); use backend 'cpu'")
    return backend


class BankRuns:
    """The part of :class:`~kalmix.streaming.TrackPredictor` that builds its bank and runs the engine on it."""

    def _decide_geographic(self, names, dim: int | None = None) -> None:
        """Settle whether the positions are geographic (:attr:`axes`; ``config.geographic`` None: from the
        position ``names``) once the names or the number of coordinates ``dim`` are known (the state file keeps
        the names, so a resumed predictor settles it the same way)."""
        from ..io.geo import resolve_axes

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
        from ..bank import check_automatic_length_unit

        metres = " m" if self.axes is not None else ""
        if table is None:
            unit, why = 1.0, None
            text = length_unit_fallback(None, where, "length_unit", metres)
        else:
            unit, why = estimate_length_unit(table[["track_id", *names]].assign(time=column_seconds(table["time"])),
                                             names, geographic=self.axes is not None)
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
            from ..core.compiled import gpu

            gpu.check_bank(self.params)
        self.backend = backend

    def _ensure_params(self, measurement_dim: int) -> Bank:
        if self.params is None:
            if self.position_names is not None and len(self.position_names) != measurement_dim:
                raise ValueError(f"measurements: expected {len(self.position_names)} coordinates per row (the position "
                                 f"names {list(self.position_names)}), got {measurement_dim}")
            params = self._build(measurement_dim)
            if self.backend == "gpu":   # a bank the GPU engine cannot run fails here, before any row
                from ..core.compiled import gpu

                gpu.check_bank(params)
            self.params = params
        elif self.params.measurement_dim != measurement_dim:
            raise ValueError(f"measurements: expected {self.params.measurement_dim} coordinates per row "
                             f"(as before), got {measurement_dim}")
        return self.params

    def _build(self, measurement_dim: int) -> Bank:
        """The bank; until the time unit is learned, of a unit of 1 (a track's first row does not depend on it), or
        of the lead / MAX_HORIZON for a lead longer than MAX_HORIZON (checked against the unit once learned)."""
        from ..bank import MAX_HORIZON

        c = self.config
        # (a hair over lead / MAX_HORIZON: the lead in units must come out at most MAX_HORIZON after rounding)
        interim = 1.0 if c.lead is None else max(1.0, c.lead / MAX_HORIZON * (1.0 + 1e-9))
        return make_bank(measurement_dim, c.bank, rule=c.rule, length_unit=c.length_unit,
                         time_unit=interim if c.time_unit is None else c.time_unit, seed=c.seed, n_akf=c.n_experts,
                         akf_options=c.options, lead=c.lead_time(), rule_options=c.rule_options, reach=c.bank_reach(),
                         lead_delay=c.lead_delay, calibration_from_points=c.calibration_from_points)

    def _without_lead(self) -> Bank:
        """This predictor's bank without its lead head (kept while the bank is the same: the engine checks a
        state against a bank once per bank)."""
        if self._plain is None or self._plain[0] is not self.params:
            self._plain = (self.params, replace(self.params, lead=None))
        return self._plain[1]

    def _fresh(self) -> BankState:
        """A new track's state: its rule from the population prior (:mod:`.population`)."""
        return self.with_prior(init_bank_state(self.params, 1))

    def _new_states(self, n: int) -> BankState:
        """``n`` new targets' states (the same bits as :meth:`_fresh` each); the store shares their leaves."""
        if not self.states.shares_as_new():
            self.states.share_as_new(self._fresh())
        return self.with_prior(init_bank_state(self.params, n))

    def _states_or_fresh(self, tracks) -> BankState:
        """The states of ``tracks`` stacked (a copy), new tracks' as :meth:`_fresh`'s."""
        return self.states.gather(tracks, self._new_states)

    def _run(self, values, times, lengths, state, restart, ahead_times=None, bank=None):
        """The compiled engine (the numpy reference without numba, the GPU engine with ``backend="gpu"``), on
        this predictor's bank or ``bank``."""
        from ..core import engine
        from ..core.compiled import numba_available

        run = engine.run
        if self.backend == "gpu":
            from ..core.compiled import gpu

            run = gpu.run
        elif numba_available():
            from ..core.compiled import engine as compiled

            run = compiled.run
        return run(bank or self.params, values, times, state, lengths=lengths, restart=restart,
                   ahead_times=ahead_times)

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

    def _forecast_far(self, state: BankState, times, thresholds) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_forecast_next` across a time gap: the constant-velocity experts' extrapolation (weighted as
        the rule weighs them) and its interval, widened by what the silence adds (:func:`.gaps.silence_variance`,
        ``thresholds (N,)`` the tracks' gap thresholds); NaN for a bank without them (whose other time-based
        experts extrapolate fits made on the usual steps)."""
        bank = self._far_bank()
        if bank is None:
            shape = (len(np.atleast_1d(times)), self.params.measurement_dim)
            return np.full(shape, np.nan), np.full(shape, np.nan)
        times = np.asarray(times, dtype=np.float64)
        blank = np.full((1, len(times), self.params.measurement_dim), np.nan)
        result = self._run(blank, times[None, :], None, state, None, bank=bank)
        mean, std = result.forecasts[0], result.std[0]
        added = silence_variance(mean, state.screen.position, state.screen.time, times, thresholds)
        return mean, np.sqrt(std ** 2 + added[:, None])

    def output_columns(self) -> dict:
        """Output key (``pred``, ``std``, ``lead``, ``lead_std``) -> its columns' names: ``pred_<pos>``,
        ``std_<pos>``, ... (:func:`kalmix.io.columns.output_name`: no surrounding spaces); for geographic
        positions the standard deviations are in metres east, north (and up): ``std_east_m``, ``std_north_m``
        (``lead_std_east_m``, ``std<H>_east_m``)."""
        from ..io.columns import output_name

        names = [output_name(name) for name in self.position_names or ()]
        if self.axes is not None:
            from ..io.geo import std_names

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
