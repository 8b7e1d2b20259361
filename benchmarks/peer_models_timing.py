"""Seconds each peer of :mod:`kalmix.peer_models` takes to tune and predict, to choose ``max_rows``.

``python -m benchmarks.peer_models_timing [--tracks 10] [--rows 5000] [--peers cv_dt,...]``

Synthetic seeded tracks: smooth 2-D curves sampled at irregular times with noise 0.5 and
2 % missing rows; the tuning part is the first 20 % of each track. Prints, per peer, the
tune time, the predict time over every track at horizon 1 and 5 (``predict_many`` where
the peer has one), and the evaluation's one-step RMS on the rest, as a sanity check.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kalmix.peer_models import PEERS, available


def tracks(count: int, rows: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        times = np.cumsum(rng.uniform(0.5, 1.5, rows))
        freq, phase = rng.uniform(0.005, 0.03, 2), rng.uniform(0, 6, 2)
        values = 100 * np.sin(freq * times[:, None] + phase) + 0.5 * rng.normal(size=(rows, 2))
        values[rng.random(rows) < 0.02] = np.nan
        out.append((values, times, np.arange(rows) < rows // 5))
    return out


def main(count: int, rows: int, names: list[str]) -> None:
    segments = tracks(count, rows)
    print(f"{count} tracks x {rows} rows = {count * rows} rows; tuning part 20 %")
    print(f"{'peer':14s} {'tune s':>8s} {'h=1 s':>8s} {'h=5 s':>8s} {'rms h=1':>8s}")
    for name in names:
        peer = PEERS[name]
        if not available(peer):
            print(f"{name:14s} skipped: needs {', '.join(peer.needs)}")
            continue
        start = time.perf_counter()
        params = peer.tune(segments, unit=0.5, time_unit=1.0)
        tuned = time.perf_counter()
        seconds, errors = [], []
        for horizon in (1, 5):
            start_h = time.perf_counter()
            if peer.predict_many is not None:
                predictions = peer.predict_many([(v, t) for v, t, _ in segments], params, horizon)
            else:
                predictions = [peer.predict(v, t, params, horizon) for v, t, _ in segments]
            seconds.append(time.perf_counter() - start_h)
            if horizon == 1:
                errors = np.concatenate([(v[1:] - p[:-1])[~m[1:]] for (v, _, m), p in zip(segments, predictions)])
        rms = float(np.sqrt(np.nanmean(errors**2)))
        print(f"{name:14s} {tuned - start:8.1f} {seconds[0]:8.1f} {seconds[1]:8.1f} {rms:8.3f}", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m benchmarks.peer_models_timing", description=__doc__)
    parser.add_argument("--tracks", type=int, default=10)
    parser.add_argument("--rows", type=int, default=5000)
    parser.add_argument("--peers", default=",".join(PEERS), help="comma-separated names (default: all)")
    arguments = parser.parse_args()
    main(arguments.tracks, arguments.rows, arguments.peers.split(","))
