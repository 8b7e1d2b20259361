"""An honest comparison on a user's tracks: the mixture beside the predictors one would pick instead.

:func:`evaluate_table` takes a track table (``track_id, time, positions``; see
:mod:`kalmix.io`), cuts every track into segments at time gaps with the same causal
rule as ``kalmix predict`` (:mod:`kalmix.streaming`), runs every predictor online over
every segment, and summarises the one-step and ``horizon``-step errors per track and
overall.

Fair tuning, all on the same tuning part
----------------------------------------
The first ``tuning_fraction`` (default 20 %) of each track's samples is the *tuning
part*; errors are reported on the rest only (every predictor still runs online from
the first sample). On the tuning part:

- the mixture's (and the single AKF's) ``length_unit``, unless given: the documented
  rule :func:`kalmix.streaming.auto_length_unit` (median absolute second difference)
  gives ``u``; the mixture is run on the tuning part with ``u`` times each of
  :data:`UNIT_FACTORS` (1, 3, 10, 30) and the factor with the lowest one-step RMS is
  kept (the rule measures the noise; smooth but manoeuvring data such as a kicked ball
  needs a larger unit so that the bank's process-noise grid covers the manoeuvres);
- the CV and CA Kalman filters get the process/measurement noise variances with the
  lowest one-step RMS over the grid ``process ∈ geomspace(1e-3, 1e5, 17) · u²``,
  ``measurement ∈ {0.05, 0.25, 1, 4} · u²`` (:data:`kalmix.peers.FIXED_GRID` widened
  upward; ``u`` is the rule's unit) — 68 candidates each, all run at once;
- filterpy's IMM (:func:`kalmix.peers.imm_predictions`) gets the best of the grid
  ``cv_process ∈ {0.1, ..., 1000}``, ``ca_process ∈ {0.01, ..., 100}`` (decades),
  ``switch ∈ {0.02, 0.1}`` (times ``u²``) with the CV filter's tuned measurement
  noise, scored on the tuning part of up to 3 longest segments (at most 400 samples
  each). The IMM gives one-step predictions only.

The best expert in hindsight is an oracle: per track, the single expert of the
mixture's bank with the lowest error over the reported part.
"""

from __future__ import annotations

import importlib.util
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..bank import (DEFAULT_BANK, GATE_OPTIONS, LENGTH_UNIT_RANGE, check_automatic_length_unit, check_horizon,
                    check_length_unit, make_bank, make_params)
from ..core.mixture import init_state, predict, step
from ..io.geo import local_table, resolve_axes, std_names
from ..metrics import error_summary
from ..streaming import GapTracker, StreamConfig, auto_time_unit, length_unit_rule

__all__ = ["Streams", "EvaluationResult", "split_streams", "evaluate_table", "PREDICTORS", "ERROR_METRICS",
           "NOT_PEERS", "error_measure", "verdict", "ranking", "format_result"]

#: Row names in table order.
PREDICTORS = ("mixture", "AKF mixture (paper)", "no prediction", "CV Kalman", "CA Kalman",
              "IMM (filterpy)", "CV Kalman (real dt)", "CA Kalman (real dt)", "IMM (filterpy, real dt)",
              "MMAE bank (filterpy, real dt)", "Holt-Winters (river)", "RLS AR (padasip)",
              "local linear trend (statsmodels ML)", "single AKF", "best expert (hindsight)")
_FIXED_PROCESS = tuple(float(v) for v in np.geomspace(1e-3, 1e5, 17))
_FIXED_MEASUREMENT = (0.05, 0.25, 1.0, 4.0)
#: Multiples of the rule's length unit tried for the mixture on the tuning part.
UNIT_FACTORS = (1.0, 3.0, 10.0, 30.0)
_IMM_GRID = {"cv_process_noise": (0.1, 1.0, 10.0, 100.0, 1000.0), "ca_process_noise": (0.01, 0.1, 1.0, 10.0, 100.0),
             "switch_probability": (0.02, 0.1)}


@dataclass
class Streams:
    """Tracks cut into segments, as dense arrays (one column per segment).

    ``values`` (T, S, p) NaN-padded; ``times`` (T, S); ``lengths`` (S,); ``track_of`` (S,)
    index into ``track_ids``; ``sample_index`` (T, S) the row's index within its track
    (-1 for padding).
    """

    values: np.ndarray
    times: np.ndarray
    lengths: np.ndarray
    track_of: np.ndarray
    track_ids: list
    sample_index: np.ndarray
    position_names: tuple


def split_streams(table, *, max_gap: float | None = None, max_gap_factor: float = 3.0,
                  max_samples: int | None = None) -> Streams:
    """Cut each track of a track table into segments with the ``kalmix predict`` gap rule."""
    names = tuple(c for c in table.columns if c not in ("track_id", "time"))
    config = StreamConfig(max_gap=max_gap, max_gap_factor=max_gap_factor)
    columns, track_ids = [], []
    for track, group in table.groupby("track_id", sort=False):
        if max_samples is not None:
            group = group.iloc[:max_samples]
        gaps = GapTracker()
        times = group["time"].to_numpy(np.float64)
        values = group[list(names)].to_numpy(np.float64)
        starts = []
        for i, t in enumerate(times):
            new = gaps.advance(float(t), config)
            if new is None:
                raise ValueError(f"track {track!r}: times must increase (row {i} at {t}); read the file "
                                 "with kalmix.io.read_tracks, which sorts and de-duplicates")
            if new:
                starts.append(i)
        starts.append(len(times))
        track_ids.append(track)
        for a, b in zip(starts[:-1], starts[1:]):
            columns.append((len(track_ids) - 1, a, values[a:b], times[a:b]))
    if not columns:
        raise ValueError("no rows to evaluate")
    length = max(len(c[2]) for c in columns)
    s, p = len(columns), len(names)
    values = np.full((length, s, p), np.nan)
    times = np.full((length, s), np.nan)
    index = np.full((length, s), -1, dtype=np.int64)
    for j, (_, first, v, t) in enumerate(columns):
        values[:len(v), j], times[:len(v), j] = v, t
        index[:len(v), j] = first + np.arange(len(v))
    return Streams(values, times, np.array([len(c[2]) for c in columns]),
                   np.array([c[0] for c in columns]), track_ids, index, names)


def _run(params, values, horizon, state=None, experts=False, lengths=None):
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


def _shift(array, h, fill=np.nan):
    """``out[t] = array[t + h]`` along the first axis (``fill`` past the end)."""
    out = np.full_like(array, fill)
    if h < len(array):
        out[:len(array) - h] = array[h:]
    return out


def track_layout(streams: Streams):
    """Segments joined back into tracks (one column per track), with a restart at each segment start.

    Returns ``(values (L, n, p), times (L, n), lengths (n,), restart (L, n), rows, columns)``:
    segment-layout entry ``[t, j]`` is track-layout entry ``[rows[t, j], columns[j]]``
    (``rows`` is the sample index, -1 on padding). This is how ``kalmix predict`` runs a
    track: the families start again after a gap, the rule and the calibration go on.
    """
    n = len(streams.track_ids)
    lengths = np.zeros(n, dtype=np.int64)
    np.add.at(lengths, streams.track_of, streams.lengths)
    p = streams.values.shape[2]
    values, times = np.full((int(lengths.max()), n, p), np.nan), np.full((int(lengths.max()), n), np.nan)
    restart = np.zeros(times.shape, dtype=bool)
    present = streams.sample_index >= 0
    t_seg, j_seg = np.nonzero(present)
    rows, cols = streams.sample_index[t_seg, j_seg], streams.track_of[j_seg]
    values[rows, cols], times[rows, cols] = streams.values[t_seg, j_seg], streams.times[t_seg, j_seg]
    starts = streams.sample_index[0] > 0   # a segment that is not its track's first
    restart[streams.sample_index[0, starts], streams.track_of[starts]] = True
    return values, times, lengths, restart, streams.sample_index, streams.track_of


def _to_segments(array, rows, columns, fill=np.nan):
    """Track-layout ``(L, n, ...)`` back to the segment layout ``(T, S, ...)`` of ``rows, columns``."""
    out = np.full(rows.shape + array.shape[2:], fill, dtype=array.dtype)
    present = rows >= 0
    t_seg, j_seg = np.nonzero(present)
    out[t_seg, j_seg] = array[rows[t_seg, j_seg], columns[j_seg]]
    return out


def _to_tracks(array, rows, columns, shape, fill=False):
    out = np.full(shape, fill, dtype=array.dtype)
    present = rows >= 0
    t_seg, j_seg = np.nonzero(present)
    out[rows[t_seg, j_seg], columns[j_seg]] = array[t_seg, j_seg]
    return out


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


def _run_bank(bank, streams, horizon, scored, warm=True, restart_gaps=True):
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
        seg_ahead = _shift(times, horizon)   # the row `horizon` later in the same segment (NaN past its end)
        t_ahead = _to_tracks(seg_ahead, rows, columns, tt.shape, np.nan)
        t_scored = _to_tracks(scored, rows, columns, tt.shape)
        t_scored_ahead = _to_tracks(_shift(scored, horizon, False), rows, columns, tt.shape)
        back = lambda a: None if a is None else _to_segments(a, rows, columns)  # noqa: E731
    else:
        tv, tt, tl, restart, t_ahead = values, times, lengths, None, _shift(times, horizon)
        t_scored, t_scored_ahead = scored, _shift(scored, horizon, False)
        back = lambda a: a  # noqa: E731
    result = run(bank, tv, tt, lengths=tl, ahead_times=t_ahead, ahead_frames=horizon,
                 restart=restart if restart_gaps else None,
                 record_covariance=True,
                 **({"score": t_scored, "score_ahead": t_scored_ahead} if numba_available() else
                    {"record_experts": True}))
    forecasts, std, cov = back(result.forecasts), back(result.std), back(result.covariance)
    one = _shift(forecasts, 1)
    plain = back(result.ahead)
    ahead = back(result.lead) if result.lead is not None else plain
    ahead_std = back(result.lead_std) if result.lead is not None else back(result.ahead_std)
    # the rows the one-step RMS scores (_errors): not a segment's first, which the segment layout cannot predict
    # (the track layout forecasts it from the previous segment, across the gap: that is not scored either)
    predictable = scored & (np.arange(len(scored)) >= 1)[:, None]
    calibration = {"one_step": _calibration(values - forecasts, std, cov, predictable)}
    if horizon > 1:
        calibration["horizon"] = _calibration(_shift(values, horizon) - ahead, ahead_std,
                                              back(result.lead_covariance), _shift(scored, horizon, False))
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
    ahead_times = _shift(times, horizon)
    for expert in np.unique(best):
        tracks = np.flatnonzero(best == expert)
        chosen = np.flatnonzero(np.isin(streams.track_of, tracks))
        alone = _single_expert_bank(bank, int(expert))
        sub = run(alone, values[:, chosen], times[:, chosen], lengths=lengths[chosen],
                  ahead_times=ahead_times[:, chosen], ahead_frames=horizon)
        oracle_one[:, chosen] = _shift(sub.forecasts, 1)
        oracle_ahead[:, chosen] = sub.ahead
        for i in tracks:
            picks[str(streams.track_ids[i])] = _expert_name(bank, int(expert))
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


def _locate(bank, expert):
    for family, columns in zip(bank.families, bank.slices()):
        if columns.start <= expert < columns.stop:
            return family, expert - columns.start
    raise IndexError(expert)


def _expert_name(bank, expert):
    family, i = _locate(bank, expert)
    if family.kind == "akf":
        return f"akf[{i}]"
    if family.kind == "ar":
        fp = family.params
        return f"ar{fp.order}(forgetting={fp.forgetting[i]:.4g}, ridge={fp.ridge[i]:.3g})"
    if family.kind == "turn":
        return f"turn(gain={family.params.gain[i]:.3g})"
    return (f"{family.kind}(q={family.params.process_noise[i]:.3g}, r={family.params.measurement_noise[i]:.3g})")


def _single_expert_bank(bank, expert):
    """A bank of the one expert ``expert`` (same parameters), under the same rule."""
    from dataclasses import replace

    from ..core.engine import Family

    family, i = _locate(bank, expert)
    if family.kind == "akf":
        params = family.params
        per_expert = {name: getattr(params, name)[i:i + 1] for name in (
            "forgetting", "ridge", "process_noise", "measurement_noise", "initial_variance", "initial_velocity",
            "expert_scale")}
        single = replace(params, **per_expert)
    elif family.kind == "ar":
        single = family.params._replace(forgetting=family.params.forgetting[i:i + 1],
                                        ridge=family.params.ridge[i:i + 1])
    elif family.kind == "turn":
        single = family.params._replace(gain=family.params.gain[i:i + 1])
    else:
        single = family.params._replace(process_noise=family.params.process_noise[i:i + 1],
                                        measurement_noise=family.params.measurement_noise[i:i + 1],
                                        initial_variance=family.params.initial_variance[i:i + 1])
    return replace(bank, families=(Family(family.kind, single),), lead=None)


#: Rows of the peers of :mod:`kalmix.peer_models`, by their registry name.
PEER_LABELS = {"cv_dt": "CV Kalman (real dt)", "ca_dt": "CA Kalman (real dt)", "imm_dt": "IMM (filterpy, real dt)",
               "mmae_dt": "MMAE bank (filterpy, real dt)", "holt_winters": "Holt-Winters (river)",
               "rls_ar": "RLS AR (padasip)", "ucm_llt": "local linear trend (statsmodels ML)"}


def _leave_out(label, error, tuned, log) -> None:
    """A peer that failed on this data: said now (``log``) and recorded in ``tuned`` (the table names it)."""
    reason = f"{type(error).__name__}: {error}"
    log(f"{label}: left out, it failed on this data ({reason})")
    tuned[label] = {"left_out": reason}


def _run_peer_models(streams, tuning, unit, horizon, predictions, tuned, log):
    """Tune every installed peer of :mod:`kalmix.peer_models` on the tuning part and run it on every segment.

    A peer with ``max_rows`` runs on the first rows of each segment (:func:`~kalmix.peer_models.row_budget`);
    its rows past that are not predicted, which the ``tuned`` entry says (``rows_evaluated``).
    """
    from ..peer_models import PEERS, available, row_budget

    time_unit = auto_time_unit(np.where(tuning, streams.times, np.nan) if tuning.any() else streams.times)
    segments = [(streams.values[:n, j], streams.times[:n, j], tuning[:n, j]) for j, n in enumerate(streams.lengths)]
    for name, peer in PEERS.items():
        if not available(peer):
            continue
        label = PEER_LABELS.get(name, name)
        keep = row_budget(streams.lengths, peer.max_rows)
        log(f"{label}: tuning and running on {int(keep.sum())} of {int(streams.lengths.sum())} rows")
        cut = [(v[:n], t[:n], m[:n]) for (v, t, m), n in zip(segments, keep) if n > 1]
        try:
            params = peer.tune([c for c in cut if c[2].any()] or cut, unit=unit, time_unit=time_unit)
            one = np.full_like(streams.values, np.nan)
            ahead = np.full_like(streams.values, np.nan) if horizon > 1 else one
            columns = [j for j, n in enumerate(keep) if n >= 2]
            runs = [(streams.values[:keep[j], j], streams.times[:keep[j], j]) for j in columns]
            for h, out in ((1, one), (horizon, ahead)) if horizon > 1 else ((1, one),):
                if peer.predict_many is not None:   # every segment in one batched pass, the same numbers
                    results = peer.predict_many(runs, params, horizon=h)
                else:
                    results = [peer.predict(v, t, params, horizon=h) for v, t in runs]
                for j, result in zip(columns, results):
                    out[:keep[j], j] = result
        except Exception as error:   # noqa: BLE001 - a peer library that fails on this data is left out, said
            _leave_out(label, error, tuned, log)
            continue
        predictions[label] = (one, ahead)
        tuned[label] = {**params, "rows_evaluated": int(keep.sum()), "rows": int(streams.lengths.sum())}


def _errors(predictions, values, horizon, scored):
    """``values[t+h] - predictions[t]`` aligned on the target frame, NaN outside ``scored``."""
    errors = np.full_like(values, np.nan)
    errors[horizon:] = values[horizon:] - predictions[:-horizon]
    errors[~scored] = np.nan
    return errors


#: What the error summaries of :func:`evaluate_table` pool (:func:`error_measure`).
ERROR_METRICS = ("euclidean", "per-coordinate")


def error_measure(errors: np.ndarray, metric: str) -> np.ndarray:
    """The errors the summaries pool, from the differences ``measurement - forecast`` ``(..., p)``.

    ``"per-coordinate"``: the differences themselves (``p`` values a row). ``"euclidean"``:
    each row's distance ``|e|`` ``(..., 1)``, NaN where a coordinate is (computed without
    overflow for errors near the float range). Every figure of :func:`evaluate_table` goes
    through here, so a distance of another kind (on geographic coordinates, say) is a new
    metric of this function.
    """
    if metric == "per-coordinate":
        return errors
    if metric == "euclidean":
        distance = np.hypot.reduce(errors, axis=-1) if errors.shape[-1] > 1 else np.abs(errors[..., 0])
        return np.where(np.isnan(errors).any(axis=-1), np.nan, distance)[..., None]
    raise ValueError(f"metric: expected one of {', '.join(ERROR_METRICS)}, got {metric!r}")


#: Rows of :func:`evaluate_table` that are not tuned peers (name prefixes): kalmix's own (the mixture and its
#: parts, the paper's AKF rows) and the references (no prediction, the best expert in hindsight).
NOT_PEERS = ("mixture", "AKF mixture", "best expert", "no prediction", "single AKF")
#: kalmix's row: the default bank, as ``kalmix predict`` runs it.
KALMIX = "mixture"
_NOT_AHEAD = "no forecast this far ahead"


def _compare(summaries: dict, which: str) -> dict:
    """kalmix against the best tuned peer in ``summaries`` (``{row: {"one_step" | "horizon": summary}}``)."""
    own = (summaries.get(KALMIX) or {}).get(which) or {}
    kalmix, count = own.get("rms"), own.get("count")
    peers, left_out = {}, {}
    for name, entry in summaries.items():
        if name.startswith(NOT_PEERS):
            continue
        summary = entry.get(which)
        if summary is None:
            left_out[name] = _NOT_AHEAD
        elif summary.get("rms") is None or not math.isfinite(summary["rms"]):
            left_out[name] = "no finite error"
        elif summary.get("count") != count:
            left_out[name] = f"scored on {summary['count']} of the mixture's {count} values (a subsample)"
        else:
            peers[name] = summary["rms"]
    out = {"kalmix_rms": kalmix, "best_peer": None, "best_peer_rms": None, "percent": None, "kalmix_better": None,
           "peers": peers, "left_out": left_out}
    if kalmix is None or not math.isfinite(kalmix):
        return {**out, "text": "kalmix has no scored error to compare"}
    if not peers:
        return {**out, "text": f"kalmix's RMS {kalmix:.4g}; no tuned peer to compare it with"}
    best = min(peers, key=peers.get)   # the first in table order on a tie
    rms = peers[best]
    percent = 100.0 * (kalmix - rms) / rms if rms > 0 else (0.0 if kalmix == rms else math.inf)
    if kalmix == rms:
        how = "kalmix is level with it"
    else:
        how = f"kalmix is {abs(percent):.3g} % {'lower (better)' if kalmix < rms else 'higher (worse)'}"
    return {**out, "best_peer": best, "best_peer_rms": rms, "percent": percent, "kalmix_better": bool(kalmix < rms),
            "text": f"kalmix's RMS {kalmix:.4g}, the best tuned peer {best} {rms:.4g}: {how}"}


def verdict(overall: dict, per_track: dict, horizon: int) -> dict:
    """Who wins: kalmix's RMS against the best tuned peer's, one step ahead and (``horizon > 1``) ``horizon`` ahead.

    Each entry (:func:`_compare`) holds ``kalmix_rms``, ``best_peer``, ``best_peer_rms``,
    ``percent`` (kalmix's RMS relative to the peer's, in %: negative when kalmix is
    better), ``kalmix_better``, every compared peer's RMS, the peers left out with why
    (no forecast that far ahead, a subsample), and a sentence. ``per_track`` holds the same per track.
    """
    which = ("one_step", "horizon") if horizon > 1 else ("one_step",)
    return {**{w: _compare(overall, w) for w in which},
            "per_track": {track: {w: _compare(rows, w) for w in which} for track, rows in per_track.items()}}


def ranking(summaries: dict, horizon: int) -> dict:
    """Row names by RMS, best first (rows without a finite RMS last, in table order), one step and ``horizon`` ahead."""
    def order(which):
        def key(name):
            rms = ((summaries[name] or {}).get(which) or {}).get("rms")
            return (0, rms) if rms is not None and math.isfinite(rms) else (1, 0.0)
        return sorted(summaries, key=key)

    return {"one_step": order("one_step"), **({"horizon": order("horizon")} if horizon > 1 else {})}


def _fixed_params(order, degree, unit, p):
    return make_params(p, 1, dynamics="fixed", order=order, prior_degree=degree, adapt_noise=False,
                       length_unit=unit, process_noise_range=(1.0, 1.0), measurement_noise_range=(1.0, 1.0))


def _tune_fixed(order, degree, unit, values, tuning):
    """Grid search of a fixed CV/CA filter on the tuning part, every candidate in one batched run."""
    last = int(np.flatnonzero(tuning.any(axis=1)).max()) + 1
    lengths = tuning.sum(axis=0)
    values, tuning = values[:last], tuning[:last]
    t_count, s, p = values.shape
    params = _fixed_params(order, degree, unit, p)
    grid = list(itertools.product(_FIXED_PROCESS, _FIXED_MEASUREMENT))
    tiled = np.tile(values, (1, len(grid), 1))
    state = init_state(params, s * len(grid), stream_ids=np.zeros(s * len(grid), dtype=np.int64))
    q = np.repeat([g[0] * unit**2 for g in grid], s)
    r = np.repeat([g[1] * unit**2 for g in grid], s)
    state = state._replace(process_noise=np.broadcast_to(q[:, None, None], state.process_noise.shape).copy(),
                           measurement_noise=np.broadcast_to(r[:, None, None], state.measurement_noise.shape).copy())
    one = _run(params, tiled, 1, state, lengths=np.tile(lengths, len(grid)))[0]
    errors = _errors(one, tiled, 1, np.tile(tuning, (1, len(grid))))
    squared = np.nanmean((errors**2).reshape(t_count, len(grid), s, p).transpose(1, 0, 2, 3).reshape(len(grid), -1),
                         axis=1)
    best = int(np.nanargmin(squared))
    return {"process_noise": grid[best][0] * unit**2, "measurement_noise": grid[best][1] * unit**2}


def _tune_imm(streams, tuning, unit, measurement_noise):
    from ..peers import imm_predictions_many

    order = np.argsort(-streams.lengths)[:3]
    pieces = []
    for j in order:
        rows = np.flatnonzero(tuning[:, j])[:400]
        if rows.size > 10:
            pieces.append(streams.values[rows, j])
    if not pieces:   # too short to tune on: the grid's middle, said in ``tuned``
        return {"measurement_noise": measurement_noise / unit**2, **{k: v[1] for k, v in _IMM_GRID.items()},
                "untuned": "no track's tuning part has more than 10 rows: the grid's middle values"}
    candidates = [dict(zip(_IMM_GRID, candidate), measurement_noise=measurement_noise / unit**2)
                  for candidate in itertools.product(*_IMM_GRID.values())]
    best, best_rms = None, math.inf
    for options, predictions in zip(candidates, imm_predictions_many(pieces, candidates, unit)):   # in one pass
        squared, count = 0.0, 0
        for z, prediction in zip(pieces, predictions):
            e = z[1:] - prediction[:-1]
            e = e[np.isfinite(e)]
            squared, count = squared + float(np.sum(e**2)), count + e.size
        rms = math.sqrt(squared / count) if count else math.inf
        if rms < best_rms:
            best, best_rms = options, rms
    return best


def _tune_unit(values, tuning, rule, n_experts, seed, options):
    """The mixture's length unit: the multiple of the rule with the lowest one-step RMS on the tuning part."""
    last = int(np.flatnonzero(tuning.any(axis=1)).max()) + 1
    part = np.where(tuning[:last, :, None], values[:last], np.nan)
    columns = np.flatnonzero(tuning.any(axis=0))
    part, mask = part[:, columns], tuning[:last, columns]
    scores = {}
    for factor in [f for f in UNIT_FACTORS if rule * f <= LENGTH_UNIT_RANGE[1]]:   # (near the top: fewer)
        params = make_params(values.shape[2], n_experts, seed=seed, length_unit=rule * factor, **options)
        errors = _errors(_run(params, part, 1, lengths=mask.sum(axis=0))[0], part, 1, mask)
        scores[factor] = float(np.sqrt(np.nanmean(errors**2))) if np.isfinite(errors).any() else math.inf
    best = min(scores, key=lambda f: scores[f] if math.isfinite(scores[f]) else math.inf)
    return rule * best, {str(k): v for k, v in scores.items()}


@dataclass
class EvaluationResult:
    """Error summaries (``{"mean_abs", "std", "max", "rms", "count"}``) per predictor.

    ``overall[name]["one_step" | "horizon"]`` and ``per_track[track][name][...]``, of the
    errors ``metric`` says (:func:`error_measure`); ``errors[name]`` holds the one-step
    differences (T, S, p) for plots. ``verdict`` (:func:`verdict`): kalmix against the best
    tuned peer; ``ranking`` (:func:`ranking`): the rows by RMS, best first.
    """

    horizon: int
    length_unit: float
    tuning_fraction: float
    tuned: dict
    predictors: list
    overall: dict
    per_track: dict
    streams: Streams = field(repr=False)
    errors: dict = field(repr=False)
    dataset: str | None = None
    intervals: tuple | None = field(default=None, repr=False)   # mixture's forecasts (T, S, p), covariances
    metric: str = "per-coordinate"
    verdict: dict = field(default_factory=dict)
    ranking: dict = field(default_factory=dict)
    units: str = "data units"   # of the positions, errors and length unit: "metres" for geographic data

    def to_json(self) -> dict:
        """JSON-serialisable summary (no arrays)."""
        def clean(value):
            if isinstance(value, dict):
                return {str(k): clean(v) for k, v in value.items()}
            if isinstance(value, float) and not math.isfinite(value):
                return None
            if isinstance(value, (np.floating, np.integer)):
                return clean(value.item())
            return value

        return clean({"dataset": self.dataset, "horizon": self.horizon, "length_unit": self.length_unit,
                      "tuning_fraction": self.tuning_fraction, "tuned": self.tuned,
                      "predictors": list(self.predictors), "overall": self.overall,
                      "per_track": self.per_track,
                      "tracks": {str(t): int(self.streams.lengths[self.streams.track_of == i].sum())
                                 for i, t in enumerate(self.streams.track_ids)},
                      "errors": self.metric, "verdict": self.verdict, "ranking": self.ranking,
                      "units": self.units})


def _require_errors(values, mask, doing, part, track_lengths):
    """``ValueError`` unless ``mask`` holds a one-step error: a measurement right after another."""
    present = np.isfinite(values).all(axis=-1)
    if not (mask[1:] & present[1:] & present[:-1]).any():
        complete = int(present.sum())
        which = ("" if complete == int(track_lengths.sum()) else
                 f"; only {complete} row(s) have every position column measured (NaN or empty elsewhere: check "
                 "--position)")
        raise ValueError(f"too little data to {doing}: {part} holds no two consecutive measurements of a "
                         f"segment (longest track: {int(track_lengths.max())} row(s) after de-duplicating times"
                         f"{which}; evaluate needs tracks of a few dozen rows, or a smaller --tuning-fraction)")


def evaluate_table(table, *, horizon: int = 1, n_experts: int = 40, seed: int = 0,
                   length_unit: float | None = None, tuning_fraction: float = 0.2,
                   max_gap: float | None = None, max_gap_factor: float = 3.0,
                   max_samples: int | None = None, tracks=None, peers: bool = True,
                   options: dict | None = None, tune_units: bool = True, log=None,
                   bank_options: dict | None = None, metric: str = "per-coordinate",
                   geographic: bool | None = None) -> EvaluationResult:
    """Run every predictor over every track segment and summarise the errors.

    Parameters
    ----------
    table : pandas.DataFrame
        Track table (``track_id``, ``time``, 1–3 position columns), each track in time order.
    horizon : int
        H of the H-step errors (the one-step errors are always reported).
    n_experts, seed : int
        K of the bank's AKF family and of the AKF mixture row, and the seed.
    length_unit : float, optional
        Default: :func:`~kalmix.streaming.auto_length_unit` on the tuning part, times the
        factor of :data:`UNIT_FACTORS` with the lowest one-step RMS there (``tune_units``).
    tuning_fraction : float in [0, 1)
        Leading share of each track used for tuning and not reported.
    max_gap, max_gap_factor
        Gap rule (see :mod:`kalmix.streaming`).
    max_samples : int, optional
        Keep only the first ``max_samples`` rows of each track (a quicker run).
    tracks : sequence, optional
        Keep only these track ids.
    peers : bool
        Include the peers: filterpy's IMM (the ``peers`` extra) and those of
        :mod:`kalmix.peer_models` whose packages are installed.
    tune_units : bool
        Tune the mixture's length unit on the tuning part (else the rule's value).
    options : dict, optional
        Other :func:`kalmix.bank.make_params` arguments: of the AKF mixture row, and of the
        bank's AKF family except the gate's (:data:`kalmix.bank.GATE_OPTIONS`), as in
        ``kalmix predict``.
    log : callable, optional
        Called with a short progress message before each predictor.
    bank_options : dict, optional
        :func:`kalmix.bank.make_bank` arguments of the mixture (default
        :data:`kalmix.bank.DEFAULT_BANK`); its length unit is the rule's
        (:func:`~kalmix.streaming.auto_length_unit`) and its time unit
        :func:`~kalmix.streaming.auto_time_unit`, both on the tuning part.
    metric : {"per-coordinate", "euclidean"}
        What the summaries pool (:func:`error_measure`): each coordinate's error, or each
        row's distance between forecast and measurement (``kalmix evaluate``'s default).
        The result's :attr:`~EvaluationResult.verdict` and ranking use the same.
    geographic : bool or None
        Whether the positions are latitude and longitude in degrees (and an altitude in metres):
        then every predictor runs on metres east and north (and up) of each track's first fix
        (:func:`kalmix.io.geo.local_table`), and the errors, summaries and length unit are in
        metres (:attr:`EvaluationResult.units`). None: when the position names say so (as
        :class:`~kalmix.streaming.StreamConfig`'s ``geographic``).
    """
    horizon = check_horizon(horizon)
    positions = [c for c in table.columns if c not in ("track_id", "time")]
    axes = resolve_axes(positions, geographic)
    if axes is not None:   # errors in metres: every predictor on each track's local frame
        table = local_table(table, positions, axes)
        log_geo = (f"geographic coordinates ({', '.join(positions)}): every predictor runs on "
                   f"{', '.join(std_names(axes))} of each track's first fix; errors in metres")
    units = "metres" if axes is not None else "data units"
    if metric not in ERROR_METRICS:
        raise ValueError(f"metric: expected one of {', '.join(ERROR_METRICS)}, got {metric!r}")
    if length_unit is not None:
        length_unit = check_length_unit(length_unit)
    if not 0 <= tuning_fraction < 1:
        raise ValueError(f"tuning_fraction: expected a number in [0, 1), got {tuning_fraction!r}")
    log = log or (lambda message: None)
    if axes is not None:
        log(log_geo)
    if tracks is not None:
        wanted = {str(t) for t in tracks}
        ids = table["track_id"].astype(str)
        missing = sorted(wanted - set(ids))
        if missing:
            have = list(dict.fromkeys(ids))
            raise ValueError(f"tracks: {missing} not in the data (its track ids: {have[:20]}"
                             f"{' ...' if len(have) > 20 else ''})")
        table = table[ids.isin(wanted)]
    streams = split_streams(table, max_gap=max_gap, max_gap_factor=max_gap_factor, max_samples=max_samples)
    values, p = streams.values, streams.values.shape[2]
    track_lengths = np.bincount(streams.track_of, weights=streams.lengths).astype(int)
    cut = np.ceil(tuning_fraction * track_lengths[streams.track_of]).astype(int)   # (S,)
    present = streams.sample_index >= 0
    scored = present & (streams.sample_index >= cut[None, :])
    tuning = present & ~scored
    options = dict(options or {})
    tuned: dict[str, Any] = {}
    tune_scored = tuning if tuning.any() else scored
    _require_errors(values, tune_scored, "tune the predictors on",
                    f"the first {100 * tuning_fraction:.3g}% of each track (--tuning-fraction)", track_lengths)
    _require_errors(values, scored, "score", "the rest of each track", track_lengths)
    finite = np.isfinite(values).all(axis=-1)
    if horizon > 1 and not (finite & _shift(scored & finite, horizon, False)).any():
        raise ValueError(f"horizon: no measurement of a scored row has one {horizon} rows before it in its "
                         f"segment (longest segment: {int(streams.lengths.max())} rows); give a smaller -H")
    # the peers' noise grids scale with the data's length unit (the rule), whatever unit the mixture is given
    peer_unit, why = length_unit_rule(np.where(tuning[..., None], values, np.nan) if tuning.any() else values)
    if why is not None:   # as predict says it
        log(f"length unit 1 for the peers{'' if length_unit is not None else ' and the mixture'} (the rule could "
            f"not estimate it: the tuning part has {why}; pass --length-unit, or a larger --tuning-fraction)")
    if length_unit is not None:
        unit = rule = float(length_unit)
        tuned["length_unit"] = {"given": unit, "peers": peer_unit}
    else:
        rule = check_automatic_length_unit(peer_unit)
        unit, scores = rule, {}
        if tune_units and tuning.any():
            log(f"AKF rows: tuning their length unit around the rule's {rule:.4g}")
            unit, scores = _tune_unit(values, tuning, rule, n_experts, seed, options)
        tuned["length_unit"] = {"rule": rule, "chosen": unit, "tuning_rms": scores}

    if options:
        tuned["mixture_options"] = options
    predictions: dict[str, tuple] = {}
    time_unit = auto_time_unit(np.where(tuning, streams.times, np.nan) if tuning.any() else streams.times)
    # the AKF family takes K and the options as predict's does (the gate's reach only the AKF mixture row)
    family = {"n_akf": n_experts, "akf_options": {k: v for k, v in options.items() if k not in GATE_OPTIONS}}
    bank = make_bank(p, length_unit=rule, time_unit=time_unit, seed=seed,
                     lead=horizon * time_unit if horizon > 1 else None,
                     **{**family, **dict(bank_options or DEFAULT_BANK)})
    tuned["mixture"] = {"bank": bank.description, "n_experts": bank.n_experts}
    log(f"mixture: {bank.description['kind']} bank of {bank.n_experts} experts, rule {bank.rule} "
        f"(length unit {rule:.4g}, time unit {time_unit:.4g})")
    one, ahead, picks, oracle, plain, calibration = _run_bank(bank, streams, horizon, scored)
    predictions["mixture"] = (one, ahead)
    intervals = calibration.pop("_arrays")
    tuned["mixture"]["calibration"] = calibration
    if horizon > 1:
        predictions["mixture, one-step weights"] = plain
    log(f"AKF mixture (the paper's: K={n_experts}, fixed share, length unit {unit:.4g})")
    mix_params = make_params(p, n_experts, seed=seed, length_unit=unit, **options)
    predictions["AKF mixture (paper)"] = _run(mix_params, values, horizon, lengths=streams.lengths)[:2]

    log("no prediction")
    carried = np.empty_like(values)
    carried[0] = values[0]
    for t in range(1, len(values)):
        carried[t] = np.where(np.isnan(values[t]), carried[t - 1], values[t])
    predictions["no prediction"] = (carried, carried)

    for name, order, degree in (("CV Kalman", 2, 1), ("CA Kalman", 3, 2)):
        log(f"{name}: tuning on the first {100 * tuning_fraction:.3g}% of each track" if tuning.any() else
            f"{name}: tuning on the scored rows themselves (no tuning part: in hindsight)")
        best = _tune_fixed(order, degree, peer_unit, values, tune_scored)
        tuned[name] = best
        params = make_params(p, 1, dynamics="fixed", order=order, prior_degree=degree, adapt_noise=False,
                             length_unit=unit, process_noise_range=(best["process_noise"] / unit**2,) * 2,
                             measurement_noise_range=(best["measurement_noise"] / unit**2,) * 2)
        predictions[name] = _run(params, values, horizon, lengths=streams.lengths)[:2]

    if peers:
        from ..peers import imm_predictions_many

        if importlib.util.find_spec("filterpy") is not None:   # the row of a user who has filterpy's IMM
            log("IMM (filterpy): tuning")
            try:
                best = _tune_imm(streams, tune_scored, peer_unit, tuned["CV Kalman"]["measurement_noise"])
                note = best.pop("untuned", None)
                imm_tuned = {k: v * peer_unit**2 if k != "switch_probability" else v for k, v in best.items()}
                if note:
                    imm_tuned["untuned"] = note
                    log(f"IMM (filterpy): not tuned ({note})")
                log("IMM (filterpy): running")
                imm = np.full_like(values, np.nan)
                runs = imm_predictions_many([values[:n, j] for j, n in enumerate(streams.lengths)], [best],
                                            peer_unit)[0]
                for j, n in enumerate(streams.lengths):
                    imm[:n, j] = runs[j]
            except Exception as error:   # noqa: BLE001 - as the other peers: one wild value can make filterpy's
                _leave_out("IMM (filterpy)", error, tuned, log)   # matrices singular; left out, the run goes on
            else:
                tuned["IMM (filterpy)"] = imm_tuned
                predictions["IMM (filterpy)"] = (imm, None)

    if peers:
        _run_peer_models(streams, tune_scored, peer_unit, horizon, predictions, tuned, log)

    log("single AKF")
    akf_params = make_params(p, 1, seed=seed, length_unit=unit, **{**options, "adapt_noise": False})
    predictions["single AKF"] = _run(akf_params, values, horizon, lengths=streams.lengths)[:2]

    tuned["best expert (hindsight)"] = {"expert_per_track": picks}
    predictions["best expert (hindsight)"] = oracle

    overall, per_track, errors_one = {}, {}, {}
    for name, (first, later) in predictions.items():
        e1 = _errors(first, values, 1, scored)
        errors_one[name] = e1
        m1 = error_measure(e1, metric)
        mh = error_measure(_errors(later, values, horizon, scored), metric) if later is not None else None
        summary = {"one_step": error_summary(m1)}
        if horizon > 1:
            summary["horizon"] = error_summary(mh) if mh is not None else None
        overall[name] = summary
        for i, track in enumerate(streams.track_ids):
            columns = streams.track_of == i
            entry = {"one_step": error_summary(m1[:, columns])}
            if horizon > 1:
                entry["horizon"] = error_summary(mh[:, columns]) if mh is not None else None
            per_track.setdefault(str(track), {})[name] = entry
    return EvaluationResult(horizon=int(horizon), length_unit=unit, tuning_fraction=tuning_fraction,
                            tuned=tuned, predictors=list(predictions), overall=overall, per_track=per_track,
                            streams=streams, errors=errors_one, intervals=intervals, metric=metric,
                            verdict=verdict(overall, per_track, horizon), ranking=ranking(overall, horizon),
                            units=units)


#: Fewer scored rows than this: the interval line of ``kalmix evaluate`` says they are too few to judge.
FEW_CALIBRATION_ROWS = 100
_METRIC_WORDS = {"euclidean": "errors are distances |e| per row", "per-coordinate": "errors per coordinate"}


def _verdict_lines(result, entry, indent=""):
    """The verdict sentences of one table: one step ahead, and ``horizon`` rows ahead."""
    lines = [f"{indent}one step ahead: {entry['one_step']['text']}"]
    if "horizon" in entry:
        lines.append(f"{indent}{result.horizon} rows ahead: {entry['horizon']['text']}")
    return lines


def _table(title, summaries, result, entry):
    """A table of ``summaries`` ranked by one-step RMS, kalmix's row and the best tuned peers' marked."""
    best_peer = entry["one_step"]["best_peer"]
    best_ahead = entry.get("horizon", {}).get("best_peer")
    horizon = result.horizon
    order = ranking(summaries, horizon)["one_step"]
    width = max([26] + [len(name) + 2 for name in summaries])
    lines = [title, f"{'rank':>4}  {'predictor':<{width}}{'mean|e|':>10}{'RMS':>10}{'max':>10}"
             + (f"  |{f'mean|e| H={horizon}':>14}{'RMS':>10}{'max':>10}" if horizon > 1 else "")]
    for rank, name in enumerate(order, 1):
        one = summaries[name]["one_step"]
        line = f"{rank:>4}  {name:<{width}}{one['mean_abs']:>10.4g}{one['rms']:>10.4g}{one['max']:>10.4g}"
        if horizon > 1:
            later = summaries[name].get("horizon")
            line += "  |" + (f"{later['mean_abs']:>14.4g}{later['rms']:>10.4g}{later['max']:>10.4g}" if later
                             else f"{'-':>14}{'-':>10}{'-':>10}")
        marks = (["kalmix"] if name == KALMIX else []) + (["best tuned peer"] if name == best_peer else []) \
            + ([f"best tuned peer {horizon} rows ahead"] if name == best_ahead and best_ahead != best_peer else [])
        lines.append(line + (f"  <- {', '.join(marks)}" if marks else ""))
    return lines


def format_result(result: EvaluationResult, per_track: bool = True) -> str:
    """The text ``kalmix evaluate`` prints: the verdict first, then the tables ranked by one-step RMS."""
    streams = result.streams
    n_rows = int(streams.lengths.sum())
    tuning = (f"first {100 * result.tuning_fraction:.3g}% of each track tunes the peers and is not scored"
              if result.tuning_fraction > 0 else
              "no tuning part (--tuning-fraction 0): the peers are tuned on the scored rows, in hindsight")
    bank = result.tuned.get("mixture", {}).get("bank", {})
    if "length_unit" in bank and "time_unit" in bank:
        units = (f"the mixture's length unit {bank['length_unit']:.4g} and time unit {bank['time_unit']:.4g}, "
                 f"the AKF rows' length unit {result.length_unit:.4g}\n(kalmix predict --length-unit "
                 f"{bank['length_unit']!r} --time-unit {bank['time_unit']!r}, with this command's --experts, --seed, "
                 "gap flags, --reach and --option but the gate's, runs the same mixture)")
    else:
        units = f"length unit {result.length_unit:.4g}"
    verdict_ = result.verdict or verdict(result.overall, result.per_track, result.horizon)
    lines = [f"verdict on {result.dataset}:"] + _verdict_lines(result, verdict_, "  ")
    for which in ("one_step", "horizon"):   # a subsample or no figure; the frame IMM's one-step-only is its row's
        for name, why in verdict_.get(which, {}).get("left_out", {}).items():
            if which == "one_step" or why != _NOT_AHEAD:
                ahead = "" if which == "one_step" else f" {result.horizon} rows ahead"
                lines.append(f"  ({name} is not compared{ahead}: {why})")
    lines += ["", f"{result.dataset}: {len(streams.track_ids)} track(s), {n_rows} samples in {len(streams.lengths)} "
              f"segment(s); {units}; {tuning}; {_METRIC_WORDS[result.metric]}, {result.units}", ""]
    lines += _table("overall, best one-step RMS first", result.overall, result, verdict_)
    calibration = result.tuned.get("mixture", {}).get("calibration", {})
    for which, entry in calibration.items():
        label = "one-step" if which == "one_step" else f"{result.horizon}-step"
        nees = f", mean NEES {entry['mean_nees']:.3g} (median {entry['median_nees']:.3g}; p = " \
               f"{len(streams.position_names)} if Gaussian)" if "mean_nees" in entry else ""
        count = int(entry.get("count", 0))
        few = ("; too few rows to judge the intervals (a 95 % coverage needs hundreds)"
               if count < FEW_CALIBRATION_ROWS else "")
        lines.append(f"mixture {label} intervals, {count} scored row(s): {entry['coverage_95']:.1%} of the scored "
                     f"values inside pred ± 1.96 std (aim 95 %){nees}{few}")
    partial = {name: entry for name, entry in result.tuned.items()
               if isinstance(entry, dict) and "rows_evaluated" in entry and entry["rows_evaluated"] < entry["rows"]}
    for name, entry in partial.items():
        lines.append(f"note: {name} ran on a subsample, the first rows of each segment: {entry['rows_evaluated']} of "
                     f"{entry['rows']} rows (its errors are not on the same pairs as the other rows)")
    for name, entry in result.tuned.items():   # said on stderr as they happened; the table says it too
        if isinstance(entry, dict) and "left_out" in entry:
            lines.append(f"note: {name} is not in the table: it failed on this data ({entry['left_out']})")
        elif isinstance(entry, dict) and "untuned" in entry:
            lines.append(f"note: {name} ran with its default settings, not tuned ({entry['untuned']})")
    if per_track:
        unscored = []
        for track, summaries in result.per_track.items():
            if not summaries.get("mixture", {}).get("one_step", {}).get("count", 1):
                unscored.append(str(track))   # a table of NaN said nothing
                continue
            entry = verdict_["per_track"][str(track)]
            lines += ["", *_table(f"track {track}", summaries, result, entry),
                      *_verdict_lines(result, entry)]
        if unscored:
            lines += ["", f"no scored error (too few rows after the tuning part, alone in their segments, or no "
                          f"measurement): track(s) "
                          f"{', '.join(unscored[:20])}{' ...' if len(unscored) > 20 else ''}"]
    return "\n".join(lines)


def track_columns(result: EvaluationResult, track=None):
    """The track a figure shows (``track``, else the first with a scored error) and its segments' columns."""
    streams = result.streams
    names = [str(t) for t in streams.track_ids]
    scored = np.isfinite(result.errors[KALMIX]).all(axis=-1).any(axis=0)   # (segments,)
    if track is None:
        track = next((name for i, name in enumerate(names) if scored[streams.track_of == i].any()), names[0])
    if str(track) not in names:
        raise ValueError(f"--track: expected one of {names[:20]}{' ...' if len(names) > 20 else ''}, got {track!r}")
    columns = np.flatnonzero(streams.track_of == names.index(str(track)))
    if not scored[columns].any():
        raise ValueError(f"--track {track}: no scored error to plot (its rows are in the tuning part, or alone in "
                         "their segments); pick a longer track")
    return str(track), columns


#: The rows the error figure shows unless asked for others: kalmix, then the references beside the best tuned peer.
PLOT_ROWS = (KALMIX, "CV Kalman", "no prediction")


def plot_rows(result: EvaluationResult, rows=None) -> list[str]:
    """The rows of the error figure: ``None`` or ``"default"``: kalmix, the best tuned peer (one step ahead),
    CV Kalman and no prediction; ``"all"``: every row; else a list of row names (checked)."""
    if rows is None or rows == "default":
        best = (result.verdict or {}).get("one_step", {}).get("best_peer")
        wanted = [KALMIX] + ([best] if best else []) + list(PLOT_ROWS[1:])
        return [name for name in dict.fromkeys(wanted) if name in result.errors]
    if rows == "all":
        return list(result.errors)
    rows = [rows] if isinstance(rows, str) else list(rows)
    unknown = [name for name in rows if name not in result.errors]
    if unknown:
        raise ValueError(f"--plot-row: {unknown} not among the rows of this run ({'; '.join(result.errors)})")
    return list(dict.fromkeys(rows))
