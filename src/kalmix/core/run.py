"""Run the batched core over a whole measurement array (the loop over time)."""

from __future__ import annotations

import numpy as np

from . import fast
from .mixture import MixtureParams, MixtureState, RunResult, init_state, predict, step

__all__ = ["RunResult", "run_core", "BACKENDS"]

#: Implementations of the time loop: the numpy reference and the compiled one.
BACKENDS = ("auto", "numpy", "numba")


def run_core(
    params: MixtureParams,
    measurements: np.ndarray,
    state: MixtureState | None = None,
    *,
    horizon: int = 1,
    diagnostics: bool = False,
    expert_predictions: bool = False,
    progress=None,
    backend: str = "auto",
) -> RunResult:
    """Step through ``measurements`` of shape ``(T, N, p)``.

    Parameters
    ----------
    params : MixtureParams
    measurements : ndarray, shape (T, N, p)
        NaN rows are missing measurements.
    state : MixtureState, optional
        State to resume from; a fresh one by default.
    horizon : int
        Frames ahead to predict, :math:`H \\ge 1`.
    diagnostics : bool
        Record weights, eta and the Q/R diagonals at every step.
    expert_predictions : bool
        Record every expert's prediction (memory ``T N K p``).
    progress : callable, optional
        Called with the number of steps done after each step (after each chunk of
        256 steps with the numba backend).
    backend : {"auto", "numpy", "numba"}
        ``numpy``: the reference loop over :func:`~kalmix.core.mixture.step`;
        ``numba``: the compiled loop of :mod:`kalmix.core.fast` (same numbers to
        rounding, needs the ``fast`` extra); ``auto``: numba when it can be imported.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    if backend != "numpy":
        if fast.numba_available():
            return fast.run_fast(params, measurements, state, horizon=horizon, diagnostics=diagnostics,
                                 expert_predictions=expert_predictions, progress=progress)
        if backend == "numba":
            raise ImportError("backend='numba' needs numba (the 'fast' extra): pip install 'kalmix[fast]'")
    t_count, n = measurements.shape[:2]
    if state is None:
        state = init_state(params, n)
    k, p = params.n_experts, params.measurement_dim
    predictions = np.empty((t_count, n, p))
    record = {}
    if diagnostics:
        record = dict(weights=np.empty((t_count, n, k)), eta=np.empty((t_count, n)),
                      process_noise=np.empty((t_count, n, k, p)), measurement_noise=np.empty((t_count, n, k, p)))
    experts = np.empty((t_count, n, k, p)) if expert_predictions else None
    for t in range(t_count):
        state, out = step(params, state, measurements[t])
        if horizon == 1:
            predictions[t], expert_out = out.prediction, out.expert_predictions
        else:
            predictions[t], expert_out = predict(params, state, horizon)
        if experts is not None:
            experts[t] = expert_out
        if diagnostics:
            record["weights"][t] = out.weights
            record["eta"][t] = out.eta
            record["process_noise"][t] = state.process_noise
            record["measurement_noise"][t] = state.measurement_noise
        if progress is not None:
            progress(t + 1)
    return RunResult(predictions, state, expert_predictions=experts, **record)
