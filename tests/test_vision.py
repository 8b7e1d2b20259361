"""Tests for kalmix.vision: stereo projection, its Jacobian and inverse, and noisy observation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kalmix.vision import Observation, StereoCamera

CAMERA = StereoCamera()
CX, CY = CAMERA.image_width_px / 2, CAMERA.image_height_px / 2
F, B = CAMERA.focal_length_px, CAMERA.baseline_m


def _points(rng, shape=(50,)):
    xy = rng.uniform(-0.3, 0.3, size=shape + (2,))
    z = rng.uniform(0.6, 2.5, size=shape + (1,))
    return np.concatenate([xy, z], axis=-1)


def test_project_triangulate_round_trip_batched():
    points = _points(np.random.default_rng(0), shape=(4, 7))
    features = CAMERA.project(points)
    assert features.shape == (4, 7, 3)
    np.testing.assert_allclose(CAMERA.triangulate(features), points, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(CAMERA.project(CAMERA.triangulate(features)), features, rtol=1e-12)


@settings(max_examples=50)
@given(
    x=st.floats(-1.0, 1.0),
    y=st.floats(-1.0, 1.0),
    z=st.floats(0.2, 5.0),
)
def test_round_trip_property(x, y, z):
    point = np.array([x, y, z])
    np.testing.assert_allclose(CAMERA.triangulate(CAMERA.project(point)), point, rtol=1e-9, atol=1e-12)


def test_point_on_left_optical_axis():
    z = 1.7
    features = CAMERA.project([-B / 2, 0.0, z])
    np.testing.assert_allclose(features, [CX, CX - F * B / z, CY], rtol=1e-14)


def test_y_up_moves_feature_up_in_image():
    low, high = CAMERA.project([[0.0, 0.0, 1.0], [0.0, 0.1, 1.0]])
    assert high[2] < low[2]


def test_jacobian_matches_finite_differences():
    points = _points(np.random.default_rng(1), shape=(20,))
    jac = CAMERA.jacobian(points)
    assert jac.shape == (20, 3, 3)
    step = 1e-6
    numeric = np.empty_like(jac)
    for j in range(3):
        delta = np.zeros(3)
        delta[j] = step
        numeric[..., j] = (CAMERA.project(points + delta) - CAMERA.project(points - delta)) / (2 * step)
    scale = np.abs(jac).max(axis=(-2, -1), keepdims=True)
    np.testing.assert_allclose(jac / scale, numeric / scale, atol=1e-6)


def test_in_view():
    inside = CAMERA.project([[0.0, 0.0, 1.2], [0.1, -0.1, 2.0]])
    assert CAMERA.in_view(inside).all()
    outside = np.array(
        [
            [-1.0, 100.0, 200.0],  # u_left < 0
            [800.0, 300.0, 200.0],  # u_left >= width
            [400.0, 768.0, 200.0],  # u_right == width
            [400.0, 300.0, 576.0],  # v == height
            [400.0, 300.0, -0.5],  # v < 0
            [np.nan, 300.0, 200.0],  # missing
            [np.inf, 300.0, 200.0],
        ]
    )
    assert not CAMERA.in_view(outside).any()
    assert CAMERA.project([2.0, 0.0, 1.0])[0] > CAMERA.image_width_px
    assert not CAMERA.in_view(CAMERA.project([2.0, 0.0, 1.0]))


def test_pixel_to_metre_scale():
    np.testing.assert_allclose(CAMERA.pixel_to_metre_scale([[0, 0, 1.2], [0.1, 0, 2.4]]), [1.2 / F, 2.4 / F])


def _line(n=40):
    return np.column_stack([np.linspace(-0.2, 0.2, n), np.zeros(n), np.full(n, 1.2)])


def test_observe_clean_noise_and_shapes():
    points = _line()
    obs = CAMERA.observe(points, noise_px=0.5, seed=3)
    assert isinstance(obs, Observation)
    assert obs.clean.shape == obs.measured.shape == (40, 3) and obs.visible.shape == (40,)
    assert obs.out_of_view_count == 0 and obs.visible.all()
    np.testing.assert_allclose(obs.clean, CAMERA.project(points))
    assert 0.3 < np.std(obs.measured - obs.clean) < 0.7
    exact = CAMERA.observe(points, noise_px=0.0, seed=3)
    np.testing.assert_array_equal(exact.measured, exact.clean)


def test_observe_out_of_view_rows_nan_warned_and_counted():
    points = _line()
    points[5:8, 0] = 2.0  # far right: out of both images
    with pytest.warns(RuntimeWarning, match="3 of 40 frames"):
        obs = CAMERA.observe(points, seed=0)
    assert obs.out_of_view_count == 3
    assert not obs.visible[5:8].any() and obs.visible[[4, 8]].all()
    assert np.isnan(obs.measured[5:8]).all()
    assert np.isfinite(obs.measured[obs.visible]).all()


def test_observe_delay_shifts_by_exactly_delay_frames():
    points = _line()
    points[10, 0] = 2.0
    with pytest.warns(RuntimeWarning):
        base = CAMERA.observe(points, seed=7)
    with pytest.warns(RuntimeWarning):
        delayed = CAMERA.observe(points, delay_frames=3, seed=7)
    assert np.isnan(delayed.measured[:3]).all()
    np.testing.assert_array_equal(delayed.measured[3:], base.measured[:-3])
    np.testing.assert_array_equal(delayed.visible, base.visible)
    np.testing.assert_array_equal(delayed.clean, base.clean)
    assert np.isnan(delayed.measured[13]).all()


def test_observe_batched_leading_axes():
    points = np.stack([_line(), _line() + [0.0, 0.1, 0.3]])
    obs = CAMERA.observe(points, delay_frames=2, seed=1)
    assert obs.measured.shape == (2, 40, 3) and obs.visible.shape == (2, 40)
    assert np.isnan(obs.measured[:, :2]).all() and np.isfinite(obs.measured[:, 2:]).all()


def test_observe_seeding():
    points = _line()
    first = CAMERA.observe(points, seed=11).measured
    np.testing.assert_array_equal(first, CAMERA.observe(points, seed=11).measured)
    np.testing.assert_array_equal(first, CAMERA.observe(points, seed=np.random.default_rng(11)).measured)
    assert not np.allclose(first, CAMERA.observe(points, seed=12).measured)


def test_observe_does_not_mutate_input():
    points = _line()
    copy = points.copy()
    CAMERA.observe(points, seed=0, delay_frames=2)
    np.testing.assert_array_equal(points, copy)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: CAMERA.project(np.zeros((10, 2))), r"points: expected shape \(\.\.\., 3\), got \(10, 2\)"),
        (lambda: CAMERA.project([0.0, np.nan, 1.0]), "points: expected finite"),
        (lambda: CAMERA.project([0.0, 0.0, 0.0]), "points: expected depth z > 0"),
        (lambda: CAMERA.jacobian([[0.0, 0.0, -1.0]]), "points: expected depth z > 0"),
        (lambda: CAMERA.pixel_to_metre_scale(np.ones((3, 4))), "points: expected shape"),
        (lambda: CAMERA.triangulate(np.ones((5, 2))), r"features: expected shape \(\.\.\., 3\), got \(5, 2\)"),
        (lambda: CAMERA.triangulate([100.0, 200.0, 100.0]), "features: expected positive disparity"),
        (lambda: CAMERA.triangulate([np.nan, 200.0, 100.0]), "features: expected finite"),
        (lambda: CAMERA.in_view(np.ones(4)), "features: expected shape"),
        (lambda: CAMERA.observe(np.array([0.0, 0.0, 1.0]), seed=0), r"points: expected shape \(T, 3\)"),
        (lambda: CAMERA.observe(_line(), noise_px=-1.0, seed=0), "noise_px: expected"),
        (lambda: CAMERA.observe(_line(), delay_frames=-1, seed=0), "delay_frames: expected"),
        (lambda: CAMERA.observe(_line(), delay_frames=1.5, seed=0), "delay_frames: expected"),
        (lambda: CAMERA.observe(_line(), seed=None), "seed: expected"),
        (lambda: StereoCamera(focal_length_px=0.0), "focal_length_px: expected"),
        (lambda: StereoCamera(baseline_m=-0.3), "baseline_m: expected"),
        (lambda: StereoCamera(image_width_px=767.5), "image_width_px: expected"),
    ],
)
def test_bad_inputs_name_the_argument(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_seed_is_required():
    with pytest.raises(TypeError):
        CAMERA.observe(_line())
