"""Compiled lead head (:mod:`kalmix.core.lead`): same rule, same numbers, targets in ranges on threads."""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from ._cache import JIT, KERNEL_JIT, configure_cache
from .calibration import calibrate_issued_row
from .rules import (cold_row, copy_matrix, forecast_row, learn_row, rule_cold_row, target, weigh_row, write_row)
from .rules import scratch as rule_scratch

configure_cache()

__all__ = ["Slots", "Rows", "Out", "kernel", "scratch"]


@nb.njit(inline="always", **JIT)
def _clear(due, pending, issued, candidates, s):
    due[s] = np.nan
    pending[s] = np.nan
    issued[s] = np.nan
    candidates[s] = np.nan


@nb.njit(inline="always", **JIT)
def _blend(params, s, count, mix, cov, ahead_mean, log_scale, max_variance, awake2, w2, logw2, r2, mix2, two):
    """The spec's :func:`kalmix.core.lead.blend` of one target: ``mix2`` the blended mean, ``cov`` moved about it;
    returns the count of the two that are finite."""
    p = mix.shape[0]
    for ci in range(p):
        two[0, ci] = mix[ci] if count > 0 else np.nan
        two[1, ci] = ahead_mean[ci]
    count2 = weigh_row(params, s, two, awake2, w2, logw2, r2, mix2)
    if awake2[0]:
        factor = math.exp(2.0 * log_scale)
        for i in range(p):
            for j in range(p):
                value = cov[i, j] + factor * ((mix[i] - mix2[i]) * (mix[j] - mix2[j]))
                if math.isnan(value):
                    value = max_variance
                cov[i, j] = min(max(value, -max_variance), max_variance)
    return count2


class Slots(NamedTuple):
    """The lead head's pending forecasts, ``S`` slots a target, advanced in place."""

    due: np.ndarray          # (N, S) when each falls due (NaN: a free slot)
    pending: np.ndarray      # (N, S, K, p) the experts' forecasts it was made of
    issued: np.ndarray       # (N, S, 2, p) the forecast and standard deviations it was issued with
    candidates: np.ndarray   # (N, S, 2, p) the two forecasts the blend weighed


class Rows(NamedTuple):
    """A block's rows as :func:`kernel` reads them."""

    due_times: np.ndarray       # (B, N) when each row's lead forecast falls due
    ahead_experts: np.ndarray   # (B, N, K, p) the experts' forecasts for that time
    ahead_mean: np.ndarray      # (B, N, p) the one-step weights' forecast for that time
    z: np.ndarray               # (B, N, p)
    times: np.ndarray           # (B, N)
    lengths: np.ndarray         # (N,)
    learn: np.ndarray           # (B, N) rows that score the forecasts due (``learn & ~restart``)
    keep: np.ndarray            # (B, N) rows whose forecast is kept (``keep & ~restart``: not a target's first)
    restart: np.ndarray         # (B, N)
    cold: np.ndarray            # (B, N) the screen's cold restarts


class Out(NamedTuple):
    """The lead head's forecasts."""

    mean: np.ndarray   # (B, N, p)
    std: np.ndarray    # (B, N, p)
    cov: np.ndarray    # (B, N, p, p) or (0, 0, 0, 0)


def scratch(k_count: int, p: int) -> tuple:
    """A target's scratch of :func:`kernel`: its rule's (over the experts), then its blend's (over two forecasts):
    awake, w, logw, r, mix, cov, then awake2, w2, logw2, r2, mix2, two."""
    return (*rule_scratch(k_count, p), np.empty(2, dtype=np.bool_), np.empty(2), np.empty(2), np.empty(2),
            np.empty(p), np.empty((2, p)))


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, blend_params, blend_state, cal, cal_state, slots, rows, out, tolerance, scratch):
    """For every row: score the pending forecasts due at its time (``learn & ~restart`` rows), forecast
    ``due_times`` from ``ahead_experts`` with the lead weights, blend that with the one-step weights'
    ``ahead_mean`` under the blend's rule (``blend_params`` / ``blend_state``), keep that forecast if a slot
    is free (``keep & ~restart`` rows: learned, not a target's first) with the interval it was issued with
    (``issued``: its mean and standard deviations, the miss the calibration learns from) and the two
    forecasts blended (``candidates``); a pending forecast is due at a row within ``tolerance`` of its time.
    On a ``cold`` row (the screen's cold restart, which scores nothing) the lead rule, the blend and the
    calibration first start again (the variances at ``cal.initial_variance``). ``params`` / ``state``: the
    lead rule's, ``blend_params`` / ``blend_state`` the blend's, of the same rule (:data:`.rules.COMPILED_RULES`);
    ``cal`` / ``cal_state`` the lead head's calibration; ``slots`` (:class:`Slots`), ``rows`` (:class:`Rows`),
    ``out`` (:class:`Out`), ``scratch`` (:func:`scratch`). Targets ``lo .. hi - 1`` (one GPU thread runs it with
    ``lo, hi = j, j + 1``)."""
    window, rate, level, z_level, max_variance, max_log_scale, initial_variance, _ = cal
    variance, n_errors, log_scale = cal_state
    due, pending, issued, candidates = slots
    due_times, ahead_experts, ahead_mean, z, times, lengths, learn, keep, restart, cold = rows
    out_mean, out_std, out_cov = out
    awake, w, logw, r, mix, cov, awake2, w2, logw2, r2, mix2, two = scratch
    p = z.shape[2]
    slots = due.shape[1]
    want_cov = out_cov.shape[0] > 0
    for n in range(lo, hi):
        rule = target(state, n)   # (s counts the slots)
        mixer = target(blend_state, n)
        ls = log_scale[n:n + 1]
        for t in range(lengths[n]):
            now = times[t, n]
            y = z[t, n]
            if cold[t, n]:
                cold_row(rule, variance[n], n_errors[n], ls, initial_variance)
                rule_cold_row(mixer)
            go = learn[t, n] and not restart[t, n]
            if go:
                for s in range(slots):
                    if abs(due[n, s] - now) <= tolerance:
                        x = pending[n, s]
                        count = forecast_row(params, rule, x, awake, w, logw, r, mix, variance[n], ls[0], max_variance,
                                             cov)
                        if count > 0:
                            calibrate_issued_row(x, y, awake, count, mix, cov, issued[n, s], variance[n],
                                                 n_errors[n], ls, window, rate, level, z_level, max_variance,
                                                 max_log_scale)
                            learn_row(params, rule, x, y, awake, count, w, logw, mix, r)
                        x2 = candidates[n, s]
                        count2 = weigh_row(blend_params, mixer, x2, awake2, w2, logw2, r2, mix2)
                        if count2 > 0:
                            learn_row(blend_params, mixer, x2, y, awake2, count2, w2, logw2, mix2, r2)
                kept = 0
                for s in range(slots):
                    if not due[n, s] <= now + tolerance:
                        if kept != s:
                            due[n, kept] = due[n, s]
                            copy_matrix(pending[n, s], pending[n, kept])
                            copy_matrix(issued[n, s], issued[n, kept])
                            copy_matrix(candidates[n, s], candidates[n, kept])
                        kept += 1
                for s in range(kept, slots):
                    _clear(due[n], pending[n], issued[n], candidates[n], s)
            xa = ahead_experts[t, n]
            count = forecast_row(params, rule, xa, awake, w, logw, r, mix, variance[n], ls[0], max_variance, cov)
            count2 = _blend(blend_params, mixer, count, mix, cov, ahead_mean[t, n], ls[0], max_variance, awake2, w2,
                            logw2, r2, mix2, two)
            write_row(count2, mix2, cov, out_mean[t, n], out_std[t, n])
            if want_cov:
                copy_matrix(cov, out_cov[t, n])
            if restart[t, n]:
                for s in range(slots):
                    _clear(due[n], pending[n], issued[n], candidates[n], s)
            if keep[t, n] and not restart[t, n] and count > 0 and math.isfinite(due_times[t, n]):
                for s in range(slots):
                    if math.isnan(due[n, s]):
                        due[n, s] = due_times[t, n]
                        copy_matrix(xa, pending[n, s])
                        copy_matrix(two, candidates[n, s])
                        for ci in range(p):
                            issued[n, s, 0, ci] = out_mean[t, n, ci]
                            issued[n, s, 1, ci] = out_std[t, n, ci]
                        break
