"""Seeded 3-D target trajectories: the paper's scenario and two simple ones.

Wira, Urban & Gresser (2001, section 5) test the predictors on "an accelerating curved trajectory
which ends with little random movements in a restricted area", with target speed from 0.01 to
1.5 m/s. The paper gives no more detail; :class:`PaperScenario` is our reading of it, documented
field by field. Every scenario is a frozen dataclass with its own ``seed`` and a
``generate()`` method returning a :class:`Trajectory`; nothing uses the global random state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol

import numpy as np

from kalmix.vision import Observation, StereoCamera

__all__ = [
    "SCENARIOS",
    "CircleScenario",
    "PaperScenario",
    "RandomWalkScenario",
    "Scenario",
    "Trajectory",
    "paper_measurements",
]

PHASE_CURVE, PHASE_DECELERATION, PHASE_WANDER = 0, 1, 2

# SeedSequence spawn keys: independent streams derived from one scenario seed.
_STREAM_TRAJECTORY, _STREAM_NOISE = 0, 1


class Trajectory(NamedTuple):
    """A sampled target trajectory.

    Attributes
    ----------
    times : ndarray, shape (T,)
        Sample times in seconds, ``k / sample_rate_hz``.
    positions : ndarray, shape (T, 3)
        Positions in metres, in the world frame of :class:`kalmix.vision.StereoCamera`.
    speeds : ndarray, shape (T,)
        Instantaneous speed in m/s at each sample.
    phase : ndarray of int, shape (T,)
        0 curve, 1 deceleration, 2 wander (random moves).
    """

    times: np.ndarray
    positions: np.ndarray
    speeds: np.ndarray
    phase: np.ndarray


class Scenario(Protocol):
    """Anything with a ``seed``, a ``sample_rate_hz`` and ``generate() -> Trajectory``."""

    seed: int
    sample_rate_hz: float

    def generate(self) -> Trajectory: ...


# -- validation --------------------------------------------------------------------------------


def _positive(obj, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (np.isscalar(value) and np.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")


def _seed(obj) -> None:
    seed = obj.seed
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected a non-negative int, got {seed!r}")


def _point(obj, name: str) -> None:
    value = np.asarray(getattr(obj, name), dtype=float)
    if value.shape != (3,) or not np.all(np.isfinite(value)):
        raise ValueError(f"{name}: expected 3 finite coordinates (x, y, z), got {getattr(obj, name)!r}")


def _range(obj, name: str, *, integer: bool = False) -> None:
    value = getattr(obj, name)
    ok = (
        isinstance(value, tuple)
        and len(value) == 2
        and all(np.isscalar(v) and np.isfinite(v) and v > 0 for v in value)
        and value[0] <= value[1]
    )
    if ok and integer:
        ok = all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value)
    if not ok:
        kind = "integers" if integer else "numbers"
        raise ValueError(
            f"{name}: expected a pair (low, high) of {kind} with 0 < low <= high, got {value!r}"
        )


def _frames(duration_s: float, rate_hz: float) -> int:
    return int(round(duration_s * rate_hz))


def _rng(seed: int, stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))


# -- building blocks ---------------------------------------------------------------------------


def _reflected_random_walk(
    start: np.ndarray,
    box_centre: np.ndarray,
    box_side: float,
    n_frames: int,
    rate_hz: float,
    speed_range: tuple[float, float],
    hold_frames: tuple[int, int],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Piecewise-constant random velocity, specularly reflected at the walls of a cube.

    Segment ``j`` has speed :math:`s_j \sim U(\text{speed\_range})`, a direction uniform on the
    sphere and lasts :math:`h_j \in \{h_\min, \dots, h_\max\}` frames (uniform). The free path
    :math:`q_k = \text{start} + \sum_{i<k} v_i / r` is folded into the cube coordinate by
    coordinate with the triangle wave :math:`L - |(\xi \bmod 2L) - L|`, which is exactly a
    mirror reflection at each wall. Returns ``(positions (n, 3), speeds (n,))``.
    """
    low, high = hold_frames
    n_segments = n_frames // low + 1
    holds = rng.integers(low, high + 1, size=n_segments)
    speed = rng.uniform(speed_range[0], speed_range[1], size=n_segments)
    direction = rng.standard_normal((n_segments, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    velocity = np.repeat(speed[:, None] * direction, holds, axis=0)[:n_frames]

    displacement = np.concatenate([np.zeros((1, 3)), np.cumsum(velocity[:-1], axis=0) / rate_hz])
    corner = box_centre - box_side / 2.0
    free = start - corner + displacement
    folded = box_side - np.abs(np.mod(free, 2.0 * box_side) - box_side)
    return corner + folded, np.linalg.norm(velocity, axis=-1)


# -- the paper's scenario ----------------------------------------------------------------------


@dataclass(frozen=True)
class PaperScenario:
    r"""The paper's target: an accelerating curved 3-D path, speed 0.01 -> 1.5 m/s, then small
    random moves in a restricted area.

    Phase A (curve, ``curve_duration_s``): the target runs along a circle of radius :math:`R` in
    the :math:`x`–:math:`y` plane (facing the cameras) around ``centre_m``, with a sinusoidal
    depth oscillation of amplitude :math:`a` (``vertical_amplitude_m``, "vertical" meaning out of
    the circle's plane) and :math:`m` cycles per turn, so the path is truly 3-D:

    .. math::

        p(\theta) = c + \bigl(R \cos\theta,\; R \sin\theta,\; a \sin(m\theta)\bigr).

    The speed rises **geometrically** (exponentially in time), which spends comparable time in
    every decade of speed:

    .. math::

        v(t) = v_0 \left(\frac{v_1}{v_0}\right)^{t / T_A}, \qquad
        s(t) = \int_0^t v = \frac{v_0 T_A}{\ln(v_1/v_0)}
               \left[\left(\frac{v_1}{v_0}\right)^{t/T_A} - 1\right],

    and the position is :math:`p(\theta(s(t)))` with :math:`\theta(s)` the inverse of the arc
    length of the path (computed on a fine grid), so the speed along the path is exactly
    :math:`v(t)`.

    Deceleration (``deceleration_duration_s`` = :math:`T_D`): the target continues along the same
    curve with constant deceleration from :math:`v_1` to ``deceleration_end_speed_mps``.

    Phase B (wander, ``wander_duration_s``): piecewise-constant random velocity (speed uniform in
    ``wander_speed_range_mps``, direction uniform on the sphere, held for a uniform random number
    of frames in ``wander_hold_frames``, inclusive), reflected at the walls of a cube of side
    ``wander_box_m`` centred where the deceleration ended.

    Durations are rounded to whole samples. Phases A and the deceleration are deterministic;
    ``seed`` drives phase B (and, through :func:`paper_measurements`, the pixel noise, on an
    independent stream).

    With the defaults: 1000 samples at 25 Hz, about 5 turns, and a fastest image motion of about
    40 px per frame for :class:`kalmix.vision.StereoCamera` defaults.
    """

    sample_rate_hz: float = 25.0
    curve_duration_s: float = 28.0
    deceleration_duration_s: float = 1.0
    wander_duration_s: float = 11.0
    centre_m: tuple[float, float, float] = (0.0, 0.0, 1.2)
    radius_m: float = 0.25
    vertical_amplitude_m: float = 0.08
    vertical_cycles_per_turn: float = 2.0
    speed_start_mps: float = 0.01
    speed_end_mps: float = 1.5
    deceleration_end_speed_mps: float = 0.05
    wander_box_m: float = 0.04
    wander_speed_range_mps: tuple[float, float] = (0.01, 0.1)
    wander_hold_frames: tuple[int, int] = (3, 8)
    seed: int = 0

    def __post_init__(self) -> None:
        _positive(
            self,
            "sample_rate_hz",
            "curve_duration_s",
            "radius_m",
            "speed_start_mps",
            "speed_end_mps",
            "deceleration_end_speed_mps",
            "wander_box_m",
        )
        non_negative = (
            "deceleration_duration_s",
            "wander_duration_s",
            "vertical_amplitude_m",
            "vertical_cycles_per_turn",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not (np.isscalar(value) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        _point(self, "centre_m")
        _range(self, "wander_speed_range_mps")
        _range(self, "wander_hold_frames", integer=True)
        _seed(self)

    def _path(self, arc_length: np.ndarray) -> np.ndarray:
        """Positions at the given arc lengths along the phase-A curve."""
        radius, amplitude = self.radius_m, self.vertical_amplitude_m
        cycles = self.vertical_cycles_per_turn
        # |dp/dtheta| >= R, so theta(s) <= s / R; 4096 grid points per turn.
        theta_max = float(np.max(arc_length, initial=0.0)) / radius + 1e-9
        theta = np.linspace(0.0, theta_max, int(np.ceil(theta_max / (2 * np.pi) * 4096)) + 2)
        ds_dtheta = np.hypot(radius, amplitude * cycles * np.cos(cycles * theta))
        increments = 0.5 * (ds_dtheta[1:] + ds_dtheta[:-1]) * np.diff(theta)
        s_grid = np.concatenate([[0.0], np.cumsum(increments)])
        angle = np.interp(arc_length, s_grid, theta)
        offset = np.stack(
            [radius * np.cos(angle), radius * np.sin(angle), amplitude * np.sin(cycles * angle)],
            axis=-1,
        )
        return np.asarray(self.centre_m, dtype=float) + offset

    def generate(self) -> Trajectory:
        """Sample the trajectory; see the class docstring for the equations."""
        rate = self.sample_rate_hz
        n_curve = _frames(self.curve_duration_s, rate)
        n_decel = _frames(self.deceleration_duration_s, rate)
        n_wander = _frames(self.wander_duration_s, rate)
        duration_a, duration_d = n_curve / rate, n_decel / rate
        v0, v1, v2 = self.speed_start_mps, self.speed_end_mps, self.deceleration_end_speed_mps

        # Phase A and the deceleration: speed and arc length in closed form, k = 0 .. n_curve + n_decel
        # (the last point is where the deceleration ends and the wander starts).
        t = np.arange(n_curve + n_decel + 1) / rate
        t_a = np.minimum(t, duration_a)
        log_ratio = np.log(v1 / v0)
        if abs(log_ratio) < 1e-12:
            speed, arc = np.full_like(t_a, v0), v0 * t_a
        else:
            speed = v0 * np.exp(log_ratio * t_a / duration_a)
            arc = v0 * duration_a / log_ratio * np.expm1(log_ratio * t_a / duration_a)
        if n_decel:
            t_d = np.maximum(t - duration_a, 0.0)
            slope = (v2 - v1) / duration_d
            speed = np.where(t > duration_a, v1 + slope * t_d, speed)
            arc = arc + v1 * t_d + 0.5 * slope * t_d**2
        curve = self._path(arc)
        end = curve[-1]

        wander, wander_speed = _reflected_random_walk(
            start=end,
            box_centre=end,
            box_side=self.wander_box_m,
            n_frames=n_wander,
            rate_hz=rate,
            speed_range=self.wander_speed_range_mps,
            hold_frames=self.wander_hold_frames,
            rng=_rng(self.seed, _STREAM_TRAJECTORY),
        )
        n_total = n_curve + n_decel + n_wander
        positions = np.concatenate([curve[: n_curve + n_decel], wander])
        speeds = np.concatenate([speed[: n_curve + n_decel], wander_speed])
        phase = np.repeat([PHASE_CURVE, PHASE_DECELERATION, PHASE_WANDER], [n_curve, n_decel, n_wander])
        times = np.arange(n_total) / rate
        return Trajectory(times=times, positions=positions, speeds=speeds, phase=phase)


# -- two simple scenarios ----------------------------------------------------------------------


@dataclass(frozen=True)
class CircleScenario:
    r"""Constant-speed circle facing the cameras.

    .. math::

        p(t) = c + R\,(\cos(\phi_0 + \omega t),\; \sin(\phi_0 + \omega t),\; 0), \qquad \omega = v / R,

    with the start angle :math:`\phi_0` drawn uniformly from ``seed``. All samples have phase 0.
    """

    sample_rate_hz: float = 25.0
    duration_s: float = 40.0
    centre_m: tuple[float, float, float] = (0.0, 0.0, 1.2)
    radius_m: float = 0.2
    speed_mps: float = 0.3
    seed: int = 0

    def __post_init__(self) -> None:
        _positive(self, "sample_rate_hz", "duration_s", "radius_m", "speed_mps")
        _point(self, "centre_m")
        _seed(self)

    def generate(self) -> Trajectory:
        """Sample the circle."""
        times = np.arange(_frames(self.duration_s, self.sample_rate_hz)) / self.sample_rate_hz
        start_angle = _rng(self.seed, _STREAM_TRAJECTORY).uniform(0.0, 2.0 * np.pi)
        angle = start_angle + self.speed_mps / self.radius_m * times
        unit = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=-1)
        offset = self.radius_m * unit
        return Trajectory(
            times=times,
            positions=np.asarray(self.centre_m, dtype=float) + offset,
            speeds=np.full_like(times, self.speed_mps),
            phase=np.full(times.shape, PHASE_CURVE),
        )


@dataclass(frozen=True)
class RandomWalkScenario:
    """Piecewise-constant random velocity reflected inside a cube (phase B of the paper, larger).

    Speed uniform in ``speed_range_mps``, direction uniform on the sphere, held for a uniform
    random number of frames in ``hold_frames`` (inclusive); the walk starts at ``centre_m`` and is
    mirrored at the walls of the cube of side ``box_m`` centred there. All samples have phase 2.
    """

    sample_rate_hz: float = 25.0
    duration_s: float = 40.0
    centre_m: tuple[float, float, float] = (0.0, 0.0, 1.2)
    box_m: float = 0.3
    speed_range_mps: tuple[float, float] = (0.05, 0.5)
    hold_frames: tuple[int, int] = (5, 25)
    seed: int = 0

    def __post_init__(self) -> None:
        _positive(self, "sample_rate_hz", "duration_s", "box_m")
        _point(self, "centre_m")
        _range(self, "speed_range_mps")
        _range(self, "hold_frames", integer=True)
        _seed(self)

    def generate(self) -> Trajectory:
        """Sample the walk."""
        n = _frames(self.duration_s, self.sample_rate_hz)
        centre = np.asarray(self.centre_m, dtype=float)
        positions, speeds = _reflected_random_walk(
            start=centre,
            box_centre=centre,
            box_side=self.box_m,
            n_frames=n,
            rate_hz=self.sample_rate_hz,
            speed_range=self.speed_range_mps,
            hold_frames=self.hold_frames,
            rng=_rng(self.seed, _STREAM_TRAJECTORY),
        )
        return Trajectory(
            times=np.arange(n) / self.sample_rate_hz,
            positions=positions,
            speeds=speeds,
            phase=np.full(n, PHASE_WANDER),
        )


def _paper(seed: int) -> PaperScenario:
    return PaperScenario(seed=seed)


def _circle(seed: int) -> CircleScenario:
    return CircleScenario(seed=seed)


def _random_walk(seed: int) -> RandomWalkScenario:
    return RandomWalkScenario(seed=seed)


SCENARIOS: dict[str, Callable[[int], Scenario]] = {
    "paper": _paper,
    "circle": _circle,
    "random_walk": _random_walk,
}
"""Named scenarios with default settings: ``SCENARIOS[name](seed)`` builds one."""


def paper_measurements(
    scenario: Scenario | None = None,
    camera: StereoCamera | None = None,
    *,
    noise_px: float = 0.5,
    delay_frames: int = 0,
) -> tuple[Trajectory, Observation]:
    """Generate the trajectory and observe it with the stereo camera.

    The noise seed is derived from ``scenario.seed`` on a stream independent of the one that
    drives the trajectory, so the same scenario always gives the same measurements.

    Parameters
    ----------
    scenario : PaperScenario or any Scenario, optional
        Defaults to ``PaperScenario()``.
    camera : StereoCamera, optional
        Defaults to ``StereoCamera()``.
    noise_px, delay_frames
        Passed to :meth:`kalmix.vision.StereoCamera.observe`.

    Returns
    -------
    (Trajectory, Observation)
    """
    scenario = PaperScenario() if scenario is None else scenario
    camera = StereoCamera() if camera is None else camera
    trajectory = scenario.generate()
    observation = camera.observe(
        trajectory.positions,
        noise_px=noise_px,
        delay_frames=delay_frames,
        seed=_rng(scenario.seed, _STREAM_NOISE),
    )
    return trajectory, observation
