"""Online estimation of each expert's system matrix (the paper's state-model AKF).

The Kalman state of every expert is a delay embedding of normalised features
:math:`s_k = (z_k - c)/\\kappa`:

.. math:: x_k = [s_k; s_{k-1}; \\dots; s_{k-o+1}] \\in \\mathbb{R}^{n},\\ n = o\\,p,
          \\qquad C = [I_p\\ 0 \\cdots 0].

Two ways to get the system matrix :math:`A_k` (and a drift :math:`u_k`):

``literal``
    The paper's eq. (6)/(7) (eq. 7 without its misprinted factor :math:`C_k^T`, which makes it
    equal to eq. 6):
    :math:`\\hat A_k = C^+ z_k (z_{k-1}^T G^{-1} z_{k-1})^{-1} z_{k-1}^T G^{-1} C`,
    :math:`G = C C^T`, which equals :math:`x_k x_{k-1}^+` with :math:`x = C^+ z`.
``rls``
    :math:`s_k \\approx \\Theta_k \\xi_{k-1}` with regressor
    :math:`\\xi_{k-1} = [s_{k-1}; \\dots; s_{k-o}; 1]`, fitted by ridge-regularised
    recursive least squares with forgetting :math:`\\lambda` toward a prior
    :math:`\\Theta_0` (constant velocity by default), then guarded so that the spectral
    radius of the companion matrix stays below a bound.

All functions are batched over leading axes and pure.
"""

from __future__ import annotations

import numpy as np

from .kalman import cholesky_inverse, cholesky_solve_rows

__all__ = [
    "polynomial_prior",
    "regressor",
    "rls_accumulate",
    "rls_solve",
    "companion_from_theta",
    "spectral_radius",
    "guard_theta",
    "literal_transition",
]

#: The shrink factors gamma that :func:`guard_theta` tries, largest first (the compiled loop gets them
#: packed with its parameters, :func:`kalmix.core.fast.pack_params`).
GUARD_SHRINK = np.array([1.0, 0.8, 0.6, 0.4, 0.2, 0.0])


def polynomial_prior(measurement_dim: int, order: int, degree: int | None = None) -> np.ndarray:
    """Prior :math:`\\Theta_0` of a polynomial extrapolator, shape ``(p, o p + 1)``.

    ``degree`` 0 repeats the last value, 1 is constant velocity
    (:math:`s_{k+1} = 2 s_k - s_{k-1}`), 2 is constant acceleration
    (:math:`3 s_k - 3 s_{k-1} + s_{k-2}`). The default degree is ``min(order - 1, 1)``.
    The bias column is zero.
    """
    if degree is None:
        degree = min(order - 1, 1)
    coefficients = {0: [1.0], 1: [2.0, -1.0], 2: [3.0, -3.0, 1.0]}[degree]
    p = measurement_dim
    theta = np.zeros((p, order * p + 1))
    for lag, c in enumerate(coefficients):
        theta[:, lag * p:(lag + 1) * p] = c * np.eye(p)
    return theta


def regressor(history: np.ndarray) -> np.ndarray:
    """Regressor :math:`\\xi = [s_{k-1}; \\dots; s_{k-o}; 1]` from ``history`` ``(..., o, p)``."""
    flat = history.reshape(history.shape[:-2] + (history.shape[-2] * history.shape[-1],))   # also for 0 targets
    return np.concatenate([flat, np.ones(flat.shape[:-1] + (1,))], axis=-1)


def rls_accumulate(gram, cross, features, target, forgetting):
    """Discounted sufficient statistics of least squares.

    .. math:: S_k = \\lambda S_{k-1} + \\xi \\xi^T, \\qquad M_k = \\lambda M_{k-1} + s_k \\xi^T

    Parameters
    ----------
    gram : ndarray, shape (..., d, d)
    cross : ndarray, shape (..., p, d)
    features : ndarray, shape (..., d)
        Regressor :math:`\\xi_{k-1}`.
    target : ndarray, shape (..., p)
        New features :math:`s_k`.
    forgetting : ndarray, shape (...)
        :math:`\\lambda \\in [0, 1]`.
    """
    lam = np.asarray(forgetting)[..., None, None]
    gram = lam * gram + features[..., :, None] * features[..., None, :]
    cross = lam * cross + target[..., :, None] * features[..., None, :]
    return gram, cross


def rls_solve(gram, cross, ridge, prior):
    """Ridge solution shrunk toward a prior.

    .. math:: \\Theta_k = (M_k + \\rho \\Theta_0)(S_k + \\rho I)^{-1}

    With :math:`\\lambda = 0` and :math:`\\rho \\to 0` this tends to
    :math:`s_k \\xi^+ + \\Theta_0 (I - \\xi \\xi^+)`: the last pair is fitted exactly
    and the prior acts only off :math:`\\xi`; with :math:`\\Theta_0 = 0` (and the
    unstructured regressor :math:`\\xi = x_{k-1}`) it is the paper's eq. (6).
    """
    d = gram.shape[-1]
    rho = np.asarray(ridge)[..., None, None]
    return cholesky_solve_rows(gram + rho * np.eye(d), cross + rho * prior)


def companion_from_theta(theta: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """System matrix and drift of the delay-embedded state.

    .. math::
        A = \\begin{bmatrix} \\Theta_1 & \\cdots & \\Theta_o \\\\
                             I & & 0 \\end{bmatrix}, \\qquad
        u = \\begin{bmatrix} b \\\\ 0 \\end{bmatrix}

    Parameters
    ----------
    theta : ndarray, shape (..., p, o p + 1)

    Returns
    -------
    transition : ndarray, shape (..., o p, o p)
    offset : ndarray, shape (..., o p)
    """
    p = theta.shape[-2]
    n = order * p
    batch = theta.shape[:-2]
    transition = np.zeros(batch + (n, n))
    transition[..., :p, :] = theta[..., :n]
    if order > 1:
        transition[..., p:, :n - p] = np.eye(n - p)
    offset = np.zeros(batch + (n,))
    offset[..., :p] = theta[..., n]
    return transition, offset


def spectral_radius(matrix: np.ndarray) -> np.ndarray:
    r"""Largest eigenvalue modulus of ``(..., n, n)`` matrices; NaN for one with a NaN or inf.

    Computed as the compiled guard computes it: the eigenvalues of the matrix as complex numbers (LAPACK's
    complex solver; the real one can round them differently) and the modulus as
    :math:`\sqrt{\max(re^2 + im^2)}` (numpy's and numba's ``abs`` of a complex number differ in the last
    bit). A candidate on the bound (the prior's roots at 1 with a bound of 1) is otherwise accepted by one
    engine and shrunk by the other.
    """
    matrix = np.asarray(matrix)
    finite = np.isfinite(matrix).all(axis=(-1, -2))
    radius = np.full(matrix.shape[:-2], np.nan)
    if finite.any():
        values = np.linalg.eigvals(matrix[finite].astype(np.complex128))
        with np.errstate(over="ignore"):
            radius[finite] = np.sqrt(np.max(values.real * values.real + values.imag * values.imag, axis=-1))
    return radius


def guard_theta(theta, prior, order: int, bound: float):
    """Shrink :math:`\\Theta` toward :math:`\\Theta_0` until the companion is stable.

    Candidates :math:`\\Theta_0 + \\gamma (\\Theta - \\Theta_0)` for
    :math:`\\gamma \\in \\{1, 0.8, \\dots, 0\\}` are checked at once; the largest
    :math:`\\gamma` whose companion matrix has spectral radius :math:`\\le` ``bound``
    wins (:math:`\\gamma = 0`, the prior, is always accepted).

    The unshrunk candidate is checked first; the eigenvalues of the shrunk ones are
    computed only for the thetas that fail it (same result, far fewer eigenvalues).
    """
    gammas = GUARD_SHRINK.reshape((-1,) + (1,) * theta.ndim)
    candidates = prior + gammas * (theta - prior)
    first, _ = companion_from_theta(candidates[0], order)
    failing = ~(spectral_radius(first) <= bound)
    first_ok = np.zeros(failing.shape, dtype=np.intp)
    if np.any(failing):
        shrunk, _ = companion_from_theta(candidates[1:, failing], order)
        ok = spectral_radius(shrunk) <= bound
        ok[-1] = True
        first_ok[failing] = 1 + np.argmax(ok, axis=0)
    return np.take_along_axis(candidates, first_ok[None, ..., None, None], axis=0)[0]


def literal_transition(current, previous, observation, epsilon: float = 1e-12):
    """The paper's eq. (6)/(7) system matrix from the last two measurements.

    .. math:: \\hat A_k = C^+ z_k \\left(z_{k-1}^T G^{-1} z_{k-1}\\right)^{-1}
              z_{k-1}^T G^{-1} C, \\qquad G = C C^T,\\ C^+ = C^T G^{-1}

    Parameters
    ----------
    current, previous : ndarray, shape (..., p)
        :math:`z_k` and :math:`z_{k-1}`.
    observation : ndarray, shape (p, n)
        :math:`C`.
    epsilon : float
        Added to the scalar denominator so that :math:`z_{k-1} = 0` stays finite.

    Returns
    -------
    ndarray, shape (..., n, n)
    """
    gram_inv, _ = cholesky_inverse(observation @ observation.T, jitter=0.0)
    pseudo_inverse = observation.T @ gram_inv
    weighted_prev = previous @ gram_inv  # z_{k-1}^T G^{-1}
    denominator = np.einsum("...i,...i->...", weighted_prev, previous) + epsilon
    left = np.einsum("ij,...j->...i", pseudo_inverse, current)
    right = weighted_prev @ observation
    return left[..., :, None] * right[..., None, :] / denominator[..., None, None]
