"""GPU engine against the compiled CPU engine, same run, same data (kalmix issue 16).

Run on a machine with an NVIDIA GPU: ``python -m benchmarks.gpu [--bank default|kinematic]
[--targets 1e4 1e5 1e6] [--steps 50] [--cpu-limit 1e5] [--json out.json]``. ``default`` is the
bank ``kalmix predict`` uses (``make_bank(2, **DEFAULT_BANK)``: CV, CA, 4 AR orders, turn and 40
AKF, 119 experts, BOA, the glitch screen), run by the staged GPU engine; ``kinematic`` is
``make_bank(2, "kinematic")`` (28 experts), run by the fused kernel. Each size: the GPU run (kernels
alone and with the transfers), the CPU engine on every core (``NUMBA_NUM_THREADS``) up to
``--cpu-limit`` targets, the largest relative difference between them, expert-steps/s, and the
state and scratch bytes per target.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from kalmix.bank import DEFAULT_BANK, make_bank
from kalmix.core.compiled import engine as cpu
from kalmix.core.compiled import gpu
from kalmix.core.engine import init_bank_state


def tracks(n, steps, seed=0):
    rng = np.random.default_rng(seed)
    z = np.cumsum(np.cumsum(rng.normal(0, 0.05, (steps, n, 2)), axis=0), axis=0) + rng.normal(0, 0.3, (steps, n, 2))
    times = np.broadcast_to(np.arange(steps, dtype=float)[:, None], (steps, n))
    return z, times


def state_bytes(bank, n=1000):
    state = init_bank_state(bank, n)
    total = 0
    stack = [state]
    while stack:
        item = stack.pop()
        if isinstance(item, tuple):
            stack.extend(item)
        elif isinstance(item, np.ndarray):
            total += item.nbytes
    return total / n


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--bank", choices=("default", "kinematic"), default="default")
    parser.add_argument("--targets", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--cpu-limit", type=float, default=1e5, help="skip the CPU run above this many targets")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    if args.bank == "default":
        bank = make_bank(2, **DEFAULT_BANK, length_unit=0.3)
    else:
        bank = make_bank(2, "kinematic", length_unit=0.3)
    k = bank.n_experts
    z, t = tracks(256, 10)
    start = time.perf_counter()
    gpu.run(bank, z, t)       # compile
    compile_gpu = time.perf_counter() - start
    start = time.perf_counter()
    cpu.run(bank, z, t)
    compile_cpu = time.perf_counter() - start
    print(json.dumps(dict(compile_gpu_s=compile_gpu, compile_cpu_s=compile_cpu)), flush=True)
    rows = []
    import numba

    for size in args.targets:
        n = int(size)
        z, t = tracks(n, args.steps)
        timings = {}
        g = gpu.run(bank, z, t, timings=timings)
        row = dict(targets=n, steps=args.steps, experts=k, gpu_kernel_s=timings["kernel"], gpu_total_s=timings["total"],
                   gpu_expert_steps_per_s=n * args.steps * k / timings["kernel"],
                   gpu_expert_steps_per_s_with_transfers=n * args.steps * k / timings["total"])
        if n <= args.cpu_limit:
            start = time.perf_counter()
            c = cpu.run(bank, z, t)
            seconds = time.perf_counter() - start
            fin = np.isfinite(c.forecasts)
            diff = np.abs(c.forecasts[fin] - g.forecasts[fin]) / np.maximum(1.0, np.abs(c.forecasts[fin]))
            row.update(cpu_s=seconds, cpu_threads=numba.get_num_threads(),
                       cpu_expert_steps_per_s=n * args.steps * k / seconds,
                       speedup_kernel=seconds / timings["kernel"], speedup_with_transfers=seconds / timings["total"],
                       max_relative_difference=float(diff.max()),
                       same_missing=bool(np.array_equal(fin, np.isfinite(g.forecasts))))
        if not gpu.fused(bank) and n <= 1e5:   # where the time goes: each kernel alone (waits after each)
            from kalmix.core.compiled import gpu_staged

            stages = {}
            gpu_staged.run(bank, z, t, stages=stages)
            row["gpu_stage_s"] = stages
        rows.append(row)
        print(json.dumps(row), flush=True)
    from numba import cuda

    from kalmix.core.compiled import gpu_staged

    families = ", ".join(f"{f.kind} {f.n_experts}" for f in bank.families)
    result = dict(bank=f"{args.bank}: {families} ({k} experts, {bank.rule}, screen)",
                  engine="fused kernel" if gpu.fused(bank) else "staged", state_bytes_per_target=state_bytes(bank),
                  device_bytes_per_target=gpu_staged.bytes_per_target(bank, args.steps),
                  compile_gpu_s=compile_gpu, compile_cpu_s=compile_cpu, rows=rows,
                  device=cuda.get_current_device().name.decode() if hasattr(cuda.get_current_device().name, "decode")
                  else str(cuda.get_current_device().name))
    print(json.dumps({key: value for key, value in result.items() if key != "rows"}))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main()
