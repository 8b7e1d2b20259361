"""Families of experts: homogeneous batches that meet the rest of a bank only as predictions.

- :mod:`.kinematic`: constant-velocity and constant-acceleration Kalman filters with
  the real time step between samples;
- :mod:`.ar`: adaptive autoregressive models of the velocity in real time (weighted least
  squares with forgetting, a persistence prior and a jump test for relocations);
- :mod:`.turn`: coordinated-turn extrapolation (the last turn rate and speed carried
  forward) in real time, in any dimension;
- :mod:`.ct`: coordinated-turn Kalman filters (an extended Kalman filter of position, velocity and
  turn rate) in real time, in the plane of the first two coordinates;
- :mod:`.akf`: the paper's state-model adaptive Kalman filters (frame-based).

Every family module has the same functions: ``init_state(params, n_targets, measurement_dim)``,
``forecast(params, state, time, frames=1) -> (means (N, K, p), variances)``,
``update(params, state, measurement, time, learn, active, restart) -> state``, and for reports
``expert_name(params, i, kind)`` and ``one_expert(params, i)`` (the parameters of expert ``i`` alone). A bank asks for a
forecast by both clocks at once, the time and the rows ahead; a time-based family reads the time,
a frame-based one the rows (its :attr:`FamilyKind.clock`). Every state has ``initialised (N,)``.

:data:`KINDS` maps a family kind to its parts; the compiled versions are in
:mod:`kalmix.core.compiled` (each kind's module there is named in its entry).
"""

from __future__ import annotations

from types import ModuleType
from typing import NamedTuple

from . import akf, ar, ct, kinematic, turn

__all__ = ["akf", "ar", "ct", "kinematic", "turn", "FamilyKind", "KINDS", "parts"]


class FamilyKind(NamedTuple):
    """A family kind's parts: what a bank and its engines need to know of it."""

    spec: ModuleType            # init_state, forecast, update: the numpy reference
    compiled: str               # its compiled driver, the module kalmix.core.compiled.<compiled> (needs numba)
    clock: str = "time"         # "time": forecasts at a time; "frames": so many rows ahead, whatever the time
    order: int | None = None    # the state's order the kind fixes (its compiled kernels are built for it)
    long_step: bool = False     # forecasts across a step longer than the bank's reach (kalmix.core.engine)
    warmup: int = 1             # learned rows of a track (segment) before its forecasts weigh (kalmix.core.engine)


#: Family kinds and their parts: kinematic CV / CA, adaptive AR of the velocity and coordinated turns in real
#: time, and the paper's AKF (frame-based). The warm-up rows: a kinematic state of order m is fitted by m rows
#: (position and velocity from two, the acceleration from a third); a turn needs a velocity (two rows; with no
#: turn rate yet it goes straight), as does a coordinated-turn filter (its velocity); the AR needs two
#: velocities (its first one is taken for a jump), and the AKF's state model a row past its first step.
KINDS = {
    "cv": FamilyKind(kinematic, "kinematic", order=2, long_step=True, warmup=2),
    "ca": FamilyKind(kinematic, "kinematic", order=3, warmup=3),
    "ar": FamilyKind(ar, "ar", warmup=3),
    "turn": FamilyKind(turn, "turn", warmup=2),
    "ct": FamilyKind(ct, "ct", warmup=2),
    "akf": FamilyKind(akf, "akf_driver", clock="frames", warmup=3),
}


def parts(name: str) -> FamilyKind:
    """The parts of the family kind ``name``; ``ValueError`` naming the kinds for another."""
    try:
        return KINDS[name]
    except (KeyError, TypeError):
        raise ValueError(f"kind: expected one of {', '.join(map(repr, KINDS))}, got {name!r}") from None
