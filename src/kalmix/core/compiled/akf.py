"""The bank engine's AKF family (:mod:`kalmix.core.families.akf`) over a block of rows, target by target.

Each target runs through :func:`kalmix.core._numba_kernels.advance_target` (the paper mixture's
compiled kernel) in pieces cut at its own restart rows, and its experts' predictions are written
into the bank's buffer one row later (the forecast of row t is the prediction made after row
t - 1). The same driver runs on the CPU engine (targets in ranges on threads) and on the GPU
engine (one thread per target): nothing in it allocates, so its scratch comes from the caller.
It takes the arguments of every family's driver (:mod:`.kinematic`) and ignores the times;
its host side (packing, the parts the engines use) is :mod:`.akf_driver`.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from .. import _numba_kernels as kernels
from ._cache import JIT as _JIT
from ._cache import configure_cache

configure_cache()

__all__ = ["Constants", "kernel", "scratch"]


class Constants(NamedTuple):
    """The family's parameters as :func:`kernel` takes them: packed as :func:`kalmix.core.fast.run_fast` packs
    them, with one new target's packed state (for the restart rows)."""

    params: tuple
    fresh: tuple


def scratch(state):
    """A target's scratch of :func:`kernel` for a packed state: float, int and bool buffers."""
    k_count, p, dim = state[6].shape[1], state[4].shape[1], state[6].shape[2]
    floats, ints, bools = kernels.scratch_size(k_count, p, dim // p)
    return np.empty(floats), np.empty(ints, dtype=np.int64), np.empty(bools, dtype=np.bool_)


@nb.njit(**_JIT)
def _copy_target(target, source, n):
    """``target[n] = source[0]`` for C-contiguous arrays with the target index first."""
    width = source.size
    flat_target = target.reshape(target.size)
    flat_source = source.reshape(width)
    for i in range(width):
        flat_target[n * width + i] = flat_source[i]


@nb.njit(**_JIT)
def _reset(n, state, fresh):
    """Target ``n`` of a packed AKF state as ``fresh`` (a packed state of one new target)."""
    _copy_target(state[0], fresh[0], n)
    _copy_target(state[1], fresh[1], n)
    _copy_target(state[2], fresh[2], n)
    _copy_target(state[3], fresh[3], n)
    _copy_target(state[4], fresh[4], n)
    _copy_target(state[5], fresh[5], n)
    _copy_target(state[6], fresh[6], n)
    _copy_target(state[7], fresh[7], n)
    _copy_target(state[8], fresh[8], n)
    _copy_target(state[9], fresh[9], n)
    _copy_target(state[10], fresh[10], n)
    _copy_target(state[11], fresh[11], n)
    _copy_target(state[12], fresh[12], n)
    _copy_target(state[13], fresh[13], n)
    _copy_target(state[14], fresh[14], n)
    _copy_target(state[15], fresh[15], n)
    _copy_target(state[16], fresh[16], n)
    _copy_target(state[17], fresh[17], n)
    _copy_target(state[18], fresh[18], n)
    _copy_target(state[19], fresh[19], n)


@nb.njit(**_JIT)   # with reference counting: the guard's eigenvalues (numpy) allocate
def kernel(lo, hi, constants, state, rows, forecasts, work, scratch):
    """The AKF family's experts over the rows of a block, targets ``lo .. hi - 1`` (the arguments of every family's
    driver, :mod:`.kinematic`).

    ``constants``: :class:`Constants`; ``state``: packed as :func:`kalmix.core.fast.run_fast` packs it, advanced in
    place. ``forecasts.experts`` receives the forecast of every row in columns ``forecasts.offset ..``, made
    before it; ``forecasts.ahead`` (if not empty) the forecast ``rows.horizon`` frames after each row (the times,
    the time-based families' clock, are not read). Only learned rows (``rows.learn``) are fed to the filters; a
    present row not learned advances them one frame. ``work`` holds the bank's work arrays of the block
    (:func:`.akf_driver.work_arrays`; each target uses its own column), ``scratch`` the target's float, int and
    bool buffers.
    """
    params, fresh = constants
    z, _, lengths, learn, restart, _, horizon = rows
    out, offset, ahead = forecasts
    fed, piece, predictions, recorded, later = work
    fbuf, ibuf, bbuf = scratch
    p = z.shape[2]
    k_count = recorded.shape[2]
    want_ahead = ahead.shape[0] > 0
    record_later = later.shape[0] > 0
    initialised = state[2]
    predicted = state[18]
    for n in range(lo, hi):
        rows = lengths[n]
        for t in range(rows):
            for i in range(p):
                fed[t, n, i] = z[t, n, i] if learn[t, n] else np.nan
        begin = 0
        while begin < rows:
            end = begin + 1
            while end < rows and not restart[end, n]:
                end += 1
            # a piece's first row is forecast by the state before it (the old one, on a restart row)
            if initialised[n]:
                for k in range(k_count):
                    for i in range(p):
                        out[begin, n, offset + k, i] = predicted[n, k, i]
            if restart[begin, n]:
                _reset(n, state, fresh)
            started = initialised[n]
            piece[n] = end - begin
            records = (predictions[begin:end], False, predictions[begin:begin], z[begin:begin, :, 0],
                       recorded[begin:begin], recorded[begin:begin], record_later, later[begin:end])
            kernels.advance_target(n, fed[begin:end], piece, horizon, params, state, records, recorded[begin:end],
                                   fbuf, ibuf, bbuf)
            for t in range(begin, end):
                started = started or learn[t, n]
                if not started:
                    continue
                for k in range(k_count):
                    for i in range(p):
                        if t + 1 < end:
                            out[t + 1, n, offset + k, i] = recorded[t, n, k, i]
                        if want_ahead:
                            ahead[t, n, offset + k, i] = later[t, n, k, i] if record_later else recorded[t, n, k, i]
            begin = end
