"""What the evaluation measures (:mod:`kalmix.experiments.evaluate`): the errors of each row's forecasts, their
summaries per track and overall, who wins (:func:`verdict`), the ranking, and the :class:`EvaluationResult`
that holds them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..metrics import error_summary
from ._evaluate_segments import Streams


def forecast_errors(predictions, values, horizon, scored):
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


NOT_AHEAD = "no forecast this far ahead"


#: An RMS under this fraction of the data's spread (:func:`spreads`) is rounding: the verdict compares no such
#: RMS by percentage (on an exactly straight track 1e-15 against 1e-16 is "900 % higher").
ROUNDING = 1e-9


def spreads(streams: Streams) -> dict:
    """Each track's spread (``{track as text: largest max - min of a coordinate}``), the yardstick of
    :data:`ROUNDING`; ``"overall"``: the largest."""
    n, p = len(streams.track_ids), streams.values.shape[-1]
    low, high = np.full((n, p), np.inf), np.full((n, p), -np.inf)
    np.fmin.at(low, streams.track_of, np.fmin.reduce(streams.values, axis=0, initial=np.inf))   # (NaN: left out)
    np.fmax.at(high, streams.track_of, np.fmax.reduce(streams.values, axis=0, initial=-np.inf))
    span = high - low   # (-inf for a coordinate with no finite value)
    out = {str(track): float(np.max(row, initial=0.0)) for track, row in zip(streams.track_ids, span)}
    out["overall"] = max(out.values(), default=0.0)
    return out


def _compare(summaries: dict, which: str, spread: float = 0.0) -> dict:
    """kalmix against the best tuned peer in ``summaries`` (``{row: {"one_step" | "horizon": summary}}``);
    ``spread``: the data's (:func:`spreads`), under whose :data:`ROUNDING` fraction an RMS is rounding."""
    own = (summaries.get(KALMIX) or {}).get(which) or {}
    kalmix, count = own.get("rms"), own.get("count")
    peers, left_out = {}, {}
    for name, entry in summaries.items():
        if name.startswith(NOT_PEERS):
            continue
        summary = entry.get(which)
        if summary is None:
            left_out[name] = NOT_AHEAD
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
    exact = kalmix <= ROUNDING * spread, rms <= ROUNDING * spread
    if kalmix == rms:
        how = "kalmix is level with it"
    elif any(exact):   # (a percentage of rounding errors says nothing)
        how = ("both predict" if all(exact) else "kalmix predicts" if exact[0] else f"{best} predicts") + \
            f" it to rounding precision (RMS under {ROUNDING:g} of the data's spread, {spread:.4g})" + \
            ("" if all(exact) else f", {best if exact[0] else 'kalmix'} does not")
    else:
        how = f"kalmix is {abs(percent):.3g} % {'lower (better)' if kalmix < rms else 'higher (worse)'}"
    return {**out, "best_peer": best, "best_peer_rms": rms, "percent": percent, "kalmix_better": bool(kalmix < rms),
            "text": f"kalmix's RMS {kalmix:.4g}, the best tuned peer {best} {rms:.4g}: {how}"}


def verdict(overall: dict, per_track: dict, horizon: int, spread: dict | None = None) -> dict:
    """Who wins: kalmix's RMS against the best tuned peer's, one step ahead and (``horizon > 1``) ``horizon`` ahead.

    Each entry (:func:`_compare`) holds ``kalmix_rms``, ``best_peer``, ``best_peer_rms``,
    ``percent`` (kalmix's RMS relative to the peer's, in %: negative when kalmix is
    better), ``kalmix_better``, every compared peer's RMS, the peers left out with why
    (no forecast that far ahead, a subsample), and a sentence. ``per_track`` holds the same per track.
    ``spread`` (:func:`spreads`): the data's, overall and per track; where kalmix's or the peer's RMS is under
    :data:`ROUNDING` of it, the sentence says that RMS is rounding instead of a percentage.
    """
    which = ("one_step", "horizon") if horizon > 1 else ("one_step",)
    spread = spread or {}
    return {**{w: _compare(overall, w, spread.get("overall", 0.0)) for w in which},
            "per_track": {track: {w: _compare(rows, w, spread.get(track, 0.0)) for w in which}
                          for track, rows in per_track.items()}}


def ranking(summaries: dict, horizon: int) -> dict:
    """Row names by RMS, best first (rows without a finite RMS last, in table order), one step and ``horizon`` ahead."""
    def order(which):
        def key(name):
            rms = ((summaries[name] or {}).get(which) or {}).get("rms")
            return (0, rms) if rms is not None and math.isfinite(rms) else (1, 0.0)
        return sorted(summaries, key=key)

    return {"one_step": order("one_step"), **({"horizon": order("horizon")} if horizon > 1 else {})}


def summarise(predictions: dict, streams: Streams, horizon: int, scored: np.ndarray, metric: str):
    """Each row's error summaries, overall and per track (``{row: {"one_step" | "horizon": summary}}``, of the
    errors ``metric`` says), and its one-step errors (T, S, p); ``predictions``: ``{row: (one-step, horizon-step)}``
    (horizon-step None: the row has none), ``scored``: the rows the errors count."""
    values = streams.values
    overall, per_track, errors_one = {}, {}, {}
    for name, (first, later) in predictions.items():
        e1 = forecast_errors(first, values, 1, scored)
        errors_one[name] = e1
        m1 = error_measure(e1, metric)
        mh = error_measure(forecast_errors(later, values, horizon, scored), metric) if later is not None else None
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
    return overall, per_track, errors_one


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
