"""The seeded recipe of the paper's mixture of K adaptive Kalman experts: :func:`make_params`.

Every argument is checked here, against the constraints :class:`kalmix.core.mixture.MixtureParams` declares
for its fields (:mod:`kalmix.core.constraints`) and, for the arguments the recipe turns into fields (the noise
ranges, the length unit, ...), against its own (:data:`ARGUMENT_CONSTRAINTS`), so that :mod:`kalmix.core` can
stay free of checks. :func:`kalmix.bank.make_bank` builds a bank's AKF family with it.
"""

from __future__ import annotations

import math

import numpy as np

from .core.constraints import Choice, Integer, Pair, Real, validate
from .core.dynamics import polynomial_prior
from .core.mixture import MAX_SEED, MixtureParams

__all__ = ["make_params", "noise_grid", "check_length_unit", "LENGTH_UNIT_RANGE", "MAX_SEED", "ARGUMENT_CONSTRAINTS",
           "PROCESS_NOISE_RANGE", "MEASUREMENT_NOISE_RANGE", "FORGETTING_LEVELS", "RIDGE_LEVELS"]

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

#: What each argument of :func:`make_params` may be: a field's own constraint where the argument is the field
#: (:attr:`MixtureParams.CONSTRAINTS <kalmix.core.mixture.MixtureParams>`), the recipe's where the field is made
#: from it. ``prior_degree`` depends on ``order`` and is checked apart.
ARGUMENT_CONSTRAINTS = {
    **MixtureParams.CONSTRAINTS,
    "n_experts": Integer(ge=1), "seed": MixtureParams.CONSTRAINTS["random_seed"],
    "length_unit": Real(ge=LENGTH_UNIT_RANGE[0], le=LENGTH_UNIT_RANGE[1], noun="a number",
                        hint="the typical measurement-noise size in data units"),
    "forgetting_levels": MixtureParams.CONSTRAINTS["forgetting"], "ridge_levels": MixtureParams.CONSTRAINTS["ridge"],
    **dict.fromkeys(("process_noise_range", "measurement_noise_range", "initial_variance_range"), Pair(Real(gt=0))),
    "initial_velocity_spread": Real(ge=0), "expert_scale": Real(gt=0),
}


def check_length_unit(value, name: str = "length_unit") -> float:
    """``value`` as a float in :data:`LENGTH_UNIT_RANGE`; ``TypeError``/``ValueError`` naming ``name``."""
    return validate(name, value, ARGUMENT_CONSTRAINTS["length_unit"])


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
    arguments = dict(locals())   # the arguments as given
    args = {name: validate(name, value, ARGUMENT_CONSTRAINTS[name]) for name, value in arguments.items()
         if name in ARGUMENT_CONSTRAINTS and not (name == "feature_scale" and value is None)}
    p, k, o, seed, unit = args["measurement_dim"], args["n_experts"], args["order"], args["seed"], args["length_unit"]
    kappa = 100.0 * unit if feature_scale is None else args["feature_scale"]
    forgetting_levels, ridge_levels = args["forgetting_levels"], args["ridge_levels"]
    # rules between arguments, not constraints of one: a range runs upward; the prior's degree is below the
    # order (and 3); the noise feedback needs a gate
    for name in ("process_noise_range", "measurement_noise_range", "initial_variance_range"):
        if args[name][0] > args[name][1]:
            raise ValueError(f"{name}: expected low <= high, got {arguments[name]!r}")
    if prior_degree is not None:
        validate("prior_degree", prior_degree, Choice(tuple(range(min(o, 3)))))
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
        initial_velocity = rng.normal(0.0, args["initial_velocity_spread"], size=(k, p)) * unit
    return MixtureParams(
        measurement_dim=p,
        order=o,
        dynamics=dynamics,
        gating=gating,
        gating_input=gating_input,
        feature_scale=kappa,
        velocity_scale=args["velocity_scale"],
        forgetting=forgetting,
        ridge=ridge,
        prior_theta=polynomial_prior(p, o, prior_degree),
        spectral_radius_bound=args["spectral_radius_bound"],
        process_noise=np.repeat(process[:, None], p, axis=1),
        measurement_noise=np.repeat(measurement[:, None], p, axis=1),
        initial_variance=initial_variance,
        initial_velocity=initial_velocity,
        expert_scale=np.full(k, args["expert_scale"] * unit),
        temperature=args["temperature"],
        gate_share=args["gate_share"],
        eta_initial=args["eta_initial"],
        eta_minimum=args["eta_minimum"],
        eta_decay_steps=args["eta_decay_steps"],
        eta_sensitivity=args["eta_sensitivity"] / unit**2,
        adapt_noise=bool(adapt_noise),
        process_noise_shrink=args["process_noise_shrink"],
        measurement_noise_shrink=args["measurement_noise_shrink"],
        noise_floor=args["noise_floor"],
        noise_reinflation=args["noise_reinflation"],
        random_seed=seed,
    )
