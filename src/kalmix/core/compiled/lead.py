"""Compiled lead head (:mod:`kalmix.core.lead`): same rule, same numbers, targets in ranges on threads."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._cache import KERNEL_JIT, configure_cache
from .calibration import calibrate_issued_row
from .rules import cold_row, copy_matrix, forecast_row, learn_row, scratch, target, write_row

configure_cache()

__all__ = ["run_block", "kernel"]


def run_block(lo, hi, params, state, window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors,
              log_scale, due_times, tolerance, due, pending, issued, ahead_experts, z, times, lengths, learn, keep,
              restart, out, out_std, out_cov, cold, initial_variance):
    """For every row: score the pending forecasts due at its time (``learn & ~restart`` rows), forecast
    ``due_times`` from ``ahead_experts`` with the lead weights, keep that forecast if a slot is free
    (``keep & ~restart`` rows: learned, not a target's first) with the interval it was issued with
    (``issued``: its mean and standard deviations, the miss the calibration learns from). On a ``cold``
    row (the screen's cold restart, which scores nothing) the lead rule and calibration first start
    again (the variances at ``initial_variance``). ``params`` / ``state``: the lead rule's
    (:data:`.rules.COMPILED_RULES`). Targets ``lo .. hi - 1``."""
    kernel(lo, hi, params, state, window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors,
           log_scale, due_times, tolerance, due, pending, issued, ahead_experts, z, times, lengths, learn, keep,
           restart, out, out_std, out_cov, cold, float(initial_variance), *scratch(ahead_experts.shape[2], z.shape[2]))


@nb.njit(**KERNEL_JIT)
def kernel(lo, hi, params, state, window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors,
           log_scale, due_times, tolerance, due, pending, issued, ahead_experts, z, times, lengths, learn, keep,
           restart, out, out_std, out_cov, cold, initial_variance, awake, w, logw, r, mix, cov):
    """:func:`run_block` with its scratch given (one GPU thread runs it with ``lo, hi = j, j + 1``)."""
    p = z.shape[2]
    slots = due.shape[1]
    want_cov = out_cov.shape[0] > 0
    for n in range(lo, hi):
        rule = target(state, n)   # (s counts the slots)
        ls = log_scale[n:n + 1]
        for t in range(lengths[n]):
            now = times[t, n]
            y = z[t, n]
            if cold[t, n]:
                cold_row(rule, variance[n], n_errors[n], ls, initial_variance)
            go = learn[t, n] and not restart[t, n]
            if go:
                for s in range(slots):
                    if abs(due[n, s] - now) <= tolerance:
                        x = pending[n, s]
                        count = forecast_row(params, rule, x, awake, w, logw, mix, variance[n], ls[0], max_variance,
                                             cov)
                        if count > 0:
                            calibrate_issued_row(x, y, awake, count, mix, cov, issued[n, s], variance[n],
                                                 n_errors[n], ls, window, rate, level, z_level, max_variance,
                                                 max_log_scale)
                            learn_row(params, rule, x, y, awake, count, w, mix, r)
                kept = 0
                for s in range(slots):
                    if not due[n, s] <= now + tolerance:
                        if kept != s:
                            due[n, kept] = due[n, s]
                            copy_matrix(pending[n, s], pending[n, kept])
                            copy_matrix(issued[n, s], issued[n, kept])
                        kept += 1
                for s in range(kept, slots):
                    due[n, s] = np.nan
                    pending[n, s] = np.nan
                    issued[n, s] = np.nan
            xa = ahead_experts[t, n]
            count = forecast_row(params, rule, xa, awake, w, logw, mix, variance[n], ls[0], max_variance, cov)
            write_row(count, mix, cov, out[t, n], out_std[t, n])
            if want_cov:
                copy_matrix(cov, out_cov[t, n])
            if restart[t, n]:
                for s in range(slots):
                    due[n, s] = np.nan
                    pending[n, s] = np.nan
                    issued[n, s] = np.nan
            if keep[t, n] and not restart[t, n] and count > 0 and math.isfinite(due_times[t, n]):
                for s in range(slots):
                    if math.isnan(due[n, s]):
                        due[n, s] = due_times[t, n]
                        copy_matrix(xa, pending[n, s])
                        for ci in range(p):
                            issued[n, s, 0, ci] = out[t, n, ci]
                            issued[n, s, 1, ci] = out_std[t, n, ci]
                        break
