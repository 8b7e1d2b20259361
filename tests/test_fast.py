"""The compiled time loop (numba) gives the numpy reference's numbers; numpy is the fallback."""

import signal

import numpy as np
import pytest

from conftest import smooth_tracks
from kalmix import make_params
from kalmix.core import fast, init_state, run_core, step
from kalmix.core import dynamics as dyn

pytest.importorskip("numba")

from kalmix.core.compiled._warm import kernel_cached as _REAL_KERNEL_CACHED  # noqa: E402 (before any patch)

# a bank narrower than a vector of experts and one wider (the kernel's loops over the experts have a remainder)
SIZES = (6, 9)


def _close(reference, compiled, name):
    """The same bits (NaN in the same places): both engines do the same operations in the same order."""
    reference, compiled = np.asarray(reference), np.asarray(compiled)
    assert reference.shape == compiled.shape, name
    np.testing.assert_array_equal(compiled, reference, err_msg=name)


def _compare(a, b):
    for name in ("predictions", "weights", "eta", "process_noise", "measurement_noise", "expert_predictions"):
        if getattr(a, name) is None:
            assert getattr(b, name) is None, name
        else:
            _close(getattr(a, name), getattr(b, name), name)
    for name, value in a.state._asdict().items():
        _close(value, getattr(b.state, name), f"state.{name}")


def _data(seed, steps=90, targets=3):
    z = smooth_tracks(seed, steps, targets=targets)
    z[0, 1] = np.nan            # a target that starts late
    z[10:14, -1] = np.nan       # a gap
    z[steps // 2, 0, 1] = np.nan  # a partly missing row is missing
    return z


@pytest.mark.parametrize("n_experts", SIZES)
@pytest.mark.parametrize("gating", ["fixed_share", "paper", "random"])
@pytest.mark.parametrize("dynamics", ["rls", "literal", "fixed"])
def test_compiled_loop_equals_the_numpy_reference(dynamics, gating, n_experts):
    z = _data(7)
    params = make_params(3, n_experts, dynamics=dynamics, gating=gating, seed=3)
    options = dict(diagnostics=True, expert_predictions=True)
    _compare(run_core(params, z, backend="numpy", **options), fast.run_fast(params, z, **options))


@pytest.mark.parametrize("n_experts", SIZES)
@pytest.mark.parametrize("dynamics", ["rls", "literal", "fixed"])
def test_without_a_gate_the_experts_are_those_of_a_gated_mixture_and_nothing_is_learned(dynamics, n_experts):
    """``gating="none"`` (a bank's AKF family) skips the gate's work in the kernel and the numpy spec: the
    experts are bit for bit those of a gated mixture without noise feedback, and the weights, the
    responsibilities and the rate stay where they started."""
    z = _data(11)
    z[30, 1] = 1e8               # a jump, to be sure a skipped score changes nothing
    params = make_params(3, n_experts, dynamics=dynamics, gating="none", adapt_noise=False, seed=3)
    gated = make_params(3, n_experts, dynamics=dynamics, gating="fixed_share", adapt_noise=False, seed=3)
    options = dict(diagnostics=True, expert_predictions=True)
    reference = run_core(params, z, backend="numpy", **options)
    _compare(reference, fast.run_fast(params, z, **options))
    start = init_state(params, z.shape[1])
    for name in ("weights", "responsibilities", "eta", "gate_weights"):
        np.testing.assert_array_equal(getattr(reference.state, name), getattr(start, name), err_msg=name)
    np.testing.assert_array_equal(reference.weights, np.broadcast_to(start.weights, reference.weights.shape))
    with_gate = fast.run_fast(gated, z, **options)
    np.testing.assert_array_equal(reference.expert_predictions, with_gate.expert_predictions)
    for name in ("mean", "cov", "gram", "cross", "transition", "offset", "history", "origin"):
        np.testing.assert_array_equal(getattr(reference.state, name), getattr(with_gate.state, name), err_msg=name)
    assert not np.array_equal(reference.weights, with_gate.weights)   # the gated one did learn


def test_no_gate_refuses_the_noise_feedback_it_cannot_drive():
    with pytest.raises(ValueError, match="adapt_noise: .*gating='none' has no gate; pass adapt_noise=False"):
        make_params(3, 4, gating="none")


def test_a_banks_akf_family_runs_without_a_gate():
    from kalmix.bank import make_bank

    (akf,) = [family for family in make_bank(3, "mixed+ar+turn").families if family.kind == "akf"]
    assert akf.params.gating == "none" and not akf.params.adapt_noise


@pytest.mark.parametrize("n_experts", SIZES)
@pytest.mark.parametrize("gating_input", ["bias", "position"])
def test_other_gate_inputs_orders_and_dimensions(gating_input, n_experts):
    z = _data(8, targets=2)[..., :2]
    params = make_params(2, n_experts, gating="paper", gating_input=gating_input, order=3, seed=1,
                         noise_reinflation=0.01)
    _compare(run_core(params, z, backend="numpy"), run_core(params, z, backend="numba"))


@pytest.mark.parametrize("n_experts", SIZES)
def test_horizon_resume_and_serial_and_parallel_agree(n_experts):
    z = _data(9, steps=60, targets=4)
    params = make_params(3, n_experts, seed=2)
    reference = run_core(params, z, horizon=3, backend="numpy", expert_predictions=True)
    _compare(reference, fast.run_fast(params, z, horizon=3, expert_predictions=True, parallel=True))
    _compare(reference, fast.run_fast(params, z, horizon=3, expert_predictions=True, parallel=False))
    first = fast.run_fast(params, z[:25])
    resumed = fast.run_fast(params, z[25:], first.state, horizon=3, expert_predictions=True)
    _close(reference.predictions[25:], resumed.predictions, "resumed predictions")
    _compare(reference._replace(predictions=reference.predictions[25:],
                                expert_predictions=reference.expert_predictions[25:]), resumed)


def test_step_fast_equals_step_and_does_not_mutate_its_input():
    z = _data(10, steps=30)
    params = make_params(3, 4, seed=4)
    state = init_state(params, 3, stream_ids=[5, 6, 7])
    compiled = state
    for t in range(len(z)):
        state, out = step(params, state, z[t])
        compiled, compiled_out = fast.step_fast(params, compiled, z[t])
        _close(out.prediction, compiled_out.prediction, "prediction")
        _close(out.weights, compiled_out.weights, "weights")
    for name, value in state._asdict().items():
        _close(value, getattr(compiled, name), name)
    snapshot = [value.copy() for value in compiled]
    fast.step_fast(params, compiled, z[0])
    for original, value in zip(snapshot, compiled):
        np.testing.assert_array_equal(original, value)


def test_progress_is_reported_in_chunks():
    z = smooth_tracks(3, 600)
    params = make_params(3, 2, seed=0)
    seen = []
    fast.run_fast(params, z, progress=seen.append)
    assert seen == [256, 512, 600]


@pytest.mark.parametrize("n_experts", (4, 12))
def test_guard_shrinks_like_the_eigenvalue_guard(monkeypatch, n_experts):
    """Rough, growing tracks make many fits unstable: the compiled guard must shrink them alike."""
    rng = np.random.default_rng(0)
    z = 300 + np.cumsum(np.cumsum(rng.normal(size=(120, 2, 3)), axis=0), axis=0)
    params = make_params(3, n_experts, seed=6, forgetting_levels=(0.9,), ridge_levels=(1e-2,))
    raw_radius = []
    guard = dyn.guard_theta

    def spy(theta, prior, order, bound):
        raw_radius.append(dyn.spectral_radius(dyn.companion_from_theta(theta, order)[0]).ravel())
        return guard(theta, prior, order, bound)

    monkeypatch.setattr(dyn, "guard_theta", spy)
    reference = run_core(params, z, backend="numpy")
    raw_radius = np.concatenate(raw_radius)
    assert (raw_radius > params.spectral_radius_bound).mean() > 0.2  # the guard is exercised
    assert (dyn.spectral_radius(reference.state.transition) <= params.spectral_radius_bound + 1e-9).all()
    compiled = run_core(params, z, backend="numba")
    # these rough fits are ill-conditioned (cond(S + rho I) ~ 1e7): any rounding difference between the
    # engines would grow here (it reached 1e-9 in the gate when they added in different orders)
    _compare(reference, compiled)


def test_backend_choice_and_numpy_fallback(monkeypatch):
    z = _data(11, steps=20)
    params = make_params(3, 3, seed=0)
    with pytest.raises(ValueError, match="backend"):
        run_core(params, z, backend="cuda")
    calls = []
    monkeypatch.setattr(fast, "run_fast", lambda *args, **kwargs: calls.append(1) or None)
    run_core(params, z, backend="numpy")
    assert calls == []
    run_core(params, z)  # auto, numba present
    assert calls == [1]
    monkeypatch.setattr(fast, "numba_available", lambda: False)
    auto = run_core(params, z)  # falls back to the numpy loop
    _compare(run_core(params, z, backend="numpy"), auto)
    with pytest.raises(ImportError, match="fast"):
        run_core(params, z, backend="numba")


def test_numba_available_is_false_without_numba(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_numba(name, *args, **kwargs):
        if name == "numba" or name.startswith("numba."):
            raise ImportError("no numba")
        return real_import(name, *args, **kwargs)

    fast.numba_available.cache_clear()
    monkeypatch.setattr(builtins, "__import__", no_numba)
    try:
        assert fast.numba_available() is False
    finally:
        fast.numba_available.cache_clear()


@pytest.mark.parametrize("n_experts", SIZES)
def test_variance_cap_after_a_long_gap_matches(n_experts):
    z = smooth_tracks(8, 30)
    params = make_params(3, n_experts, length_unit=50.0, seed=0, dynamics="fixed")
    if not hasattr(params, "max_variance"):
        pytest.skip("this core has no variance cap")
    gap = np.concatenate([z, np.full((4000, 1, 3), np.nan), z])
    reference = run_core(params, gap, backend="numpy")
    capped = run_core(params, gap[:4030], backend="numpy").state.cov
    assert np.diagonal(capped, axis1=-2, axis2=-1).max() == pytest.approx(params.max_variance)  # cap reached
    _compare(reference, run_core(params, gap, backend="numba"))


@pytest.mark.parametrize("n_experts", SIZES)
@pytest.mark.parametrize("p, order, degree", [(4, 2, None), (3, 3, 2), (1, 3, 2), (5, 1, None)])
def test_other_sizes_including_the_eigenvalue_guard(p, order, degree, n_experts):
    """Large clusters of roots at 1 (p (degree + 1) > 6) make the guard use eigenvalues."""
    z = _data(12, steps=60, targets=2)
    z = np.concatenate([z, z[..., :2] + 7.0], axis=-1)[..., :p]
    params = make_params(p, n_experts, order=order, prior_degree=degree, seed=1)
    degree = min(order - 1, 1) if degree is None else degree
    assert fast.fast_guard(params) == (p * (degree + 1) <= 6)
    _compare(run_core(params, z, backend="numpy"), run_core(params, z, backend="numba"))


@pytest.fixture
def cold_cache(monkeypatch):
    """compile_ahead as on a fresh install with two cores (the cache declared empty), once more in this process."""
    from kalmix.core.compiled import _warm

    monkeypatch.setattr(_warm, "kernel_cached", lambda dispatcher: False)
    monkeypatch.setattr(_warm, "_cores", lambda: 2)
    monkeypatch.delenv("KALMIX_BACKGROUND_COMPILE", raising=False)
    done = _warm._done
    _warm._reset()
    yield _warm
    _warm._done = done


def test_compile_ahead_runs_the_akf_kernel_in_a_child_and_changes_no_number(cold_cache):
    """On a fresh cache the engine's first run starts a child process for the AKF and turn kernels, compiles the
    bank's other kernels meanwhile and waits. Here the kernels are cached already (the child only loads them) and
    the cache is declared empty: the child must exit 0, only once per process, and the numbers stay."""
    from kalmix.bank import make_bank
    from kalmix.core.compiled import akf, engine, turn
    from kalmix.core.testing import benign_tracks

    bank = make_bank(2, "mixed+ar+turn", n_akf=8, length_unit=0.3)
    z, t = benign_tracks(seed=1)
    before = engine.run(bank, z, t)
    assert _REAL_KERNEL_CACHED(akf.kernel) and _REAL_KERNEL_CACHED(turn.kernel)   # the run above cached them
    compiled = {kernel: len(kernel._cache._cache_file._load_index()) for kernel in (akf.kernel, turn.kernel)}
    cold_cache._reset()   # that run (under the fixture) took this process's turn
    assert cold_cache.compile_ahead(bank, engine.run) == 0
    assert cold_cache.compile_ahead(bank, engine.run) is None   # once per process
    after = engine.run(bank, z, t)
    for name in ("forecasts", "std"):
        assert np.array_equal(getattr(before, name), getattr(after, name), equal_nan=True), name
    # the child called each kernel with the engine's argument types: it loaded them, and compiled nothing new
    assert {kernel: len(kernel._cache._cache_file._load_index()) for kernel in compiled} == compiled


def test_compile_ahead_only_when_it_helps(monkeypatch, cold_cache):
    """A child for the AKF and coordinated-turn kernels (one per kind); none without such a family, for a bank of
    them alone (nothing to overlap), on one core, or when switched off."""
    from kalmix.bank import DEFAULT_BANK, make_bank

    _warm = cold_cache
    mixed = make_bank(2, "mixed", n_akf=8)
    assert _warm._eligible(mixed) == (next(f for f in mixed.families if f.kind == "akf"),)
    default = make_bank(2, **DEFAULT_BANK)
    assert [f.kind for f in _warm._eligible(default)] == ["turn", "akf"]
    assert _warm._eligible(make_bank(2, "kinematic")) == ()
    assert _warm._eligible(make_bank(2, "akf", n_akf=8)) == ()
    assert _warm._eligible(make_bank(2, "turn")) == ()
    monkeypatch.setenv("KALMIX_BACKGROUND_COMPILE", "0")
    assert _warm._eligible(mixed) == ()
    monkeypatch.delenv("KALMIX_BACKGROUND_COMPILE")
    monkeypatch.setattr(_warm, "_cores", lambda: 1)
    assert _warm._eligible(mixed) == ()


def test_read_only_inputs_compile_no_second_kernel():
    """A read-only time column (a broadcast) and a writable one reach the kernels with one type."""
    from kalmix.bank import make_bank
    from kalmix.core.compiled import engine
    from kalmix.core.compiled import kinematic
    from kalmix.core.testing import benign_tracks

    bank = make_bank(2, "kinematic", length_unit=0.3)
    z, t = benign_tracks(seed=1)
    engine.run(bank, z, t)
    count = len(kinematic.kernel.signatures)
    readonly = np.broadcast_to(t[:, :1], t.shape)
    zr = z.copy()
    zr.flags.writeable = False
    engine.run(bank, zr, readonly, ahead_times=readonly + 1.0)
    engine.run(bank, z, np.array(t), ahead_times=t + 1.0)
    assert len(kinematic.kernel.signatures) == count


def test_a_failing_warm_up_does_not_break_the_run(monkeypatch, cold_cache):
    """The tiny run is only a warm-up: if it raises, compile_ahead still waits for its child and returns."""
    from kalmix.bank import make_bank
    from kalmix.core.compiled import engine

    def broken(bank, run):
        raise RuntimeError("warm-up failed")

    monkeypatch.setattr(cold_cache, "_tiny_run", broken)
    assert cold_cache.compile_ahead(make_bank(2, "mixed", n_akf=8, length_unit=0.3), engine.run) == 0


def test_a_compile_child_still_running_at_exit_is_ended():
    """A process that exits while a compile child runs (a warm-up thread dies with it) ends the child: no
    orphan compiling for a minute after the command returned (predict - with an empty stdin)."""
    import subprocess
    import sys

    from kalmix.core.compiled import _warm

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    _warm._children.add(child)
    try:
        _warm._end_children()
        assert child.wait(timeout=10) != 0
    finally:
        _warm._children.discard(child)
        if child.poll() is None:
            child.kill()


def test_an_interrupted_warm_up_ends_its_child_at_once(monkeypatch, cold_cache):
    """Ctrl-C during a fresh install's compile stops the command now: compile_ahead kills its child instead
    of waiting for it (the wait took up to ~25 s, the child's whole compile)."""
    import subprocess
    import sys

    from kalmix.bank import make_bank
    from kalmix.core.compiled import engine

    children = []
    popen = subprocess.Popen

    def slow_child(args, **kwargs):   # a child that would still compile for a minute
        child = popen([sys.executable, "-c", "import sys, time; sys.stdin.buffer.read(); time.sleep(60)"],
                                 **kwargs)
        children.append(child)
        return child

    def interrupted(bank, run):
        raise KeyboardInterrupt

    monkeypatch.setattr(cold_cache.subprocess, "Popen", slow_child)
    monkeypatch.setattr(cold_cache, "_tiny_run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        cold_cache.compile_ahead(make_bank(2, "mixed", n_akf=8, length_unit=0.3), engine.run)
    assert children[0].returncode == -signal.SIGKILL   # killed and reaped, not waited for
    assert not cold_cache._children


def test_experts_of_one_fit_share_it_only_while_their_statistics_are_the_same():
    """The experts-last kernel fits once for experts of the same forgetting and ridge whose RLS statistics
    are the same bits (40 experts have 12 fits); a state where two of them differ (here, a hand-made one)
    fits them apart, and both engines agree on every expert."""
    z = _data(13, steps=120, targets=2)
    params = make_params(3, 40, seed=4, adapt_noise=False)   # experts independent (as in a bank)
    pairs = list(zip(params.forgetting.tolist(), params.ridge.tolist()))
    k = next(i for i in range(1, 40) if pairs[i] in pairs[:i])   # an expert with an earlier twin
    twin = pairs.index(pairs[k])
    first = run_core(params, z[:60], backend="numpy").state
    assert np.array_equal(first.gram[:, k], first.gram[:, twin])   # twins stay equal
    assert len(set(pairs)) == 12
    for name in ("gram", "cross"):   # the ridge enters the solution only
        assert len({tuple(getattr(first, name)[0, i].ravel()) for i in range(40)}) == len(set(params.forgetting))
    parted = first._replace(gram=first.gram.copy(), cross=first.cross.copy())
    parted.gram[:, k] *= 3.0
    parted.cross[:, k] *= 0.5
    options = dict(expert_predictions=True, horizon=2)
    reference = run_core(params, z[60:], parted, backend="numpy", **options)
    _compare(reference, run_core(params, z[60:], parted, backend="numba", **options))
    together = run_core(params, z[60:], first, backend="numba", **options)
    moved = np.abs(reference.expert_predictions[:, :, k] - together.expert_predictions[:, :, k]).max()
    assert moved > 1e-3 * np.abs(together.expert_predictions[:, :, k]).max()   # the parted twin went its own way
    resumed = run_core(params, z[60:], parted, backend="numba", **options)
    np.testing.assert_array_equal(together.expert_predictions[:, :, twin], resumed.expert_predictions[:, :, twin])


def _same_bytes(a, b, name):
    """Bit for bit including the sign of zeros (np.array_equal takes -0.0 == 0.0)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.tobytes() == b.tobytes(), name


@pytest.mark.parametrize("n_experts", SIZES)
def test_a_guard_on_the_bound_decides_alike(n_experts):
    """With a bound of 1 the prior's roots at 1 put candidates on the bound at every fit: both engines take
    the eigenvalues of the complex companion and the modulus as sqrt(re^2 + im^2), so they shrink alike
    (numpy's real solver, or numba's abs of a complex number, round the radius to another last bit)."""
    z = np.cumsum(np.random.default_rng(2).normal(0, 1, (80, 2, 1)), axis=0)
    params = make_params(1, n_experts, order=2, adapt_noise=False, spectral_radius_bound=1.0, seed=1)
    _compare(run_core(params, z, backend="numpy"), run_core(params, z, backend="numba"))


@pytest.mark.parametrize("n_experts", SIZES)
def test_hand_made_states_with_nan_run_alike(n_experts):
    """A NaN variance (the variance cap skips it, as the kernels' max does), a NaN gate weight (the dominant
    expert is found by the kernels' scan) and a NaN RLS statistic (no exception in the spec's guard)."""
    rng = np.random.default_rng(0)
    z = np.cumsum(rng.normal(size=(30, 1, 2)), axis=0)
    params = make_params(2, n_experts, seed=1, adapt_noise=False)
    state = run_core(params, z, backend="numpy").state
    later = np.concatenate([np.full((2, 1, 2), np.nan), z[-1] + np.cumsum(rng.normal(size=(6, 1, 2)), axis=0)])
    cov, weights, gram = state.cov.copy(), state.weights.copy(), state.gram.copy()
    cov[0, 3, 1, 1] = np.nan
    weights[0, 2] = np.nan
    gram[0, 1, 0, 0] = np.nan
    for broken in (state._replace(cov=cov), state._replace(weights=weights), state._replace(gram=gram)):
        options = dict(expert_predictions=True, diagnostics=True)
        _compare(run_core(params, later, broken, backend="numpy", **options),
                 run_core(params, later, broken, backend="numba", **options))


def test_signs_of_zero_are_the_kernels_too():
    """Sums start from 0.0 as the kernels' loops do, and twins whose statistics differ only in the sign of a
    zero keep their own fits: the same bytes, not only equal values."""
    params = make_params(5, 9, dynamics="literal", gating="random", order=2, adapt_noise=True, seed=1338)
    z = np.cumsum(np.random.default_rng(1338).normal(0, 1, (80, 3, 5)), axis=0) * 5e-324 * 3   # subnormal
    _same_bytes(run_core(params, z, backend="numpy").predictions, run_core(params, z, backend="numba").predictions,
                "predictions")
    params = make_params(2, 12, seed=1, adapt_noise=False)
    state = run_core(params, np.cumsum(np.random.default_rng(0).normal(size=(30, 1, 2)), axis=0),
                     backend="numpy").state
    lam, rho = params.forgetting, params.ridge
    twin = next(k for k in range(1, 12) if lam[k] == lam[0] and rho[k] == rho[0])
    gram, cross = state.gram.copy(), state.cross.copy()
    gram[0, twin], cross[0, twin] = gram[0, 0], cross[0, 0]
    gram[0, 0, 0, 1], gram[0, twin, 0, 1] = 0.0, -0.0
    state = state._replace(gram=gram, cross=cross)
    missing = np.full((2, 1, 2), np.nan)
    _same_bytes(run_core(params, missing, state, backend="numpy").state.gram,
                run_core(params, missing, state, backend="numba").state.gram, "gram")
