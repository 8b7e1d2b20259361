"""The gap rule: causal detection of time gaps that start a new segment of a track (see :mod:`kalmix.streaming`,
which re-exports it), and what a forecast across such a gap is sure of (:func:`silence_variance`)."""

from __future__ import annotations

import math

import numpy as np

from .config import GAP_SPREAD_POWER, REFERENCE_INTERVALS, StreamConfig



def short_median(values) -> float:
    """``np.median`` of a short list, bit for bit, without numpy's per-call cost (called once a row)."""
    ordered = sorted(values)
    middle = len(ordered) // 2
    if len(ordered) % 2:
        return float(ordered[middle])
    return float((ordered[middle - 1] + ordered[middle]) / 2.0)


def _upper_quartile(values) -> float:
    """The ``"upper quartile"`` gap rule's reference interval: of ``n`` steps in increasing order the one at index
    ``3n // 4`` (the 13th of 16; of up to 4 steps, the largest)."""
    ordered = sorted(values)
    return float(ordered[min(len(ordered) - 1, 3 * len(ordered) // 4)])


def _spread_reference(values) -> float:
    """The ``"spread"`` gap rule's reference interval: the upper quartile (:func:`_upper_quartile`) times the
    spread of the steps, the upper quartile over the lower (index ``n // 4``: the 5th of 16) to the power
    :data:`GAP_SPREAD_POWER`. On a log scale the upper quartile plus 1.5 interquartile ranges, as Tukey's fence:
    a step beyond it (and the factor) is an outlier of the track's own sampling."""
    ordered = sorted(values)
    upper = float(ordered[min(len(ordered) - 1, 3 * len(ordered) // 4)])
    lower = float(ordered[len(ordered) // 4])
    return upper * (upper / lower) ** GAP_SPREAD_POWER


def silence_variance(mean, position, last_time, time, threshold) -> np.ndarray:
    """The variance ``(N,)`` that a silence adds to each coordinate of a forecast made across it.

    The experts learn a track's motion on its usual steps, where the process noise is lost in the measurement
    noise, so their intervals say little of how a velocity may change over hours or days. Across a silence the
    honest statement is that the velocity may have changed by about its own size: over the silence, white
    acceleration whose velocity change :math:`\\delta v` has :math:`E|\\delta v|^2 = |v|^2`, i.e. a variance
    :math:`|v|^2 / p` per coordinate, which leaves a position variance of :math:`|v|^2 \\Delta^2 / (3p)` per
    coordinate at the silence's end. With :math:`d = v \\Delta` the forecast's own displacement, ``mean (N, p)``
    minus the last accepted ``position (N, p)`` at ``last_time (N,)``, and :math:`\\Delta` the span from
    ``last_time`` to ``time (N,)``:

    .. math::  \\sigma^2 = \\frac{|d|^2}{3p} \\max\\Big(0, 1 - \\frac{\\tau}{\\Delta}\\Big),

    where :math:`\\tau` is the ``threshold (N,)`` of the gap rule: the track's own steps vouch for steps up to it,
    so only the part of the silence beyond it counts (the variance is 0 at the threshold, and about the full
    :math:`|d|^2 / (3p)` across a silence of many thresholds). 0 where any of these is unknown.
    """
    mean, position = np.asarray(mean, dtype=np.float64), np.asarray(position, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        span = np.asarray(time, dtype=np.float64) - np.asarray(last_time, dtype=np.float64)
        share = np.maximum(0.0, 1.0 - np.asarray(threshold, dtype=np.float64) / span)
        variance = ((mean - position) ** 2).sum(axis=-1) / (3.0 * mean.shape[-1]) * share
    return np.where(np.isfinite(variance) & (span > 0), variance, 0.0)


class SkippedRowWarning(RuntimeWarning):
    """A row was skipped because it had no time, or its time was not after its track's last time (said once per
    predictor)."""


class GapTracker:
    """Causal gap detection for one track (see the module docstring)."""

    __slots__ = ("last_time", "intervals", "segment", "jumped_from", "jump_counted", "glitches", "origin", "clock")

    def __init__(self, last_time: float | None = None, intervals=(), segment: int = -1,
                 jumped_from: float | None = None, jump_counted: bool = False, glitches: int = 0,
                 origin=None, clock=None):
        self.last_time = last_time
        self.intervals = list(intervals)
        self.segment = segment
        #: when the previous row jumped ahead (a gap, the track's first row, or its first step, which
        #: has no reference to be judged against): the time before it; else None
        self.jumped_from = jumped_from
        #: that jump's step went into ``intervals`` (the first step), to be taken back if it was wrong
        self.jump_counted = jump_counted
        #: rows that came back before a jump (the jump's timestamp was wrong)
        self.glitches = glitches
        #: geographic data: the origin (latitude, longitude, height) of the track's current frame
        #: (:func:`kalmix.io.geo.assign_frames`), None before its first fix
        self.origin = None if origin is None else tuple(float(v) for v in origin)
        #: a file's track whose clock restarted (:class:`kalmix.io.tables.ClockResets`): ``[shift, last time as
        #: given, first time of its current clock]``, for a resumed run to go on moving its times; else None
        self.clock = None if clock is None else [float(v) for v in clock]

    def copy(self) -> "GapTracker":
        return GapTracker(self.last_time, self.intervals, self.segment, self.jumped_from, self.jump_counted,
                          self.glitches, self.origin, self.clock)

    def threshold(self, config: StreamConfig) -> float:
        """A step longer than this starts a new segment."""
        if config.max_gap is None and len(self.intervals) < config.gap_min_steps:
            return math.inf   # (too few steps to tell the sampling's spread)
        return self._jump(config)

    def _jump(self, config: StreamConfig) -> float:
        """A step longer than this jumps ahead: a row that then comes back in between is a time glitch (the jump's
        timestamp was wrong). The gap threshold, but for a track with fewer than ``gap_min_steps`` steps."""
        if config.max_gap is not None:
            return float(config.max_gap)
        if not self.intervals or not math.isfinite(config.max_gap_factor):
            return math.inf
        if config.gap_reference == "median":   # state files before version 12
            own = config.max_gap_factor * short_median(self.intervals)
        elif config.gap_reference == "upper quartile":   # state files of versions 12 to 14
            own = config.max_gap_factor * _upper_quartile(self.intervals)
        else:
            own = config.max_gap_factor * _spread_reference(self.intervals)
        floor = config.gap_floor
        return own if floor is None or floor == "auto" else max(own, float(floor))

    def advance(self, time: float, config: StreamConfig) -> bool | None:
        """Register ``time``; True if it starts a new segment, None if out of order or not finite (skip: a NaN
        or infinite time never becomes the track's clock, which would skip every later row)."""
        if not math.isfinite(time):
            return None
        if self.last_time is None:
            self.last_time, self.segment = time, self.segment + 1
            self.jumped_from, self.jump_counted = -math.inf, False
            return True
        dt = time - self.last_time
        if not dt > 0:
            if self.jumped_from is not None and self.jumped_from < time < self.last_time and (
                    not self.jump_counted  # a gap or the first row: any row coming back in between
                    or self.last_time - self.jumped_from > config.max_gap_factor * (time - self.jumped_from)):
                # the previous row jumped ahead and this one comes back in between: that jump was a
                # wrong timestamp; the clock follows this row, which continues the jump's segment
                if self.jump_counted:
                    self.intervals.pop()
                self.last_time, self.jumped_from, self.jump_counted = time, None, False
                self.glitches += 1
                return False
            return None
        unjudged = not self.intervals and config.max_gap is None
        jump = dt > self._jump(config)   # (the reference interval, once a row)
        gap = jump and (config.max_gap is not None or len(self.intervals) >= config.gap_min_steps)   # threshold()
        self.jumped_from = self.last_time if jump or unjudged else None
        self.jump_counted = False
        if gap:
            self.segment += 1
        if len(self.intervals) < REFERENCE_INTERVALS and (not gap or config.max_gap is None):
            # while the reference is incomplete a gap's step goes into it too: otherwise a short first step
            # (10 ms among 33 ms frames) would make every later step a gap, kept out of the reference, and the
            # track would restart at every row. A row coming back inside that gap is still a wrong timestamp, as
            # after any gap (jump_counted stays False: the first step's test would lose such a row); the gap's
            # step then stays in the reference, where the median outvotes it.
            self.intervals.append(dt)
            self.jump_counted = unjudged
        self.last_time = time
        return gap

    def advance_many(self, times: np.ndarray, config: StreamConfig) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`advance` over ``times`` in order: codes ``(n,)`` int8 (1 a new segment, 0 continues,
        -1 skipped) and each row's segment ``(n,)``.

        The same state and answers as calling :meth:`advance` row by row, faster: once a track's
        reference intervals are complete its threshold is fixed, so a stretch of rows whose
        steps are positive and within it changes nothing but the clock, and is taken at once;
        every other row (a gap, a row out of order, the rows before the reference is complete)
        goes through :meth:`advance`.
        """
        n = len(times)
        codes = np.zeros(n, dtype=np.int8)
        segments = np.empty(n, dtype=np.int64)
        stops = threshold = None
        i = 0
        while i < n:
            if self.jumped_from is None and self.last_time is not None and len(self.intervals) >= REFERENCE_INTERVALS:
                if stops is None:   # complete intervals stay complete: the threshold no longer moves
                    threshold = self.threshold(config)
                    steps = np.diff(times, prepend=np.nan)
                    stops = np.flatnonzero(~((steps > 0) & (steps <= threshold)))
                step = float(times[i]) - self.last_time
                if step > 0 and step <= threshold:
                    k = np.searchsorted(stops, i, side="right")
                    end = int(stops[k]) if k < len(stops) else n
                    segments[i:end] = self.segment
                    self.last_time, self.jump_counted = float(times[end - 1]), False
                    i = end
                    continue
            new = self.advance(float(times[i]), config)
            codes[i] = -1 if new is None else int(new)
            segments[i] = self.segment
            i += 1
        return codes, segments

    def to_json(self) -> dict:
        out = {"last_time": self.last_time, "intervals": self.intervals, "segment": self.segment,
               "jumped_from": self.jumped_from, "jump_counted": self.jump_counted, "glitches": self.glitches}
        if self.origin is not None:
            out["origin"] = list(self.origin)
        if self.clock is not None:
            out["clock"] = list(self.clock)
        return out
