"""The documented, seeded recipe for a bank of K adaptive Kalman experts, with validation.

This is the boundary of the batched core: every argument is checked here, so that
:mod:`kalmix.core` can stay free of checks.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .core.dynamics import polynomial_prior
from .core.engine import MAX_HORIZON, Bank, Family, check_horizon
from .core.gating import GATING_INPUTS
from .core.mixture import DYNAMICS, GATINGS, MixtureParams

__all__ = ["make_params", "noise_grid", "check_horizon", "check_length_unit", "MAX_HORIZON", "MAX_SEED",
           "LENGTH_UNIT_RANGE", "make_bank", "BANK_KINDS", "KINEMATIC_PROCESS_LEVELS",
           "KINEMATIC_MEASUREMENT_LEVELS", "DEFAULT_BANK", "AR_ORDERS", "AR_FORGETTING", "AR_RIDGE",
           "TURN_GAINS", "recipe_parts", "GATE_OPTIONS"]

#: Largest seed: the compiled kernels hold it in a signed 64-bit integer.
MAX_SEED = 2**63 - 1
#: Accepted ``length_unit`` range. The bank squares it (noise variances) and multiplies variances;
#: within 1e-60 .. 1e60 those stay inside double range and the predictions are scale-equivariant
#: (data and unit scaled together give predictions and intervals scaled alike, to 1e-9 relative,
#: tested at both ends for the default bank and the paper's mixture). Far outside it the variance
#: products overflow or vanish and the predictions depart from scale-equivariance.
LENGTH_UNIT_RANGE = (1e-60, 1e60)

#: Process-noise levels of the grid span this range (measurement units squared per frame).
PROCESS_NOISE_RANGE = (1e-2, 1e2)
#: Measurement-noise levels of the grid span this range (measurement units squared).
MEASUREMENT_NOISE_RANGE = (5e-2, 5.0)
#: Forgetting factors assigned to experts (cycled through a seeded permutation).
FORGETTING_LEVELS = (0.9, 0.95, 0.98, 0.99)
#: Ridge weights toward the prior (normalised units).
RIDGE_LEVELS = (1e-3, 1e-2, 1e-1)


def _check_delay(name, value) -> float:
    """A delay in rows between a forecast and its score (BOA's ``delay``): a finite number >= 1."""
    delay = _check_positive(name, value)
    if delay < 1:
        raise ValueError(f"{name}: expected a number >= 1 (rows between a forecast and its score), got {value!r}")
    return delay


def _check_positive(name, value, *, allow_zero=False, upper=None):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__} {value!r}")
    value = float(value)
    bad = not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero)
    if upper is not None and value > upper:
        bad = True
    if bad:
        rng = f"in [0, {upper}]" if allow_zero and upper is not None else (
            ">= 0" if allow_zero else "> 0") if upper is None else f"in (0, {upper}]"
        raise ValueError(f"{name}: expected a finite number {rng}, got {value!r}")
    return value


def _check_int(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an integer >= {minimum}, got {type(value).__name__} {value!r}")
    if value < minimum:
        raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def short_lead(lead: float | None, time_unit: float | None) -> str | None:
    """Why a ``lead`` is too short for a ``time_unit`` to learn its weights, or None: the lead head learns
    from a row that comes within half a unit of t + lead, and the rows come a unit apart."""
    if lead is None or time_unit is None or not lead < 0.5 * time_unit:
        return None
    return (f"lead: {lead:g} is shorter than half the time unit ({time_unit:g}): no row comes within half a unit of "
            "t + lead, so the lead's weights never learn (they stay uniform over the experts); ask for a lead of at "
            "least half the sampling interval")


def check_length_unit(value, name: str = "length_unit") -> float:
    """``value`` as a float in :data:`LENGTH_UNIT_RANGE`; ``TypeError``/``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name}: expected a real number, got {type(value).__name__} {value!r}")
    low, high = LENGTH_UNIT_RANGE
    if not low <= float(value) <= high:  # also refuses NaN
        raise ValueError(f"{name}: expected a number in [{low:g}, {high:g}] (the typical measurement-noise "
                         f"size in data units), got {value!r}")
    return float(value)


def check_automatic_length_unit(unit: float) -> float:
    """The length unit estimated from the data (``auto``), if in :data:`LENGTH_UNIT_RANGE`; else a ``ValueError``
    that says so (not naming an option the user did not give as the culprit)."""
    low, high = LENGTH_UNIT_RANGE
    if not low <= unit <= high:
        raise ValueError(f"--length-unit: the automatic length unit {unit:.3g} is outside [{low:g}, {high:g}]; "
                         "rescale the data or pass --length-unit")
    return unit


def _check_pair(name, pair):
    if isinstance(pair, (str, bytes)) or not hasattr(pair, "__len__") or len(pair) != 2:
        raise ValueError(f"{name}: expected a pair (low, high) of numbers > 0, got {pair!r}")
    low, high = (_check_positive(f"{name}[{i}]", v) for i, v in enumerate(pair))
    if low > high:
        raise ValueError(f"{name}: expected low <= high, got {pair!r}")
    return low, high


def _check_levels(name, levels, upper=None, allow_zero=False):
    if isinstance(levels, (str, bytes)) or not hasattr(levels, "__iter__"):
        raise ValueError(f"{name}: expected a sequence of numbers {'>=' if allow_zero else '>'} 0, got {levels!r}")
    values = [_check_positive(f"{name}[{i}]", v, upper=upper, allow_zero=allow_zero) for i, v in enumerate(levels)]
    if not values:
        raise ValueError(f"{name}: expected at least one value, got none")
    return values


def _check_choice(name, value, choices):
    if value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


def _levels(low: float, high: float, count: int) -> np.ndarray:
    """``count`` log-spaced levels; one level is the geometric middle of the range."""
    if count == 1:
        return np.array([math.sqrt(low * high)])
    return np.geomspace(low, high, count)


def noise_grid(n_experts: int) -> tuple[int, int]:
    """Grid shape (process levels, measurement levels) for K experts: 8 x 5 for K = 40.

    The measurement axis has :math:`n_R = \\max(1, \\mathrm{round}(\\sqrt{K \\cdot 5/8}))`
    levels and the process axis :math:`n_Q = \\lceil K / n_R \\rceil`; the first K points
    (process level varying fastest) are used.
    """
    n_r = max(1, round(math.sqrt(n_experts * 5 / 8)))
    n_q = math.ceil(n_experts / n_r)
    return n_q, n_r


def make_params(
    measurement_dim: int,
    n_experts: int = 40,
    *,
    dynamics: str = "rls",
    gating: str = "fixed_share",
    gating_input: str = "velocity",
    order: int = 2,
    seed: int = 0,
    length_unit: float = 1.0,
    feature_scale: float | None = None,
    velocity_scale: float = 0.1,
    process_noise_range: tuple[float, float] = PROCESS_NOISE_RANGE,
    measurement_noise_range: tuple[float, float] = MEASUREMENT_NOISE_RANGE,
    forgetting_levels=FORGETTING_LEVELS,
    ridge_levels=RIDGE_LEVELS,
    prior_degree: int | None = None,
    spectral_radius_bound: float = 1.02,
    initial_variance_range: tuple[float, float] = (1.0, 100.0),
    initial_velocity_spread: float = 2.0,
    expert_scale: float = 2.0,
    temperature: float = 1.0,
    gate_share: float = 0.02,
    eta_initial: float = 0.5,
    eta_minimum: float = 0.02,
    eta_decay_steps: float = 150.0,
    eta_sensitivity: float = 0.02,
    adapt_noise: bool = True,
    process_noise_shrink: float = 0.05,
    measurement_noise_shrink: float = 0.02,
    noise_floor: float = 0.01,
    noise_reinflation: float = 0.0,
) -> MixtureParams:
    """Build and validate the parameters of a bank of K experts and its gate.

    The bank (a fixed function of ``seed``): expert *i* sits on a log-spaced grid of
    process-noise levels :math:`Q_i = q_i I` and measurement-noise levels
    :math:`R_i = r_i I` (8 x 5 for K = 40; K = 1 gives the grid's geometric middle);
    its forgetting factor :math:`\\lambda_i` and ridge :math:`\\rho_i` are drawn from
    ``forgetting_levels`` and ``ridge_levels``, its initial variance :math:`P_{0,i}`
    log-uniformly from ``initial_variance_range`` and its initial velocity guess from
    :math:`N(0, \\text{spread}^2)`. With K = 1 the expert is the grid's middle with
    the middle forgetting and ridge, zero initial velocity and the geometric middle
    initial variance.

    Parameters
    ----------
    measurement_dim : int
        p, the number of measured coordinates (3 for the paper's stereo features).
    n_experts : int
        K >= 1.
    dynamics : {"rls", "literal", "fixed"}
        How each expert's system matrix is estimated (:mod:`kalmix.core.dynamics`).
        ``fixed`` keeps the prior (a plain constant-velocity/acceleration filter).
    gating : {"fixed_share", "paper", "random", "none"}
        ``paper``: softmax gate of eq. (8) trained by eq. (9); ``fixed_share``: a
        softmax over the experts' running log-likelihoods with a share
        :math:`\\alpha_s` (tracking the best expert); ``random``: weights drawn at
        random each frame, no learning (the paper's baseline); ``none``: no gate,
        the weights stay as they start (equal) and nothing is scored (what a bank's
        AKF family runs: the bank's rule combines its experts); needs
        ``adapt_noise=False``.
    gating_input : {"velocity", "position", "bias"}
        Input :math:`x_k` of the paper gate (eq. 8).
    order : int
        o >= 1, number of past feature vectors in each expert's state (n = o p).
    seed : int
        Seed of the bank recipe and of the random gate.
    length_unit : float
        Typical size of a measurement unit's noise (1 for pixels): noise levels,
        scales and velocities below are multiplied by it (squared for variances).
    feature_scale : float, optional
        :math:`\\kappa`, default ``100 * length_unit``.
    velocity_scale : float
        :math:`v_0` of the gating input, in normalised features per frame.
    process_noise_range : (float, float)
        Range of the grid's process-noise levels :math:`q_i` (units squared).
    measurement_noise_range : (float, float)
        Range of the grid's measurement-noise levels :math:`r_i` (units squared).
    forgetting_levels : sequence of float in (0, 1]
        :math:`\\lambda` values of the RLS dynamics.
    ridge_levels : sequence of float > 0
        :math:`\\rho` values of the RLS dynamics.
    prior_degree : {0, 1, 2}, optional
        Polynomial degree of the prior :math:`\\Theta_0`, default ``min(order-1, 1)``.
    spectral_radius_bound : float
        Guard on the learned companion matrix.
    initial_variance_range : (float, float)
        Range of :math:`P_{0,i} / I` (units squared).
    initial_velocity_spread : float
        Standard deviation of the experts' initial velocity guess (units per frame).
    expert_scale : float
        :math:`\\sigma_i` of eq. (10) (units).
    temperature : float
        T of eq. (8) (and the likelihood tempering of the fixed-share gate).
    gate_share : float
        :math:`\\alpha_s \\in [0, 1]` of the fixed-share gate.
    eta_initial : float
        :math:`\\eta_0` of :math:`\\eta(t) = \\eta_{min} + (\\eta_0 - \\eta_{min}) e^{-t/\\tau}`.
    eta_minimum : float
        :math:`\\eta_{min}`, the rate's floor.
    eta_decay_steps : float
        :math:`\\tau`, the rate's decay time (measurements).
    eta_sensitivity : float
        :math:`\\alpha` of :math:`\\eta_k = \\eta(t)(1 - e^{-\\alpha\\varepsilon})` (units^-2).
    adapt_noise : bool
        Apply eq. (11)/(12).
    process_noise_shrink : float
        :math:`\\beta` of eq. (11).
    measurement_noise_shrink : float
        :math:`\\beta'` of eq. (12).
    noise_floor : float
        :math:`\\phi`: Q and R never fall below :math:`\\phi` times their initial value
        (0 = the paper's rule).
    noise_reinflation : float
        :math:`\\gamma`: per-frame pull back toward the initial value (0 = the paper's rule).
    """
    p = _check_int("measurement_dim", measurement_dim, 1)
    k = _check_int("n_experts", n_experts, 1)
    o = _check_int("order", order, 1)
    _check_choice("dynamics", dynamics, DYNAMICS)
    _check_choice("gating", gating, GATINGS)
    _check_choice("gating_input", gating_input, GATING_INPUTS)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
        raise TypeError(f"seed: expected an integer in [0, 2**63 - 1], got {type(seed).__name__} {seed!r}")
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seed: expected an integer in [0, 2**63 - 1], got {seed!r}")
    seed = int(seed)
    unit = check_length_unit(length_unit)
    kappa = 100.0 * unit if feature_scale is None else _check_positive("feature_scale", feature_scale)
    for name, pair in (("process_noise_range", process_noise_range),
                       ("measurement_noise_range", measurement_noise_range),
                       ("initial_variance_range", initial_variance_range)):
        _check_pair(name, pair)
    forgetting_levels = _check_levels("forgetting_levels", forgetting_levels, upper=1.0)
    ridge_levels = _check_levels("ridge_levels", ridge_levels)
    if prior_degree is not None:
        _check_choice("prior_degree", prior_degree, tuple(range(min(o, 3))))
    values = dict(
        velocity_scale=_check_positive("velocity_scale", velocity_scale),
        spectral_radius_bound=_check_positive("spectral_radius_bound", spectral_radius_bound),
        initial_velocity_spread=_check_positive("initial_velocity_spread", initial_velocity_spread, allow_zero=True),
        expert_scale=_check_positive("expert_scale", expert_scale),
        temperature=_check_positive("temperature", temperature),
        gate_share=_check_positive("gate_share", gate_share, allow_zero=True, upper=1.0),
        eta_initial=_check_positive("eta_initial", eta_initial, allow_zero=True),
        eta_minimum=_check_positive("eta_minimum", eta_minimum, allow_zero=True),
        eta_decay_steps=_check_positive("eta_decay_steps", eta_decay_steps),
        eta_sensitivity=_check_positive("eta_sensitivity", eta_sensitivity, allow_zero=True),
        process_noise_shrink=_check_positive("process_noise_shrink", process_noise_shrink, allow_zero=True),
        measurement_noise_shrink=_check_positive("measurement_noise_shrink", measurement_noise_shrink, allow_zero=True),
        noise_floor=_check_positive("noise_floor", noise_floor, allow_zero=True, upper=1.0),
        noise_reinflation=_check_positive("noise_reinflation", noise_reinflation, allow_zero=True, upper=1.0),
    )
    if not isinstance(adapt_noise, (bool, np.bool_)):
        raise TypeError(f"adapt_noise: expected a bool, got {type(adapt_noise).__name__} {adapt_noise!r}")
    if gating == "none" and adapt_noise:
        raise ValueError("adapt_noise: the eq. 11/12 noise feedback is driven by the gate's responsibilities, and "
                         "gating='none' has no gate; pass adapt_noise=False with it")

    rng = np.random.default_rng(seed)
    n_q, n_r = noise_grid(k)
    q_levels = _levels(*process_noise_range, n_q) * unit**2
    r_levels = _levels(*measurement_noise_range, n_r) * unit**2
    grid_q, grid_r = np.meshgrid(q_levels, r_levels, indexing="xy")
    process = grid_q.ravel()[:k]
    measurement = grid_r.ravel()[:k]
    if k == 1:
        forgetting = np.array([forgetting_levels[len(forgetting_levels) // 2]])
        ridge = np.array([ridge_levels[len(ridge_levels) // 2]])
        initial_variance = np.array([math.sqrt(initial_variance_range[0] * initial_variance_range[1])]) * unit**2
        initial_velocity = np.zeros((1, p))
    else:
        forgetting = np.resize(rng.permutation(np.asarray(forgetting_levels, float)), k)
        rng.shuffle(forgetting)
        ridge = rng.choice(np.asarray(ridge_levels, float), size=k)
        initial_variance = np.exp(rng.uniform(*np.log(initial_variance_range), size=k)) * unit**2
        initial_velocity = rng.normal(0.0, values["initial_velocity_spread"], size=(k, p)) * unit
    return MixtureParams(
        measurement_dim=p,
        order=o,
        dynamics=dynamics,
        gating=gating,
        gating_input=gating_input,
        feature_scale=kappa,
        velocity_scale=values["velocity_scale"],
        forgetting=forgetting,
        ridge=ridge,
        prior_theta=polynomial_prior(p, o, prior_degree),
        spectral_radius_bound=values["spectral_radius_bound"],
        process_noise=np.repeat(process[:, None], p, axis=1),
        measurement_noise=np.repeat(measurement[:, None], p, axis=1),
        initial_variance=initial_variance,
        initial_velocity=initial_velocity,
        expert_scale=np.full(k, values["expert_scale"] * unit),
        temperature=values["temperature"],
        gate_share=values["gate_share"],
        eta_initial=values["eta_initial"],
        eta_minimum=values["eta_minimum"],
        eta_decay_steps=values["eta_decay_steps"],
        eta_sensitivity=values["eta_sensitivity"] / unit**2,
        adapt_noise=bool(adapt_noise),
        process_noise_shrink=values["process_noise_shrink"],
        measurement_noise_shrink=values["measurement_noise_shrink"],
        noise_floor=values["noise_floor"],
        noise_reinflation=values["noise_reinflation"],
        random_seed=seed,
    )


# --------------------------------------------------------------------------------------------
# Banks of expert families under an aggregation rule (kalmix.core.engine)

#: Bank recipes of :func:`make_bank`.
BANK_KINDS = ("mixed", "kinematic", "akf", "ar", "kinematic+ar", "mixed+ar", "turn", "kinematic+ar+turn",
              "mixed+ar+turn")
#: Options of each rule that :func:`make_bank` uses unless ``rule_options`` says otherwise. BOA's range
#: bound forgets at 0.99 a row: without forgetting (1.0, the original rule) one large error, such as a
#: ball's kick, caps every learning rate for the rest of the track. BOA's regrets see the errors clipped
#: at 3 times their RMS so far (``clip``, :mod:`kalmix.core.aggregators.boa`), so a kick or a relocation
#: does not move the weights. Both were chosen by the ablation (benchmarks/results/ablation_*.json).
DEFAULT_RULE_OPTIONS = {"boa": {"bound_forgetting": 0.99, "clip": 3.0}}
#: make_bank's ``reach`` (time units): off by default, as no value wins everywhere. A reach helps on tracks
#: sampled at irregular intervals and bridged across their gaps (``--max-gap none``); it hurts where staying
#: near the last position across a gap beats extrapolating a velocity (a lost player), and it worsens H-step
#: forecasts made with the one-step weights (the lead head's weights are not affected); see
#: benchmarks/results/irregular_sampling.json. Use reach 8 on tracks sampled at irregular intervals.
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
    from .core.families.kinematic import KinematicParams

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
    from .core.families.ar import ARParams

    lam = np.repeat(np.asarray(forgetting, float), len(ridge))
    rho = np.tile(np.asarray(ridge, float), len(forgetting))
    return ARParams(order=int(order), forgetting=lam, ridge=rho, length_unit=float(unit),
                    time_unit=float(time_unit), **options)


#: Gains of the coordinated-turn experts (the fraction of the last turn rate carried forward). The rules'
#: weights are convex, so gains on both sides of 1 let the mixture reach any fraction of the turn.
TURN_GAINS = (0.5, 1.0, 1.5)


def recipe_parts(kind: str) -> set:
    """The families of a recipe: ``"mixed"`` is the kinematic and AKF families."""
    parts = set(kind.split("+"))
    if "mixed" in parts:
        parts = (parts - {"mixed"}) | {"kinematic", "akf"}
    return parts


def _check_ar_options(options):
    from .core.families.ar import ARParams

    options = dict(options or {})
    allowed = {"persistence", "bias", "initial_error", "jump_threshold", "window", "max_step", "max_velocity"}
    unknown = set(options) - allowed
    if unknown:
        raise ValueError(f"ar_options: {sorted(unknown)} not options of the AR family (expected some of "
                         f"{sorted(allowed)})")
    for name, value in options.items():
        if name == "bias":
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"ar_options['bias']: expected a bool, got {type(value).__name__} {value!r}")
        elif name == "persistence":
            _check_positive("ar_options['persistence']", value, allow_zero=True)
        elif name == "jump_threshold":
            if not (isinstance(value, numbers.Real) and value > 0 and not math.isnan(value)):
                raise ValueError(f"ar_options['jump_threshold']: expected a number > 0 (inf: no jump test), "
                                 f"got {value!r}")
        else:
            _check_positive(f"ar_options[{name!r}]", value)
    defaults = ARParams._field_defaults
    if options.get("window", defaults["window"]) < 1:
        raise ValueError(f"ar_options['window']: expected a number >= 1, got {options['window']!r}")
    return options


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
    ar_orders=AR_ORDERS,
    ar_forgetting=AR_FORGETTING,
    ar_ridge=AR_RIDGE,
    ar_options: dict | None = None,
    turn_gains=TURN_GAINS,
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
      (79, 119 experts; ``"mixed+ar+turn"`` is the default, :data:`DEFAULT_BANK`).

    Parameters
    ----------
    measurement_dim : int
        p, coordinates per measurement.
    rule : {"boa", "mlpoly", "fixed_share"}
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
    reach : float or None
        In time units: across a longer step (from a target's last learned row to the
        forecast's time) only the CV experts make the one-step forecast, when the bank has
        some (see :mod:`kalmix.core.engine`, "Reach"); None (or inf): every expert at every step.
        Off by default (:data:`DEFAULT_REACH`: what it wins and loses); 8 suits tracks sampled
        at irregular intervals and not cut at gaps (``--max-gap none``).
    """
    from .core import aggregators

    p = _check_int("measurement_dim", measurement_dim, 1)
    _check_choice("kind", kind, BANK_KINDS)
    _check_choice("rule", rule, tuple(aggregators.RULES))
    unit = check_length_unit(length_unit)   # the range the families' numbers stay finite in
    tunit = _check_positive("time_unit", time_unit)
    _check_int("seed", seed, 0)
    _check_int("n_akf", n_akf, 1)
    for name, levels in (("process_levels", process_levels), ("measurement_levels", measurement_levels)):
        if np.ndim(levels) != 1 or len(levels) == 0:
            raise ValueError(f"{name}: expected a non-empty sequence of positive numbers, got {levels!r}")
        for value in levels:
            _check_positive(name, value)
    module = aggregators.RULES[rule]
    options = {**DEFAULT_RULE_OPTIONS.get(rule, {}), **(rule_options or {})}
    unknown = set(options) - set(module.Params._fields)
    if unknown:
        raise ValueError(f"rule_options: {sorted(unknown)} not options of rule {rule!r} "
                         f"(expected some of {list(module.Params._fields)})")
    for key in ("forgetting", "bound_forgetting"):
        if key in options:
            _check_positive(f"rule_options[{key!r}]", options[key], upper=1.0)
    for key in ("scale", "scale_factor"):   # fixed share: 0 = the online scale (scale), a positive factor
        if key in options:
            _check_positive(f"rule_options[{key!r}]", options[key], allow_zero=key == "scale")
    if "delay" in options:
        _check_delay("rule_options['delay']", options["delay"])
    if "clip" in options:   # BOA: errors beyond clip x their running RMS are shrunk to it; inf = off
        clip = options["clip"]
        if isinstance(clip, bool) or not isinstance(clip, numbers.Real):
            raise TypeError(f"rule_options['clip']: expected a number > 0 (inf: off), got {type(clip).__name__} "
                            f"{clip!r}")
        try:
            value = float(clip)
        except OverflowError:   # an integer past float's range
            value = math.inf
        if not value > 0:
            raise ValueError(f"rule_options['clip']: expected a number > 0 (inf: off), got {clip!r}")
        options["clip"] = value
    if "share" in options:
        share = _check_positive("rule_options['share']", options["share"], allow_zero=True)
        if share >= 1:
            raise ValueError(f"rule_options['share']: expected a number in [0, 1), got {share!r}")
    parts = recipe_parts(kind)
    if "ar" in parts:
        ar_orders = _check_levels("ar_orders", ar_orders)
        for i, order in enumerate(ar_orders):
            if order != int(order):
                raise ValueError(f"ar_orders[{i}]: expected an integer >= 1, got {order!r}")
        _check_levels("ar_forgetting", ar_forgetting, upper=1.0)
        _check_levels("ar_ridge", ar_ridge)
        ar_options = _check_ar_options(ar_options)
    if "turn" in parts:
        turn_gains = _check_levels("turn_gains", turn_gains, allow_zero=True)
    families = []
    if "kinematic" in parts:
        families.append(Family("cv", _kinematic(2, unit, tunit, process_levels, measurement_levels)))
        families.append(Family("ca", _kinematic(3, unit, tunit, process_levels, measurement_levels)))
    if "ar" in parts:
        families.extend(Family("ar", _ar(order, unit, tunit, ar_forgetting, ar_ridge, **(ar_options or {})))
                        for order in ar_orders)
    if "turn" in parts:
        from .core.families.turn import TurnParams

        families.append(Family("turn", TurnParams(gain=np.asarray(turn_gains, float), length_unit=unit,
                                                  time_unit=tunit)))
    if "akf" in parts:
        gate = [name for name in (akf_options or {}) if name in GATE_OPTIONS]
        if gate:
            raise ValueError(f"akf_options: {gate} set the paper's gate (or its eq. 11/12 noise feedback), which "
                             "the AKF family of a bank does not have: the bank's rule combines the experts (rule, "
                             "rule_options); the paper's gated mixture is kalmix.core.mixture with make_params")
        akf = make_params(p, _check_int("n_akf", n_akf, 1), seed=seed, length_unit=unit,
                          **{**(akf_options or {}), "gating": "none", "adapt_noise": False})
        families.append(Family("akf", akf))
    if isinstance(outlier_threshold, bool) or not isinstance(outlier_threshold, numbers.Real):
        raise TypeError(f"outlier_threshold: expected a number > 1 (inf: no screen), got "
                        f"{type(outlier_threshold).__name__} {outlier_threshold!r}")
    threshold = float(outlier_threshold)
    if not threshold > 1:
        raise ValueError(f"outlier_threshold: expected a number > 1 (inf: no screen), got {outlier_threshold!r}")
    from .core.calibration import CalibrationParams
    from .core.lead import LeadParams
    from .core.screen import ScreenParams

    if isinstance(level, bool) or not isinstance(level, numbers.Real):
        raise TypeError(f"level: expected a probability in (0, 1), got {type(level).__name__} {level!r}")
    level = float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: expected a probability in (0, 1), got {level!r}")
    reach = None if reach is None or reach == math.inf else _check_positive("reach", reach)   # inf: off
    if lead_delay is not None:
        _check_delay("lead_delay", lead_delay)
    lead_params = None
    if lead is not None:
        lead_time = _check_positive("lead", lead)
        if lead_time / tunit > MAX_HORIZON:
            raise ValueError(f"lead: expected at most {MAX_HORIZON} time units ({MAX_HORIZON * tunit:g}), "
                             f"got {lead!r}")
        frames = max(1, int(round(lead_time / tunit)))
        delay = float(frames) if lead_delay is None else float(lead_delay)
        lead_params = LeadParams(time=lead_time, frames=frames, tolerance=0.5 * tunit, delay=delay)
    description = dict(kind=kind, rule=rule, outlier_threshold=threshold, outlier_rejects=int(outlier_rejects),
                       length_unit=unit, time_unit=tunit, seed=seed, n_akf=n_akf, lead=lead,
                       lead_delay=None if lead_params is None else lead_params.delay, level=level,
                       process_levels=[float(v) for v in process_levels],
                       measurement_levels=[float(v) for v in measurement_levels],
                       rule_options=options, akf_options=dict(akf_options or {}), reach=reach)
    if "turn" in parts:
        description.update(turn_gains=[float(v) for v in turn_gains])
    if "ar" in parts:
        description.update(ar_orders=[int(v) for v in ar_orders], ar_forgetting=[float(v) for v in ar_forgetting],
                           ar_ridge=[float(v) for v in ar_ridge], ar_options=ar_options)
    return Bank(measurement_dim=p, families=tuple(families), rule=rule, rule_params=module.Params(**options),
                description=description,
                screen_params=ScreenParams(threshold=threshold,
                                           max_rejects=_check_int("outlier_rejects", outlier_rejects, 1)),
                calibration_params=CalibrationParams(initial_variance=unit * unit, level=level),
                lead=lead_params, reach=np.inf if reach is None else reach * tunit)


#: The default bank and rule of ``kalmix predict`` / ``evaluate`` / :class:`kalmix.streaming.TrackPredictor`,
#: chosen by the ablation on the shipped recordings and the paper scenario (benchmarks/results/ablation_*.json).
DEFAULT_BANK = {"kind": "mixed+ar+turn", "rule": "boa"}

#: :func:`make_params` arguments of the paper's gate and its eq. 11/12 noise feedback: the AKF
#: family of a bank has neither (its rule combines the experts), so ``akf_options`` refuses them.
GATE_OPTIONS = ("gating", "gating_input", "velocity_scale", "expert_scale", "temperature", "gate_share",
                "eta_initial", "eta_minimum", "eta_decay_steps", "eta_sensitivity", "adapt_noise",
                "process_noise_shrink", "measurement_noise_shrink", "noise_floor", "noise_reinflation")
