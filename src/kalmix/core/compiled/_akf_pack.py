"""An AKF family packed for its compiled driver (:mod:`.akf`): parameters, state and work arrays.

Host-side code shared by the CPU engine (:mod:`.engine`), the GPU engine (:mod:`.gpu_staged`) and
the compile warm-up (:mod:`._warm`).
"""

from __future__ import annotations

import numpy as np

from ..families import akf
from ..fast import pack_params, pack_state

__all__ = ["pack_akf", "akf_work"]

#: Per AKF family parameters, the packed parameters and one new target's packed state (the kernels only read
#: them): building them anew took ~20 % of a live feed's ``step_row`` (one row of one track a call). Keyed on
#: the parameters object: parameters are values, not changed in place (see :class:`kalmix.core.engine.Bank`).
_PACKED: dict = {}


def pack_akf(params, state):
    """An AKF family's parameters and one new target's state (both read only, kept per ``params``) and its
    state (fresh copies, advanced in place), packed for :mod:`.akf`."""
    entry = _PACKED.get(id(params))
    if entry is None or entry[0] is not params:   # (the entry holds params: its id is not reused meanwhile)
        if len(_PACKED) >= 32:
            _PACKED.clear()
        entry = _PACKED[id(params)] = (params, pack_params(params),
                                       pack_state(akf.init_state(params, 1, params.measurement_dim)))
    return entry[1], pack_state(state), entry[2]


def akf_work(rows: int, n: int, k: int, p: int, later: bool, allocate=np.empty):
    """The AKF driver's work arrays of a block (fed, piece, predictions, recorded, later), by ``allocate(shape,
    dtype)``; each target's rows are written before they are read."""
    return (allocate((rows, n, p), np.float64), allocate((n,), np.int64), allocate((rows, n, p), np.float64),
            allocate((rows, n, k, p), np.float64), allocate((rows, n, k, p) if later else (0, 0, 0, 0), np.float64))
