"""How far below the best peer can any predictor get on hawkeye_ball? Lower bounds fitted in hindsight.

Run: python -m benchmarks.hawkeye_bounds [--json benchmarks/results/hawkeye_bounds.json]

Issue 11 asks for a one-step RMS of at most 0.97x the best tuned peer on hawkeye_ball (Hawk-Eye's 3-D
football, 50 Hz). The scored rows are those of ``python -m benchmarks.ablation`` (``predict``'s segments,
the last 80 % of each track). Every figure here is an oracle, fitted on the very rows it scores, so
no online predictor of the same kind can do better:

- the two-point extrapolation ``2 z[t-1] - z[t-2]`` (what the tuned CV filter and Holt-Winters amount to);
- the best linear predictor of the next velocity ``z[t] - z[t-1]`` from the last L velocities, per
  coordinate and across all three, least squares on the scored rows (L = 1 ... 21): every
  translation-invariant predictor that forecasts a linear, time-invariant function of the last L + 1
  positions (CV, CA, fixed AR models of the velocity, damped or not, and any fixed convex or affine
  combination of them) is in this class;
- the same with terms no linear model of the velocity forms: a constant per coordinate (gravity), the
  last velocity times the speed (quadratic drag) and its squares (``kinematic_features``): what a
  generic nonlinear kinematic expert could bring at best;
- a ground-bounce rule on top of the two-point extrapolation: below a floor (the lowest height seen so
  far, plus an offset) the forecast height is reflected with a restitution; restitution and offset chosen
  in hindsight. This is physics of a ball, not something kalmix's experts know; it measures what such
  knowledge could bring;
- the same bounce rule on the default mixture's own forecasts (``python -m benchmarks.ablation``'s
  protocol: the default bank through the compiled engine on the same segments and scored rows): what a
  bounce correction after the mixture could bring at best;
- where the default mixture's squared error lies against the two-point extrapolation's: the kick rows (the
  latter's 47 worst), the three rows after each, and the others.

It also prints how the squared error of the two-point extrapolation is spread over the rows.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks.ablation import scored_streams

#: The best tuned peer's one-step RMS on these rows (river's Holt-Winters; "Choosing the default").
BEST_PEER = 0.01908


def scored_tracks():
    """Each segment's positions ``(T, 3)`` with no NaN, and which of its rows are scored."""
    streams, scored, _, _ = scored_streams("hawkeye_ball")
    values = streams.values
    out = []
    for j in range(values.shape[1]):
        keep = np.isfinite(values[:, j]).all(axis=1)
        out.append((values[keep, j], scored[keep, j]))
    return out


def second_differences(z):
    d = np.full_like(z, np.nan)
    d[2:] = z[2:] - 2 * z[1:-1] + z[:-2]
    return d


def two_point(tracks):
    total, count, rows = 0.0, 0, []
    for z, scored in tracks:
        d = second_differences(z)
        ok = scored & np.isfinite(d).all(axis=1)
        squared = (d[ok] ** 2).sum(axis=1)
        rows.append(squared)
        total += squared.sum()
        count += 3 * ok.sum()
    return float(np.sqrt(total / count)), np.concatenate(rows)


def velocities(z):
    v = np.full_like(z, np.nan)
    v[1:] = z[1:] - z[:-1]
    return v


def kinematic_features(velocity):
    """Terms a linear model of the velocity cannot form, from the last velocity ``v``: a constant (gravity),
    ``|v| v`` (quadratic drag along the motion) and ``v * v`` per coordinate."""
    return np.concatenate([[1.0], np.linalg.norm(velocity) * velocity, velocity * velocity])


def linear_oracle(tracks, lags: int, across: bool, target=None, extra=None):
    """RMS of the best linear predictor of each coordinate's next velocity (or of ``target(z)``, the
    residual of another forecast) from the last ``lags`` velocities (of that coordinate, or of all three
    with ``across``), and ``extra(last velocity)``'s terms if given, fitted on the scored rows; and the
    fitted coefficients' sums (the velocity's persistence) per coordinate."""
    total, count, persistence = 0.0, 0, []
    designs = {c: ([], []) for c in range(3)}
    for z, scored in tracks:
        v = velocities(z)
        y_all = v if target is None else target(z)
        for t in range(lags + 1, len(z)):
            if not scored[t]:
                continue
            past = v[t - lags:t][::-1]
            more = [] if extra is None else extra(past[0])
            for c in range(3):
                designs[c][0].append(np.concatenate([past.reshape(-1) if across else past[:, c], more]))
                designs[c][1].append(y_all[t, c])
    for c in range(3):
        x, y = np.asarray(designs[c][0]), np.asarray(designs[c][1])
        beta, *_ = np.linalg.lstsq(x, y, rcond=None)
        total += float(((y - x @ beta) ** 2).sum())
        count += len(y)
        own = beta[:3 * lags].reshape(lags, 3)[:, c] if across else beta[:lags]
        persistence.append(float(own.sum()))
    return float(np.sqrt(total / count)), persistence


#: The bounce rule's grid (restitution; floor offset, metres).
RESTITUTIONS = (0.0, 0.3, 0.5, 0.7, 0.8, 0.9, 1.0, 1.2, 1.4, 1.6)
OFFSETS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05)


def bounce_forecasts(z, restitution, offset):
    """The two-point extrapolation of each row ``t >= 2`` with the ground-bounce rule (NaN before)."""
    out = np.full_like(z, np.nan)
    floor = np.minimum.accumulate(z[:, 2])   # lowest height up to each row
    out[2:] = 2 * z[1:-1] - z[:-2]
    level = floor[1:-1] + offset
    below = (out[2:, 2] < level) & (level <= z[1:-1, 2])
    out[2:, 2] = np.where(below, level + restitution * (level - out[2:, 2]), out[2:, 2])
    return out


def bounce_oracle(tracks):
    """The best (RMS, restitution, offset) of a ground-bounce rule on the two-point extrapolation."""
    best = (np.inf, None, None)
    for restitution in RESTITUTIONS:
        for offset in OFFSETS:
            total, count = 0.0, 0
            for z, scored in tracks:
                error = z - bounce_forecasts(z, restitution, offset)
                ok = scored & np.isfinite(error).all(axis=1)
                total += float((error[ok] ** 2).sum())
                count += 3 * int(ok.sum())
            rms = float(np.sqrt(total / count))
            if rms < best[0]:
                best = (rms, restitution, offset)
    return best


def mixture_bounce_oracle():
    """The default mixture's one-step RMS on the ablation's scored rows, and the best (RMS, restitution, offset)
    of the ground-bounce rule applied to its forecasts (the floor: the lowest height measured before the row)."""
    from kalmix.bank import DEFAULT_BANK, make_bank
    from kalmix.core.compiled import engine as ce

    streams, scored, unit, tunit = scored_streams("hawkeye_ball")
    values, times = streams.values, streams.times
    bank = make_bank(values.shape[2], **DEFAULT_BANK, length_unit=unit, time_unit=tunit)
    forecasts = ce.run(bank, values, times, lengths=streams.lengths, score=scored).forecasts
    height = np.where(np.isfinite(values[..., 2]), values[..., 2], np.inf)
    floor = np.full_like(height, np.inf)
    floor[1:] = np.minimum.accumulate(height, axis=0)[:-1]          # the lowest height before each row
    last = np.full_like(height, np.nan)                               # the last measured height before each row
    for j in range(values.shape[1]):
        seen = np.where(np.isfinite(values[:, j, 2]), np.arange(len(values)), -1)
        before = np.maximum.accumulate(seen)[:-1]
        last[1:, j] = np.where(before >= 0, values[np.maximum(before, 0), j, 2], np.nan)

    def rms(f):
        error = np.where(scored[..., None], values - f, np.nan)
        return float(np.sqrt(np.nanmean(error ** 2)))

    by_rows = error_by_rows(values, forecasts, scored)
    best = (np.inf, None, None)
    for restitution in RESTITUTIONS:
        for offset in OFFSETS:
            level = floor + offset
            below = (forecasts[..., 2] < level) & (level <= last)
            bounced = forecasts.copy()
            bounced[..., 2] = np.where(below, level + restitution * (level - forecasts[..., 2]), forecasts[..., 2])
            value = rms(bounced)
            if value < best[0]:
                best = (value, restitution, offset)
    return rms(forecasts), best, by_rows


def error_by_rows(values, forecasts, scored, kicks=47, after=3):
    """Squared error (summed over the coordinates) of ``forecasts`` and of the two-point extrapolation on the
    scored rows where both forecast: on the ``kicks`` rows where the latter errs most, on the ``after`` rows
    after each, and on the others (the layout of the segments, ``(T, S, p)``)."""
    two = np.full_like(values, np.nan)
    two[2:] = 2 * values[1:-1] - values[:-2]
    squared = {name: np.where(scored, ((values - f) ** 2).sum(axis=-1), np.nan)
               for name, f in (("two-point", two), ("mixture", forecasts))}
    ok = np.isfinite(squared["two-point"]) & np.isfinite(squared["mixture"])
    kick = ok & (squared["two-point"] >= np.sort(squared["two-point"][ok])[-kicks])
    following = np.zeros_like(kick)
    for lag in range(1, after + 1):
        following[lag:] |= kick[:-lag]
    following &= ok & ~kick
    rows = {"kick rows": kick, f"{after} rows after each": following, "other rows": ok & ~kick & ~following}
    return {label: {"rows": int(mask.sum()), **{name: float(sq[mask].sum()) for name, sq in squared.items()}}
            for label, mask in rows.items()}


def combined_oracle(tracks, restitution, offset, lags=21):
    """The bounce rule's forecast plus the best linear correction from the last ``lags`` velocities of all
    three coordinates, fitted in hindsight on the scored rows."""
    return linear_oracle(tracks, lags, True, lambda z: z - bounce_forecasts(z, restitution, offset))[0]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the figures here")
    args = parser.parse_args(argv)
    tracks = scored_tracks()
    result = {"best_peer": BEST_PEER}
    rms, rows = two_point(tracks)
    result["two_point"] = rms
    print(f"two-point extrapolation: {rms:.5f} ({rms / BEST_PEER:.4f}x the best peer)")
    ranked = np.sort(rows)[::-1]
    shares = {f"top {k} rows": float(ranked[:k].sum() / ranked.sum()) for k in (10, 47, 100)}
    result["squared_error_shares"] = shares
    result["scored_rows"] = int(len(rows))
    print(f"  of its squared error over {len(rows)} scored rows: "
          + ", ".join(f"{k} {v:.0%}" for k, v in shares.items()))
    result["linear_oracle"] = {}
    for across in (False, True):
        for lags in (1, 2, 5, 10, 21):
            value, persistence = linear_oracle(tracks, lags, across)
            label = f"{'all coordinates' if across else 'per coordinate'}, {lags} velocities"
            result["linear_oracle"][label] = {"rms": value, "persistence": persistence}
            print(f"best linear predictor in hindsight, {label}: {value:.5f} ({value / BEST_PEER:.4f}x); "
                  f"its own velocity weights sum to {', '.join(f'{x:.3f}' for x in persistence)} (x, y, z)")
    result["kinematic_features_oracle"] = {}
    for lags in (2, 5, 21):
        value, _ = linear_oracle(tracks, lags, True, extra=kinematic_features)
        result["kinematic_features_oracle"][f"all coordinates, {lags} velocities"] = value
        print(f"best linear predictor in hindsight, all coordinates, {lags} velocities, with a constant (gravity), "
              f"|v| v (drag) and v*v terms: {value:.5f} ({value / BEST_PEER:.4f}x)")
    value, restitution, offset = bounce_oracle(tracks)
    result["bounce_oracle"] = {"rms": value, "restitution": restitution, "offset": offset}
    print(f"two-point + ground bounce, tuned in hindsight (restitution {restitution}, offset {offset} m): "
          f"{value:.5f} ({value / BEST_PEER:.4f}x)")
    both = combined_oracle(tracks, restitution, offset)
    result["bounce_and_linear_oracle"] = both
    print(f"both: the bounce rule and the best linear correction (all coordinates, 21 velocities) in hindsight: "
          f"{both:.5f} ({both / BEST_PEER:.4f}x)")
    plain, (value, restitution, offset), by_rows = mixture_bounce_oracle()
    result["default_mixture"] = plain
    result["default_mixture_squared_error_by_rows"] = by_rows
    result["default_mixture_bounce_oracle"] = {"rms": value, "restitution": restitution, "offset": offset}
    print(f"the default mixture (the ablation's protocol): {plain:.5f} ({plain / BEST_PEER:.4f}x); with the ground "
          f"bounce on its forecasts, tuned in hindsight (restitution {restitution}, offset {offset} m): "
          f"{value:.5f} ({value / BEST_PEER:.4f}x)")
    print("  its squared error against the two-point extrapolation's, by rows: " + "; ".join(
        f"{label} ({entry['rows']}) {entry['mixture']:.3f} against {entry['two-point']:.3f}"
        for label, entry in by_rows.items()))
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(result, handle, indent=2)


if __name__ == "__main__":
    main()
