"""Compiled reach (:func:`kalmix.core.engine.within_reach`): across a long step only the long-step experts forecast.

:func:`sleep_beyond` is the rule on one target's row; :func:`kernel` runs it over a block's rows,
targets ``lo .. hi - 1``, on the CPU engine (targets in ranges on threads) and the GPU staged engine
(one GPU thread a target); the fused GPU kernel calls :func:`sleep_beyond` on its rows. The spans
come from the glitch screen (:func:`.screen.last_learned`, the spec's :func:`kalmix.core.engine.span`).
"""

from __future__ import annotations

import math

import numba as nb

from ._cache import JIT as _JIT
from ._cache import KERNEL_JIT, configure_cache

configure_cache()

__all__ = ["sleep_beyond", "kernel"]


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
def kernel(lo, hi, far, reach, experts, times, last, lengths, out):
    """:func:`kalmix.core.engine.within_reach` over a block: ``out`` is ``experts`` with the ``far`` experts
    asleep on the rows whose span ``times - last`` is over the reach (``far``: the bank's
    :meth:`~kalmix.core.engine.Bank.far_experts`). Rows past a target's length are not written."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            for k in range(experts.shape[2]):
                for ci in range(experts.shape[3]):
                    out[t, j, k, ci] = experts[t, j, k, ci]
            sleep_beyond(far, out[t, j], times[t, j] - last[t, j], reach)
