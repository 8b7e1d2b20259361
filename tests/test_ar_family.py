"""The AR family (kalmix.core.families.ar): what it learns, relocations, both engines, resume, checks."""

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings, strategies as st

from kalmix.bank import make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.core.families import ar
from kalmix.core.testing import adversarial_tracks
from kalmix.streaming import StreamConfig, TrackPredictor


def _ar_bank(**kwargs):
    return make_bank(2, "ar", length_unit=0.1, **{"ar_orders": (2,), "ar_forgetting": (0.95,), "ar_ridge": (1e-3,),
                                                     "ar_options": {"jump_threshold": float("inf")}, **kwargs})


def test_an_order_2_expert_learns_an_ar2_velocity():
    """Velocity v_t = a1 v_{t-1} + a2 v_{t-2} (a slowly damped oscillation), irregular steps: once
    learned, the one-step forecast is exact up to the prior's pull (ridge 1e-3 of 20 samples' weight); the
    forgetting drops the first sample, whose regressor has a zero for the velocity before the track.

    (Without the jump test: on noise-free data the running error shrinks to rounding, and then
    any change is a "jump".)"""
    rng = np.random.default_rng(0)
    t_count = 200
    v = np.zeros((t_count, 2))
    v[0], v[1] = (1.0, -0.5), (0.8, 0.2)
    for i in range(2, t_count):
        v[i] = 2 * 0.99 * np.cos(0.3) * v[i - 1] - 0.99**2 * v[i - 2]
    steps = rng.uniform(0.5, 1.5, t_count)
    times = np.cumsum(steps)
    z = np.cumsum(v * steps[:, None] * 0.1, axis=0)       # positions in length units of 0.1
    result = engine.run(_ar_bank(), z[:, None], times[:, None], record_experts=True)
    err = np.abs(result.experts[:, 0, 0] - z)
    scale = np.abs(np.diff(z, axis=0)).max()
    assert err[150:].max() < 1e-3 * scale and err[1:10].max() > 1e-2 * scale


def test_a_relocation_moves_the_track_without_extrapolating_the_jump():
    """A jump of 200 units in one row (under the glitch screen's threshold): the AR expert's next
    forecast keeps the old velocity, the CV Kalman filter's extrapolates the jump."""
    t_count = 120
    times = np.arange(t_count, dtype=float)
    z = np.column_stack([times * 0.5, np.zeros(t_count)]) + np.random.default_rng(1).normal(0, 0.1, (t_count, 2))
    z[60:, 0] += 20.0
    ar_bank = make_bank(2, "ar", length_unit=0.1, outlier_threshold=np.inf)
    kin_bank = make_bank(2, "kinematic", length_unit=0.1, outlier_threshold=np.inf)
    ar_next = np.abs(ce.run(ar_bank, z[:, None], times[:, None]).forecasts[61, 0] - z[61])
    kin_next = np.abs(ce.run(kin_bank, z[:, None], times[:, None]).forecasts[61, 0] - z[61])
    assert ar_next.max() < 1.0 and kin_next.max() > 5.0


@pytest.mark.parametrize("rule", ["boa", "mlpoly", "fixed_share"])
def test_spec_and_compiled_agree_with_bias_and_ahead_times(rule):
    z, t = adversarial_tracks(seed=3, t_count=240)
    bank = make_bank(2, "kinematic+ar", rule=rule, length_unit=0.3, ar_orders=(1, 3),
                     ar_options={"bias": True})
    ahead = t + 2.5
    reference = engine.run(bank, z, t, ahead_times=ahead)
    compiled = ce.run(bank, z, t, ahead_times=ahead)
    assert np.isfinite(compiled.forecasts[1:]).all() and np.isfinite(compiled.ahead).all()
    np.testing.assert_array_equal(compiled.forecasts, reference.forecasts)
    np.testing.assert_array_equal(compiled.ahead, reference.ahead)


def test_without_a_jump_test_a_zero_running_error_flags_no_jump():
    """jump_threshold = inf turns the jump test off, even where the running error is exactly 0
    (a long stretch of exact input: inf x 0 was NaN, and the next change of velocity was taken
    for a jump and not fitted). Both engines."""
    bank = _ar_bank()
    times = np.arange(6, dtype=float)[:, None]
    z = np.column_stack([np.arange(6.0) * 0.1, np.zeros(6)])[:, None]
    z[5, 0, 0] += 0.3                                             # a change of velocity on the last row
    for run in (engine.run, ce.run):
        head = run(bank, z[:5], times[:5])
        family = head.state.families[0]
        quiet = head.state._replace(families=(family._replace(error=np.zeros_like(family.error)),))
        last = run(bank, z[5:], times[5:], quiet).state.families[0]
        assert last.jumps[0, 0] == 0                               # not a jump ...
        assert last.history[0, 0, 0, 0] == pytest.approx(4.0)      # ... the velocity (0.4 / 0.1) is learned
        assert last.error[0, 0] > 0


@settings(max_examples=4)
@given(seed=st.integers(0, 2**16), p=st.integers(1, 3))
def test_ar_family_property_both_engines_on_adversarial_tracks(seed, p):
    """Any seed and dimension: experts and mixture equal on both engines, every forecast finite."""
    z, t = adversarial_tracks(seed=seed, t_count=240, p=p)
    bank = make_bank(p, "ar", length_unit=0.3)
    reference = engine.run(bank, z, t, record_experts=True)
    compiled = ce.run(bank, z, t, record_experts=True)
    assert np.isfinite(reference.forecasts[1:]).all() and np.isfinite(compiled.forecasts[1:]).all()
    np.testing.assert_array_equal(compiled.experts, reference.experts)
    np.testing.assert_array_equal(compiled.forecasts, reference.forecasts)


@pytest.mark.parametrize("rule", ["boa", "mlpoly"])
def test_mixture_of_the_ar_experts_is_the_same_on_both_engines(rule):
    """At a track's third row every AR expert forecasts the same velocity: their weights must then be
    equal bit for bit (a zero regressor keeps the prior exactly), since the scale-free rules are chaotic
    on experts that equal the mixture to rounding (a regret of ~1e-17 in one engine, 0 in the other)."""
    for p, seed in ((1, 0), (2, 1)):
        z, t = adversarial_tracks(seed=seed, t_count=240, p=p)
        bank = make_bank(p, "ar", rule=rule, length_unit=0.3)
        np.testing.assert_array_equal(ce.run(bank, z, t).forecasts, engine.run(bank, z, t).forecasts)


def _hand_state(params, weights, history, position=(1.0, -2.0)):
    state = ar.init_state(params, 1, 2)
    return state._replace(weights=np.broadcast_to(weights, state.weights.shape).copy(),
                          history=np.broadcast_to(history, state.history.shape).copy(),
                          position=np.array([position]), last_time=np.array([0.0]), initialised=np.array([True]))


def test_a_forecast_iterates_the_fitted_recursion_once_per_row_ahead():
    """Delta < 1.5 time units: the next row, position + v1 * delta * u (as a one-step forecast always was).
    Further: n = round(delta) rows of delta / n, each predicted velocity fed back into the regressor."""
    params = _ar_bank().families[0].params                       # order 2, length unit 0.1
    w, history = np.array([[0.5, 0.25], [1.0, -0.5]]), np.array([[2.0, 4.0], [1.0, 2.0]])
    state = _hand_state(params, w, history)

    def by_hand(delta):
        rows = max(1, int(np.floor(delta + 0.5)))
        step, h, position = delta / rows * 0.1, history.copy(), np.array([1.0, -2.0])
        for _ in range(rows):
            v = (w * h).sum(axis=1)
            position = position + v * step
            h = np.column_stack([v, h[:, 0]])
        return position

    for delta in (0.0, 0.4, 1.0, 1.49, 1.5, 2.4, 3.0, 7.7):
        means, _ = ar.forecast(params, state, np.array([delta]))
        np.testing.assert_allclose(means[0, 0], by_hand(delta), rtol=1e-12, atol=1e-15)
    # one row ahead: exactly the straight line of the first velocity
    means, _ = ar.forecast(params, state, np.array([1.2]))
    np.testing.assert_array_equal(means[0, 0], np.array([1.0, -2.0]) + np.array([2.0, 0.0]) * (1.2 * 0.1))


def test_an_unstable_fit_cannot_explode_over_a_long_lead():
    """w = (3, 0): the recursion triples the velocity each row. Iterated velocities are clipped to the largest of
    v1 and the regressor's velocities, so 64 rows ahead the forecast moves at most 64 x that speed."""
    params = _ar_bank().families[0].params
    state = _hand_state(params, np.array([[3.0, 0.0], [3.0, 0.0]]), np.array([[1.0, 0.5], [-1.0, 2.0]]))
    means, _ = ar.forecast(params, state, np.array([64.0]))
    # v1 = 3 (coordinate 0), -3 (coordinate 1): then clipped to 3 in magnitude, 64 rows of 0.1
    np.testing.assert_allclose(means[0, 0], np.array([1.0, -2.0]) + np.array([3.0, -3.0]) * 64 * 0.1, rtol=1e-12)
    far, _ = ar.forecast(params, state, np.array([1e5]))        # more than ITERATED_STEPS rows: 64 longer steps
    np.testing.assert_allclose(far[0, 0], np.array([1.0, -2.0]) + np.array([3.0, -3.0]) * 1e5 * 0.1, rtol=1e-12)


@pytest.mark.parametrize("history", [[2.0, 1.0], [2.0, np.nan], [np.nan, 1e9]])
def test_the_kernels_forecast_equals_the_specs_on_a_hand_made_state(history):
    """The compiled per-expert forecast against the spec on one state, a NaN in the history included (the
    engines never store one, a hand-made or loaded state might): bit for bit at every lead."""
    from kalmix.core.compiled import ar as compiled_ar

    params = _ar_bank().families[0].params
    state = _hand_state(params, np.array([[0.5, 0.25], [1.2, -0.5]]), np.array([history, [1.0, -1.0]]))
    for delta in (0.7, 1.5, 3.0, 70.0):
        spec, _ = ar.forecast(params, state, np.array([delta]))
        out = np.empty(2)
        compiled_ar._forecast(params.order, params.bias, params.size, delta, params.length_unit, params.max_velocity,
                              state.weights[0, 0], state.history[0, 0], state.position[0], out, np.empty(2),
                              np.empty(2))
        np.testing.assert_array_equal(out, spec[0, 0])


def test_iterated_forecasts_are_the_same_on_both_engines_at_any_lead():
    """Leads across the rounding edges (1.5, 2.5 rows), long ones and beyond ITERATED_STEPS rows, with a
    bias, on adversarial tracks (gaps, jumps, constant stretches): compiled == spec."""
    from kalmix.core.compiled import ar as compiled_ar

    assert compiled_ar.ITERATED_STEPS == ar.ITERATED_STEPS
    z, t = adversarial_tracks(seed=5, t_count=200)
    bank = make_bank(2, "ar", length_unit=0.3, ar_orders=(1, 2, 5), ar_options={"bias": True})
    for lead in (1.49, 1.5, 2.5, 9.3, 500.0):
        ahead = t + lead
        reference = engine.run(bank, z, t, ahead_times=ahead, record_experts=True)
        compiled = ce.run(bank, z, t, ahead_times=ahead, record_experts=True)
        assert np.isfinite(compiled.ahead[np.isfinite(z).all(axis=-1)]).all()
        np.testing.assert_array_equal(compiled.ahead, reference.ahead)
        np.testing.assert_array_equal(compiled.experts, reference.experts)


def test_forecast_variance_is_the_running_velocity_error_over_the_step():
    bank = _ar_bank()
    params = bank.families[0].params
    state = ar.init_state(params, 1, 2)
    for i, point in enumerate(([0.0, 0.0], [1.0, 0.0], [2.5, 0.5])):
        state = ar.update(params, state, np.array([point]), np.array([float(i)]), np.array([True]))
    _, variance = ar.forecast(params, state, np.array([4.0]))
    np.testing.assert_allclose(variance, state.error * (2.0 * 0.1) ** 2)


def test_track_predictor_with_the_ar_family_resumes_bit_for_bit(tmp_path):
    rng = np.random.default_rng(2)
    rows = [(track, i * 0.1, *xy) for track in ("a", "b")
            for i, xy in enumerate(np.cumsum(rng.normal(0, 0.1, (60, 2)), axis=0))]
    table = pd.DataFrame(rows, columns=["track_id", "time", "x", "y"]).sort_values("time", kind="stable")
    config = StreamConfig(length_unit=0.1, bank="kinematic+ar")
    whole = TrackPredictor(config).process_table(table)
    first = TrackPredictor(config)
    later = table.iloc[50:].groupby("track_id")["time"].first().to_dict()   # where each track goes on
    head = first.process_table(table.iloc[:50], next_times=later)
    first.save(tmp_path / "state.npz")
    tail = TrackPredictor.load(tmp_path / "state.npz").process_table(table.iloc[50:])
    resumed = pd.concat([head, tail], ignore_index=True)
    np.testing.assert_array_equal(resumed[["pred_x", "pred_y"]].to_numpy(), whole[["pred_x", "pred_y"]].to_numpy())


@pytest.mark.parametrize("kwargs, match", [
    ({"ar_forgetting": (0.9, 1.5)}, "ar_forgetting"),
    ({"ar_ridge": (0.0,)}, "ar_ridge"),
    ({"ar_orders": (1.5,)}, "ar_orders"),
    ({"ar_orders": ()}, "ar_orders"),
    ({"ar_options": {"lag": 3}}, "ar_options"),
    ({"ar_options": {"window": 0.5}}, "window"),
    ({"ar_options": {"jump_threshold": float("nan")}}, "jump_threshold"),
])
def test_bad_ar_arguments_are_refused_by_name(kwargs, match):
    with pytest.raises((ValueError, TypeError), match=match):
        make_bank(2, "ar", **kwargs)


def test_gpu_engine_takes_the_ar_family_on_its_staged_path():
    from kalmix.core.compiled import gpu

    bank = make_bank(2, "kinematic+ar")
    gpu.check_bank(bank)
    assert not gpu.fused(bank)
