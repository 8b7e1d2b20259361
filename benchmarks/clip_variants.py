"""Which errors BOA's ``clip`` should shrink, and where its scale should come from: offline replays.

Run: python -m benchmarks.clip_variants [--datasets hawkeye_ball cycling skillcorner paper] [--json out.json]

The default bank's experts run once through the compiled engine (with ``clip`` off; their forecasts do not
depend on the rule) on the segments and scored rows of ``python -m benchmarks.ablation``; BOA (bound forgetting
0.99) is then replayed on their recorded forecasts in variants that kalmix does not ship:

- ``shipped``: what :mod:`kalmix.core.aggregators.boa` does with ``clip`` 3 (the regrets and their variance see
  the shrunk error, the range bound the whole one; the scale is the mean squared error norm of the last rows,
  a memory of 1,000);
- ``bound shrunk too``: the range bound also takes the regret of the shrunk error;
- ``scale of shrunk errors``: the scale is the mean of the *shrunk* squared norms (a Huber scale);
- ``regime change``: not a recording but a noise-free target that moves 0.5 mm a row and is kicked to 3 m a row
  (``tests/test_glitches.py``), RMS of rows 64-119 (from the third row after the kick): how fast each variant
  follows a lasting change of motion.

The replay of ``shipped`` and of ``clip`` off gives the engine's own figures (both printed): the replay is the
rule, not an approximation of it. On skillcorner they differ in the 4th digit: the replay learns every row,
the engine not the 7 its glitch screen rejected there. Skillcorner's segments are replayed in batches of
similar length.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks.ablation import scored_streams
from kalmix.bank import make_bank
from kalmix.core.compiled import engine as ce

VARIANTS = {"clip off": dict(clip=np.inf), "shipped": dict(clip=3.0),
            "bound shrunk too": dict(clip=3.0, bound="shrunk"),
            "scale of shrunk errors": dict(clip=3.0, scale="shrunk")}
WARMUP, MEMORY = 10, 1000   # kalmix.core.aggregators.boa's CLIP_WARMUP, CLIP_MEMORY


def replay(x, y, clip, bound="whole", scale="whole", beta=0.99):
    """BOA (gradient trick, bound forgetting ``beta``) over forecasts ``x (T, N, K, p)`` of ``y (T, N, p)``."""
    t_count, n, k, _ = x.shape
    regret, variance, big = np.zeros((n, k)), np.zeros((n, k)), np.zeros((n, k))
    mean_square, count = np.zeros(n), np.zeros(n)
    out = np.full(y.shape, np.nan)
    for t in range(t_count):
        awake = np.isfinite(x[t]).all(axis=-1)
        informed = variance > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            eta = np.where(informed, np.minimum(1 / (2 * big), np.sqrt(np.log(k) / variance)), 0.0)
            top = eta.max(axis=-1, keepdims=True)
            eta = np.where(informed, eta, np.where(top > 0, top, 1.0))
            logw = np.where(awake, np.log(eta) + eta * regret, -np.inf)
            logw -= np.where(awake.any(axis=-1), logw.max(axis=-1), 0.0)[:, None]
            w = np.exp(logw)
            w /= w.sum(axis=-1, keepdims=True)
        xs = np.where(awake[..., None], x[t], 0.0)
        mix = np.einsum("nk,nkp->np", np.nan_to_num(w), xs)
        out[t] = np.where(awake.any(axis=-1)[:, None], mix, np.nan)
        learn = np.isfinite(y[t]).all(axis=-1) & awake.any(axis=-1)
        g = np.where(learn[:, None], mix - np.where(learn[:, None], y[t], 0.0), 0.0)
        norm = np.sqrt((g * g).sum(axis=-1))
        with np.errstate(invalid="ignore"):   # clip off: inf x 0
            limit = clip * np.sqrt(mean_square)
        cut = (count >= WARMUP) & (mean_square > 0) & (norm > limit)
        factor = np.where(cut, limit / np.where(cut, norm, 1.0), 1.0)
        whole = np.where(awake, 2 * np.einsum("np,nkp->nk", g, mix[:, None, :] - xs), 0.0)
        r = whole * factor[:, None]
        kept = np.where(cut, limit, norm) if scale == "shrunk" else norm
        if np.isfinite(clip):
            count = np.minimum(count + learn, MEMORY)
            mean_square = np.where(learn, mean_square + (kept * kept - mean_square) / np.maximum(count, 1), mean_square)
        new_variance = variance + r * r
        new_big = np.maximum(beta * big, np.abs(r if bound == "shrunk" else whole))
        with np.errstate(divide="ignore", invalid="ignore"):
            rate = np.where(new_variance > 0, np.minimum(1 / (2 * new_big), np.sqrt(np.log(k) / new_variance)), 0.0)
        go = learn[:, None] & awake
        regret = np.where(go, regret + r - rate * r * r, regret)
        variance, big = np.where(go, new_variance, variance), np.where(go, new_big, big)
    return out


def recorded(name):
    """``[(experts (T, N, K, p), values (T, N, p), scored (T, N))]``: the default bank's forecasts with ``clip``
    off, in batches of segments of similar length, and the engine's RMS with ``clip`` off and at 3."""
    if name == "regime change":
        t = np.arange(120) * 0.1
        x = np.where(np.arange(120) < 60, 0.0005 * np.arange(120), 0.03 + 3.0 * (np.arange(120) - 60))
        values, times = np.stack([x, np.zeros(120)], axis=-1)[:, None], t[:, None]
        scored, lengths, unit, tunit = (np.arange(120) >= 64)[:, None], np.array([120]), 0.05, 0.1
    else:
        streams, scored, unit, tunit = scored_streams(name)
        values, times, lengths = streams.values, streams.times, streams.lengths
    banks = {label: make_bank(values.shape[2], kind="mixed+ar+turn", length_unit=unit, time_unit=tunit,
                              rule_options={"bound_forgetting": 0.99, "clip": clip})
             for label, clip in (("clip off", np.inf), ("shipped", 3.0))}
    engine = {label: rms(values, ce.run(bank, values, times, lengths=lengths).forecasts, scored)
              for label, bank in banks.items()}
    order = np.argsort(lengths)
    batches = []
    for i in range(0, len(order), 400):
        cols = order[i:i + 400]
        rows = lengths[cols].max()
        result = ce.run(banks["clip off"], values[:rows, cols], times[:rows, cols], lengths=lengths[cols],
                        record_experts=True)
        batches.append((result.experts, values[:rows, cols], scored[:rows, cols]))
    return batches, engine


def rms(values, forecasts, scored):
    err = np.where(scored[..., None], values - forecasts, np.nan)
    return float(np.sqrt(np.nanmean(err ** 2)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--datasets", nargs="+",
                        default=["hawkeye_ball", "cycling", "skillcorner", "paper", "regime change"])
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    report = {}
    for name in args.datasets:
        batches, engine = recorded(name)
        report[name] = {"engine": engine}
        for label, options in VARIANTS.items():
            total, count = 0.0, 0
            for experts, values, scored in batches:
                err = np.where(scored[..., None], values - replay(experts, values, **options), np.nan)
                total, count = total + np.nansum(err ** 2), count + np.isfinite(err).sum()
            report[name][label] = float(np.sqrt(total / count))
        print(f"{name:14s} " + "  ".join(f"{label} {value:.6g}" for label, value in report[name].items()
                                         if label != "engine")
              + f"   (the engine: clip off {engine['clip off']:.6g}, shipped {engine['shipped']:.6g})", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)


if __name__ == "__main__":
    main()
