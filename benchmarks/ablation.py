"""Ablation of aggregation rules x banks on the shipped recordings (one-step RMS, last 80 % of each track).

Run: python -m benchmarks.ablation [--datasets hawkeye_ball cycling skillcorner paper] [--json out.json]
     [--configs [LABEL ...]] [--two-level]   (``--configs`` with no label: none of CONFIGS)
(``paper``: the paper's simulated stereo target, seeds 0-4 as five tracks of 1000 frames.)
Every bank (with the glitch screen at its default threshold unless the row says otherwise)
runs through the compiled engine on the segments ``kalmix predict`` makes
(gap rule), with the length unit of :func:`kalmix.streaming.auto_length_unit` and the
time unit :func:`kalmix.streaming.auto_time_unit`, both from the first 20 % of each track.
Rows named "boa" run the original rule (``bound_forgetting`` 1.0 and no ``clip``, not the default's
0.99 and 3); the rows with "bound forgetting .99" or "clip" run those.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from kalmix.bank import make_bank
from kalmix.core.compiled import engine as ce
from kalmix.experiments.evaluate import split_streams
from kalmix.experiments.table1 import paper_table
from kalmix.io.datasets import load_dataset
from kalmix.streaming import auto_length_unit, auto_time_unit

CONFIGS = {
    "akf40 fixed_share(sigma=2u)": dict(kind="akf", rule="fixed_share", fixed_scale=2.0),
    "akf40 boa": dict(kind="akf", rule="boa"),
    "kinematic28 boa": dict(kind="kinematic", rule="boa"),
    "kinematic28 mlpoly": dict(kind="kinematic", rule="mlpoly"),
    "kinematic28 fixed_share(online)": dict(kind="kinematic", rule="fixed_share"),
    "mixed68 boa": dict(kind="mixed", rule="boa"),
    "mixed68 mlpoly": dict(kind="mixed", rule="mlpoly"),
    "mixed68 fixed_share(online)": dict(kind="mixed", rule="fixed_share"),
    "mixed68 fixed_share(sigma=2u)": dict(kind="mixed", rule="fixed_share", fixed_scale=2.0),
    "mixed36 boa (8 AKF)": dict(kind="mixed", rule="boa", n_akf=8),
    "kinematic28 boa forget .999 share .01": dict(kind="kinematic", rule="boa",
                                                  rule_options={"forgetting": 0.999, "share": 0.01}),
    "mixed68 boa forget .999 share .01": dict(kind="mixed", rule="boa",
                                              rule_options={"forgetting": 0.999, "share": 0.01}),
    "mixed68 boa, no glitch screen": dict(kind="mixed", rule="boa", outlier_threshold=float("inf")),
    "mixed68 boa, screen 30": dict(kind="mixed", rule="boa", outlier_threshold=30.0),
    "mixed68 boa, screen 300": dict(kind="mixed", rule="boa", outlier_threshold=300.0),
    "kinematic28 boa, no glitch screen": dict(kind="kinematic", rule="boa", outlier_threshold=float("inf")),
    "mixed68 boa, screen 100, restart at 2": dict(kind="mixed", rule="boa", outlier_rejects=2),
    "mixed68 boa, screen 1000": dict(kind="mixed", rule="boa", outlier_threshold=1000.0),
    "ar48 boa": dict(kind="ar", rule="boa"),
    "kinematic28+ar48 boa": dict(kind="kinematic+ar", rule="boa"),
    "mixed68+ar48 boa": dict(kind="mixed+ar", rule="boa"),
    "kinematic28+ar24 (orders 1, 2) boa": dict(kind="kinematic+ar", rule="boa", ar_orders=(1, 2)),
    "kinematic28+ar24 (ridge 1) boa": dict(kind="kinematic+ar", rule="boa", ar_ridge=(1.0,)),
    "kinematic28+ar48 boa, no jump test": dict(kind="kinematic+ar", rule="boa",
                                               ar_options={"jump_threshold": float("inf")}),
    "mixed68 boa, bound forgetting .99": dict(kind="mixed", rule="boa", rule_options={"bound_forgetting": 0.99}),
    "kinematic28 boa, bound forgetting .99": dict(kind="kinematic", rule="boa",
                                                  rule_options={"bound_forgetting": 0.99}),
    "kinematic28+ar48 boa, bound forgetting .99": dict(kind="kinematic+ar", rule="boa",
                                                       rule_options={"bound_forgetting": 0.99}),
    "mixed68+ar48 boa, bound forgetting .99": dict(kind="mixed+ar", rule="boa",
                                                   rule_options={"bound_forgetting": 0.99}),
    "kinematic28+ar48 mlpoly": dict(kind="kinematic+ar", rule="mlpoly"),
    "mixed68+ar48 mlpoly": dict(kind="mixed+ar", rule="mlpoly"),
    "mixed68+ar48 fixed_share(online)": dict(kind="mixed+ar", rule="fixed_share"),
    "mixed68+ar48 fixed_share(sigma=2u)": dict(kind="mixed+ar", rule="fixed_share", fixed_scale=2.0),
    "kinematic28+ar48 fixed_share(online)": dict(kind="kinematic+ar", rule="fixed_share"),
    "turn3 boa, bound forgetting .99": dict(kind="turn", rule="boa", rule_options={"bound_forgetting": 0.99}),
    "kinematic28+ar48+turn3 boa, bound forgetting .99": dict(kind="kinematic+ar+turn", rule="boa",
                                                             rule_options={"bound_forgetting": 0.99}),
    "mixed68+ar48+turn3 boa": dict(kind="mixed+ar+turn", rule="boa"),
    "mixed68+ar48+turn3 boa, bound forgetting .99": dict(kind="mixed+ar+turn", rule="boa",
                                                         rule_options={"bound_forgetting": 0.99}),
    "mixed68+ar48+turn3 mlpoly": dict(kind="mixed+ar+turn", rule="mlpoly"),
    "mixed68+ar48+turn3 fixed_share(online)": dict(kind="mixed+ar+turn", rule="fixed_share"),
    "mixed68+ar48+turn1 (gain 1) boa, bound forgetting .99": dict(kind="mixed+ar+turn", rule="boa",
                                                                  turn_gains=(1.0,),
                                                                  rule_options={"bound_forgetting": 0.99}),
    "mixed68+ar48+turn5 (gains .5-2.5) boa, bound forgetting .99": dict(
        kind="mixed+ar+turn", rule="boa", turn_gains=(0.5, 1.0, 1.5, 2.0, 2.5),
        rule_options={"bound_forgetting": 0.99}),
    # BOA on errors clipped at c times their RMS so far (kalmix.core.aggregators.boa, ``clip``)
    "mixed68+ar48+turn3 boa, bound forgetting .99, clip 3 (the default)": dict(
        kind="mixed+ar+turn", rule="boa", rule_options={"bound_forgetting": 0.99, "clip": 3.0}),
    "mixed68+ar48+turn3 boa, bound forgetting .99, clip 2": dict(
        kind="mixed+ar+turn", rule="boa", rule_options={"bound_forgetting": 0.99, "clip": 2.0}),
    "mixed68+ar48+turn3 boa, bound forgetting .99, clip 5": dict(
        kind="mixed+ar+turn", rule="boa", rule_options={"bound_forgetting": 0.99, "clip": 5.0}),
    "mixed68+ar48+turn3 boa, clip 3 (bound not forgotten)": dict(
        kind="mixed+ar+turn", rule="boa", rule_options={"clip": 3.0}),
    "kinematic28 boa, bound forgetting .99, clip 3": dict(
        kind="kinematic", rule="boa", rule_options={"bound_forgetting": 0.99, "clip": 3.0}),
    "kinematic28+ar48+turn3 boa, bound forgetting .99, clip 3": dict(
        kind="kinematic+ar+turn", rule="boa", rule_options={"bound_forgetting": 0.99, "clip": 3.0}),
}


#: Second-level aggregation (``--two-level``): BOA (bound forgetting .99) over the forecasts of BOA mixtures of
#: sub-banks (each BOA, bound forgetting .99), in the numpy spec (kalmix.core.aggregators.boa); not a bank
#: kind of kalmix, an experiment.
TWO_LEVEL = {
    "2-level BOA over (default, kinematic28)": ("mixed+ar+turn", "kinematic"),
    "2-level BOA over (default, kinematic28, ar48)": ("mixed+ar+turn", "kinematic", "ar"),
    "2-level BOA over (default, kinematic28, ar48, kinematic+ar+turn, akf40)": (
        "mixed+ar+turn", "kinematic", "ar", "kinematic+ar+turn", "akf"),
}


def two_level(values, times, lengths, unit, tunit, combos):
    """Each combination's forecasts ``(T, N, p)``: BOA over its sub-banks' BOA mixtures, row by row."""
    from kalmix.core.aggregators import boa

    forecasts = {}
    for kind in sorted({kind for combo in combos.values() for kind in combo}):
        bank = make_bank(values.shape[2], kind=kind, rule="boa", length_unit=unit, time_unit=tunit,
                         rule_options={"bound_forgetting": 0.99})
        forecasts[kind] = ce.run(bank, values, times, lengths=lengths).forecasts
    params = boa.Params(bound_forgetting=0.99)
    out = {}
    for label, combo in combos.items():
        x = np.stack([forecasts[kind] for kind in combo], axis=2)   # (T, N, K, p)
        state = boa.init(params, x.shape[1], x.shape[2])
        mixed = np.full_like(values, np.nan)
        for row in range(len(values)):
            awake = np.isfinite(x[row]).all(axis=-1)
            w = boa.weights(params, state, awake)
            mixed[row] = np.where(awake.any(axis=-1)[:, None],
                                  np.einsum("nk,nkp->np", w, np.where(awake[..., None], x[row], 0.0)), np.nan)
            learn = np.isfinite(values[row]).all(axis=-1) & awake.any(axis=-1)
            state = boa.update(params, state, x[row], np.where(learn[:, None], values[row], 0.0), awake, learn)
        out[label] = mixed
    return out


def scored_streams(name, max_samples=None):
    """A data set as every row here sees it: its segments (``predict``'s gap rule), which of their rows are
    scored ``(T, S)`` (the last 80 % of each track), and the length and time units from the first 20 %."""
    table = paper_table() if name == "paper" else load_dataset(name)
    streams = split_streams(table, max_samples=max_samples)
    track_lengths = np.bincount(streams.track_of, weights=streams.lengths).astype(int)
    cut = np.ceil(0.2 * track_lengths[streams.track_of]).astype(int)
    present = streams.sample_index >= 0
    scored = present & (streams.sample_index >= cut[None, :])
    tuning = present & ~scored
    unit = auto_length_unit(np.where(tuning[..., None], streams.values, np.nan))
    tunit = auto_time_unit(np.where(tuning, streams.times, np.nan))
    return streams, scored, unit, tunit


def run_dataset(name, configs, max_samples=None, two_levels=None):
    streams, scored, unit, tunit = scored_streams(name, max_samples)
    values, times = streams.values, streams.times
    rows = {}
    for label, cfg in configs.items():
        cfg = dict(cfg)
        fixed = cfg.pop("fixed_scale", None)
        options = dict(cfg.pop("rule_options", {}))
        if cfg.get("rule") == "boa":
            options.setdefault("bound_forgetting", 1.0)   # "boa" rows: the original rule; the others say so
            options.setdefault("clip", float("inf"))
        if fixed is not None:
            options["scale"] = fixed * unit
        bank = make_bank(values.shape[2], length_unit=unit, time_unit=tunit, rule_options=options, **cfg)
        start = time.perf_counter()
        result = ce.run(bank, values, times, lengths=streams.lengths, score=scored)
        seconds = time.perf_counter() - start
        err = values - result.forecasts
        rms = float(np.sqrt(np.nanmean(np.where(scored[..., None], err, np.nan) ** 2)))
        # best expert in hindsight of this bank (per track), from the per-column sums
        sq, cnt = result.experts, result.weights
        per_track_sq = np.zeros((len(streams.track_ids), bank.n_experts))
        per_track_cnt = np.zeros_like(per_track_sq)
        np.add.at(per_track_sq, streams.track_of, sq)
        np.add.at(per_track_cnt, streams.track_of, cnt)
        mse = per_track_sq / np.maximum(per_track_cnt, 1)
        mse[per_track_cnt == 0] = np.inf
        best = per_track_sq[np.arange(len(mse)), mse.argmin(axis=1)].sum() / p_count(values, scored, result)
        mae = float(np.nanmean(np.abs(np.where(scored[..., None], err, np.nan))))
        outliers = float(result.state.screen.outliers.sum())
        rows[label] = dict(rms=rms, mean_abs=mae, best_expert=float(np.sqrt(best)), seconds=seconds,
                           outliers=outliers)
        print(f"{name:12s} {label:42s} rms {rms:.5g}  mean|e| {mae:.4g}  best expert {np.sqrt(best):.5g}  "
              f"outliers {outliers:.0f}  {seconds:.1f}s", flush=True)
    if two_levels:
        for label, forecasts in two_level(values, times, streams.lengths, unit, tunit, two_levels).items():
            err = values - forecasts
            rms = float(np.sqrt(np.nanmean(np.where(scored[..., None], err, np.nan) ** 2)))
            rows[label] = dict(rms=rms)
            print(f"{name:12s} {label:42s} rms {rms:.5g}", flush=True)
    return dict(unit=unit, time_unit=tunit, rows=rows)


def p_count(values, scored, result):
    """Scored coordinate-values (the denominator of the mixture's mean square)."""
    ok = scored[..., None] & np.isfinite(values - result.forecasts)
    return ok.sum()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--datasets", nargs="+", default=["hawkeye_ball", "cycling", "skillcorner", "paper"])
    parser.add_argument("--max-samples", type=int, default=None)
    parser.add_argument("--configs", nargs="*", default=None)
    parser.add_argument("--json", default=None)
    parser.add_argument("--two-level", action="store_true", help="also the second-level rows (TWO_LEVEL)")
    args = parser.parse_args(argv)
    configs = CONFIGS if args.configs is None else {k: CONFIGS[k] for k in args.configs}
    out = {name: run_dataset(name, configs, args.max_samples, TWO_LEVEL if args.two_level else None)
           for name in args.datasets}
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
