"""A bank of expert families under one aggregation rule, and the loop over time (reference).

A :class:`Bank` is a tuple of families (each a homogeneous batch of experts, see
:mod:`kalmix.core.families`) and one aggregation rule (:mod:`kalmix.core.aggregators`).
They meet only in measurement space: at every row the families forecast the row's
measurement, ``(N, K_f, p)`` each, concatenated into ``(N, K, p)``; the rule's weights
combine them into the mixture's forecast; then the rule and the families learn the row.

Conventions of :func:`run` (the readable spec; :mod:`kalmix.core.compiled` gives the
same numbers fast, and is what every command uses):

- ``measurements (T, N, p)`` with NaN rows missing; ``times (T, N)`` in the time
  column's units (frame-based families ignore them);
- ``lengths (N,)``: target ``n`` has rows ``0 .. lengths[n] - 1``; later rows are
  padding, never fed to anything (outputs there are NaN);
- ``learn (T, N)``: rows to learn from (default: every present row). A row not learned
  still advances the frame-based families by one frame. Rows then pass the glitch screen
  (:mod:`kalmix.core.screen`): an outlier is not learned; a restart row starts the families
  again (the rule does not learn from it, and keeps what it learned before);
- output ``forecasts[t]`` is the mixture's forecast of row ``t`` made *before* seeing
  it (so the one-step error is ``measurements[t] - forecasts[t]``); with ``ahead_times``
  / ``ahead_frames``, ``ahead[t]`` is the forecast made *after* row ``t`` of the time
  ``ahead_times[t]`` (time-based families) or ``ahead_frames`` frames later
  (frame-based ones).

An expert sleeps (is left out of the weights and of the rule's learning) while its
forecast is not finite, e.g. before its first measurement.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from . import aggregators
from . import screen as glitch
from .families import akf, ar, kinematic

__all__ = ["Family", "Bank", "BankState", "EngineResult", "init_bank_state", "run", "FAMILY_KINDS", "FAMILY_MODULES",
           "check_run_arguments"]

#: Family kinds: kinematic CV / CA and adaptive AR of the velocity in real time, and the paper's
#: AKF (frame-based).
FAMILY_KINDS = ("cv", "ca", "ar", "akf")
#: Each kind's module (:mod:`kalmix.core.families`).
FAMILY_MODULES = {"cv": kinematic, "ca": kinematic, "ar": ar, "akf": akf}


@dataclass(frozen=True, eq=False)
class Family:
    """One family of a bank: ``kind`` in :data:`FAMILY_KINDS` and its parameters."""

    kind: str
    params: Any   # KinematicParams for cv / ca, ARParams for ar, MixtureParams for akf

    @property
    def n_experts(self) -> int:
        return self.params.n_experts

    @property
    def module(self):
        return FAMILY_MODULES[self.kind]


@dataclass(frozen=True, eq=False)
class Bank:
    """Families of experts and the rule that aggregates them. Build it with :func:`kalmix.bank.make_bank`."""

    measurement_dim: int
    families: tuple
    rule: str
    rule_params: Any
    description: dict | None = None
    screen_params: glitch.ScreenParams = glitch.ScreenParams()

    @property
    def n_experts(self) -> int:
        return sum(f.n_experts for f in self.families)

    @property
    def rule_module(self):
        return aggregators.RULES[self.rule]

    def slices(self) -> list[slice]:
        """Each family's columns in the ``(N, K, p)`` expert axis."""
        out, start = [], 0
        for f in self.families:
            out.append(slice(start, start + f.n_experts))
            start += f.n_experts
        return out


class BankState(NamedTuple):
    families: tuple   # one state per family
    rule: Any         # the rule's state
    screen: glitch.ScreenState   # the glitch screen's (kalmix.core.screen)


class EngineResult(NamedTuple):
    forecasts: np.ndarray              # (T, N, p) mixture forecast of each row, made before it
    state: BankState
    ahead: np.ndarray | None = None    # (T, N, p) forecast made after row t (ahead_times / frames)
    experts: np.ndarray | None = None  # (T, N, K, p) experts' forecasts of each row
    weights: np.ndarray | None = None  # (T, N, K) weights of each row's forecast
    expert_ahead: np.ndarray | None = None  # (T, N, K, p)


def init_bank_state(bank: Bank, n_targets: int) -> BankState:
    p = bank.measurement_dim
    return BankState(tuple(f.module.init_state(f.params, n_targets, p) for f in bank.families),
                     bank.rule_module.init(bank.rule_params, n_targets, bank.n_experts),
                     glitch.init(n_targets, p))


def check_run_arguments(bank: Bank, measurements, times, state, lengths):
    """The arguments of :func:`run` (and the compiled one) as arrays; ``ValueError`` naming the bad one.

    ``measurements (T, N, p)`` with ``p = bank.measurement_dim``; ``times`` broadcastable to
    ``(T, N)``; ``lengths (N,)``; ``state`` a :class:`BankState` of this bank for N targets.
    """
    z = np.asarray(measurements, dtype=np.float64)
    if z.ndim != 3:
        raise ValueError(f"measurements: expected shape (T, N, p) (rows, targets, coordinates), got {z.shape}")
    t_count, n, p = z.shape
    if p != bank.measurement_dim:
        raise ValueError(f"measurements: expected {bank.measurement_dim} coordinates per row (the bank's "
                         f"measurement_dim), got {p}")
    try:
        times = np.broadcast_to(np.asarray(times, dtype=np.float64), (t_count, n))
    except ValueError:
        raise ValueError(f"times: expected shape (T, N) = {(t_count, n)} or one that broadcasts to it, "
                         f"got {np.shape(times)}") from None
    if lengths is not None:
        lengths = np.asarray(lengths)
        if lengths.shape != (n,):
            raise ValueError(f"lengths: expected shape (N,) = ({n},), got {lengths.shape}")
    if state is not None:
        _check_state(bank, state, n)
    return z, times, lengths


#: Per bank, the shapes (after the target axis) of the first array of each part of its state.
_STATE_SHAPES: "weakref.WeakKeyDictionary[Bank, list]" = weakref.WeakKeyDictionary()


def _parts(state):
    """``(name, first array)`` of each family's state, the rule's and the screen's."""
    families, rule, screen = state
    return ([(f"state.families[{i}].{part._fields[0]}", part[0]) for i, part in enumerate(families)]
            + [(f"state.rule.{rule._fields[0]}", rule[0]), (f"state.screen.{screen._fields[0]}", screen[0])])


def _check_state(bank: Bank, state, n: int) -> None:
    """A state of another bank (other families, expert counts, rule) or of another number of targets
    is refused by name (the first array of each part is enough to tell; states come from this module)."""
    template = _STATE_SHAPES.get(bank)
    if template is None:
        template = _STATE_SHAPES[bank] = [np.shape(a)[1:] for _, a in _parts(init_bank_state(bank, 1))]
    try:
        given = _parts(state)
    except (TypeError, ValueError, AttributeError, IndexError):
        given = None
    if given is None or len(given) != len(template):
        raise ValueError(f"state: expected a BankState of this bank ({len(bank.families)} families, rule "
                         f"{bank.rule!r}), got {type(state).__name__} "
                         f"{'' if given is None else f'with {len(given) - 2} families'}".rstrip())
    for (name, value), shape in zip(given, template):
        if np.shape(value) != (n,) + shape:
            raise ValueError(f"state: {name} has shape {np.shape(value)}, expected {(n,) + shape} for {n} "
                             "targets of this bank (a state of another bank, or of other targets?)")


def _family_forecast(family: Family, state, time, frames: int):
    if family.kind == "akf":
        means, _ = akf.forecast(family.params, state, frames)
        return np.where(state.initialised[:, None, None], means, np.nan)
    means, _ = family.module.forecast(family.params, state, time)   # time-based: cv, ca, ar
    return np.where(state.initialised[:, None, None], means, np.nan)


def _family_update(family: Family, state, z, time, learn, active, restart):
    """Learn the row; a target that ``restart``s starts again from it (as after a time gap)."""
    if family.kind == "akf":
        if restart.any():
            fresh = akf.init_state(family.params, len(restart), z.shape[-1])
            state = type(state)(*(np.where(restart.reshape((-1,) + (1,) * (o.ndim - 1)), f, o)
                                  for f, o in zip(fresh, state)))
        return akf.update(family.params, state, z, learn, active)
    if restart.any():
        state = state._replace(initialised=state.initialised & ~restart)
    return family.module.update(family.params, state, z, time, learn)


def expert_forecasts(bank: Bank, state: BankState, time, frames: int = 1) -> np.ndarray:
    """Every expert's forecast ``(N, K, p)`` at ``time (N,)`` (time-based) / ``frames`` ahead (frame-based)."""
    return np.concatenate([_family_forecast(f, s, time, frames) for f, s in zip(bank.families, state.families)],
                          axis=1)


def mixture_forecast(bank: Bank, state: BankState, experts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rule's weights ``(N, K)`` and the mixture ``(N, p)`` (NaN where no expert is awake)."""
    awake = np.isfinite(experts).all(axis=-1)
    w = bank.rule_module.weights(bank.rule_params, state.rule, awake)
    mix = np.einsum("nk,nkp->np", w, np.where(awake[..., None], experts, 0.0))
    return w, np.where(awake.any(axis=-1)[:, None], mix, np.nan)


def step(bank: Bank, state: BankState, measurement, time, learn=None, active=None):
    """One row for every target: forecast it, then learn it. Returns ``(state, forecast, experts, weights)``."""
    z = np.asarray(measurement, dtype=np.float64)
    n = z.shape[0]
    time = np.broadcast_to(np.asarray(time, dtype=np.float64), (n,))
    active = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    present = np.isfinite(z).all(axis=-1) & active
    learn = present if learn is None else (np.asarray(learn, dtype=bool) & present)
    screened, accept, restart = glitch.screen(bank.screen_params, state.screen, np.where(learn[:, None], z, 0.0),
                                              time, learn)
    learn = learn & accept
    experts = expert_forecasts(bank, state, time)
    weights, mix = mixture_forecast(bank, state, experts)
    awake = np.isfinite(experts).all(axis=-1)
    rule_state = bank.rule_module.update(bank.rule_params, state.rule, experts, z, awake, learn & ~restart)
    families = tuple(_family_update(f, s, z, time, learn, active, restart)
                     for f, s in zip(bank.families, state.families))
    return BankState(families, rule_state, screened), mix, experts, weights


def run(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, record_experts: bool = False) -> EngineResult:
    """Reference loop over time (see the module docstring for the conventions)."""
    z, times, lengths = check_run_arguments(bank, measurements, times, state, lengths)
    t_count, n, p = z.shape
    state = init_bank_state(bank, n) if state is None else state
    lengths = np.full(n, t_count) if lengths is None else np.asarray(lengths)
    forecasts = np.full((t_count, n, p), np.nan)
    ahead = None if ahead_times is None else np.full((t_count, n, p), np.nan)
    experts_out = np.full((t_count, n, bank.n_experts, p), np.nan) if record_experts else None
    ahead_experts = np.full((t_count, n, bank.n_experts, p), np.nan) if record_experts and ahead is not None else None
    weights_out = np.full((t_count, n, bank.n_experts), np.nan) if record_experts else None
    for t in range(t_count):
        active = t < lengths
        row_learn = None if learn is None else learn[t]
        state, mix, experts, weights = step(bank, state, z[t], times[t], row_learn, active)
        forecasts[t] = np.where(active[:, None], mix, np.nan)
        if record_experts:
            experts_out[t] = np.where(active[:, None, None], experts, np.nan)
            weights_out[t] = np.where(active[:, None], weights, np.nan)
        if ahead is not None:
            later = expert_forecasts(bank, state, ahead_times[t], ahead_frames)
            _, mix_ahead = mixture_forecast(bank, state, later)
            ahead[t] = np.where(active[:, None], mix_ahead, np.nan)
            if ahead_experts is not None:
                ahead_experts[t] = np.where(active[:, None, None], later, np.nan)
    return EngineResult(forecasts, state, ahead, experts_out, weights_out, ahead_experts)
