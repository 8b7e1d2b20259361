"""The peers of the evaluation (:mod:`kalmix.experiments.evaluate`), each tuned on the tuning part then run on
every segment: the CV and CA Kalman filters (a grid of noise variances), filterpy's IMM, and the models of
:mod:`kalmix.peer_models` whose packages are installed."""

from __future__ import annotations

import importlib.util
import itertools
import math

import numpy as np

from ..bank import make_params
from ..core.mixture import init_state
from ..streaming import auto_time_unit
from ._evaluate_mixture import run_mixture
from ._evaluate_scores import forecast_errors


_FIXED_PROCESS = tuple(float(v) for v in np.geomspace(1e-3, 1e5, 17))


_FIXED_MEASUREMENT = (0.05, 0.25, 1.0, 4.0)


_IMM_GRID = {"cv_process_noise": (0.1, 1.0, 10.0, 100.0, 1000.0), "ca_process_noise": (0.01, 0.1, 1.0, 10.0, 100.0),
             "switch_probability": (0.02, 0.1)}


#: Rows of the peers of :mod:`kalmix.peer_models`, by their registry name.
PEER_LABELS = {"cv_dt": "CV Kalman (real dt)", "ca_dt": "CA Kalman (real dt)", "imm_dt": "IMM (filterpy, real dt)",
               "mmae_dt": "MMAE bank (filterpy, real dt)", "holt_winters": "Holt-Winters (river)",
               "rls_ar": "RLS AR (padasip)", "ucm_llt": "local linear trend (statsmodels ML)"}


def _leave_out(label, error, tuned, log) -> None:
    """A peer that failed on this data: said now (``log``) and recorded in ``tuned`` (the table names it)."""
    reason = f"{type(error).__name__}: {error}"
    log(f"{label}: left out, it failed on this data ({reason})")
    tuned[label] = {"left_out": reason}


def run_peer_models(streams, tuning, unit, horizon, predictions, tuned, log, own_only: bool = False):
    """Tune every installed peer of :mod:`kalmix.peer_models` on the tuning part and run it on every segment
    (``own_only``: only those that need no other package, the CV and CA Kalman filters in real time).

    A peer with ``max_rows`` runs on the first rows of each segment (:func:`~kalmix.peer_models.row_budget`);
    its rows past that are not predicted, which the ``tuned`` entry says (``rows_evaluated``).
    """
    from ..peer_models import PEERS, available, row_budget

    time_unit = auto_time_unit(np.where(tuning, streams.times, np.nan) if tuning.any() else streams.times)
    segments = [(streams.values[:n, j], streams.times[:n, j], tuning[:n, j]) for j, n in enumerate(streams.lengths)]
    for name, peer in PEERS.items():
        if not available(peer) or (own_only and peer.needs):
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
    one = run_mixture(params, tiled, 1, state, lengths=np.tile(lengths, len(grid)))[0]
    errors = forecast_errors(one, tiled, 1, np.tile(tuning, (1, len(grid))))
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


def run_fixed_filters(streams, tuning, tune_scored, peer_unit, unit, horizon, tuning_fraction, predictions, tuned,
                      log) -> None:
    """The CV and CA Kalman filters' rows: each filter's noise variances tuned on ``tune_scored``
    (:func:`_tune_fixed`, on the grid scaled by ``peer_unit``), then run online over every segment."""
    values = streams.values
    p = values.shape[2]
    for name, order, degree in (("CV Kalman", 2, 1), ("CA Kalman", 3, 2)):
        log(f"{name}: tuning on the first {100 * tuning_fraction:.3g}% of each track" if tuning.any() else
            f"{name}: tuning on the scored rows themselves (no tuning part: in hindsight)")
        best = _tune_fixed(order, degree, peer_unit, values, tune_scored)
        tuned[name] = best
        params = make_params(p, 1, dynamics="fixed", order=order, prior_degree=degree, adapt_noise=False,
                             length_unit=unit, process_noise_range=(best["process_noise"] / unit**2,) * 2,
                             measurement_noise_range=(best["measurement_noise"] / unit**2,) * 2)
        predictions[name] = run_mixture(params, values, horizon, lengths=streams.lengths)[:2]


def run_imm(streams, tune_scored, peer_unit, measurement_noise, predictions, tuned, log) -> None:
    """filterpy's IMM row, where filterpy is installed: tuned on ``tune_scored`` (:func:`_tune_imm`, with the CV
    filter's ``measurement_noise``), then run on every segment; one-step predictions only. Left out, and said,
    when it fails on this data."""
    from ..peers import imm_predictions_many

    if importlib.util.find_spec("filterpy") is None:   # the row of a user who has filterpy's IMM
        return
    values = streams.values
    log("IMM (filterpy): tuning")
    try:
        best = _tune_imm(streams, tune_scored, peer_unit, measurement_noise)
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
