"""The text ``kalmix evaluate`` prints (:func:`format_result`: the verdict first, then the tables ranked by
one-step RMS), and what its figures show (:func:`track_columns`, :func:`plot_rows`)."""

from __future__ import annotations

import numpy as np

from ..bank import DEFAULT_BANK
from ._evaluate_scores import KALMIX, NOT_AHEAD, EvaluationResult, ranking, spreads, verdict


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
    rule = bank.get("rule", DEFAULT_BANK["rule"])
    if "length_unit" in bank and "time_unit" in bank:
        units = (f"the mixture's length unit {bank['length_unit']:.4g} and time unit {bank['time_unit']:.4g}, "
                 f"the AKF rows' length unit {result.length_unit:.4g}\n(kalmix predict --length-unit "
                 f"{bank['length_unit']!r} --time-unit {bank['time_unit']!r} --no-population-prior"
                 + (f" --rule {rule}" if rule != DEFAULT_BANK["rule"] else "") + ", with this "
                 "command's --experts, --seed, gap flags, --reach and --option but the gate's, runs the same "
                 "mixture)")
    else:
        units = f"length unit {result.length_unit:.4g}"
    verdict_ = result.verdict or verdict(result.overall, result.per_track, result.horizon,
                                               spreads(result.streams))
    lines = [f"verdict on {result.dataset}:"] + _verdict_lines(result, verdict_, "  ")
    for which in ("one_step", "horizon"):   # a subsample or no figure; the frame IMM's one-step-only is its row's
        for name, why in verdict_.get(which, {}).get("left_out", {}).items():
            if which == "one_step" or why != NOT_AHEAD:
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
