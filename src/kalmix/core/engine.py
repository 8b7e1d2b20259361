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
- ``restart (T, N)``: rows where the caller starts the families again (a time gap), as
  the screen's restarts: the row is forecast by the old state, the families start from
  it (from the next present row if it is missing), the rule and the calibration keep
  what they learned (a warm start);
- a row that ends a warm-up which held a glitch (the screen's audit) is a **cold** restart
  (:func:`cold_start`): forecast by the old state, then the rule, the calibration and the
  lead head's start again, without learning it; the families at the next present row;
- output ``forecasts[t]`` is the mixture's forecast of row ``t`` made *before* seeing
  it (so the one-step error is ``measurements[t] - forecasts[t]``), ``std[t]`` its
  calibrated standard deviation per coordinate (:mod:`kalmix.core.calibration`); with
  ``ahead_times`` / ``ahead_frames``, ``ahead[t]`` is the forecast made *after* row
  ``t`` of the time ``ahead_times[t]`` (time-based families) or ``ahead_frames`` frames
  later (frame-based ones), with the one-step weights;
- a bank with a lead (:mod:`kalmix.core.lead`) also gives ``lead[t]`` / ``lead_std[t]``,
  the forecast made after row ``t`` for ``times[t] + lead`` (or ``ahead_times[t]`` when
  given; ``lead.frames`` rows for frame-based families, whatever ``ahead_frames``) with the
  weights and intervals learned on lead errors (blended with the one-step weights' forecast,
  :func:`kalmix.core.lead.blend`); ``ahead`` is then the same forecast with the one-step weights.

An expert sleeps (is left out of the weights and of the rule's learning) while its
forecast is not finite, e.g. before its first measurement.

**Warm-up.** An expert's forecasts weigh once its target's track (since its last (re)start) has given it
its kind's ``warmup`` learned rows (:data:`kalmix.core.families.KINDS`: 2 for CV and turn, 3 for CA, AR and
the AKF): before, the one-step weights leave it out (it sleeps for that forecast), if an expert warmed up is
awake there; while none is, every expert forecasts. On a track's third row a CA fitted to two points, an AR
that took its first velocity for a jump or an AKF one step into its model can miss by orders of magnitude more
than the CV, and one such row would set BOA's scale of the losses for the rest of a short track. The count is
the glitch screen's accepted rows, known before the row; the experts learn every row, and the lead head sees
every expert (:func:`warmed_up`).

**Reach** (off unless the bank has one: ``make_bank(..., reach=...)``). The one-step weights
are learned mostly on a track's usual steps. Across a step longer than the bank's ``reach``
(time-column units, from the target's last learned row to the forecast's time, once it has two
learned rows: :func:`span`), only the CV experts (:data:`LONG_STEP_KINDS`) forecast for the
one-step weights (the others sleep for that forecast), if any is awake: on tracks sampled at
irregular intervals the experts that extrapolate a fitted derivative or model (CA, AR, turn,
the frame-based AKF) can be off by orders of magnitude there. The experts themselves learn the
row as usual, and the lead head, which learns its own weights on its own horizon, sees every
expert (:func:`within_reach`).
"""

from __future__ import annotations

import math
import numbers
import weakref
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from . import aggregators, calibration
from . import lead as lead_head
from . import screen as glitch
from .families import KINDS, FamilyKind
from .families import parts as family_parts

__all__ = ["Family", "Bank", "BankState", "EngineResult", "StepOutput", "init_bank_state", "run", "step", "forecast",
           "cold_start", "FAMILY_KINDS", "FAMILY_MODULES", "LONG_STEP_KINDS", "span", "within_reach", "warmed_up",
           "for_weights",
           "check_run_arguments", "check_horizon", "MAX_HORIZON", "tree_map", "tree_leaves"]

#: Largest prediction horizon (frames ahead). A prediction H frames ahead costs H - 1
#: matrix-vector products per expert and stream, so the bound keeps every call's cost bounded;
#: 10 000 frames is 10 s at 1 kHz or 5.5 min at 30 fps, past any useful motion forecast, and with
#: the default spectral-radius guard (1.02) the extrapolation stays finite there
#: (1.02**10 000 ~ 1e86), which it does not at 10**6 (NaN).
MAX_HORIZON = 10_000

#: Family kinds (:data:`kalmix.core.families.KINDS`, the registry of their parts): kinematic CV / CA, adaptive AR
#: of the velocity and coordinated turns in real time, and the paper's AKF (frame-based).
FAMILY_KINDS = tuple(KINDS)
#: Each kind's module (:mod:`kalmix.core.families`).
FAMILY_MODULES = {name: entry.spec for name, entry in KINDS.items()}
#: The kinds whose one-step forecasts are used across a step longer than the bank's reach.
LONG_STEP_KINDS = tuple(name for name, entry in KINDS.items() if entry.long_step)


@dataclass(frozen=True, eq=False)
class Family:
    """One family of a bank: ``kind`` in :data:`FAMILY_KINDS` and its parameters."""

    kind: str
    params: Any   # KinematicParams for cv / ca, ARParams for ar, TurnParams for turn, MixtureParams for akf

    def __post_init__(self):
        order, got = family_parts(self.kind).order, getattr(self.params, "order", None)
        if order is not None and got != order:
            raise ValueError(f"a {self.kind!r} family has order {order} (its state: position, velocity"
                             f"{', acceleration' if order == 3 else ''}); got order {got!r}")

    @property
    def n_experts(self) -> int:
        return self.params.n_experts

    @property
    def parts(self) -> FamilyKind:
        """The kind's parts (:data:`kalmix.core.families.KINDS`)."""
        return KINDS[self.kind]

    @property
    def module(self):
        """The kind's numpy reference (:mod:`kalmix.core.families`)."""
        return KINDS[self.kind].spec


@dataclass(frozen=True, eq=False)
class Bank:
    """Families of experts and the rule that aggregates them. Build it with :func:`kalmix.bank.make_bank`.

    A bank and its families' parameters are values: make another (``make_bank``, ``dataclasses.replace``,
    ``params._replace``) rather than change their arrays in place; the compiled engine keeps packed copies
    of an AKF family's parameters from call to call (:func:`kalmix.core.compiled.akf_driver.constants`).
    """

    measurement_dim: int
    families: tuple
    rule: str
    rule_params: Any
    description: dict | None = None
    screen_params: glitch.ScreenParams = glitch.ScreenParams()
    calibration_params: calibration.CalibrationParams = calibration.CalibrationParams()
    lead: lead_head.LeadParams | None = None   # the lead head (kalmix.core.lead), if any
    reach: float = np.inf   # time-column units; across a longer step only LONG_STEP_KINDS forecast (see above)

    @property
    def n_experts(self) -> int:
        return sum(f.n_experts for f in self.families)

    def far_experts(self) -> np.ndarray | None:
        """``(K,)`` bool: the experts that sleep across a step over the reach; None when none ever does
        (an infinite reach, or a bank without experts of :data:`LONG_STEP_KINDS` or without others)."""
        if not np.isfinite(self.reach):
            return None
        far = np.concatenate([np.full(f.n_experts, not f.parts.long_step) for f in self.families])
        return far if far.any() and not far.all() else None

    def warmup_rows(self) -> np.ndarray | None:
        """``(K,)`` float: the learned rows each expert's track needs before its forecasts weigh (its kind's
        ``warmup``, see the module docstring); None when they are all the same (then no expert ever sleeps
        for it)."""
        rows = np.concatenate([np.full(f.n_experts, float(f.parts.warmup)) for f in self.families])
        return rows if rows.size and rows.min() < rows.max() else None

    @property
    def rule_module(self):
        return aggregators.RULES[self.rule]

    @property
    def lead_rule_params(self):
        """The lead head's rule parameters: the rule's, with a delayed-feedback rule's ``delay`` (BOA's)
        multiplied by the lead's (:class:`~kalmix.core.lead.LeadParams`; ``make_bank``: its frames, the
        forecasts the head issues per feedback it receives), and BOA's ``clip`` off: the lead's errors are
        learned whole, as a large H-step miss is a change of motion the experts differ on, not a surprise
        (in the ablation, clipping them makes the lead forecasts worse)."""
        params = self.rule_params
        if self.lead is None or "delay" not in params._fields:
            return params
        return params._replace(delay=params.delay * self.lead.delay,
                               **({"clip": math.inf} if "clip" in params._fields else {}))

    @property
    def blend_rule_params(self):
        """The rule parameters of the lead head's blend (:func:`kalmix.core.lead.blend`): the lead head's
        (:attr:`lead_rule_params`, BOA's ``clip`` off) at the one-step rule's ``delay``, not the lead's."""
        params = self.lead_rule_params
        return params._replace(delay=self.rule_params.delay) if "delay" in params._fields else params

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
    calibration: calibration.CalibrationState   # of the one-step forecasts (kalmix.core.calibration)
    lead: lead_head.LeadState | None = None     # the lead head's (kalmix.core.lead), if the bank has one


class EngineResult(NamedTuple):
    forecasts: np.ndarray              # (T, N, p) mixture forecast of each row, made before it
    state: BankState
    ahead: np.ndarray | None = None    # (T, N, p) forecast made after row t (ahead_times / frames)
    experts: np.ndarray | None = None  # (T, N, K, p) experts' forecasts of each row
    weights: np.ndarray | None = None  # (T, N, K) weights of each row's forecast
    expert_ahead: np.ndarray | None = None  # (T, N, K, p)
    std: np.ndarray | None = None           # (T, N, p) calibrated standard deviation of ``forecasts``
    ahead_std: np.ndarray | None = None     # (T, N, p) of ``ahead``
    lead: np.ndarray | None = None          # (T, N, p) lead forecast made after row t (bank.lead)
    lead_std: np.ndarray | None = None      # (T, N, p)
    covariance: np.ndarray | None = None    # (T, N, p, p) of ``forecasts`` (record_covariance)
    lead_covariance: np.ndarray | None = None  # (T, N, p, p) of ``lead`` (record_covariance)


def tree_map(function, *trees):
    """``function`` over the arrays of nested (named) tuples of the same structure (a state); None stays None."""
    first = trees[0]
    if first is None:
        return None
    if isinstance(first, tuple):
        mapped = [tree_map(function, *parts) for parts in zip(*trees)]
        return type(first)(*mapped) if hasattr(first, "_fields") else tuple(mapped)
    return function(*trees)


def tree_leaves(tree, prefix="state"):
    """``[(name, array)]`` of a state tree, names like ``state/families/0/mean`` (None parts have none)."""
    if tree is None:
        return []
    if isinstance(tree, tuple):
        names = tree._fields if hasattr(tree, "_fields") else [str(i) for i in range(len(tree))]
        return [leaf for name, part in zip(names, tree) for leaf in tree_leaves(part, f"{prefix}/{name}")]
    return [(prefix, tree)]


def init_bank_state(bank: Bank, n_targets: int) -> BankState:
    p = bank.measurement_dim
    return BankState(tuple(f.module.init_state(f.params, n_targets, p) for f in bank.families),
                     bank.rule_module.init(bank.rule_params, n_targets, bank.n_experts),
                     glitch.init(n_targets, p),
                     calibration.init(bank.calibration_params, n_targets, bank.n_experts, p),
                     None if bank.lead is None else lead_head.init(bank, n_targets))


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
        times = np.asarray(times, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"times: expected numbers, shape (T, N) = {(t_count, n)} or one that broadcasts to it, "
                         f"got {times!r:.80}") from None
    try:
        times = np.broadcast_to(times, (t_count, n))
    except ValueError:
        raise ValueError(f"times: expected shape (T, N) = {(t_count, n)} or one that broadcasts to it, "
                         f"got {np.shape(times)}") from None
    if lengths is not None:
        lengths = np.asarray(lengths)
        if lengths.shape != (n,):
            raise ValueError(f"lengths: expected shape (N,) = ({n},), got {lengths.shape}")
        if not (np.issubdtype(lengths.dtype, np.integer) or (np.issubdtype(lengths.dtype, np.floating)
                                                             and np.all(lengths == np.round(lengths)))):
            raise ValueError(f"lengths: expected whole numbers of rows, got {lengths[:8]!r}")
        # 0 .. T rows (a length over T is every row, one under 0 none, as row t runs where t < length): int64, so
        # that the compiled engine's cast of a length of 2**63 or more does not wrap around
        if lengths.dtype != np.int64 or (n and (lengths.min() < 0 or lengths.max() > t_count)):
            lengths = np.clip(lengths, 0, t_count).astype(np.int64)
    if state is not None:
        _check_state(bank, state, n)
    return z, times, lengths


def check_run_options(shape, learn, ahead_times, ahead_frames):
    """``learn`` and ``ahead_times`` of :func:`run` broadcast to ``shape`` = (T, N) (None stays None), and
    ``ahead_frames`` an integer >= 1; ``ValueError`` naming the bad one. Both engines take them so."""
    out = []
    for name, value, dtype in (("learn", learn, bool), ("ahead_times", ahead_times, np.float64)):
        if value is None:
            out.append(None)
            continue
        try:
            out.append(np.broadcast_to(np.asarray(value, dtype=dtype), shape))
        except (ValueError, TypeError):
            raise ValueError(f"{name}: expected shape (T, N) = {tuple(shape)} or one that broadcasts to it, "
                             f"got {np.shape(value)}") from None
    if isinstance(ahead_frames, bool) or not isinstance(ahead_frames, (int, np.integer)) or ahead_frames < 1:
        raise ValueError(f"ahead_frames: expected an integer >= 1, got {ahead_frames!r}")
    return out[0], out[1], int(ahead_frames)


#: Per bank, the shapes (after the target axis) of the first array of each part of its state.
_STATE_SHAPES: "weakref.WeakKeyDictionary[Bank, list]" = weakref.WeakKeyDictionary()


def _parts(state):
    """``(name, first array)`` of each family's state, the rule's, the screen's, the calibration's, the lead's."""
    families, rule, screen, cal, lead = state
    parts = ([(f"state.families[{i}].{part._fields[0]}", part[0]) for i, part in enumerate(families)]
             + [(f"state.rule.{rule._fields[0]}", rule[0]), (f"state.screen.{screen._fields[0]}", screen[0]),
                (f"state.calibration.{cal._fields[0]}", cal[0])])
    if lead is not None:
        parts += [("state.lead.rule", lead.rule[0]), ("state.lead.pending", lead.pending)]
    return parts


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
                         f"{'' if given is None else f'with {len(state.families)} families'}".rstrip())
    for (name, value), shape in zip(given, template):
        if np.shape(value) != (n,) + shape:
            raise ValueError(f"state: {name} has shape {np.shape(value)}, expected {(n,) + shape} for {n} "
                             "targets of this bank (a state of another bank, or of other targets?)")


def _family_forecast(family: Family, state, time, frames: int):
    """The family's experts' forecasts at ``time`` / ``frames`` ahead (its clock's), NaN before a target's start."""
    means, _ = family.module.forecast(family.params, state, time, frames)
    return np.where(state.initialised[:, None, None], means, np.nan)


def expert_forecasts(bank: Bank, state: BankState, time, frames: int = 1) -> np.ndarray:
    """Every expert's forecast ``(N, K, p)`` at ``time (N,)`` (time-based) / ``frames`` ahead (frame-based)."""
    return np.concatenate([_family_forecast(f, s, time, frames) for f, s in zip(bank.families, state.families)],
                          axis=1)


def check_horizon(value, name: str = "horizon") -> int:
    """``value`` as an int in [1, :data:`MAX_HORIZON`]; ``ValueError`` naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 1 <= value <= MAX_HORIZON:
        raise ValueError(f"{name}: expected an integer in [1, {MAX_HORIZON}], got {value!r}")
    return int(value)


def forecast(bank: Bank, state: BankState, time, frames: int = 1, *, lead: bool = False):
    """Predict without learning: the mixture's mean ``(N, p)`` and covariance ``(N, p, p)`` at ``time (N,)``.

    Time-based families extrapolate to ``time``, frame-based ones ``frames`` rows ahead.
    The one-step weights and calibration are used, or the lead head's (``lead=True``, for a bank
    with a lead: its forecast blended with the one-step weights', :func:`kalmix.core.lead.blend`).
    The state is not changed.

    ``frames`` is an integer in [1, MAX_HORIZON]; ``time`` a finite time (or one per target), at
    or after each target's last learned row; ``ValueError`` naming the argument otherwise.
    """
    frames = check_horizon(frames, "frames")
    try:
        n = len(state.screen.time)
    except (AttributeError, TypeError):
        raise ValueError(f"state: expected a BankState of this bank, got {type(state).__name__}") from None
    _check_state(bank, state, n)
    if lead and state.lead is None:
        raise ValueError("lead=True: this bank has no lead head (make_bank(..., lead=...))")
    try:
        time = np.broadcast_to(np.asarray(time, dtype=np.float64), (n,))
    except (TypeError, ValueError):
        raise ValueError(f"time: expected a number or one per target, shape ({n},), got {time!r:.80}") from None
    bad = np.zeros(n, dtype=bool)
    if any(family.parts.clock == "time" for family in bank.families):   # (frame-based ones do not read it)
        bad = ~np.isfinite(time)
        with np.errstate(invalid="ignore"):
            bad |= time < state.screen.time   # a target not started (NaN there) takes any finite time
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"time: expected finite times at or after each target's last learned row, got "
                         f"{float(time[i])!r} for target {i} (last learned row at {float(state.screen.time[i])!r})")
    experts = expert_forecasts(bank, state, time, frames)
    _, mean, cov = lead_head.forecast(bank, state, for_weights(bank, experts, state.screen, time))
    if lead:
        _, lead_mean, lead_cov = lead_head.forecast(bank, state.lead, experts, lead=True)
        mean, cov, _ = lead_head.blend(bank, state.lead, lead_mean, lead_cov, mean)
    return mean, cov


def span(screen: glitch.ScreenState, time):
    """Time from each target's last learned row (the screen's) to ``time``; NaN while the target has fewer than
    two learned rows since its (re)start: from one position no expert extrapolates anything yet."""
    return np.where(screen.points >= 2, time - screen.time, np.nan)


def within_reach(bank: Bank, experts, span):
    """``experts (..., K, p)`` as the one-step weights see them: where the ``span (...)`` (time from the
    target's last learned row to the forecast's time) is over ``bank.reach``, the experts not of
    :data:`LONG_STEP_KINDS` are NaN (asleep), if one of those kinds is awake there. Returns ``experts``
    itself when nothing changes (the compiled engine passes blocks of rows ``(T, N, K, p)``)."""
    far = bank.far_experts()
    if far is None:
        return experts
    with np.errstate(invalid="ignore"):
        beyond = np.asarray(span) > bank.reach
    if not beyond.any():
        return experts
    beyond = beyond & np.isfinite(experts[..., ~far, :]).all(axis=-1).any(axis=-1)
    if not beyond.any():
        return experts
    return np.where((beyond[..., None] & far)[..., None], np.nan, experts)


def warmed_up(bank: Bank, experts, points):
    """``experts (..., K, p)`` as the one-step weights see them at the warm-up: where the target's learned rows
    since its (re)start ``points (...)`` (the glitch screen's, before the forecast) are fewer than an expert's
    :meth:`Bank.warmup_rows`, the expert is NaN (asleep), if an expert with enough rows is awake there. Returns
    ``experts`` itself when nothing changes."""
    rows = bank.warmup_rows()
    if rows is None:
        return experts
    cold = np.asarray(points)[..., None] < rows   # (..., K)
    ready = (~cold & np.isfinite(experts).all(axis=-1)).any(axis=-1)
    asleep = cold & ready[..., None]
    if not asleep.any():
        return experts
    return np.where(asleep[..., None], np.nan, experts)


def for_weights(bank: Bank, experts, screen: glitch.ScreenState, time):
    """``experts (N, K, p)`` forecasting ``time (N,)`` as the one-step weights see them, from the screen's state
    before the forecast: :func:`warmed_up`, then :func:`within_reach`."""
    return within_reach(bank, warmed_up(bank, experts, screen.points), span(screen, time))


class StepOutput(NamedTuple):
    forecast: np.ndarray     # (N, p) of the row, made before it
    covariance: np.ndarray   # (N, p, p)
    experts: np.ndarray      # (N, K, p)
    weights: np.ndarray      # (N, K)
    ahead_experts: np.ndarray | None = None   # (N, K, p) after the row, for the lead (bank.lead) or ahead time
    lead: np.ndarray | None = None            # (N, p) lead forecast (bank.lead)
    lead_covariance: np.ndarray | None = None
    ahead: np.ndarray | None = None           # (N, p) the one-step weights' forecast of ``ahead_experts``
    ahead_covariance: np.ndarray | None = None


def cold_start(bank: Bank, state: BankState, cold) -> BankState:
    """``state`` with the rule, the calibration and the lead head's rule and calibration of the ``cold (N,)``
    targets as new (the screen's cold restart, :mod:`kalmix.core.screen`); a lead forecast still pending is
    dropped by the restart itself."""
    cold = np.asarray(cold, dtype=bool)
    if not cold.any():
        return state
    n, k, p = len(cold), bank.n_experts, bank.measurement_dim

    def fresh(new, old):
        return type(old)(*(np.where(cold.reshape((-1,) + (1,) * (o.ndim - 1)), a, o) for a, o in zip(new, old)))

    rule = lambda old: fresh(bank.rule_module.init(bank.rule_params, n, k), old)  # noqa: E731
    cal = lambda old: fresh(calibration.init(bank.calibration_params, n, k, p), old)  # noqa: E731
    head = state.lead
    if head is not None:
        head = head._replace(rule=rule(head.rule), calibration=cal(head.calibration),
                             blend=fresh(lead_head.init_blend(bank, n), head.blend))
    return state._replace(rule=rule(state.rule), calibration=cal(state.calibration), lead=head)


def step(bank: Bank, state: BankState, measurement, time, learn=None, active=None, ahead_time=None,
         ahead_frames: int = 1, restart=None):
    """One row for every target: forecast it, then learn it. Returns ``(state, StepOutput)``.

    With a lead head, the forecasts after the row for ``time + lead`` (or ``ahead_time``:
    e.g. the time of the row ``lead.frames`` later, known in a file) are made and the lead
    head learns; else ``ahead_time`` asks for the experts' forecasts after the row at that
    time (``ahead_frames`` for frame-based ones).
    ``restart (N,)`` starts the families again at this row (see :func:`run`).
    """
    z = np.asarray(measurement, dtype=np.float64)
    n = z.shape[0]
    time = np.broadcast_to(np.asarray(time, dtype=np.float64), (n,))
    active = np.ones(n, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    present = np.isfinite(z).all(axis=-1) & active
    learn = present if learn is None else (np.asarray(learn, dtype=bool) & present)
    gap = np.zeros(n, dtype=bool) if restart is None else (np.asarray(restart, dtype=bool) & active)
    screened, accept, restart, cold = glitch.screen(bank.screen_params, state.screen,
                                                    np.where(learn[:, None], z, 0.0), time, learn, gap)
    learn = learn & accept
    experts = expert_forecasts(bank, state, time)
    mixed = for_weights(bank, experts, state.screen, time)
    awake = np.isfinite(mixed).all(axis=-1)
    weights, mix, cov = lead_head.forecast(bank, state, mixed)
    go = learn & ~restart & ~cold
    rule_state = bank.rule_module.update(bank.rule_params, state.rule, mixed, z, awake, go)
    if restart.any() and hasattr(bank.rule_module, "restart"):
        rule_state = bank.rule_module.restart(bank.rule_params, rule_state, restart)
    cal_state = calibration.update(bank.calibration_params, state.calibration, weights, mixed, awake, z,
                                   go & calibration.learns(bank.calibration_params, state.screen.points))
    # a target that restarts starts its families again from this row (as after a time gap)
    families = tuple(f.module.update(f.params, s, z, time, learn, active, restart)
                     for f, s in zip(bank.families, state.families))
    # a cold restart (the screen's warm-up audit): the row was forecast by the old rule and calibration; what is
    # forecast after it (ahead, lead) and everything later by new ones
    new = cold_start(bank, BankState(families, rule_state, screened, cal_state, state.lead), cold)
    out = StepOutput(mix, cov, experts, weights)
    if bank.lead is not None:
        target = time + bank.lead.time if ahead_time is None else np.broadcast_to(ahead_time, (n,))
        head = lead_head.learn(bank, new.lead, z, time, go)
        later = expert_forecasts(bank, new, target, bank.lead.frames)
        _, one_mix, one_cov = lead_head.forecast(bank, new, for_weights(bank, later, new.screen, target))
        _, lead_mix, lead_cov = lead_head.forecast(bank, head, later, lead=True)
        lead_mix, lead_cov, candidates = lead_head.blend(bank, head, lead_mix, lead_cov, one_mix)
        head = lead_head.push(bank, head, later, target, learn & (state.screen.points >= 1), restart, lead_mix,
                              _std(lead_cov), candidates)
        new = new._replace(lead=head)
        out = out._replace(ahead_experts=later, lead=lead_mix, lead_covariance=lead_cov, ahead=one_mix,
                           ahead_covariance=one_cov)
    elif ahead_time is not None:
        later = expert_forecasts(bank, new, ahead_time, ahead_frames)
        _, one_mix, one_cov = lead_head.forecast(bank, new, for_weights(bank, later, new.screen, ahead_time))
        out = out._replace(ahead_experts=later, ahead=one_mix, ahead_covariance=one_cov)
    return new, out


def run(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, record_experts: bool = False,
        record_covariance: bool = False, restart=None) -> EngineResult:
    """Reference loop over time (see the module docstring for the conventions)."""
    z, times, lengths = check_run_arguments(bank, measurements, times, state, lengths)
    learn, ahead_times, ahead_frames = check_run_options(z.shape[:2], learn, ahead_times, ahead_frames)
    restart = check_restart(restart, z.shape[:2])
    t_count, n, p = z.shape
    state = init_bank_state(bank, n) if state is None else state
    lengths = np.full(n, t_count) if lengths is None else np.asarray(lengths)
    nan = lambda *shape: np.full(shape, np.nan)  # noqa: E731
    forecasts, std = nan(t_count, n, p), nan(t_count, n, p)
    with_ahead = ahead_times is not None or bank.lead is not None
    ahead = nan(t_count, n, p) if with_ahead else None
    ahead_std = nan(t_count, n, p) if with_ahead else None
    lead = nan(t_count, n, p) if bank.lead is not None else None
    lead_std = nan(t_count, n, p) if bank.lead is not None else None
    k = bank.n_experts
    experts_out = nan(t_count, n, k, p) if record_experts else None
    ahead_experts = nan(t_count, n, k, p) if record_experts and with_ahead else None
    weights_out = nan(t_count, n, k) if record_experts else None
    covariance = nan(t_count, n, p, p) if record_covariance else None
    lead_covariance = nan(t_count, n, p, p) if record_covariance and lead is not None else None
    for t in range(t_count):
        active = t < lengths
        row_learn = None if learn is None else learn[t]
        state, out = step(bank, state, z[t], times[t], row_learn, active,
                          None if ahead_times is None else ahead_times[t], ahead_frames,
                          None if restart is None else restart[t])
        on = active[:, None]
        forecasts[t] = np.where(on, out.forecast, np.nan)
        std[t] = np.where(on, _std(out.covariance), np.nan)
        if record_covariance:
            covariance[t] = np.where(on[..., None], out.covariance, np.nan)
        if record_experts:
            experts_out[t] = np.where(on[..., None], out.experts, np.nan)
            weights_out[t] = np.where(on, out.weights, np.nan)
        if with_ahead:
            ahead[t] = np.where(on, out.ahead, np.nan)
            ahead_std[t] = np.where(on, _std(out.ahead_covariance), np.nan)
            if ahead_experts is not None:
                ahead_experts[t] = np.where(on[..., None], out.ahead_experts, np.nan)
        if lead is not None:
            lead[t] = np.where(on, out.lead, np.nan)
            lead_std[t] = np.where(on, _std(out.lead_covariance), np.nan)
            if lead_covariance is not None:
                lead_covariance[t] = np.where(on[..., None], out.lead_covariance, np.nan)
    return EngineResult(forecasts, state, ahead, experts_out, weights_out, ahead_experts, std, ahead_std, lead,
                        lead_std, covariance, lead_covariance)


def check_restart(restart, shape):
    """``restart`` as a bool array of ``shape`` (T, N), or None; ``ValueError`` naming it."""
    if restart is None:
        return None
    array = np.asarray(restart)
    if array.shape != tuple(shape) or array.dtype != bool:
        raise ValueError(f"restart: expected a bool array of shape (T, N) = {tuple(shape)}, got "
                         f"{array.dtype} {array.shape}")
    return array


def _std(cov):
    return np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
