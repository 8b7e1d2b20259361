"""Batched Kalman filter kernels.

Every function works on arrays with any number of leading (batch) axes: means are
``(..., n)``, covariances ``(..., n, n)``, measurements ``(..., p)``. Matrix algebra
happens on the last two axes, so a whole bank of filters (targets x experts) is
advanced by one call, with no Python loop over filters.

A measurement row containing NaN is *missing*: the update returns the prior
unchanged and a log-likelihood of zero for that row.
"""

from __future__ import annotations

import numpy as np

from ._libm import ordered_sum

__all__ = [
    "symmetrize",
    "cholesky_inverse",
    "cholesky_lower",
    "cholesky_solve_rows",
    "kalman_predict",
    "kalman_update",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


def symmetrize(matrix: np.ndarray) -> np.ndarray:
    """Return :math:`(M + M^T)/2` on the last two axes."""
    return 0.5 * (matrix + np.swapaxes(matrix, -1, -2))


def cholesky_inverse(spd: np.ndarray, jitter: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and log-determinant of symmetric positive definite matrices via Cholesky.

    .. math:: S + \\epsilon I = L L^T,\\quad S^{-1} = L^{-T} L^{-1},\\quad
              \\log|S| = 2 \\sum_i \\log L_{ii}

    Parameters
    ----------
    spd : ndarray, shape (..., m, m)
        Symmetric positive definite matrices.
    jitter : float
        Relative diagonal boost :math:`\\epsilon` (scaled by the mean diagonal) that
        keeps the factorisation defined for nearly singular input.

    Returns
    -------
    inverse : ndarray, shape (..., m, m)
    log_det : ndarray, shape (...)

    Entry by entry in the compiled kernels' order (:func:`kalmix.core._numba_linalg.cholesky_inverse`: the
    mean diagonal summed in order, :math:`L^{-1}` by forward substitution, the upper triangle of
    :math:`L^{-T} L^{-1}` mirrored), so that the AKF's filter gives the same bits in both engines; a matrix
    that is not positive definite gives NaN.
    """
    m = spd.shape[-1]
    trace = ordered_sum(np.diagonal(spd, axis1=-2, axis2=-1), axis=-1)
    work = symmetrize(spd)
    work[..., np.arange(m), np.arange(m)] += jitter * (trace / m)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        low = cholesky_lower(work)
        inverse_low = np.zeros_like(work)
        for c in range(m):
            for i in range(c, m):
                acc = np.full(work.shape[:-2], 1.0 if i == c else 0.0)
                for l in range(c, i):
                    acc = acc - low[..., i, l] * inverse_low[..., l, c]
                inverse_low[..., i, c] = acc / low[..., i, i]
        inverse = np.empty_like(work)
        for i in range(m):
            for j in range(i, m):
                acc = np.zeros(work.shape[:-2])
                for l in range(j, m):
                    acc = acc + inverse_low[..., l, i] * inverse_low[..., l, j]
                inverse[..., i, j] = inverse[..., j, i] = acc
        log_det = 2.0 * np.sum(np.log(np.diagonal(low, axis1=-2, axis2=-1)), axis=-1)
    return inverse, log_det


def cholesky_lower(spd: np.ndarray, clamp: bool = False) -> np.ndarray:
    """Cholesky factors :math:`L` (``(..., m, m)``, lower triangle) of the lower triangles of ``spd``, entry by
    entry in the compiled kernels' order (:func:`kalmix.core._numba_linalg.cholesky_lower`); NaN where a
    matrix is not positive definite, or with ``clamp`` a pivot below 0 (rounding, in a matrix that is positive
    semi-definite) taken as 0."""
    m = spd.shape[-1]
    lower = np.zeros(spd.shape)
    for j in range(m):
        acc = spd[..., j, j]
        for k in range(j):
            acc = acc - lower[..., j, k] * lower[..., j, k]
        lower[..., j, j] = np.sqrt(np.maximum(acc, 0.0) if clamp else acc)
        for i in range(j + 1, m):
            acc = spd[..., i, j]
            for k in range(j):
                acc = acc - lower[..., i, k] * lower[..., j, k]
            lower[..., i, j] = acc / lower[..., j, j]
    return lower


def cholesky_solve_rows(spd: np.ndarray, rhs: np.ndarray, clamp: bool = False) -> np.ndarray:
    """``rhs @ spd^{-1}`` for symmetric positive definite ``spd``: each row of ``rhs`` solved.

    .. math:: S = L L^T, \\qquad L y = b, \\qquad L^T x = y

    The factor and the two substitutions are written out entry by entry, vectorised over
    the leading axes, in the order of the compiled kernels
    (:func:`kalmix.core._numba_linalg.cholesky_solve_rows`), so that both give the same bits:
    the RLS solve is where digits are lost (its Gram matrix is as ill-conditioned as the
    regressor is far from its origin), and a rounding difference in the system matrix
    grows with every frame extrapolated through it (long gaps).
    A matrix that is not positive definite gives NaN (no exception), as in the kernels; ``clamp``: see
    :func:`cholesky_lower`.

    Parameters
    ----------
    spd : ndarray, shape (..., m, m)
        Only the lower triangle is read.
    rhs : ndarray, shape (..., r, m)

    Returns
    -------
    ndarray, shape (..., r, m)
    """
    m = spd.shape[-1]
    shape = np.broadcast_shapes(spd.shape[:-2], rhs.shape[:-2])
    with np.errstate(invalid="ignore", divide="ignore"):
        lower = np.broadcast_to(cholesky_lower(spd, clamp), shape + (m, m))
        out = np.zeros(shape + rhs.shape[-2:])
        for i in range(m):  # L y = b
            acc = rhs[..., :, i]
            for k in range(i):
                acc = acc - lower[..., i, k, None] * out[..., :, k]
            out[..., :, i] = acc / lower[..., i, i, None]
        for i in range(m - 1, -1, -1):  # L^T x = y
            acc = out[..., :, i]
            for k in range(i + 1, m):
                acc = acc - lower[..., k, i, None] * out[..., :, k]
            out[..., :, i] = acc / lower[..., i, i, None]
    return out


def kalman_predict(
    mean: np.ndarray,
    cov: np.ndarray,
    transition: np.ndarray,
    process_cov: np.ndarray,
    offset: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Time update (prediction) of a linear Gaussian state.

    .. math::
        \\hat x_{k+1|k} = A_k \\hat x_{k|k} + u_k, \\qquad
        P_{k+1|k} = A_k P_{k|k} A_k^T + D Q_k D^T

    Parameters
    ----------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)
    transition : ndarray, shape (..., n, n)
        System matrix :math:`A_k`.
    process_cov : ndarray, shape (..., n, n)
        Process noise covariance in state space, :math:`D Q_k D^T`.
    offset : ndarray, shape (..., n), optional
        Known additive term :math:`u_k` (e.g. a learned drift).

    Returns
    -------
    mean, cov : predicted mean ``(..., n)`` and covariance ``(..., n, n)``.
    """
    new_mean = np.einsum("...ij,...j->...i", transition, mean)
    if offset is not None:
        new_mean = new_mean + offset
    new_cov = transition @ cov @ np.swapaxes(transition, -1, -2) + process_cov
    return new_mean, symmetrize(new_cov)


def kalman_update(
    mean: np.ndarray,
    cov: np.ndarray,
    measurement: np.ndarray,
    observation: np.ndarray,
    measurement_cov: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurement update in Joseph form, with the innovation log-likelihood.

    .. math::
        r = z - C \\hat x, \\quad S = C P C^T + R, \\quad K = P C^T S^{-1},

        \\hat x^+ = \\hat x + K r, \\quad
        P^+ = (I - K C) P (I - K C)^T + K R K^T,

        \\log p(z) = -\\tfrac12 \\left(r^T S^{-1} r + \\log|S| + m \\log 2\\pi\\right)

    Rows of ``measurement`` that contain a NaN are missing: the prior is returned for
    them and their log-likelihood is 0.

    Parameters
    ----------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)
    measurement : ndarray, shape (..., m)
    observation : ndarray, shape (..., m, n)
        Observation matrix :math:`C`.
    measurement_cov : ndarray, shape (..., m, m)
        Measurement noise covariance :math:`R`.

    Returns
    -------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)
    log_likelihood : ndarray, shape (...)
    """
    missing = np.isnan(measurement).any(axis=-1)
    safe_z = np.where(missing[..., None], 0.0, measurement)
    predicted_z = np.einsum("...ij,...j->...i", observation, mean)
    residual = safe_z - predicted_z
    cov_ct = cov @ np.swapaxes(observation, -1, -2)
    innovation_cov = observation @ cov_ct + measurement_cov
    # rows without a measurement are discarded below: factor the identity for them instead
    innovation_cov = np.where(missing[..., None, None], np.eye(measurement.shape[-1]), innovation_cov)
    innovation_inv, log_det = cholesky_inverse(innovation_cov)
    gain = cov_ct @ innovation_inv
    new_mean = mean + np.einsum("...ij,...j->...i", gain, residual)
    n = mean.shape[-1]
    i_kc = np.eye(n) - gain @ observation
    new_cov = i_kc @ cov @ np.swapaxes(i_kc, -1, -2) + gain @ measurement_cov @ np.swapaxes(gain, -1, -2)
    new_cov = symmetrize(new_cov)
    m = measurement.shape[-1]
    mahalanobis = np.einsum("...i,...ij,...j->...", residual, innovation_inv, residual)
    log_likelihood = -0.5 * (mahalanobis + log_det + m * _LOG_2PI)
    new_mean = np.where(missing[..., None], mean, new_mean)
    new_cov = np.where(missing[..., None, None], cov, new_cov)
    log_likelihood = np.where(missing, 0.0, log_likelihood)
    return new_mean, new_cov, log_likelihood
