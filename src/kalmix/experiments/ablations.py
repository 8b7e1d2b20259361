"""Ablations: the questions the paper leaves open, answered on the paper's scenario.

Each variant changes one thing from the default mixture (K = 40,
:func:`kalmix.bank.make_params` defaults) and is run on the same measurements over
several seeds. Reported per variant (mean over seeds): the mixture's RMS for X and Y,
its max error, the RMS of the best single expert of the same run in hindsight and the
ratio of the two (the gate's quality: 1 = as good as the oracle, < 1 = better than any
single expert), and the fraction of frames whose largest gating weight exceeds 0.8.

Groups (:data:`ABLATIONS`):

``akf_mode``       expert dynamics: ``rls`` (default) vs ``literal`` (eq. 6/7 as printed)
``gate``           ``fixed_share`` (default) vs the paper's softmax gate (eq. 8-10) vs random
``gating_input``   input :math:`x_k` of the paper's gate: bias, position, position + velocity
``noise``          eq. (11)/(12) on with a floor (default), off, on without floor (the paper's
                   rule), on with re-inflation, and a strong adaptation (large :math:`\beta, \beta'`
                   and :math:`\alpha`, so that eq. 11/12 actually move Q and R) with and without floor
``n_experts``      K = 1, 5, 10, 40, 80
``gate_settings``  fixed-share share :math:`\\alpha_s`, temperature T and expert scale
                   :math:`\\sigma_i` (to check the defaults)
"""

from __future__ import annotations

from typing import Any, Callable, Iterable

import numpy as np

__all__ = ["ABLATIONS", "ablations", "run_variant", "variants"]

#: (group, name, n_experts, make_params options); the first row of a group is its reference.
ABLATIONS: tuple[tuple[str, str, int, dict[str, Any]], ...] = (
    ("akf_mode", "rls (default)", 40, {}),
    ("akf_mode", "literal", 40, {"dynamics": "literal"}),
    ("gate", "fixed_share (default)", 40, {}),
    ("gate", "paper eq. 8-10", 40, {"gating": "paper"}),
    ("gate", "random", 40, {"gating": "random"}),
    ("gating_input", "paper gate, bias", 40, {"gating": "paper", "gating_input": "bias"}),
    ("gating_input", "paper gate, position", 40, {"gating": "paper", "gating_input": "position"}),
    ("gating_input", "paper gate, velocity (default)", 40, {"gating": "paper", "gating_input": "velocity"}),
    ("noise", "Q/R adaptation on, floor 0.01 (default)", 40, {}),
    ("noise", "Q/R adaptation off", 40, {"adapt_noise": False}),
    ("noise", "Q/R adaptation on, no floor (paper)", 40, {"noise_floor": 0.0}),
    ("noise", "Q/R adaptation on, floor, re-inflation 0.01", 40, {"noise_reinflation": 0.01}),
    ("noise", "strong adaptation (beta 1, beta' 0.5, alpha 1), no floor", 40,
     {"process_noise_shrink": 1.0, "measurement_noise_shrink": 0.5, "eta_sensitivity": 1.0, "noise_floor": 0.0}),
    ("noise", "strong adaptation, floor 0.01", 40,
     {"process_noise_shrink": 1.0, "measurement_noise_shrink": 0.5, "eta_sensitivity": 1.0}),
    ("n_experts", "K = 1", 1, {}),
    ("n_experts", "K = 5", 5, {}),
    ("n_experts", "K = 10", 10, {}),
    ("n_experts", "K = 40 (default)", 40, {}),
    ("n_experts", "K = 80", 80, {}),
    ("gate_settings", "share 0.02, T 1, sigma 2 (default)", 40, {}),
    ("gate_settings", "share 0", 40, {"gate_share": 0.0}),
    ("gate_settings", "share 0.005", 40, {"gate_share": 0.005}),
    ("gate_settings", "share 0.1", 40, {"gate_share": 0.1}),
    ("gate_settings", "temperature 0.5", 40, {"temperature": 0.5}),
    ("gate_settings", "temperature 4", 40, {"temperature": 4.0}),
    ("gate_settings", "sigma 1 px", 40, {"expert_scale": 1.0}),
    ("gate_settings", "sigma 4 px", 40, {"expert_scale": 4.0}),
)


def variants(groups: Iterable[str] | None = None):
    """The rows of :data:`ABLATIONS` in ``groups`` (all by default)."""
    wanted = None if groups is None else set(groups)
    return [row for row in ABLATIONS if wanted is None or row[0] in wanted]


def run_variant(measurements: np.ndarray, *, seed: int, n_experts: int, options: dict[str, Any]) -> dict[str, float]:
    """One variant on one measurement array: RMS, max, best expert, one-hot fraction."""
    from ..baselines import best_expert_in_hindsight
    from ..metrics import paper_axes_summary, prediction_errors
    from ..predictor import MixturePredictor
    from .table1 import ONE_HOT_THRESHOLD

    z = measurements
    result = MixturePredictor(n_experts, seed=seed, **options).run(z, diagnostics=True, expert_predictions=True)
    summary = paper_axes_summary(prediction_errors(result.predictions, z))
    _, best = best_expert_in_hindsight(result.expert_predictions, z)
    best_summary = paper_axes_summary(prediction_errors(best, z))
    errors = prediction_errors(result.predictions, z)
    best_errors = prediction_errors(best, z)
    rms = float(np.sqrt(np.nanmean(errors**2)))
    best_rms = float(np.sqrt(np.nanmean(best_errors**2)))
    return {
        "rms_X": summary["X"]["rms"],
        "rms_Y": summary["Y"]["rms"],
        "rms": rms,
        "max": float(np.nanmax(np.abs(errors))),
        "best_expert_rms_X": best_summary["X"]["rms"],
        "best_expert_rms_Y": best_summary["Y"]["rms"],
        "best_expert_rms": best_rms,
        "ratio_to_best_expert": rms / best_rms,
        "max_weight_above_0.8_fraction": float(np.mean(result.weights.max(axis=-1) > ONE_HOT_THRESHOLD)),
    }


def ablations(seeds: Iterable[int] = (0, 1, 2), *, groups: Iterable[str] | None = None, scenario=None,
              progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Run every variant in ``groups`` over ``seeds``.

    Returns
    -------
    dict
        ``{"seeds": [...], "rows": [{"group", "name", "n_experts", "options", "mean": {metric: value},
        "spread": {metric: std over seeds}, "per_seed": [...]}]}``.
    """
    from .table1 import scenario_measurements

    seeds = [int(seed) for seed in seeds]
    measurements = {seed: scenario_measurements(seed, scenario)[1] for seed in seeds}
    rows = []
    for group, name, n_experts, options in variants(groups):
        per_seed = []
        for seed in seeds:
            per_seed.append(run_variant(measurements[seed], seed=seed, n_experts=n_experts, options=options))
            if progress is not None:
                progress()
        keys = per_seed[0].keys()
        rows.append({
            "group": group, "name": name, "n_experts": n_experts, "options": dict(options),
            "mean": {key: float(np.mean([item[key] for item in per_seed])) for key in keys},
            "spread": {key: float(np.std([item[key] for item in per_seed])) for key in keys},
            "per_seed": per_seed,
        })
    return {"seeds": seeds, "rows": rows}
