"""The block driver: a bank's rows, a block at a time, through its stages; one for the CPU and the GPU staged engines.

Per block of rows, every target of the call at once::

    glitch screen -> learning rows -> each family's experts -> reach -> rule (+ calibration) -> lead head

Each stage is a compiled driver ``kernel(lo, hi, params, state, ..., rows, out, scratch)`` over a range of
targets (:mod:`.stage`; :mod:`.screen`, :mod:`.masks`, the families' drivers (:mod:`.drivers`), :mod:`.reach`,
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

import functools
from typing import Callable, NamedTuple, Protocol

import numpy as np

from ..calibration import CalibrationState
from ..engine import Bank, BankState, EngineResult
from ..lead import LeadState
from ..screen import ScreenState
from . import lead as clead
from . import reach as creach
from . import rules as crules
from . import screen as cscreen
from . import stage
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
        """Host arrays, C-contiguous (a (named) tuple of them, nested, or one array) as the stages take them; scalars
        and None stay. (The CPU's are the very arrays: what a stage advances in place comes as fresh copies,
        :func:`fresh` and the drivers' ``pack``.)"""

    def host(self, tree):
        """:meth:`put`'s inverse: numpy arrays."""

    def nan(self, shape):
        """A float array of ``shape`` (targets on axis 1) filled with NaN."""

    def empty(self, shape, dtype=np.float64):
        """An uninitialised array (every target's rows are written before they are read)."""

    def scratch(self, make: Callable[[], tuple]):
        """A stage's scratch, from ``make()``: one target's fresh scratch arrays (a tuple)."""

    def launch(self, name: str, kernel, args: tuple, scratch=None) -> None:
        """``kernel(lo, hi, *args)`` over every target, or ``kernel(lo, hi, *args, scratch)`` with the targets'
        scratch tuple (``scratch`` from :meth:`scratch`)."""

    def each_family(self, run: Callable[[int], None], costs: list) -> None:
        """``run(i)`` for each family ``i`` (``costs[i]``: the rough relative cost of its row), in turn in the bank's
        order or side by side."""

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


class _Packed(NamedTuple):
    """A call's state as the stages advance it in place: fresh copies, where the backend keeps its arrays."""

    families: list
    rule: tuple
    calibration: CalibrationState
    screen: ScreenState
    lead_rule: tuple | None
    lead_calibration: CalibrationState | None
    lead_slots: tuple | None   # the lead head's due, pending, issued, candidates
    lead_blend: tuple | None   # the state of the lead head's blend (its rule's)


def _pack(bank: Bank, state: BankState, drivers, put) -> _Packed:
    families = [put(d.pack(family.params, fstate)) for d, family, fstate in zip(drivers, bank.families,
                                                                                 state.families)]
    head = state.lead
    lead = (None, None, None, None)
    if bank.lead is not None:
        lead = (put(pack_rule(bank, head.rule)), put(fresh(head.calibration)),
                put(fresh(clead.Slots(head.due, head.pending, head.issued, head.candidates))),
                put(pack_rule(bank, head.blend)))
    return _Packed(families, put(pack_rule(bank, state.rule)), put(fresh(state.calibration)), put(fresh(state.screen)),
                   *lead)


def _unpack(bank: Bank, packed: _Packed, state: BankState, drivers, host) -> BankState:
    families = [d.unpack(host(fs), fstate) for d, fs, fstate in zip(drivers, packed.families, state.families)]
    head = None
    if bank.lead is not None:
        due, pending, issued, candidates = host(packed.lead_slots)
        head = LeadState(unpack_rule(bank, host(packed.lead_rule)), CalibrationState(*host(packed.lead_calibration)),
                         due, pending, issued, unpack_rule(bank, host(packed.lead_blend)), candidates)
    return BankState(tuple(families), unpack_rule(bank, host(packed.rule)), ScreenState(*host(packed.screen)),
                     CalibrationState(*host(packed.calibration)), head)


class _Masks(NamedTuple):
    """A block's rows, ``(rows, N)`` each, as the stages pass them on: the screen's verdicts (``accept``,
    ``restart``, ``started``, ``cold``), spans (``before``, ``after``) and learned rows (``points_before``,
    ``points_after``: :func:`.screen.screen_block`), the rows
    that learn (``learned``, ``go``: :func:`.masks.learning_rows`), the lead head's ``keep``. Each target's rows
    are written before they are read."""

    accept: object
    restart: object
    started: object
    cold: object
    learned: object
    go: object
    keep: object
    before: object
    after: object
    points_before: object
    points_after: object

    @classmethod
    def allocate(cls, backend: Backend, block: int, n: int, lead: bool) -> _Masks:
        flag = lambda: backend.empty((block, n), np.bool_)  # noqa: E731
        return cls(flag(), flag(), flag(), flag(), flag(), flag(), flag() if lead else None,
                   backend.empty((block, n)), backend.empty((block, n)), backend.empty((block, n)),
                   backend.empty((block, n)))

    def first(self, rows: int) -> _Masks:
        return _Masks(*(None if a is None else a[:rows] for a in self))


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
    put, nan, empty = backend.put, backend.nan, backend.empty
    ahead_times, ahead_frames = with_lead(bank, times, ahead_times, ahead_frames)
    with_ahead = ahead_times is not None
    horizon = ahead_frames if with_ahead else 1
    empty4, empty3, empty2 = empty((0, 0, 0, 0)), empty((0, 0, 0)), empty((0, 0))
    z, times, learn = put(z), put(times), put(learn)
    gaps = put(np.zeros((t_count, n), dtype=bool) if gaps is None else gaps)
    if with_ahead:
        ahead_times = put(kernel_array(np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n))))

    # the parameters, the state and each stage's scratch
    drivers = [driver(family.kind) for family in bank.families]
    constants = [put(d.constants(family.params)) for d, family in zip(drivers, bank.families)]
    scratch = [backend.scratch(functools.partial(d.scratch, family.params, p))
               for d, family in zip(drivers, bank.families)]
    offsets = [cols.start for cols in bank.slices()]
    costs = [d.COST * family.n_experts for d, family in zip(drivers, bank.families)]
    packed = _pack(bank, state, drivers, put)
    rule_params = pack_rule_params(bank)
    lead_params = pack_rule_params(bank, bank.lead_rule_params) if lead is not None else None
    blend_params = pack_rule_params(bank, bank.blend_rule_params) if lead is not None else None
    rule_scratch = backend.scratch(functools.partial(crules.scratch, k, p))
    lead_scratch = backend.scratch(functools.partial(clead.scratch, k, p)) if lead is not None else None
    cal = pack_calibration(bank.calibration_params)
    screen = cscreen.constants(bank.screen_params)
    # the one-step masks (the spec's for_weights): none when no expert ever sleeps for the warm-up or a long step
    warm, far = bank.warmup_rows(), bank.far_experts()
    masked = warm is not None or far is not None
    warm = put(np.zeros(0) if warm is None else warm)
    far = put(np.zeros(k, dtype=np.bool_) if far is None else far)

    # the outputs
    forecasts, std = nan((t_count, n, p)), nan((t_count, n, p))
    ahead, ahead_std = (nan((t_count, n, p)), nan((t_count, n, p))) if with_ahead else (None, None)
    lead_out, lead_std = (nan((t_count, n, p)), nan((t_count, n, p))) if lead is not None else (None, None)
    covariance = nan((t_count, n, p, p)) if record_covariance else None
    lead_covariance = nan((t_count, n, p, p)) if record_covariance and lead is not None else None
    experts = nan((t_count, n, k, p)) if record_experts else None
    weights = nan((t_count, n, k)) if record_experts else None
    ahead_experts = nan((t_count, n, k, p)) if record_experts and with_ahead else None

    per_row = backend.block_targets * k * p * 8 * (2 if with_ahead else 1)
    block = int(max(1, min(t_count, backend.buffer_bytes // max(per_row, 1))))
    masks = _Masks.allocate(backend, block, n, lead is not None)
    with backend.timed():
        for begin in range(0, t_count, block):
            end = min(begin + block, t_count)
            rows = slice(begin, end)
            lens = put(np.clip(lengths - begin, 0, end - begin).astype(np.int64))
            zb, tb, ahead_b = z[rows], times[rows], ahead_times[rows] if with_ahead else empty2
            m = masks.first(end - begin)
            backend.launch("screen", cscreen.screen_block, (
                screen, packed.screen, cscreen.Rows(zb, tb, lens, learn[rows], gaps[rows]),
                cscreen.Verdicts(m.accept, m.restart, m.started, m.cold, m.before, m.after, m.points_before,
                                 m.points_after)))
            backend.launch("learning rows", learning_rows, (learn[rows], m.accept, m.restart, m.cold, lens, m.learned,
                                                            m.go))

            # each family writes its experts' forecasts of the block into its columns of one buffer
            buffer = experts[rows] if record_experts else nan((end - begin, n, k, p))
            ahead_buffer = empty4
            if with_ahead:
                ahead_buffer = ahead_experts[rows] if record_experts else nan((end - begin, n, k, p))
            family_rows = stage.family_rows(zb, tb, lens, m.learned, m.restart, ahead_b, horizon)

            def run_family(i):
                d, family = drivers[i], bank.families[i]
                work = d.work_arrays(end - begin, n, family.params, p, horizon > 1, empty)
                backend.launch(d.NAME, d.kernel, (constants[i], packed.families[i], family_rows,
                                                  stage.FamilyOut(buffer, offsets[i], ahead_buffer), work),
                               scratch[i])

            backend.each_family(run_family, costs)
            if observe is not None:
                observe(begin, end, buffer, ahead_buffer if with_ahead else None)

            # the one-step weights see the experts warmed up and within reach (the spec's for_weights); the lead
            # head all of them
            mixed, mixed_ahead = buffer, ahead_buffer
            if masked:
                mixed = empty(buffer.shape)
                backend.launch("reach", creach.kernel, (warm, far, float(bank.reach), buffer, m.points_before, tb,
                                                        m.before, lens, mixed))
                if with_ahead:
                    mixed_ahead = empty(ahead_buffer.shape)
                    backend.launch("reach", creach.kernel, (warm, far, float(bank.reach), ahead_buffer, m.points_after,
                                                            ahead_b, m.after, lens, mixed_ahead))
            backend.launch("rules", crules.kernel, (
                rule_params, packed.rule, cal, packed.calibration,
                crules.Rows(mixed, mixed_ahead, zb, lens, m.go, m.points_before, m.cold, m.restart),
                crules.Out(forecasts[rows], std[rows], covariance[rows] if record_covariance else empty4,
                           weights[rows] if record_experts else empty3, ahead[rows] if with_ahead else empty3,
                           ahead_std[rows] if with_ahead else empty3)), rule_scratch)
            if lead is not None:
                backend.launch("keep", both, (m.learned, m.started, lens, m.keep))
                backend.launch("lead", clead.kernel, (
                    lead_params, packed.lead_rule, blend_params, packed.lead_blend, cal, packed.lead_calibration,
                    packed.lead_slots,
                    clead.Rows(ahead_b, ahead_buffer, ahead[rows], zb, tb, lens, m.go, m.keep, m.restart, m.cold),
                    clead.Out(lead_out[rows], lead_std[rows], lead_covariance[rows] if record_covariance else empty4),
                    float(lead.tolerance)), lead_scratch)

    host = backend.host
    return EngineResult(host(forecasts), _unpack(bank, packed, state, drivers, host), host(ahead), host(experts),
                        host(weights), host(ahead_experts), host(std), host(ahead_std), host(lead_out),
                        host(lead_std), host(covariance), host(lead_covariance))
