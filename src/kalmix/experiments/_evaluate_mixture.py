"""kalmix's rows of the evaluation (:mod:`kalmix.experiments.evaluate`): the bank run online as ``kalmix predict``
runs it, with its intervals and the best expert in hindsight; the paper's AKF mixture and other
:func:`kalmix.bank.make_params` mixtures; and the mixture's length unit tuned on the tuning part."""

from __future__ import annotations

import math

import numpy as np

from ..bank import DEFAULT_BANK, GATE_OPTIONS, LENGTH_UNIT_RANGE, make_bank, make_params
from ..core.mixture import init_state, predict, step
from ..streaming import auto_reach, auto_time_unit
from ._evaluate_experts import expert_name, single_expert_bank
from ._evaluate_scores import forecast_errors
from ._evaluate_segments import shift, to_segments, to_tracks, track_layout


#: Multiples of the rule's length unit tried for the mixture on the tuning part.
UNIT_FACTORS = (1.0, 3.0, 10.0, 30.0)


def run_mixture(params, values, horizon, state=None, experts=False, lengths=None):
    """Online run over (T, S, p): one-step and horizon-step predictions (and experts').

    Column ``j`` is stepped only over its first ``lengths[j]`` rows, each column with its
    own state from start to end (padding is never fed to the filters; outputs past a
    column's length are NaN). The compiled engine runs it when numba is installed, the
    numpy reference otherwise; both give the same numbers, whatever the batching.
    """
    t_count, s, p = values.shape
    state = init_state(params, s, stream_ids=np.zeros(s, dtype=np.int64)) if state is None else state
    lengths = np.full(s, t_count) if lengths is None else np.asarray(lengths)
    from ..core.fast import numba_available, run_fast

    if numba_available():
        first = run_fast(params, values, state, lengths=lengths, expert_predictions=experts)
        one, one_experts = first.predictions, first.expert_predictions
        ahead, ahead_experts = one, one_experts
        if horizon > 1:
            later = run_fast(params, values, state, lengths=lengths, expert_predictions=experts, horizon=horizon)
            ahead, ahead_experts = later.predictions, later.expert_predictions
        return one, ahead, one_experts, ahead_experts
    k = params.n_experts
    one = np.full((t_count, s, p), np.nan)
    ahead = np.full((t_count, s, p), np.nan) if horizon > 1 else one
    one_experts = np.full((t_count, s, k, p), np.nan) if experts else None
    ahead_experts = (np.full((t_count, s, k, p), np.nan) if horizon > 1 else one_experts) if experts else None
    for t in range(t_count):
        active = t < lengths
        new, out = step(params, state, values[t])
        state = type(state)(*(np.where(active.reshape((-1,) + (1,) * (n.ndim - 1)), n, o)
                              for n, o in zip(new, state)))
        one[t, active] = out.prediction[active]
        if experts:
            one_experts[t, active] = out.expert_predictions[active]
        if horizon > 1:
            pred, expert_pred = predict(params, state, horizon)
            ahead[t, active] = pred[active]
            if experts:
                ahead_experts[t, active] = expert_pred[active]
    return one, ahead, one_experts, ahead_experts


def _calibration(errors, std, covariance, scored):
    """Coverage of mean ± 1.96 std per coordinate, and mean NEES, over the scored pairs."""
    ok = scored & np.isfinite(errors).all(axis=-1) & np.isfinite(std).all(axis=-1)
    if not ok.any():
        return {"coverage_95": float("nan"), "mean_nees": float("nan"), "median_nees": float("nan"), "count": 0}
    e, s = errors[ok], std[ok]
    coverage = float(np.mean(np.abs(e) <= 1.959963984540054 * s))
    out = {"coverage_95": coverage, "count": int(ok.sum())}
    if covariance is not None:
        c = covariance[ok]
        with np.errstate(all="ignore"):   # a singular covariance (an exact forecast) gets its pseudo-inverse
            nees = np.einsum("ni,nij,nj->n", e, np.linalg.pinv(c), e)
        out["mean_nees"] = float(np.nanmean(nees))
        out["median_nees"] = float(np.nanmedian(nees))
    return out


def run_bank(bank, streams, horizon, scored, warm=True, restart_gaps=True):
    """The bank's one-step and ``horizon``-step predictions in this module's convention, and the oracle.

    ``one[t]`` predicts row ``t + 1`` (the engine's forecast of that row), ``ahead[t]``
    row ``t + horizon`` (made after row ``t`` for that row's time), with the weights of
    the lead head (learned on ``horizon``-step errors) when the bank has one; ``plain``
    is the same with the one-step weights. With ``warm``, a track's segments run as
    ``kalmix predict`` runs them (:func:`track_layout`). The best expert in hindsight is
    chosen per track from the engine's per-expert squared errors over the reported rows,
    then rerun alone (experts do not depend on each other, so alone it predicts what it
    predicted in the bank). ``calibration`` holds the coverage and NEES of the intervals.
    ``restart_gaps=False`` (with ``warm``) bridges the gaps instead: the experts go on across them.
    """
    from ..core.compiled import numba_available

    values, times, lengths = streams.values, streams.times, streams.lengths
    run = _engine_run()
    if warm:
        tv, tt, tl, restart, rows, columns = track_layout(streams)
        seg_ahead = shift(times, horizon)   # the row `horizon` later in the same segment (NaN past its end)
        t_ahead = to_tracks(seg_ahead, rows, columns, tt.shape, np.nan)
        t_scored = to_tracks(scored, rows, columns, tt.shape)
        t_scored_ahead = to_tracks(shift(scored, horizon, False), rows, columns, tt.shape)
        back = lambda a: None if a is None else to_segments(a, rows, columns)  # noqa: E731
    else:
        tv, tt, tl, restart, t_ahead = values, times, lengths, None, shift(times, horizon)
        t_scored, t_scored_ahead = scored, shift(scored, horizon, False)
        back = lambda a: a  # noqa: E731
    result = run(bank, tv, tt, lengths=tl, ahead_times=t_ahead, ahead_frames=horizon,
                 restart=restart if restart_gaps else None,
                 record_covariance=True,
                 **({"score": t_scored, "score_ahead": t_scored_ahead} if numba_available() else
                    {"record_experts": True}))
    forecasts, std, cov = back(result.forecasts), back(result.std), back(result.covariance)
    one = shift(forecasts, 1)
    plain = back(result.ahead)
    ahead = back(result.lead) if result.lead is not None else plain
    ahead_std = back(result.lead_std) if result.lead is not None else back(result.ahead_std)
    # the rows the one-step RMS scores (forecast_errors): not a segment's first, which the segment layout cannot predict
    # (the track layout forecasts it from the previous segment, across the gap: that is not scored either)
    predictable = scored & (np.arange(len(scored)) >= 1)[:, None]
    calibration = {"one_step": _calibration(values - forecasts, std, cov, predictable)}
    if horizon > 1:
        calibration["horizon"] = _calibration(shift(values, horizon) - ahead, ahead_std,
                                              back(result.lead_covariance), shift(scored, horizon, False))
    if numba_available():
        sums, counts = result.experts, result.weights
    else:
        err = np.sum((result.experts - tv[:, :, None, :]) ** 2, axis=-1)
        ok = t_scored[..., None] & np.isfinite(err)
        sums, counts = np.where(ok, err, 0.0).sum(axis=0), ok.sum(axis=0)
    if warm:   # per track already: put each on its track's first segment column
        first = np.unique(columns, return_index=True)[1]
        sums_seg, counts_seg = np.zeros((len(columns), bank.n_experts)), np.zeros((len(columns), bank.n_experts))
        sums_seg[first], counts_seg[first] = sums, counts
        sums, counts = sums_seg, counts_seg
    n_tracks = len(streams.track_ids)
    per_track = np.zeros((n_tracks, bank.n_experts))
    per_count = np.zeros_like(per_track)
    np.add.at(per_track, streams.track_of, sums)
    np.add.at(per_count, streams.track_of, counts)
    mse = np.where(per_count > 0, per_track / np.maximum(per_count, 1), np.inf)
    best = np.where(np.isfinite(mse).any(axis=1), np.argmin(mse, axis=1), 0)
    oracle_one, oracle_ahead = np.full_like(one, np.nan), np.full_like(one, np.nan)
    picks = {}
    ahead_times = shift(times, horizon)
    for expert in np.unique(best):
        tracks = np.flatnonzero(best == expert)
        chosen = np.flatnonzero(np.isin(streams.track_of, tracks))
        alone = single_expert_bank(bank, int(expert))
        sub = run(alone, values[:, chosen], times[:, chosen], lengths=lengths[chosen],
                  ahead_times=ahead_times[:, chosen], ahead_frames=horizon)
        oracle_one[:, chosen] = shift(sub.forecasts, 1)
        oracle_ahead[:, chosen] = sub.ahead
        for i in tracks:
            picks[str(streams.track_ids[i])] = expert_name(bank, int(expert))
    calibration["_arrays"] = (forecasts, cov)   # for the interval figure; not in the JSON
    return (one, (ahead if horizon > 1 else one), picks, (oracle_one, oracle_ahead if horizon > 1 else oracle_one),
            (one, plain), calibration)


def _engine_run():
    from ..core import engine
    from ..core.compiled import numba_available

    if numba_available():
        from ..core.compiled import engine as compiled

        return compiled.run
    return engine.run


def tune_unit(values, tuning, rule, n_experts, seed, options):
    """The mixture's length unit: the multiple of the rule with the lowest one-step RMS on the tuning part."""
    last = int(np.flatnonzero(tuning.any(axis=1)).max()) + 1
    part = np.where(tuning[:last, :, None], values[:last], np.nan)
    columns = np.flatnonzero(tuning.any(axis=0))
    part, mask = part[:, columns], tuning[:last, columns]
    scores = {}
    for factor in [f for f in UNIT_FACTORS if rule * f <= LENGTH_UNIT_RANGE[1]]:   # (near the top: fewer)
        params = make_params(values.shape[2], n_experts, seed=seed, length_unit=rule * factor, **options)
        errors = forecast_errors(run_mixture(params, part, 1, lengths=mask.sum(axis=0))[0], part, 1, mask)
        scores[factor] = float(np.sqrt(np.nanmean(errors**2))) if np.isfinite(errors).any() else math.inf
    best = min(scores, key=lambda f: scores[f] if math.isfinite(scores[f]) else math.inf)
    return rule * best, {str(k): v for k, v in scores.items()}


def _settled_reach(streams, tuning, learning, rule, time_unit, n_experts, seed, bank_options):
    """The reach ``"auto"`` settles at for the tuning part, as ``kalmix predict --no-population-prior`` settles it on
    a file (:meth:`kalmix.streaming.TrackPredictor.learn_time_unit`: on heavy-tailed steps, a pilot of both
    choices); None on other steps."""
    import pandas as pd

    from ..streaming import StreamConfig, TrackPredictor

    if auto_reach(learning) is None:
        return None
    t, s = np.nonzero(tuning if tuning.any() else np.isfinite(streams.times))
    order = np.lexsort((t, s))   # each segment's rows in time order, one segment after another
    t, s = t[order], s[order]
    names = [f"c{j}" for j in range(streams.values.shape[2])]
    table = pd.DataFrame({"track_id": s, "time": streams.times[t, s],
                          **{name: streams.values[t, s, j] for j, name in enumerate(names)}})
    config = StreamConfig(length_unit=rule, time_unit=time_unit, n_experts=n_experts, seed=seed, max_gap_factor=np.inf,
                          population_prior=False, bank=bank_options.get("kind", DEFAULT_BANK["kind"]),
                          rule=bank_options.get("rule", DEFAULT_BANK["rule"]), geographic=False)
    pilot = TrackPredictor(config)
    pilot.learn_time_unit(table, names)
    return pilot.config.reach


def run_kalmix(streams, scored, tuning, horizon, rule, unit, n_experts, seed, options, bank_options, predictions,
               tuned, log):
    """kalmix's rows: the bank (``bank_options``, as ``kalmix predict`` makes it with length unit ``rule`` and the
    time unit of the tuning part) and the paper's AKF mixture (length unit ``unit``, the gate's ``options`` too).
    The best expert in hindsight's picks per track and its predictions, and the mixture's forecasts and
    covariances (for the interval figure)."""
    values, p = streams.values, streams.values.shape[2]
    bank_options = {"reach": "auto", **(bank_options or DEFAULT_BANK)}
    time_unit = bank_options.pop("time_unit", None)   # given (--time-unit), or learned as predict learns it
    learning = np.where(tuning, streams.times, np.nan) if tuning.any() else streams.times
    if time_unit is None:
        time_unit = auto_time_unit(learning)
    if bank_options.get("reach") == "auto":   # settled from the same steps and a pilot, as predict settles it
        bank_options["reach"] = _settled_reach(streams, tuning, learning, rule, time_unit, n_experts, seed,
                                               bank_options)
    # the AKF family takes K and the options as predict's does (the gate's reach only the AKF mixture row)
    family = {"n_akf": n_experts, "akf_options": {k: v for k, v in options.items() if k not in GATE_OPTIONS}}
    bank = make_bank(p, length_unit=rule, time_unit=time_unit, seed=seed,
                     lead=horizon * time_unit if horizon > 1 else None, **{**family, **bank_options})
    tuned["mixture"] = {"bank": bank.description, "n_experts": bank.n_experts}
    log(f"mixture: {bank.description['kind']} bank of {bank.n_experts} experts, rule {bank.rule} "
        f"(length unit {rule:.4g}, time unit {time_unit:.4g}"
        + ("" if bank.description["reach"] is None else f", reach {bank.description['reach']:g} time units") + ")")
    one, ahead, picks, oracle, plain, calibration = run_bank(bank, streams, horizon, scored)
    predictions["mixture"] = (one, ahead)
    intervals = calibration.pop("_arrays")
    tuned["mixture"]["calibration"] = calibration
    if horizon > 1:
        predictions["mixture, one-step weights"] = plain
    log(f"AKF mixture (the paper's: K={n_experts}, fixed share, length unit {unit:.4g})")
    mix_params = make_params(p, n_experts, seed=seed, length_unit=unit, **options)
    predictions["AKF mixture (paper)"] = run_mixture(mix_params, values, horizon, lengths=streams.lengths)[:2]
    return picks, oracle, intervals
