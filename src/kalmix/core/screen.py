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
it needs no knowledge of the data's units: ``s`` is learned per target.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._libm import ordered_sum

__all__ = ["ScreenParams", "ScreenState", "init", "screen"]


class ScreenParams(NamedTuple):
    threshold: float = 1000.0   # inf disables the screen
    max_rejects: int = 3
    warmup: int = 5
    window: int = 50


class ScreenState(NamedTuple):
    position: np.ndarray   # (N, p) last accepted measurement (NaN before the first)
    velocity: np.ndarray   # (N, p) from the last two accepted measurements (0 before)
    time: np.ndarray       # (N,) time of the last accepted measurement
    scale: np.ndarray      # (N,) running mean distance s
    count: np.ndarray      # (N,) accepted distances in s
    rejects: np.ndarray    # (N,) outliers in a row
    outliers: np.ndarray   # (N,) outliers so far
    points: np.ndarray     # (N,) accepted rows since the (re)start, capped at 2 (2: the velocity is known)


def init(n_targets: int, measurement_dim: int) -> ScreenState:
    return ScreenState(np.full((n_targets, measurement_dim), np.nan), np.zeros((n_targets, measurement_dim)),
                       np.full(n_targets, np.nan), np.zeros(n_targets), np.zeros(n_targets),
                       np.zeros(n_targets), np.zeros(n_targets), np.zeros(n_targets))


def screen(params: ScreenParams, state: ScreenState, z, time, present, gap=None):
    """Screen one row per target. Returns ``(state, accept (N,), restart (N,))``.

    ``gap (N,)`` asks for a restart at this row (a time gap): the row is not tested; if it
    is missing, the screen (and the families) start again from the next present row.
    """
    gap = np.zeros(len(present), dtype=bool) if gap is None else np.asarray(gap, dtype=bool)
    started = state.points >= 1
    moving = state.points >= 2
    dt = np.where(started, time - state.time, 0.0)
    dt = np.where(np.isfinite(dt) & (dt > 0), dt, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        guess = state.position + state.velocity * dt[:, None]
        distance = np.sqrt(ordered_sum((z - guess) ** 2))   # in index order, as the kernel adds
    checked = present & moving & (state.count >= params.warmup) & ~gap
    with np.errstate(invalid="ignore"):
        wild = checked & ~(distance <= params.threshold * state.scale)
    rejects = np.where(wild, state.rejects + 1, 0.0)
    restart = (wild & (rejects >= params.max_rejects)) | gap
    outlier = wild & ~restart
    accept = present & ~outlier
    # accepted, not a restart: learn the distance and the velocity
    learn = accept & moving & ~restart & np.isfinite(distance)
    count = np.where(learn, np.minimum(state.count + 1, params.window), state.count)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(learn, state.scale + (distance - state.scale) / np.where(learn, count, 1.0), state.scale)
        step = (z - state.position) / np.where(dt > 0, dt, 1.0)[:, None]
    velocity = np.where((accept & started & ~restart & (dt > 0))[:, None], step, state.velocity)
    velocity = np.where(restart[:, None], 0.0, velocity)
    new = ScreenState(
        position=np.where(accept[:, None], z, state.position),
        velocity=velocity,
        time=np.where(accept, time, state.time),
        scale=scale,
        count=count,
        rejects=np.where(present | gap, np.where(restart, 0.0, rejects), state.rejects),
        outliers=state.outliers + outlier,
        points=np.where(restart, np.where(present, 1.0, 0.0),
                        np.where(accept, np.minimum(state.points + 1, 2.0), state.points)),
    )
    return new, accept, restart
