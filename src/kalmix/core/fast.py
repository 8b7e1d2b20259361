"""Compiled time loop of the mixture (numba), same numbers as the numpy reference.

:func:`run_fast` is :func:`kalmix.core.run.run_core` with the whole loop over time
compiled: each target is advanced through all its steps by one numba function that
does, for every expert, exactly the operations of :func:`kalmix.core.mixture.step`
(same formulas, same order: the Joseph-form update, Cholesky inverses with the same
jitter, the log-sum-exp with the largest score split out, the splitmix64 random gate,
the C library's exp / expm1 / log). Targets are independent, so they run on threads,
in ranges, without synchronisation. Results are the numpy reference's bits (tested:
every output and state field).

One kernel (:mod:`._numba_kernels`, the AKF family's too) for every bank size: it keeps each
target's expert state with the expert index last and vectorises every inner loop across the
experts.

numba is an optional extra (``pip install 'kalmix[fast]'``): it is imported on first
use; :func:`numba_available` says whether it can be. Without it, ``run_core`` uses the
numpy reference, which gives the same numbers.

The spectral-radius guard (:func:`kalmix.core.dynamics.guard_theta`) is the one place
where the compiled path uses another algorithm for the same answer: a Schur-Cohn test
on the characteristic polynomial :math:`\\det(\\lambda^o I - \\sum_l \\Theta_l \\lambda^{o-l})` of the
candidate companion matrix (cofactors for p <= 3, Faddeev-LeVerrier otherwise). It
accepts when every root lies inside ``bound (1 - 1e-5)``, rejects when one lies outside
``bound (1 + 1e-5)`` and computes the eigenvalues (LAPACK, as numpy does) only in
between, so it picks the same shrink factor as the eigenvalue test.
"""

from __future__ import annotations

import numpy as np

from . import dynamics as dyn
from .mixture import DYNAMICS, GATINGS, MixtureParams, MixtureState, RunResult, StepOutput, init_state
from .compiled._cache import numba_available
from .compiled._threads import over_targets

__all__ = ["numba_available", "run_fast", "step_fast", "pack_params", "pack_state", "fast_guard"]

_GATING_INPUTS = ("bias", "position", "velocity")


def pack_params(params: MixtureParams) -> tuple:
    f = np.ascontiguousarray
    return (
        DYNAMICS.index(params.dynamics), GATINGS.index(params.gating), _GATING_INPUTS.index(params.gating_input),
        int(params.measurement_dim), int(params.order), float(params.feature_scale), float(params.velocity_scale),
        f(params.forgetting, dtype=np.float64), f(params.ridge, dtype=np.float64),
        f(params.prior_theta, dtype=np.float64), float(params.spectral_radius_bound),
        f(params.process_noise, dtype=np.float64), f(params.measurement_noise, dtype=np.float64),
        f(params.initial_variance, dtype=np.float64), f(params.initial_velocity, dtype=np.float64),
        f(params.expert_scale, dtype=np.float64), float(params.temperature), float(params.gate_share),
        float(params.eta_initial), float(params.eta_minimum), float(params.eta_decay_steps),
        float(params.eta_sensitivity), bool(params.adapt_noise), float(params.process_noise_shrink),
        float(params.measurement_noise_shrink), float(params.noise_floor), float(params.noise_reinflation),
        int(params.random_seed), float(params.state_jitter), dyn.GUARD_SHRINK.astype(np.float64),
        float(params.max_variance), fast_guard(params),
        float(params.feature_limit), float(params.miss_limit),
    )


def fast_guard(params: MixtureParams) -> bool:
    """Whether the Schur-Cohn guard is exact enough: the prior's cluster of roots at 1 is small.

    The prior of degree g puts p (g + 1) eigenvalues at 1; the Schur-Cohn recursion was
    checked against the eigenvalues for clusters of up to 6 roots (all p <= 3 with
    order <= 4 and the default degree) and fails beyond, where the eigenvalues are used.
    """
    from ._numba_linalg import MAX_CLUSTER

    p, n = params.measurement_dim, params.state_dim
    blocks = params.prior_theta[:, :n].reshape(p, params.order, p)
    used_lags = int(np.max(np.nonzero(np.abs(blocks).sum(axis=(0, 2)))[0], initial=-1)) + 1
    return p * max(used_lags, 1) <= MAX_CLUSTER


_STATE_DTYPES = dict(steps=np.int64, valid_steps=np.int64, initialised=np.bool_, stream_ids=np.int64)


def pack_state(state: MixtureState) -> tuple:
    """Fresh contiguous copies (the kernel updates them in place; the input is not mutated)."""
    return tuple(np.array(value, dtype=_STATE_DTYPES.get(name, np.float64), order="C", copy=True)
                 for name, value in state._asdict().items())


def run_fast(
    params: MixtureParams,
    measurements: np.ndarray,
    state: MixtureState | None = None,
    *,
    horizon: int = 1,
    diagnostics: bool = False,
    expert_predictions: bool = False,
    progress=None,
    parallel: bool | None = None,
    lengths=None,
) -> RunResult:
    """:func:`kalmix.core.run.run_core` compiled with numba (same arguments, same result).

    Parameters
    ----------
    parallel : bool, optional
        ``False`` runs the targets on one thread; by default they are spread over
        numba's threads (``NUMBA_NUM_THREADS``).
    progress : callable, optional
        Called with the number of steps done, after each chunk of 256 steps.
    lengths : array of int (N,), optional
        Target ``j`` is advanced through its first ``lengths[j]`` steps only (ragged
        tracks padded to a common length: padding is not fed as missing measurements);
        outputs past a target's length are NaN. Default: every step.
    """
    import numba

    from . import _numba_kernels as kernels
    from .compiled._notice import watch

    watch()   # a fresh install: say so while the kernels compile (kalmix.core.compiled._notice)
    measurements = np.ascontiguousarray(measurements, dtype=np.float64)
    t_count, n = measurements.shape[:2]
    if state is None:
        state = init_state(params, n)
    k, p = params.n_experts, params.measurement_dim
    packed_params = pack_params(params)
    packed_state = pack_state(state)
    if lengths is None:
        lengths = np.full(n, t_count, dtype=np.int64)
        fill = np.empty
    else:
        lengths = np.minimum(np.asarray(lengths, dtype=np.int64), t_count)

        def fill(shape):
            return np.full(shape, np.nan)
    predictions = fill((t_count, n, p))
    if diagnostics:
        weights, eta = fill((t_count, n, k)), fill((t_count, n))
        q_record, r_record = fill((t_count, n, k, p)), fill((t_count, n, k, p))
    else:
        weights, eta = np.empty((0, 0, 0)), np.empty((0, 0))
        q_record, r_record = np.empty((0, 0, 0, 0)), np.empty((0, 0, 0, 0))
    experts = fill((t_count, n, k, p)) if expert_predictions else np.empty((0, 0, 0, 0))
    chunk = t_count if progress is None else 256
    threads = numba.get_num_threads()
    if parallel is False:
        numba.set_num_threads(1)
    try:
        for begin in range(0, t_count, chunk):
            end = min(begin + chunk, t_count)
            records = (predictions[begin:end], bool(diagnostics), weights[begin:end], eta[begin:end],
                       q_record[begin:end], r_record[begin:end], bool(expert_predictions), experts[begin:end])
            remaining = np.clip(lengths - begin, 0, end - begin)
            over_targets(kernels.run_targets, n, measurements[begin:end], remaining, int(horizon), packed_params,
                         packed_state, records)
            if progress is not None:
                progress(end)
    finally:
        if parallel is False:
            numba.set_num_threads(threads)
    final = MixtureState(*packed_state)
    record = {}
    if diagnostics:
        record = dict(weights=weights, eta=eta, process_noise=q_record, measurement_noise=r_record)
    return RunResult(predictions, final, expert_predictions=experts if expert_predictions else None, **record)


def step_fast(params: MixtureParams, state: MixtureState, measurement: np.ndarray) -> tuple[MixtureState, StepOutput]:
    """:func:`kalmix.core.mixture.step` compiled: one frame for every target."""
    result = run_fast(params, np.asarray(measurement, dtype=np.float64)[None], state)
    new = result.state
    out = StepOutput(result.predictions[0], new.expert_predictions, new.weights, new.responsibilities, new.eta)
    return new, out
