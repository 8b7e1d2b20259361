"""Object API: one stream (or a fixed batch of streams) of measurements, step by step.

>>> import numpy as np
>>> from kalmix import MixturePredictor
>>> predictor = MixturePredictor(n_experts=10, seed=0)
>>> for k in range(50):
...     next_frame = predictor.step([np.cos(0.1 * k), np.sin(0.1 * k)])
>>> predictor.weights_.shape
(10,)
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ._values import measurements as _measurements
from .archive import open_archive, write_archive
from .bank import check_horizon, make_params
from .core.mixture import MixtureParams, MixtureState, init_state, predict, step
from .core.fast import numba_available, step_fast
from .core.run import BACKENDS, RunResult, run_core

__all__ = ["MixturePredictor", "run", "FORMAT_VERSION"]

#: Version of the file written by :meth:`MixturePredictor.save`.
FORMAT_VERSION = 1
_MAGIC = "kalmix-predictor"


def _as_measurements(value, name: str = "z", width: int | None = None) -> np.ndarray:
    """Numeric float array; NaN allowed (missing, as pandas' NA, None and a masked array's masked values), +-inf
    refused."""
    try:
        array = _measurements(value, width)
    except (TypeError, ValueError, OverflowError) as error:
        raise TypeError(f"{name}: expected numbers (NaN for a missing measurement), got {value!r:.80}") from error
    if np.isinf(array).any():
        where = tuple(int(i) for i in np.argwhere(np.isinf(array))[0])
        raise ValueError(f"{name}: expected finite numbers or NaN (missing), got {array[where]} at index {where}")
    return array


class MixturePredictor:
    """Mixture of state-model adaptive Kalman filters for one stream or a batch.

    ``__init__`` only stores its arguments (see :func:`kalmix.bank.make_params` for
    each one and its equation); the bank is built at the first measurement, once the
    measurement dimension is known.

    Parameters
    ----------
    n_experts : int
        K, the number of experts (40 in the paper).
    seed : int
        Seed of the bank recipe and of the random gate.
    backend : {"auto", "numpy", "numba"}
        Implementation of the step: the numpy reference or the compiled numba kernel
        (the ``fast`` extra); ``auto`` takes numba when it can be imported. Both give
        the same numbers to rounding; one predictor always uses the same one, so a
        saved and resumed run is bit-for-bit identical.
    **options
        Any other argument of :func:`kalmix.bank.make_params`
        (``dynamics``, ``gating``, ``order``, ``length_unit``, ...).

    Attributes
    ----------
    prediction_ : ndarray, shape (p,) or (N, p)
        Prediction of the next frame.
    weights_ : ndarray, shape (K,) or (N, K)
        Gating weights :math:`g_{i,k}` (eq. 8).
    responsibilities_ : ndarray, shape (K,) or (N, K)
        Posterior :math:`h_{i,k}` (eq. 10) of the last scored frame.
    eta_ : float or ndarray (N,)
        Adaptive learning rate :math:`\\eta_k`.
    process_noise_, measurement_noise_ : ndarray, shape (K, p) or (N, K, p)
        Diagonals of :math:`Q_{i,k}` and :math:`R_{i,k}` (eq. 11/12).
    expert_predictions_ : ndarray, shape (K, p) or (N, K, p)
    n_steps_ : int
        Frames seen so far (measurements present or missing).
    """

    def __init__(self, n_experts: int = 40, *, seed: int = 0, backend: str = "auto", **options: Any):
        self.n_experts = n_experts
        self.seed = seed
        self.backend = backend
        self.options = options
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
        make_params(1, n_experts, seed=seed, **options)  # validate now: errors name the argument
        self._params: MixtureParams | None = None
        self._state: MixtureState | None = None
        self._single: bool | None = None

    # -- construction -------------------------------------------------------------
    def _build(self, measurement_dim: int, n_targets: int, single: bool) -> None:
        self._params = make_params(measurement_dim, self.n_experts, seed=self.seed, **self.options)
        self._state = init_state(self._params, n_targets)
        self._single = single

    def _batch(self, z) -> np.ndarray:
        if z is None:   # a missing row, as for TrackPredictor.step_row
            if self._params is None:
                raise ValueError("z: None (a missing row) needs the number of coordinates, which the predictor "
                                 "learns from its first measurement; give NaN for each coordinate")
            z = np.full((self._params.measurement_dim,) if self._single else self._state.steps.shape[:1]
                        + (self._params.measurement_dim,), np.nan)
        array = _as_measurements(z)
        if self._params is None:
            if array.ndim not in (1, 2) or array.shape[-1] < 1 or (array.ndim == 2 and array.shape[0] < 1):
                raise ValueError(f"z: expected shape (p,) for one stream or (N, p) for N streams, got {array.shape}")
            self._build(array.shape[-1], 1 if array.ndim == 1 else array.shape[0], array.ndim == 1)
        expected = (self._params.measurement_dim,) if self._single else (self._state.steps.shape[0],
                                                                          self._params.measurement_dim)
        if array.shape != expected:
            raise ValueError(f"z: expected shape {expected}, got {array.shape}")
        return array[None] if self._single else array

    def _unbatch(self, array):
        return array[0] if self._single else array

    def _backend(self) -> str:
        """The backend in use: ``auto`` resolved to ``numba`` or ``numpy``."""
        if self.backend == "auto":
            return "numba" if numba_available() else "numpy"
        return self.backend

    def _require_fitted(self):
        if self._state is None:
            raise RuntimeError("this predictor has seen no measurement yet: call step(z) first")

    # -- learning and prediction ----------------------------------------------------
    def step(self, z) -> np.ndarray:
        """Learn from measurement ``z`` (NaN = missing) and return the prediction of the next frame."""
        batch = self._batch(z)
        self._state, out = (step_fast if self._backend() == "numba" else step)(self._params, self._state, batch)
        return self._unbatch(out.prediction).copy()

    def update(self, z) -> "MixturePredictor":
        """Learn from ``z``; returns ``self`` (use :meth:`predict` for forecasts)."""
        self.step(z)
        return self

    def predict(self, horizon: int = 1) -> np.ndarray:
        """Prediction ``horizon`` frames after the last measurement, shape (p,) or (N, p).

        ``horizon`` is an integer in [1, :data:`kalmix.bank.MAX_HORIZON`] (10 000).
        """
        self._require_fitted()
        horizon = check_horizon(horizon)
        prediction, _ = predict(self._params, self._state, int(horizon))
        return self._unbatch(prediction)

    def run(self, measurements, *, horizon: int = 1, diagnostics: bool = True,
            expert_predictions: bool = False, progress=None) -> RunResult:
        """Step through ``(T, p)`` (or ``(T, N, p)`` for a batch) measurements.

        Returns a :class:`~kalmix.core.run.RunResult` whose arrays have the stream axis
        removed for a single stream; ``predictions[t]`` predicts frame ``t + horizon``.
        """
        array = _as_measurements(measurements, "measurements",
                                 None if self._params is None else self._params.measurement_dim)
        if array.ndim not in (2, 3) or array.shape[0] < 1:
            raise ValueError(f"measurements: expected shape (T, p) or (T, N, p) with T >= 1, got {array.shape}")
        horizon = check_horizon(horizon)
        try:
            self._batch(array[0])  # builds on first use and checks the per-step shape
        except ValueError:
            step = (self._params.measurement_dim,) if self._single else (self._state.steps.shape[0],
                                                                         self._params.measurement_dim)
            raise ValueError(f"measurements: expected shape (T, {', '.join(map(str, step))}) for this predictor, "
                             f"got {array.shape}") from None
        batched = array[:, None, :] if self._single else array
        result = run_core(self._params, batched, self._state, horizon=int(horizon), diagnostics=diagnostics,
                          expert_predictions=expert_predictions, progress=progress, backend=self._backend())
        self._state = result.state
        if not self._single:
            return result
        return result._replace(**{name: None if value is None else value[:, 0]
                                  for name, value in result._asdict().items() if name != "state"})

    # -- inspection -----------------------------------------------------------------
    @property
    def params_(self) -> MixtureParams:
        self._require_fitted()
        return self._params

    @property
    def state_(self) -> MixtureState:
        self._require_fitted()
        return self._state

    @property
    def prediction_(self):
        self._require_fitted()
        return self.predict(1)

    def _field(self, name):
        self._require_fitted()
        return self._unbatch(getattr(self._state, name))

    weights_ = property(lambda self: self._field("weights"))
    responsibilities_ = property(lambda self: self._field("responsibilities"))
    eta_ = property(lambda self: self._field("eta"))
    process_noise_ = property(lambda self: self._field("process_noise"))
    measurement_noise_ = property(lambda self: self._field("measurement_noise"))
    expert_predictions_ = property(lambda self: self._field("expert_predictions"))
    n_steps_ = property(lambda self: int(self._state.steps.max()) if self._state is not None else 0)

    # -- persistence ----------------------------------------------------------------
    def get_config(self) -> dict:
        """Constructor arguments, JSON-serialisable."""
        return {"n_experts": self.n_experts, "seed": self.seed, "backend": self.backend, "options": self.options}

    def save(self, path: str | os.PathLike) -> None:
        """Write the full state to ``path`` (a ``.npz`` archive); :meth:`load` resumes it exactly."""
        self._require_fitted()
        meta = {"magic": _MAGIC, "format_version": FORMAT_VERSION, "config": self.get_config(),
                "measurement_dim": self._params.measurement_dim, "single": self._single,
                "n_targets": int(self._state.steps.shape[0])}
        write_archive(path, meta, {f"state/{name}": value for name, value in self._state._asdict().items()})

    @classmethod
    def load(cls, path: str | os.PathLike) -> "MixturePredictor":
        """Read a predictor written by :meth:`save`; raises ``ValueError`` on a bad file."""
        with open_archive(path, magic=_MAGIC, version=FORMAT_VERSION, what="kalmix predictor file",
                          written_by="MixturePredictor.save") as archive:
            meta = archive.meta
            try:
                config, n_targets = meta["config"], meta["n_targets"]
                if isinstance(n_targets, bool) or not isinstance(n_targets, int) or not (
                        0 < 8 * n_targets <= archive.size("state/steps")):
                    raise ValueError(f"{path}: the kalmix predictor file's target count {n_targets!r} does not "
                                     "match its arrays")
                predictor = cls(config["n_experts"], seed=config["seed"], backend=config.get("backend", "auto"),
                                **config["options"])
                predictor._build(meta["measurement_dim"], n_targets, meta["single"])
            except (KeyError, TypeError) as error:
                raise ValueError(f"{path}: the kalmix predictor file's settings are incomplete or corrupt: "
                                 f"{error!r}") from error
            fields = {name: archive.array(f"state/{name}", expected.shape, expected.dtype, label=name)
                      for name, expected in predictor._state._asdict().items()}
        predictor._state = MixtureState(**fields)
        return predictor


def run(measurements, *, n_experts: int = 40, seed: int = 0, horizon: int = 1,
        diagnostics: bool = True, **options: Any) -> RunResult:
    """Run a fresh :class:`MixturePredictor` over ``(T, p)`` or ``(T, N, p)`` measurements."""
    return MixturePredictor(n_experts, seed=seed, **options).run(measurements, horizon=horizon,
                                                                 diagnostics=diagnostics)
