"""Speed and memory of kalmix against filterpy and simdkalman, measured in one run.

``python -m benchmarks`` (a thin wrapper kept at the repository root) and ``kalmix bench``
both call :func:`main`. The code lives in the package so that the installed CLI can run
it. Every figure is the median of several timed repetitions (wall clock,
``time.perf_counter``) after one untimed warm-up run (numba compilation excluded).

Sections
--------
(a) one stream, K = 40 experts, p = 3 (state size n = 6): kalmix (numba and numpy)
    against filterpy's ``IMMEstimator`` over 40 ``KalmanFilter`` objects of the same size;
(b) N targets x K = 40: target-steps/s, expert-steps/s and peak memory per target
    (``tracemalloc``: the arrays numpy allocates, i.e. state, copies and outputs; the
    numba kernel's per-thread scratch, a few kB, is not counted);
(c) plain Kalman filtering (K = 1, fixed constant-velocity A, p = 1, n = 2) of 10,000
    series x 1,000 steps against ``simdkalman`` on the same model and data, with a
    check that both give the same predictions;
(d) cost per expert-step against K (1 ... 256) and against the state size (order).

The physical limit is estimated from a flop count of one expert-step (see
:func:`flops_per_expert_step`) and the machine's peak (cores x clock x flops/cycle).
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import time
import tracemalloc

import numpy as np

from .bank import make_params
from .core.dynamics import companion_from_theta
from .core.mixture import observation_matrix
from .core.run import run_core

__all__ = ["run_benchmarks", "markdown_table", "plot", "main", "flops_per_expert_step", "machine_peak"]


# ----------------------------------------------------------------------------- helpers
def tracks(seed: int, steps: int, targets: int, dim: int) -> np.ndarray:
    """Smooth curves with noise in pixel-like units, shape (T, N, p)."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps)[:, None, None]
    freq = rng.uniform(0.01, 0.08, size=(1, targets, dim))
    phase = rng.uniform(0, 2 * np.pi, size=(1, targets, dim))
    return 300 + 50 * np.sin(freq * t + phase) + 0.5 * rng.normal(size=(steps, targets, dim))


def median_seconds(function, repeats: int, warmup=None) -> float:
    """Median wall time of ``repeats`` calls after one warm-up call (``warmup`` or ``function``)."""
    (warmup or function)()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def flops_per_expert_step(p: int, order: int, dynamics: str = "rls") -> float:
    """Floating-point operations of one expert and one step (an FMA counts 2), estimated.

    Kalman update with C = [I 0] (gain, Joseph form), prediction with a companion A,
    and for ``rls`` the statistics update, the Cholesky solve and one guard check
    (characteristic polynomial and Schur-Cohn). Scoring and gating add O(p) per expert.
    """
    n = order * p
    d = n + 1
    update = 2 * (p**3 / 3 + n * p * p + 2 * n * n * p + n * p) + 2 * n * n
    predict = 2 * (2 * p * n * n + n * n) + 2 * n * n
    total = update + predict + 10 * p
    if dynamics == "rls":
        total += (4 * (d * d + p * d) + 2 * (d**3 / 3 + 2 * p * d * d) + 2 * (p**3 * (order + 1) ** 2 + n * n)
                  + 4 * p * d)
    return float(total)


def machine_peak() -> dict:
    """Cores, clock and peak double-precision flop rates (vector FMA and scalar FMA)."""
    cores = os.cpu_count() or 1
    mhz, flags = None, ""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if mhz is None and line.startswith("cpu MHz"):
                    mhz = float(line.split(":")[1])
                if not flags and line.startswith("flags"):
                    flags = line
    except OSError:
        pass
    ghz = (mhz or 2000.0) / 1000.0
    lanes = 8 if " avx512f" in flags else 4 if " avx2" in flags else 2
    per_cycle_vector = 2 * 2 * lanes  # two FMA ports, 2 flops per FMA
    return dict(cores=cores, ghz=ghz, simd_doubles=lanes, model=platform.processor() or platform.machine(),
                peak_flops=cores * ghz * 1e9 * per_cycle_vector,
                scalar_peak_flops=cores * ghz * 1e9 * 4, single_core_scalar_flops=ghz * 1e9 * 4)


# ----------------------------------------------------------------------------- (a)
def _filterpy_imm(params, z):
    """filterpy IMMEstimator over K KalmanFilters with the bank's A, Q, R (one stream)."""
    from filterpy.kalman import IMMEstimator, KalmanFilter

    k, p, n = params.n_experts, params.measurement_dim, params.state_dim
    kappa = params.feature_scale
    transition, _ = companion_from_theta(params.prior_theta, params.order)
    filters = []
    for i in range(k):
        f = KalmanFilter(dim_x=n, dim_z=p)
        f.F = transition.copy()
        f.H = observation_matrix(params)
        q = np.zeros((n, n))
        q[:p, :p] = np.diag(params.process_noise[i]) / kappa**2
        f.Q = q + params.state_jitter * np.eye(n)
        f.R = np.diag(params.measurement_noise[i]) / kappa**2
        f.P = params.initial_variance[i] / kappa**2 * np.eye(n)
        filters.append(f)
    switch = np.full((k, k), 0.03 / max(k - 1, 1))
    np.fill_diagonal(switch, 0.97 if k > 1 else 1.0)
    imm = IMMEstimator(filters, np.full(k, 1.0 / k), switch)
    features = (z[:, 0] - z[0, 0]) / kappa

    def run():
        for row in features:
            imm.predict()
            imm.update(row)

    return run


def bench_single_stream(steps: int, imm_steps: int, numpy_steps: int, repeats: int) -> dict:
    params = make_params(3, 40)
    z = tracks(0, steps, 1, 3)
    numba_s = median_seconds(lambda: run_core(params, z, backend="numba"), repeats,
                             warmup=lambda: run_core(params, z[:2], backend="numba"))
    numpy_s = median_seconds(lambda: run_core(params, z[:numpy_steps], backend="numpy"), max(1, repeats // 2),
                             warmup=lambda: run_core(params, z[:2], backend="numpy"))
    result = dict(n_experts=40, measurement_dim=3, state_dim=params.state_dim, steps=steps,
                  kalmix_steps_per_s=steps / numba_s, kalmix_numpy_steps_per_s=numpy_steps / numpy_s)
    try:
        imm = _filterpy_imm(params, z[:imm_steps])
        imm_seconds = median_seconds(imm, max(1, repeats // 2), warmup=lambda: None)
        result["filterpy_imm40_steps_per_s"] = imm_steps / imm_seconds
        result["ratio_vs_filterpy"] = result["kalmix_steps_per_s"] / result["filterpy_imm40_steps_per_s"]
    except ImportError:
        result["filterpy_imm40_steps_per_s"] = None
    return result


# ----------------------------------------------------------------------------- (b)
def bench_batch(targets, budget: float, repeats: int, min_steps: int = 5) -> dict:
    params = make_params(3, 40)
    out = dict(targets=list(targets), steps=[], target_steps_per_s=[], expert_steps_per_s=[], peak_mb_per_target=[],
               memory_method="tracemalloc peak of numpy allocations during run_core (numba scratch excluded)")
    for n in targets:
        steps = int(max(min_steps, min(1000, budget / (n * 40))))
        z = tracks(1, steps, n, 3)
        run_core(params, z[:1], backend="numba")  # compile (or load the cache) outside the timing
        # tracemalloc traces numpy's allocations only, so it does not slow the compiled loop
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        seconds = median_seconds(lambda: run_core(params, z, backend="numba"), repeats,
                                 warmup=lambda: None)
        peak = tracemalloc.get_traced_memory()[1] - base
        tracemalloc.stop()
        out["steps"].append(steps)
        out["target_steps_per_s"].append(n * steps / seconds)
        out["expert_steps_per_s"].append(n * steps * 40 / seconds)
        out["peak_mb_per_target"].append(peak / n / 1e6)
    return out


# ----------------------------------------------------------------------------- (c)
def bench_plain_kf(series: int, steps: int, repeats: int) -> dict:
    params = make_params(1, 1, order=2, dynamics="fixed", adapt_noise=False, initial_velocity_spread=0.0)
    z = tracks(2, steps, series, 1)
    kalmix_s = median_seconds(lambda: run_core(params, z, backend="numba"), repeats,
                              warmup=lambda: run_core(params, z[:2], backend="numba"))
    result = dict(series=series, steps=steps, state_dim=2,
                  kalmix_series_steps_per_s=series * steps / kalmix_s)
    try:
        import simdkalman
    except ImportError:
        result["simdkalman_series_steps_per_s"] = None
        return result
    kappa = params.feature_scale
    transition, _ = companion_from_theta(params.prior_theta, params.order)
    q = np.diag([params.process_noise[0, 0] / kappa**2, 0.0]) + params.state_jitter * np.eye(2)
    r = params.measurement_noise[0, 0] / kappa**2
    p0 = params.initial_variance[0] / kappa**2 * np.eye(2)
    kf = simdkalman.KalmanFilter(state_transition=transition, process_noise=q,
                                 observation_model=np.array([[1.0, 0.0]]), observation_noise=r)
    # kalmix starts each series at its first measurement (x = 0 in centred units, P0) and
    # predicts; simdkalman is given the same prior for the second measurement.
    data = ((z[1:, :, 0] - z[0, :, 0]) / kappa).T  # (series, steps - 1)
    initial_cov = transition @ p0 @ transition.T + q

    def simd():
        return kf.compute(data, 0, initial_value=np.zeros(2), initial_covariance=initial_cov,
                          smoothed=False, filtered=True, covariances=False, observations=False)

    simd_s = median_seconds(simd, repeats, warmup=lambda: None)
    result["simdkalman_series_steps_per_s"] = series * (steps - 1) / simd_s
    result["ratio_vs_simdkalman"] = result["kalmix_series_steps_per_s"] / result["simdkalman_series_steps_per_s"]
    filtered = simd().filtered.states.mean  # (series, steps - 1, 2): x_{t|t}
    simd_pred = z[0, :, 0][:, None] + kappa * (filtered @ transition.T)[..., 0]
    ours = run_core(params, z, backend="numba").predictions[1:, :, 0].T
    result["max_abs_difference"] = float(np.max(np.abs(simd_pred - ours)))
    result["max_rel_difference"] = float(np.max(np.abs(simd_pred - ours)) / np.max(np.abs(ours)))
    return result


# ----------------------------------------------------------------------------- (d)
def bench_scaling(experts, orders, steps: int, repeats: int) -> dict:
    z = tracks(3, steps, 1, 3)
    by_k = []
    for k in experts:
        params = make_params(3, k)
        seconds = median_seconds(lambda: run_core(params, z, backend="numba"), repeats,
                                 warmup=lambda: run_core(params, z[:2], backend="numba"))
        by_k.append(seconds / steps / k * 1e9)
    by_order = []
    for o in orders:
        params = make_params(3, 40, order=o)
        seconds = median_seconds(lambda: run_core(params, z, backend="numba"), repeats,
                                 warmup=lambda: run_core(params, z[:2], backend="numba"))
        by_order.append(seconds / steps / 40 * 1e9)
    return dict(experts=list(experts), ns_per_expert_step_vs_k=by_k, orders=list(orders),
                state_dims=[3 * o for o in orders], ns_per_expert_step_vs_order=by_order,
                flops_per_expert_step_vs_order=[flops_per_expert_step(3, o) for o in orders])


# ----------------------------------------------------------------------------- all
def run_benchmarks(quick: bool = False, log=print) -> dict:
    """Run (a)-(d); ``quick`` shrinks sizes so that the whole run takes under a minute."""
    from .core.fast import numba_available

    if not numba_available():
        raise ImportError("the benchmarks need numba (the 'fast' extra): pip install 'kalmix[fast]'")
    repeats = 2 if quick else 5
    results = dict(quick=quick, machine=machine_peak())
    log("(a) one stream, K = 40 ...")
    results["single_stream"] = bench_single_stream(steps=1000 if quick else 5000, imm_steps=20 if quick else 100,
                                                   numpy_steps=30 if quick else 200, repeats=repeats)
    log("(b) batch of targets ...")
    targets = [1, 10, 100, 1000, 10000]
    # at least 50 steps in the full run: the first ~10 frames of a track (RLS fits from a
    # handful of samples, many shrunk by the guard) cost more than the steady state
    results["batch"] = bench_batch(targets, budget=2e5 if quick else 4e6, repeats=min(repeats, 3),
                                   min_steps=5 if quick else 50)
    log("(c) plain Kalman filter vs simdkalman ...")
    results["plain_kf"] = (bench_plain_kf(2000, 300, repeats) if quick else bench_plain_kf(10000, 1000, repeats))
    log("(d) scaling with K and state size ...")
    results["scaling"] = bench_scaling([1, 4, 16, 64, 256] if quick else [1, 2, 4, 8, 16, 32, 64, 128, 256],
                                       [1, 2, 3, 4], steps=100 if quick else 400, repeats=repeats)
    results["physical"] = physical_limits(results)
    return results


def physical_limits(results: dict) -> dict:
    machine = results["machine"]
    rls = flops_per_expert_step(3, 2, "rls")
    fixed = flops_per_expert_step(1, 2, "fixed")
    single = results["single_stream"]["kalmix_steps_per_s"] * 40 * rls
    batch = results["batch"]["expert_steps_per_s"][-1] * rls
    plain = results["plain_kf"]["kalmix_series_steps_per_s"] * fixed
    one_core_vector = machine["peak_flops"] / machine["cores"]
    return dict(
        flops_per_expert_step_rls_p3_o2=rls, flops_per_step_plain_kf=fixed,
        single_stream_gflops=single / 1e9, single_stream_fraction_of_one_core_peak=single / one_core_vector,
        single_stream_limit_steps_per_s=one_core_vector / (40 * rls),
        batch_gflops=batch / 1e9, batch_fraction_of_peak=batch / machine["peak_flops"],
        batch_limit_expert_steps_per_s=machine["peak_flops"] / rls,
        plain_kf_gflops=plain / 1e9, plain_kf_fraction_of_peak=plain / machine["peak_flops"],
        plain_kf_limit_series_steps_per_s=machine["peak_flops"] / fixed,
    )


def _fmt(value, digits=3):
    if value is None:
        return "n/a"
    if isinstance(value, float) and (abs(value) >= 1e5 or (value != 0 and abs(value) < 1e-2)):
        return f"{value:.{digits - 1}e}"
    if isinstance(value, float):
        return f"{value:,.{max(0, digits - 1 - int(math.log10(abs(value) + 1e-300)))}f}" if value else "0"
    return f"{value:,}" if isinstance(value, int) else str(value)


def markdown_table(results: dict) -> str:
    a, b, c, d = results["single_stream"], results["batch"], results["plain_kf"], results["scaling"]
    phys, machine = results["physical"], results["machine"]
    lines = ["| figure | kalmix | peer | ratio | target |", "|---|---|---|---|---|"]
    lines.append(f"| (a) one stream, K=40, p=3: steps/s (numba) | {_fmt(a['kalmix_steps_per_s'])} | "
                 f"filterpy IMM(40): {_fmt(a.get('filterpy_imm40_steps_per_s'))} | "
                 f"{_fmt(a.get('ratio_vs_filterpy'))}x | >= 20,000 steps/s |")
    lines.append(f"| (a) same, numpy reference backend | {_fmt(a['kalmix_numpy_steps_per_s'])} | | | |")
    for n, steps, ts, es, mb in zip(b["targets"], b["steps"], b["target_steps_per_s"], b["expert_steps_per_s"],
                                    b["peak_mb_per_target"]):
        target = ">= 5e6 expert-steps/s" if n == 10000 else ""
        lines.append(f"| (b) N={n:,} x K=40 ({steps} steps): target-steps/s; expert-steps/s; peak MB/target | "
                     f"{_fmt(ts)}; {_fmt(es)}; {mb:.3f} | | | {target} |")
    lines.append(f"| (c) plain KF, {c['series']:,} series x {c['steps']:,} steps: series-steps/s | "
                 f"{_fmt(c['kalmix_series_steps_per_s'])} | "
                 f"simdkalman: {_fmt(c.get('simdkalman_series_steps_per_s'))} | "
                 f"{_fmt(c.get('ratio_vs_simdkalman'))}x | >= 1.0x |")
    if "max_rel_difference" in c:
        lines.append(f"| (c) same predictions as simdkalman: max relative difference | "
                     f"{_fmt(c['max_rel_difference'])} | | | |")
    lines.append("| (d) ns per expert-step vs K (" + ", ".join(map(str, d["experts"])) + ") | "
                 + ", ".join(f"{v:.0f}" for v in d["ns_per_expert_step_vs_k"]) + " | | | |")
    lines.append("| (d) ns per expert-step vs state size n (" + ", ".join(map(str, d["state_dims"])) + "), K=40 | "
                 + ", ".join(f"{v:.0f}" for v in d["ns_per_expert_step_vs_order"]) + " | | | |")
    lines.append("")
    lines.append(f"Machine: {machine['cores']} cores at {machine['ghz']:.2f} GHz, {machine['simd_doubles']} doubles "
                 f"per vector; peak {machine['peak_flops'] / 1e9:.0f} GFLOP/s (vector FMA), "
                 f"{machine['scalar_peak_flops'] / 1e9:.0f} GFLOP/s (scalar FMA).")
    lines.append(f"Physical estimate: one expert-step (rls, p=3, n=6) ~ {phys['flops_per_expert_step_rls_p3_o2']:.0f} "
                 f"flops; (a) runs at {phys['single_stream_gflops']:.2f} GFLOP/s = "
                 f"{100 * phys['single_stream_fraction_of_one_core_peak']:.1f}% of one core's peak "
                 f"(limit ~{phys['single_stream_limit_steps_per_s']:,.0f} steps/s); (b) at N=10,000 "
                 f"{phys['batch_gflops']:.2f} GFLOP/s = {100 * phys['batch_fraction_of_peak']:.1f}% of peak "
                 f"(limit ~{phys['batch_limit_expert_steps_per_s']:.2e} expert-steps/s); (c) plain KF "
                 f"~{phys['flops_per_step_plain_kf']:.0f} flops/step, {phys['plain_kf_gflops']:.2f} GFLOP/s = "
                 f"{100 * phys['plain_kf_fraction_of_peak']:.1f}% of peak.")
    return "\n".join(lines)


def plot(results: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b, d = results["batch"], results["scaling"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    ax = axes[0]
    ax.loglog(b["targets"], b["expert_steps_per_s"], "o-", label="kalmix (numba)")
    ax.axhline(5e6, color="grey", ls="--", label="target 5e6")
    ax.set_xlabel("targets N (K = 40)")
    ax.set_ylabel("expert-steps / s")
    ax.set_title("(b) throughput vs number of targets")
    ax.legend()
    ax = axes[1]
    ax.semilogx(d["experts"], d["ns_per_expert_step_vs_k"], "o-", base=2)
    ax.set_xlabel("experts K (one stream)")
    ax.set_ylabel("ns per expert-step")
    ax.set_title("(d) cost per expert vs K")
    ax.set_ylim(bottom=0)
    ax = axes[2]
    ax.plot(d["state_dims"], d["ns_per_expert_step_vs_order"], "o-", label="measured")
    ax2 = ax.twinx()
    ax2.plot(d["state_dims"], d["flops_per_expert_step_vs_order"], "s--", color="C1", label="flop estimate")
    ax.set_xlabel("state size n = order x p (p = 3, K = 40)")
    ax.set_ylabel("ns per expert-step")
    ax2.set_ylabel("flops per expert-step", color="C1")
    ax.set_title("(d) cost vs state size")
    ax.set_ylim(bottom=0)
    ax2.set_ylim(bottom=0)
    fig.tight_layout()
    from .archive import save_figure

    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _json_ready(value):
    if isinstance(value, dict):
        return {key: _json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(item) for item in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def main(quick: bool = False, json_path=None, png_path=None, log=print) -> dict:
    """Run the benchmarks, print the markdown table, write the JSON and the PNG if asked."""
    start = time.perf_counter()
    results = run_benchmarks(quick=quick, log=log)
    results["seconds"] = time.perf_counter() - start
    log(markdown_table(results))
    log(f"\n(total {results['seconds']:.1f} s)")
    if json_path:
        from .archive import replaced_file

        with replaced_file(json_path, "w", what="a JSON file path", output=True) as handle:
            json.dump(_json_ready(results), handle, indent=2)
        log(f"wrote {json_path}")
    if png_path:
        plot(results, png_path)
        log(f"wrote {png_path}")
    return results
