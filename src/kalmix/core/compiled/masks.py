"""Which rows of a block learn, from the glitch screen's verdicts: the masks between the block's stages.

Drivers over targets like the others (``kernel(lo, hi, ...)``, targets ``lo .. hi - 1``, each
target's rows up to its length), so the CPU engine runs them over ranges of targets on threads
and the GPU staged engine one GPU thread a target (:mod:`.block`).
"""

from __future__ import annotations

import numba as nb

from ._cache import KERNEL_JIT, configure_cache

configure_cache()

__all__ = ["learning_rows", "both"]


@nb.njit(**KERNEL_JIT)
def learning_rows(lo, hi, learn, accept, restart, cold, lengths, learned, go):
    """The rows the experts learn, ``learned = learn & accept`` (present, asked for, not a glitch), and those
    the rule and the calibration learn, ``go = learned & ~restart & ~cold``."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            learned[t, j] = learn[t, j] and accept[t, j]
            go[t, j] = learned[t, j] and not restart[t, j] and not cold[t, j]


@nb.njit(**KERNEL_JIT)
def both(lo, hi, a, b, lengths, out):
    """``out = a & b`` on the targets' rows."""
    for j in range(lo, hi):
        for t in range(lengths[j]):
            out[t, j] = a[t, j] and b[t, j]
