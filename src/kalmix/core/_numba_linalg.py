"""Small dense algebra for K experts at once, experts last (numba; used by the compiled AKF and AR kernels).

The Cholesky factor, inverse and solve of the compiled kernels (their numpy spec: :mod:`kalmix.core.kalman`).

Every array here carries the expert index as its last axis (a structure of arrays:
``cov[r, c, k]`` is entry (r, c) of expert k's covariance), and every inner loop runs
over the experts with unit stride, so the compiler turns it into vector instructions
(4 or 8 experts per instruction). For each expert the operations, and their order,
are those of the scalar formulas of the numpy reference, so the numbers agree with it
to rounding.

``acc`` arguments are scratch rows of length K that hold running sums.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numba.core.extending import overload

from .compiled._cache import JIT as _JIT
from .compiled._cache import configure_cache

configure_cache()  # before any decorator below: the cache is keyed on every compiled source

jit = nb.njit(**_JIT)

# Half-width of the band around the guard's bound in which the Schur-Cohn test defers
# to the eigenvalues (relative); see ``stable_experts``.
GUARD_BAND = 1e-5
# The Schur-Cohn recursion loses its accuracy for clusters of more than this many roots
# near the bound (the prior puts p (degree + 1) roots at 1): beyond it, eigenvalues.
MAX_CLUSTER = 6


# ---------------------------------------------------------------- Cholesky
@jit
def cholesky_lower(source, m, work, acc, clamp):
    """Cholesky factors of the leading m x m blocks of ``source`` into the lower triangles of ``work``.

    ``source`` may be ``work`` itself (each entry is read before it is overwritten). With ``clamp`` a pivot
    below 0 (rounding, in a matrix that is positive semi-definite) is taken as 0, else it gives NaN.
    """
    experts = acc.shape[0]
    for j in range(m):
        for k in range(experts):
            acc[k] = source[j, j, k]
        for l in range(j):
            for k in range(experts):
                acc[k] -= work[j, l, k] * work[j, l, k]
        if clamp:
            for k in range(experts):
                work[j, j, k] = math.sqrt(max(acc[k], 0.0))
        else:
            for k in range(experts):
                work[j, j, k] = math.sqrt(acc[k])
        for i in range(j + 1, m):
            for k in range(experts):
                acc[k] = source[i, j, k]
            for l in range(j):
                for k in range(experts):
                    acc[k] -= work[i, l, k] * work[j, l, k]
            for k in range(experts):
                work[i, j, k] = acc[k] / work[j, j, k]


@jit
def cholesky_inverse(spd, m, jitter, work, lower_inv, inverse, acc):
    """:func:`kalmix.core.kalman.cholesky_inverse` of the leading m x m blocks (no log-determinant).

    ``spd`` is symmetrised and its diagonal raised by ``jitter`` times its mean diagonal.
    """
    experts = acc.shape[0]
    for k in range(experts):
        acc[k] = 0.0
    for i in range(m):
        for k in range(experts):
            acc[k] += spd[i, i, k]
    for i in range(m):
        for j in range(m):
            for k in range(experts):
                work[i, j, k] = 0.5 * (spd[i, j, k] + spd[j, i, k])
        for k in range(experts):
            work[i, i, k] += jitter * (acc[k] / m)
    cholesky_lower(work, m, work, acc, False)
    # L^{-1} by forward substitution
    for c in range(m):
        for i in range(m):
            if i < c:
                for k in range(experts):
                    lower_inv[i, c, k] = 0.0
                continue
            one = 1.0 if i == c else 0.0
            for k in range(experts):
                acc[k] = one
            for l in range(c, i):
                for k in range(experts):
                    acc[k] -= work[i, l, k] * lower_inv[l, c, k]
            for k in range(experts):
                lower_inv[i, c, k] = acc[k] / work[i, i, k]
    # S^{-1} = L^{-T} L^{-1}
    for i in range(m):
        for j in range(i, m):
            for k in range(experts):
                acc[k] = 0.0
            for l in range(j, m):
                for k in range(experts):
                    acc[k] += lower_inv[l, i, k] * lower_inv[l, j, k]
            for k in range(experts):
                inverse[i, j, k] = acc[k]
                inverse[j, i, k] = acc[k]


@jit
def cholesky_solve_rows(spd, m, rhs, rows, work, out, acc, clamp):
    """``out[r] = spd^{-1} rhs[r]`` for r < rows, for every expert (``spd`` positive definite; ``clamp``: see
    :func:`cholesky_lower`)."""
    experts = acc.shape[0]
    cholesky_lower(spd, m, work, acc, clamp)
    for i in range(m):  # L y = b
        for r in range(rows):
            for k in range(experts):
                acc[k] = rhs[r, i, k]
            for l in range(i):
                for k in range(experts):
                    acc[k] -= work[i, l, k] * out[r, l, k]
            for k in range(experts):
                out[r, i, k] = acc[k] / work[i, i, k]
    for i in range(m - 1, -1, -1):  # L^T x = y
        for r in range(rows):
            for k in range(experts):
                acc[k] = out[r, i, k]
            for l in range(i + 1, m):
                for k in range(experts):
                    acc[k] -= work[l, i, k] * out[r, l, k]
            for k in range(experts):
                out[r, i, k] = acc[k] / work[i, i, k]


# ---------------------------------------------------------------- stability of a companion matrix
@jit
def _poly_mul_add(entries, row_a, col_a, row_b, col_b, degree, sign, out, count):
    """``out += sign * a * b`` for the polynomials a = entries[row_a, col_a], b = entries[row_b, col_b].

    Polynomials of ``degree + 1`` coefficients, low order first. (Indices rather than
    views: a view costs a reference count, atomically, at every call.)
    """
    for i in range(degree + 1):
        for j in range(degree + 1):
            for k in range(count):
                out[i + j, k] += (sign * entries[row_a, col_a, i, k]) * entries[row_b, col_b, j, k]


@jit
def char_poly_small(theta, p, order, entries, minor, coef, count):
    """det(lambda I - A) of the block companion of ``theta`` (p, n + 1, K) for p <= 3, by cofactors.

    :math:`\\det(\\lambda I - A) = \\det(\\lambda^o I - \\sum_l \\Theta_l \\lambda^{o-l})`,
    a p x p determinant of polynomials of degree o; ``coef[e, k]`` multiplies
    :math:`\\lambda^e` for expert column k < ``count``.
    """
    n = order * p
    for i in range(p):
        for c in range(p):
            for e in range(order + 1):
                for k in range(count):
                    entries[i, c, e, k] = 0.0
            one = 1.0 if i == c else 0.0
            for k in range(count):
                entries[i, c, order, k] = one
            for lag in range(1, order + 1):
                for k in range(count):
                    entries[i, c, order - lag, k] -= theta[i, (lag - 1) * p + c, k]
    for e in range(n + 1):
        for k in range(count):
            coef[e, k] = 0.0
    if p == 1:
        for e in range(order + 1):
            for k in range(count):
                coef[e, k] = entries[0, 0, e, k]
    elif p == 2:
        _poly_mul_add(entries, 0, 0, 1, 1, order, 1.0, coef, count)
        _poly_mul_add(entries, 0, 1, 1, 0, order, -1.0, coef, count)
    else:
        for col in range(3):
            c1 = 1 if col == 0 else 0
            c2 = 1 if col == 2 else 2
            for e in range(2 * order + 1):
                for k in range(count):
                    minor[e, k] = 0.0
            _poly_mul_add(entries, 1, c1, 2, c2, order, 1.0, minor, count)
            _poly_mul_add(entries, 1, c2, 2, c1, order, -1.0, minor, count)
            sign = -1.0 if col == 1 else 1.0
            for i in range(order + 1):
                for e in range(2 * order + 1):
                    for k in range(count):
                        coef[i + e, k] += (sign * entries[0, col, i, k]) * minor[e, k]


@jit
def companion(theta, p, n, transition, offset):
    """Block companion matrix and drift of one expert's ``theta`` (p, n + 1)."""
    for i in range(n):
        for j in range(n):
            transition[i, j] = 0.0
        offset[i] = 0.0
    for i in range(p):
        for j in range(n):
            transition[i, j] = theta[i, j]
        offset[i] = theta[i, n]
    for i in range(n - p):
        transition[p + i, i] = 1.0


@jit
def char_poly(transition, p, n, power, product, coef):
    """Coefficients of det(lambda I - A) for one block companion A (Faddeev-LeVerrier).

    ``coef[k]`` multiplies lambda^k. Products A M use the shift structure of the rows
    below the first p (they cost p n^2 instead of n^3).
    """
    coef[n] = 1.0
    for i in range(n):
        for j in range(n):
            power[i, j] = 0.0
    for k in range(1, n + 1):
        # power <- A power + c_{n-k+1} I  (M_k), product <- A M_k
        for i in range(n):
            power[i, i] += coef[n - k + 1]
        trace = 0.0
        for i in range(p):
            for j in range(n):
                acc = 0.0
                for l in range(n):
                    acc += transition[i, l] * power[l, j]
                product[i, j] = acc
        for i in range(n - p):
            for j in range(n):
                product[p + i, j] = power[i, j]
        for i in range(n):
            trace += product[i, i]
        coef[n - k] = -trace / k
        for i in range(n):
            for j in range(n):
                power[i, j] = product[i, j]


@jit
def schur_cohn(coef, n, radius, work, saved, norm, inside, count):
    """Schur-Cohn: ``inside[k]`` = every root of ``sum_e coef[e, k] x^e`` lies strictly inside ``|x| < radius``.

    For the expert columns k < ``count``. The recursion runs to the end for every
    expert (no branch, so it vectorises); an expert that fails a step stays failed,
    whatever its later, meaningless, numbers.
    """
    scale = 1.0
    for e in range(n + 1):
        for k in range(count):
            work[e, k] = coef[e, k] * scale
        scale *= radius
    for k in range(count):
        inside[k] = True
    for m in range(n, 0, -1):
        for k in range(count):
            a0 = abs(work[0, k])
            am = abs(work[m, k])
            inside[k] = inside[k] & (a0 < am)
            norm[k] = 1.0 / (am + a0)
        for i in range(m + 1):
            for k in range(count):
                saved[i, k] = work[i, k]
        for i in range(m):
            for k in range(count):
                work[i, k] = (saved[m, k] * saved[i + 1, k] - saved[0, k] * saved[m - 1 - i, k]) * norm[k]


def radius_le_eig(theta, transition, p, n, bound, scratch, coef):
    """Spectral radius of the companion of one expert's ``theta`` <= ``bound``, from its eigenvalues.

    ``coef (n + 1, 1)`` holds the companion's characteristic polynomial where the caller computed it
    (``fast_guard``); unused here. A GPU has no eigenvalue routine: there the Schur-Cohn test on
    ``coef`` at exactly ``bound`` decides (:mod:`kalmix.core.compiled.gpu` registers it), which
    agrees with the eigenvalues except for a root within rounding of the bound.
    """
    companion(theta, p, n, transition, scratch)
    values = np.linalg.eigvals(transition[:n, :n].astype(np.complex128))
    largest = 0.0   # the modulus as sqrt(re^2 + im^2), as the spec computes it (numba's abs and numpy's differ)
    for value in values:
        largest = max(largest, value.real * value.real + value.imag * value.imag)
    return math.sqrt(largest) <= bound


@overload(radius_le_eig, target="cpu")
def _radius_le_eig_cpu(theta, transition, p, n, bound, scratch, coef):
    return radius_le_eig
