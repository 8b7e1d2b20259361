"""The lead rule's learning rate under delayed feedback: BOA at rate / sqrt(H) against the one-step rate.

Run: python -m benchmarks.lead_rate [--datasets cycling hawkeye_ball paper] [--horizons 2 5 10]
     [--hindsight] [--json out.json]

For each recording and horizon H, ``kalmix.experiments.evaluate.evaluate_table`` without peers
(what ``kalmix evaluate -H H`` prints for the mixture), twice: the default bank, whose lead head's
BOA learns with ``delay`` H (``make_bank(..., lead_delay=None)``), and the same bank with
``lead_delay=1`` (the one-step rate, the rule before this change). Both report the H-step RMS with
the lead weights (per coordinate, the rows ``evaluate`` scores).

With ``--hindsight``, also the bound no online rule can beat on that bank: the lowest H-step RMS
of one expert, and of a fixed convex combination of the experts fitted in hindsight on the same
scored rows (the rows where every expert has a forecast), beside the mixture's on those rows.
It needs every expert's H-step forecast of every row in memory: skip it on skillcorner.
"""

from __future__ import annotations

import numpy as np

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.core.compiled import engine as compiled
from kalmix.experiments import evaluate as ev
from kalmix.experiments._evaluate_segments import shift, to_segments, to_tracks, track_layout
from kalmix.streaming import auto_length_unit, auto_time_unit

from .lead_and_intervals import arguments, over_datasets


def _lead_rms(table, h, lead_delay):
    bank = {**DEFAULT_BANK, "lead_delay": lead_delay}
    result = ev.evaluate_table(table, horizon=h, peers=False, bank_options=bank, log=lambda *_: None)
    return result.overall["mixture"]["horizon"]["rms"]


def hindsight(table, h):
    """Per-coordinate H-step RMS on the rows where every expert forecasts: the mixture (lead weights), its best
    expert and its best fixed convex combination, both fitted in hindsight on those rows."""
    from scipy.optimize import minimize

    streams = ev.split_streams(table)
    values = streams.values
    count = np.bincount(streams.track_of, weights=streams.lengths).astype(int)
    cut = np.ceil(0.2 * count[streams.track_of]).astype(int)
    present = streams.sample_index >= 0
    scored = present & (streams.sample_index >= cut[None, :])
    tuning = present & ~scored
    unit = auto_time_unit(np.where(tuning, streams.times, np.nan))
    bank = make_bank(values.shape[2], length_unit=auto_length_unit(np.where(tuning[..., None], values, np.nan)),
                     time_unit=unit, lead=h * unit, **DEFAULT_BANK)
    tv, tt, tl, restart, rows, columns = track_layout(streams)
    later = to_tracks(shift(streams.times, h), rows, columns, tt.shape, np.nan)
    result = compiled.run(bank, tv, tt, lengths=tl, ahead_times=later, ahead_frames=h, restart=restart,
                          record_experts=True)
    experts = to_segments(result.expert_ahead, rows, columns)      # (T, S, K, p): made after row t
    lead = to_segments(result.lead, rows, columns)
    target = shift(values, h)                                        # the row h later
    ok = (shift(scored, h, False) & np.isfinite(experts).all(axis=(-1, -2)) & np.isfinite(target).all(-1)
          & np.isfinite(lead).all(-1))
    x, y = experts[ok], target[ok]                                       # (n, K, p), (n, p)
    n, k, p = x.shape
    a, b = x.transpose(0, 2, 1).reshape(n * p, k), y.reshape(n * p)
    single = np.sqrt(((a - b[:, None]) ** 2).mean(axis=0))
    fit = minimize(lambda w: np.mean((a @ w - b) ** 2), np.full(k, 1 / k), jac=lambda w: 2 * a.T @ (a @ w - b) / len(b),
                   method="SLSQP", bounds=[(0, 1)] * k, constraints=[{"type": "eq", "fun": lambda w: w.sum() - 1}],
                   options={"maxiter": 500})
    return {"rows": int(n), "mixture": float(np.sqrt(np.mean((lead[ok] - y) ** 2))),
            "best_expert": float(single.min()), "best_convex": float(np.sqrt(fit.fun))}


def main(argv=None):
    import argparse

    extra = argparse.ArgumentParser(add_help=False)
    extra.add_argument("--hindsight", action="store_true")
    known, rest = extra.parse_known_args(argv)
    if "--datasets" not in rest:   # skillcorner takes minutes per run, and its hindsight fit does not fit in memory
        rest = ["--datasets", "cycling", "hawkeye_ball", "paper", *rest]
    args = arguments(__doc__, rest)

    def measure(name, table, h):
        delayed, one_step = _lead_rms(table, h, None), _lead_rms(table, h, 1.0)
        entry = {"lead_rms_delay_H": delayed, "lead_rms_delay_1": one_step, "change": delayed / one_step - 1}
        line = f"lead RMS, rate / sqrt(H) {delayed:.5g}, one-step rate {one_step:.5g} ({entry['change']:+.2%})"
        if known.hindsight:
            entry["hindsight"] = found = hindsight(table, h)
            line += (f"; on {found['rows']} rows: mixture {found['mixture']:.5g}, best expert "
                     f"{found['best_expert']:.5g}, best convex combination {found['best_convex']:.5g}")
        return entry, line

    return over_datasets(args, measure)


if __name__ == "__main__":
    main()
