"""The glitch screen: a causal test that keeps one wild measurement from poisoning a track.

Before any expert or rule sees a row, each target's row is compared with a simple,
bank-independent extrapolation of its last accepted measurements (constant velocity
from the last two, over the real time step; the test starts once two rows are
accepted). With ``d`` the distance between the row
and that extrapolation and ``s`` the running mean of ``d`` over the accepted rows (the
last ~``window`` of them), a row with ``d > threshold * s`` is an **outlier** once the
target has ``warmup`` accepted distances: it is not learned (like a missing row) and is
counted. ``max_rejects`` outliers in a row mean the target really moved (an identity
switch, a relocation): that row is accepted as a **restart** (the families start again
from it, as after a time gap; the rule keeps what it learned).

The screen sees only measurements and times, so it is the same whatever the bank, and
it needs no knowledge of the data's units: ``s`` is learned per target. A distance below
``ZERO`` (1e-9) of the last accepted position's largest coordinate is rounding, i.e. 0. The screen tests a row
only once ``s`` is above that, or, for a target whose extrapolation has been exact (``s = 0``:
a simulated or interpolated track in uniform motion), once the distance it moves in the step,
``|v| dt``, is: ``threshold |v| dt`` is then the scale, so ``d > threshold^2 |v| dt`` (a million
steps) is an outlier. Without it a glitch on such a track would be learned by everything (one at
1e300 would ruin it for good); the square keeps a kick followed, not rejected: with
``threshold |v| dt`` alone, a ball rolling at 0.5 mm a row and kicked to 3 m a row would be
rejected twice and restarted. A
target at rest through its warm-up (the same position on every row: a moored vessel, a ball
before a kick, quantised positions) has neither, and every move would be an outlier; its first
moves are learned instead (so a glitch on a target at rest is learned too: with no motion there
is no scale to judge it by).

**The warm-up audit.** The rows that teach ``s`` are not tested, so a glitch among a
target's first ~7 rows would be learned by everything: the scale, the experts (whose fits
keep it), the rule (BOA's cumulative variance, which never forgets, would freeze its
learning rates) and the calibration. So once ``s`` has its ``warmup`` distances, they are
audited: if the largest is more than ``threshold`` times the smallest non-zero one (or is
not finite: a glitch beyond 1e154 overflows it), the warm-up held a glitch. (A glitch of size
G puts two or three of the distances at G to 2G and leaves the others clean; non-zero,
because quantised positions give distances of exactly 0.) Then the glitch is counted as an
outlier, ``s`` is learned again, and the row is a **cold restart**: it is forecast by the
rule and the calibration the target had, which then start again, as for a new target (they
do not learn the row; what is forecast after it uses the new ones), and the families start
again at the target's next present row. Every warm-up is audited: a target's first, and the
one after an audit.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._libm import ordered_sum
from .constraints import Integer, Real

__all__ = ["ScreenParams", "ScreenState", "init", "screen", "ZERO", "MAX_POINTS"]

#: A distance below this fraction of the last accepted position's largest coordinate (in absolute value) is
#: rounding: 0.
ZERO = 1e-9
#: The count of accepted rows since a target's (re)start stops here: the screen needs two (a velocity), the
#: bank's experts up to this many before their forecasts weigh (their kind's ``warmup``,
#: :data:`kalmix.core.families.KINDS`).
MAX_POINTS = 3.0


class ScreenParams(NamedTuple):
    threshold: float = 1000.0   # inf disables the screen
    max_rejects: int = 3
    warmup: int = 5
    window: int = 50

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`).
    CONSTRAINTS = {"threshold": Real(gt=1, inf_ok=True, hint="inf: no screen"), "max_rejects": Integer(ge=1)}


class ScreenState(NamedTuple):
    position: np.ndarray   # (N, p) last accepted measurement (NaN before the first)
    velocity: np.ndarray   # (N, p) from the last two accepted measurements (0 before)
    time: np.ndarray       # (N,) time of the last accepted measurement
    scale: np.ndarray      # (N,) running mean distance s
    count: np.ndarray      # (N,) accepted distances in s
    rejects: np.ndarray    # (N,) outliers in a row
    outliers: np.ndarray   # (N,) outliers so far
    points: np.ndarray     # (N,) accepted rows since the (re)start, capped at MAX_POINTS (>= 2: the velocity is
    #                        known); -1: the warm-up held a glitch, the families start again at the next present row
    low: np.ndarray        # (N,) smallest non-zero distance of the warm-up (inf before one; NaN once audited)
    high: np.ndarray       # (N,) largest distance of the warm-up (NaN once audited)


def init(n_targets: int, measurement_dim: int) -> ScreenState:
    return ScreenState(np.full((n_targets, measurement_dim), np.nan), np.zeros((n_targets, measurement_dim)),
                       np.full(n_targets, np.nan), np.zeros(n_targets), np.zeros(n_targets),
                       np.zeros(n_targets), np.zeros(n_targets), np.zeros(n_targets),
                       np.full(n_targets, np.inf), np.zeros(n_targets))


def screen(params: ScreenParams, state: ScreenState, z, time, present, gap=None):
    """Screen one row per target. Returns ``(state, accept (N,), restart (N,), cold (N,))``.

    ``gap (N,)`` asks for a restart at this row (a time gap): the row is not tested; if it
    is missing, the screen (and the families) start again from the next present row.
    ``cold``: an accepted row that ends a warm-up which held a glitch (see the module
    docstring): it is forecast by the rule and the calibration, which then start again without
    learning it; the families start again at the target's next present row (a restart).
    """
    gap = np.zeros(len(present), dtype=bool) if gap is None else np.asarray(gap, dtype=bool)
    pending_restart = state.points < 0   # the warm-up held a glitch: the families start again at the next row
    gap = gap | (pending_restart & present)
    started = state.points >= 1
    moving = state.points >= 2
    dt = np.where(started, time - state.time, 0.0)
    dt = np.where(np.isfinite(dt) & (dt > 0), dt, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        guess = state.position + state.velocity * dt[:, None]
        distance = np.sqrt(ordered_sum((z - guess) ** 2))   # in index order, as the kernel adds
    with np.errstate(invalid="ignore", over="ignore"):
        # the last accepted position's largest coordinate (a glitch must not set it); the max is exact in any order
        tiny = ZERO * np.max(np.abs(np.where(moving[:, None], state.position, 0.0)), axis=-1)
        # no error to judge by (a target in exact motion): threshold x the distance it moves in the step is the
        # scale, so only a jump of threshold^2 steps is an outlier (a kick may multiply a speed by thousands)
        motion = np.sqrt(ordered_sum((state.velocity * dt[:, None]) ** 2))
        reference = np.where(state.scale > tiny, state.scale, params.threshold * motion)
        checked = present & moving & (state.count >= params.warmup) & (reference > tiny) & ~gap
        wild = checked & ~(distance <= params.threshold * reference)
    rejects = np.where(wild, state.rejects + 1, 0.0)
    restart = (wild & (rejects >= params.max_rejects)) | gap
    outlier = wild & ~restart
    accept = present & ~outlier
    # accepted, not a restart: learn the distance and the velocity
    kept = accept & moving & ~restart
    learn = kept & np.isfinite(distance)
    count = np.where(learn, np.minimum(state.count + 1, params.window), state.count)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(learn, state.scale + (distance - state.scale) / np.where(learn, count, 1.0), state.scale)
        step = (z - state.position) / np.where(dt > 0, dt, 1.0)[:, None]
    velocity = np.where((accept & started & ~restart & (dt > 0))[:, None], step, state.velocity)
    velocity = np.where(restart[:, None], 0.0, velocity)
    # the warm-up audit (see the module docstring): the smallest non-zero distance and the largest (inf for one
    # that overflowed)
    pending = ~np.isnan(state.high)
    auditing = learn & pending
    with np.errstate(invalid="ignore"):
        low = np.where(auditing & (distance > tiny), np.minimum(state.low, distance), state.low)
    high = np.where(auditing, np.maximum(state.high, distance), state.high)
    high = np.where(kept & pending & ~np.isfinite(distance), np.inf, high)
    audited = auditing & (count >= params.warmup)
    glitch = audited & (high > params.threshold * low)
    points = np.where(restart, np.where(present, 1.0, np.where(pending_restart, -1.0, 0.0)),
                      np.where(accept, np.minimum(state.points + 1, MAX_POINTS), state.points))
    new = ScreenState(
        position=np.where(accept[:, None], z, state.position),
        velocity=velocity,
        time=np.where(accept, time, state.time),
        scale=np.where(glitch, 0.0, scale),
        count=np.where(glitch, 0.0, count),
        rejects=np.where(present | gap, np.where(restart, 0.0, rejects), state.rejects),
        outliers=state.outliers + outlier + glitch,
        points=np.where(glitch, -1.0, points),
        low=np.where(glitch, np.inf, np.where(audited, np.nan, low)),
        high=np.where(glitch, 0.0, np.where(audited, np.nan, high)),
    )
    return new, accept, restart, glitch
