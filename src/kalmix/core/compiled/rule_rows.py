"""The row helpers every compiled aggregation rule shares (:mod:`.rules`, :mod:`.boa`): which experts are awake,
a softmax over them, the share's floor, the mixture and the regrets of one target's row."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._cache import JIT as _JIT
from ._cache import configure_cache

configure_cache()

__all__ = ["awake_of", "softmax", "share_floor", "mix_of", "regrets"]


@nb.njit(inline="always", **_JIT)
def awake_of(x, awake):
    """Which experts' forecasts ``x (K, p)`` are finite; returns how many."""
    count = 0
    for k in range(x.shape[0]):
        ok = True
        for c in range(x.shape[1]):
            if not math.isfinite(x[k, c]):
                ok = False
        awake[k] = ok
        if ok:
            count += 1
    return count


@nb.njit(inline="always", **_JIT)
def softmax(logw, awake, w):
    top = -np.inf
    for k in range(w.shape[0]):
        if awake[k] and logw[k] > top:
            top = logw[k]
    if not math.isfinite(top):
        top = 0.0
    total = 0.0
    for k in range(w.shape[0]):
        w[k] = math.exp(logw[k] - top) if awake[k] else 0.0
        total += w[k]
    for k in range(w.shape[0]):
        w[k] = w[k] / total if total > 0 else 0.0


@nb.njit(inline="always", **_JIT)
def share_floor(w, awake, count, share):
    if share > 0:
        for k in range(w.shape[0]):
            w[k] = (1.0 - share) * w[k] + (share / max(count, 1) if awake[k] else 0.0)


@nb.njit(inline="always", **_JIT)
def mix_of(x, w, awake, out):
    for ci in range(x.shape[1]):
        acc = 0.0
        for k in range(x.shape[0]):
            if awake[k]:
                acc += w[k] * x[k, ci]
        out[ci] = acc


@nb.njit(inline="always", **_JIT)
def regrets(x, y, mix, awake, r, exact):
    """The linearised regrets ``r (K,)`` of the awake experts (0 for the others), or with ``exact`` the squared
    loss's own (:math:`\\lVert \\hat y - y \\rVert^2 - \\lVert x_k - y \\rVert^2`, the linearised one less
    :math:`\\lVert x_k - \\hat y \\rVert^2`); returns the largest squared one (inf if one overflows)."""
    biggest = 0.0
    for k in range(r.shape[0]):
        if awake[k]:
            acc = 0.0
            for ci in range(x.shape[1]):
                acc += (mix[ci] - y[ci]) * (mix[ci] - x[k, ci])
            r[k] = 2.0 * acc   # the whole regret (BOA's range bound takes it)
            if exact:
                far = 0.0
                for ci in range(x.shape[1]):
                    far += (x[k, ci] - mix[ci]) * (x[k, ci] - mix[ci])
                r[k] = r[k] - far
        else:
            r[k] = 0.0
        if not math.isfinite(r[k] * r[k]):
            biggest = np.inf
        elif r[k] * r[k] > biggest:
            biggest = r[k] * r[k]
    return biggest
