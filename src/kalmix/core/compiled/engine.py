"""The compiled loop over time of a bank: :func:`kalmix.core.engine.run` with the same numbers, fast.

Families do not depend on the rule's output, so a block of rows is run family by
family (each writes its experts' forecasts into one ``(B, N, K, p)`` buffer), then the
rule runs over the block. Blocks are sized so the buffer stays under
:data:`BUFFER_BYTES`; the state carries over between blocks exactly, so the result does
not depend on the block size.
"""

from __future__ import annotations

import threading

import numpy as np

from ..calibration import CalibrationState
from ..engine import (Bank, BankState, EngineResult, check_restart, check_run_arguments, check_run_options,
                      init_bank_state, tree_map)
from ..lead import LeadState
from ..screen import ScreenState
from . import lead as clead
from . import reach as creach
from . import rules as crules
from .calibration import pack_params as pack_calibration
from . import screen as cscreen
from ._threads import families_in_parallel, group_size, over_groups, over_targets
from ._notice import watch as watch_compiles
from ._warm import compile_ahead
from .drivers import driver

__all__ = ["run", "BUFFER_BYTES", "pack_rule", "unpack_rule", "pack_rule_params"]

#: Upper bound of the per-block expert buffer(s): large enough that the per-block Python work is small beside
#: the kernels' (below a few MiB it is not), small enough to stay a modest share of memory.
BUFFER_BYTES = 16 * 2**20
#: More targets than this are run in groups of this many, each through all its rows: a group's state
#: (~0.2 MB a target for the default bank) stays in the caches from row to row, and the groups run on
#: threads (each whole on one thread, so its Python work overlaps with the others' kernels). Fewer targets
#: run in smaller groups when that keeps the threads busier (:func:`._threads.group_size`).
TARGET_GROUP = 256

#: Fewest target-rows for which a call over few targets runs the families side by side on threads.
#: Below it, handing the families to the threads costs more than it saves. A live stream steps one row a
#: call.
SIDE_BY_SIDE_MIN_ROWS = 16


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


def prepare(bank: Bank, measurements, times, state, lengths, learn):
    """Contiguous float inputs, a fresh state if none, lengths, and the rows to learn (present ones only)."""
    z, times, lengths = check_run_arguments(bank, measurements, times, state, lengths)
    learn, _, _ = check_run_options(z.shape[:2], learn, None, 1)
    z = _kernel_array(z)
    t_count, n, _ = z.shape
    times = _kernel_array(times)
    state = init_bank_state(bank, n) if state is None else state
    lengths = (np.full(n, t_count, dtype=np.int64) if lengths is None
               else _kernel_array(np.asarray(lengths, dtype=np.int64)))
    present = np.isfinite(z).all(axis=-1) & (np.arange(t_count)[:, None] < lengths[None, :])
    learn = present if learn is None else (np.asarray(learn, dtype=bool) & present)
    return z, times, state, lengths, learn


def _kernel_array(a):
    """``a`` C-contiguous and writable (copied if not): a read-only array (a broadcast time column) is another
    type for numba, and would compile every kernel it reaches a second time."""
    return np.require(a, requirements=["C", "W"])


def _family_cost(family) -> float:
    """Rough cost of a family's row (relative), to hand the costliest to a thread first."""
    return driver(family.kind).COST * family.n_experts


def _copy(state):
    return type(state)(*(np.array(x, dtype=np.float64, copy=True, order="C") for x in state))


def run(bank: Bank, measurements, times, state: BankState | None = None, *, lengths=None, learn=None,
        ahead_times=None, ahead_frames: int = 1, record_experts: bool = False, score=None,
        score_ahead=None, record_covariance: bool = False, restart=None, _block_targets=None) -> EngineResult:
    """Same arguments and result as :func:`kalmix.core.engine.run`.

    With ``score (T, N)`` (and ``score_ahead``) bool masks, the result's ``experts`` is
    replaced by the per-target, per-expert sums of squared errors over the scored rows,
    ``(N, K)``, and ``weights`` by their counts (memory independent of T; what the
    best-expert-in-hindsight needs), ``expert_ahead`` likewise for the ahead forecasts.
    (``_block_targets``: for :func:`_run_groups`, see there.)
    """
    z, times, state, lengths, learn = prepare(bank, measurements, times, state, lengths, learn)
    _, ahead_times, ahead_frames = check_run_options(z.shape[:2], None, ahead_times, ahead_frames)
    watch_compiles()   # a fresh install: say so on stderr while the kernels compile (._notice)
    compile_ahead(bank, run)   # a fresh install: the AKF kernel compiles in a second process meanwhile
    t_count, n, p = z.shape
    size = group_size(n, TARGET_GROUP)
    if size is not None:
        return _run_groups(bank, z, times, state, lengths, learn, ahead_times, ahead_frames, record_experts, score,
                           score_ahead, record_covariance, restart, size)
    gaps = check_restart(restart, (t_count, n))
    if gaps is None:
        gaps = np.zeros((t_count, n), dtype=bool)
    k = bank.n_experts
    lead = bank.lead
    ahead_times, ahead_frames = with_lead(bank, times, ahead_times, ahead_frames)
    with_ahead = ahead_times is not None
    if with_ahead:
        ahead_times = _kernel_array(np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n)))

    drivers = [driver(family.kind) for family in bank.families]
    constants = [d.constants(family.params) for d, family in zip(drivers, bank.families)]
    families = [d.pack(family.params, fstate) for d, family, fstate in zip(drivers, bank.families, state.families)]
    horizon = ahead_frames if with_ahead else 1
    rule = pack_rule(bank, state.rule)
    rule_params = pack_rule_params(bank)
    cal_args = pack_calibration(bank.calibration_params)
    initial_variance = float(bank.calibration_params.initial_variance)
    cal = _copy(state.calibration)
    if lead is not None:
        lead_rule = pack_rule(bank, state.lead.rule)
        lead_params = pack_rule_params(bank, bank.lead_rule_params)
        lead_cal = _copy(state.lead.calibration)
        due = np.array(state.lead.due, dtype=np.float64, copy=True, order="C")
        pending = np.array(state.lead.pending, dtype=np.float64, copy=True, order="C")
        issued = np.array(state.lead.issued, dtype=np.float64, copy=True, order="C")
        candidates = np.array(state.lead.candidates, dtype=np.float64, copy=True, order="C")
        blend = pack_rule(bank, state.lead.blend)
        blend_params = pack_rule_params(bank, bank.blend_rule_params)
    scr = ScreenState(*(np.array(x, dtype=np.float64, copy=True, order="C") for x in state.screen))
    sp = bank.screen_params
    screen_args = (float(sp.threshold), float(sp.max_rejects), float(sp.warmup), float(sp.window))

    nan = lambda *shape: np.full(shape, np.nan)  # noqa: E731
    forecasts, std = nan(t_count, n, p), nan(t_count, n, p)
    ahead, ahead_std = (nan(t_count, n, p), nan(t_count, n, p)) if with_ahead else (None, None)
    lead_out, lead_std = (nan(t_count, n, p), nan(t_count, n, p)) if lead is not None else (None, None)
    covariance = nan(t_count, n, p, p) if record_covariance else None
    lead_covariance = nan(t_count, n, p, p) if record_covariance and lead is not None else None
    experts_out = weights_out = ahead_experts_out = None
    if record_experts:
        experts_out = nan(t_count, n, k, p)
        weights_out = nan(t_count, n, k)
        ahead_experts_out = nan(t_count, n, k, p) if with_ahead else None
    sums = [np.zeros((n, k)), np.zeros((n, k)), np.zeros((n, k)), np.zeros((n, k))] if score is not None else None

    offsets = [cols.start for cols in bank.slices()]
    far = bank.far_experts()   # None: no expert ever sleeps for a long step
    costliest_first = sorted(range(len(bank.families)), key=lambda i: -_family_cost(bank.families[i]))
    side_by_side = families_in_parallel(n) and t_count * n >= SIDE_BY_SIDE_MIN_ROWS
    per_row = (n if _block_targets is None else _block_targets) * k * p * 8 * (2 if with_ahead else 1)
    block = int(max(1, min(t_count, BUFFER_BYTES // max(per_row, 1))))
    empty4, empty3, empty2 = np.empty((0, 0, 0, 0)), np.empty((0, 0, 0)), np.empty((0, 0))
    for begin in range(0, t_count, block):
        end = min(begin + block, t_count)
        rows = end - begin
        lens = np.clip(lengths - begin, 0, rows).astype(np.int64)
        zb, tb = z[begin:end], times[begin:end]
        accept = np.zeros((rows, n), dtype=bool)
        restart = np.zeros((rows, n), dtype=bool)
        started = np.zeros((rows, n), dtype=bool)
        cold = np.zeros((rows, n), dtype=bool)
        before, after = np.full((rows, n), np.nan), np.full((rows, n), np.nan)
        over_targets(cscreen.screen_block, n, *screen_args, *scr, zb, tb, lens, learn[begin:end], gaps[begin:end],
                     accept, restart, started, cold, before, after)
        lb = learn[begin:end] & accept
        buffer = np.full((rows, n, k, p), np.nan)
        ahead_buffer = np.full((rows, n, k, p), np.nan) if with_ahead else None
        ahead_b = ahead_times[begin:end] if with_ahead else empty2

        def run_family(i):
            d, family = drivers[i], bank.families[i]
            over_targets(d.run_block, n, *constants[i], *families[i], zb, tb, lens, lb, restart, buffer, offsets[i],
                         ahead_b, ahead_buffer if with_ahead else empty4, horizon,
                         *d.work_arrays(rows, n, family.params, p, horizon > 1))

        # Families are independent and write their own columns of the buffers: with too few targets to split
        # (one stream), they run side by side on the threads instead, the costliest first.
        if side_by_side:
            over_groups(run_family, costliest_first)
        else:
            for i in range(len(bank.families)):
                run_family(i)
        if record_experts:
            experts_out[begin:end] = buffer
            if with_ahead:
                ahead_experts_out[begin:end] = ahead_buffer
        if sums is not None:
            _accumulate(sums[0], sums[1], buffer, zb, score[begin:end])
            if with_ahead and score_ahead is not None:
                _accumulate_ahead(sums[2], sums[3], ahead_buffer, z, begin, end, ahead_frames, score_ahead)
        # the one-step weights see the experts within reach (the spec's within_reach); the lead head all of them
        mixed, mixed_ahead = buffer, ahead_buffer
        if far is not None:
            mixed = np.empty_like(buffer)
            over_targets(creach.kernel, n, far, float(bank.reach), buffer, tb, before, lens, mixed)
            if with_ahead:
                mixed_ahead = np.empty_like(ahead_buffer)
                over_targets(creach.kernel, n, far, float(bank.reach), ahead_buffer, ahead_b, after, lens,
                             mixed_ahead)
        w_block = np.full((rows, n, k), np.nan) if record_experts else empty3
        go = lb & ~restart & ~cold
        over_targets(crules.run_block, n, rule_params, rule, *cal_args, *cal, mixed, zb, lens, go,
                     forecasts[begin:end], std[begin:end], covariance[begin:end] if record_covariance else empty4,
                     w_block, mixed_ahead if with_ahead else empty4, ahead[begin:end] if with_ahead else empty3,
                     ahead_std[begin:end] if with_ahead else empty3, cold, restart, initial_variance)
        if lead is not None:
            over_targets(clead.run_block, n, lead_params, lead_rule, blend_params, blend, *cal_args, *lead_cal,
                         ahead_b, float(lead.tolerance), due, pending, issued, candidates, ahead_buffer,
                         ahead[begin:end], zb, tb, lens, go, lb & started, restart, lead_out[begin:end],
                         lead_std[begin:end], lead_covariance[begin:end] if record_covariance else empty4, cold,
                         initial_variance)
        if record_experts:
            weights_out[begin:end] = w_block
    families = [d.unpack(packed, fstate) for d, packed, fstate in zip(drivers, families, state.families)]
    head = None
    if lead is not None:
        head = LeadState(unpack_rule(bank, lead_rule), CalibrationState(*lead_cal), due, pending, issued,
                         unpack_rule(bank, blend), candidates)
    final = BankState(tuple(families), unpack_rule(bank, rule), scr, CalibrationState(*cal), head)
    if sums is not None:
        experts_out, weights_out, ahead_experts_out = sums[0], sums[1], sums[2] if with_ahead else None
    return EngineResult(forecasts, final, ahead, experts_out, weights_out, ahead_experts_out, std, ahead_std,
                        lead_out, lead_std, covariance, lead_covariance)


def _run_groups(bank, z, times, state, lengths, learn, ahead_times, ahead_frames, record_experts, score, score_ahead,
                record_covariance, restart, size) -> EngineResult:
    """:func:`run` over groups of ``size`` targets, each through all its rows; the same numbers (targets are
    independent), stitched back in target order. The sums of ``score`` are added block of rows by block, so
    every group runs blocks of the rows that :data:`TARGET_GROUP` targets (or all of them, if fewer) would:
    the same sums, to the bit, whatever the groups."""
    t_count, n, _ = z.shape
    gaps = check_restart(restart, (t_count, n))
    if ahead_times is not None:
        ahead_times = np.broadcast_to(np.asarray(ahead_times, dtype=np.float64), (t_count, n))
    rows = lambda a, g: None if a is None else np.ascontiguousarray(a[:, g])  # noqa: E731

    summed = score is not None    # experts / weights / expert_ahead are (N, K) sums, not (T, N, ...) rows
    axes = {name: 0 if name == "state" or (summed and name in ("experts", "weights", "expert_ahead")) else 1
            for name in EngineResult._fields}
    fields = {}
    allocate = threading.Lock()

    def place(axis, g):
        def put(out, part):
            out[(slice(None),) * axis + (g,)] = part
        return put

    def group(g):
        sub = tree_map(lambda a: a[g], state)
        part = run(bank, rows(z, g), rows(times, g), sub, lengths=lengths[g], learn=rows(learn, g),
                   ahead_times=rows(ahead_times, g), ahead_frames=ahead_frames, record_experts=record_experts,
                   score=rows(score, g), score_ahead=rows(score_ahead, g),
                   record_covariance=record_covariance, restart=rows(gaps, g), _block_targets=min(n, TARGET_GROUP))
        # each group writes its part of the result from its own thread (the copies overlap with other groups)
        with allocate:
            if not fields:
                for name in EngineResult._fields:
                    axis = axes[name]
                    fields[name] = tree_map(
                        lambda a: np.empty(a.shape[:axis] + (n,) + a.shape[axis + 1:], a.dtype),
                        getattr(part, name))
        for name in EngineResult._fields:
            tree_map(place(axes[name], g), fields[name], getattr(part, name))

    over_groups(group, [slice(begin, min(begin + size, n)) for begin in range(0, n, size)])
    return EngineResult(**fields)


def _accumulate(total, count, buffer, z, score):
    err = np.sum((buffer - z[:, :, None, :]) ** 2, axis=-1)          # (B, N, K)
    ok = score[..., None] & np.isfinite(err)
    total += np.where(ok, err, 0.0).sum(axis=0)
    count += ok.sum(axis=0)


def _accumulate_ahead(total, count, buffer, z, begin, end, h, score_ahead):
    """Ahead forecasts made after row t are scored against row t + h (rows known in the whole array)."""
    t_count = z.shape[0]
    stop = min(end, t_count - h)
    if stop <= begin:
        return
    target = z[begin + h:stop + h]
    err = np.sum((buffer[:stop - begin] - target[:, :, None, :]) ** 2, axis=-1)
    ok = score_ahead[begin:stop][..., None] & np.isfinite(err)
    total += np.where(ok, err, 0.0).sum(axis=0)
    count += ok.sum(axis=0)
