"""Lead forecasts on the model zoo: kalmix H steps ahead against the optimal H-step predictor.

Run: python -m benchmarks.zoo_lead [--json FILE] [--quick] [--scenario NAME ...] [--horizons 5 10]

On the regularly sampled scenarios of :mod:`benchmarks.model_zoo` with a single known model (the same seeded
tracks), for each H, on the same rows (every row after the first 20 % of its track, as the one-step zoo), the
RMS of the forecasts of each row made H rows (H time steps) before it by

- the **optimum**: the Kalman filter with the true model, its filtered state after row ``i - H`` propagated to
  row ``i``'s time: the conditional mean, exact for these linear-Gaussian models;
- **kalmix predict --horizon H**, defaults otherwise, as a user runs it (a subprocess on a CSV of the tracks): its
  ``pred<H>_`` columns, the lead head's forecasts (weights learned on the H-step errors); and the same with
  ``--no-population-prior`` (each track's weights start empty, as in the evaluation below);
- what ``kalmix evaluate -H H`` measures on the same table (:func:`kalmix.experiments.evaluate.evaluate_table`):
  the default mixture with the lead head's weights, the **same experts with the one-step weights** (their
  one-step mixture extrapolated H steps), and every tuned peer (each tuned on the first 20 % of every track,
  one-step RMS; the best at H is the one :mod:`benchmarks.lead_vs_peers` picks);
- **no prediction**: the measurement H rows before.

The lead head's forecast is a blend of its own weights' forecast and the one-step weights' (:mod:`kalmix.core.lead`);
``lead_over_one_step_weights`` is the evaluation's lead RMS over its one-step weights' RMS, overall and per track.

Each figure is also given as a ratio to the optimum's RMS. The evaluation's rows are checked to be the
optimum's: the same count, and its no-prediction RMS equal to the one computed here.

Left out: the scenarios whose time steps vary (``cv_irregular``, ``short_tracks``: "H steps ahead" is then no
fixed lead, and ``--horizon H`` forecasts H time units ahead, not the row H later), the one with a 3-day silence
(``cv_outage``: a row H later may lie across it), and the switching one (``switching_turn``: its reference, an IMM,
is near-optimal one step ahead only, and its H-step forecast would be a further approximation, not the optimum).
``--quick``: 5 tracks of 200 rows per scenario.
"""

from __future__ import annotations

import argparse
import functools
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from kalmix.experiments import evaluate as ev

from . import model_zoo as mz
from .lead_vs_peers import horizon_peers

#: The scenarios scored, and why the others are not.
SCENARIOS = ("cv_10hz", "ca_10hz", "singer_1hz", "random_walk_frames")
LEFT_OUT = {
    "cv_irregular": "time steps uniform in 5-60 s: H rows ahead is no fixed lead",
    "short_tracks": "time steps uniform in 10-60 min: H rows ahead is no fixed lead (and 12 rows a track)",
    "cv_outage": "a 3-day silence mid-track: the row H later may lie across it",
    "switching_turn": "its reference (an IMM) is near-optimal one step ahead only, not H steps ahead",
}
HORIZONS = (5, 10)
#: The ``kalmix predict --horizon H`` rows: with the defaults, and without the population prior (every track's
#: weights start empty, as the evaluation's do).
PREDICT = "kalmix predict --horizon H"
RUNS = ((PREDICT, ()), (f"{PREDICT} --no-population-prior", ("--no-population-prior",)))


def _no_prediction(tracks, h):
    return [np.vstack([np.full((h, 2), np.nan), z[:-h]]) for _, z in tracks]


def _evaluation(table, h, rows, no_prediction_rms):
    """``kalmix evaluate -H h``'s H-step RMS per coordinate of the mixture (lead head), the same experts with the
    one-step weights and every tuned peer, after checking that it scored ``rows`` rows whose no-prediction RMS is
    ``no_prediction_rms`` (the rows of the optimum)."""
    result = ev.evaluate_table(table, horizon=h, log=lambda *_: None)
    overall = result.overall
    count = overall["mixture"]["horizon"]["count"]
    nothing = overall["no prediction"]["horizon"]["rms"]
    if count != 2 * rows or not math.isclose(nothing, no_prediction_rms, rel_tol=1e-9):
        raise RuntimeError(f"kalmix evaluate -H {h} scored other rows: {count} values (expected {2 * rows}), "
                           f"no-prediction RMS {nothing} (expected {no_prediction_rms})")
    peers, best = horizon_peers(overall)
    per_track = [rows["mixture"]["horizon"]["rms"] / rows["mixture, one-step weights"]["horizon"]["rms"]
                 for rows in result.per_track.values()]
    return {"mixture (lead head)": overall["mixture"]["horizon"]["rms"],
            "mixture, one-step weights": overall["mixture, one-step weights"]["horizon"]["rms"],
            "best expert (hindsight)": overall["best expert (hindsight)"]["horizon"]["rms"],
            "peers": peers, "best_peer": best, "lead_over_one_step_weights_per_track": per_track}


def run_scenario(s: mz.Scenario, directory: Path, horizons=HORIZONS, log=None) -> dict:
    """The scenario's tracks, scored ``h`` rows ahead for each of ``horizons``; each line of progress to ``log``
    (default: printed)."""
    log = log or functools.partial(print, flush=True)
    start = time.perf_counter()
    transitions = [mz.Transitions(A, Qc) for A, Qc, _ in s.models]
    table, tracks = mz.simulate(s, transitions)
    ref = [mz.kalman_forecasts(t, z, s.models[0], s.r, s.prior_mean, s.prior_std, transitions[0], horizons)
           for t, z in tracks]
    result = {"label": s.label, "about": s.about, "reference": s.reference, "unit": s.unit,
              "parameters": s.parameters, "tracks": s.tracks, "rows_per_track": s.rows, "seed": s.seed,
              "burn_in": mz.BURN_IN, "time": "integer frame numbers" if s.integer_times else "seconds",
              "horizons": {}}
    for h in horizons:
        predictors = {"optimum": [r[h][0] for r in ref], "no prediction": _no_prediction(tracks, h)}
        stds = {"optimum": [np.sqrt(np.diagonal(r[h][1], axis1=1, axis2=2)) for r in ref]}
        runs = {}
        for name, options in RUNS:
            out, seconds, said = mz.kalmix_predict(table, directory, ("--horizon", str(h), *options))
            per = mz.kalmix_one_step(out, table, tracks, h)
            predictors[name], stds[name] = [p for p, _ in per], [sd for _, sd in per]
            runs[name] = {"seconds": seconds, "stderr": said}
        scores, missing = mz.score(s, tracks, predictors, stds)
        scored = scores["scored"]
        p = scored["predictors"]
        optimum = p["optimum"]["rms_per_coordinate"]
        evaluation = _evaluation(table, h, scored["rows"], p["no prediction"]["rms_per_coordinate"])
        rms = {name: p[name]["rms_per_coordinate"] for name in predictors}
        rms.update({k: v for k, v in evaluation.items() if isinstance(v, float)})
        rms.update({f"peer: {k}": v for k, v in evaluation["peers"].items()})
        lead, plain = evaluation["mixture (lead head)"], evaluation["mixture, one-step weights"]
        best = evaluation["best_peer"]
        worse = evaluation["lead_over_one_step_weights_per_track"]
        entry = {"rows": scored["rows"], "unforecast_rows": missing,
                 "rms_per_coordinate": rms, "ratio_to_optimum": {k: v / optimum for k, v in rms.items()},
                 "coverage_95": {name: p[name]["coverage_95"] for name in stds},
                 "best_peer": best, "best_peer_ratio_to_optimum": evaluation["peers"][best] / optimum,
                 "lead_over_one_step_weights": lead / plain,
                 "lead_over_one_step_weights_per_track": worse,
                 "tracks_lead_worse": sum(v > 1 for v in worse), "kalmix_predict": runs}
        result["horizons"][f"H={h}"] = entry
        r = entry["ratio_to_optimum"]
        log(f"{s.name} H={h} [{scored['rows']} rows]: optimum {optimum:.4g} {s.unit}; / optimum: predict "
            f"{r[PREDICT]:.3f} (--no-population-prior {r[RUNS[1][0]]:.3f}), evaluate lead "
            f"{r['mixture (lead head)']:.3f}, one-step weights "
            f"{r['mixture, one-step weights']:.3f} (lead / one-step {entry['lead_over_one_step_weights']:.4f}, "
            f"worse on {entry['tracks_lead_worse']} of {len(worse)} tracks), "
            f"best peer {best} {entry['best_peer_ratio_to_optimum']:.3f}, no prediction {r['no prediction']:.3f}; "
            f"coverage predict {100 * entry['coverage_95'][PREDICT]:.1f} %, optimum "
            f"{100 * entry['coverage_95']['optimum']:.1f} %")
    result["seconds"] = time.perf_counter() - start
    return result


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="write the results here")
    parser.add_argument("--quick", action="store_true", help="5 tracks of 200 rows per scenario")
    parser.add_argument("--scenario", action="append", choices=SCENARIOS, help="only this scenario (repeatable)")
    parser.add_argument("--horizons", nargs="+", type=int, default=list(HORIZONS), help="H (default 5 10)")
    args = parser.parse_args(argv)
    if min(args.horizons) < 2:
        parser.error("--horizons: each H at least 2 (the one-step zoo is benchmarks.model_zoo)")
    chosen = args.scenario or list(SCENARIOS)
    zoo = mz.scenarios()
    report = {"command": "python -m benchmarks.zoo_lead" + (" --quick" if args.quick else "")
              + ("" if tuple(args.horizons) == HORIZONS else f" --horizons {' '.join(map(str, args.horizons))}"),
              "machine": mz.machine(), "burn_in": mz.BURN_IN, "left_out": LEFT_OUT, "scenarios": {}}
    try:
        report["kalmix"] = mz.checkout()
    except (RuntimeError, FileNotFoundError) as error:
        report["kalmix"] = {"commit": None, "note": f"not a git checkout ({error})"}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kalmix-zoo-lead-") as temporary:
        return mz.run_all(report, zoo, chosen, args.quick, Path(temporary),
                          lambda s, directory: run_scenario(s, directory, tuple(args.horizons)), start, args.json)


if __name__ == "__main__":
    main()
