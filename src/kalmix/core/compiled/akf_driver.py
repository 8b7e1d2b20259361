"""The AKF family's driver (:mod:`.akf`'s kernel) with its host side: parameters, state and work arrays packed.

The parts every family's driver has (:mod:`.kinematic` lists them), used alike by the CPU engine
(:mod:`.engine`), the GPU staged engine (:mod:`.gpu_staged`) and the compile warm-up (:mod:`._warm`).
They are apart from the kernel's module because they pack with :mod:`kalmix.core.fast`, which the
compiled cache is not keyed on (the kernel's module imports only what it compiles).
"""

from __future__ import annotations

import numpy as np

from ..families import akf
from ..fast import fast_guard, pack_params, pack_state
from .akf import Constants, kernel
from .akf import scratch as _packed_scratch

__all__ = ["COST", "NAME", "COMPILE_APART", "MAX_GPU_STATE", "constants", "pack", "unpack", "scratch", "work_arrays",
           "check_gpu", "kernel"]

#: Relative cost of an expert's row (the engine hands the costliest family to a thread first).
COST = 4.0
#: The GPU staged engine's name for this family's stage.
NAME = "akf"
#: A fresh install compiles this kernel (most of the default bank's compile time) in a second process while
#: the first compiles the others (:mod:`._warm`).
COMPILE_APART = True
#: Largest AKF state (order x coordinates) the GPU's guard takes (its scratch is fixed-size there).
MAX_GPU_STATE = 32

#: Per AKF family parameters, the packed parameters and one new target's packed state (the kernels only read
#: them): building them anew took ~20 % of a live feed's ``step_row`` (one row of one track a call). Keyed on
#: the parameters object: parameters are values, not changed in place (see :class:`kalmix.core.engine.Bank`).
_PACKED: dict = {}


def constants(params) -> Constants:
    """The family's packed parameters and one new target's packed state (both read only, kept per ``params``),
    as :func:`kernel` takes them."""
    entry = _PACKED.get(id(params))
    if entry is None or entry[0] is not params:   # (the entry holds params: its id is not reused meanwhile)
        if len(_PACKED) >= 32:
            _PACKED.clear()
        entry = _PACKED[id(params)] = (params, Constants(
            pack_params(params), pack_state(akf.init_state(params, 1, params.measurement_dim))))
    return entry[1]


def pack(params, state) -> tuple:
    """The state as :func:`kernel` advances it in place: a packed tuple (fresh copies)."""
    return pack_state(state)


def unpack(packed, like):
    """The state :func:`pack` packed, as the family's state class (that of ``like``)."""
    return type(like)(*packed)


def scratch(params, p: int) -> tuple:
    """One target's scratch of :func:`kernel`: float, int and bool buffers."""
    return _packed_scratch(constants(params).fresh)


def work_arrays(rows: int, n: int, params, p: int, later: bool, allocate=np.empty) -> tuple:
    """The kernel's work arrays of a block (fed, piece, predictions, recorded, later), by ``allocate(shape,
    dtype)``; each target's rows are written before they are read. ``later``: forecasts more than a frame ahead
    are asked for."""
    k = params.n_experts
    return (allocate((rows, n, p), np.float64), allocate((n,), np.int64), allocate((rows, n, p), np.float64),
            allocate((rows, n, k, p), np.float64), allocate((rows, n, k, p) if later else (0, 0, 0, 0), np.float64))


def check_gpu(params) -> None:
    """``ValueError`` when the GPU cannot run the family: a state over :data:`MAX_GPU_STATE`, or a guard that
    needs eigenvalues (a prior with more than ``MAX_CLUSTER`` roots at 1)."""
    if params.state_dim > MAX_GPU_STATE:
        raise ValueError(f"backend 'gpu': an AKF family's state (order x coordinates) is at most {MAX_GPU_STATE} "
                         f"there, got {params.state_dim}; use the CPU engine")
    if params.dynamics == "rls" and not fast_guard(params):
        raise ValueError("backend 'gpu': this AKF family's guard needs eigenvalues (its prior puts more than "
                         "6 roots at 1), which the GPU has not; use the CPU engine or a lower AKF order")
