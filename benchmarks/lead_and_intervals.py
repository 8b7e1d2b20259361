"""Lead weights, calibrated intervals and warm starts of the default mixture (issue: time, lead, intervals).

Run: python -m benchmarks.lead_and_intervals [--datasets hawkeye_ball cycling skillcorner paper]
     [--horizons 1 2 5 10] [--json out.json]

For each recording (and the paper's simulated stereo target, seed 0) and each horizon H,
``kalmix.experiments.evaluate.evaluate_table`` without peers: the H-step RMS of the
default mixture with the lead head's weights (learned on H-step errors, delayed
feedback) and with the one-step weights; the coverage of pred ± 1.96 std and the mean
NEES of the one-step and H-step intervals. For skillcorner (segments of a median of 56
frames) the one-step RMS and coverage with a warm start across a track's segments (what
``kalmix predict`` does), cold (each segment from scratch), and bridged (no restart at a
gap: the experts predict across it; the rows after a gap are not scored in any of the three).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.experiments import evaluate as ev
from kalmix.experiments._evaluate_mixture import run_bank
from kalmix.experiments._evaluate_scores import forecast_errors
from kalmix.experiments.table1 import paper_table
from kalmix.io.datasets import load_dataset
from kalmix.streaming import auto_length_unit, auto_time_unit


def table_of(name):
    return paper_table(seeds=(0,)) if name == "paper" else load_dataset(name)


def warm_and_cold(table):
    """One-step RMS and coverage of the default bank, warm (track layout) and cold (segments)."""
    streams = ev.split_streams(table)
    tl = np.bincount(streams.track_of, weights=streams.lengths).astype(int)
    cut = np.ceil(0.2 * tl[streams.track_of]).astype(int)
    present = streams.sample_index >= 0
    scored = present & (streams.sample_index >= cut[None, :])
    tuning = present & ~scored
    unit = auto_length_unit(np.where(tuning[..., None], streams.values, np.nan))
    tunit = auto_time_unit(np.where(tuning, streams.times, np.nan))
    bank = make_bank(streams.values.shape[2], length_unit=unit, time_unit=tunit, **DEFAULT_BANK)
    out = {}
    for label, warm, restart in (("warm", True, True), ("cold", False, True), ("bridged", True, False)):
        one, _, _, _, _, calibration = run_bank(bank, streams, 1, scored, warm=warm, restart_gaps=restart)
        err = forecast_errors(one, streams.values, 1, scored)
        out[label] = {"rms": float(np.sqrt(np.nanmean(err ** 2))), **calibration["one_step"]}
        print(f"  {label}: one-step RMS {out[label]['rms']:.5g}, coverage {out[label]['coverage_95']:.4f}", flush=True)
    return out


def arguments(description, argv):
    """``--datasets``, ``--horizons``, ``--json`` (shared with :mod:`benchmarks.lead_vs_peers`)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--datasets", nargs="+", default=["hawkeye_ball", "cycling", "skillcorner", "paper"])
    parser.add_argument("--horizons", nargs="+", type=int, default=[2, 5, 10])
    parser.add_argument("--json", default=None)
    return parser.parse_args(argv)


def save(report, path) -> None:
    if path:
        with open(path, "w") as fh:
            json.dump(report, fh, indent=1)


def over_datasets(args, measure, after=None) -> dict:
    """``report[name]["H=h"] = measure(name, table, h)`` (plus its ``seconds``) for every dataset and horizon
    of ``args``, printed as it comes; ``after(name, table)`` adds the dataset's other entries. Saved to
    ``args.json``."""
    report = {}
    for name in args.datasets:
        table = table_of(name)
        report[name] = {}
        for h in args.horizons:
            start = time.perf_counter()
            entry, line = measure(name, table, h)
            entry["seconds"] = time.perf_counter() - start
            report[name][f"H={h}"] = entry
            print(f"{name} H={h}: {line}; {entry['seconds']:.0f}s", flush=True)
        if after is not None:
            report[name].update(after(name, table))
    save(report, args.json)
    return report


def _lead_and_coverage(name, table, h):
    result = ev.evaluate_table(table, horizon=h, peers=False, log=lambda *_: None)
    o = result.overall
    cal = result.tuned["mixture"]["calibration"]
    entry = {"one_step_rms": o["mixture"]["one_step"]["rms"],
             "lead_weights_rms": o["mixture"]["horizon"]["rms"],
             "one_step_weights_rms": o["mixture, one-step weights"]["horizon"]["rms"],
             "best_expert_rms": o["best expert (hindsight)"]["horizon"]["rms"],
             "calibration": cal}
    line = (f"H-step RMS lead weights {entry['lead_weights_rms']:.5g} vs one-step weights "
            f"{entry['one_step_weights_rms']:.5g}; coverage one-step {cal['one_step']['coverage_95']:.4f} "
            f"(NEES {cal['one_step']['mean_nees']:.3g}), H-step {cal['horizon']['coverage_95']:.4f} "
            f"(NEES {cal['horizon']['mean_nees']:.3g})")
    return entry, line


def _warm_start(name, table):
    return {"warm_start": warm_and_cold(table)} if name in ("skillcorner", "cycling", "hawkeye_ball") else {}


def main(argv=None):
    return over_datasets(arguments(__doc__, argv), _lead_and_coverage, _warm_start)


if __name__ == "__main__":
    main()
