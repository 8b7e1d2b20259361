"""Tracks sampled at heavy-tailed intervals (AIS-like): what the gap rule and the aggregation cost there.

Run: python -m benchmarks.irregular_sampling [--json out.json]

Six simulated vessels, 400 reports each (seed 0): speed ~5 m/s, a slowly drifting heading, 5 m
position noise, reports every 2, 3, 10, 30 or 180 s (10 s most often; one report in seven after 180
s). :func:`kalmix.experiments.evaluate.evaluate_table` with its peers: with the default gap rule (a
step beyond 3 reference intervals, which take the spread of a track's first steps into account,
restarts the track) and with no gap restart (``--max-gap none``, the experts predict across every
step), each with the default reach (settled from the irregular steps: across a step over 1.5 time
units only the CV experts predict) and with none, and bridged with ``--reach 8``. For the bridged
run it also gives the one-step RMS with the time unit forced to 3-180 s, for reach none, 8 and 1.5.
For the bridged runs it also splits the default mixture's one-step errors (the engine on
evaluation's rule for the units) between the long steps (> 60 s) and the others, and gives each
family's best expert and its weight there.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pandas as pd

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.experiments import evaluate as ev
from kalmix.streaming import auto_time_unit

#: Rows of ``evaluate`` that are not peers.
NOT_PEERS = ("mixture", "AKF mixture", "best expert", "no prediction", "single AKF")
LONG_STEP = 60.0
REACH = 8.0   # a longer reach, for comparison


def vessels(seed: int = 0, count: int = 6, reports: int = 400) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    for vessel in range(count):
        dt = rng.choice([2, 3, 10, 10, 10, 30, 180], size=reports) + rng.uniform(0, 1, size=reports)
        heading = np.cumsum(rng.normal(0, 0.01, size=reports)) + rng.uniform(0, 2 * np.pi)
        speed = 5 + np.cumsum(rng.normal(0, 0.02, size=reports))
        x = np.cumsum(speed * np.cos(heading) * dt) + rng.normal(0, 5, reports)
        y = np.cumsum(speed * np.sin(heading) * dt) + rng.normal(0, 5, reports)
        rows += [(vessel, t, a, b) for t, a, b in zip(np.cumsum(dt), x, y)]
    return pd.DataFrame(rows, columns=["track_id", "time", "x", "y"])


def _summary(result):
    overall = result.overall
    peers = {name: s["one_step"]["rms"] for name, s in overall.items() if not name.startswith(NOT_PEERS)}
    best = min(peers, key=peers.get)
    calibration = result.tuned["mixture"]["calibration"]["one_step"]
    return {"segments": int(result.streams.values.shape[1]), "mixture": overall["mixture"]["one_step"]["rms"],
            "best_expert": overall["best expert (hindsight)"]["one_step"]["rms"], "best_peer": best,
            "best_peer_rms": peers[best], "coverage_95": calibration["coverage_95"],
            "mean_nees": calibration["mean_nees"]}


def _long_steps(table, result, reach=None):
    """The default bank (with ``reach``) on the bridged tracks (the evaluation's units), errors split by the
    step's length."""
    from kalmix.core.compiled import engine
    from kalmix.io import to_arrays

    arrays = to_arrays(table)
    z, t = arrays.values, arrays.times
    tuning = np.arange(len(z))[:, None] < 0.2 * np.isfinite(t).sum(axis=0)[None, :]
    unit, time_unit = result.tuned["length_unit"]["rule"], auto_time_unit(np.where(tuning, t, np.nan))
    bank = make_bank(2, **DEFAULT_BANK, length_unit=unit, time_unit=time_unit, reach=reach)
    run = engine.run(bank, z, t, record_experts=True)
    step = np.diff(t, axis=0, prepend=np.nan)
    scored = np.isfinite(run.forecasts - z).all(-1) & ~tuning
    long = scored & (step > LONG_STEP)
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    mix = run.forecasts - z
    out = {"rows_long": int(long.sum()), "rows_other": int((scored & ~long).sum()),
           "mixture_long": rms(mix[long]), "mixture_other": rms(mix[scored & ~long]), "families": {}}
    errors = run.experts - z[:, :, None, :]
    for family, columns in zip(bank.families, bank.slices()):
        name = f"{family.kind}" + (f"{family.params.order}" if family.kind == "ar" else "")
        per = np.sqrt(np.mean(errors[:, :, columns][scored] ** 2, axis=(0, 2)))
        best = int(np.argmin(per))
        out["families"][name] = {"best_rms": float(per[best]),
                                 "best_long": rms(errors[:, :, columns][long][:, best]),
                                 "weight_long": float(run.weights[long][:, columns].sum(-1).mean())}
    return out


def _time_units(table, result, units=(3.0, 10.58, 30.0, 60.0, 180.0), reaches=(None, 8.0, 1.5)):
    """The default bank on the bridged tracks with the time unit forced (the evaluation's length unit and tuning
    part), one-step RMS per (time unit, reach)."""
    from kalmix.core.compiled import engine
    from kalmix.io import to_arrays

    arrays = to_arrays(table)
    z, t = arrays.values, arrays.times
    tuning = np.arange(len(z))[:, None] < 0.2 * np.isfinite(t).sum(axis=0)[None, :]
    out = {}
    for time_unit in units:
        for reach in reaches:
            bank = make_bank(2, **DEFAULT_BANK, length_unit=result.tuned["length_unit"]["rule"], time_unit=time_unit,
                             reach=reach)
            run = engine.run(bank, z, t)
            scored = ~tuning & np.isfinite(run.forecasts).all(-1) & np.isfinite(z).all(-1)
            out[f"time unit {time_unit:g}, reach {reach}"] = float(np.sqrt(np.mean((run.forecasts - z)[scored] ** 2)))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    table = vessels()
    report = {}
    for name, factor, reach in (("gap restarts (default)", 3.0, "auto"), ("bridged (--max-gap none)", math.inf, "auto"),
                                ("gap restarts, --reach none", 3.0, None), ("bridged, --reach none", math.inf, None),
                                ("bridged, --reach 8", math.inf, REACH)):
        result = ev.evaluate_table(table, max_gap_factor=factor, log=lambda *_: None,
                                   bank_options={**DEFAULT_BANK, "reach": reach})
        report[name] = _summary(result)
        s = report[name]
        print(f"{name}: {s['segments']} segments; mixture {s['mixture']:.4g} m, best expert {s['best_expert']:.4g}, "
              f"best peer {s['best_peer']} {s['best_peer_rms']:.4g}; 95 % coverage {100 * s['coverage_95']:.1f} %, "
              f"mean NEES {s['mean_nees']:.3g}")
        if math.isinf(factor) and reach is None:
            report["bridged, by time unit and reach"] = units = _time_units(table, result)
            print("  " + "; ".join(f"{key}: {value:.4g} m" for key, value in units.items()))
        if math.isinf(factor):
            report[f"{name}, by step"] = split = _long_steps(table, result, result.tuned["mixture"]["bank"]
                                                             ["reach"] if reach == "auto" else reach)
            print(f"  mixture on steps > {LONG_STEP:g} s: {split['mixture_long']:.4g} m ({split['rows_long']} rows), "
                  f"on the others {split['mixture_other']:.4g} m ({split['rows_other']} rows)")
            for family, f in split["families"].items():
                print(f"  {family}: best expert {f['best_rms']:.4g} m, on the long steps {f['best_long']:.4g}; "
                      f"the family's weight there {f['weight_long']:.3f}")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(report, handle, indent=2)


if __name__ == "__main__":
    main()
