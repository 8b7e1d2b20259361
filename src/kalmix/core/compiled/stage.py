"""What the block driver's stages take besides their own parameters and state: a block's rows and outputs, named.

Every stage's compiled driver has one shape, ``kernel(lo, hi, params, state, ..., rows, out, scratch)``: targets
``lo .. hi - 1`` through the block's rows, reading ``rows``, writing ``out``, advancing ``state`` in place, with
``scratch`` (one target's work space, a tuple) given by the caller so that the driver allocates nothing. These
classes name the rows and outputs every family's driver shares; a driver's own parameters, state, rows and outputs
are its component's (:mod:`.kinematic`'s ``Constants``, the spec's state classes, :data:`.rules.COMPILED_RULES`,
:class:`.rules.Rows`, :class:`.screen.Rows`, :class:`.lead.Rows`). Arrays are
``(B, N, ...)`` over the block's rows and the call's targets; an optional output is an empty array.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["FamilyRows", "FamilyOut", "family_rows"]


class FamilyRows(NamedTuple):
    """A block's rows as every family's driver reads them."""

    z: np.ndarray             # (B, N, p) measurements
    times: np.ndarray         # (B, N) their times (a frame-based family does not read them)
    lengths: np.ndarray       # (N,) rows of each target in the block
    learn: np.ndarray         # (B, N) rows the experts learn
    restart: np.ndarray       # (B, N) rows the experts start again from
    ahead_times: np.ndarray   # (B, N) times of the forecasts made after each row, or (0, 0)
    horizon: int              # frames of those forecasts (a time-based family does not read it)


class FamilyOut(NamedTuple):
    """Where a family writes its experts' forecasts: the bank's buffers, from column ``offset``."""

    experts: np.ndarray   # (B, N, K_bank, p) the forecast of each row, made before it
    offset: int           # the family's first column
    ahead: np.ndarray     # (B, N, K_bank, p) the forecast made after each row for its ahead time, or (0, 0, 0, 0)


def family_rows(z, times, lengths, learn, restart, ahead_times, horizon) -> FamilyRows:
    """:class:`FamilyRows` with the types the compiled drivers are compiled for (one specialisation each: the
    engines and the compile warm-up build them here)."""
    return FamilyRows(z, times, lengths, learn, restart, ahead_times, int(horizon))
