"""The coordinated-turn Kalman family: it follows a circle and a straight line, its further coordinates are a CV
filter, the compiled kernel computes the reference's bits (adversarial input included), and its grid is checked."""

import numpy as np
import pandas as pd
import pytest

from kalmix.bank import make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.core.families import ct
from kalmix.core.testing import check_bank
from kalmix.streaming import StreamConfig, TrackPredictor


def _experts(z, t, compiled=True, **options):
    bank = make_bank(z.shape[-1], "ct", length_unit=0.1, **options)
    run = ce.run if compiled else engine.run
    return run(bank, z[:, None, :], t[:, None], record_experts=True).experts[:, 0]   # (T, K, p)


@pytest.mark.parametrize("compiled", [False, True])
def test_a_straight_line_at_uneven_steps_is_forecast_exactly_from_the_third_row(compiled):
    t = np.array([0.0, 1.0, 2.5, 3.0, 4.5, 6.0, 6.2, 9.0])
    line = np.column_stack([2.0 * t - 1.0, -0.5 * t, 0.25 * t + 3.0])      # 3-D: the third coordinate is CV
    experts = _experts(line, t, compiled)
    np.testing.assert_allclose(experts[2:], np.broadcast_to(line[2:, None, :], experts[2:].shape), atol=1e-9)
    np.testing.assert_array_equal(experts[1], np.broadcast_to(line[0], experts[1].shape))   # one row: hold it
    assert np.isnan(experts[0]).all()                                                        # none yet: asleep


def test_it_learns_the_turn_rate_of_a_circle_where_a_cv_filter_cannot():
    """Noisy, the best expert's forecasts are ~4x closer to the circle than the best CV filter's; noise-free, every
    expert's are the circle and its turn rate and speed the circle's."""
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.5, 1.5, size=200))
    omega, radius = 0.15, 40.0
    circle = radius * np.column_stack([np.cos(omega * t), np.sin(omega * t)])
    z = circle + rng.normal(0, 0.1, circle.shape)
    experts = _experts(z, t)
    error = np.sqrt(np.mean((experts[100:] - circle[100:, None, :]) ** 2, axis=(0, 2)))   # (K,)
    cv = make_bank(2, "kinematic", length_unit=0.1)
    cv_experts = ce.run(cv, z[:, None, :], t[:, None], record_experts=True).experts[100:, 0, :14]
    cv_error = np.sqrt(np.mean((cv_experts - circle[100:, None, :]) ** 2, axis=(0, 2)))
    assert error.min() < 0.2 < 0.3 * cv_error.min(), (error.min(), cv_error.min())   # 0.18 and 0.69 measured
    exact = ce.run(make_bank(2, "ct", length_unit=0.1), circle[:, None, :], t[:, None], record_experts=True)
    np.testing.assert_allclose(exact.experts[100:, 0], np.broadcast_to(circle[100:, None], (100, 6, 2)), atol=1e-6)
    mean = exact.state.families[0].mean[0]                                                   # (K, [x, y, vx, vy, w])
    np.testing.assert_allclose(mean[:, 4], omega, atol=1e-9)                                # rad per time unit
    np.testing.assert_allclose(np.hypot(mean[:, 2], mean[:, 3]), radius * omega, rtol=1e-9)  # the speed


def test_forecast_variance_grows_with_the_step_and_holds_the_first_row():
    t = np.arange(6.0)
    z = np.column_stack([t, np.zeros(6)])
    bank = make_bank(2, "ct", length_unit=0.1)
    params = bank.families[0].params
    state = engine.init_bank_state(bank, 1)
    state, _ = engine.step(bank, state, z[0][None], t[0])
    means, variances = ct.forecast(params, state.families[0], np.array([3.0]))
    np.testing.assert_array_equal(means[0], np.broadcast_to(z[0], means[0].shape))
    np.testing.assert_allclose(variances[0], params.measurement_noise + params.initial_variance * 9.0)
    for row in range(1, 6):
        state, _ = engine.step(bank, state, z[row][None], t[row])
    near = ct.forecast(params, state.families[0], np.array([6.0]))[1]
    far = ct.forecast(params, state.families[0], np.array([16.0]))[1]
    assert np.all(far > near) and np.all(near > 0)


def test_one_coordinate_has_no_plane_to_turn_in():
    assert "ct" not in [f.kind for f in make_bank(1, "mixed+ar+turn+ct").families]
    assert "ct" in [f.kind for f in make_bank(2, "mixed+ar+turn+ct").families]
    with pytest.raises(ValueError, match="'ct' needs at least 2 coordinates"):
        make_bank(1, "ct")


def test_a_track_predictor_runs_the_ct_bank_alone_on_a_plane_and_refuses_it_on_a_line():
    """``--bank ct`` / ``StreamConfig(bank="ct")``: the settings are checked before the first row, when the
    number of coordinates is not known yet; a bank that needs a plane is refused only on a track of one."""
    t = np.arange(30.0)
    table = pd.DataFrame({"track_id": "a", "time": t, "x": np.cos(t / 5) * 10, "y": np.sin(t / 5) * 10})
    out = TrackPredictor(StreamConfig(bank="ct", length_unit=0.1, time_unit=1.0)).process_table(table)
    assert np.isfinite(out[["pred_x", "pred_y"]].to_numpy()).all()
    with pytest.raises(ValueError, match="'ct' needs at least 2 coordinates"):
        TrackPredictor(StreamConfig(bank="ct", length_unit=0.1, time_unit=1.0)).process_table(table[["track_id",
                                                                                                    "time", "x"]])


@pytest.mark.parametrize("turn", [0.0, 3e-4, -9.99e-4, 1.01e-3, 0.4, -2.5, 3.1])
def test_the_jacobian_is_the_transitions_slope(turn):
    """The covariance's Jacobian (the compiled kernel's, which computes the reference's bits) against central
    differences of the transition, on either side of the small-turn series (``turn``: radians over the step)."""
    from kalmix.core.compiled import ct as compiled

    d = 1.7
    state = np.array([3.0, -1.0, 2.0, -0.7, turn / d])

    def predict(mean):
        out = [np.empty(5), np.empty((5, 5)), np.empty((2, 0)), np.empty((2, 2)), np.empty((5, 5)), np.empty((5, 5)),
               np.empty((5, 5))]
        compiled.predict_expert(d, 0.1, 0.1, mean, np.eye(5), np.empty((2, 0)), np.eye(2), *out)
        return out[0], out[4]   # the predicted mean, the Jacobian

    jacobian = predict(state)[1]
    for j in range(5):
        h = 1e-6
        step = np.zeros(5)
        step[j] = h
        slope = (predict(state + step)[0] - predict(state - step)[0]) / (2 * h)
        np.testing.assert_allclose(jacobian[:, j], slope, rtol=1e-7, atol=1e-8, err_msg=f"column {j}")


def test_the_grid_is_checked():
    with pytest.raises(ValueError, match=r"ct_turn_levels\[1\]: expected a finite number > 0, got -1.0"):
        make_bank(2, "ct", ct_turn_levels=(0.1, -1.0))
    with pytest.raises(ValueError, match="ct_process_levels: expected at least one value"):
        make_bank(2, "mixed+ar+turn+ct", ct_process_levels=())
    bank = make_bank(2, "ct", ct_process_levels=(0.5,), ct_turn_levels=(1e-3, 1e-2), length_unit=2.0)
    params = bank.families[0].params
    np.testing.assert_allclose(params.process_noise, [2.0, 2.0])
    np.testing.assert_allclose(params.turn_noise, [4e-3, 4e-2])   # in length units squared too
    assert ct.expert_name(params, 1) == "ct(q=2, q_turn=0.04, r=4)"


@pytest.mark.parametrize("p", [2, 3])
def test_compiled_equals_reference_after_huge_jumps_values_and_a_long_gap(p):
    """1e8 jumps, 1e200 values, a 1,000-row NaN gap and constant input on a turning track: the contract
    (compiled == spec bit for bit, resume, batch == single streams) and finite forecasts after it."""
    rng = np.random.default_rng(3)
    t = np.arange(2000.0)
    z = np.column_stack([np.cos(t / 30) * 20, np.sin(t / 30) * 20, t / 50]) + rng.normal(0, 0.1, (2000, 3))
    z[150] += 1e8                          # a glitch
    z[300:] += np.array([1e8, -1e8, 0.0])  # a relocation
    z[400] = 1e200                         # an absurd value
    z[500:1500] = np.nan                   # a 1,000-row gap
    z[1800:] = z[1799]                     # constant input
    z = np.stack([z, np.column_stack([t * 0.5, -t, np.sin(t)])], axis=1)[..., :p]   # and a straight track
    times = np.broadcast_to(t[:, None], z.shape[:2]).copy()
    bank = make_bank(p, "ct", length_unit=0.3)
    check_bank(bank, z, times)
    assert np.isfinite(ce.run(bank, z, times).forecasts[1600:]).all()


def test_the_bank_with_it_keeps_the_contract_on_irregular_steps_with_restarts():
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.lognormal(0.0, 1.0, size=(120, 3)), axis=0)
    z = np.cumsum(rng.normal(0, 1, (120, 3, 2)), axis=0)
    z[rng.random((120, 3)) < 0.1] = np.nan
    restart = np.zeros((120, 3), bool)
    restart[[40, 80], [0, 2]] = True
    check_bank(make_bank(2, "kinematic+ar+turn+ct", length_unit=0.5, lead=3.0), z, t, restart=restart)


def test_every_expert_is_back_on_the_track_after_an_abrupt_turn():
    """A target at 20 noise sizes a step turns by 90 degrees at once: every expert forecasts within 10 noise sizes
    50 rows later (without the restart at LOST_NIS the experts of q 0.01 and a lateral jerk of 0.3 or 10 were at
    100 to 300 noise sizes, spinning at up to pi radians a step)."""
    t = np.arange(260.0)
    velocity = np.where(t[:, None] < 150, [1.0, 0.0], [0.0, 1.0])
    z = np.cumsum(velocity, axis=0) + np.random.default_rng(0).normal(0, 0.05, (260, 2))
    bank = make_bank(2, "ct", length_unit=0.05)   # the noise's size, as kalmix predict estimates the unit
    experts = ce.run(bank, z[:, None], t[:, None], record_experts=True).experts[:, 0]
    error = np.sqrt(np.mean(np.sum((experts[200:] - z[200:, None]) ** 2, axis=-1), axis=0))   # (K,)
    assert error.max() < 10 * 0.05, error
