"""Every family and every rule passes the contract of kalmix.core.testing, on benign and adversarial input."""

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from kalmix.bank import BANK_KINDS, make_bank
from kalmix.core import aggregators
from kalmix.core.testing import adversarial_tracks, benign_tracks, check_bank

RULES = list(aggregators.RULES)


def _bank(kind, rule, p=2, unit=0.3):
    # a small AKF family keeps the reference runs quick; 8 experts use the vectorised kernel
    return make_bank(p, kind, rule=rule, length_unit=unit, n_akf=8 if kind != "akf" else 9)


def _pairs(kinds, rule_kinds, blend=True):
    """Every bank kind with the default rule, and every rule with ``rule_kinds``: a rule sees only the experts'
    forecasts and which are awake, whatever their family, so the whole cross product (27 benign cases, 18
    adversarial; ~55 s of the suite) checked each rule again on banks that differ only in their families."""
    default = RULES[0]
    # BOA-blend runs BOA's row functions twice: one benign bank kind (the last) checks it here, adversarial input
    # with the lead head and gap restarts (test_contract_with_a_lead_head_and_gap_restarts)
    return [(kind, default) for kind in kinds] + [(kind, rule) for kind in rule_kinds for rule in RULES[1:]
                                                  if rule != "boa_blend" or (blend and kind == rule_kinds[-1])]


@pytest.mark.parametrize("kind, rule", _pairs(BANK_KINDS, ["kinematic", "mixed+ar+turn"]))
def test_contract_benign(kind, rule):
    z, t = benign_tracks(seed=1)
    check_bank(_bank(kind, rule), z, t)


@pytest.mark.parametrize("kind, rule", _pairs(["kinematic", "akf", "ar", "turn", "kinematic+ar+turn"],
                                              ["akf", "kinematic+ar+turn"], blend=False))
def test_contract_adversarial(kind, rule):
    """Jumps of 1e8, a 200-row gap, constant input, values of 1e200: finite, and compiled == reference.

    (The mixed bank: tests/test_glitches.py.)"""
    z, t = adversarial_tracks(seed=2)
    check_bank(_bank(kind, rule), z, t)


def _assert_identical(one, other):
    """Two engine results have the same bits in every output and every state leaf (shapes included)."""
    from kalmix.core.engine import tree_leaves

    for name in one._fields:
        a, b = getattr(one, name), getattr(other, name)
        if name == "state":
            leaves = dict(tree_leaves(b))
            assert [key for key, _ in tree_leaves(a)] == list(leaves), "the state leaves differ by name or count"
            for key, x in tree_leaves(a):
                assert np.array_equal(x, leaves[key], equal_nan=True), key
        elif a is None:
            assert b is None, name
        else:
            assert np.array_equal(a, b, equal_nan=True), name


def _gaps(shape, seed):
    """Gap restarts at 4 % of the rows, half of them on missing rows."""
    rng = np.random.default_rng(seed)
    return rng.random(shape) < 0.04, rng.random(shape) < 0.5


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("data", ["benign", "adversarial"])
def test_contract_with_a_lead_head_and_gap_restarts(data, rule):
    """The lead head (delayed feedback) and gap restarts (warm starts) keep the contract, outputs and all."""
    z, t = benign_tracks(seed=3) if data == "benign" else adversarial_tracks(seed=4, t_count=150)
    restart, blank = _gaps(z.shape[:2], 5)
    z = np.where((restart & blank)[..., None], np.nan, z)
    bank = make_bank(2, "mixed", rule=rule, length_unit=0.3, n_akf=8, lead=3.0)
    check_bank(bank, z, t, restart=restart)
    if rule == "boa_blend":   # (BOA's row functions, twice: the other banks check them with "boa")
        return
    check_bank(_bank("kinematic", rule), z, t, restart=restart)
    check_bank(make_bank(2, "kinematic+ar", rule=rule, length_unit=0.3, lead=2.0), z, t, restart=restart)


def _without_the_last_leaf(tree):
    """``tree`` (a state) with its last array replaced by None, so that it has one leaf fewer."""
    parts = list(tree)
    last = max(i for i, part in enumerate(parts) if part is not None)
    parts[last] = _without_the_last_leaf(parts[last]) if isinstance(parts[last], tuple) else None
    return type(tree)(*parts) if hasattr(tree, "_fields") else tuple(parts)


@pytest.mark.parametrize("drop", ["lead output", "trailing state leaf"])
def test_check_bank_fails_on_a_compiled_run_that_drops_an_output_or_a_state_leaf(monkeypatch, drop):
    """The contract compares outputs and state leaves by name and count: an engine that left one out (the lead
    forecasts, the state's last array) fails it, where comparing the pairs that both sides have would not."""
    from kalmix.core.compiled import engine as ce
    from kalmix.core.engine import tree_leaves

    run = ce.run

    def dropping(*args, **kwargs):
        result = run(*args, **kwargs)
        if not kwargs.get("record_experts"):   # the whole run, the one compared with the reference
            return result
        if drop == "lead output":
            return result._replace(lead=None)
        state = _without_the_last_leaf(result.state)
        assert len(tree_leaves(state)) == len(tree_leaves(result.state)) - 1
        return result._replace(state=state)

    bank = make_bank(2, "kinematic+ar", length_unit=0.3, lead=2.0)
    z, t = benign_tracks(seed=0, t_count=30, n=2)
    check_bank(bank, z, t)      # the engine as it is passes
    monkeypatch.setattr(ce, "run", dropping)
    with pytest.raises(AssertionError, match="on one side only"):
        check_bank(bank, z, t)


def test_the_lead_calibration_learns_the_miss_of_the_interval_it_issued():
    """Delayed feedback: a lead forecast is scored against the interval issued with it, not today's.

    The measurement is outside the narrow interval issued (std 0.1) and inside today's (std ~1):
    the scale must grow by rate x (1 - 0.05). An old pending forecast without its interval (NaN,
    a version-5 state file) falls back to today's, a cover: the scale shrinks by rate x 0.05.
    The compiled head gives the same numbers."""
    from kalmix.core import engine, lead
    from kalmix.core.compiled import engine as compiled

    bank = make_bank(2, "kinematic", length_unit=1.0, lead=1.0)
    rate = bank.calibration_params.rate
    for interval, expected in ((0.1, rate * 0.95), (np.nan, -rate * 0.05)):
        state = engine.init_bank_state(bank, 1)
        head = state.lead
        due, pending, issued = head.due.copy(), head.pending.copy(), head.issued.copy()
        due[0, 0], pending[0, 0], issued[0, 0, 0], issued[0, 0, 1] = 1.0, 0.0, 0.0, interval
        head = head._replace(due=due, pending=pending, issued=issued)
        learned = lead.learn(bank, head, np.array([[0.5, 0.5]]), np.array([1.0]), np.array([True]))
        np.testing.assert_allclose(learned.calibration.log_scale, [expected], rtol=1e-12)
        assert np.isnan(learned.issued).all() and np.isnan(learned.due).all()   # scored, then dropped
        # the compiled head, through a one-row run at that time (a target's first row keeps no forecast)
        z, t = np.array([[[0.5, 0.5]]]), np.array([[1.0]])
        reference = engine.run(bank, z, t, state._replace(lead=head))
        fast = compiled.run(bank, z, t, state._replace(lead=head))
        np.testing.assert_allclose(fast.state.lead.calibration.log_scale, [expected], rtol=1e-12)
        np.testing.assert_allclose(reference.state.lead.calibration.log_scale, [expected], rtol=1e-12)


def test_fixed_scale_fixed_share_is_the_previous_rule():
    """fixed_share with a fixed scale is exponential weighting at rate 1/(2 sigma^2): check one step by hand."""
    from kalmix.core.aggregators import fixed_share

    params = fixed_share.Params(share=0.1, scale=2.0)
    state = fixed_share.init(params, 1, 3)
    experts = np.array([[[0.0, 0.0], [1.0, 0.0], [4.0, 0.0]]])
    z = np.array([[1.0, 0.0]])
    awake = np.ones((1, 3), bool)
    new = fixed_share.update(params, state, experts, z, awake, np.array([True]))
    loss = np.array([1.0, 0.0, 9.0]) / (2 * 4.0)
    scored = np.exp(-loss) / np.exp(-loss).sum()
    np.testing.assert_allclose(fixed_share.weights(params, new, awake)[0], 0.9 * scored + 0.1 / 3, rtol=1e-12)


def test_boa_competes_with_the_best_convex_combination():
    """Experts y+1, y, y-2 and y+noise: BOA's mixture becomes exact and the noisy expert's weight vanishes.

    (Here 0.124 (y+1) + 0.813 y + 0.062 (y-2) is exact too: BOA need not be one-hot.)"""
    from kalmix.core.aggregators import boa

    rng = np.random.default_rng(0)
    params, state = boa.Params(), boa.init(boa.Params(), 1, 4)
    awake = np.ones((1, 4), bool)
    for _ in range(400):
        y = rng.normal(size=(1, 2))
        experts = np.stack([y + 1.0, y, y - 2.0, y + rng.normal(size=(1, 2))], axis=1)
        state = boa.update(params, state, experts, y, awake, np.array([True]))
    w = boa.weights(params, state, awake)[0]
    mixture = np.einsum("k,kp->p", w, experts[0])
    assert np.abs(mixture - y[0]).max() < 1e-2 and w[3] < 0.01 and w[1] == w.max()


def test_boa_delay_divides_the_second_order_rate_and_the_lead_head_takes_its_rows():
    """BOA with delay D: eta_k = min(1 / (2 B_k), sqrt(ln K / (D V_k))) (the range bound unchanged). A bank's lead
    head of H rows learns with D = H (make_bank), its one-step rule with D = 1. (Compiled = reference with a
    delayed lead head: test_contract_with_a_lead_head_and_gap_restarts.)"""
    from kalmix.core import engine
    from kalmix.core.aggregators import boa

    state = boa.State(np.zeros((1, 3)), np.array([[4.0, 0.01, 0.0]]), np.array([[0.1, 0.1, 0.1]]), np.zeros(1),
                      np.zeros(1))
    for delay in (1.0, 4.0):
        eta = boa.learning_rates(state, 3, delay)[0]
        expected = np.minimum(1 / (2 * 0.1), np.sqrt(np.log(3) / (delay * np.array([4.0, 0.01]))))
        np.testing.assert_array_equal(eta[:2], expected)
        assert eta[2] == eta[:2].max()   # an uninformed expert takes the largest informed rate
    assert boa.learning_rates(state, 3, 4.0)[0, 0] == boa.learning_rates(state, 3)[0, 0] / 2
    assert boa.learning_rates(state, 3, 4.0)[0, 1] == 5.0   # capped by 1 / (2 B): no delay there

    z, t = benign_tracks(seed=1)
    bank = make_bank(2, "kinematic", length_unit=0.3, lead=4.0)
    assert bank.lead.frames == 4 and bank.lead_rule_params.delay == 4.0 and bank.rule_params.delay == 1.0
    one = make_bank(2, "kinematic", length_unit=0.3, lead=4.0, lead_delay=1.0)
    assert one.lead_rule_params.delay == 1.0
    delayed, plain = engine.run(bank, z, t), engine.run(one, z, t)
    assert np.array_equal(delayed.forecasts, plain.forecasts, equal_nan=True)   # the one-step rule is the same
    assert np.array_equal(delayed.state.rule.regret, plain.state.rule.regret)
    assert not np.allclose(delayed.lead, plain.lead, equal_nan=True)   # the lead head's is not


def test_boa_clip_shrinks_the_error_its_regrets_learn_from_not_its_range_bound():
    """One BOA step by hand, ``clip`` 3, after 10 rows of squared error norm 1 (s = 1): an error of norm 10 is
    shrunk to 3 in the regrets and their variance; the range bound takes the whole regret; so does the scale. An
    error within 3 s, and any error during the warm-up or with ``clip`` off, is taken whole."""
    from kalmix.core.aggregators import boa

    experts = np.array([[[0.0, 0.0], [2.0, 0.0]]])
    awake, learn = np.ones((1, 2), bool), np.array([True])
    params = boa.Params(clip=3.0)
    state = boa.init(params, 1, 2)._replace(error_scale=np.array([1.0]), error_count=np.array([10.0]))
    mix = boa.weights(params, state, awake)[0] @ experts[0]           # uniform: (1, 0)
    for y, factor in ((np.array([[-9.0, 0.0]]), 0.3), (np.array([[-1.0, 0.0]]), 1.0)):
        whole = 2 * ((mix - y[0]) * (mix - experts[0])).sum(axis=-1)  # (2,): the linearised regrets
        shrunk = factor * whole
        new = boa.update(params, state, experts, y, awake, learn)
        eta = np.minimum(1 / (2 * np.abs(whole)), np.sqrt(np.log(2) / shrunk ** 2))
        np.testing.assert_array_equal(new.regret[0], shrunk - eta * shrunk ** 2)
        np.testing.assert_array_equal(new.variance[0], shrunk ** 2)
        np.testing.assert_array_equal(new.bound[0], np.abs(whole))
        np.testing.assert_array_equal(new.error_scale, [1.0 + (((mix - y[0]) ** 2).sum() - 1.0) / 11])
        assert new.error_count[0] == 11
    # the warm-up (9 rows) and clip off take the error whole
    big = np.array([[-9.0, 0.0]])
    whole = 2 * ((mix - big[0]) * (mix - experts[0])).sum(axis=-1)
    young = boa.update(params, state._replace(error_count=np.array([9.0])), experts, big, awake, learn)
    off = boa.update(boa.Params(), state, experts, big, awake, learn)
    for new in (young, off):
        np.testing.assert_array_equal(new.variance[0], whole ** 2)
    assert off.error_count[0] == 10 and off.error_scale[0] == 1.0   # clip off keeps no scale


def test_boa_clip_keeps_a_kick_from_moving_the_weights():
    """Two experts, the truth and a biased one (+0.5), measured with unit noise; one kick (a measurement 100 off,
    the biased expert a little closer) at row 100. Unclipped, the kick's regret moves a tenth of the weight to
    the biased expert for the next hundred rows; with ``clip`` 3 the weights stay where they were."""
    from kalmix.core.aggregators import boa

    rng = np.random.default_rng(0)
    truth = rng.normal(size=(300, 1, 1)).cumsum(axis=0)
    experts = np.concatenate([truth, truth + 0.5], axis=1)[:, None]        # (T, N=1, K=2, p=1)
    y = truth[:, :, 0] + rng.normal(size=(300, 1))
    y[100] += 100.0
    awake, learn = np.ones((1, 2), bool), np.array([True])
    lowest = {}
    for clip in (np.inf, 3.0):
        params = boa.Params(bound_forgetting=0.99, clip=clip)
        state, on_truth = boa.init(params, 1, 2), []
        for t in range(300):
            on_truth.append(boa.weights(params, state, awake)[0, 0])
            state = boa.update(params, state, experts[t], y[t], awake, learn)
        assert on_truth[99] > 0.96   # before the kick, either way
        lowest[clip] = min(on_truth[101:201])
    assert lowest[np.inf] < 0.92 and lowest[3.0] > 0.96, lowest


def test_the_lead_head_learns_its_errors_whole():
    """The one-step rule clips (the default, 3), the lead head's does not: its weights are those of a bank with
    ``clip`` off, bit for bit, while the one-step forecasts differ (and so do the lead forecasts, which blend the
    lead weights' forecast with the one-step weights')."""
    from kalmix.core import engine

    z, t = benign_tracks(seed=1)
    z[40, 0] += 50.0   # a surprise, which the one-step rule clips
    clipped = make_bank(2, "kinematic+ar", length_unit=0.3, lead=3.0)
    whole = make_bank(2, "kinematic+ar", length_unit=0.3, lead=3.0, rule_options={"clip": np.inf})
    assert clipped.rule_params.clip == 3.0 and clipped.lead_rule_params.clip == np.inf
    one, other = engine.run(clipped, z, t), engine.run(whole, z, t)
    assert np.abs(one.state.lead.rule.regret).max() > 0
    for mine, theirs in zip(one.state.lead.rule, other.state.lead.rule):
        assert np.array_equal(mine, theirs)
    assert not np.array_equal(one.forecasts, other.forecasts, equal_nan=True)


def test_boa_clip_follows_a_change_of_motion_after_any_quiet_stretch():
    """Two experts after a quiet stretch (errors ~0.5 mm): the target starts moving 3 m a row and only B follows.
    Unclipped, B has 0.9 of the weight within 11 rows; with ``clip`` 3 within 18, after 1,000 quiet rows or after
    200,000: the scale's memory (CLIP_MEMORY) keeps a long quiet stream from hiding the change (with a plain mean
    over all rows it took 31 rows after 10,000 and 71 after 200,000)."""
    from kalmix.core.aggregators import boa

    awake, learn = np.ones((1, 2), bool), np.array([True])
    follow = {}
    for quiet in (1_000, 200_000):
        for clip in (np.inf, 3.0):
            rng = np.random.default_rng(0)
            params = boa.Params(bound_forgetting=0.99, clip=clip)
            state = boa.init(params, 1, 2)
            state = state._replace(error_scale=np.array([2.5e-7]), error_count=np.array([float(quiet)]))
            for _ in range(50):   # the end of the quiet stretch: A (0.5 mm off) a little better than B (1 mm)
                y = rng.normal(0, 5e-4, (1, 1))
                state = boa.update(params, state, np.array([[[y[0, 0] + 5e-4], [y[0, 0] + 1e-3]]]), y, awake, learn)
            assert state.error_count[0] <= boa.CLIP_MEMORY or clip == np.inf
            for row in range(1, 200):   # A stays, B follows the target to within 1 cm
                state = boa.update(params, state, np.array([[[3.0], [rng.normal(0, 0.01)]]]), np.zeros((1, 1)),
                                   awake, learn)
                if boa.weights(params, state, awake)[0, 1] > 0.9:
                    break
            follow[quiet, clip] = row
    assert follow[1_000, np.inf] == follow[200_000, np.inf] == 11
    assert follow[1_000, 3.0] == follow[200_000, 3.0] <= 18, follow


def test_a_restart_starts_boas_error_scale_again_and_keeps_its_weights():
    """At a restart row (a time gap: the experts start again) BOA's error scale starts again, as the warm-up
    of the clip; its regrets and bounds go on (the row itself is not learned). Where no row restarts, nothing
    changes. (Compiled = reference across restarts: test_contract_with_a_lead_head_and_gap_restarts.)"""
    from kalmix.core import engine

    z, t = benign_tracks(seed=1)
    bank = make_bank(2, "kinematic", length_unit=0.3)
    before = engine.run(bank, z[:30], t[:30]).state
    assert (before.rule.error_count >= 20).all() and (before.rule.error_scale > 0).all()
    restart = np.zeros((1, z.shape[1]), dtype=bool)
    restart[0, 0] = True
    after = engine.run(bank, z[30:31], t[30:31], before, restart=restart).state.rule
    present = np.isfinite(z[30]).all(axis=-1)
    assert after.error_count[0] == 0.0 and after.error_scale[0] == 0.0
    np.testing.assert_array_equal(after.error_count[1:], before.rule.error_count[1:] + present[1:])
    np.testing.assert_array_equal(after.regret[0], before.rule.regret[0])
    np.testing.assert_array_equal(after.bound[0], before.rule.bound[0])


def test_boa_clip_in_a_bank_passes_the_contract():
    """``clip`` off (the original rule) and ``clip`` 1 (most rows shrunk) keep the contract, compiled = reference
    bit for bit, on benign and adversarial input (the default, 3, runs in every other contract test)."""
    for z, t in (benign_tracks(seed=1), adversarial_tracks(seed=2, t_count=200)):
        for clip in (np.inf, 1.0):
            check_bank(make_bank(2, "kinematic+ar", length_unit=0.3, lead=2.0, rule_options={"clip": clip}), z, t)


@pytest.mark.parametrize("clip, error", [(0.0, ValueError), (-1.0, ValueError), (float("nan"), ValueError),
                                         ("3", TypeError), (True, TypeError)])
def test_a_bad_clip_is_refused_by_name(clip, error):
    with pytest.raises(error, match=r"rule_options\['clip'\]: expected a number > 0"):
        make_bank(2, "kinematic", length_unit=0.3, rule_options={"clip": clip})


@pytest.mark.parametrize("options, error", [
    (dict(lead=3.0, lead_delay=0.5), ValueError), (dict(lead_delay=0.99), ValueError),
    (dict(lead=3.0, lead_delay=float("inf")), ValueError), (dict(lead=3.0, lead_delay=True), TypeError),
    (dict(rule_options={"delay": 0.5}), ValueError), (dict(rule="mlpoly", rule_options={"delay": 2.0}), ValueError)])
def test_a_delay_below_one_row_is_refused(options, error):
    """A delay counts rows between a forecast and its score: below 1 (or not a number) is refused, naming it."""
    with pytest.raises(error, match="delay"):
        make_bank(2, "kinematic", **options)


def test_rules_are_scale_free():
    """BOA and ML-Poly give the same weights when the data are multiplied by 1e6."""
    z, t = benign_tracks(seed=3)
    from kalmix.core import engine

    for rule in ("boa", "mlpoly"):
        small = engine.run(make_bank(2, "kinematic", rule=rule, length_unit=0.3), z, t, record_experts=True)
        big = engine.run(make_bank(2, "kinematic", rule=rule, length_unit=0.3e6), z * 1e6, t, record_experts=True)
        np.testing.assert_allclose(big.weights, small.weights, rtol=1e-6, atol=1e-9)


def test_kinematic_family_equals_filterpy():
    """One CV expert with irregular time steps equals filterpy's KalmanFilter to 1e-10."""
    filterpy = pytest.importorskip("filterpy.kalman")
    from kalmix.core.families import kinematic

    rng = np.random.default_rng(4)
    times = np.cumsum(rng.uniform(0.2, 2.0, 60))
    z = np.cumsum(rng.normal(size=(60, 1)), axis=0)
    params = kinematic.KinematicParams(2, np.array([0.7]), np.array([0.3]), np.array([[0.3, 1e4]]), time_unit=0.5)
    state = kinematic.init_state(params, 1, 1)
    kf = filterpy.KalmanFilter(dim_x=2, dim_z=1)
    kf.x = np.array([[z[0, 0]], [0.0]])
    kf.P = np.diag([0.3, 1e4])
    kf.H = np.array([[1.0, 0.0]])
    kf.R = np.array([[0.3]])
    state = kinematic.update(params, state, z[:1], times[:1], np.array([True]))
    for i in range(1, 60):
        d = (times[i] - times[i - 1]) / 0.5
        kf.F = kinematic.transition(2, np.array(d))
        kf.Q = 0.7 * kinematic.process_noise(2, np.array(d))
        kf.predict()
        mean, _ = kinematic.forecast(params, state, times[i:i + 1])
        assert abs(mean[0, 0, 0] - kf.x[0, 0]) <= 1e-10 * max(1.0, abs(kf.x[0, 0]))
        kf.update(z[i:i + 1, :].T)
        state = kinematic.update(params, state, z[i:i + 1], times[i:i + 1], np.array([True]))
        np.testing.assert_allclose(state.mean[0, 0, :, 0], kf.x[:, 0], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(state.cov[0, 0], kf.P, rtol=1e-10, atol=1e-10)


def test_compiled_cache_is_keyed_on_the_sources(tmp_path, monkeypatch):
    """Editing any compiled source changes the cache directory, so a warm cache never serves stale code."""
    from kalmix.core.compiled import _cache

    before = _cache.source_hash()
    monkeypatch.setattr(_cache, "_CORE", tmp_path)
    for name in _cache.COMPILED_SOURCES:
        target = tmp_path / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes((_cache.Path(__file__).resolve().parents[1] / "src/kalmix/core" / name).read_bytes())
    assert _cache.source_hash() == before
    rules = tmp_path / "compiled/rules.py"
    rules.write_text(rules.read_text() + "\n# edited\n")
    assert _cache.source_hash() != before


def test_an_unusable_cache_directory_falls_back_to_a_keyed_temporary_one(tmp_path, monkeypatch):
    """KALMIX_CACHE_DIR naming a file left numba's default, the sources' __pycache__ (not keyed on the
    constants the kernels import), silently; the comment said 'compiling without a cache'."""
    import tempfile

    import numba

    from kalmix.core.compiled import _cache

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    (tmp_path / "tmp").mkdir()
    monkeypatch.setenv("KALMIX_CACHE_DIR", str(blocker))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)
    with pytest.warns(RuntimeWarning, match="cannot use the compiled-kernel cache .*a-file.*Not a directory"):
        path = _cache.configure_cache.__wrapped__()
    assert path.parent.parent == tmp_path / "tmp" and path.name == f"numba-{_cache.source_hash()}" and path.is_dir()
    assert numba.config.CACHE_DIR == str(path)
    # a fallback parent another user could write to (its pickled index could hand us code) is not used
    path.rmdir()
    path.parent.chmod(0o777)
    with pytest.warns(RuntimeWarning, match="cannot use the compiled-kernel cache"):
        other = _cache.configure_cache.__wrapped__()
    assert other.parent == tmp_path / "tmp" and other.name.startswith("kalmix-numba-") and not path.exists()


def test_two_copies_of_the_same_sources_share_one_cache(tmp_path):
    """The same kalmix in two places (an installed package and its checkout, two clones) compiles once: numba keyed
    a kernel's cache on its file's absolute directory, so the test suite's zoo runs (the checkout's ``src``) compiled
    every kernel the installed package had compiled again. An edited copy still compiles anew."""
    import shutil
    import subprocess

    import kalmix

    package = Path(kalmix.__file__).resolve().parent
    copies = [tmp_path / "one", tmp_path / "two"]
    for copy in copies:
        shutil.copytree(package, copy / "kalmix", ignore=shutil.ignore_patterns("__pycache__"))
    script = ("import numpy as np; from kalmix.core._numba_linalg import cholesky_lower as f; "
              "a = np.eye(2)[:, :, None] * np.ones(3); f(a, 2, np.zeros_like(a), np.zeros(3), False); "
              "print(sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values()), f.stats.cache_path)")

    def run(copy):
        env = dict(os.environ, PYTHONPATH=str(copy), KALMIX_CACHE_DIR=str(tmp_path / "cache"))
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=600)
        assert done.returncode == 0, done.stderr
        hits, misses, path = done.stdout.split()
        return int(hits), int(misses), path

    first, second = run(copies[0]), run(copies[1])
    assert first[:2] == (0, 1) and second[:2] == (1, 0) and first[2] == second[2]   # compiled once, loaded once
    linalg = copies[1] / "kalmix/core/_numba_linalg.py"
    linalg.write_text(linalg.read_text() + "\n# edited\n")
    assert run(copies[1])[:2] == (0, 1)   # a new cache directory (the sources' hash), compiled again


def test_every_module_a_compiled_source_imports_from_is_in_the_cache_key():
    """A constant a kernel imports is frozen into the compiled code, so its file must key the cache too: an edit to
    ``screen.ZERO`` or ``families/kinematic.RESTART_NIS`` left a warm cache running the old value."""
    import ast

    from kalmix.core.compiled import _cache

    core = _cache._CORE
    for name in _cache.KERNEL_SOURCES:
        path = core / name
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom) or not node.level:
                continue
            base = path.parent
            for _ in range(node.level - 1):
                base = base.parent
            parts = (node.module or "").split(".") if node.module else []
            targets = [base.joinpath(*parts)] if parts else [base / alias.name for alias in node.names]
            for target in targets:
                module = target.with_suffix(".py") if not target.is_dir() else None
                if module is None:   # a package: the names imported are its modules
                    modules = [target / f"{alias.name}.py" for alias in node.names]
                else:
                    modules = [module]
                for found in modules:
                    if found.is_file():
                        relative = found.relative_to(core).as_posix()
                        assert relative in _cache.COMPILED_SOURCES, f"{name} imports from {relative}"


@pytest.mark.parametrize("scored", [False, True])
@pytest.mark.parametrize("size", [3, 5])
def test_target_groups_equal_one_pass(monkeypatch, scored, size):
    """Targets run in groups (smaller groups to keep the threads busy) give the same bits as one pass: outputs,
    sums and state; also when the rows run in several blocks (the sums are added block by block, so every
    group runs the blocks of one pass: a review found them 1e-15 apart when the groups ran bigger blocks)."""
    from kalmix.core.compiled import engine as ce

    z, t = adversarial_tracks(seed=6, t_count=120)
    z = np.concatenate([z, benign_tracks(seed=7)[0][:120]], axis=1)
    t = np.concatenate([t, benign_tracks(seed=7)[1][:120]], axis=1)
    n = z.shape[1]
    restart, blank = _gaps(z.shape[:2], 8)
    z = np.where((restart & blank)[..., None], np.nan, z)
    bank = make_bank(2, "mixed+ar", length_unit=0.3, n_akf=8, lead=2.0)
    lengths = np.arange(n) % 5 + 116
    score = np.random.default_rng(9).random(z.shape[:2]) < 0.7 if scored else None
    kwargs = dict(lengths=lengths - 60, restart=restart[60:], record_covariance=True, record_experts=True,
                  score=None if score is None else score[60:], score_ahead=None if score is None else score[60:])
    first = ce.run(bank, z[:60], t[:60], lengths=np.minimum(lengths, 60), restart=restart[:60])
    monkeypatch.setattr(ce, "BUFFER_BYTES", 7 * n * bank.n_experts * 2 * 8 * 2)   # blocks of 7 rows in one pass
    monkeypatch.setattr(ce, "group_size", lambda n_targets, largest: None)
    whole = ce.run(bank, z[60:], t[60:], first.state, **kwargs)
    monkeypatch.setattr(ce, "group_size", lambda n_targets, largest: size if n_targets > size else None)
    grouped = ce.run(bank, z[60:], t[60:], first.state, **kwargs)
    assert n > size
    _assert_identical(whole, grouped)


@pytest.mark.parametrize("scored", [False, True])
def test_more_targets_than_a_group_in_groups_of_any_size(monkeypatch, scored):
    """More than TARGET_GROUP targets always run in groups; their sizes (on one thread: TARGET_GROUP; on four:
    smaller) do not change a bit, sums included, with the rows in several blocks."""
    from kalmix.core.compiled import _threads
    from kalmix.core.compiled import engine as ce

    z, t = adversarial_tracks(seed=6, t_count=50)
    z = np.concatenate([z + 0.1 * i for i in range(10)], axis=1)   # 40 targets
    t = np.concatenate([t] * 10, axis=1)
    bank = make_bank(2, "mixed+ar", length_unit=0.3, n_akf=8)
    score = np.random.default_rng(9).random(z.shape[:2]) < 0.7 if scored else None
    monkeypatch.setattr(ce, "TARGET_GROUP", 8)
    monkeypatch.setattr(ce, "BUFFER_BYTES", 4 * 8 * bank.n_experts * 2 * 8 * 2)   # blocks of 4 rows
    monkeypatch.setattr(_threads, "MIN_CHUNK", 2)
    results, sizes = [], []
    for threads in (1, 4):
        monkeypatch.setattr(_threads, "_threads", lambda: threads)
        sizes.append(_threads.group_size(40, 8))
        results.append(ce.run(bank, z, t, ahead_times=t + 1.0, record_experts=True, score=score,
                              score_ahead=score))
    assert sizes == [8, 5]
    _assert_identical(*results)


def _threads_group_size(n_targets, largest):
    from kalmix.core.compiled._threads import group_size

    return group_size(n_targets, largest)


def test_group_size(monkeypatch):
    """Groups of the largest size beyond it; else about two groups a thread, none on one thread, for too few
    targets, or inside a group."""
    from kalmix.core.compiled import _threads

    monkeypatch.setattr(_threads, "_threads", lambda: 2)
    assert _threads.group_size(10_000, 256) == 250     # 40 groups
    assert _threads.group_size(300, 256) == 75
    assert _threads.group_size(100, 256) == 25
    assert _threads.group_size(40, 256) == 20
    assert _threads.group_size(31, 256) is None
    monkeypatch.setattr(_threads._local, "inline", True, raising=False)
    assert _threads.group_size(100, 256) is None and _threads.group_size(300, 256) == 150
    monkeypatch.setattr(_threads._local, "inline", False)
    monkeypatch.setattr(_threads, "_threads", lambda: 1)
    assert _threads.group_size(100, 256) is None and _threads.group_size(257, 256) == 129


def test_target_ranges_cover_every_target_once(monkeypatch):
    """over_targets hands out disjoint ranges that cover [0, n), on several threads, and re-raises errors."""
    import threading
    import time

    from kalmix.core.compiled import _threads

    monkeypatch.setattr(_threads, "_threads", lambda: 3)
    seen, names = [], set()

    def kernel(lo, hi, out):
        seen.append((lo, hi))
        names.add(threading.current_thread().name)
        out[lo:hi] += 1
        time.sleep(0.01)   # a kernel releases the GIL: the other threads take ranges meanwhile

    out = np.zeros(1000)
    _threads.over_targets(kernel, 1000, out)
    assert np.all(out == 1) and len(seen) == 12 and len(names) > 1
    seen.clear()
    _threads.over_targets(kernel, 2 * _threads.MIN_CHUNK - 1, out[:31])   # few targets: one call, this thread
    assert seen == [(0, 2 * _threads.MIN_CHUNK - 1)]

    def broken(lo, hi):
        if lo > 0:
            raise ValueError("range failed")

    with pytest.raises(ValueError, match="range failed"):
        _threads.over_targets(broken, 1000)


def test_groups_run_in_order_on_at_most_numba_threads(monkeypatch):
    """over_groups returns results in the groups' order, runs at most numba's thread count at once, and a
    group's kernels stay on its thread (over_targets inside runs one call)."""
    import threading
    import time

    from kalmix.core.compiled import _threads

    monkeypatch.setattr(_threads, "_threads", lambda: 3)
    running, peak, lock, calls = [0], [0], threading.Lock(), []

    def group(g):
        with lock:
            running[0] += 1
            peak[0] = max(peak[0], running[0])
        _threads.over_targets(lambda lo, hi: calls.append((lo, hi)), 1000)
        time.sleep(0.01)
        with lock:
            running[0] -= 1
        return g * g

    assert _threads.over_groups(group, range(10)) == [g * g for g in range(10)]
    assert 1 < peak[0] <= 3 and sorted(calls) == [(0, 1000)] * 10


@pytest.mark.parametrize("threads", [1, 3])
def test_targets_on_threads_equal_one_thread(monkeypatch, threads):
    """The compiled engine over targets split across threads gives the bits of one thread (every family,
    the rule, the lead head, the screen; adversarial and benign targets)."""
    from kalmix.core.compiled import _threads
    from kalmix.core.compiled import engine as ce

    z, t = adversarial_tracks(seed=6, t_count=120)
    z = np.concatenate([z, benign_tracks(seed=7)[0][:120]], axis=1)
    t = np.concatenate([t, benign_tracks(seed=7)[1][:120]], axis=1)
    bank = make_bank(2, "mixed+ar", length_unit=0.3, n_akf=8, lead=2.0)
    lengths = np.arange(z.shape[1]) % 5 + 116
    monkeypatch.setattr(_threads, "_threads", lambda: 1)
    one = ce.run(bank, z, t, lengths=lengths, record_experts=True, record_covariance=True)
    monkeypatch.setattr(_threads, "_threads", lambda: threads)
    monkeypatch.setattr(_threads, "MIN_CHUNK", 1)                  # 7 targets: ranges of 1-2 targets
    split = ce.run(bank, z, t, lengths=lengths, record_experts=True, record_covariance=True)
    _assert_identical(one, split)


def test_families_side_by_side_equal_one_after_another(monkeypatch):
    """Few targets: the families run side by side on the threads; the same bits as one after another,
    on adversarial input with gaps and a lead head (the families write disjoint columns)."""
    from kalmix.core.compiled import engine as ce

    z, t = adversarial_tracks(seed=11, t_count=150)
    restart, blank = _gaps(z.shape[:2], 12)
    z = np.where((restart & blank)[..., None], np.nan, z)
    bank = make_bank(2, "mixed+ar+turn", length_unit=0.3, n_akf=8, lead=2.0)
    calls = []
    real = ce.over_groups
    monkeypatch.setattr(ce, "over_groups", lambda function, groups: calls.append(len(groups)) or real(function, groups))
    monkeypatch.setattr(ce, "families_in_parallel", lambda n: True)
    side = ce.run(bank, z, t, restart=restart, record_experts=True, record_covariance=True)
    assert calls and calls[0] == len(bank.families)
    monkeypatch.setattr(ce, "families_in_parallel", lambda n: False)
    serial = ce.run(bank, z, t, restart=restart, record_experts=True, record_covariance=True)
    _assert_identical(side, serial)


def test_both_engines_check_learn_ahead_and_lengths_alike():
    """A ``learn`` or ``ahead_times`` that does not broadcast to (T, N), ``ahead_frames`` < 1 and fractional
    lengths are refused by name by both engines (the reference ran some, the compiled engine failed with a raw
    broadcast error or took a (N,) mask for every row, and they disagreed); a (N,) mask is every row's in both."""
    from kalmix.core import engine
    from kalmix.core.compiled import engine as compiled

    bank = make_bank(2, "kinematic", length_unit=0.3)
    z = np.random.default_rng(0).normal(size=(10, 3, 2))
    t = np.arange(10.0)[:, None].repeat(3, 1)
    for kwargs, message in ((dict(learn=np.ones(10, bool)), r"learn: expected shape \(T, N\) = \(10, 3\)"),
                            (dict(ahead_times=np.arange(10.0)), r"ahead_times: expected shape \(T, N\)"),
                            (dict(ahead_frames=0), "ahead_frames: expected an integer >= 1"),
                            (dict(lengths=[5.5, 3, 2]), "lengths: expected whole numbers of rows")):
        for run in (engine.run, compiled.run):
            with pytest.raises(ValueError, match=message):
                run(bank, z, t, **kwargs)
    mask = np.array([True, False, True])
    assert np.array_equal(engine.run(bank, z, t, learn=mask).forecasts, compiled.run(bank, z, t, learn=mask).forecasts,
                          equal_nan=True)


def test_make_bank_names_what_it_cannot_take():
    """Settings that were taken silently (a length unit outside the range every family stays finite in, for
    banks without the AKF family; a NaN or negative fixed-share scale, read as 0; a negative scale factor; a seed
    or AKF size of any type when the bank has no AKF family) or refused without their name."""
    for kwargs, kind, message in (
            (dict(kind="kinematic", length_unit=1e-200), ValueError, r"length_unit: expected a number in \[1e-60"),
            (dict(length_unit=1e300), ValueError, "length_unit: expected a number in"),
            (dict(rule="fixed_share", rule_options={"scale": float("nan")}), ValueError, r"rule_options\['scale'\]"),
            (dict(rule="fixed_share", rule_options={"scale_factor": -1}), ValueError, "scale_factor"),
            (dict(outlier_threshold="x"), TypeError, "outlier_threshold: expected a number > 1"),
            (dict(level="x"), TypeError, r"level: expected a probability in \(0, 1\), got str"),
            (dict(kind="kinematic", seed="x"), TypeError, "seed: expected an integer >= 0"),
            (dict(kind="kinematic", n_akf=0), ValueError, "n_akf: expected an integer >= 1")):
        with pytest.raises(kind, match=message):
            make_bank(2, **kwargs)


def test_bit_for_bit_at_the_edges_a_review_found():
    """Cases where the engines disagreed: 8 coordinates (the screen's distance summed in pairs in the spec), a
    turn at an infinite angle (the spec's sin raised where the kernel gives NaN), fixed share whose running sum
    of losses overflows (the kernel stored inf where the spec skipped the row)."""
    from kalmix.core import engine
    from kalmix.core.compiled import engine as compiled
    from kalmix.core.engine import tree_leaves

    def same(bank, z, t):
        a, b = engine.run(bank, z, t, record_experts=True), compiled.run(bank, z, t, record_experts=True)
        for name in ("forecasts", "std", "experts", "weights"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
        for (key, x), (_, y) in zip(tree_leaves(a.state), tree_leaves(b.state)):
            assert np.array_equal(x, y, equal_nan=True), key

    rng = np.random.default_rng(1)
    z = np.cumsum(rng.normal(0, 1, (60, 3, 8)), 0) * 1.37 + rng.normal(0, 0.3, (60, 3, 8))
    same(make_bank(8, "kinematic", outlier_threshold=3.0), z, np.cumsum(rng.uniform(0.5, 1.5, (60, 3)), 0))
    angle = np.linspace(0, 3 * np.pi, 6)
    same(make_bank(2, "turn", time_unit=1e308), np.stack([np.cos(angle), np.sin(angle)], -1)[:, None, :] * 10,
         np.arange(6.0)[:, None])
    z = (np.random.default_rng(0).normal(0, 1, 40).cumsum() * 6e153)[:, None, None]
    same(make_bank(1, "kinematic", rule="fixed_share", outlier_threshold=np.inf), z, np.arange(40.0)[:, None])


def test_signs_of_zero_and_a_guard_on_the_bound_in_banks():
    """Subnormal and -0.0 input give the same bytes in both engines (sums from 0.0 as the kernels add), and an
    AKF bank whose guard bound is 1 (candidates on the bound at every fit) passes the contract."""
    from kalmix.core import engine
    from kalmix.core.compiled import engine as ce

    bank = make_bank(1, "kinematic", rule="mlpoly", lead=2.0)
    z = np.array([-1.5e-323, -0.0, 5e-324, 1e-323, -5e-324, 0.0])[:, None, None]
    t = np.arange(6.0)[:, None]
    a, b = engine.run(bank, z, t), ce.run(bank, z, t)
    for name in ("forecasts", "lead"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    check_bank(make_bank(2, "akf", n_akf=9, akf_options={"spectral_radius_bound": 1.0}), *benign_tracks(0))


@pytest.mark.parametrize("lead", [None, 2.0])
def test_zero_targets_in_both_engines(lead):
    """A batch of no targets is empty results of the right shapes in both engines, not an error (the spec's
    AKF regressor could not reshape an empty history)."""
    from kalmix.core import engine
    from kalmix.core.compiled import engine as ce

    bank = make_bank(2, "mixed+ar+turn", length_unit=0.3, n_akf=4, lead=lead)
    z, t = np.zeros((5, 0, 2)), np.zeros((5, 0))
    ahead = None if lead else t + 1.0
    for run in (engine.run, ce.run):
        result = run(bank, z, t, ahead_times=ahead, record_experts=True, record_covariance=True)
        assert result.forecasts.shape == result.std.shape == result.ahead.shape == (5, 0, 2)
        assert result.experts.shape == (5, 0, bank.n_experts, 2) and result.covariance.shape == (5, 0, 2, 2)
        assert result.state.screen.outliers.shape[0] == 0


@pytest.mark.parametrize("kind, order", [("cv", 1), ("cv", 3), ("ca", 2), ("ca", 4)])
def test_a_kinematic_family_of_another_order_is_refused(kind, order):
    """The compiled kinematic kernels are built for CV of order 2 and CA of order 3 (a hand-made family of
    order 1 crashed the process, one of order 4 returned numbers where the spec raised IndexError)."""
    from kalmix.core.engine import Family
    from kalmix.core.families.kinematic import KinematicParams

    params = KinematicParams(order=order, process_noise=np.ones(2), measurement_noise=np.ones(2),
                             initial_variance=np.ones((2, order)), time_unit=1.0)
    with pytest.raises(ValueError, match=f"a '{kind}' family has order .*; got order {order}"):
        Family(kind, params)


def _drifting(t_count=600, seed=3):
    """Targets that cross the AKF family's feature limit (100 feature units of 100 length units; the unit is 0.3
    here, so every 3,000) by moving on (its dynamics translated) and by jumping (started again), with a gap on
    the way."""
    rng = np.random.default_rng(seed)
    z = np.cumsum(rng.normal(0, 0.05, (t_count, 3, 2)), axis=0)
    z[:, 0] += np.arange(t_count)[:, None] * np.array([21.0, -13.0])   # ~8 crossings
    z[:, 1, 1] += 17.0 * np.arange(t_count)
    z[300:310, 1] = np.nan
    z[200:, 2] += 4_500.0          # a jump of 150 feature units: started again
    z[400:, 2] += 40_000.0         # of 1,300: started again
    return z, np.broadcast_to(np.arange(t_count, dtype=float)[:, None], (t_count, 3)).copy()


@pytest.mark.parametrize("kind, rule", [("akf", "boa"), ("mixed+ar+turn", "boa"), ("akf", "fixed_share")])
def test_contract_across_re_anchors(kind, rule):
    """A target far from its AKF origin moves the origin (mixture.reanchor); the RLS statistics, history and
    drift are now translated there, not reset: the contract holds across it, compiled == reference bit for bit
    (the experts-last kernel, 8-9 experts, here; the scalar one in tests/test_mixture.py)."""
    z, t = _drifting()
    check_bank(_bank(kind, rule), z, t)
