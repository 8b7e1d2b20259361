"""The settings of :class:`~kalmix.servo.som.InverseJacobianSOM` and what it returns.

:class:`SOMConfig` (its settings, checked on creation), :class:`TrainingHistory` (the learning curve of
:meth:`~kalmix.servo.som.InverseJacobianSOM.fit`) and :class:`RelativeError` (the distance of the learned map
from the analytic inverse Jacobian). The equations are in :mod:`kalmix.servo.som`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ["SOMConfig", "TrainingHistory", "RelativeError", "as_joints"]

_MAP_UPDATES = ("interpolated", "neighbourhood")
_LOOKUPS = ("blend", "winner")


@dataclass
class SOMConfig:
    """Settings of :class:`~kalmix.servo.som.InverseJacobianSOM` (validated on creation).

    Parameters
    ----------
    lattice_shape : tuple of 3 int, default (6, 6, 6)
        Neurons per joint axis; the lattice spans the joint box given to the SOM.
    reference_rate_initial, reference_rate_final : float
        Kohonen rate :math:`\\varepsilon_w` for the reference vectors.
    map_rate_initial, map_rate_final : float
        Widrow–Hoff rate :math:`\\varepsilon_B` for the local maps; also the
        rate of :meth:`~kalmix.servo.som.InverseJacobianSOM.learn` (the final one).
    neighbourhood_initial, neighbourhood_final : float
        Width :math:`\\sigma` of the Kohonen neighbourhood, lattice units.
    n_training_moves : int, default 10_000
        Babbling moves in :meth:`~kalmix.servo.som.InverseJacobianSOM.fit`.
    babbling_step_rad : float, default 0.1
        Standard deviation of each joint's babbling move (rad).
    feature_noise_px : float, default 0.5
        Standard deviation of the pixel noise on each observed feature during
        babbling (the camera noise of the paper's scenario).
    map_update : {"interpolated", "neighbourhood"}
        Widrow–Hoff on the blended output (default) or on each neuron's own
        output weighted by the neighbourhood (ref. [2]); see the module notes.
    lookup : {"blend", "winner"}
        Gaussian blend of nearby maps (default) or the winner's map alone.
    blend_width : float, default 0.5
        :math:`\\tau`, width of the blend, lattice units.
    nlms_offset : float, default 0.01
        :math:`\\delta` in the normalised LMS denominator, in whitened feature
        units (a babbling move has :math:`E\\|\\mathbf x\\|^2 = 3`).
    feature_scale_px : float, default 10.0
        Pixel scale of the whitening used before any ``fit``.
    evaluation_every : int, default 500
        Moves between two points of the learning curve.
    n_validation : int, default 500
        Joint configurations (uniform in the box) of the default validation set.
    seed : int, default 0
        Seeds babbling, noise and validation set; no global random state.
    """

    lattice_shape: tuple[int, int, int] = (6, 6, 6)
    reference_rate_initial: float = 0.5
    reference_rate_final: float = 0.01
    map_rate_initial: float = 0.9
    map_rate_final: float = 0.05
    neighbourhood_initial: float = 2.0
    neighbourhood_final: float = 0.5
    n_training_moves: int = 10_000
    babbling_step_rad: float = 0.1
    feature_noise_px: float = 0.5
    map_update: str = "interpolated"
    lookup: str = "blend"
    blend_width: float = 0.5
    nlms_offset: float = 0.01
    feature_scale_px: float = 10.0
    evaluation_every: int = 500
    n_validation: int = 500
    seed: int = 0

    def __post_init__(self) -> None:
        shape = tuple(self.lattice_shape) if np.ndim(self.lattice_shape) == 1 else None
        if (
            shape is None
            or len(shape) != 3
            or not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in shape)
            or min(shape) < 1
        ):
            raise ValueError(
                f"lattice_shape: expected 3 integers >= 1, got {self.lattice_shape!r}"
            )
        self.lattice_shape = tuple(int(n) for n in shape)
        for name in (
            "reference_rate_initial",
            "reference_rate_final",
            "map_rate_initial",
            "map_rate_final",
            "neighbourhood_initial",
            "neighbourhood_final",
            "babbling_step_rad",
            "blend_width",
            "feature_scale_px",
        ):
            value = getattr(self, name)
            if not (np.isscalar(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        for name in ("feature_noise_px", "nlms_offset"):
            value = getattr(self, name)
            if not (np.isscalar(value) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        for name, minimum in (("n_training_moves", 0), ("evaluation_every", 1), ("n_validation", 1), ("seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
                raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
        if self.map_update not in _MAP_UPDATES:
            raise ValueError(f"map_update: expected one of {_MAP_UPDATES}, got {self.map_update!r}")
        if self.lookup not in _LOOKUPS:
            raise ValueError(f"lookup: expected one of {_LOOKUPS}, got {self.lookup!r}")


class TrainingHistory(NamedTuple):
    """Learning curve returned by :meth:`~kalmix.servo.som.InverseJacobianSOM.fit`.

    Attributes
    ----------
    moves : ndarray of int, shape (E,)
        Training moves done at each evaluation (starts at 0).
    median_relative_error, mean_relative_error : ndarray, shape (E,)
        :meth:`~kalmix.servo.som.InverseJacobianSOM.relative_error` on the validation set.
    training_seconds : float
        Wall-clock time of ``fit``, evaluations included.
    """

    moves: np.ndarray
    median_relative_error: np.ndarray
    mean_relative_error: np.ndarray
    training_seconds: float


class RelativeError(NamedTuple):
    r"""Relative error of the learned inverse Jacobian.

    ``values[i]`` is :math:`\|\mathbf B(\mathbf q_i) - \mathbf J_f^{-1}(\mathbf q_i)\|_F /
    \|\mathbf J_f^{-1}(\mathbf q_i)\|_F`; ``median`` and ``mean`` summarise them.
    """

    median: float
    mean: float
    values: np.ndarray


def as_joints(name: str, value) -> np.ndarray:
    """``value`` as a float array of joint vectors, shape (..., 3); ``ValueError`` naming ``name`` otherwise."""
    array = np.asarray(value, dtype=float)
    if array.ndim < 1 or array.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (..., 3), got {array.shape}")
    return array
