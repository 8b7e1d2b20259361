"""State-model adaptation: the paper's eq. (6)/(7) and the RLS generalisation."""

import numpy as np
import pytest

from kalmix.core import dynamics as dyn


def test_literal_transition_equals_eq6_and_corrected_eq7():
    rng = np.random.default_rng(0)
    p, n = 3, 6
    observation = rng.normal(size=(p, n))  # a general C, not only [I 0]
    z_now, z_prev = rng.normal(size=p), rng.normal(size=p)
    gram_inv = np.linalg.inv(observation @ observation.T)
    pinv = observation.T @ gram_inv  # C^+
    # eq. (6): A = x_k x_{k-1}^+ with x = C^+ z
    x_now, x_prev = pinv @ z_now, pinv @ z_prev
    eq6 = np.outer(x_now, x_prev) / (x_prev @ x_prev)
    # corrected eq. (7): C^+ z_k (z_{k-1}^T G^-1 z_{k-1})^-1 z_{k-1}^T G^-1 C
    eq7 = np.outer(pinv @ z_now, z_prev @ gram_inv @ observation) / (z_prev @ gram_inv @ z_prev)
    ours = dyn.literal_transition(z_now, z_prev, observation, epsilon=0.0)
    np.testing.assert_allclose(ours, eq7, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours, eq6, rtol=1e-8, atol=1e-10)


def test_literal_prediction_is_a_radial_rescaling_of_the_measurement():
    rng = np.random.default_rng(1)
    p = 3
    c = np.hstack([np.eye(p), np.zeros((p, p))])
    z_now, z_prev = rng.normal(size=p), rng.normal(size=p)
    a = dyn.literal_transition(z_now, z_prev, c, epsilon=0.0)
    rho = (z_prev @ z_now) / (z_prev @ z_prev)
    np.testing.assert_allclose(c @ a @ (c.T @ z_now), rho * z_now, rtol=1e-12)


def test_rls_reduces_to_eq6_when_forgetting_and_ridge_vanish():
    rng = np.random.default_rng(2)
    n = 4
    xs = rng.normal(size=(10, n))
    gram, cross = np.zeros((n, n)), np.zeros((n, n))
    for previous, current in zip(xs[:-1], xs[1:]):
        gram, cross = dyn.rls_accumulate(gram, cross, previous, current, forgetting=0.0)
    eq6 = np.outer(xs[-1], xs[-2]) / (xs[-2] @ xs[-2])
    gaps = [np.abs(dyn.rls_solve(gram, cross, ridge=rho, prior=np.zeros((n, n))) - eq6).max()
            for rho in (1e-3, 1e-5, 1e-7)]
    assert gaps[0] > 10 * gaps[1] > 100 * gaps[2] and gaps[2] < 1e-5  # converges linearly in rho
    # with a prior, the last pair is still fitted exactly and the prior fills the rest:
    prior = rng.normal(size=(n, n))
    theta = dyn.rls_solve(gram, cross, ridge=1e-7, prior=prior)
    projector = np.outer(xs[-2], xs[-2]) / (xs[-2] @ xs[-2])
    np.testing.assert_allclose(theta, eq6 + prior @ (np.eye(n) - projector), atol=1e-5)


def test_rls_recovers_a_linear_system_and_forgetting_weights_recent_pairs():
    rng = np.random.default_rng(3)
    p, order = 2, 2
    truth = np.hstack([1.6 * np.eye(p), -0.7 * np.eye(p), np.array([[0.05], [-0.02]])])
    s = [rng.normal(size=p), rng.normal(size=p)]
    gram, cross = np.zeros((5, 5)), np.zeros((p, 5))
    prior = dyn.polynomial_prior(p, order)
    for _ in range(300):
        xi = dyn.regressor(np.array([s[-1], s[-2]]))
        new = truth @ xi + 1e-3 * rng.normal(size=p)
        gram, cross = dyn.rls_accumulate(gram, cross, xi, new, 0.99)
        s.append(new + rng.normal(size=p) * 0.0)
        if len(s) % 20 == 0:  # excite the system
            s[-1] = s[-1] + rng.normal(size=p)
    theta = dyn.rls_solve(gram, cross, 1e-6, prior)
    np.testing.assert_allclose(theta, truth, atol=1e-2)


def test_polynomial_prior_extrapolates_polynomials():
    p = 2
    t = np.arange(5.0)
    for degree, order in ((0, 1), (1, 2), (2, 3)):
        coeffs = np.array([[1.0, -2.0, 0.5][: degree + 1], [0.3, 1.0, -0.25][: degree + 1]])
        path = np.stack([np.polyval(c[::-1], t) for c in coeffs], axis=1)  # (5, p)
        theta = dyn.polynomial_prior(p, order, degree)
        history = path[-2::-1][:order]  # s_{k-1}, s_{k-2}, ...
        np.testing.assert_allclose(theta @ dyn.regressor(history), path[-1], atol=1e-12)


def test_guard_keeps_stable_theta_and_shrinks_unstable_one():
    p, order = 3, 2
    prior = dyn.polynomial_prior(p, order)
    stable = prior.copy()
    stable[:, :p] = 1.5 * np.eye(p)
    stable[:, p:2 * p] = -0.6 * np.eye(p)
    np.testing.assert_array_equal(dyn.guard_theta(stable, prior, order, 1.02), stable)
    unstable = prior.copy()
    unstable[:, p:2 * p] = -1.2 * np.eye(p)  # complex roots of modulus sqrt(1.2)
    guarded = dyn.guard_theta(unstable, prior, order, 1.02)
    transition, _ = dyn.companion_from_theta(guarded, order)
    assert dyn.spectral_radius(transition) <= 1.02 + 1e-9
    assert not np.allclose(guarded, prior)  # shrunk only as far as needed
    batch = dyn.guard_theta(np.stack([stable, unstable]), prior, order, 1.02)
    np.testing.assert_array_equal(batch[0], stable)
    np.testing.assert_array_equal(batch[1], guarded)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_companion_shapes(order):
    theta = dyn.polynomial_prior(3, order)
    transition, offset = dyn.companion_from_theta(theta, order)
    assert transition.shape == (3 * order, 3 * order) and offset.shape == (3 * order,)
