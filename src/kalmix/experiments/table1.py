"""The paper's Table 1 (Wira, Urban & Gresser 2001, section 5), with our peers beside it.

Every row is computed on the same measurements (the paper's simulated stereo scenario,
:class:`kalmix.scenarios.PaperScenario`), one seed at a time, and summarised as the
paper does: mean of the absolute one-step prediction error, its standard deviation
and its maximum, for X (pooling ``u_left`` and ``u_right``) and Y (``v``), in pixels,
plus the RMS.

Rows (``ROWS``):

``single_akf``
    One state-model AKF, defined before looking at results (NOTES.md): the middle
    expert of the bank (K = 1), eq. (11)/(12) off (:func:`kalmix.baselines.single_akf`).
``mixture_softmax``
    The default mixture, K = 40 (:func:`kalmix.baselines.softmax_mixture`).
``mixture_random``
    The same bank, gating weights drawn at random each frame, no gate learning.
``imm_filterpy``
    filterpy's IMMEstimator over CV and CA models, tuned on a separate seed
    (:mod:`kalmix.peers`).
``cv_kalman``, ``ca_kalman``
    Fixed constant-velocity / constant-acceleration Kalman filters, noise tuned on the
    same separate seed (:data:`kalmix.peers.CV_DEFAULTS`, :data:`~kalmix.peers.CA_DEFAULTS`).
``best_expert_hindsight``
    An oracle: the single expert of the mixture's bank with the lowest RMS over the
    whole run, chosen after the fact (among the experts as they ran inside the mixture,
    and the same bank run without Q/R adaptation; the better of the two).
``no_prediction``
    Repeat the last measurement.

The AKF rows (single, mixtures, best expert) are computed for each expert ``dynamics``
mode (``rls``, the default, and ``literal``, eq. 6/7 as printed); the peer rows do not
depend on the mode and are repeated.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Iterable

import numpy as np

__all__ = [
    "ROWS",
    "AKF_ROWS",
    "PEER_ROWS",
    "PAPER_TABLE1",
    "ONE_HOT_THRESHOLD",
    "quick_scenario",
    "scenario_measurements",
    "run_seed",
    "default_bank_rows",
    "paper_table",
    "table1",
    "aggregate",
    "check_claims",
    "explain_claim",
    "ROW_LABELS",
    "CLAIM_LINKS",
]

ROWS = ("single_akf", "mixture_softmax", "mixture_random", "default_bank", "imm_filterpy", "cv_kalman",
        "ca_kalman", "best_expert_hindsight", "default_best_expert", "no_prediction")
AKF_ROWS = ("single_akf", "mixture_softmax", "mixture_random", "best_expert_hindsight")
PEER_ROWS = ("imm_filterpy", "cv_kalman", "ca_kalman", "no_prediction")
#: Rows of the bank ``kalmix predict`` uses by default (:data:`kalmix.bank.DEFAULT_BANK`), not the paper's.
DEFAULT_ROWS = ("default_bank", "default_best_expert")
#: Frames per second of the scenario's cameras.
FRAME_RATE = 25.0
STATS = ("mean_abs", "std", "max", "rms")
ONE_HOT_THRESHOLD = 0.8
#: How the rows are named in the printed table and in the claims' explanations.
ROW_LABELS = {
    "single_akf": "single AKF",
    "mixture_softmax": "mixture, softmax gate",
    "mixture_random": "mixture, random gate",
    "default_bank": "default bank (predict)",
    "imm_filterpy": "IMM CV+CA (filterpy)",
    "cv_kalman": "CV Kalman",
    "ca_kalman": "CA Kalman",
    "best_expert_hindsight": "best expert (hindsight)",
    "default_best_expert": "  its best expert",
    "no_prediction": "no prediction",
}
#: The page (relative to the repository, and its anchor) that explains each claim's outcome.
CLAIM_LINKS = {
    "ordering": "docs/paper.md#claim-ordering",
    "single_over_softmax_3x": "docs/paper.md#claim-single-3x",
    "random_over_single_3x": "docs/paper.md#claim-random-3x",
    "one_hot": "docs/paper.md#claim-one-hot",
    "mixture_beats_peers": "docs/paper.md#our-claims",
    "within_5pct_of_best_expert": "docs/paper.md#our-claims",
    "default_beats_peers_by_3pct": "docs/paper.md#our-claims",
    "default_within_5pct_of_best_expert": "docs/paper.md#our-claims",
}


def _paper_axis(mean: float, std: float, maximum: float) -> dict[str, float]:
    # The paper prints mean, std and max of |e|; RMS = sqrt(mean^2 + std^2) is derived.
    return {"mean_abs": mean, "std": std, "max": maximum, "rms": float(np.hypot(mean, std))}


#: Table 1 of the paper (pixels). ``rms`` is derived: :math:`\sqrt{\text{mean}^2 + \text{std}^2}`.
PAPER_TABLE1: dict[str, dict[str, dict[str, float]]] = {
    "single_akf": {"X": _paper_axis(0.5162, 9.431, 178.481), "Y": _paper_axis(0.432, 7.532, 161.599)},
    "mixture_softmax": {"X": _paper_axis(0.375, 2.716, 22.110), "Y": _paper_axis(0.2938, 2.632, 13.057)},
    "mixture_random": {"X": _paper_axis(31.270, 70.296, 148.361), "Y": _paper_axis(23.35, 52.269, 195.607)},
}


def quick_scenario(seed: int = 0):
    """A short version of the paper's scenario (8 s curve, 0.5 s deceleration, 4 s of random moves:
    312 frames) for smoke runs and the claim tests; same speeds, path and cameras."""
    from ..scenarios import PaperScenario

    return PaperScenario(curve_duration_s=8.0, deceleration_duration_s=0.5, wander_duration_s=4.0, seed=seed)


def scenario_measurements(seed: int, scenario=None, camera=None, noise_px: float = 0.5):
    """Trajectory and measurements ``(T, 3)`` of the paper's scenario for ``seed``.

    ``scenario`` is a template :class:`~kalmix.scenarios.PaperScenario` (default: the
    documented defaults) whose ``seed`` is replaced.
    """
    from ..scenarios import PaperScenario, paper_measurements

    template = PaperScenario() if scenario is None else scenario
    trajectory, observation = paper_measurements(dataclasses.replace(template, seed=int(seed)), camera,
                                                 noise_px=noise_px)
    return trajectory, observation.measured


def paper_table(seeds: Iterable[int] = range(5)):
    """The paper's simulated target as a table, one track per seed: ``track_id``, ``time`` (s, 25 Hz)
    and the stereo features ``f0, f1, f2`` (u_left, u_right, v in pixels) of :func:`scenario_measurements`."""
    import pandas as pd

    frames = []
    for seed in seeds:
        z = np.asarray(scenario_measurements(seed)[1], dtype=float).reshape(-1, 3)
        frame = pd.DataFrame(z, columns=[f"f{i}" for i in range(z.shape[1])])
        frame.insert(0, "time", np.arange(len(z)) / FRAME_RATE)
        frame.insert(0, "track_id", int(seed))
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def _summary(predictions: np.ndarray, measurements: np.ndarray) -> dict[str, dict[str, float]]:
    from ..metrics import paper_axes_summary, prediction_errors

    summary = paper_axes_summary(prediction_errors(predictions, measurements))
    return {axis: {stat: summary[axis][stat] for stat in STATS} for axis in ("X", "Y")}


def _total_rms(predictions: np.ndarray, measurements: np.ndarray) -> float:
    errors = measurements[1:] - predictions[:-1]
    errors = errors[np.isfinite(errors)]
    return float(np.sqrt(np.mean(errors**2)))


def run_seed(seed: int, *, modes: Iterable[str] = ("rls", "literal"), n_experts: int = 40, scenario=None,
             mixture_options: dict[str, Any] | None = None, peers: bool = True,
             progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Every row of Table 1 on one seed.

    Parameters
    ----------
    seed : int
        Seed of the scenario (trajectory and pixel noise) and of the expert bank.
    modes : iterable of {"rls", "literal"}
        Expert dynamics modes for the AKF rows.
    n_experts : int
        K of the mixtures.
    scenario : PaperScenario, optional
        Template scenario (its seed is replaced); default the documented one.
    mixture_options : dict, optional
        Extra :func:`kalmix.bank.make_params` options for every AKF row.
    peers : bool
        Compute the IMM / CV / CA rows (filterpy needed for the IMM).
    progress : callable, optional
        Called once after each predictor run.

    Returns
    -------
    dict
        ``{"seed", "frames", "modes": {mode: {"rows": {row: {"X": stats, "Y": stats}},
        "max_weight_above_0.8_fraction", "best_expert_index"}}, "peers": {row: ...}}``.
    """
    from .. import baselines, peers as peer_module

    tick = progress or (lambda: None)
    options = dict(mixture_options or {})
    _, z = scenario_measurements(seed, scenario)
    out: dict[str, Any] = {"seed": int(seed), "frames": int(len(z)), "modes": {}, "peers": {}}
    for mode in modes:
        rows: dict[str, Any] = {}
        mode_options = {**options, "dynamics": mode}
        single = baselines.single_akf(seed=seed, **mode_options).run(z, diagnostics=False)
        rows["single_akf"] = _summary(single.predictions, z)
        tick()
        mixture = baselines.softmax_mixture(n_experts, seed=seed, **mode_options).run(
            z, diagnostics=True, expert_predictions=True)
        rows["mixture_softmax"] = _summary(mixture.predictions, z)
        tick()
        random_options = {key: value for key, value in mode_options.items() if key != "gating"}
        random = baselines.random_mixture(n_experts, seed=seed, **random_options).run(z, diagnostics=False)
        rows["mixture_random"] = _summary(random.predictions, z)
        tick()
        # the oracle: best expert as it ran inside the mixture, or in the bank without Q/R adaptation
        bank = baselines.softmax_mixture(n_experts, seed=seed, **{**mode_options, "adapt_noise": False}).run(
            z, diagnostics=False, expert_predictions=True)
        tick()
        candidates = []
        for source, result in (("mixture", mixture), ("bank_without_adaptation", bank)):
            index, predictions = baselines.best_expert_in_hindsight(result.expert_predictions, z)
            candidates.append((_total_rms(predictions, z), index, source, predictions))
        best_rms, best_index, best_source, best_predictions = min(candidates, key=lambda item: item[0])
        rows["best_expert_hindsight"] = _summary(best_predictions, z)
        weights = mixture.weights
        out["modes"][mode] = {
            "rows": rows,
            "max_weight_above_0.8_fraction": float(np.mean(weights.max(axis=-1) > ONE_HOT_THRESHOLD)),
            "best_expert_index": best_index,
            "best_expert_source": best_source,
        }
    if peers:
        out["peers"]["imm_filterpy"] = _summary(peer_module.imm_predictions(z), z)
        tick()
        out["peers"]["cv_kalman"] = _summary(
            baselines.cv_kalman(**peer_module.CV_DEFAULTS).run(z, diagnostics=False).predictions, z)
        tick()
        out["peers"]["ca_kalman"] = _summary(
            baselines.ca_kalman(**peer_module.CA_DEFAULTS).run(z, diagnostics=False).predictions, z)
        tick()
    out["peers"]["no_prediction"] = _summary(baselines.no_prediction(z), z)
    out["peers"].update(default_bank_rows(z))
    tick()
    return out


def default_bank_rows(z: np.ndarray) -> dict[str, Any]:
    """The rows of :data:`DEFAULT_ROWS` for one run ``z (T, 3)``: the default bank as ``kalmix predict``
    runs it on these features at 25 Hz (compiled engine; length unit from the first 20 % of the frames by
    :func:`kalmix.streaming.auto_length_unit`, seed 0), and the best single expert of that bank in hindsight
    (lowest RMS over the whole run)."""
    from ..bank import DEFAULT_BANK, make_bank
    from ..core.compiled import engine
    from ..streaming import auto_length_unit

    z = np.asarray(z, dtype=float)
    unit = auto_length_unit(z[: max(3, int(np.ceil(0.2 * len(z))))])
    bank = make_bank(z.shape[1], **DEFAULT_BANK, length_unit=unit, time_unit=1.0 / FRAME_RATE)
    times = np.arange(len(z), dtype=float)[:, None] / FRAME_RATE
    result = engine.run(bank, z[:, None, :], times, record_experts=True)
    # the engine's row t is the forecast of z[t]; Table 1's predictions[t] is the forecast of z[t + 1]
    forecasts = np.concatenate([result.forecasts[1:, 0], np.full((1, z.shape[1]), np.nan)])
    experts = np.concatenate([result.experts[1:, 0], np.full((1,) + result.experts.shape[2:], np.nan)])
    with np.errstate(invalid="ignore"):
        errors = np.nanmean((experts[:-1] - z[1:, None, :]) ** 2, axis=(0, 2))
    best = int(np.nanargmin(errors))
    return {"default_bank": _summary(forecasts, z), "default_best_expert": _summary(experts[:, best], z)}


def runs_per_seed(modes: Iterable[str] = ("rls", "literal"), peers: bool = True) -> int:
    """Number of ``progress`` calls :func:`run_seed` makes (for a progress bar's total)."""
    return 4 * len(tuple(modes)) + (3 if peers else 0) + 1


def _mean_rows(per_seed_rows: list[dict], reducer) -> dict:
    rows = {}
    for row in per_seed_rows[0]:
        rows[row] = {axis: {stat: float(reducer([r[row][axis][stat] for r in per_seed_rows]))
                            for stat in STATS} for axis in ("X", "Y")}
    return rows


def _key(mode: str) -> str:
    """JSON key of a mode's rows: ``rows`` for ``rls`` (the default), ``rows_<mode>`` otherwise."""
    return "rows" if mode == "rls" else f"rows_{mode}"


def _suffix(mode: str) -> str:
    return "" if mode == "rls" else f"_{mode}"


def aggregate(per_seed: list[dict[str, Any]], modes: Iterable[str] = ("rls", "literal"), *,
              gating: str | None = None) -> dict[str, Any]:
    """Combine :func:`run_seed` outputs into the JSON shape of ``kalmix reproduce table1``.

    Each number is the mean over seeds; ``rows_spread`` (``rows_literal_spread``) holds
    the standard deviation over seeds (0 for one seed). ``rows`` is the ``rls`` mode,
    ``rows_literal`` the ``literal`` mode. ``claims`` (``claims_literal``) evaluates
    :func:`check_claims` on the mean rows, each with its ``why`` (:func:`explain_claim`;
    ``gating`` is the gate the mixture rows ran with, default fixed-share) and ``link``;
    ``claims_per_seed`` evaluates them on each seed.
    """
    modes = tuple(modes)
    result: dict[str, Any] = {"paper": PAPER_TABLE1, "seeds": [item["seed"] for item in per_seed],
                              "frames": per_seed[0]["frames"], "modes": list(modes)}
    for mode in modes:
        key, suffix = _key(mode), _suffix(mode)
        merged = [{**item["modes"][mode]["rows"], **item["peers"]} for item in per_seed]
        ordered = lambda rows: {row: rows[row] for row in ROWS if row in rows}  # noqa: E731
        result[key] = ordered(_mean_rows(merged, np.mean))
        result[f"{key}_spread"] = ordered(_mean_rows(merged, np.std))
        fractions = [item["modes"][mode]["max_weight_above_0.8_fraction"] for item in per_seed]
        result[f"max_weight_above_0.8_fraction{suffix}"] = float(np.mean(fractions))
        result[f"best_expert{suffix}"] = [{"seed": item["seed"], "index": item["modes"][mode]["best_expert_index"],
                                           "source": item["modes"][mode]["best_expert_source"]}
                                          for item in per_seed]
        claims = check_claims(result[key], result[f"max_weight_above_0.8_fraction{suffix}"])
        for claim in claims:
            claim["why"] = explain_claim(claim, result[key], mode=mode, gating=gating)
            claim["link"] = CLAIM_LINKS[claim["name"]]
        result[f"claims{suffix}"] = claims
    result["claims_per_seed"] = {
        mode: [check_claims({**item["modes"][mode]["rows"], **item["peers"]},
                            item["modes"][mode]["max_weight_above_0.8_fraction"]) for item in per_seed]
        for mode in modes}
    result["per_seed"] = per_seed
    return result


def table1(seeds: Iterable[int] = range(5), *, modes: Iterable[str] = ("rls", "literal"), n_experts: int = 40,
           scenario=None, mixture_options: dict[str, Any] | None = None, peers: bool = True,
           progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Table 1 over several seeds, as data (see :func:`aggregate` for the shape).

    Parameters are those of :func:`run_seed`; ``seeds`` are evaluation seeds (the peers
    were tuned on :data:`kalmix.peers.TUNING_SEED`, which is not one of them by default).
    """
    modes = tuple(modes)
    per_seed = [run_seed(seed, modes=modes, n_experts=n_experts, scenario=scenario,
                         mixture_options=mixture_options, peers=peers, progress=progress) for seed in seeds]
    return aggregate(per_seed, modes, gating=(mixture_options or {}).get("gating"))


def _claim(name: str, source: str, statement: str, holds: bool, numbers: dict[str, float]) -> dict[str, Any]:
    if source == "paper":
        verdict = "reproduced" if holds else "not reproduced"
    else:
        verdict = "holds" if holds else "does not hold"
    return {"name": name, "source": source, "statement": statement, "holds": bool(holds), "verdict": verdict,
            "numbers": {key: float(value) for key, value in numbers.items()}}


#: The peer rows our claims compare against.
_CLAIM_PEERS = ("imm_filterpy", "cv_kalman", "ca_kalman", "single_akf", "no_prediction")
_SHORT = {"imm_filterpy": "IMM", "cv_kalman": "CV", "ca_kalman": "CA", "single_akf": "single AKF",
          "no_prediction": "no prediction"}


def _best_expert_claim(name, subject, oracle, row, best, tolerance) -> list[dict[str, Any]]:
    """``[claim]`` that ``row``'s RMS <= (1 + tolerance) x ``best``'s, X and Y; ``[]`` without ``best``."""
    if not best:
        return []
    numbers = {f"{axis}.ratio": row[axis]["rms"] / best[axis]["rms"] for axis in ("X", "Y")}
    return [_claim(name, "ours", f"{subject} RMS <= {1 + tolerance:.2f}x {oracle} in hindsight, X and Y",
                   all(v <= 1.0 + tolerance for v in numbers.values()), numbers)]


def check_claims(rows: dict[str, Any], one_hot_fraction: float | None = None,
                 best_expert_tolerance: float = 0.05) -> list[dict[str, Any]]:
    """The paper's claims and ours, evaluated on one table of rows.

    Returns a list of ``{"name", "source": "paper" | "ours", "statement", "holds", "verdict", "numbers"}``;
    ``verdict`` is "reproduced" / "not reproduced" for the paper's claims, "holds" / "does not hold" for
    ours. Claims whose rows are absent are skipped.
    """
    claims = []
    single, softmax, random = (rows.get(name) for name in ("single_akf", "mixture_softmax", "mixture_random"))
    if single and softmax and random:
        numbers, ok = {}, True
        for axis in ("X", "Y"):
            for stat in ("std", "max"):
                values = (softmax[axis][stat], single[axis][stat], random[axis][stat])
                numbers.update({f"{axis}.{stat}.softmax": values[0], f"{axis}.{stat}.single": values[1],
                                f"{axis}.{stat}.random": values[2]})
                ok &= values[0] < values[1] < values[2]
        claims.append(_claim("ordering", "paper", "softmax mixture < single AKF < random mixture, in std and in "
                             "max, X and Y", ok, numbers))
    if single and softmax:
        numbers, ok = {}, True
        for axis in ("X", "Y"):
            ratio = single[axis]["rms"] / softmax[axis]["rms"]
            max_ratio = single[axis]["max"] / softmax[axis]["max"]
            numbers.update({f"{axis}.rms_ratio": ratio, f"{axis}.max_ratio": max_ratio})
            ok &= ratio >= 3.0 and max_ratio >= 3.0
        claims.append(_claim("single_over_softmax_3x", "paper", "single AKF >= 3x the softmax mixture, in RMS and "
                             "in max, X and Y", ok, numbers))
    if single and random:
        numbers = {f"{axis}.rms_ratio": random[axis]["rms"] / single[axis]["rms"] for axis in ("X", "Y")}
        claims.append(_claim("random_over_single_3x", "paper", "random mixture >= 3x the single AKF in RMS, X and Y",
                             all(v >= 3.0 for v in numbers.values()), numbers))
    if one_hot_fraction is not None:
        claims.append(_claim("one_hot", "paper", f"gating weights mostly one-hot: largest > {ONE_HOT_THRESHOLD} "
                             "on over half the frames", one_hot_fraction > 0.5,
                             {"fraction": one_hot_fraction}))
    peers = [name for name in _CLAIM_PEERS if name in rows]
    peer_text = ", ".join(_SHORT[name] for name in peers)
    if softmax:
        numbers, ok = {}, True
        for axis in ("X", "Y"):
            numbers[f"{axis}.softmax"] = softmax[axis]["rms"]
            for name in peers:
                numbers[f"{axis}.{name}"] = rows[name][axis]["rms"]
                ok &= softmax[axis]["rms"] <= rows[name][axis]["rms"]
        claims.append(_claim("mixture_beats_peers", "ours", f"mixture RMS <= every peer's ({peer_text}), X and Y",
                             ok, numbers))
        claims += _best_expert_claim("within_5pct_of_best_expert", "mixture", "its best single expert",
                                     softmax, rows.get("best_expert_hindsight"), best_expert_tolerance)
    default = rows.get("default_bank")
    if default:
        numbers, ok = {}, True
        for axis in ("X", "Y"):
            numbers[f"{axis}.default"] = default[axis]["rms"]
            best_peer = min(rows[name][axis]["rms"] for name in peers) if peers else float("inf")
            numbers[f"{axis}.ratio_to_best_peer"] = default[axis]["rms"] / best_peer
            ok &= default[axis]["rms"] <= 0.97 * best_peer
        claims.append(_claim("default_beats_peers_by_3pct", "ours", "default-bank RMS <= 0.97x the best peer's, X "
                             "and Y", ok, numbers))
        claims += _best_expert_claim("default_within_5pct_of_best_expert", "default-bank", "its best single expert",
                                     default, rows.get("default_best_expert"), best_expert_tolerance)
    return claims


def _pair(numbers: dict[str, float], key: str, unit: str = "x", digits: int = 2) -> str:
    """``"1.14x / 1.14x"`` (``unit`` "x") or ``"1.051 / 1.080 px"`` (a unit with a space): the X and the Y
    value, ``numbers["X.<key>"]`` and ``numbers["Y.<key>"]``."""
    values = [numbers[f"{axis}.{key}"] for axis in ("X", "Y")]
    if unit.startswith(" "):
        return " / ".join(f"{value:.{digits}f}" for value in values) + unit
    return " / ".join(f"{value:.{digits}f}{unit}" for value in values)


def explain_claim(claim: dict[str, Any], rows: dict[str, Any], *, mode: str = "rls",
                  gating: str | None = None) -> str:
    """One line: what was measured for ``claim`` (from :func:`check_claims` on ``rows``) and, where it is
    known, why the paper's claim is or is not reproduced (the page ``claim["link"]`` explains it at length).

    ``mode`` is the AKF mode and ``gating`` the gate (None: the default, fixed-share) the rows ran with.
    """
    name, holds, numbers = claim["name"], claim["holds"], claim["numbers"]
    literal, paper_gate = mode == "literal", gating == "paper"
    same_dynamics = "eq. 6 gives all experts the same dynamics"
    slow_gate = "the paper's gate learns too slowly, its weights stay near uniform"
    if name == "ordering":
        if holds:
            if literal or paper_gate:
                return "std and max: mixture < single AKF < random mixture, X and Y"
            return "with our fixed-share gate; not with the paper's own gate (--gating paper)"
        broken = []
        for axis in ("X", "Y"):
            for stat in ("std", "max"):
                mixture, single, random = (numbers[f"{axis}.{stat}.{row}"] for row in ("softmax", "single", "random"))
                if not mixture < single:
                    broken.append(f"{stat} {axis}: mixture {mixture:.3g} >= single {single:.3g}")
                if not single < random:
                    broken.append(f"{stat} {axis}: single {single:.3g} >= random {random:.3g}")
        text = broken[0] + (f" (+{len(broken) - 1} more)" if len(broken) > 1 else "")
        cause = same_dynamics if literal else slow_gate if paper_gate else None
        return f"{text}: {cause}" if cause else text
    if name == "single_over_softmax_3x":
        ratios = f"{_pair(numbers, 'rms_ratio')} in RMS, {_pair(numbers, 'max_ratio')} in max"
        if holds:
            return ratios
        if literal:
            return f"{ratios}: {same_dynamics}"
        if paper_gate:
            return f"{ratios}: {slow_gate}"
        best, single = rows.get("best_expert_hindsight"), rows.get("single_akf")
        if best and single:
            gap = 100 * max(single[axis]["rms"] / best[axis]["rms"] - 1.0 for axis in ("X", "Y"))
            if gap <= 20:
                return f"{ratios}: our single AKF is already within {max(gap, 0):.0f} % of the best expert in RMS"
        return ratios
    if name == "random_over_single_3x":
        ratios = _pair(numbers, "rms_ratio")
        if holds:
            return ratios
        return f"{ratios}: every expert of the bank predicts well, so a random mix of them does too"
    if name == "one_hot":
        share = f"largest > {ONE_HOT_THRESHOLD} on {100 * numbers['fraction']:.1f} % of the frames"
        if holds:
            return share
        if literal:
            return f"{share}: {same_dynamics}, none stands out"
        if paper_gate:
            return f"{share}: {slow_gate}"
        return f"{share}: the fixed-share gate spreads it over near-equal experts"
    if name == "mixture_beats_peers":
        peers = sorted({key.split(".", 1)[1] for key in numbers} - {"softmax"}, key=_CLAIM_PEERS.index)
        mixture = {axis: numbers[f"{axis}.softmax"] for axis in ("X", "Y")}
        if holds:
            best = {axis: min(peers, key=lambda peer: numbers[f"{axis}.{peer}"]) for axis in ("X", "Y")}
            if best["X"] == best["Y"]:
                peer_text = f"{_SHORT[best['X']]} {_pair(numbers, best['X'], ' px', 3)}"
            else:
                peer_text = " / ".join(f"{_SHORT[best[axis]]} {numbers[f'{axis}.{best[axis]}']:.3f}"
                                       for axis in ("X", "Y")) + " px"
            return f"mixture {_pair(numbers, 'softmax', ' px', 3)}, best peer {peer_text}"
        beaten = []
        for axis in ("X", "Y"):
            better = sorted((peer for peer in peers if numbers[f"{axis}.{peer}"] < mixture[axis]),
                            key=lambda peer: numbers[f"{axis}.{peer}"])
            if better:
                beaten.append(f"{axis}: mixture {mixture[axis]:.3f} px > " +
                              ", ".join(f"{_SHORT[peer]} {numbers[f'{axis}.{peer}']:.3f}" for peer in better))
        return "; ".join(beaten)
    if name in ("within_5pct_of_best_expert", "default_within_5pct_of_best_expert"):
        text = f"ratio {_pair(numbers, 'ratio', '', 3)}"
        if all(numbers[f"{axis}.ratio"] < 1.0 for axis in ("X", "Y")):
            text += ": better than the oracle"
        return text
    if name == "default_beats_peers_by_3pct":
        return (f"default bank {_pair(numbers, 'default', ' px', 3)}, "
                f"{_pair(numbers, 'ratio_to_best_peer', 'x', 3)} the best peer")
    return ""
