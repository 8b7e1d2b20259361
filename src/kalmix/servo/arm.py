"""Kinematics of the simulated three-joint (RRR) arm used for visual servoing.

The arm has a base yaw ``q0`` about the vertical axis, a shoulder ``q1`` and an
elbow ``q2`` (both pitch joints), like the 3-DOF arm of the paper's section 5.
Everything is batched on leading axes: a joint vector has shape ``(..., 3)``
and a Jacobian ``(..., 3, 3)``.

World frame (shared with :mod:`kalmix.vision`): ``x`` to the right, ``y`` up,
``z`` in depth away from the cameras, which sit at ``z = 0`` and look along
``+z``. The target moves around ``(0, 0, 1.2)`` m.

Geometry (defaults of :class:`Arm`, in metres)
---------------------------------------------
- Base at ``(0, -0.3, 1.9)``: 0.7 m *behind* the centre of the target region,
  so the arm reaches toward the cameras and the end effector faces them.
- Base height 0.3 m: the shoulder is at ``(0, 0, 1.9)``, level with the
  centre of the target region.
- Upper arm 0.6 m and forearm 0.6 m (reach 1.2 m).

Why these numbers (and not shorter links, such as 0.45 m): the yaw axis must stay out
of the workspace (on it the base joint moves nothing, ``det J = 0``), which
pushes the shoulder at least ~0.35 m away from the cube ``(0, 0, 1.2) ± 0.35``
m; the far corners of the cube are then ~1.15 m from the shoulder, beyond the
0.9 m reach of two 0.45 m links. With 0.6 m links and the shoulder at
``z = 1.9`` every point of that cube is reachable elbow-up (elbow flexion
between 29° and 146°, distance to the yaw axis ≥ 0.35 m, Jacobian condition
number ≤ 10), and the region the target actually visits (``± 0.3`` m in x and
y, ``± 0.15`` m in depth, see :data:`TARGET_REGION_HALF_WIDTHS`) is far from
any singularity (flexion 75°–125°, condition number ≤ 3.3). The test suite
checks these figures numerically. (The near corners of the cube, at
``z = 0.85`` m and ``|x| = 0.35`` m, fall outside one camera's image: a limit of
the cameras, not of the arm; the target region is fully in view.)

Joint conventions
-----------------
- ``q0`` (base yaw): 0 points the arm toward the cameras (``-z``); positive
  values swing it toward ``+x``.
- ``q1`` (shoulder): elevation of the upper arm above the horizontal plane.
- ``q2`` (elbow): flexion, i.e. the forearm's elevation is ``q1 - q2``.
  ``q2 > 0`` is the elbow-up posture (elbow above the shoulder–wrist line),
  ``q2 = 0`` (stretched) and ``q2 = π`` (folded) are singular.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Arm",
    "WORKSPACE_CENTRE",
    "WORKSPACE_HALF_WIDTHS",
    "TARGET_REGION_HALF_WIDTHS",
]

#: Centre of the region the target moves in (m), 1.2 m in front of the cameras.
WORKSPACE_CENTRE = (0.0, 0.0, 1.2)
#: Half-widths (m) of the cube the arm must be able to reach.
WORKSPACE_HALF_WIDTHS = (0.35, 0.35, 0.35)
#: Half-widths (m) of the box the simulated target visits: a circle of radius
#: 0.25 m in the x-y plane with a small depth oscillation, then small moves in
#: a 4 cm cube (:class:`kalmix.scenarios.PaperScenario`), plus a margin.
TARGET_REGION_HALF_WIDTHS = (0.3, 0.3, 0.15)


def _as_triple(name: str, value) -> tuple[float, float, float]:
    array = np.asarray(value, dtype=float)
    if array.shape != (3,):
        raise ValueError(f"{name}: expected 3 values, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: expected finite values, got {array.tolist()}")
    return tuple(float(v) for v in array)


@dataclass(frozen=True)
class Arm:
    r"""A three-joint arm: base yaw, shoulder pitch, elbow pitch.

    Forward kinematics, with shoulder :math:`\mathbf s = \mathbf b + (0, h_b, 0)`,
    horizontal heading :math:`\mathbf d(q_0) = (\sin q_0, 0, -\cos q_0)` and
    vertical :math:`\mathbf e_y = (0, 1, 0)`:

    .. math::

        \rho &= L_1 \cos q_1 + L_2 \cos(q_1 - q_2), \qquad
        \eta = L_1 \sin q_1 + L_2 \sin(q_1 - q_2), \\
        \mathbf p(\mathbf q) &= \mathbf s + \rho\, \mathbf d(q_0) + \eta\, \mathbf e_y .

    :math:`\rho` is the distance of the end effector from the yaw axis and
    :math:`\eta` its height above the shoulder.
    :math:`\det \partial\mathbf p/\partial\mathbf q = \rho L_1 L_2 \sin q_2`, so
    the arm is singular on the yaw axis and at a stretched or folded elbow.

    Parameters
    ----------
    base_position : tuple of 3 float
        Foot of the base (m), world frame.
    base_height : float
        Height of the shoulder above the base foot (m).
    upper_arm_length, forearm_length : float
        Link lengths :math:`L_1`, :math:`L_2` (m).
    joint_low, joint_high : tuple of 3 float
        Joint limits (rad).
    joint_speed_limit : tuple of 3 float
        Largest joint speed (rad/s). At 1.5 m/s in the target region the worst
        direction needs about (2.7, 3.1, 4.1) rad/s.
    """

    base_position: tuple[float, float, float] = (0.0, -0.3, 1.9)
    base_height: float = 0.3
    upper_arm_length: float = 0.6
    forearm_length: float = 0.6
    joint_low: tuple[float, float, float] = (-1.3, -0.5, 0.2)
    joint_high: tuple[float, float, float] = (1.3, 2.3, 2.9)
    joint_speed_limit: tuple[float, float, float] = (4.0, 4.0, 5.0)

    def __post_init__(self) -> None:
        for name in ("base_position", "joint_low", "joint_high", "joint_speed_limit"):
            object.__setattr__(self, name, _as_triple(name, getattr(self, name)))
        for name in ("base_height", "upper_arm_length", "forearm_length"):
            value = float(getattr(self, name))
            if name != "base_height" and not value > 0:
                raise ValueError(f"{name}: expected a positive length (m), got {value}")
            if not np.isfinite(value):
                raise ValueError(f"{name}: expected a finite length (m), got {value}")
            object.__setattr__(self, name, value)
        low, high = np.array(self.joint_low), np.array(self.joint_high)
        if np.any(low >= high):
            raise ValueError(
                f"joint_low: expected joint_low < joint_high for every joint, "
                f"got joint_low={self.joint_low}, joint_high={self.joint_high}"
            )
        if np.any(np.array(self.joint_speed_limit) <= 0):
            raise ValueError(
                f"joint_speed_limit: expected positive speeds (rad/s), got {self.joint_speed_limit}"
            )

    # ------------------------------------------------------------------ geometry
    @property
    def shoulder_position(self) -> np.ndarray:
        """Position of the shoulder joint, ``base_position + (0, base_height, 0)`` (m)."""
        return np.array(self.base_position) + np.array([0.0, self.base_height, 0.0])

    @property
    def low(self) -> np.ndarray:
        """Lower joint limits as an array (rad)."""
        return np.array(self.joint_low)

    @property
    def high(self) -> np.ndarray:
        """Upper joint limits as an array (rad)."""
        return np.array(self.joint_high)

    @property
    def speed_limit(self) -> np.ndarray:
        """Joint speed limits as an array (rad/s)."""
        return np.array(self.joint_speed_limit)

    def _planar(self, q: np.ndarray):
        q0, q1, q2 = q[..., 0], q[..., 1], q[..., 2]
        forearm_elevation = q1 - q2
        rho = self.upper_arm_length * np.cos(q1) + self.forearm_length * np.cos(forearm_elevation)
        eta = self.upper_arm_length * np.sin(q1) + self.forearm_length * np.sin(forearm_elevation)
        heading = np.stack([np.sin(q0), np.zeros_like(q0), -np.cos(q0)], axis=-1)
        return q0, forearm_elevation, rho, eta, heading

    def forward(self, q) -> np.ndarray:
        r"""End-effector position :math:`\mathbf p(\mathbf q)`.

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Joint angles (rad).

        Returns
        -------
        numpy.ndarray, shape (..., 3)
            Position in the world frame (m).
        """
        q = np.asarray(q, dtype=float)
        _, _, rho, eta, heading = self._planar(q)
        up = np.array([0.0, 1.0, 0.0])
        return self.shoulder_position + rho[..., None] * heading + eta[..., None] * up

    def jacobian(self, q) -> np.ndarray:
        r"""Analytic Jacobian :math:`\partial\mathbf p / \partial\mathbf q`.

        .. math::

            \frac{\partial\mathbf p}{\partial q_0} = \rho\,(\cos q_0, 0, \sin q_0), \quad
            \frac{\partial\mathbf p}{\partial q_1} = -\eta\,\mathbf d + \rho\,\mathbf e_y, \quad
            \frac{\partial\mathbf p}{\partial q_2} = L_2 \sin(q_1 - q_2)\,\mathbf d
                - L_2 \cos(q_1 - q_2)\,\mathbf e_y .

        Parameters
        ----------
        q : array_like, shape (..., 3)

        Returns
        -------
        numpy.ndarray, shape (..., 3, 3)
            ``J[..., i, j] = d p_i / d q_j`` (m/rad).
        """
        q = np.asarray(q, dtype=float)
        q0, forearm_elevation, rho, eta, heading = self._planar(q)
        zeros = np.zeros_like(q0)
        up = np.broadcast_to(np.array([0.0, 1.0, 0.0]), heading.shape)
        column0 = rho[..., None] * np.stack([np.cos(q0), zeros, np.sin(q0)], axis=-1)
        column1 = -eta[..., None] * heading + rho[..., None] * up
        column2 = (self.forearm_length * np.sin(forearm_elevation))[..., None] * heading - (
            self.forearm_length * np.cos(forearm_elevation)
        )[..., None] * up
        return np.stack([column0, column1, column2], axis=-1)

    def inverse(self, points) -> np.ndarray:
        r"""Analytic inverse kinematics, elbow-up branch.

        With :math:`\boldsymbol\delta = \mathbf p - \mathbf s`,
        :math:`\rho = \sqrt{\delta_x^2 + \delta_z^2}`, :math:`\eta = \delta_y`:

        .. math::

            q_0 &= \operatorname{atan2}(\delta_x, -\delta_z), \qquad
            \cos q_2 = \frac{\rho^2 + \eta^2 - L_1^2 - L_2^2}{2 L_1 L_2},
            \quad q_2 \in [0, \pi], \\
            q_1 &= \operatorname{atan2}(\eta, \rho)
                 + \operatorname{atan2}(L_2 \sin q_2, L_1 + L_2 \cos q_2).

        Joint limits are not applied (see :meth:`within_limits`).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            End-effector positions (m).

        Returns
        -------
        numpy.ndarray, shape (..., 3)
            Joint angles (rad) with ``forward(inverse(p)) == p``.

        Raises
        ------
        ValueError
            If a point is outside the annulus of reach
            :math:`|L_1 - L_2| \le \|\boldsymbol\delta\| \le L_1 + L_2`.
        """
        points = np.asarray(points, dtype=float)
        delta = points - self.shoulder_position
        rho = np.hypot(delta[..., 0], delta[..., 2])
        eta = delta[..., 1]
        l1, l2 = self.upper_arm_length, self.forearm_length
        cos_q2 = (rho**2 + eta**2 - l1**2 - l2**2) / (2.0 * l1 * l2)
        bad = ~(np.abs(cos_q2) <= 1.0 + 1e-12)
        if np.any(bad):
            raise ValueError(
                f"points: expected positions within reach of the arm "
                f"({abs(l1 - l2):.3g} m to {l1 + l2:.3g} m from the shoulder at "
                f"{self.shoulder_position.tolist()}), got {int(np.sum(bad))} point(s) out of reach"
            )
        q2 = np.arccos(np.clip(cos_q2, -1.0, 1.0))
        q1 = np.arctan2(eta, rho) + np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
        q0 = np.arctan2(delta[..., 0], -delta[..., 2])
        return np.stack([q0, q1, q2], axis=-1)

    # ------------------------------------------------------------------ limits
    def clip(self, q) -> np.ndarray:
        """Clip joint angles to ``[joint_low, joint_high]`` (rad), shape ``(..., 3)``."""
        return np.clip(np.asarray(q, dtype=float), self.low, self.high)

    def within_limits(self, q) -> np.ndarray:
        """Boolean array ``(...)``: every joint within its limits."""
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.low) & (q <= self.high), axis=-1)

    def limit_step(self, dq, dt: float) -> np.ndarray:
        r"""Scale a joint step so that no joint exceeds its speed limit.

        The whole step is scaled by one factor (its direction is kept):

        .. math::

            \Delta\mathbf q' = \Delta\mathbf q \,
            \min\Bigl(1, \min_i \frac{\dot q_{i,\max}\, \Delta t}{|\Delta q_i|}\Bigr).

        Parameters
        ----------
        dq : array_like, shape (..., 3)
            Requested joint step (rad).
        dt : float
            Duration of the step (s).

        Returns
        -------
        numpy.ndarray, shape (..., 3)
        """
        dq = np.asarray(dq, dtype=float)
        allowed = self.speed_limit * float(dt)
        ratio = np.max(np.abs(dq) / allowed, axis=-1, keepdims=True)
        return dq / np.maximum(ratio, 1.0)

    def joint_box(self, centre=WORKSPACE_CENTRE, half_widths=TARGET_REGION_HALF_WIDTHS, *,
                  margin: float = 0.1, points_per_axis: int = 9):
        """Joint-space bounding box of a Cartesian box, for focusing a learner.

        Solves :meth:`inverse` on a ``points_per_axis``³ grid of the box
        ``centre ± half_widths``, takes the per-joint minimum and maximum, widens
        them by ``margin`` rad on each side and clips to the joint limits.

        Parameters
        ----------
        centre, half_widths : tuple of 3 float
            The Cartesian box (m).
        margin : float
            Widening on each side (rad).
        points_per_axis : int
            Grid resolution.

        Returns
        -------
        low, high : numpy.ndarray, shape (3,)
        """
        centre = np.array(_as_triple("centre", centre))
        half_widths = np.array(_as_triple("half_widths", half_widths))
        if margin < 0:
            raise ValueError(f"margin: expected >= 0 rad, got {margin}")
        grid = np.linspace(-1.0, 1.0, int(points_per_axis))
        offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), axis=-1).reshape(-1, 3)
        q = self.inverse(centre + offsets * half_widths)
        low = np.maximum(q.min(axis=0) - margin, self.low)
        high = np.minimum(q.max(axis=0) + margin, self.high)
        return low, high

    # ------------------------------------------------------------------ camera
    def image_features(self, q, camera) -> np.ndarray:
        r"""Image features of the end effector, :math:`\mathbf v = \mathbf f(\mathbf q)`.

        The paper's eq. (2): :math:`\mathbf f = \pi \circ \mathbf p`, with
        :math:`\pi` the stereo projection ``camera.project``, so
        ``v = (u_left, u_right, v)`` in pixels.

        Parameters
        ----------
        q : array_like, shape (..., 3)
        camera : kalmix.vision.StereoCamera

        Returns
        -------
        numpy.ndarray, shape (..., 3)
        """
        return camera.project(self.forward(q))

    def image_jacobian(self, q, camera) -> np.ndarray:
        r"""Image Jacobian :math:`\mathbf J_f = \partial\mathbf f / \partial\mathbf q`.

        .. math::

            \mathbf J_f(\mathbf q) = \frac{\partial \pi}{\partial \mathbf p}
            \bigl(\mathbf p(\mathbf q)\bigr)\,
            \frac{\partial \mathbf p}{\partial \mathbf q}(\mathbf q)

        The paper's controller uses its inverse, eq. (3):
        :math:`\Delta\mathbf q = \mathbf B\,\mathbf e` with
        :math:`\mathbf B \approx \mathbf J_f^{-1}`.

        Returns
        -------
        numpy.ndarray, shape (..., 3, 3)
            Pixels per radian.
        """
        q = np.asarray(q, dtype=float)
        return camera.jacobian(self.forward(q)) @ self.jacobian(q)
