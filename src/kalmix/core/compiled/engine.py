"""The compiled engine on the CPU: :func:`kalmix.core.engine.run` with the same numbers, fast.

The block driver (:func:`.block.run_rows`) runs the bank's stages a block of rows at a time; this
module's backend keeps the arrays in numpy and runs each stage over ranges of targets on threads
(:mod:`._threads`). Blocks are sized so the experts' forecasts of a block stay under
:data:`BUFFER_BYTES`; more targets than :data:`TARGET_GROUP` run in groups, each through all its
rows. The result does not depend on the block size nor on the groups.
"""

from __future__ import annotations

import contextlib
import threading

import numpy as np

from ..engine import (Bank, BankState, EngineResult, check_restart, check_run_arguments, check_run_options,
                      init_bank_state, tree_map)
from ._threads import families_in_parallel, group_size, over_groups, over_targets, splits
from ._notice import watch as watch_compiles
from ._warm import compile_ahead
from .block import kernel_array, pack_rule, pack_rule_params, run_rows, unpack_rule, with_lead

__all__ = ["run", "BUFFER_BYTES", "pack_rule", "unpack_rule", "pack_rule_params", "with_lead", "prepare",
           "CpuBackend"]

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


def prepare(bank: Bank, measurements, times, state, lengths, learn):
    """Contiguous float inputs, a fresh state if none, lengths, and the rows to learn (present ones only)."""
    z, times, lengths = check_run_arguments(bank, measurements, times, state, lengths)
    learn, _, _ = check_run_options(z.shape[:2], learn, None, 1)
    z = kernel_array(z)
    t_count, n, _ = z.shape
    times = kernel_array(times)
    state = init_bank_state(bank, n) if state is None else state
    lengths = (np.full(n, t_count, dtype=np.int64) if lengths is None
               else kernel_array(np.asarray(lengths, dtype=np.int64)))
    present = np.isfinite(z).all(axis=-1) & (np.arange(t_count)[:, None] < lengths[None, :])
    learn = present if learn is None else (np.asarray(learn, dtype=bool) & present)
    return z, times, state, lengths, learn


class CpuBackend:
    """The block driver's backend on the CPU (:class:`.block.Backend`): numpy arrays; a stage over ranges of
    targets on threads, its scratch allocated a range at a time; with too few targets to split (one stream),
    the families side by side on the threads instead."""

    def __init__(self, n: int, t_count: int, block_targets: int | None = None):
        self.n = n
        self.buffer_bytes = BUFFER_BYTES
        self.block_targets = n if block_targets is None else block_targets
        self.split = splits(n)   # else every stage runs in this thread (a stream, a group of targets)
        self.side_by_side = families_in_parallel(n) and t_count * n >= SIDE_BY_SIDE_MIN_ROWS

    @staticmethod
    def put(tree):
        return tree

    @staticmethod
    def host(tree):
        return tree

    @staticmethod
    def nan(shape):
        return np.full(shape, np.nan)

    @staticmethod
    def empty(shape, dtype=np.float64):
        return np.empty(shape, dtype=dtype)

    @staticmethod
    def scratch(make):
        return make

    def launch(self, name, kernel, args, scratch=None):
        if scratch is None:
            if self.split:
                over_targets(kernel, self.n, *args)
            else:
                kernel(0, self.n, *args)
        elif self.split:
            over_targets(_with_scratch, self.n, kernel, scratch, *args)
        else:
            kernel(0, self.n, *args, scratch())

    def each_family(self, run, costs):
        # families are independent and write their own columns of the buffers: side by side, the costliest first
        if self.side_by_side:
            over_groups(run, sorted(range(len(costs)), key=lambda i: -costs[i]))
        else:
            for i in range(len(costs)):
                run(i)

    @staticmethod
    def timed():
        return contextlib.nullcontext()


def _with_scratch(lo, hi, kernel, make, *args):
    """``kernel`` over targets ``lo .. hi - 1`` with a scratch of its own (``make()``)."""
    kernel(lo, hi, *args, make())


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
    t_count, n, _ = z.shape
    size = group_size(n, TARGET_GROUP)
    if size is not None:
        return _run_groups(bank, z, times, state, lengths, learn, ahead_times, ahead_frames, record_experts, score,
                           score_ahead, record_covariance, restart, size)
    gaps = check_restart(restart, (t_count, n))
    scores = None
    if score is not None:
        frames = with_lead(bank, times, ahead_times, ahead_frames)[1]
        scores = _Scores(bank.n_experts, z, score, score_ahead, frames)
    result = run_rows(bank, CpuBackend(n, t_count, _block_targets), z, times, state, lengths, learn, gaps,
                      ahead_times, ahead_frames, record_experts=record_experts, record_covariance=record_covariance,
                      observe=None if scores is None else scores.add)
    if scores is None:
        return result
    ahead_sums = scores.sums[2] if result.ahead is not None else None
    return result._replace(experts=scores.sums[0], weights=scores.sums[1], expert_ahead=ahead_sums)


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


class _Scores:
    """Per target and expert, the sums of squared errors of the scored rows and their counts (``sums``: of the
    one-step forecasts, then of the ahead ones), added block by block (:func:`.block.run_rows`'s ``observe``)."""

    def __init__(self, k, z, score, score_ahead, frames):
        n = z.shape[1]
        self.sums = [np.zeros((n, k)), np.zeros((n, k)), np.zeros((n, k)), np.zeros((n, k))]
        self.z, self.score, self.score_ahead, self.frames = z, score, score_ahead, frames

    def add(self, begin, end, experts, ahead_experts):
        sums = self.sums
        _accumulate(sums[0], sums[1], experts, self.z[begin:end], self.score[begin:end])
        if ahead_experts is not None and self.score_ahead is not None:
            _accumulate_ahead(sums[2], sums[3], ahead_experts, self.z, begin, end, self.frames, self.score_ahead)


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
