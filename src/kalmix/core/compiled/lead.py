"""Compiled lead head (:mod:`kalmix.core.lead`): same rule, same numbers, one target per thread."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._cache import configure_cache
from .calibration import calibrate_row
from .rules import _learn, forecast_row, write_row

configure_cache()
_JIT = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False)

__all__ = ["run_block"]


@nb.njit(parallel=True, **_JIT)
def run_block(rule, forgetting, share, scale, scale_factor, bound_forgetting, a, b, c, d, e,
              window, rate, level, z_level, max_variance, max_log_scale, variance, n_errors, log_scale,
              due_times, tolerance, due, pending, ahead_experts, z, times, lengths, learn, keep, restart,
              out, out_std, out_cov):
    """For every row: score the pending forecasts due at its time (``learn & ~restart`` rows), forecast
    ``due_times`` from ``ahead_experts`` with the lead weights, keep that forecast if a slot is free
    (``keep & ~restart`` rows: learned, not a target's first)."""
    n_targets = z.shape[1]
    k_count = ahead_experts.shape[2]
    p = z.shape[2]
    slots = due.shape[1]
    want_cov = out_cov.shape[0] > 0
    for n in nb.prange(n_targets):
        awake = np.empty(k_count, dtype=np.bool_)
        w = np.empty(k_count)
        logw = np.empty(k_count)
        r = np.empty(k_count)
        mix = np.empty(p)
        cov = np.empty((p, p))
        dn = d[n:n + 1]
        en = e[n:n + 1]
        ls = log_scale[n:n + 1]
        for t in range(lengths[n]):
            now = times[t, n]
            y = z[t, n]
            go = learn[t, n] and not restart[t, n]
            if go:
                for s in range(slots):
                    if abs(due[n, s] - now) <= tolerance:
                        x = pending[n, s]
                        count = forecast_row(rule, forgetting, share, a[n], b[n], c[n], dn[0], x, awake, w, logw,
                                             mix, variance[n], ls[0], max_variance, cov)
                        if count > 0:
                            calibrate_row(x, y, awake, count, mix, cov, variance[n], n_errors[n], ls, window, rate,
                                          level, z_level, max_variance, max_log_scale)
                            _learn(rule, forgetting, share, scale, scale_factor, bound_forgetting, a[n], b[n], c[n],
                                   dn, en, x, y, awake, count, w, mix, r)
                kept = 0
                for s in range(slots):
                    if not due[n, s] <= now + tolerance:
                        if kept != s:
                            due[n, kept] = due[n, s]
                            pending[n, kept] = pending[n, s]
                        kept += 1
                for s in range(kept, slots):
                    due[n, s] = np.nan
                    pending[n, s] = np.nan
            xa = ahead_experts[t, n]
            count = forecast_row(rule, forgetting, share, a[n], b[n], c[n], dn[0], xa, awake, w, logw, mix,
                                 variance[n], ls[0], max_variance, cov)
            write_row(count, mix, cov, out[t, n], out_std[t, n])
            if want_cov:
                out_cov[t, n] = cov
            if restart[t, n]:
                for s in range(slots):
                    due[n, s] = np.nan
                    pending[n, s] = np.nan
            if keep[t, n] and not restart[t, n] and count > 0 and math.isfinite(due_times[t, n]):
                for s in range(slots):
                    if math.isnan(due[n, s]):
                        due[n, s] = due_times[t, n]
                        pending[n, s] = xa
                        break
