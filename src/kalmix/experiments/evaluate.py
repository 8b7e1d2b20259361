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
  each; filterpy is a Python loop). The IMM gives one-step predictions only.

The best expert in hindsight is an oracle: per track, the single expert of the
mixture's bank with the lowest error over the reported part.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..bank import check_horizon, check_length_unit, make_params
from ..core.mixture import init_state, predict, step
from ..metrics import error_summary
from ..streaming import GapTracker, StreamConfig, _take, auto_length_unit

__all__ = ["Streams", "EvaluationResult", "split_streams", "evaluate_table", "PREDICTORS"]

#: Row names in table order.
PREDICTORS = ("mixture", "no prediction", "CV Kalman", "CA Kalman", "IMM (filterpy)", "single AKF",
              "best expert (hindsight)")
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

    With ``lengths`` (S,), column ``j`` is stepped only over its first ``lengths[j]`` rows
    (padding is not fed to the filters as missing measurements: thousands of predict-only
    steps would let a covariance overflow); outputs past a column's length are NaN.
    """
    t_count, s, p = values.shape
    state = init_state(params, s, stream_ids=np.zeros(s, dtype=np.int64)) if state is None else state
    lengths = np.full(s, t_count) if lengths is None else np.asarray(lengths)
    order = np.argsort(-lengths, kind="stable")
    values, lengths = values[:, order], lengths[order]
    state = _take(state, order)
    k = params.n_experts
    one = np.full((t_count, s, p), np.nan)
    ahead = np.full((t_count, s, p), np.nan) if horizon > 1 else one
    one_experts = np.full((t_count, s, k, p), np.nan) if experts else None
    ahead_experts = (np.full((t_count, s, k, p), np.nan) if horizon > 1 else one_experts) if experts else None
    t = 0
    while t < t_count and lengths[0] > t:
        width = int(np.sum(lengths > t))
        stop = int(lengths[width - 1])
        sub = _take(state, slice(0, width))
        for step_index in range(t, stop):
            sub, out = step(params, sub, values[step_index, :width])
            one[step_index, :width] = out.prediction
            if experts:
                one_experts[step_index, :width] = out.expert_predictions
            if horizon > 1:
                pred, expert_pred = predict(params, sub, horizon)
                ahead[step_index, :width] = pred
                if experts:
                    ahead_experts[step_index, :width] = expert_pred
        t = stop
    back = np.argsort(order, kind="stable")
    pick = (lambda a: None if a is None else a[:, back])
    return pick(one), (pick(ahead) if horizon > 1 else pick(one)), pick(one_experts), \
        (pick(ahead_experts) if horizon > 1 else pick(one_experts))


def _errors(predictions, values, horizon, scored):
    """``values[t+h] - predictions[t]`` aligned on the target frame, NaN outside ``scored``."""
    errors = np.full_like(values, np.nan)
    errors[horizon:] = values[horizon:] - predictions[:-horizon]
    errors[~scored] = np.nan
    return errors


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
    from ..peers import imm_predictions

    order = np.argsort(-streams.lengths)[:3]
    pieces = []
    for j in order:
        rows = np.flatnonzero(tuning[:, j])[:400]
        if rows.size > 10:
            pieces.append(streams.values[rows, j])
    if not pieces:
        return {"measurement_noise": measurement_noise / unit**2, **{k: v[1] for k, v in _IMM_GRID.items()}}
    best, best_rms = None, math.inf
    for candidate in itertools.product(*_IMM_GRID.values()):
        options = dict(zip(_IMM_GRID, candidate), measurement_noise=measurement_noise / unit**2)
        squared, count = 0.0, 0
        for z in pieces:
            e = z[1:] - imm_predictions(z, length_unit=unit, **options)[:-1]
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
    for factor in UNIT_FACTORS:
        params = make_params(values.shape[2], n_experts, seed=seed, length_unit=rule * factor, **options)
        errors = _errors(_run(params, part, 1, lengths=mask.sum(axis=0))[0], part, 1, mask)
        scores[factor] = float(np.sqrt(np.nanmean(errors**2))) if np.isfinite(errors).any() else math.inf
    best = min(scores, key=lambda f: scores[f] if math.isfinite(scores[f]) else math.inf)
    return rule * best, {str(k): v for k, v in scores.items()}


@dataclass
class EvaluationResult:
    """Error summaries (``{"mean_abs", "std", "max", "rms", "count"}``) per predictor.

    ``overall[name]["one_step" | "horizon"]`` and ``per_track[track][name][...]``;
    ``errors[name]`` holds the one-step error arrays (T, S, p) for plots.
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
                                 for i, t in enumerate(self.streams.track_ids)}})


def _require_errors(values, mask, doing, part, track_lengths):
    """``ValueError`` unless ``mask`` holds a one-step error: a measurement right after another."""
    present = np.isfinite(values).all(axis=-1)
    if not (mask[1:] & present[1:] & present[:-1]).any():
        raise ValueError(f"too little data to {doing}: {part} holds no two consecutive measurements of a "
                         f"segment (longest track: {int(track_lengths.max())} row(s) after de-duplicating times; "
                         "evaluate needs tracks of a few dozen rows)")


def evaluate_table(table, *, horizon: int = 1, n_experts: int = 40, seed: int = 0,
                   length_unit: float | None = None, tuning_fraction: float = 0.2,
                   max_gap: float | None = None, max_gap_factor: float = 3.0,
                   max_samples: int | None = None, tracks=None, peers: bool = True,
                   options: dict | None = None, tune_units: bool = True, log=None) -> EvaluationResult:
    """Run every predictor over every track segment and summarise the errors.

    Parameters
    ----------
    table : pandas.DataFrame
        Track table (``track_id``, ``time``, 1–3 position columns), each track in time order.
    horizon : int
        H of the H-step errors (the one-step errors are always reported).
    n_experts, seed : int
        The mixture's K and bank seed.
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
        Include filterpy's IMM (needs the ``peers`` extra).
    tune_units : bool
        Tune the mixture's length unit on the tuning part (else the rule's value).
    options : dict, optional
        Other :func:`kalmix.bank.make_params` arguments for the mixture.
    log : callable, optional
        Called with a short progress message before each predictor.
    """
    horizon = check_horizon(horizon)
    if length_unit is not None:
        length_unit = check_length_unit(length_unit)
    if not 0 <= tuning_fraction < 1:
        raise ValueError(f"tuning_fraction: expected a number in [0, 1), got {tuning_fraction!r}")
    log = log or (lambda message: None)
    if tracks is not None:
        wanted = {str(t) for t in tracks}
        table = table[table["track_id"].astype(str).isin(wanted)]
        if table.empty:
            raise ValueError(f"tracks: none of {sorted(wanted)} is in the data")
    streams = split_streams(table, max_gap=max_gap, max_gap_factor=max_gap_factor, max_samples=max_samples)
    values, s, p = streams.values, streams.values.shape[1], streams.values.shape[2]
    track_lengths = np.bincount(streams.track_of, weights=streams.lengths).astype(int)
    cut = np.ceil(tuning_fraction * track_lengths[streams.track_of]).astype(int)   # (S,)
    present = streams.sample_index >= 0
    scored = present & (streams.sample_index >= cut[None, :])
    tuning = present & ~scored
    options = dict(options or {})
    tuned: dict[str, Any] = {}
    tune_scored = tuning if tuning.any() else scored
    _require_errors(values, tune_scored, "tune the predictors on",
                    f"the first {tuning_fraction:.0%} of each track (--tuning-fraction)", track_lengths)
    _require_errors(values, scored, "score", "the rest of each track", track_lengths)
    if length_unit is not None:
        unit = rule = float(length_unit)
        tuned["length_unit"] = {"given": unit}
    else:
        rule = auto_length_unit(np.where(tuning[..., None], values, np.nan) if tuning.any() else values)
        unit, scores = rule, {}
        if tune_units and tuning.any():
            log(f"mixture: tuning the length unit around the rule's {rule:.4g}")
            unit, scores = _tune_unit(values, tuning, rule, n_experts, seed, options)
        tuned["length_unit"] = {"rule": rule, "chosen": unit, "tuning_rms": scores}

    if options:
        tuned["mixture_options"] = options
    predictions: dict[str, tuple] = {}
    log(f"mixture (K={n_experts}, length unit {unit:.4g})")
    mix_params = make_params(p, n_experts, seed=seed, length_unit=unit, **options)
    one, ahead, one_experts, ahead_experts = _run(mix_params, values, horizon, experts=True,
                                                  lengths=streams.lengths)
    predictions["mixture"] = (one, ahead)

    log("no prediction")
    carried = np.empty_like(values)
    carried[0] = values[0]
    for t in range(1, len(values)):
        carried[t] = np.where(np.isnan(values[t]), carried[t - 1], values[t])
    predictions["no prediction"] = (carried, carried)

    for name, order, degree in (("CV Kalman", 2, 1), ("CA Kalman", 3, 2)):
        log(f"{name}: tuning on the first {tuning_fraction:.0%} of each track")
        best = _tune_fixed(order, degree, rule, values, tune_scored)
        tuned[name] = best
        params = make_params(p, 1, dynamics="fixed", order=order, prior_degree=degree, adapt_noise=False,
                             length_unit=unit, process_noise_range=(best["process_noise"] / unit**2,) * 2,
                             measurement_noise_range=(best["measurement_noise"] / unit**2,) * 2)
        predictions[name] = _run(params, values, horizon, lengths=streams.lengths)[:2]

    if peers:
        try:
            from ..peers import imm_predictions
            import filterpy  # noqa: F401
        except ImportError:
            imm_predictions = None
        if imm_predictions is not None:
            log("IMM (filterpy): tuning")
            best = _tune_imm(streams, tune_scored, rule, tuned["CV Kalman"]["measurement_noise"])
            tuned["IMM (filterpy)"] = {k: v * rule**2 if k != "switch_probability" else v for k, v in best.items()}
            log("IMM (filterpy): running")
            imm = np.full_like(values, np.nan)
            for j in range(s):
                n = streams.lengths[j]
                imm[:n, j] = imm_predictions(values[:n, j], length_unit=rule, **best)
            predictions["IMM (filterpy)"] = (imm, None)

    log("single AKF")
    akf_params = make_params(p, 1, seed=seed, length_unit=unit, **{**options, "adapt_noise": False})
    predictions["single AKF"] = _run(akf_params, values, horizon, lengths=streams.lengths)[:2]

    # oracle: per track, the expert with the lowest error on the reported part
    def hindsight(expert_predictions, h):
        errors = np.full(expert_predictions.shape, np.nan)
        errors[h:] = values[h:, :, None, :] - expert_predictions[:-h]
        errors[~scored] = np.nan
        chosen = np.empty((len(values), s, p))
        picks = {}
        for i in range(len(streams.track_ids)):
            columns = np.flatnonzero(streams.track_of == i)
            squared = np.nanmean(np.moveaxis(errors[:, columns] ** 2, 2, 0).reshape(errors.shape[2], -1), axis=1) \
                if np.isfinite(errors[:, columns]).any() else np.zeros(errors.shape[2])
            best = int(np.nanargmin(squared)) if np.isfinite(squared).any() else 0
            picks[str(streams.track_ids[i])] = best
            chosen[:, columns] = expert_predictions[:, columns, best]
        return chosen, picks

    oracle_one, picks = hindsight(one_experts, 1)
    oracle_ahead = hindsight(ahead_experts, horizon)[0] if horizon > 1 else oracle_one
    tuned["best expert (hindsight)"] = {"expert_per_track": picks}
    predictions["best expert (hindsight)"] = (oracle_one, oracle_ahead)
    del one_experts, ahead_experts

    overall, per_track, errors_one = {}, {}, {}
    for name, (first, later) in predictions.items():
        e1 = _errors(first, values, 1, scored)
        eh = _errors(later, values, horizon, scored) if later is not None else None
        errors_one[name] = e1
        summary = {"one_step": error_summary(e1)}
        if horizon > 1:
            summary["horizon"] = error_summary(eh) if eh is not None else None
        overall[name] = summary
        for i, track in enumerate(streams.track_ids):
            columns = streams.track_of == i
            entry = {"one_step": error_summary(e1[:, columns])}
            if horizon > 1:
                entry["horizon"] = error_summary(eh[:, columns]) if eh is not None else None
            per_track.setdefault(str(track), {})[name] = entry
    return EvaluationResult(horizon=int(horizon), length_unit=unit, tuning_fraction=tuning_fraction,
                            tuned=tuned, predictors=list(predictions), overall=overall, per_track=per_track,
                            streams=streams, errors=errors_one)
