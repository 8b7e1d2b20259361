"""The predictors a user would pick instead of kalmix, each tuned fairly on the same tuning part.

Every peer is a row of ``kalmix evaluate`` and follows one convention.

Input (one track segment)
    ``values`` (T, p) floats, p in 1..3; a row with a NaN is a missing measurement (the
    peer only predicts, it does not learn). ``times`` (T,) strictly increasing, in the
    time column's units.

``predict(values, times, params, horizon=1) -> (T, p)``
    Row ``t`` is the prediction of the measurement at row ``t + horizon`` (at time
    ``times[t + horizon]``, which a file knows), made from rows ``<= t`` only: strictly
    causal, and ``horizon``-step forecasts are open loop (no measurement after row ``t``).
    Rows ``t >= T - horizon`` and rows before the first valid measurement are NaN.

``tune(segments, *, unit, time_unit) -> params``
    ``segments`` is a list of ``(values, times, mask)``; ``mask`` (T,) bool marks the
    tuning part: a candidate is scored by the RMS of its one-step errors at the rows whose
    *target* row is in the mask (each segment is cut after its last mask row; the peer
    still runs from the segment's first row). ``unit`` is a length scale of the data
    (the measurement-noise size: grids are multiples of ``unit**2``), ``time_unit`` the
    typical sampling interval. Budget, the same order for every peer: a grid of at most
    ~70 candidates, or maximum likelihood (statsmodels). Returns a JSON-serialisable dict
    of numbers, with the tuning RMS of the chosen candidate under ``"tuning_rms"``.

:data:`PEERS` maps a name to a :class:`Peer`. ``Peer.max_rows`` is set for the peers
that cannot keep up with ~500k rows in a few minutes, the IMM and MMAE: every peer steps
all its segments (and, when tuning, all its candidates) at once, one step per row, and the
multiple-model peers' steps are the costliest, so a single long segment is their slow case
(``python -m benchmarks.peer_models_timing`` times every peer). The capped peers are
evaluated on the first ``n`` rows of every segment, the largest ``n`` that keeps the total
within ``max_rows`` (:func:`row_budget`, deterministic). The tuning of the peers that
reproduce a library's loop (filterpy, river, padasip) scores each candidate on at most ``TUNE_ROWS`` rows
chosen the same way from the tuning parts (a constant of each module). ``Peer.predict_many`` (when set) runs a list
of ``(values, times)`` in one batched pass with the same results as ``predict`` on each.

Peers (modules):

- ``cv_dt``, ``ca_dt`` (:mod:`.kinematic`): CV / CA Kalman filters with the real Δt, numpy,
  all 68 grid candidates in one batched pass;
- ``imm_dt``, ``mmae_dt`` (:mod:`.multiple_model`): filterpy's IMM (CV + CA) and MMAE bank
  (CV filters at several ``q``), real Δt, their equations batched in numpy (checked against
  filterpy);
- ``holt_winters`` (:mod:`.holt_winters`): river's Holt-Winters (level + trend), frame-based;
- ``rls_ar`` (:mod:`.rls_ar`): padasip's RLS as an adaptive AR model of the velocity;
- ``ucm_llt`` (:mod:`.ucm`): statsmodels' local linear trend, variances by maximum
  likelihood, frame-based.

Optional packages: filterpy (extra ``peers``), river, padasip, statsmodels (extra
``baselines``); each is imported inside the functions that need it (``Peer.needs``).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Callable

from . import holt_winters, kinematic, multiple_model, rls_ar, ucm
from ._common import row_budget

__all__ = ["Peer", "PEERS", "row_budget", "available"]


@dataclass(frozen=True)
class Peer:
    """One peer: its tuning and prediction functions (module docstring for the convention)."""

    name: str
    tune: Callable[..., dict]
    predict: Callable[..., object]
    needs: tuple[str, ...] = ()
    max_rows: int | None = None
    predict_many: Callable[..., list] | None = None


PEERS: dict[str, Peer] = {peer.name: peer for peer in (
    Peer("cv_dt", kinematic.tune_cv, kinematic.predict_cv, predict_many=kinematic.predict_many_cv),
    Peer("ca_dt", kinematic.tune_ca, kinematic.predict_ca, predict_many=kinematic.predict_many_ca),
    Peer("imm_dt", multiple_model.tune_imm, multiple_model.predict_imm, ("filterpy",), max_rows=50_000,
         predict_many=multiple_model.predict_many_imm),
    Peer("mmae_dt", multiple_model.tune_mmae, multiple_model.predict_mmae, ("filterpy",), max_rows=50_000,
         predict_many=multiple_model.predict_many_mmae),
    Peer("holt_winters", holt_winters.tune, holt_winters.predict, ("river",), predict_many=holt_winters.predict_many),
    Peer("rls_ar", rls_ar.tune, rls_ar.predict, ("padasip",), predict_many=rls_ar.predict_many),
    Peer("ucm_llt", ucm.tune, ucm.predict, ("statsmodels",)),
)}


def available(peer: Peer | str) -> bool:
    """Whether every package that ``peer`` needs is installed."""
    if isinstance(peer, str):
        if peer not in PEERS:
            raise ValueError(f"peer: expected one of {', '.join(PEERS)}, got {peer!r}")
        peer = PEERS[peer]
    return all(importlib.util.find_spec(name) is not None for name in peer.needs)
