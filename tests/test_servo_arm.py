"""Tests for kalmix.servo.arm: kinematics, Jacobians, inverse kinematics, geometry claims."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from kalmix.servo import TARGET_REGION_HALF_WIDTHS, WORKSPACE_CENTRE, WORKSPACE_HALF_WIDTHS, Arm


def _box_grid(half_widths, n=9) -> np.ndarray:
    grid = np.linspace(-1.0, 1.0, n)
    offsets = np.array(list(itertools.product(grid, grid, grid)))
    return np.array(WORKSPACE_CENTRE) + offsets * np.array(half_widths)


def _random_target_joints(arm: Arm, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = np.array(WORKSPACE_CENTRE) + rng.uniform(-1, 1, (n, 3)) * np.array(TARGET_REGION_HALF_WIDTHS)
    return arm.inverse(points)


def _central_difference(function, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    columns = []
    for j in range(3):
        step = np.zeros(3)
        step[j] = eps
        columns.append((function(q + step) - function(q - step)) / (2 * eps))
    return np.stack(columns, axis=-1)


# ---------------------------------------------------------------- forward kinematics
@pytest.mark.parametrize(
    "q, expected",
    [
        # stretched toward the cameras: shoulder (0, 0, 1.9) minus the 1.2 m reach in z
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.7)),
        # upper arm straight up, forearm horizontal toward the cameras
        ((0.0, np.pi / 2, np.pi / 2), (0.0, 0.6, 1.3)),
        # yawed a quarter turn toward +x, stretched
        ((np.pi / 2, 0.0, 0.0), (1.2, 0.0, 1.9)),
        # symmetric elbow-up posture: wrist level with the shoulder, 2 * 0.6 cos 45° in front
        ((0.0, np.pi / 4, np.pi / 2), (0.0, 0.0, 1.9 - 1.2 * np.cos(np.pi / 4))),
        # yaw 30°, upper arm up 60°, forearm horizontal
        (
            (np.pi / 6, np.pi / 3, np.pi / 3),
            (
                (0.6 * np.cos(np.pi / 3) + 0.6) * np.sin(np.pi / 6),
                0.6 * np.sin(np.pi / 3),
                1.9 - (0.6 * np.cos(np.pi / 3) + 0.6) * np.cos(np.pi / 6),
            ),
        ),
    ],
)
def test_forward_matches_hand_computed_positions(arm, q, expected):
    np.testing.assert_allclose(arm.forward(q), expected, atol=1e-12)


def test_forward_is_batched(arm):
    rng = np.random.default_rng(0)
    q = rng.uniform(arm.low, arm.high, (4, 5, 3))
    batched = arm.forward(q)
    assert batched.shape == (4, 5, 3)
    looped = np.array([[arm.forward(q[i, j]) for j in range(5)] for i in range(4)])
    np.testing.assert_allclose(batched, looped, atol=1e-15)


# ---------------------------------------------------------------- Jacobians
def test_jacobian_matches_finite_differences(arm):
    rng = np.random.default_rng(1)
    q = rng.uniform(arm.low, arm.high, (4, 5, 3))
    analytic = arm.jacobian(q)
    assert analytic.shape == (4, 5, 3, 3)
    numeric = _central_difference(arm.forward, q)
    np.testing.assert_allclose(analytic, numeric, atol=1e-8)


def test_jacobian_determinant_formula(arm):
    """det dp/dq = rho L1 L2 sin q2: singular on the yaw axis and at a stretched elbow."""
    rng = np.random.default_rng(2)
    q = rng.uniform(arm.low, arm.high, (50, 3))
    rho = arm.upper_arm_length * np.cos(q[:, 1]) + arm.forearm_length * np.cos(q[:, 1] - q[:, 2])
    expected = rho * arm.upper_arm_length * arm.forearm_length * np.sin(q[:, 2])
    np.testing.assert_allclose(np.linalg.det(arm.jacobian(q)), expected, atol=1e-12)


def test_image_jacobian_matches_finite_differences_of_image_features(arm, camera):
    q = _random_target_joints(arm, 20, seed=3).reshape(4, 5, 3)
    analytic = arm.image_jacobian(q, camera)
    assert analytic.shape == (4, 5, 3, 3)
    numeric = _central_difference(lambda x: arm.image_features(x, camera), q)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-5)


def test_image_features_are_the_projection_of_the_end_effector(arm, camera):
    q = _random_target_joints(arm, 10, seed=4)
    np.testing.assert_allclose(arm.image_features(q, camera), camera.project(arm.forward(q)))


# ---------------------------------------------------------------- inverse kinematics
def test_inverse_round_trip_from_points(arm):
    points = _box_grid(WORKSPACE_HALF_WIDTHS)
    q = arm.inverse(points)
    np.testing.assert_allclose(arm.forward(q), points, atol=1e-12)
    assert np.all(q[:, 2] > 0), "inverse must return the elbow-up branch (q2 > 0)"


def test_inverse_round_trip_from_joints(arm):
    low, high = arm.joint_box()
    q = np.random.default_rng(5).uniform(low, high, (200, 3))
    np.testing.assert_allclose(arm.inverse(arm.forward(q)), q, atol=1e-10)


def test_inverse_out_of_reach_raises(arm):
    with pytest.raises(ValueError, match="points"):
        arm.inverse([[0.0, 0.0, -1.0]])


# ---------------------------------------------------------------- geometry claims (module docstring)
def test_workspace_cube_is_reachable_elbow_up_within_limits(arm):
    points = _box_grid(WORKSPACE_HALF_WIDTHS)
    q = arm.inverse(points)
    assert np.all(arm.within_limits(q))
    flexion = np.degrees(q[:, 2])
    assert flexion.min() > 25 and flexion.max() < 150
    rho = np.hypot(*(points - arm.shoulder_position)[:, [0, 2]].T)
    assert rho.min() >= 0.35 - 1e-9
    singular_values = np.linalg.svd(arm.jacobian(q), compute_uv=False)
    assert np.max(singular_values[:, 0] / singular_values[:, -1]) < 10


def test_target_region_is_far_from_singularities_and_in_view(arm, camera):
    points = _box_grid(TARGET_REGION_HALF_WIDTHS)
    q = arm.inverse(points)
    assert np.all(arm.within_limits(q))
    assert np.all(camera.in_view(arm.image_features(q, camera)))
    flexion = np.degrees(q[:, 2])
    assert flexion.min() > 70 and flexion.max() < 130
    singular_values = np.linalg.svd(arm.jacobian(q), compute_uv=False)
    assert np.max(singular_values[:, 0] / singular_values[:, -1]) < 3.5


def test_speed_limits_allow_tracking_at_1_5_metres_per_second(arm):
    """Worst direction of a 1.5 m/s target in the target region needs less than the limits."""
    q = arm.inverse(_box_grid(TARGET_REGION_HALF_WIDTHS))
    needed = 1.5 * np.linalg.norm(np.linalg.inv(arm.jacobian(q)), axis=-1)  # (n, joint)
    assert np.all(needed.max(axis=0) < arm.speed_limit)


def test_joint_box_contains_the_target_region(arm):
    low, high = arm.joint_box(margin=0.1)
    q = _random_target_joints(arm, 500, seed=6)
    assert np.all(q >= low + 0.1 - 1e-9) and np.all(q <= high - 0.1 + 1e-9)
    assert np.all(low >= arm.low) and np.all(high <= arm.high)


# ---------------------------------------------------------------- limits
def test_clip_and_within_limits(arm):
    q = np.array([[-5.0, 0.0, 1.0], [0.0, 5.0, 1.0], [0.1, 0.2, 0.3]])
    clipped = arm.clip(q)
    np.testing.assert_allclose(clipped[0], [arm.low[0], 0.0, 1.0])
    np.testing.assert_allclose(clipped[1], [0.0, arm.high[1], 1.0])
    np.testing.assert_array_equal(arm.within_limits(q), [False, False, True])
    assert np.all(arm.within_limits(clipped))


def test_limit_step_keeps_direction_and_respects_speed(arm):
    dt = 0.04
    dq = np.array([[1.0, -0.5, 0.2], [0.01, 0.0, 0.0]])
    limited = arm.limit_step(dq, dt)
    assert np.all(np.abs(limited) <= arm.speed_limit * dt + 1e-12)
    # direction kept
    np.testing.assert_allclose(limited[0] / np.linalg.norm(limited[0]), dq[0] / np.linalg.norm(dq[0]))
    # small steps untouched
    np.testing.assert_allclose(limited[1], dq[1])


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"upper_arm_length": -0.1}, "upper_arm_length"),
        ({"forearm_length": 0.0}, "forearm_length"),
        ({"joint_low": (0.0, 0.0, 3.0)}, "joint_low"),
        ({"joint_speed_limit": (1.0, 0.0, 1.0)}, "joint_speed_limit"),
        ({"base_position": (0.0, 1.0)}, "base_position"),
    ],
)
def test_bad_arm_values_raise_naming_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Arm(**kwargs)
