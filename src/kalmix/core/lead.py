"""The lead head: weights and intervals for forecasts a lead time ahead, learned on their own errors.

A forecast made after row ``t`` for the time ``t + lead`` can only be scored when a
measurement at that time arrives: the feedback is delayed. The lead head keeps, per
target, up to ``capacity`` pending forecasts (every expert's, with the time they are
for). When a learned row comes at a time within ``tolerance`` of a pending forecast's
time, the lead head's own aggregation rule and calibration (:mod:`.calibration`) learn
from that forecast against the row; pending forecasts whose time has passed without such
a row are dropped. So the weights of a lead-L forecast are those that did best at lead L,
not at one step (reference; :mod:`kalmix.core.compiled` has the same numbers fast).

Frame-based families forecast ``frames`` rows ahead; time-based ones to ``t + lead``.
With a regular sampling interval ``u`` and ``lead = H u``, that is the H-step forecast
and each pending forecast is scored by the row H later. With more than ``capacity``
rows per lead, new forecasts wait for a free slot (learning from a subset of the rows;
memory stays ``capacity x K x p`` per target). A restart (glitch screen, time gap) drops
the pending forecasts: they were made before the jump. Forecasts made after a target's
first row (or a restart row), from a single position, are not kept: they teach nothing
about the lead, and this way nothing depends on a time unit learned later.

**Blend.** Weights learned on lead errors see their errors H rows late and learn at a rate
slowed for that delay, so they can do worse than the one-step weights on the same experts
(on a short lead, or on a short track). The forecast issued is therefore a blend of two: the
lead weights' forecast and the one-step weights' forecast of the same time (:func:`blend`).
The bank's rule aggregates the two (a second, two-expert state: ``blend``); both are kept
with the pending forecast (``candidates``) and scored by the same delayed feedback, so the
blend's regret to the better of the two, and to any convex combination of them, grows as the
rule's (BOA: :math:`O(\\sqrt{T})`), and its weights come from the losses alone. It runs with
the lead head's parameters but at the one-step rule's rate
(:attr:`~kalmix.core.engine.Bank.blend_rule_params`): its two forecasts differ little, so a
step taken on errors H rows old costs little, while the slower rate is slow to leave a lead
forecast that does worse. The interval is the lead head's covariance about the blended mean,
recalibrated on the misses of the intervals issued.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from . import calibration
from ._libm import exp, ordered_sum
from .aggregators import boa
from .constraints import Real

__all__ = ["LeadParams", "LeadState", "init", "init_blend", "learn", "forecast", "blend", "push"]


class LeadParams(NamedTuple):
    time: float          # lead, in the time column's units
    frames: int          # the same lead in rows, for frame-based families
    tolerance: float     # a row within this of a forecast's time scores it
    capacity: int = 16   # pending forecasts kept per target
    delay: float = 1.0   # the rule's delay factor (BOA: its learning rate / sqrt(delay)); make_bank: ``frames``

    #: What the fields a caller sets may be (:mod:`kalmix.core.constraints`); ``delay`` is BOA's.
    CONSTRAINTS = {"time": Real(gt=0, hint="time-column units"), "delay": boa.Params.CONSTRAINTS["delay"]}


class LeadState(NamedTuple):
    rule: Any                                  # the lead head's rule state
    calibration: calibration.CalibrationState  # and its calibration
    due: np.ndarray                            # (N, C) times of the pending forecasts, NaN = free slot
    pending: np.ndarray                        # (N, C, K, p) their experts' forecasts
    issued: np.ndarray                         # (N, C, 2, p) the intervals issued with them: mean, std
    blend: Any                                 # the rule's state over the two forecasts blended (see above)
    candidates: np.ndarray                     # (N, C, 2, p) those two issued with them: lead, one-step weights'


def init(bank, n_targets: int) -> LeadState:
    k, p, c = bank.n_experts, bank.measurement_dim, bank.lead.capacity
    return LeadState(bank.rule_module.init(bank.lead_rule_params, n_targets, k),
                     calibration.init(bank.calibration_params, n_targets, k, p),
                     np.full((n_targets, c), np.nan), np.full((n_targets, c, k, p), np.nan),
                     np.full((n_targets, c, 2, p), np.nan), init_blend(bank, n_targets),
                     np.full((n_targets, c, 2, p), np.nan))


def init_blend(bank, n_targets: int):
    """The blend's rule state for ``n_targets``, before any feedback (even weights)."""
    return bank.rule_module.init(bank.blend_rule_params, n_targets, 2)


def learn(bank, state: LeadState, measurement, time, go) -> LeadState:
    """Score the pending forecasts due at ``time (N,)`` against ``measurement`` where ``go``; drop the past ones."""
    params = bank.lead
    rule, cal, mix = state.rule, state.calibration, state.blend
    due = state.due
    with np.errstate(invalid="ignore"):
        matched = go[:, None] & (np.abs(due - time[:, None]) <= params.tolerance)
        done = go[:, None] & (due <= time[:, None] + params.tolerance)
    for c in range(due.shape[1]):   # oldest first
        if not matched[:, c].any():
            continue
        experts = state.pending[:, c]
        awake = np.isfinite(experts).all(axis=-1)
        w = bank.rule_module.weights(bank.lead_rule_params, rule, awake)
        cal = calibration.update(bank.calibration_params, cal, w, experts, awake, measurement, matched[:, c],
                                 state.issued[:, c])
        rule = bank.rule_module.update(bank.lead_rule_params, rule, experts, measurement, awake, matched[:, c])
        two = state.candidates[:, c]
        mix = bank.rule_module.update(bank.blend_rule_params, mix, two, measurement, np.isfinite(two).all(axis=-1),
                                      matched[:, c])
    # keep the others in order
    order = np.argsort(done, axis=1, kind="stable")
    kept = np.take_along_axis(np.where(done, np.nan, due), order, axis=1)
    pending = np.take_along_axis(state.pending, order[:, :, None, None], axis=1)
    issued = np.take_along_axis(state.issued, order[:, :, None, None], axis=1)
    candidates = np.take_along_axis(state.candidates, order[:, :, None, None], axis=1)
    free = ~np.isfinite(kept)[:, :, None, None]
    return LeadState(rule, cal, kept, np.where(free, np.nan, pending), np.where(free, np.nan, issued), mix,
                     np.where(free, np.nan, candidates))


def forecast(bank, state, experts, *, lead: bool = False):
    """Weights ``(N, K)``, mean ``(N, p)`` and covariance ``(N, p, p)`` of ``experts (N, K, p)`` under a head:
    ``state`` has a ``rule`` and a ``calibration`` state: a :class:`LeadState` with ``lead`` (its rule runs
    with :attr:`~kalmix.core.engine.Bank.lead_rule_params`), or a bank's state for the one-step forecasts."""
    awake = np.isfinite(experts).all(axis=-1)
    w = bank.rule_module.weights(bank.lead_rule_params if lead else bank.rule_params, state.rule, awake)
    mean, cov = calibration.moments(bank.calibration_params, state.calibration, w, experts, awake)
    return w, mean, cov


def blend(bank, state: LeadState, lead_mean, lead_cov, one_step_mean):
    """The forecast issued: the blend of the lead weights' ``lead_mean (N, p)`` (covariance ``lead_cov``) and the
    one-step weights' ``one_step_mean`` under the blend's weights; its covariance is ``lead_cov`` about the blended
    mean (plus the outer product of the shift, scaled as the head's calibration scales the spread). Returns
    ``(mean, cov, candidates)``, ``candidates (N, 2, p)`` the two forecasts (for :func:`push`)."""
    two = np.stack([lead_mean, one_step_mean], axis=1)
    awake = np.isfinite(two).all(axis=-1)
    w = bank.rule_module.weights(bank.blend_rule_params, state.blend, awake)
    mean = ordered_sum(w[..., None] * np.where(awake[..., None], two, 0.0), axis=1)
    mean = np.where(awake.any(axis=-1)[:, None], mean, np.nan)
    with np.errstate(over="ignore", invalid="ignore"):
        shift = np.where(awake[:, :1], lead_mean - mean, 0.0)
        cov = lead_cov + exp(2.0 * state.calibration.log_scale)[:, None, None] * (shift[:, :, None] * shift[:, None, :])
    limit = bank.calibration_params.max_variance
    cov = np.clip(np.nan_to_num(cov, nan=limit, posinf=limit, neginf=-limit), -limit, limit)
    cov = np.where(awake[:, 0, None, None], cov, lead_cov)
    return mean, cov, two


def push(bank, state: LeadState, experts, due_time, go, restart, mean, std, candidates) -> LeadState:
    """After a learned row (``go``): keep ``experts (N, K, p)``, due at ``due_time (N,)``, if a slot is free,
    with the interval issued for them (``mean``, ``std``: ``(N, p)``) and the two forecasts blended into it
    (``candidates (N, 2, p)``, :func:`blend`).

    A ``restart`` first drops every pending forecast and keeps none (nor does a target's first row:
    see :func:`kalmix.core.engine.step`).
    """
    due = np.where(restart[:, None], np.nan, state.due)
    pending = np.where(restart[:, None, None, None], np.nan, state.pending)
    issued = np.where(restart[:, None, None, None], np.nan, state.issued)
    kept = np.where(restart[:, None, None, None], np.nan, state.candidates)
    free = np.isnan(due)
    slot = np.argmax(free, axis=1)
    take = go & ~restart & free.any(axis=1) & np.isfinite(experts).all(axis=-1).any(axis=-1) & np.isfinite(due_time)
    rows = np.flatnonzero(take)
    due = due.copy()
    pending = pending.copy()
    issued = issued.copy()
    kept = kept.copy()
    due[rows, slot[rows]] = due_time[rows]
    pending[rows, slot[rows]] = experts[rows]
    issued[rows, slot[rows], 0] = mean[rows]
    issued[rows, slot[rows], 1] = std[rows]
    kept[rows, slot[rows]] = candidates[rows]
    return state._replace(due=due, pending=pending, issued=issued, candidates=kept)
