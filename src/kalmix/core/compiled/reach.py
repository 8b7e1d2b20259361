"""Compiled one-step masks: the warm-up (:func:`kalmix.core.engine.warmed_up`) and the reach
(:func:`kalmix.core.engine.within_reach`): which experts the one-step weights leave out of a row.

:func:`sleep_cold` and :func:`sleep_beyond` are the rules on one target's row; :func:`kernel` runs
both over a block's rows, targets ``lo .. hi - 1``, on the CPU engine (targets in ranges on threads)
and the GPU staged engine (one GPU thread a target); the fused GPU kernel calls them on its rows.
The learned rows and the spans come from the glitch screen (its ``points``, and
:func:`.screen.last_learned`, the spec's :func:`kalmix.core.engine.span`).
"""

from __future__ import annotations

import math

import numba as nb

from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache

configure_cache()

__all__ = ["sleep_cold", "sleep_beyond", "kernel"]


@nb.njit(inline="always", **_JIT)
def sleep_cold(warm, x, points):
    """The spec's :func:`kalmix.core.engine.warmed_up` on one target's row ``x (K, p)``: the experts whose
    ``warm`` rows (:meth:`~kalmix.core.engine.Bank.warmup_rows`; empty: none) are more than the target's learned
    ``points`` sleep (NaN) if an expert with enough rows has a forecast."""
    k_count, p = x.shape
    if warm.shape[0] == 0:
        return
    ready = False
    cold = False
    for k in range(k_count):
        if points < warm[k]:
            cold = True
        else:
            finite = True
            for ci in range(p):
                finite = finite and math.isfinite(x[k, ci])
            ready = ready or finite
    if ready and cold:
        for k in range(k_count):
            if points < warm[k]:
                for ci in range(p):
                    x[k, ci] = math.nan


@nb.njit(inline="always", **_JIT)
def sleep_beyond(far, x, span, reach):
    """The spec's :func:`kalmix.core.engine.within_reach` on one target's row ``x (K, p)``: across a ``span`` over
    ``reach`` the ``far`` experts sleep (NaN) if an expert not far has a forecast."""
    if not span > reach:
        return
    k_count, p = x.shape
    near = False
    for k in range(k_count):
        if not far[k]:
            finite = True
            for ci in range(p):
                finite = finite and math.isfinite(x[k, ci])
            near = near or finite
    if near:
        for k in range(k_count):
            if far[k]:
                for ci in range(p):
                    x[k, ci] = math.nan


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, warm, far, reach, experts, points, times, last, lengths, out):
    """:func:`kalmix.core.engine.for_weights` over a block: ``out`` is ``experts`` with the experts asleep on the
    rows where the target's learned ``points`` are fewer than their ``warm`` rows (:func:`sleep_cold`), then the
    ``far`` experts on those whose span ``times - last`` is over the reach (:func:`sleep_beyond`; ``far``: the bank's
    :meth:`~kalmix.core.engine.Bank.far_experts`, none with an infinite ``reach``). Rows past a target's length are
    not written."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            for k in range(experts.shape[2]):
                for ci in range(experts.shape[3]):
                    out[t, j, k, ci] = experts[t, j, k, ci]
            sleep_cold(warm, out[t, j], points[t, j])
            sleep_beyond(far, out[t, j], times[t, j] - last[t, j], reach)
