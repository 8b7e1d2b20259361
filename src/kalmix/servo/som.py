r"""A supervised self-organising map that learns the inverse image Jacobian.

The paper's controller (Wira, Urban & Gresser 2001, section 2, eq. 3) moves the
arm by :math:`\Delta\mathbf q_k = \mathbf B_k \mathbf e_k` with
:math:`\mathbf B_k \approx \mathbf J_f^{-1}(\mathbf q_k)` learned by "a
supervised Self-Organizing Map" (their ref. [2], Urban, Buessler & Gresser
1998): a Kohonen lattice over joint space whose neurons each hold a reference
vector :math:`\mathbf w_r` and a local linear map :math:`\mathbf B_r`, trained
by error correction on pairs :math:`(\Delta\mathbf q, \Delta\mathbf v)` from
random "babbling" moves.

One training move
-----------------
1. Draw a joint configuration :math:`\mathbf q` uniformly in the lattice's
   joint box and a small move :math:`\Delta\mathbf q \sim \mathcal N(0, s^2 I)`
   (``babbling_step_rad``); observe
   :math:`\Delta\mathbf v = \mathbf f(\mathbf q + \Delta\mathbf q) - \mathbf f(\mathbf q)`
   through the cameras, each feature with pixel noise ``feature_noise_px``.
   The move is filed at its midpoint :math:`\mathbf q + \Delta\mathbf q / 2`,
   where the secant :math:`\Delta\mathbf v / \Delta\mathbf q` matches the
   Jacobian to second order.
2. Winner :math:`r = \arg\min_s \|\tilde{\mathbf q} - \mathbf w_s\|`, with
   :math:`\tilde{\mathbf q}` the joint vector mapped to lattice units (the box
   scaled to ``lattice_shape``, so one lattice spacing is one unit on every axis).
3. Kohonen update of every reference vector,
   :math:`\mathbf w_s \leftarrow \mathbf w_s + \varepsilon_w h_{rs} (\tilde{\mathbf q} - \mathbf w_s)`,
   :math:`h_{rs} = \exp(-\|\mathbf r - \mathbf s\|^2 / 2\sigma^2)` on lattice
   indices.
4. Widrow–Hoff (normalised LMS) update of the local maps. The pixel
   differences are first whitened, :math:`\mathbf x = \mathbf T \Delta\mathbf v`
   (see below), and the maps live in that space, :math:`\mathbf B_s = \tilde{\mathbf B}_s \mathbf T`.

   - ``map_update="neighbourhood"`` (the rule of ref. [2]): every neuron
     corrects its own prediction,

     .. math::

        \tilde{\mathbf B}_s \leftarrow \tilde{\mathbf B}_s + \varepsilon_B h_{rs}
        \frac{(\Delta\mathbf q - \tilde{\mathbf B}_s \mathbf x)\,\mathbf x^\top}
             {\|\mathbf x\|^2 + \delta} .

   - ``map_update="interpolated"`` (default): the map's output is the blend
     :math:`\tilde{\mathbf B}(\mathbf q) = \sum_s g_s \tilde{\mathbf B}_s` used by
     :meth:`InverseJacobianSOM.inverse_jacobian`, and its error is shared out
     by the blend weights,

     .. math::

        \tilde{\mathbf B}_s \leftarrow \tilde{\mathbf B}_s + \varepsilon_B
        \frac{g_s}{\sum_t g_t^2}
        \frac{(\Delta\mathbf q - \tilde{\mathbf B}(\mathbf q)\, \mathbf x)\,\mathbf x^\top}
             {\|\mathbf x\|^2 + \delta},

     so that with :math:`\varepsilon_B = 1` the blended map reproduces the
     move exactly (normalised LMS on the output) and with a one-hot blend it is
     the winner's Widrow–Hoff rule.

Rates and width decay exponentially from their initial to their final value
over the training moves, :math:`\varepsilon(k) = \varepsilon_0
(\varepsilon_1/\varepsilon_0)^{k/K}`.

Lookup
------
``lookup="blend"`` (default) returns the Gaussian blend of the maps of the
neurons nearest in lattice units,

.. math::

    \mathbf B(\mathbf q) = \sum_s g_s \mathbf B_s, \qquad
    g_s \propto \exp\!\bigl(-\|\tilde{\mathbf q} - \mathbf w_s\|^2 / 2\tau^2\bigr),

with :math:`\tau` = ``blend_width`` (lattice units); ``lookup="winner"``
returns :math:`\mathbf B_r` of the winner alone (piecewise constant, the
classic SOM).

Why the defaults (compared on the default :class:`~kalmix.servo.arm.Arm` and camera by the
median relative error of the learned inverse Jacobian over the target region):

- the ``interpolated`` update with the ``blend`` lookup has about half the error of the
  classic SOM of ref. [2] (``neighbourhood`` update, ``winner`` lookup); the ``interpolated``
  update with a ``winner`` lookup is worse than either;
- even with every :math:`\mathbf B_r` set to the exact inverse at its node, a winner-only
  lookup stays several percent off (the Jacobian turns across one cell); a blend with
  :math:`\tau = 0.5` removes most of that floor;
- a coarser lattice, fewer moves or a smaller babbling step each cost accuracy; a finer
  lattice gains little;
- the whitening :math:`\mathbf T` matters: stereo disparity changes four times less than the
  image position per metre, so raw :math:`\Delta\mathbf v` is badly conditioned and
  normalised LMS converges slowly along it;
- a 0.1 rad babbling step keeps the 0.7 px noise of a pixel difference small
  against the move; filing the move at its midpoint removes most of the
  curvature bias of the larger step.

Whitening
---------
:meth:`InverseJacobianSOM.fit` sets :math:`\mathbf T = \mathbf L^{-1}` with
:math:`\mathbf L \mathbf L^\top = \frac1K \sum_k \Delta\mathbf v_k \Delta\mathbf v_k^\top`
(Cholesky) over its babbling moves, so :math:`\mathbf x` has unit second moment
on every axis; this uses only the observed pixels, no camera model. Before any
``fit`` :math:`\mathbf T = \mathbf I / \text{feature\_scale\_px}`.
"""

from __future__ import annotations

import time
from dataclasses import asdict, fields
from typing import Callable

import numpy as np

from kalmix.servo.som_config import RelativeError, SOMConfig, TrainingHistory, as_joints
from kalmix.servo.som_plot import plot_learning_curve

__all__ = [
    "SOMConfig",
    "InverseJacobianSOM",
    "TrainingHistory",
    "RelativeError",
    "plot_learning_curve",
]


class InverseJacobianSOM:
    """Supervised SOM learning :math:`\\mathbf B(\\mathbf q) \\approx \\mathbf J_f^{-1}(\\mathbf q)`.

    See the module docstring for the equations.

    Parameters
    ----------
    config : SOMConfig
    joint_low, joint_high : array_like, shape (3,)
        The joint box the lattice spans (rad). ``Arm.joint_box()`` gives the
        box of the target region; ``(arm.low, arm.high)`` the whole range.

    Attributes
    ----------
    reference_vectors_ : ndarray, shape (N, 3)
        :math:`\\mathbf w_s` in normalised joint space ``[0, 1]^3`` (box-relative).
    maps_ : ndarray, shape (N, 3, 3)
        :math:`\\mathbf B_s` in rad/px (whitening folded in).
    moves_seen_ : int
        Training pairs learned so far (``fit`` and ``learn``).
    """

    def __init__(self, config: SOMConfig | None = None, joint_low=None, joint_high=None):
        self.config = config
        self.joint_low = joint_low
        self.joint_high = joint_high
        self._state: dict | None = None

    # ------------------------------------------------------------------ set-up
    def _box(self) -> tuple[np.ndarray, np.ndarray]:
        if self.joint_low is None or self.joint_high is None:
            raise ValueError("joint_low, joint_high: expected the joint box (rad), got None")
        low = np.asarray(self.joint_low, dtype=float)
        high = np.asarray(self.joint_high, dtype=float)
        if low.shape != (3,) or high.shape != (3,):
            raise ValueError(
                f"joint_low, joint_high: expected shape (3,) each, got {low.shape} and {high.shape}"
            )
        if not np.all(np.isfinite(low) & np.isfinite(high) & (low < high)):
            raise ValueError(
                f"joint_low: expected finite joint_low < joint_high, got {low.tolist()} and {high.tolist()}"
            )
        return low, high

    def _config(self) -> SOMConfig:
        if self.config is None:
            return SOMConfig()
        if not isinstance(self.config, SOMConfig):
            raise ValueError(f"config: expected a SOMConfig, got {type(self.config).__name__}")
        return self.config

    def _fresh_state(self) -> dict:
        config = self._config()
        low, high = self._box()
        shape = np.array(config.lattice_shape)
        indices = np.stack(
            np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1
        ).reshape(-1, 3)
        return {
            "joint_low": low,
            "joint_high": high,
            "lattice_indices": indices,
            # reference vectors start at the cell centres of a regular grid over the box
            "reference_vectors": (indices + 0.5) / shape,
            "whitened_maps": np.zeros((len(indices), 3, 3)),
            "feature_whitening": np.eye(3) / config.feature_scale_px,
            "moves_seen": 0,
        }

    def _ensure_state(self) -> dict:
        if self._state is None:
            self._state = self._fresh_state()
        return self._state

    # ------------------------------------------------------------------ pieces
    def _lattice_units(self, q: np.ndarray) -> np.ndarray:
        """Joint angles (..., 3) -> lattice units (..., 3): box scaled to lattice_shape."""
        state = self._ensure_state()
        normalised = (q - state["joint_low"]) / (state["joint_high"] - state["joint_low"])
        return normalised * np.array(self._config().lattice_shape)

    def _squared_distances(self, q: np.ndarray) -> np.ndarray:
        """Squared lattice-unit distances (..., N) from joint vectors to every reference vector."""
        shape = np.array(self._config().lattice_shape)
        u = self._lattice_units(q)
        w = self._ensure_state()["reference_vectors"] * shape
        return np.sum((u[..., None, :] - w) ** 2, axis=-1)

    def _blend_weights(self, squared_distances: np.ndarray) -> np.ndarray:
        config = self._config()
        if config.lookup == "winner":
            weights = np.zeros_like(squared_distances)
            np.put_along_axis(weights, np.argmin(squared_distances, axis=-1)[..., None], 1.0, axis=-1)
            return weights
        shifted = squared_distances - np.min(squared_distances, axis=-1, keepdims=True)
        weights = np.exp(-shifted / (2.0 * config.blend_width**2))
        return weights / np.sum(weights, axis=-1, keepdims=True)

    def _update(self, q_mid, dq, x, *, reference_rate, map_rate, width, adapt_references) -> None:
        """One Kohonen + Widrow–Hoff step on one pair (midpoint q, dq, whitened dv). In place."""
        config = self._config()
        state = self._state
        shape = np.array(config.lattice_shape)
        squared = self._squared_distances(q_mid)
        winner = int(np.argmin(squared))
        lattice = state["lattice_indices"]
        neighbourhood = np.exp(-np.sum((lattice - lattice[winner]) ** 2, axis=-1) / (2.0 * width**2))
        if adapt_references:
            u = self._lattice_units(q_mid) / shape
            state["reference_vectors"] += (reference_rate * neighbourhood)[:, None] * (
                u - state["reference_vectors"]
            )
            squared = self._squared_distances(q_mid)
        maps = state["whitened_maps"]
        denominator = float(x @ x) + config.nlms_offset
        if config.map_update == "neighbourhood":
            errors = dq - maps @ x  # (N, 3): each neuron's own prediction error
            gains = map_rate * neighbourhood / denominator
            maps += gains[:, None, None] * errors[:, :, None] * x
        else:
            weights = self._blend_weights(squared)
            error = dq - np.einsum("s,sij,j->i", weights, maps, x)
            gains = map_rate * weights / (float(weights @ weights) * denominator)
            maps += gains[:, None, None] * (error[:, None] * x)
        state["moves_seen"] += 1

    # ------------------------------------------------------------------ public
    @property
    def reference_vectors_(self) -> np.ndarray:
        return self._ensure_state()["reference_vectors"].copy()

    @property
    def maps_(self) -> np.ndarray:
        state = self._ensure_state()
        return state["whitened_maps"] @ state["feature_whitening"]

    @property
    def moves_seen_(self) -> int:
        return int(self._ensure_state()["moves_seen"])

    def inverse_jacobian(self, q) -> np.ndarray:
        r"""Learned inverse image Jacobian :math:`\mathbf B(\mathbf q)`.

        .. math::

            \mathbf B(\mathbf q) = \sum_s g_s(\mathbf q)\, \tilde{\mathbf B}_s \mathbf T

        with :math:`g` the Gaussian blend (``lookup="blend"``) or the winner's
        indicator (``lookup="winner"``).

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Joint angles (rad).

        Returns
        -------
        numpy.ndarray, shape (..., 3, 3)
            Radians per pixel; ``B @ e`` is the joint step for image error ``e``.
        """
        q = as_joints("q", q)
        state = self._ensure_state()
        weights = self._blend_weights(self._squared_distances(q))
        blended = np.einsum("...s,sij->...ij", weights, state["whitened_maps"])
        return blended @ state["feature_whitening"]

    def learn(self, q, dq, dv, *, rate: float | None = None, adapt_references: bool = False) -> "InverseJacobianSOM":
        r"""Online update from observed moves (to keep learning while tracking).

        For each pair: the arm was at ``q``, moved by ``dq`` and the features
        changed by ``dv``. The pair is filed at the midpoint
        :math:`\mathbf q + \Delta\mathbf q/2` and the maps get one Widrow–Hoff
        step (``config.map_update``) at ``rate`` (default ``map_rate_final``),
        with the final neighbourhood width. Pairs with a non-finite entry
        (a missing measurement) or a zero move are skipped.

        Parameters
        ----------
        q, dq : array_like, shape (3,) or (n, 3)
            Start configuration and joint move (rad).
        dv : array_like, shape (3,) or (n, 3)
            Observed feature change (px).
        rate : float, optional
            Widrow–Hoff rate; > 0.
        adapt_references : bool, default False
            Also move the reference vectors (Kohonen step at
            ``reference_rate_final``). Off by default: tracking visits a small
            region and would pull the lattice into it.

        Returns
        -------
        self
        """
        config = self._config()
        q, dq, dv = (np.atleast_2d(as_joints(name, v)) for name, v in (("q", q), ("dq", dq), ("dv", dv)))
        if not (q.shape == dq.shape == dv.shape) or q.ndim != 2:
            raise ValueError(
                f"q, dq, dv: expected equal shapes (3,) or (n, 3), got {q.shape}, {dq.shape}, {dv.shape}"
            )
        if rate is None:
            rate = config.map_rate_final
        if not (np.isscalar(rate) and np.isfinite(rate) and rate > 0):
            raise ValueError(f"rate: expected a finite number > 0, got {rate!r}")
        state = self._ensure_state()
        whitening = state["feature_whitening"]
        for q_k, dq_k, dv_k in zip(q, dq, dv):
            if not (np.all(np.isfinite(q_k)) and np.all(np.isfinite(dq_k)) and np.all(np.isfinite(dv_k))):
                continue
            if not np.any(dq_k):
                continue
            self._update(
                q_k + 0.5 * dq_k,
                dq_k,
                whitening @ dv_k,
                reference_rate=config.reference_rate_final,
                map_rate=float(rate),
                width=config.neighbourhood_final,
                adapt_references=adapt_references,
            )
        return self

    def relative_error(self, arm, camera, qs) -> RelativeError:
        r"""Distance of the learned map from the analytic inverse Jacobian.

        .. math::

            \epsilon_i = \frac{\|\mathbf B(\mathbf q_i) - \mathbf J_f^{-1}(\mathbf q_i)\|_F}
                              {\|\mathbf J_f^{-1}(\mathbf q_i)\|_F},
            \qquad \mathbf J_f = ``arm.image\_jacobian(q, camera)``.

        Parameters
        ----------
        arm : kalmix.servo.Arm
        camera : kalmix.vision.StereoCamera
        qs : array_like, shape (n, 3)
            Joint configurations (rad), away from singularities.

        Returns
        -------
        RelativeError
            ``median``, ``mean`` and per-configuration ``values``.
        """
        qs = as_joints("qs", qs).reshape(-1, 3)
        truth = np.linalg.inv(arm.image_jacobian(qs, camera))
        learned = self.inverse_jacobian(qs)
        values = np.linalg.norm(learned - truth, axis=(-2, -1)) / np.linalg.norm(truth, axis=(-2, -1))
        return RelativeError(float(np.median(values)), float(np.mean(values)), values)

    # ------------------------------------------------------------------ training
    def _babble(self, arm, camera, rng: np.random.Generator, n: int):
        """n valid babbling moves: (start q, move dq, noisy dv); both ends in view and in limits."""
        config = self._config()
        low, high = self._box()
        starts, moves, changes = [], [], []
        have, attempts = 0, 0
        while have < n:
            attempts += 1
            if attempts > 50:
                raise ValueError(
                    "joint_low, joint_high: babbling found too few configurations whose end "
                    "effector is in view of both cameras; expected a box in front of the cameras"
                )
            m = max(2 * (n - have), 16)
            q = rng.uniform(low, high, size=(m, 3))
            dq = config.babbling_step_rad * rng.standard_normal((m, 3))
            q_end = np.clip(q + dq, arm.low, arm.high)
            dq = q_end - q
            p0, p1 = arm.forward(q), arm.forward(q_end)
            front = (p0[:, 2] > 1e-3) & (p1[:, 2] > 1e-3)
            q, dq, p0, p1 = q[front], dq[front], p0[front], p1[front]
            v0, v1 = camera.project(p0), camera.project(p1)
            ok = camera.in_view(v0) & camera.in_view(v1) & np.any(dq != 0, axis=-1)
            noise = config.feature_noise_px * rng.standard_normal((2,) + v0.shape)
            dv = (v1 + noise[1]) - (v0 + noise[0])
            starts.append(q[ok]), moves.append(dq[ok]), changes.append(dv[ok])
            have += int(np.sum(ok))
        return (np.concatenate(starts)[:n], np.concatenate(moves)[:n], np.concatenate(changes)[:n])

    def fit(self, arm, camera, *, validation_joints=None,
            progress: Callable[[int, int, float], None] | None = None) -> TrainingHistory:
        r"""Train from scratch by random babbling.

        Resets the lattice (reference vectors on the cell centres of a regular
        grid, maps zero), draws ``n_training_moves`` babbling moves (see the
        module docstring), sets the whitening :math:`\mathbf T` from them, and
        learns them one by one with rates

        .. math::

            \varepsilon(k) = \varepsilon_0 (\varepsilon_1 / \varepsilon_0)^{k/K},
            \qquad k = 0, \dots, K - 1 .

        Parameters
        ----------
        arm : kalmix.servo.Arm
        camera : kalmix.vision.StereoCamera
        validation_joints : array_like, shape (n, 3), optional
            Configurations for the learning curve. Default: ``n_validation``
            configurations uniform in the joint box, from the config's seed
            (the same for every ``n_training_moves``).
        progress : callable, optional
            ``progress(moves_done, n_training_moves, median_relative_error)``,
            called at every evaluation.

        Returns
        -------
        TrainingHistory
        """
        start_time = time.perf_counter()
        config = self._config()
        low, high = self._box()
        babble_seq, validation_seq = np.random.SeedSequence(config.seed).spawn(2)
        if validation_joints is None:
            validation_joints = np.random.default_rng(validation_seq).uniform(
                low, high, size=(config.n_validation, 3)
            )
        validation_joints = as_joints("validation_joints", validation_joints).reshape(-1, 3)

        self._state = self._fresh_state()
        n_moves = config.n_training_moves
        moves_log, medians, means = [], [], []

        def evaluate(done: int) -> None:
            error = self.relative_error(arm, camera, validation_joints)
            moves_log.append(done), medians.append(error.median), means.append(error.mean)
            if progress is not None:
                progress(done, n_moves, error.median)

        if n_moves:
            q, dq, dv = self._babble(arm, camera, np.random.default_rng(babble_seq), n_moves)
            second_moment = dv.T @ dv / n_moves + 1e-9 * np.eye(3)
            try:
                cholesky = np.linalg.cholesky(second_moment)
                self._state["feature_whitening"] = np.linalg.solve(cholesky, np.eye(3))
            except np.linalg.LinAlgError:  # too few moves to span 3-D: keep the isotropic scale
                pass
            x = dv @ self._state["feature_whitening"].T
            fraction = np.arange(n_moves) / n_moves

            def schedule(initial: float, final: float) -> np.ndarray:
                return initial * (final / initial) ** fraction

            reference_rates = schedule(config.reference_rate_initial, config.reference_rate_final)
            map_rates = schedule(config.map_rate_initial, config.map_rate_final)
            widths = schedule(config.neighbourhood_initial, config.neighbourhood_final)
            midpoints = q + 0.5 * dq

        evaluate(0)
        for k in range(n_moves):
            self._update(
                midpoints[k],
                dq[k],
                x[k],
                reference_rate=reference_rates[k],
                map_rate=map_rates[k],
                width=widths[k],
                adapt_references=True,
            )
            if (k + 1) % config.evaluation_every == 0 or k + 1 == n_moves:
                evaluate(k + 1)
        return TrainingHistory(
            moves=np.array(moves_log, dtype=int),
            median_relative_error=np.array(medians),
            mean_relative_error=np.array(means),
            training_seconds=time.perf_counter() - start_time,
        )

    # ------------------------------------------------------------------ saving
    def state_dict(self) -> dict:
        """Everything needed to rebuild the SOM: config (as a dict), box and arrays (copies)."""
        state = self._ensure_state()
        return {
            "config": asdict(self._config()),
            "joint_low": state["joint_low"].copy(),
            "joint_high": state["joint_high"].copy(),
            "reference_vectors": state["reference_vectors"].copy(),
            "whitened_maps": state["whitened_maps"].copy(),
            "feature_whitening": state["feature_whitening"].copy(),
            "moves_seen": int(state["moves_seen"]),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> "InverseJacobianSOM":
        """Inverse of :meth:`state_dict`; validates array shapes."""
        config_dict = dict(state["config"])
        config_dict["lattice_shape"] = tuple(int(n) for n in config_dict["lattice_shape"])
        known = {f.name for f in fields(SOMConfig)}
        config = SOMConfig(**{k: v for k, v in config_dict.items() if k in known})
        som = cls(config, state["joint_low"], state["joint_high"])
        fresh = som._fresh_state()
        n = len(fresh["lattice_indices"])
        expected = {
            "reference_vectors": (n, 3),
            "whitened_maps": (n, 3, 3),
            "feature_whitening": (3, 3),
        }
        for name, shape in expected.items():
            array = np.array(state[name], dtype=float)
            if array.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
            fresh[name] = array
        fresh["moves_seen"] = int(state.get("moves_seen", 0))
        som._state = fresh
        return som
