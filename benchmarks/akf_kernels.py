"""The compiled AKF kernels of source trees side by side: speed by bank size, and compile time from an empty cache.

``python -m benchmarks.akf_kernels [--tree LABEL=SRC ...] [--quick] [--json out.json]``

Each ``--tree`` is a kalmix source directory (``src`` of a checkout; default: this checkout's) and every figure
of it is measured in fresh processes with ``PYTHONPATH=SRC``, the trees taking turns, so that two versions of
the code meet the same machine load. A tree's kernels are the modules whose ``run_targets(lo, hi, measurements,
lengths, horizon, params, state, records)`` :func:`kalmix.core.fast.run_fast` can choose between (the ones of
:data:`KERNELS` that the tree has). For each kernel:

- **speed**: the paper mixture's AKF step (``make_params(3, K)``: RLS dynamics, the fixed-share gate, eq. 11/12
  noise feedback) at K = 1, 2, 4, 8, 16 and 40 experts on one target x 20,000 rows and on 1,000 targets x
  200 rows, one thread (one ``run_targets`` call over every target), compiled code warm (a first call
  untimed), the best of ``--repeat`` calls in CPU seconds (a shared machine's load stretches wall seconds
  far more); target-steps and expert-steps per second. Each workload and bank size runs every tree in turn
  (a fresh process each), and the predictions' hashes show that every kernel gives the same bits;
- **compile**: the first call of ``run_targets`` (one target x 4 rows) in a new process with an empty
  ``KALMIX_CACHE_DIR``: numba's compile of the kernel and everything it calls.

With ``--cold``, each tree's **cold start** too: ``kalmix predict examples/boats.csv`` (``python -m kalmix.cli``)
with an empty ``KALMIX_CACHE_DIR``, i.e. what a fresh install costs before its first result (the default bank:
every kernel compiles, the AKF family's in a second process), then the same command again (warm): wall seconds
and the CPU seconds of the command and its compile process.

``os.getloadavg()`` is recorded beside every figure: compile times on a busy machine grow with its load.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
#: Kernel modules a tree may have (name, module); each exposes ``run_targets``.
KERNELS = (("experts_last", "kalmix.core._numba_kernels"), ("scalar", "kalmix.core._numba_scalar"))
EXPERTS = (1, 2, 4, 8, 16, 40)
#: (name, targets, rows)
WORKLOADS = (("one_target", 1, 20_000), ("many_targets", 1_000, 200))
QUICK_WORKLOADS = (("one_target", 1, 2_000), ("many_targets", 100, 50))


def tracks(steps: int, targets: int, dim: int = 3, seed: int = 0) -> np.ndarray:
    """Smooth noisy tracks ``(steps, targets, dim)``: integrated random accelerations plus noise."""
    rng = np.random.default_rng(seed)
    velocity = np.cumsum(rng.normal(scale=0.05, size=(steps, targets, dim)), axis=0)
    return np.cumsum(velocity, axis=0) + rng.normal(scale=0.1, size=(steps, targets, dim))


# -- in a worker process (PYTHONPATH = the tree) ---------------------------------------------------------------

def _available() -> list:
    import importlib.util

    return [(name, module) for name, module in KERNELS if importlib.util.find_spec(module) is not None]


def _call(kernel, params, z, horizon=1):
    """One ``run_targets`` call over every target of ``z``; its CPU seconds and predictions."""
    from kalmix.core import fast, init_state

    packed_params = fast.pack_params(params)
    packed_state = fast.pack_state(init_state(params, z.shape[1]))
    t_count, n, p = z.shape
    predictions = np.empty((t_count, n, p))
    records = (predictions, False, np.empty((0, 0, 0)), np.empty((0, 0)), np.empty((0, 0, 0, 0)),
               np.empty((0, 0, 0, 0)), False, np.empty((0, 0, 0, 0)))
    lengths = np.full(n, t_count, dtype=np.int64)
    start = time.process_time()
    kernel.run_targets(0, n, z, lengths, horizon, packed_params, packed_state, records)
    return time.process_time() - start, predictions


def worker_speed(repeats: int, workload: str, k: int) -> dict:
    """Every kernel of this tree on one workload and bank size; the predictions' hash (trees compare them)."""
    import importlib

    from kalmix.bank import make_params

    kernels = [(name, importlib.import_module(module)) for name, module in _available()]
    rows = []
    targets, steps = dict((w, (t, s)) for w, t, s in WORKLOADS + tuple(("quick_" + w, t, s)
                                                                        for w, t, s in QUICK_WORKLOADS))[workload]
    z = np.ascontiguousarray(tracks(steps, targets))
    params = make_params(3, k)
    for name, kernel in kernels:
        _call(kernel, params, z[:4])   # compiled (or loaded) outside the timing
        load = os.getloadavg()[0]
        best, predictions = min((_call(kernel, params, z) for _ in range(repeats)), key=lambda r: r[0])
        rows.append({"kernel": name, "workload": workload, "targets": targets, "rows": steps, "experts": k,
                     "seconds": best, "target_steps_per_s": targets * steps / best,
                     "expert_steps_per_s": targets * steps * k / best,
                     "predictions_sha256": hashlib.sha256(predictions.tobytes()).hexdigest(), "load_1min": load})
    return {"kernels": [name for name, _ in kernels], "speed": rows}


def worker_compile(name: str) -> dict:
    """The first call of one kernel (run in a process whose ``KALMIX_CACHE_DIR`` is empty)."""
    import importlib

    from kalmix.bank import make_params

    start = time.perf_counter()
    kernel = importlib.import_module(dict(KERNELS)[name])
    imported = time.perf_counter() - start
    load = os.getloadavg()[0]
    start = time.perf_counter()
    cpu, _ = _call(kernel, make_params(3, 4), np.ascontiguousarray(tracks(4, 1)))
    return {"kernel": name, "compile_seconds": time.perf_counter() - start, "compile_cpu_seconds": cpu,
            "import_seconds": imported, "load_1min_before": load, "load_1min_after": os.getloadavg()[0]}


# -- the driver ----------------------------------------------------------------------------------------------

def _predict(src: str, cache: str, out: str) -> dict:
    """``kalmix predict examples/boats.csv`` in a new process: wall and CPU seconds (its children's included)."""
    env = {**os.environ, "PYTHONPATH": src, "KALMIX_CACHE_DIR": cache}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    before, load = resource.getrusage(resource.RUSAGE_CHILDREN), os.getloadavg()[0]
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", str(ROOT / "examples" / "boats.csv"), "-o", out,
                    "--no-progress"], cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"seconds": seconds, "cpu_seconds": cpu, "load_1min_before": load, "load_1min_after": os.getloadavg()[0]}


def cold_start(src: str) -> dict:
    with tempfile.TemporaryDirectory() as directory:
        cache = os.path.join(directory, "cache")
        cold = _predict(src, cache, os.path.join(directory, "cold.csv"))
        warm = _predict(src, cache, os.path.join(directory, "warm.csv"))
        with open(os.path.join(directory, "cold.csv"), "rb") as one, open(os.path.join(directory, "warm.csv"),
                                                                           "rb") as two:
            first, second = one.read(), two.read()
    return {"file": "examples/boats.csv", "cold": cold, "warm": warm, "same_output": first == second,
            "output_sha256": hashlib.sha256(first).hexdigest()}


def _worker(src: str, args: list, env: dict | None = None) -> dict:
    env = {**os.environ, **(env or {}), "PYTHONPATH": src, "NUMBA_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", "benchmarks.akf_kernels", "--worker", *args], cwd=ROOT, env=env,
                          check=True, stdout=subprocess.PIPE)
    return json.loads(done.stdout)


def _commit(src: str) -> str | None:
    done = subprocess.run(["git", "-C", src, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", src, "status", "--porcelain", "--", "."], capture_output=True, text=True)
    return (done.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")) if done.returncode == 0 else None


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tree", action="append", default=None, metavar="LABEL=SRC",
                        help="a kalmix source directory to measure (repeatable; default: this checkout's src)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small sizes (a smoke test)")
    parser.add_argument("--no-compile", action="store_true", help="skip the compile times")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed figures")
    parser.add_argument("--cold", action="store_true", help="also time kalmix predict from an empty cache (minutes)")
    parser.add_argument("--json", default=None)
    parser.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        task = args.worker[0]
        if task == "speed":
            result = worker_speed(args.repeat, args.worker[1], int(args.worker[2]))
        elif task == "kernels":
            result = {"kernels": [name for name, _ in _available()]}
        else:
            result = worker_compile(args.worker[1])
        print(json.dumps(result))
        return result
    trees = dict(tree.split("=", 1) for tree in (args.tree or [f"this={ROOT / 'src'}"]))
    results = {"machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                           "load_average_before": os.getloadavg()},
               "command": " ".join(["python -m benchmarks.akf_kernels"] + [f"--tree {t}" for t in args.tree or []]
                                   + ["--quick"] * args.quick + ["--no-speed"] * args.no_speed
                                   + ["--no-compile"] * args.no_compile
                                   + ["--cold"] * args.cold + (["--json", args.json] if args.json else [])),
               "trees": {label: {"commit": _commit(src)} for label, src in trees.items()}}
    for label, src in trees.items():
        results["trees"][label].update(_worker(src, ["kernels"]))
        results["trees"][label]["speed"] = []
    if not args.no_speed:
        for workload, _, _ in WORKLOADS:
            for k in EXPERTS:
                for label, src in trees.items():   # the trees take turns
                    name = ("quick_" if args.quick else "") + workload
                    rows = _worker(src, ["speed", name, str(k), "--repeat", str(args.repeat)])["speed"]
                    results["trees"][label]["speed"] += rows
                    print(label, json.dumps(rows), file=sys.stderr, flush=True)
    if not args.no_compile:
        for label, src in trees.items():
            compiles = []
            for name in results["trees"][label]["kernels"]:
                with tempfile.TemporaryDirectory() as cache:
                    compiles.append(_worker(src, ["compile", name], env={"KALMIX_CACHE_DIR": cache}))
                print(label, json.dumps(compiles[-1]), file=sys.stderr, flush=True)
            results["trees"][label]["compile"] = compiles
    if args.cold:
        for label, src in trees.items():
            results["trees"][label]["cold_start"] = cold_start(src)
            print(label, "cold start", json.dumps(results["trees"][label]["cold_start"]), file=sys.stderr, flush=True)
    results["machine"]["load_average_after"] = os.getloadavg()
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=1)
    return results


if __name__ == "__main__":
    main()
