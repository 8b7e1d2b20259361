"""Compiled glitch screen (:mod:`kalmix.core.screen`): same formulas, one target per thread."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ._cache import configure_cache

configure_cache()
_JIT = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False)


@nb.njit(parallel=True, **_JIT)
def screen_block(threshold, max_rejects, warmup, window, position, velocity, last_time, scale, count, rejects,
                 outliers, points, z, times, lengths, present, accept, restart):
    n_targets = z.shape[1]
    p = z.shape[2]
    for n in nb.prange(n_targets):
        for t in range(lengths[n]):
            accept[t, n] = False
            restart[t, n] = False
            if not present[t, n]:
                continue
            started = points[n] >= 1
            moving = points[n] >= 2
            dt = times[t, n] - last_time[n] if started else 0.0
            if not (math.isfinite(dt) and dt > 0):
                dt = 0.0
            acc = 0.0
            for c in range(p):
                diff = z[t, n, c] - (position[n, c] + velocity[n, c] * dt)
                acc += diff * diff
            distance = math.sqrt(acc)
            wild = moving and count[n] >= warmup and not (distance <= threshold * scale[n])
            rejected = 0.0
            if wild:
                rejected = rejects[n] + 1.0
            is_restart = wild and rejected >= max_rejects
            if wild and not is_restart:
                rejects[n] = rejected
                outliers[n] += 1.0
                continue
            accept[t, n] = True
            restart[t, n] = is_restart
            if is_restart:
                for c in range(p):
                    velocity[n, c] = 0.0
                points[n] = 1.0
            else:
                if moving and math.isfinite(distance):
                    count[n] = min(count[n] + 1.0, window)
                    scale[n] = scale[n] + (distance - scale[n]) / count[n]
                if started and dt > 0:
                    for c in range(p):
                        velocity[n, c] = (z[t, n, c] - position[n, c]) / dt
                points[n] = min(points[n] + 1.0, 2.0)
            rejects[n] = 0.0
            for c in range(p):
                position[n, c] = z[t, n, c]
            last_time[n] = times[t, n]
