"""The documented, seeded recipes of expert banks, with validation: :func:`make_bank` (families of experts under an
aggregation rule, with its heads) and :func:`make_params` (the paper's mixture, :mod:`kalmix.mixture_recipe`).

This is the boundary of the batched core: every argument is checked here, against the constraints each component
declares beside its parameters (:mod:`kalmix.core.constraints`), so that :mod:`kalmix.core` can stay free of checks.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .core.aggregators import RULES
from .core.calibration import CalibrationParams
from .core.constraints import Choice, Integer, Levels, Real, validate, validate_options
from .core.engine import MAX_HORIZON, Bank, Family, check_horizon
from .core.families.ar import ARParams
from .core.families.ct import PLANE, CTParams
from .core.families.kinematic import KinematicParams
from .core.families.turn import TurnParams
from .core.lead import LeadParams
from .core.screen import ScreenParams
from .mixture_recipe import (
    FORGETTING_LEVELS,
    LENGTH_UNIT_RANGE,
    MAX_SEED,
    MEASUREMENT_NOISE_RANGE,
    PROCESS_NOISE_RANGE,
    RIDGE_LEVELS,
    check_length_unit,
    make_params,
    noise_grid,
)

__all__ = ["make_params", "noise_grid", "check_horizon", "check_length_unit", "MAX_HORIZON", "MAX_SEED",
           "LENGTH_UNIT_RANGE", "make_bank", "BANK_KINDS", "KINEMATIC_PROCESS_LEVELS",
           "KINEMATIC_MEASUREMENT_LEVELS", "DEFAULT_BANK", "AR_ORDERS", "AR_FORGETTING", "AR_RIDGE",
           "TURN_GAINS", "CT_PROCESS_LEVELS", "CT_TURN_LEVELS",
           "recipe_parts", "GATE_OPTIONS", "PROCESS_NOISE_RANGE", "MEASUREMENT_NOISE_RANGE",
           "FORGETTING_LEVELS", "RIDGE_LEVELS"]


def short_lead(lead: float | None, time_unit: float | None) -> str | None:
    """Why a ``lead`` is too short for a ``time_unit`` to learn its weights, or None: the lead head learns
    from a row that comes within half a unit of t + lead, and the rows come a unit apart."""
    if lead is None or time_unit is None or not lead < 0.5 * time_unit:
        return None
    return (f"lead: {lead:g} is shorter than half the time unit ({time_unit:g}): no row comes within half a unit of "
            "t + lead, so the lead's weights never learn (they stay uniform over the experts); ask for a lead of at "
            "least half the sampling interval")


def check_automatic_length_unit(unit: float) -> float:
    """The length unit estimated from the data (``auto``), if in :data:`LENGTH_UNIT_RANGE`; else a ``ValueError``
    that says so (not naming an option the user did not give as the culprit)."""
    low, high = LENGTH_UNIT_RANGE
    if not low <= unit <= high:
        raise ValueError(f"--length-unit: the automatic length unit {unit:.3g} is outside [{low:g}, {high:g}]; "
                         "rescale the data or pass --length-unit")
    return unit


# --------------------------------------------------------------------------------------------
# Banks of expert families under an aggregation rule (kalmix.core.engine)

#: Bank recipes of :func:`make_bank`.
BANK_KINDS = ("mixed", "kinematic", "akf", "ar", "kinematic+ar", "mixed+ar", "turn", "kinematic+ar+turn",
              "mixed+ar+turn", "ct", "kinematic+ar+turn+ct", "mixed+ar+turn+ct")
#: Options of each rule that :func:`make_bank` uses unless ``rule_options`` says otherwise. BOA's range
#: bound forgets at 0.99 a row: without forgetting (1.0, the original rule) one large error, such as a
#: ball's kick, caps every learning rate for the rest of the track. BOA's regrets see the errors clipped
#: at 3 times their RMS so far (``clip``, :mod:`kalmix.core.aggregators.boa`), so a kick or a relocation
#: does not move the weights. Both were chosen by the ablation (benchmarks/results/ablation_*.json).
DEFAULT_RULE_OPTIONS = {"boa": {"bound_forgetting": 0.99, "clip": 3.0},
                        "boa_blend": {"bound_forgetting": 0.99, "clip": 3.0}}
#: make_bank's ``reach`` (time units): off by default. A reach helps on tracks sampled at irregular intervals
#: (benchmarks/results/irregular_sampling.json); it hurts on regular tracks across missed rows, where staying
#: near the last position beats extrapolating a velocity (a lost player). ``kalmix predict`` and
#: :class:`kalmix.streaming.StreamConfig` settle it from the data (``reach="auto"``:
#: :func:`kalmix.streaming.reach_for_steps`).
DEFAULT_REACH = None

#: Process-noise levels q of the kinematic experts, in length_unit^2 per time_unit^3 (CV).
KINEMATIC_PROCESS_LEVELS = tuple(10.0**e for e in range(-3, 4))
#: Measurement-noise levels r of the kinematic experts, in length_unit^2.
KINEMATIC_MEASUREMENT_LEVELS = (0.1, 1.0)
#: Initial standard deviation of the velocity and acceleration of a kinematic expert
#: (length units per time unit, per time unit squared): wide, so the first two
#: measurements decide.
KINEMATIC_INITIAL_SPREAD = 100.0


def _kinematic(order, unit, time_unit, process_levels, measurement_levels):
    q = np.repeat(np.asarray(process_levels, float), len(measurement_levels)) * unit**2
    r = np.tile(np.asarray(measurement_levels, float), len(process_levels)) * unit**2
    spread = (KINEMATIC_INITIAL_SPREAD * unit) ** 2
    initial = np.column_stack([r] + [np.full(r.shape, spread)] * (order - 1))
    return KinematicParams(order=order, process_noise=q, measurement_noise=r, initial_variance=initial,
                           time_unit=float(time_unit))


#: Orders of the AR families (previous velocities in the regressor).
AR_ORDERS = (1, 2, 3, 5)
#: Forgetting factors of each AR family's experts.
AR_FORGETTING = (0.9, 0.95, 0.98, 0.99, 0.995, 0.999)
#: Ridge strengths (typical samples the persistence prior weighs) of each AR family's experts.
AR_RIDGE = (0.01, 1.0)


def _ar(order, unit, time_unit, forgetting, ridge, **options):
    lam = np.repeat(np.asarray(forgetting, float), len(ridge))
    rho = np.tile(np.asarray(ridge, float), len(forgetting))
    return ARParams(order=int(order), forgetting=lam, ridge=rho, length_unit=float(unit),
                    time_unit=float(time_unit), **options)


#: Gains of the coordinated-turn experts (the fraction of the last turn rate carried forward). The rules'
#: weights are convex, so gains on both sides of 1 let the mixture reach any fraction of the turn.
TURN_GAINS = (0.5, 1.0, 1.5)
#: Process-noise levels q of the coordinated-turn Kalman experts (a white acceleration on each axis), in
#: length_unit^2 per time_unit^3.
CT_PROCESS_LEVELS = (0.01, 1.0)
#: Turn noise levels q_j of the coordinated-turn Kalman experts (a lateral jerk), in length_unit^2 per time_unit^5.
CT_TURN_LEVELS = (0.01, 0.3, 10.0)
#: Measurement-noise level r of the coordinated-turn Kalman experts, in length_unit^2.
CT_MEASUREMENT_LEVEL = 1.0


def _ct(unit, time_unit, process_levels, turn_levels):
    q = np.repeat(np.asarray(process_levels, float), len(turn_levels)) * unit**2
    qj = np.tile(np.asarray(turn_levels, float), len(process_levels)) * unit**2
    r = np.full(q.shape, CT_MEASUREMENT_LEVEL * unit**2)
    return CTParams(process_noise=q, turn_noise=qj, measurement_noise=r,
                    initial_variance=np.full(q.shape, (KINEMATIC_INITIAL_SPREAD * unit) ** 2),
                    length_unit=float(unit), time_unit=float(time_unit))


def recipe_parts(kind: str) -> set:
    """The families of a recipe: ``"mixed"`` is the kinematic and AKF families."""
    parts = set(kind.split("+"))
    if "mixed" in parts:
        parts = (parts - {"mixed"}) | {"kinematic", "akf"}
    return parts


#: What each of :func:`make_bank`'s own arguments may be (the ``length_unit``: :func:`check_length_unit`); those of
#: the families, the rule and the heads are declared by their components (their ``Params.CONSTRAINTS``).
ARGUMENT_CONSTRAINTS = {"measurement_dim": Integer(ge=1), "kind": Choice(BANK_KINDS), "rule": Choice(tuple(RULES)),
                        "time_unit": Real(gt=0), "seed": Integer(ge=0), "n_akf": Integer(ge=1),
                        "reach": Real(gt=0)}
#: A bank's AR orders: an AR family's order, written as an integer or a whole float (2.0).
AR_ORDER_LEVELS = Levels(dataclasses.replace(ARParams.CONSTRAINTS["order"], integral_floats=True))
#: ``ar_options``: the AR family's fields that have a default.
AR_OPTIONS = {name: ARParams.CONSTRAINTS[name] for name in ARParams._field_defaults}


def make_bank(
    measurement_dim: int,
    kind: str = "mixed",
    *,
    rule: str = "boa",
    length_unit: float = 1.0,
    time_unit: float = 1.0,
    seed: int = 0,
    n_akf: int = 40,
    process_levels=KINEMATIC_PROCESS_LEVELS,
    measurement_levels=KINEMATIC_MEASUREMENT_LEVELS,
    rule_options: dict | None = None,
    akf_options: dict | None = None,
    outlier_threshold: float = 1000.0,
    outlier_rejects: int = 3,
    lead: float | None = None,
    lead_delay: float | None = None,
    level: float = 0.95,
    calibration_from_points: int = CalibrationParams._field_defaults["from_points"],
    ar_orders=AR_ORDERS,
    ar_forgetting=AR_FORGETTING,
    ar_ridge=AR_RIDGE,
    ar_options: dict | None = None,
    turn_gains=TURN_GAINS,
    ct_process_levels=CT_PROCESS_LEVELS,
    ct_turn_levels=CT_TURN_LEVELS,
    reach: float | None = DEFAULT_REACH,
):
    """Build and validate a bank of expert families and its aggregation rule.

    Recipes (``kind``):

    - ``"kinematic"``: constant-velocity and constant-acceleration Kalman filters with
      the real time step (:mod:`kalmix.core.families.kinematic`), one per pair
      (process level q, measurement level r): 7 x 2 of each order, 28 experts;
    - ``"akf"``: ``n_akf`` of the paper's adaptive Kalman filters (the grid and seeded
      draws of :func:`make_params`, without the paper gate's Q/R feedback);
    - ``"mixed"``: both (68 experts with the defaults);
    - ``"ar"``: adaptive autoregressive models of the velocity in real time
      (:mod:`kalmix.core.families.ar`), one family per order in ``ar_orders``, one expert
      per pair (forgetting, ridge): 4 x 6 x 2 = 48 experts;
    - ``"kinematic+ar"``, ``"mixed+ar"``: those banks and the AR families (76, 116 experts);
    - ``"turn"``: coordinated-turn experts (:mod:`kalmix.core.families.turn`), one per gain
      in ``turn_gains`` (3 experts);
    - ``"kinematic+ar+turn"``, ``"mixed+ar+turn"``: those banks and the turn family
      (79, 119 experts);
    - ``"ct"``: coordinated-turn Kalman filters (:mod:`kalmix.core.families.ct`), one per
      pair (process level, turn level): 2 x 3 = 6 experts, in the plane of the first two
      coordinates (left out of a bank of one coordinate);
    - ``"kinematic+ar+turn+ct"``, ``"mixed+ar+turn+ct"``: those banks and the coordinated-turn
      Kalman filters (85, 125 experts; ``"mixed+ar+turn+ct"`` is the default, :data:`DEFAULT_BANK`).

    Parameters
    ----------
    measurement_dim : int
        p, coordinates per measurement.
    rule : {"boa", "boa_blend", "mlpoly", "fixed_share"}
        The aggregation rule (:mod:`kalmix.core.aggregators`).
    length_unit : float
        Measurement-noise size in data units; every noise level is a multiple of its square.
    time_unit : float
        The typical sampling interval in the time column's units (kinematic experts).
    seed : int
        Seed of the AKF family's draws.
    n_akf : int
        Experts of the AKF family (``akf`` and ``mixed``).
    process_levels : sequence of float
        The kinematic grid's process-noise levels q, in units of ``length_unit**2`` per ``time_unit**3``.
    measurement_levels : sequence of float
        The kinematic grid's measurement-noise levels r, in units of ``length_unit**2``.
    rule_options : dict, optional
        The rule's parameters (e.g. ``{"forgetting": 0.999, "share": 0.01}``), over
        :data:`DEFAULT_RULE_OPTIONS` (BOA: ``bound_forgetting`` 0.99, ``clip`` 3; give
        ``{"bound_forgetting": 1.0, "clip": math.inf}`` for the original rule). A lead head's rule is the same, except
        BOA's ``delay``, multiplied by the lead's frames, and its ``clip``, off
        (:attr:`kalmix.core.engine.Bank.lead_rule_params`).
    akf_options : dict, optional
        Other :func:`make_params` arguments of the AKF family's experts (``dynamics``,
        ``order``, the noise ranges, ...); those of the gate (:data:`GATE_OPTIONS`) are
        refused, as the family has no gate.
    outlier_threshold : float
        The glitch screen's threshold (:mod:`kalmix.core.screen`): a row further than this
        many times the track's typical extrapolation error is not learned; ``inf``
        turns the screen off.
    outlier_rejects : int
        That many outliers in a row restart the track from the last of them (a relocation).
    lead : float, optional
        Give the bank a lead head (:mod:`kalmix.core.lead`): forecasts ``lead`` time-column
        units after each row (``round(lead / time_unit)`` rows for frame-based experts),
        with weights and intervals learned on their own, delayed errors; a row within half
        a ``time_unit`` of a forecast's time scores it.
    lead_delay : float, optional
        The lead head's rule learns with BOA's ``delay`` multiplied by this (see
        :mod:`kalmix.core.aggregators.boa`): a forecast is scored that many rows after it is
        made. Default: the lead's rows, ``round(lead / time_unit)``; 1 is the one-step
        rule's learning rate. Only BOA has a delay; without
        a ``lead`` it is checked and unused.
    level : float
        The central interval whose coverage the calibration aims at
        (:mod:`kalmix.core.calibration`); intervals are ``±z(level) std``.
    calibration_from_points : int
        The calibration learns the errors of forecasts made from at least this many rows of a track's
        segment (default 2: not the first, made from one row, whose miss is the target's whole
        displacement); 0 learns every one (state files before format 18 ran so); at most 3, the rows the
        glitch screen counts.
    ar_orders : sequence of int
        Orders of the AR families (previous velocities in the regressor), each >= 1.
    ar_forgetting : sequence of float
        Each AR family's forgetting factors, in (0, 1].
    ar_ridge : sequence of float
        Each AR family's ridge strengths > 0 (how many typical samples the persistence prior weighs).
    ar_options : dict, optional
        Other :class:`kalmix.core.families.ar.ARParams` fields (``bias``, ``jump_threshold``, ...).
    turn_gains : sequence of float
        The turn family's experts: fractions >= 0 of the last turn rate carried forward.
    ct_process_levels, ct_turn_levels : sequence of float
        The coordinated-turn Kalman grid: process-noise levels q on each axis (in units of
        ``length_unit**2`` per ``time_unit**3``) and turn noise levels, a lateral jerk (``length_unit**2`` per
        ``time_unit**5``).
    reach : float or None
        In time units: across a longer step (from a target's last learned row to the
        forecast's time) only the CV experts make the one-step forecast, when the bank has
        some (see :mod:`kalmix.core.engine`, "Reach"); None (or inf): every expert at every step.
        Off by default (:data:`DEFAULT_REACH`: what it wins and loses); 1.5 suits tracks sampled
        at irregular intervals.
    """
    given = dict(measurement_dim=measurement_dim, kind=kind, rule=rule, time_unit=time_unit, seed=seed, n_akf=n_akf)
    args = {name: validate(name, value, ARGUMENT_CONSTRAINTS[name]) for name, value in given.items()}
    p, tunit = args["measurement_dim"], args["time_unit"]
    unit = check_length_unit(length_unit)   # the range the families' numbers stay finite in
    validate("process_levels", process_levels, KinematicParams.CONSTRAINTS["process_noise"])
    validate("measurement_levels", measurement_levels, KinematicParams.CONSTRAINTS["measurement_noise"])
    module = RULES[rule]
    options = {**DEFAULT_RULE_OPTIONS.get(rule, {}), **(rule_options or {})}
    checked = validate_options(options, module.Params.CONSTRAINTS, "rule_options", f"rule {rule!r}")
    if "clip" in options:   # as a float: an integer past float's range is inf (off)
        options["clip"] = checked["clip"]
    parts = recipe_parts(kind)
    if "ar" in parts:
        ar_orders = validate("ar_orders", ar_orders, AR_ORDER_LEVELS)
        validate("ar_forgetting", ar_forgetting, ARParams.CONSTRAINTS["forgetting"])
        validate("ar_ridge", ar_ridge, ARParams.CONSTRAINTS["ridge"])
        ar_options = dict(ar_options or {})
        validate_options(ar_options, AR_OPTIONS, "ar_options", "the AR family")
    if "turn" in parts:
        turn_gains = validate("turn_gains", turn_gains, TurnParams.CONSTRAINTS["gain"])
    if kind == "ct" and p < PLANE:
        raise ValueError(f"kind: 'ct' needs at least {PLANE} coordinates (a plane to turn in), got measurement_dim "
                         f"{p}; in a bank of other families it is left out of one coordinate")
    if "ct" in parts:
        ct_process_levels = validate("ct_process_levels", ct_process_levels, CTParams.CONSTRAINTS["process_noise"])
        ct_turn_levels = validate("ct_turn_levels", ct_turn_levels, CTParams.CONSTRAINTS["turn_noise"])
    families = []
    if "kinematic" in parts:
        families.append(Family("cv", _kinematic(2, unit, tunit, process_levels, measurement_levels)))
        families.append(Family("ca", _kinematic(3, unit, tunit, process_levels, measurement_levels)))
    if "ar" in parts:
        families.extend(Family("ar", _ar(order, unit, tunit, ar_forgetting, ar_ridge, **ar_options))
                        for order in ar_orders)
    if "turn" in parts:
        families.append(Family("turn", TurnParams(gain=np.asarray(turn_gains, float), length_unit=unit,
                                                  time_unit=tunit)))
    if "ct" in parts and p >= PLANE:   # (one coordinate has no plane to turn in)
        families.append(Family("ct", _ct(unit, tunit, ct_process_levels, ct_turn_levels)))
    if "akf" in parts:
        gate = [name for name in (akf_options or {}) if name in GATE_OPTIONS]
        if gate:
            raise ValueError(f"akf_options: {gate} set the paper's gate (or its eq. 11/12 noise feedback), which "
                             "the AKF family of a bank does not have: the bank's rule combines the experts (rule, "
                             "rule_options); the paper's gated mixture is kalmix.core.mixture with make_params")
        akf = make_params(p, args["n_akf"], seed=seed, length_unit=unit,
                          **{**(akf_options or {}), "gating": "none", "adapt_noise": False})
        families.append(Family("akf", akf))
    threshold = validate("outlier_threshold", outlier_threshold, ScreenParams.CONSTRAINTS["threshold"])
    rejects = validate("outlier_rejects", outlier_rejects, ScreenParams.CONSTRAINTS["max_rejects"])
    level = validate("level", level, CalibrationParams.CONSTRAINTS["level"])
    from_points = validate("calibration_from_points", calibration_from_points,
                           CalibrationParams.CONSTRAINTS["from_points"])
    if reach is not None and reach != math.inf:   # None or inf: off
        reach = validate("reach", reach, ARGUMENT_CONSTRAINTS["reach"])
    else:
        reach = None
    if lead_delay is not None:
        validate("lead_delay", lead_delay, LeadParams.CONSTRAINTS["delay"])
    lead_params = None
    if lead is not None:
        lead_time = validate("lead", lead, LeadParams.CONSTRAINTS["time"])
        if lead_time / tunit > MAX_HORIZON:   # a rule between lead and time_unit, not a constraint of one
            raise ValueError(f"lead: expected at most {MAX_HORIZON} time units ({MAX_HORIZON * tunit:g}), "
                             f"got {lead!r}")
        frames = max(1, int(round(lead_time / tunit)))
        delay = float(frames) if lead_delay is None else float(lead_delay)
        lead_params = LeadParams(time=lead_time, frames=frames, tolerance=0.5 * tunit, delay=delay)
    description = dict(kind=kind, rule=rule, outlier_threshold=threshold, outlier_rejects=rejects,
                       length_unit=unit, time_unit=tunit, seed=seed, n_akf=n_akf, lead=lead,
                       lead_delay=None if lead_params is None else lead_params.delay, level=level,
                       process_levels=[float(v) for v in process_levels],
                       measurement_levels=[float(v) for v in measurement_levels],
                       rule_options=options, akf_options=dict(akf_options or {}), reach=reach)
    if "turn" in parts:
        description.update(turn_gains=[float(v) for v in turn_gains])
    if "ct" in parts:
        description.update(ct_process_levels=[float(v) for v in ct_process_levels],
                           ct_turn_levels=[float(v) for v in ct_turn_levels])
    if "ar" in parts:
        description.update(ar_orders=[int(v) for v in ar_orders], ar_forgetting=[float(v) for v in ar_forgetting],
                           ar_ridge=[float(v) for v in ar_ridge], ar_options=ar_options)
    return Bank(measurement_dim=p, families=tuple(families), rule=rule, rule_params=module.Params(**options),
                description=description, screen_params=ScreenParams(threshold=threshold, max_rejects=rejects),
                calibration_params=CalibrationParams(initial_variance=unit * unit, level=level,
                                                     from_points=from_points),
                lead=lead_params, reach=np.inf if reach is None else reach * tunit)


#: The default bank and rule of ``kalmix predict`` / ``evaluate`` / :class:`kalmix.streaming.TrackPredictor`,
#: chosen by the ablation on the shipped recordings and the paper scenario (benchmarks/results/ablation_*.json);
#: the coordinated-turn Kalman filters and BOA-blend (over BOA: the same on the recordings, far better where one
#: expert is right and the others far off at some rows) by the model zoo and the recordings (CHANGELOG).
DEFAULT_BANK = {"kind": "mixed+ar+turn+ct", "rule": "boa_blend"}

#: :func:`make_params` arguments of the paper's gate and its eq. 11/12 noise feedback: the AKF
#: family of a bank has neither (its rule combines the experts), so ``akf_options`` refuses them.
GATE_OPTIONS = ("gating", "gating_input", "velocity_scale", "expert_scale", "temperature", "gate_share",
                "eta_initial", "eta_minimum", "eta_decay_steps", "eta_sensitivity", "adapt_noise",
                "process_noise_shrink", "measurement_noise_shrink", "noise_floor", "noise_reinflation")
