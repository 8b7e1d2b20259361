"""Tests for kalmix.scenarios: the paper's trajectory, the simple named scenarios, measurements."""

import dataclasses
import warnings

import numpy as np
import pytest

from kalmix.scenarios import (
    SCENARIOS,
    CircleScenario,
    PaperScenario,
    RandomWalkScenario,
    Trajectory,
    paper_measurements,
)
from kalmix.vision import StereoCamera

PAPER = PaperScenario()
TRAJ = PAPER.generate()


def test_paper_shapes_and_phases():
    n = len(TRAJ.times)
    assert n == 1000
    assert TRAJ.positions.shape == (n, 3) and TRAJ.speeds.shape == (n,) and TRAJ.phase.shape == (n,)
    np.testing.assert_allclose(np.diff(TRAJ.times), 1 / PAPER.sample_rate_hz)
    np.testing.assert_array_equal(np.bincount(TRAJ.phase), [700, 25, 275])
    assert np.all(np.diff(TRAJ.phase) >= 0)


def test_phase_a_speed_rises_from_start_to_end_speed():
    speed_a = TRAJ.speeds[TRAJ.phase == 0]
    assert speed_a[0] == pytest.approx(0.01)
    assert speed_a[-1] == pytest.approx(1.5, rel=0.02)
    assert TRAJ.speeds.max() == pytest.approx(1.5)
    assert np.all(np.diff(speed_a) > 0)
    decel = TRAJ.speeds[TRAJ.phase == 1]
    assert np.all(np.diff(decel) < 0) and decel[-1] < 0.15


def test_speeds_match_the_positions_on_the_curve():
    """Arc-length parametrisation: distance per frame equals the mean speed over the frame."""
    on_curve = np.flatnonzero(TRAJ.phase < 2)[:-1]
    step = np.linalg.norm(np.diff(TRAJ.positions, axis=0), axis=-1)[on_curve] * PAPER.sample_rate_hz
    mean_speed = 0.5 * (TRAJ.speeds[on_curve] + TRAJ.speeds[on_curve + 1])
    np.testing.assert_allclose(step, mean_speed, rtol=0.01)


def test_phase_a_is_a_3d_curve_around_the_centre():
    curve = TRAJ.positions[TRAJ.phase == 0] - np.asarray(PAPER.centre_m)
    np.testing.assert_allclose(np.hypot(curve[:, 0], curve[:, 1]), PAPER.radius_m, rtol=1e-12)
    assert np.ptp(curve[:, 2]) > 1.5 * PAPER.vertical_amplitude_m
    assert np.all(np.abs(curve[:, 2]) <= PAPER.vertical_amplitude_m + 1e-12)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_trajectory_is_continuous(name, seed):
    traj = SCENARIOS[name](seed).generate()
    scenario = SCENARIOS[name](seed)
    jumps = np.linalg.norm(np.diff(traj.positions, axis=0), axis=-1)
    assert jumps.max() <= traj.speeds.max() / scenario.sample_rate_hz * 1.01


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_phase_b_stays_in_the_box_and_speed_range(seed):
    scenario = PaperScenario(seed=seed)
    traj = scenario.generate()
    wander = traj.positions[traj.phase == 2]
    start = wander[0]
    end_of_decel_next = traj.positions[traj.phase == 1][-1]
    assert np.linalg.norm(start - end_of_decel_next) < 0.15 / scenario.sample_rate_hz
    assert np.all(np.abs(wander - start) <= scenario.wander_box_m / 2 + 1e-12)
    low, high = scenario.wander_speed_range_mps
    speeds = traj.speeds[traj.phase == 2]
    assert np.all((speeds >= low) & (speeds <= high))
    # piecewise constant: speed changes every few frames, never after a single frame
    change = np.flatnonzero(np.diff(speeds) != 0)
    assert np.diff(change).min() >= scenario.wander_hold_frames[0]
    assert np.diff(change).max() <= scenario.wander_hold_frames[1]


def test_random_walk_stays_in_its_box():
    scenario = RandomWalkScenario(seed=5)
    traj = scenario.generate()
    assert np.all(np.abs(traj.positions - np.asarray(scenario.centre_m)) <= scenario.box_m / 2 + 1e-12)


def test_circle_is_a_constant_speed_circle():
    scenario = CircleScenario(seed=4)
    traj = scenario.generate()
    offset = traj.positions - np.asarray(scenario.centre_m)
    np.testing.assert_allclose(np.linalg.norm(offset, axis=-1), scenario.radius_m)
    np.testing.assert_allclose(traj.speeds, 0.3)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_scenario_stays_in_view(name, seed):
    traj = SCENARIOS[name](seed).generate()
    assert isinstance(traj, Trajectory)
    assert StereoCamera().in_view(StereoCamera().project(traj.positions)).all()


def test_registry_builds_seeded_frozen_scenarios():
    assert {"paper", "circle", "random_walk"} <= set(SCENARIOS)
    for name, make in SCENARIOS.items():
        scenario = make(7)
        assert scenario.seed == 7
        with pytest.raises(dataclasses.FrozenInstanceError):
            scenario.seed = 8


def test_fastest_image_motion_is_about_40_px_per_frame():
    features = StereoCamera().project(TRAJ.positions)
    fastest = np.abs(np.diff(features, axis=0)).max()
    assert 30.0 < fastest < 60.0


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_same_seed_same_trajectory(name):
    first = SCENARIOS[name](3).generate()
    again = SCENARIOS[name](3).generate()
    other = SCENARIOS[name](4).generate()
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(first.positions, other.positions)


def test_phase_a_does_not_depend_on_seed():
    other = PaperScenario(seed=9).generate()
    curve = TRAJ.phase < 2
    np.testing.assert_array_equal(TRAJ.positions[curve], other.positions[curve])


def test_paper_measurements_seeding_and_delay():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default scenario never leaves the images
        traj, obs = paper_measurements()
    assert obs.out_of_view_count == 0 and obs.visible.all()
    np.testing.assert_allclose(obs.clean, StereoCamera().project(traj.positions))
    _, again = paper_measurements(PaperScenario())
    np.testing.assert_array_equal(obs.measured, again.measured)
    _, other = paper_measurements(PaperScenario(seed=1))
    assert not np.allclose(obs.measured[:700], other.measured[:700])  # same curve, different noise
    _, delayed = paper_measurements(delay_frames=2)
    np.testing.assert_array_equal(delayed.measured[2:], obs.measured[:-2])
    assert np.isnan(delayed.measured[:2]).all()
    _, circle = paper_measurements(CircleScenario(seed=2), noise_px=0.0)
    np.testing.assert_array_equal(circle.measured, circle.clean)


def test_out_of_view_scenario_is_reported():
    wide = PaperScenario(radius_m=0.8, vertical_amplitude_m=0.0)
    with pytest.warns(RuntimeWarning, match="frames out of view"):
        _, obs = paper_measurements(wide)
    assert obs.out_of_view_count > 0
    assert np.isnan(obs.measured[~obs.visible]).all()


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: PaperScenario(sample_rate_hz=0.0), "sample_rate_hz: expected"),
        (lambda: PaperScenario(radius_m=-1.0), "radius_m: expected"),
        (lambda: PaperScenario(speed_start_mps=float("nan")), "speed_start_mps: expected"),
        (lambda: PaperScenario(wander_duration_s=-1.0), "wander_duration_s: expected"),
        (lambda: PaperScenario(centre_m=(0.0, 1.2)), "centre_m: expected 3 finite"),
        (lambda: PaperScenario(wander_speed_range_mps=(0.1, 0.01)), "wander_speed_range_mps: expected"),
        (lambda: PaperScenario(wander_hold_frames=(3.5, 8)), "wander_hold_frames: expected"),
        (lambda: PaperScenario(seed=-1), "seed: expected"),
        (lambda: CircleScenario(speed_mps=0.0), "speed_mps: expected"),
        (lambda: RandomWalkScenario(hold_frames=(0, 4)), "hold_frames: expected"),
        (lambda: RandomWalkScenario(box_m=0.0), "box_m: expected"),
    ],
)
def test_bad_parameters_name_the_field(make, match):
    with pytest.raises(ValueError, match=match):
        make()
