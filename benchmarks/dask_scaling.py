"""``kalmix predict --engine dask`` against single-machine ``kalmix predict``, same data, same run (issue 14).

``python -m benchmarks.dask_scaling [--rows 1000000] [--tracks 2000] [--files 20] [--workers 1 2 4]
[--repeat 2] [--anatomy] [--json out.json]``

The data: ``--tracks`` smooth noisy tracks sampled every second, all interleaved in time (an archive of
reports by time), written as ``--files`` Parquet files (every track crosses every file boundary) and as
one file for the single-machine run. Each run is the ``kalmix`` command in a fresh process, timed from
start to exit (interpreter, cluster start, compiled-engine load included), default bank and settings,
after one untimed run that fills the compiled engine's cache.
Reports rows/s, the ratio to the single-machine run, the CPU seconds of all the run's processes
(workers included; less sensitive than wall time to a shared machine), the cluster's share of a
Dask run (after the cluster start and the first chunk), the largest difference of the predictions
(expected 0), and the load average around each run (the machine may be shared). ``--anatomy``
adds, per worker count, the task seconds by kind (read, shuffle, predict, write) and each
worker's busy seconds against the wall time, from Dask's task stream.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np
import pandas as pd


def make_archive(directory, rows, tracks, files, seed=0):
    """The archive (``files`` Parquet files) and the same rows as one file; returns the one file's path."""
    rng = np.random.default_rng(seed)
    steps = rows // tracks
    t = np.arange(steps, dtype=np.float64)[:, None] + rng.uniform(0, 1, tracks)[None, :]
    heading = rng.uniform(0, 2 * np.pi, tracks)
    turn = np.cumsum(rng.normal(0, 0.01, (steps, tracks)), axis=0)
    speed = rng.uniform(2, 10, tracks)
    x = np.cumsum(speed * np.cos(heading + turn), axis=0) + rng.normal(0, 0.5, (steps, tracks))
    y = np.cumsum(speed * np.sin(heading + turn), axis=0) + rng.normal(0, 0.5, (steps, tracks))
    frame = pd.DataFrame({"track_id": np.tile(np.arange(tracks), steps), "time": t.ravel(), "x": x.ravel(),
                          "y": y.ravel()})
    frame = frame.sort_values("time", kind="stable").reset_index(drop=True)
    archive = os.path.join(directory, "archive")
    os.makedirs(archive)
    for i, rows_ in enumerate(np.array_split(np.arange(len(frame)), files)):
        frame.iloc[rows_].to_parquet(os.path.join(archive, f"part-{i:04d}.parquet"), index=False)
    whole = os.path.join(directory, "whole.parquet")
    frame.to_parquet(whole, index=False)
    return archive, whole, len(frame)


def timed(command):
    """Wall seconds, CPU seconds of the command and every process it started, load averages, stderr lines."""
    load = os.getloadavg()[0]
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr}")
    cpu = after.ru_utime + after.ru_stime - usage.ru_utime - usage.ru_stime
    return seconds, cpu, load, os.getloadavg()[0], done.stderr.strip().splitlines()


def cluster_seconds(log):
    """The cluster's share of a Dask run, from its summary line."""
    match = re.search(r"\(([0-9.]+) s of work on the cluster", log[-1]) if log else None
    return float(match.group(1)) if match else None


def largest_difference(reference, got):
    a = pd.read_parquet(reference).sort_values(["track_id", "time"]).reset_index(drop=True)
    b = pd.read_parquet(got).sort_values(["track_id", "time"]).reset_index(drop=True)
    if len(a) != len(b) or not a[["track_id", "time", "segment"]].equals(b[["track_id", "time", "segment"]]):
        return float("inf")
    numbers = [c for c in a.columns if c.startswith("pred")]
    return float(np.nanmax(np.abs(a[numbers].to_numpy() - b[numbers].to_numpy())))


def anatomy(archive, workers, out):
    """Where a Dask run's task time goes: seconds per task kind and each worker's busy seconds (in process)."""
    import collections
    import logging

    from distributed import Client, LocalCluster, get_task_stream

    from kalmix.dask_predict import predict_dask, read_archive

    threads = str(max(1, (os.cpu_count() or 1) // workers))
    with LocalCluster(n_workers=workers, threads_per_worker=1, dashboard_address=None, silence_logs=logging.CRITICAL,
                      env={"NUMBA_NUM_THREADS": threads}) as cluster, Client(cluster) as client:
        frame, columns, _ = read_archive(archive)
        started = time.perf_counter()
        result = predict_dask(frame, columns, prepared=True, partitions=max(frame.npartitions, 4 * workers))
        units = time.perf_counter() - started
        write = result.to_parquet(out, write_index=False, compute=False)
        with get_task_stream(client) as stream:
            started = time.perf_counter()
            client.compute(write).result()
            wall = time.perf_counter() - started
    kinds, busy = collections.defaultdict(float), collections.defaultdict(float)
    for task in stream.data:
        seconds = sum(s["stop"] - s["start"] for s in task["startstops"] if s["action"] == "compute")
        key = task["key"][0] if isinstance(task["key"], tuple) else task["key"]
        kind = ("predict" if "predict_partition" in key else "read" if "kalmix-read" in key else
                "write" if "parquet" in key else "shuffle" if "shuffle" in key else "other")
        kinds[kind] += seconds
        busy[task["worker"]] += seconds
    return {"workers": workers, "units_and_meta_s": units, "wall_s": wall, "task_s": dict(kinds),
            "busy_s_per_worker": sorted(busy.values())}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--tracks", type=int, default=2_000)
    parser.add_argument("--files", type=int, default=20)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", default=None)
    parser.add_argument("--anatomy", action="store_true",
                        help="also, for each --workers, where the task time goes (in this process)")
    args = parser.parse_args(argv)
    kalmix = [sys.executable, "-m", "kalmix.cli"]
    work = tempfile.mkdtemp(prefix="kalmix-dask-bench-")
    try:
        archive, whole, n = make_archive(work, args.rows, args.tracks, args.files)
        print(f"{n} rows, {args.tracks} tracks, {args.files} files; {os.cpu_count()} cores", flush=True)
        sample = os.path.join(work, "sample.parquet")  # untimed: fills the compiled engine's cache
        pd.read_parquet(whole).iloc[:2000].to_parquet(sample, index=False)
        timed([*kalmix, "predict", sample, "-o", os.path.join(work, "sample-out.parquet"), "--no-progress"])
        results = []
        runs = [("single machine", None)] + [(f"dask, {w} worker(s)", w) for w in args.workers]
        for repeat in range(args.repeat):
            for label, workers in runs:
                out = os.path.join(work, f"out-{workers}-{repeat}" + (".parquet" if workers is None else ""))
                if workers is None:
                    command = [*kalmix, "predict", whole, "-o", out, "--no-progress"]
                else:
                    command = [*kalmix, "predict", archive, "--engine", "dask", "--workers", str(workers),
                               "-o", out, "--no-progress"]
                seconds, cpu, before, after, log = timed(command)
                busy = cluster_seconds(log) if workers else None
                results.append({"run": label, "workers": workers, "repeat": repeat, "seconds": seconds,
                                "cpu_seconds": cpu, "cluster_seconds": busy, "rows_per_s": n / seconds,
                                "load_before": before, "load_after": after, "output": out, "log": log})
                print(f"{label:>22}  {seconds:7.1f} s  {n / seconds:9.0f} rows/s  CPU {cpu:6.1f} s"
                      + (f"  cluster {busy:5.1f} s" if busy is not None else " " * 17)
                      + f"  (load {before:.2f} -> {after:.2f})", flush=True)
        best = {}
        for r in results:
            if r["run"] not in best or r["seconds"] < best[r["run"]]["seconds"]:
                best[r["run"]] = r
        single = best["single machine"]
        summary = []
        print("\nbest of the repeats; ratio = single-machine time / this time (> 1: faster); "
              "CPU = this run's CPU seconds / single-machine's")
        for label, workers in runs:
            r = best[label]
            difference = 0.0 if workers is None else largest_difference(single["output"], r["output"])
            entry = {"run": label, "workers": workers, "seconds": r["seconds"], "rows_per_s": r["rows_per_s"],
                     "cpu_seconds": r["cpu_seconds"], "cluster_seconds": r["cluster_seconds"],
                     "ratio_to_single": single["seconds"] / r["seconds"],
                     "cpu_ratio_to_single": r["cpu_seconds"] / single["cpu_seconds"], "max_difference": difference}
            summary.append(entry)
            print(f"{label:>22}  {r['seconds']:7.1f} s  {r['rows_per_s']:9.0f} rows/s  ratio "
                  f"{entry['ratio_to_single']:.2f}  CPU x{entry['cpu_ratio_to_single']:.2f}  "
                  f"max |difference| {difference:.3g}")
        parts = []
        if args.anatomy:
            print("\nwhere the task time goes (seconds of task time; each worker's busy seconds / wall)")
            for workers in args.workers:
                part = anatomy(archive, workers, os.path.join(work, f"anatomy-{workers}"))
                parts.append(part)
                kinds = ", ".join(f"{kind} {seconds:.1f}" for kind, seconds in
                                  sorted(part["task_s"].items(), key=lambda item: -item[1]))
                busy = ", ".join(f"{b:.1f}" for b in part["busy_s_per_worker"])
                print(f"{workers} worker(s): units+meta {part['units_and_meta_s']:.1f} s; tasks: {kinds}; busy "
                      f"{busy} of {part['wall_s']:.1f} s")
        if args.json:
            for r in results:
                r.pop("output")
            with open(args.json, "w") as handle:
                json.dump({"rows": n, "tracks": args.tracks, "files": args.files, "cores": os.cpu_count(),
                           "runs": results, "best": summary, "anatomy": parts}, handle, indent=2)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
