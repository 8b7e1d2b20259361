"""Speed of the default bank on the compiled engine and through ``kalmix predict``, beside peers, same run.

``python -m benchmarks.engine_speed [--quick] [--cold] [--json out.json]``

The issue-11 figures, each the median of ``--repeat`` timed runs after an untimed warm-up:

- **one stream**: the default bank (:data:`kalmix.bank.DEFAULT_BANK`, every family) on one 3-D
  track of 4,000 rows, ``kalmix.core.compiled.engine.run``: steps/s. Peer: filterpy's
  ``IMMEstimator`` over a CV and a CA Kalman filter (a Python loop), same data;
- **10,000 targets**: the same bank on 10,000 tracks x 50 rows at once: target-steps/s and
  expert-steps/s (target-steps x experts). Peer: simdkalman's batched CV Kalman filter on the same
  tracks (one 2-state filter per coordinate, no mixture);
- **the CLI**: ``kalmix predict`` of a 100-track, 100,000-row CSV sorted by time (a fresh process,
  interpreter and imports included, warm compiled cache, kalmix's bytecode kept as an install keeps it):
  rows/s. Peer: a filterpy CV Kalman
  filter per track over the same CSV, read with pandas (a Python loop); and the same CSV piped into
  ``kalmix predict -`` (stdin: the lines that have arrived are stepped together);
- **a live row**: ``TrackPredictor.step_row`` on one 3-D track, one row a call (a live feed): the median
  latency. Peer: filterpy's IMM, a predict and an update a row;
- **cold start** (``--cold``): ``kalmix predict`` of a 1,000-row CSV with an empty compiled-engine
  cache, i.e. what a fresh install costs before the first result.

Every kalmix figure runs the bank the commands use by default, with the glitch screen and the
calibrated intervals; the peers do strictly less work (one model, no intervals).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import pandas as pd


def tracks(steps: int, targets: int, dim: int = 3, seed: int = 0) -> np.ndarray:
    """Smooth noisy tracks ``(steps, targets, dim)``: integrated random accelerations plus noise."""
    rng = np.random.default_rng(seed)
    velocity = np.cumsum(rng.normal(scale=0.05, size=(steps, targets, dim)), axis=0)
    return np.cumsum(velocity, axis=0) + rng.normal(scale=0.1, size=(steps, targets, dim))


def median_seconds(function, repeats: int) -> float:
    function()  # warm-up: compilation or cache load outside the timing
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def default_bank(dim: int):
    from kalmix.bank import DEFAULT_BANK, make_bank

    return make_bank(dim, **DEFAULT_BANK, length_unit=0.1, time_unit=1.0)


def one_stream(steps: int, imm_steps: int, repeats: int) -> dict:
    from kalmix.core.compiled import engine
    from kalmix.peers import imm_predictions

    z = tracks(steps, 1)
    times = np.arange(steps, dtype=float)[:, None]
    bank = default_bank(3)
    seconds = median_seconds(lambda: engine.run(bank, z, times), repeats)
    imm_seconds = median_seconds(lambda: imm_predictions(z[:imm_steps, 0]), max(1, repeats // 2))
    ours, imm = steps / seconds, imm_steps / imm_seconds
    return {"steps": steps, "experts": bank.n_experts, "steps_per_s": ours, "imm_steps_per_s": imm,
            "ratio_to_imm": ours / imm, "target_steps_per_s": 30_000}


def many_targets(targets: int, steps: int, repeats: int) -> dict:
    import simdkalman

    from kalmix.core.compiled import engine

    z = tracks(steps, targets)
    times = np.broadcast_to(np.arange(steps, dtype=float)[:, None], (steps, targets))
    bank = default_bank(3)
    seconds = median_seconds(lambda: engine.run(bank, z, times), repeats)
    cv = simdkalman.KalmanFilter(state_transition=np.array([[1.0, 1.0], [0.0, 1.0]]),
                                 process_noise=np.diag([1e-4, 1e-2]), observation_model=np.array([[1.0, 0.0]]),
                                 observation_noise=0.01)
    series = np.ascontiguousarray(z.transpose(1, 2, 0).reshape(targets * 3, steps))
    peer = median_seconds(lambda: cv.compute(series, 0, filtered=True, smoothed=False), repeats)
    target_steps = targets * steps
    return {"targets": targets, "steps": steps, "experts": bank.n_experts,
            "target_steps_per_s": target_steps / seconds, "expert_steps_per_s": target_steps * bank.n_experts / seconds,
            "simdkalman_cv_target_steps_per_s": target_steps / peer,
            "ratio_to_simdkalman_target_steps": (target_steps / seconds) / (target_steps / peer),
            "target_expert_steps_per_s": 5e6}


def live_row(rows: int) -> dict:
    """Latency of a live feed's row: ``TrackPredictor.step_row`` (the default bank with the screen and
    intervals, as ``kalmix predict -`` runs it), one 3-D track, one row a call, after a warm-up of 200 rows:
    the median and 90th percentile over ``rows`` calls. Peer: filterpy's IMM, a predict and update a row (the
    Python loop of the one-stream peer), per row."""
    from kalmix.peers import imm_predictions
    from kalmix.streaming import StreamConfig, TrackPredictor

    z = tracks(rows + 200, 1)[:, 0]
    predictor = TrackPredictor(StreamConfig(length_unit=0.1))
    for t in range(200):
        predictor.step_row(0, float(t), z[t])
    seconds = []
    for t in range(200, rows + 200):
        start = time.perf_counter()
        predictor.step_row(0, float(t), z[t])
        seconds.append(time.perf_counter() - start)
    imm_predictions(z[:50])   # warm-up
    start = time.perf_counter()
    imm_predictions(z[:rows])
    imm = (time.perf_counter() - start) / rows
    median = float(np.median(seconds))
    return {"rows": rows, "median_ms": 1e3 * median, "p90_ms": 1e3 * float(np.percentile(seconds, 90)),
            "imm_ms_per_row": 1e3 * imm, "ratio_to_imm": median / imm}


def write_csv(path, rows: int, n_tracks: int, seed: int = 0) -> None:
    steps = rows // n_tracks
    z = tracks(steps, n_tracks, dim=2, seed=seed)
    t = np.arange(steps, dtype=float)
    frame = pd.DataFrame({"time": np.repeat(t, n_tracks), "track_id": np.tile(np.arange(n_tracks), steps),
                          "x": z[..., 0].ravel(), "y": z[..., 1].ravel()})
    frame.to_csv(path, index=False)


def kalmix_command() -> str:
    """The ``kalmix`` script of this interpreter's environment."""
    beside = os.path.join(os.path.dirname(sys.executable), "kalmix")
    return beside if os.path.exists(beside) else (shutil.which("kalmix") or "kalmix")


def as_installed(env=None) -> dict:
    """The environment of a timed command, with Python allowed to keep kalmix's bytecode as ``pip install``
    does: with ``PYTHONDONTWRITEBYTECODE=1`` (set in some sandboxes) a source checkout compiled kalmix's
    modules again on every run, 0.07-0.1 s of the 100k-row run that no installed copy pays."""
    env = dict(os.environ if env is None else env)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run_cli(path, out, env=None) -> float:
    start = time.perf_counter()
    subprocess.run([kalmix_command(), "predict", str(path), "-o", str(out), "--no-progress"],
                   check=True, env=as_installed(env), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - start


def run_cli_stdin(path, out) -> float:
    """The same CSV piped into ``kalmix predict -`` (stdin has no sample for the length unit: 0.1 given)."""
    start = time.perf_counter()
    with open(path, "rb") as source, open(out, "wb") as sink:
        subprocess.run([kalmix_command(), "predict", "-", "--length-unit", "0.1", "--no-progress"],
                       check=True, env=as_installed(), stdin=source, stdout=sink, stderr=subprocess.PIPE)
    return time.perf_counter() - start


def filterpy_cv_csv(path) -> None:
    """The peer of the CLI row: read the CSV, run one filterpy CV Kalman filter per track, row by row."""
    from filterpy.kalman import KalmanFilter

    frame = pd.read_csv(path)
    filters = {}
    out = np.empty((len(frame), 2))
    for i, (track, x, y) in enumerate(zip(frame["track_id"].to_numpy(), frame["x"].to_numpy(),
                                          frame["y"].to_numpy())):
        kf = filters.get(track)
        if kf is None:
            kf = KalmanFilter(dim_x=4, dim_z=2)
            kf.F = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
            kf.H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=float)
            kf.R *= 0.01
            kf.Q = np.diag([1e-4, 1e-4, 1e-2, 1e-2])
            kf.x[:2, 0] = (x, y)
            filters[track] = kf
        kf.predict()
        out[i] = kf.x[:2, 0]
        kf.update(np.array([x, y]))


def cli(rows: int, n_tracks: int, repeats: int) -> dict:
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, "tracks.csv")
        write_csv(path, rows, n_tracks)
        seconds = median_seconds(lambda: run_cli(path, os.path.join(directory, "out.csv")), repeats)
        piped = median_seconds(lambda: run_cli_stdin(path, os.path.join(directory, "piped.csv")), repeats)
        peer = median_seconds(lambda: filterpy_cv_csv(path), 1)
    return {"rows": rows, "tracks": n_tracks, "seconds": seconds, "rows_per_s": rows / seconds,
            "stdin_seconds": piped, "stdin_rows_per_s": rows / piped,
            "filterpy_cv_rows_per_s": rows / peer, "ratio_to_filterpy_cv": peer / seconds,
            "target_rows_per_s": 50_000}


def cold_start(rows: int) -> dict:
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, "small.csv")
        write_csv(path, rows, 10)
        env = {**os.environ, "KALMIX_CACHE_DIR": os.path.join(directory, "empty-cache")}
        seconds = run_cli(path, os.path.join(directory, "out.csv"), env=env)
        warm = run_cli(path, os.path.join(directory, "out2.csv"), env=env)
    return {"rows": rows, "cold_seconds": seconds, "warm_seconds": warm, "target_cold_seconds": 30}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smaller sizes (a smoke test)")
    parser.add_argument("--cold", action="store_true", help="also time a cold start (empty cache; minutes)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    quick = args.quick
    results = {"machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                           "load_average_before": os.getloadavg()}}
    results["one_stream"] = one_stream(400 if quick else 4000, 100 if quick else 1000, args.repeat)
    print("one stream", results["one_stream"], flush=True)
    results["many_targets"] = many_targets(500 if quick else 10_000, 20 if quick else 50, args.repeat)
    print("many targets", results["many_targets"], flush=True)
    results["live_row"] = live_row(300 if quick else 3000)
    print("live row", results["live_row"], flush=True)
    results["cli"] = cli(5000 if quick else 100_000, 100, args.repeat)
    print("cli", results["cli"], flush=True)
    if args.cold:
        results["cold_start"] = cold_start(1000)
        print("cold start", results["cold_start"], flush=True)
    results["machine"]["load_average_after"] = os.getloadavg()
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=1)
    return results


if __name__ == "__main__":
    main()
