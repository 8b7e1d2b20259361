"""The block driver: a bank's rows, a block at a time, through its stages; one for the CPU and the GPU staged engines.

Per block of rows, every target of the call at once::

    glitch screen -> learning rows -> each family's experts -> reach -> rule (+ calibration) -> lead head

Each stage is a compiled driver ``kernel(lo, hi, *args, *scratch)`` over a range of targets
(:mod:`.screen`, :mod:`.masks`, the families' drivers (:mod:`.drivers`), :mod:`.reach`,
:mod:`.rules`, :mod:`.lead`). Families do not depend on the rule's output, so each family runs
through the whole block, writing its experts' forecasts into one ``(B, N, K, p)`` buffer at its
columns, before the rule runs over the block. The state carries over between blocks exactly,
so the result does not depend on the block size.

Where the arrays live and how a stage runs over the targets is the :class:`Backend`'s:

- the CPU engine's (:mod:`.engine`): numpy arrays, a stage over ranges of targets on threads, its
  scratch allocated a range at a time, the families side by side when the targets are too few to split;
- the GPU staged engine's (:mod:`.gpu_staged`): device arrays, a stage one kernel launch whose thread
  ``j`` runs the same driver with ``lo, hi = j, j + 1`` and its own scratch.

The numbers are the same on both: the same drivers, the same operations.
"""

from __future__ import annotations

from typing import Callable, Protocol

import numpy as np

from ..calibration import CalibrationState
from ..engine import Bank, BankState, EngineResult
from ..lead import LeadState
from ..screen import ScreenState
from . import lead as clead
from . import reach as creach
from . import rules as crules
from . import screen as cscreen
from .calibration import pack_params as pack_calibration
from .drivers import driver
from .masks import both, learning_rows

__all__ = ["Backend", "run_rows", "pack_rule", "unpack_rule", "pack_rule_params", "with_lead", "kernel_array",
           "fresh"]


class Backend(Protocol):
    """Where a call's arrays live and how a stage runs over its targets (see the module docstring)."""

    #: Targets of the call.
    n: int
    #: Upper bound of a block's expert forecasts (bytes).
    buffer_bytes: int
    #: Targets the block size is reckoned for (the call's, or a larger pass's that the call is a group of).
    block_targets: int

    def put(self, tree):
        """Host arrays that the call owns (fresh, C-contiguous), a (named) tuple of them, nested, or one array: as
        the stages take them (scalars and None stay)."""

    def host(self, tree):
        """:meth:`put`'s inverse: numpy arrays."""

    def nan(self, shape):
        """A float array of ``shape`` (targets on axis 1) filled with NaN."""

    def empty(self, shape, dtype=np.float64):
        """An uninitialised array (every target's rows are written before they are read)."""

    def scratch(self, make: Callable[[], tuple]):
        """A stage's scratch, from ``make()``: one target's fresh scratch arrays."""

    def launch(self, name: str, kernel, args: tuple, scratch=None) -> None:
        """``kernel(lo, hi, *args, *scratch)`` over every target (``scratch`` from :meth:`scratch`, or none)."""

    def each_family(self, run: Callable[[int], None], order: list) -> None:
        """``run(i)`` for each family index of ``order`` (the costliest first), in turn or side by side."""

    def timed(self):
        """A context manager around the block loop (the GPU's kernel clock)."""


def pack_rule(bank: Bank, state):
    """The rule's state as its kernels take it (its class in :data:`.rules.COMPILED_RULES`, the spec's fields):
    fresh C-contiguous float copies, advanced in place."""
    kind = crules.COMPILED_RULES[bank.rule].state
    return kind(**{name: np.array(getattr(state, name), dtype=np.float64, copy=True, order="C")
                   for name in kind._fields})


def unpack_rule(bank: Bank, packed):
    """The state :func:`pack_rule` packed, as the rule's spec state."""
    return bank.rule_module.State(**packed._asdict())


def pack_rule_params(bank: Bank, params=None):
    """The rule's parameters as its kernels take them (its class in :data:`.rules.COMPILED_RULES`) of ``params``,
    by default the bank's one-step rule's."""
    params = bank.rule_params if params is None else params
    kind = crules.COMPILED_RULES[bank.rule].params
    return kind(**{name: float(getattr(params, name)) for name in kind._fields})


def with_lead(bank: Bank, times, ahead_times, ahead_frames):
    """The ahead times and frames a run computes: the lead head's (by default at ``times`` + its lead) when the
    bank has one, else those asked for."""
    lead = bank.lead
    if lead is None:
        return ahead_times, ahead_frames
    return (times + lead.time if ahead_times is None else ahead_times), lead.frames


def kernel_array(a):
    """``a`` C-contiguous and writable (copied if not): a read-only array (a broadcast time column) is another
    type for numba, and would compile every kernel it reaches a second time."""
    return np.require(a, requirements=["C", "W"])


def fresh(arrays):
    """Fresh C-contiguous float copies of a (named) tuple of arrays, as the same type of tuple."""
    copies = [np.array(a, dtype=np.float64, copy=True, order="C") for a in arrays]
    return type(arrays)(*copies) if hasattr(arrays, "_fields") else tuple(copies)


def _family_cost(family) -> float:
    """Rough cost of a family's row (relative), to hand the costliest to a thread first."""
    return driver(family.kind).COST * family.n_experts


def run_rows(bank: Bank, backend: Backend, z, times, state: BankState, lengths, learn, gaps, ahead_times,
             ahead_frames: int, *, record_experts: bool = False, record_covariance: bool = False,
             observe=None) -> EngineResult:
    """The bank through the rows of ``z (T, N, p)`` at ``times (T, N)``, from ``state``, block by block.

    The inputs are host arrays, checked and C-contiguous (:func:`.engine.prepare`): ``lengths (N,)``,
    ``learn (T, N)`` (present rows only), ``gaps (T, N)`` restart rows or None, ``ahead_times``
    ``(T, N)``-broadcastable or None (the lead head's by default, :func:`with_lead`). With
    ``record_experts`` the result holds every expert's forecasts and weights, with
    ``record_covariance`` the mixture's covariances; ``observe(begin, end, experts, ahead_experts)``,
    if given, sees each block's expert forecasts (``ahead_experts`` None without ahead times).
    The result's arrays and state are on the host.
    """
    t_count, n, p = z.shape
    k = bank.n_experts
    lead = bank.lead
    put = backend.put
    ahead_times, ahead_frames = with_lead(bank, times, ahead_times, ahead_frames)
    with_ahead = ahead_times is not None
    horizon = ahead_frames if with_ahead else 1
    empty4, empty3, empty2 = backend.empty((0, 0, 0, 0)), backend.empty((0, 0, 0)), backend.empty((0, 0))
    z, times, learn = put(z), put(times), put(learn)
    gaps = put(np.zeros((t_count, n), dtype=bool) if gaps is None else gaps)
    if with_ahead:
        ahead_times = put(kernel_array(np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n))))

    # the state, packed as the stages advance it in place (fresh copies), and each stage's scratch
    drivers = [driver(family.kind) for family in bank.families]
    constants = [put(d.constants(family.params)) for d, family in zip(drivers, bank.families)]
    families = [put(d.pack(family.params, fstate)) for d, family, fstate in zip(drivers, bank.families,
                                                                                 state.families)]
    scratch = [backend.scratch(lambda d=d, family=family: d.scratch(family.params, p))
               for d, family in zip(drivers, bank.families)]
    offsets = [cols.start for cols in bank.slices()]
    rule, rule_params = put(pack_rule(bank, state.rule)), pack_rule_params(bank)
    rule_scratch = backend.scratch(lambda: crules.scratch(k, p))
    cal_args = pack_calibration(bank.calibration_params)
    initial_variance = float(bank.calibration_params.initial_variance)
    cal = put(fresh(state.calibration))
    if lead is not None:
        lead_rule, lead_params = put(pack_rule(bank, state.lead.rule)), pack_rule_params(bank, bank.lead_rule_params)
        lead_cal = put(fresh(state.lead.calibration))
        slots = put(fresh((state.lead.due, state.lead.pending, state.lead.issued)))
    screen = put(fresh(state.screen))
    sp = bank.screen_params
    screen_args = (float(sp.threshold), float(sp.max_rejects), float(sp.warmup), float(sp.window))
    far = bank.far_experts()   # None: no expert ever sleeps for a long step
    far = None if far is None else put(far)

    # the outputs
    nan = backend.nan
    forecasts, std = nan((t_count, n, p)), nan((t_count, n, p))
    ahead, ahead_std = (nan((t_count, n, p)), nan((t_count, n, p))) if with_ahead else (None, None)
    lead_out, lead_std = (nan((t_count, n, p)), nan((t_count, n, p))) if lead is not None else (None, None)
    covariance = nan((t_count, n, p, p)) if record_covariance else None
    lead_covariance = nan((t_count, n, p, p)) if record_covariance and lead is not None else None
    experts = nan((t_count, n, k, p)) if record_experts else None
    weights = nan((t_count, n, k)) if record_experts else None
    ahead_experts = nan((t_count, n, k, p)) if record_experts and with_ahead else None

    # a block's masks (written by the screen and masks.learning_rows, each target's rows before they are read)
    per_row = backend.block_targets * k * p * 8 * (2 if with_ahead else 1)
    block = int(max(1, min(t_count, backend.buffer_bytes // max(per_row, 1))))
    flag = lambda: backend.empty((block, n), np.bool_)  # noqa: E731
    accept_, restart_, started_, cold_, learned_, go_ = flag(), flag(), flag(), flag(), flag(), flag()
    keep_ = flag() if lead is not None else None
    before_, after_ = backend.empty((block, n)), backend.empty((block, n))
    costliest_first = sorted(range(len(bank.families)), key=lambda i: -_family_cost(bank.families[i]))
    with backend.timed():
        for begin in range(0, t_count, block):
            end = min(begin + block, t_count)
            rows = end - begin
            rows_of = slice(begin, end)
            lens = put(np.clip(lengths - begin, 0, rows).astype(np.int64))
            zb, tb = z[rows_of], times[rows_of]
            accept, restart, started, cold = accept_[:rows], restart_[:rows], started_[:rows], cold_[:rows]
            learned, go, before, after = learned_[:rows], go_[:rows], before_[:rows], after_[:rows]
            backend.launch("screen", cscreen.screen_block, (*screen_args, *screen, zb, tb, lens, learn[rows_of],
                                                            gaps[rows_of], accept, restart, started, cold, before,
                                                            after))
            backend.launch("learning rows", learning_rows, (learn[rows_of], accept, restart, cold, lens, learned, go))

            # each family writes its experts' forecasts of the block into its columns of one buffer
            buffer = experts[rows_of] if record_experts else nan((rows, n, k, p))
            ahead_buffer = empty4
            if with_ahead:
                ahead_buffer = ahead_experts[rows_of] if record_experts else nan((rows, n, k, p))
            ahead_b = ahead_times[rows_of] if with_ahead else empty2

            def run_family(i):
                d, family = drivers[i], bank.families[i]
                backend.launch(d.NAME, d.kernel, (*constants[i], *families[i], zb, tb, lens, learned, restart, buffer,
                                                  offsets[i], ahead_b, ahead_buffer, horizon,
                                                  *d.work_arrays(rows, n, family.params, p, horizon > 1,
                                                                 backend.empty)), scratch[i])

            backend.each_family(run_family, costliest_first)
            if observe is not None:
                observe(begin, end, buffer, ahead_buffer if with_ahead else None)

            # the one-step weights see the experts within reach (the spec's within_reach); the lead head all of them
            mixed, mixed_ahead = buffer, ahead_buffer
            if far is not None:
                mixed = backend.empty(buffer.shape)
                backend.launch("reach", creach.kernel, (far, float(bank.reach), buffer, tb, before, lens, mixed))
                if with_ahead:
                    mixed_ahead = backend.empty(ahead_buffer.shape)
                    backend.launch("reach", creach.kernel, (far, float(bank.reach), ahead_buffer, ahead_b, after, lens,
                                                            mixed_ahead))
            backend.launch("rules", crules.kernel, (
                rule_params, rule, *cal_args, *cal, mixed, zb, lens, go, forecasts[rows_of], std[rows_of],
                covariance[rows_of] if record_covariance else empty4, weights[rows_of] if record_experts else empty3,
                mixed_ahead, ahead[rows_of] if with_ahead else empty3, ahead_std[rows_of] if with_ahead else empty3,
                cold, restart, initial_variance), rule_scratch)
            if lead is not None:
                backend.launch("keep", both, (learned, started, lens, keep_[:rows]))
                backend.launch("lead", clead.kernel, (
                    lead_params, lead_rule, *cal_args, *lead_cal, ahead_b, float(lead.tolerance), *slots, ahead_buffer,
                    zb, tb, lens, go, keep_[:rows], restart, lead_out[rows_of], lead_std[rows_of],
                    lead_covariance[rows_of] if record_covariance else empty4, cold, initial_variance), rule_scratch)

    host = backend.host
    families = [d.unpack(host(packed), fstate) for d, packed, fstate in zip(drivers, families, state.families)]
    head = None
    if lead is not None:
        head = LeadState(unpack_rule(bank, host(lead_rule)), CalibrationState(*host(lead_cal)), *host(slots))
    final = BankState(tuple(families), unpack_rule(bank, host(rule)), ScreenState(*host(screen)),
                      CalibrationState(*host(cal)), head)
    return EngineResult(host(forecasts), final, host(ahead), host(experts), host(weights), host(ahead_experts),
                        host(std), host(ahead_std), host(lead_out), host(lead_std), host(covariance),
                        host(lead_covariance))
