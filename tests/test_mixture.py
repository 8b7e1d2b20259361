"""The batched mixture core: reference equalities and invariants."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import smooth_tracks
from kalmix import MixturePredictor, make_params
from kalmix.core import init_state, run_core, step
from kalmix.core.gating import fixed_share_update, log_expert_likelihood, posterior, softmax_gate
from kalmix.core.mixture import observation_matrix
from kalmix.core.dynamics import companion_from_theta

filterpy_kalman = pytest.importorskip("filterpy.kalman")


def test_one_expert_with_fixed_dynamics_is_a_plain_kalman_filter():
    z = smooth_tracks(0, 200, dim=2)[:, 0]
    z[50:53] = np.nan
    params = make_params(2, 1, dynamics="fixed", adapt_noise=False, initial_velocity_spread=0.0)
    predictions = run_core(params, z[:, None]).predictions[:, 0]
    kappa, origin = params.feature_scale, z[0]
    transition, _ = companion_from_theta(params.prior_theta, params.order)
    reference = filterpy_kalman.KalmanFilter(dim_x=params.state_dim, dim_z=2)
    reference.F = transition
    reference.H = observation_matrix(params)
    reference.Q = np.diag(np.r_[params.process_noise[0], 0, 0]) / kappa**2 + params.state_jitter * np.eye(4)
    reference.R = np.diag(params.measurement_noise[0]) / kappa**2
    reference.x = np.zeros(4)
    reference.P = params.initial_variance[0] / kappa**2 * np.eye(4)
    reference.predict()
    for t in range(1, len(z)):
        reference.update(None if np.isnan(z[t]).any() else (z[t] - origin) / kappa)
        reference.predict()
        np.testing.assert_allclose(predictions[t], origin + kappa * reference.x[:2], rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("gating", ["fixed_share", "paper", "random"])
@pytest.mark.parametrize("dynamics", ["rls", "literal"])
def test_a_batch_of_streams_equals_single_stream_runs(gating, dynamics):
    z = smooth_tracks(1, 80, targets=4)
    z[10:14, 2] = np.nan
    params = make_params(3, 6, gating=gating, dynamics=dynamics, seed=3)
    batch = run_core(params, z, diagnostics=True)
    for j in range(4):
        single = run_core(params, z[:, j:j + 1], init_state(params, 1, stream_ids=[j]), diagnostics=True)
        np.testing.assert_array_equal(batch.predictions[:, j], single.predictions[:, 0])
        np.testing.assert_array_equal(batch.weights[:, j], single.weights[:, 0])


@pytest.mark.parametrize("backend", ["numpy", "auto"])
def test_functional_and_object_forms_agree_at_every_step(backend):
    """The same bits, on the numpy path and on the compiled one (auto)."""
    z = smooth_tracks(2, 120)[:, 0]
    params = make_params(3, 8, seed=5)
    state = init_state(params, 1)
    predictor = MixturePredictor(8, seed=5, backend=backend)
    for t in range(len(z)):
        state, out = step(params, state, z[t][None])
        np.testing.assert_array_equal(predictor.step(z[t]), out.prediction[0])
        np.testing.assert_array_equal(predictor.weights_, out.weights[0])
        np.testing.assert_array_equal(predictor.process_noise_, state.process_noise[0])


def test_horizon_predictions_score_against_later_frames():
    z = smooth_tracks(3, 150)[:, 0]
    predictor = MixturePredictor(5, seed=0)
    result = predictor.run(z, horizon=3)
    errors = z[3:] - result.predictions[:-3]
    assert np.sqrt(np.mean(errors[50:] ** 2)) < np.sqrt(np.mean((z[3:] - z[:-3])[50:] ** 2))
    one = MixturePredictor(5, seed=0).run(z).predictions
    np.testing.assert_array_equal(MixturePredictor(5, seed=0).run(z, horizon=1).predictions, one)


@settings(max_examples=40)
@given(error=st.floats(-1e4, 1e4), k=st.integers(1, 50), scale=st.floats(0.1, 10.0))
def test_weights_and_posteriors_are_finite_and_normalised_for_huge_errors(error, k, scale):
    rng = np.random.default_rng(k)
    weights = rng.dirichlet(np.ones(k), size=2)
    errors = error * rng.uniform(0.5, 1.5, size=(2, k, 3))
    log_lik = log_expert_likelihood(errors, np.full(k, scale))
    for values in (posterior(weights, log_lik), fixed_share_update(weights, log_lik, 1.0, 0.02),
                   softmax_gate(rng.normal(size=(2, k, 4)) * 1e3, rng.normal(size=(2, 4)), 0.5)):
        assert np.isfinite(values).all()
        np.testing.assert_allclose(values.sum(axis=-1), 1.0, rtol=1e-12)


def _adversarial_stream(rng, steps):
    z = np.cumsum(rng.normal(size=(steps, 3)) * 5, axis=0) + 300
    z[1000:1500] = 123.0                        # constant input
    z[2000:2600] = np.nan                       # a long run of missing frames
    z[3000::997] += 1e4                         # jumps of 10^4 px
    z[5000:5200] = rng.normal(size=(200, 3)) * 1e3  # wild noise
    z[6000:6050] = 0.0                          # the origin
    z[rng.random(steps) < 0.05] = np.nan        # scattered gaps
    return z


@pytest.mark.parametrize("gating,dynamics", [("fixed_share", "rls"), ("paper", "rls"), ("random", "literal")])
def test_covariances_stay_symmetric_positive_definite_over_long_adversarial_runs(gating, dynamics):
    rng = np.random.default_rng(7)
    steps = 100_000 if gating == "fixed_share" else 20_000
    z = _adversarial_stream(rng, steps)
    params = make_params(3, 2, gating=gating, dynamics=dynamics, seed=1)
    state = init_state(params, 1)
    for chunk in np.array_split(z, 20):
        result = run_core(params, chunk[:, None], state)
        state = result.state
        cov = state.cov
        np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))
        assert (np.linalg.eigvalsh(cov) > 0).all()
        assert np.isfinite(result.predictions[np.isfinite(chunk).all(axis=1)]).all()
        assert np.isfinite(state.weights).all() and np.allclose(state.weights.sum(-1), 1)


def test_same_seed_same_numbers_and_different_seeds_different_banks():
    z = smooth_tracks(4, 60)[:, 0]
    a = MixturePredictor(10, seed=11).run(z).predictions
    b = MixturePredictor(10, seed=11).run(z).predictions
    np.testing.assert_array_equal(a, b)
    p1, p2 = make_params(3, 10, seed=1), make_params(3, 10, seed=2)
    assert not np.array_equal(p1.initial_velocity, p2.initial_velocity)
    assert not np.array_equal(MixturePredictor(10, seed=12).run(z).predictions, a)


def test_bank_recipe_is_the_documented_grid():
    params = make_params(3, 40)
    assert len(np.unique(params.process_noise[:, 0])) == 8
    assert len(np.unique(params.measurement_noise[:, 0])) == 5
    single = make_params(3, 1)
    assert single.process_noise[0, 0] == np.sqrt(1e-2 * 1e2)
    assert single.measurement_noise[0, 0] == np.sqrt(5e-2 * 5)
    np.testing.assert_array_equal(single.initial_velocity, 0.0)


def test_missing_measurements_predict_without_learning():
    z = smooth_tracks(5, 100)[:, 0]
    predictor = MixturePredictor(5, seed=0)
    predictor.run(z[:60])
    weights, noise = predictor.weights_.copy(), predictor.process_noise_.copy()
    before = predictor.predict(1)
    after = predictor.step([np.nan, np.nan, np.nan])
    np.testing.assert_array_equal(predictor.weights_, weights)
    np.testing.assert_array_equal(predictor.process_noise_, noise)
    np.testing.assert_array_equal(after, predictor.predict(1))
    np.testing.assert_array_equal(before, MixturePredictor(5, seed=0).run(z[:60]).predictions[-1])
    assert np.isfinite(after).all()
    nothing_yet = MixturePredictor(5).step([np.nan, np.nan])
    assert np.isnan(nothing_yet).all()


def test_the_paper_gate_learns_toward_the_better_expert():
    z = smooth_tracks(6, 400)[:, 0]
    result = MixturePredictor(40, gating="paper", seed=0).run(z, expert_predictions=True)
    errors = np.nanmean(np.sum((result.expert_predictions[:-1] - z[1:, None]) ** 2, -1)[100:], axis=0)
    weights = result.weights[-100:].mean(axis=0)
    assert np.corrcoef(weights, -errors)[0, 1] > 0  # more weight on experts with lower error


def test_very_long_runs_of_missing_measurements_stay_finite():
    z = smooth_tracks(8, 30)[:, 0]
    params = make_params(3, 4, length_unit=50.0, seed=0)
    state = run_core(params, z[:, None]).state
    gap = np.full((20_000, 1, 3), np.nan)
    result = run_core(params, gap, state)
    assert np.isfinite(result.state.cov).all() and np.isfinite(result.predictions).all()
    assert (np.linalg.eigvalsh(result.state.cov) > 0).all()
    after = run_core(params, z[:, None], result.state)  # measurements come back: learning resumes
    assert np.isfinite(after.predictions).all()


def _steady(t_count, speed, noise, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.stack([speed * np.arange(t_count), np.zeros(t_count)], axis=1)
    return truth, truth + rng.normal(0, noise, truth.shape)


@pytest.mark.parametrize("k_count", [3, 40])
def test_a_target_moving_on_past_the_feature_limit_keeps_its_dynamics(k_count):
    """A smooth target crossing the feature limit (100 feature units, 1e4 length units) every 2,500
    rows had its RLS dynamics reset there: errors up to 10 sigma for ~20 rows each time. The re-anchor now
    translates the statistics, the history and the drift: errors after each crossing are as elsewhere, and the
    compiled kernel gives the reference's bits."""
    truth, z = _steady(3000, 2.0, 0.5)
    params = make_params(2, k_count, seed=1, feature_scale=5.0)   # the limit: 500 units, crossed every 250 rows
    reference = run_core(params, z[:, None, :], backend="numpy")
    compiled = run_core(params, z[:, None, :], backend="numba")
    assert np.array_equal(reference.predictions, compiled.predictions, equal_nan=True)
    assert reference.state.origin[0, 0] > 5000   # the origin moved on (re-anchors happened)
    error = np.linalg.norm(reference.predictions[:-1, 0] - truth[1:], axis=-1) / 0.5
    crossings = np.flatnonzero(np.diff(np.floor((z[:, 0] - z[0, 0]) / 500.0)) > 0) + 1
    after = np.zeros(len(error), dtype=bool)
    for row in crossings:
        after[row:row + 20] = True
    after[:300] = False
    calm = np.zeros(len(error), dtype=bool)
    calm[300:] = True
    calm &= ~after
    assert error[after].max() <= 1.5 * error[calm].max()


def test_a_jump_past_the_feature_limit_still_restarts_the_dynamics():
    """A stationary target jumping 1.2-2 feature limits was taken as having moved on, and the jump went
    into the translated RLS statistics: errors after it 20-200 times those of a restart (RMS 190 against 1.7).
    Only a step within miss_limit of the last measurement is moving on."""
    params = make_params(2)
    rng = np.random.default_rng(0)
    for jump in (12_000.0, 20_100.0):
        truth = np.zeros((400, 2))
        truth[200:] = np.array([jump, 0.6 * jump]) / np.hypot(1, 0.6)
        z = (truth + rng.normal(0, 1.0, truth.shape))[:, None]
        reference = run_core(params, z, backend="numpy")
        compiled = run_core(params, z, backend="numba")
        assert np.array_equal(reference.predictions, compiled.predictions, equal_nan=True)
        error = np.linalg.norm(reference.predictions[201:260, 0] - truth[202:261], axis=-1)
        assert np.sqrt(np.mean(error**2)) < 3.0, jump   # translated: 190 (12,000) and 95 (20,100)


def test_little_forgetting_across_many_re_anchors_stays_finite():
    """With forgetting 0.999 the statistics keep data from far back; translated again and again they
    grew until the solve failed, and a noise-free line was NaN from row 871 to the end (the reset kept it
    finite). Data held far from the new origin now start the dynamics again."""
    params = make_params(2, 3, seed=1, order=2, feature_scale=1.0, forgetting_levels=(0.999,))
    z = (np.arange(1500)[:, None] * 90.0 * np.array([1.0, -0.42]))[:, None]
    for backend in ("numpy", "numba"):
        assert np.isfinite(run_core(params, z, backend=backend).predictions[2:]).all(), backend
