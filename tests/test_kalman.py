"""The batched Kalman kernels against filterpy's KalmanFilter, an independent reference."""

import numpy as np
import pytest

from kalmix.core.kalman import cholesky_inverse, kalman_predict, kalman_update

filterpy_kalman = pytest.importorskip("filterpy.kalman")


def _random_spd(rng, n, scale=1.0):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T + n * np.eye(n))


@pytest.mark.parametrize("seed", range(5))
def test_predict_update_equal_filterpy_including_missing(seed):
    rng = np.random.default_rng(seed)
    n, m, steps = rng.integers(2, 7), rng.integers(1, 4), 60
    transition = np.eye(n) + 0.1 * rng.normal(size=(n, n))
    observation = rng.normal(size=(m, n))
    process = _random_spd(rng, n, 0.01)
    noise = _random_spd(rng, m, 0.1)
    reference = filterpy_kalman.KalmanFilter(dim_x=n, dim_z=m)
    reference.F, reference.H, reference.Q, reference.R = transition, observation, process, noise
    reference.x = rng.normal(size=n)
    reference.P = _random_spd(rng, n)
    mean, cov = reference.x.copy(), reference.P.copy()
    for k in range(steps):
        z = rng.normal(size=m) * 3
        missing = k % 7 == 3
        if missing:
            z = np.full(m, np.nan)
            reference.update(None)
        else:
            reference.update(z)
        mean, cov, log_lik = kalman_update(mean, cov, z, observation, noise)
        np.testing.assert_allclose(mean, reference.x, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(cov, reference.P, rtol=1e-10, atol=1e-10)
        if missing:
            assert log_lik == 0.0
        else:
            np.testing.assert_allclose(log_lik, reference.log_likelihood, rtol=1e-10)
        reference.predict()
        mean, cov = kalman_predict(mean, cov, transition, process)
        np.testing.assert_allclose(mean, reference.x, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(cov, reference.P, rtol=1e-10, atol=1e-10)


def test_kernels_are_batched_over_leading_axes():
    rng = np.random.default_rng(1)
    n, m = 4, 2
    means = rng.normal(size=(3, 5, n))
    covs = np.stack([[_random_spd(rng, n) for _ in range(5)] for _ in range(3)])
    obs = rng.normal(size=(m, n))
    noise = _random_spd(rng, m)
    z = rng.normal(size=(3, 5, m))
    z[1, 2] = np.nan
    batch = kalman_update(means, covs, z, obs, noise)
    for i in range(3):
        for j in range(5):
            single = kalman_update(means[i, j], covs[i, j], z[i, j], obs, noise)
            for b, s in zip(batch, single):
                np.testing.assert_allclose(b[i, j], s, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(batch[0][1, 2], means[1, 2])


def test_covariance_stays_symmetric_and_cholesky_inverse_is_exact():
    rng = np.random.default_rng(2)
    spd = np.stack([_random_spd(rng, 3) for _ in range(10)])
    inverse, log_det = cholesky_inverse(spd, jitter=0.0)
    np.testing.assert_allclose(inverse @ spd, np.broadcast_to(np.eye(3), spd.shape), atol=1e-12)
    np.testing.assert_allclose(log_det, np.linalg.slogdet(spd)[1], rtol=1e-12)
    _, cov, _ = kalman_update(np.zeros(3), spd[0], np.ones(2), rng.normal(size=(2, 3)), np.eye(2))
    np.testing.assert_array_equal(cov, cov.T)
