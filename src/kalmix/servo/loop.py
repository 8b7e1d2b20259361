r"""Closed-loop visual servoing: the arm tracks the target through delayed, noisy cameras.

The paper's controller (Wira, Urban & Gresser 2001, sections 2 and 5) moves the arm by
:math:`\Delta\mathbf q_k = \mathbf B_k \mathbf e_k` (eq. 3), with the image error
:math:`\mathbf e_k = \mathbf d_k - \mathbf v_k` (eq. 1) and
:math:`\mathbf B_k \approx \mathbf J_f^{-1}(\mathbf q_k)` learned by a supervised SOM; the
mixture's predictions compensate the image-acquisition delay. This module simulates that loop.

Timing (25 Hz, frame :math:`k` at :math:`t = k\,T`)
---------------------------------------------------
- At frame :math:`k` the target is at :math:`\mathbf p_k` (3-D), with features
  :math:`\mathbf d_k = \pi(\mathbf p_k)`; the arm is at :math:`\mathbf q_k`, with features
  :math:`\mathbf v_k = \mathbf f(\mathbf q_k)`.
- The cameras deliver, at frame :math:`k`, the images taken at frame :math:`k - D`:
  :math:`\tilde{\mathbf d}_{k-D} = \mathbf d_{k-D} + \boldsymbol\varepsilon`,
  :math:`\tilde{\mathbf v}_{k-D} = \mathbf v_{k-D} + \boldsymbol\varepsilon'`
  (pixel noise :math:`\sigma`, one seeded draw per run, shared by every mode).
- The controller computes :math:`\Delta\mathbf q_k` at frame :math:`k`; it **takes effect at
  frame** :math:`k + 1`: :math:`\mathbf q_{k+1} = \operatorname{clip}(\mathbf q_k + \Delta\mathbf q_k)`.
  The error this command can still change is therefore
  :math:`\mathbf d_{k+1} - \mathbf v_{k+1}`, which is why the predictors are asked for frame
  :math:`k + 1`: after stepping on :math:`\tilde{\mathbf d}_{k-D}` they return
  ``predict(horizon=D + 1)`` :math:`= \hat{\mathbf d}_{k+1 \mid k-D}`.

The control law, for every mode
-------------------------------

.. math::

    \Delta\mathbf q_k = \operatorname{speed\_limit}\bigl(\lambda\, \mathbf B_k\, \mathbf e_k\bigr),
    \qquad \mathbf q_{k+1} = \operatorname{clip}(\mathbf q_k + \Delta\mathbf q_k),

with the gain :math:`\lambda` (``gain``; optionally ``prediction_gain`` for the modes without
delayed feedback), the arm's joint-speed limits
(:meth:`~kalmix.servo.Arm.limit_step`, the whole step scaled by one factor) and the joint limits
(a command outside them before clipping is counted as a *joint-limit violation*). The modes differ
only in :math:`\mathbf e_k` and :math:`\mathbf B_k`:

``no_prediction``
    :math:`\mathbf e_k = \tilde{\mathbf d}_{k-D} - \tilde{\mathbf v}_{k-D}`: the raw delayed image
    error, as the cameras deliver it; :math:`\mathbf B_k` from the SOM.
``single_akf``, ``mixture_softmax``
    :math:`\mathbf e_k = \hat{\mathbf d}_{k+1 \mid k-D} - \hat{\mathbf v}_k`, with the target
    prediction of :func:`kalmix.baselines.single_akf` or :func:`kalmix.baselines.softmax_mixture`
    (default settings, used through ``step`` / ``predict`` as a user would; NaN = missing
    measurement) and the **end-effector estimate**

    .. math::

        \hat{\mathbf v}_k = \tilde{\mathbf v}_{k-D}
            + \sum_{j=k-D}^{k-1} \mathbf B_j^{-1} \,(\mathbf q_{j+1} - \mathbf q_j),

    i.e. the last delivered image of the end effector plus the image motion the controller
    expects from the joint moves it has made since (a Smith predictor). It uses only what the
    learning controller has: its joint encoders and its own learned map :math:`\mathbf B` (no
    forward model of the arm or of the cameras). The same estimate serves both predictors.
``oracle``
    :math:`\mathbf e_k = \mathbf d_{k+1} - \mathbf v_k` with the true, undelayed, noise-free
    features and :math:`\mathbf B_k = \mathbf J_f^{-1}(\mathbf q_k)` analytic: the upper reference
    (what this controller and gain do with perfect information).

Until the first image arrives (:math:`k < D`) the arm holds still; a non-finite prediction falls
back to the latest measurement.

Online learning
---------------
Every SOM mode starts from a copy of the same trained SOM and keeps learning
(:meth:`~kalmix.servo.InverseJacobianSOM.learn`) from the arm's own moves as the delayed images
reveal them: at frame :math:`k` it learns
:math:`(\mathbf q_{k-D-1},\ \mathbf q_{k-D} - \mathbf q_{k-D-1},\ \tilde{\mathbf v}_{k-D} - \tilde{\mathbf v}_{k-D-1})`.
A pair is used only when its image move is at least ``learning_threshold_px`` (default 8 px,
about 11 standard deviations of the difference of two 0.5 px noises): on smaller moves the pixel
noise dominates :math:`\Delta\mathbf v` and the normalised LMS rule would shrink :math:`\mathbf B`
along the noise (errors-in-variables bias).

Stability with delay (why prediction matters)
---------------------------------------------
With an exact :math:`\mathbf B` the ``no_prediction`` loop is, per image axis,
:math:`v_{k+1} = v_k + \lambda (d_{k-D} - v_{k-D})`, whose characteristic polynomial
:math:`z^{D+1} - z^{D} + \lambda` has all roots inside the unit circle only for
:math:`\lambda < 2 \sin\bigl(\pi / (2(2D + 1))\bigr)` (1 for :math:`D = 1`, 0.618 for
:math:`D = 2`); a target moving :math:`u` px per frame is followed with a steady lag of
:math:`u/\lambda` px (ringing as :math:`\lambda` nears the limit). The Smith estimate removes the
delay from the arm's own feedback: :math:`v_{k+1} = v_k + \lambda(\hat d_{k+1} - v_k)`, stable for
:math:`0 < \lambda < 2`, with a steady lag of :math:`u (1 - \lambda)/\lambda` plus the prediction
error (no lag at :math:`\lambda = 1`). At one common gain the lag ratio is therefore
:math:`1/(1 - \lambda)`, below 2.6 for any gain that keeps ``no_prediction`` stable at
:math:`D = 2`: a threefold gain from prediction needs the predicting loop to use a larger gain
than the delayed loop can stand, which is what prediction allows.

Errors are reported against the true, undelayed positions: :math:`\|\mathbf d_k - \mathbf v_k\|`
in pixels (Euclidean norm over :math:`(u_\mathrm{left}, u_\mathrm{right}, v)`) and the 3-D
distance :math:`\|\mathbf p_k - \mathbf p(\mathbf q_k)\|` in millimetres, over every frame.
"""

from __future__ import annotations

import functools

import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Callable, NamedTuple

import numpy as np

from kalmix.servo.arm import Arm
from kalmix.servo.som import InverseJacobianSOM, SOMConfig, TrainingHistory

__all__ = [
    "MODES",
    "ServoConfig",
    "ModeResult",
    "ServoResult",
    "train_som",
    "run_servo",
    "delay_stability_limit",
]

#: The control modes, in the order of the report.
MODES = ("no_prediction", "single_akf", "mixture_softmax", "oracle")
_PREDICTOR_MODES = ("single_akf", "mixture_softmax")


def delay_stability_limit(delay_frames: int) -> float:
    r"""Largest gain for which :math:`z^{D+1} - z^D + \lambda` is stable: :math:`2\sin(\pi/(2(2D+1)))`.

    The ``no_prediction`` loop with an exact inverse Jacobian and delay :math:`D` is stable
    for :math:`0 < \lambda <` this value.
    """
    return float(2.0 * np.sin(np.pi / (2.0 * (2 * int(delay_frames) + 1))))


@dataclass(frozen=True)
class ServoConfig:
    """Settings of the closed loop (validated on creation).

    Parameters
    ----------
    delay_frames : int, default 2
        Image-acquisition delay :math:`D` (frames).
    noise_px : float, default 0.5
        Pixel noise on every delivered feature (target and end effector).
    gain : float, default 0.5
        :math:`\\lambda` in :math:`\\Delta q = \\lambda B e`, the same for every mode. The default
        keeps the ``no_prediction`` loop stable for :math:`D \\le 2` (limit 0.618 at
        :math:`D = 2`, see :func:`delay_stability_limit`).
    prediction_gain : float or None, default None
        Gain of the modes whose error is not delayed (``single_akf``, ``mixture_softmax``,
        ``oracle``); None: ``gain``. Lets each loop run at a gain it can stand (e.g. 1.0 with
        prediction, while ``no_prediction`` must stay below :func:`delay_stability_limit`).
    seed : int, default 0
        Seeds the camera noise (one draw per run, shared by the modes), the SOM and the
        predictors.
    n_experts : int, default 40
        Experts of the softmax mixture.
    online_learning : bool, default True
        Keep the SOM learning while tracking.
    learning_threshold_px : float, default 8.0
        Smallest image move (px) learned online.
    online_rate : float or None, default 0.01
        Widrow–Hoff rate of the online updates (None: the SOM's ``map_rate_final``, 0.05).
        At 0.05 the pixel noise on the learned moves makes the SOM drift from its trained
        accuracy over a run of the paper scenario; at 0.01 it stays close to it, for the same
        tracking error.
    divergence_px : float, default 300.0
        A mode has *diverged* if its tracking error ever exceeds this (or turns non-finite).
    modes : tuple of str
        Which of :data:`MODES` to run.
    """

    delay_frames: int = 2
    noise_px: float = 0.5
    gain: float = 0.5
    prediction_gain: float | None = None
    seed: int = 0
    n_experts: int = 40
    online_learning: bool = True
    learning_threshold_px: float = 8.0
    online_rate: float | None = 0.01
    divergence_px: float = 300.0
    modes: tuple = MODES

    def __post_init__(self) -> None:
        d = self.delay_frames
        if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d < 0:
            raise ValueError(f"delay_frames: expected an integer >= 0, got {d!r}")
        for name in ("noise_px", "learning_threshold_px"):
            value = getattr(self, name)
            if not (np.isscalar(value) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
        if self.online_rate is not None and not (
            np.isscalar(self.online_rate) and np.isfinite(self.online_rate) and self.online_rate > 0
        ):
            raise ValueError(f"online_rate: expected a finite number > 0 or None, got {self.online_rate!r}")
        if self.prediction_gain is not None and not (
            np.isscalar(self.prediction_gain) and np.isfinite(self.prediction_gain) and self.prediction_gain > 0
        ):
            raise ValueError(f"prediction_gain: expected a finite number > 0 or None, got {self.prediction_gain!r}")
        for name in ("gain", "divergence_px"):
            value = getattr(self, name)
            if not (np.isscalar(value) and np.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
        for name, minimum in (("seed", 0), ("n_experts", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
                raise ValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
        modes = tuple(self.modes)
        unknown = [m for m in modes if m not in MODES]
        if unknown or not modes:
            raise ValueError(f"modes: expected a non-empty subset of {MODES}, got {modes!r}")
        object.__setattr__(self, "modes", modes)


class ModeResult(NamedTuple):
    r"""One mode's run.

    Attributes
    ----------
    mode : str
    joints : ndarray, shape (T, 3)
        :math:`\\mathbf q_k` (rad).
    effector_positions : ndarray, shape (T, 3)
        :math:`\\mathbf p(\\mathbf q_k)` (m).
    effector_features : ndarray, shape (T, 3)
        :math:`\\mathbf v_k` (px, true, undelayed).
    error_px, error_mm : ndarray, shape (T,)
        :math:`\\|\\mathbf d_k - \\mathbf v_k\\|` (px) and the 3-D distance (mm).
    joint_limit_violations : int
        Frames whose command (after the speed limit, before clipping) left the joint limits.
    speed_limited_frames : int
        Frames whose step was scaled down by the speed limits.
    diverged : bool
    first_divergence_frame : int or None
    online_moves_learned : int
        Pairs learned online by the SOM (0 for the oracle).
    som_relative_error : float or None
        Median relative error of this mode's SOM over the target's joint region after the run.
    gain : float
        The :math:`\lambda` this mode ran with.
    seconds : float
        Wall-clock time of the mode.
    """

    mode: str
    joints: np.ndarray
    effector_positions: np.ndarray
    effector_features: np.ndarray
    error_px: np.ndarray
    error_mm: np.ndarray
    joint_limit_violations: int
    speed_limited_frames: int
    diverged: bool
    first_divergence_frame: int | None
    online_moves_learned: int
    som_relative_error: float | None
    gain: float
    seconds: float

    def summary(self) -> dict:
        """``mean_px, rms_px, max_px, mean_mm, rms_mm, max_mm`` and the counters, as plain floats/ints."""
        px, mm = self.error_px, self.error_mm
        return {
            "mean_px": float(np.mean(px)),
            "rms_px": float(np.sqrt(np.mean(px**2))),
            "max_px": float(np.max(px)),
            "mean_mm": float(np.mean(mm)),
            "rms_mm": float(np.sqrt(np.mean(mm**2))),
            "max_mm": float(np.max(mm)),
            "joint_limit_violations": int(self.joint_limit_violations),
            "speed_limited_frames": int(self.speed_limited_frames),
            "diverged": bool(self.diverged),
            "first_divergence_frame": self.first_divergence_frame,
            "online_moves_learned": int(self.online_moves_learned),
            "som_relative_error_after_run": self.som_relative_error,
            "gain": float(self.gain),
            "seconds": float(self.seconds),
        }


class ServoResult(NamedTuple):
    """Everything a servo run produced.

    Attributes
    ----------
    config : ServoConfig
    times : ndarray, shape (T,)
    target_positions : ndarray, shape (T, 3)
        :math:`\\mathbf p_k` (m).
    target_features : ndarray, shape (T, 3)
        :math:`\\mathbf d_k` (px, true).
    modes : dict of str to ModeResult
    som_history : TrainingHistory or None
        The SOM's learning curve (None if a trained SOM was passed in).
    som_relative_error_untrained, som_relative_error_trained : float
        Median relative error of :math:`\\mathbf B` against :math:`\\mathbf J_f^{-1}` over the
        joint configurations of the target's path, before and after babbling.
    som_relative_error_p90_trained : float
        90th percentile of the same, after babbling.
    """

    config: ServoConfig
    times: np.ndarray
    target_positions: np.ndarray
    target_features: np.ndarray
    modes: dict
    som_history: TrainingHistory | None
    som_relative_error_untrained: float
    som_relative_error_trained: float
    som_relative_error_p90_trained: float

    @property
    def joint_limit_violations(self) -> int:
        """Total over the modes."""
        return int(sum(m.joint_limit_violations for m in self.modes.values()))

    def to_dict(self) -> dict:
        """JSON-ready summary (no per-frame arrays)."""
        return {
            "config": asdict(self.config) | {"modes": list(self.config.modes)},
            "frames": int(len(self.times)),
            "som_relative_error": self.som_relative_error_trained,
            "som_relative_error_untrained": self.som_relative_error_untrained,
            "som_relative_error_p90": self.som_relative_error_p90_trained,
            "som_training_seconds": None if self.som_history is None
            else float(self.som_history.training_seconds),
            "modes": {name: result.summary() for name, result in self.modes.items()},
            "joint_limit_violations": self.joint_limit_violations,
            "diverged": {name: result.diverged for name, result in self.modes.items()},
            "stability_limit_no_prediction": delay_stability_limit(self.config.delay_frames),
        }


def _copy_som(som: InverseJacobianSOM) -> InverseJacobianSOM:
    return InverseJacobianSOM.from_state_dict(som.state_dict())


def train_som(arm: Arm, camera, *, seed: int = 0, config: SOMConfig | None = None,
              progress: Callable[[int, int, float], None] | None = None):
    """Train the default SOM by babbling over ``arm.joint_box()`` (the target region).

    Returns
    -------
    (InverseJacobianSOM, TrainingHistory)
    """
    if config is None:
        config = SOMConfig(seed=int(seed))
    som = InverseJacobianSOM(config, *arm.joint_box())
    history = som.fit(arm, camera, progress=progress)
    return som, history


def _path_joints(arm: Arm, positions: np.ndarray, every: int = 1) -> np.ndarray:
    """Joint configurations of the target's path (inverse kinematics), subsampled."""
    return arm.inverse(positions[::every])


def _simulate(mode: str, *, arm: Arm, camera, config: ServoConfig, dt: float,
              target_positions: np.ndarray, target_features: np.ndarray,
              target_noisy: np.ndarray, effector_noise: np.ndarray,
              som: InverseJacobianSOM | None, q_start: np.ndarray,
              path_joints: np.ndarray, tick: Callable[[], None] | None) -> ModeResult:
    from kalmix.baselines import single_akf, softmax_mixture

    start_time = time.perf_counter()
    n_frames = len(target_positions)
    delay = int(config.delay_frames)
    gain = float(config.gain if mode == "no_prediction" or config.prediction_gain is None
                 else config.prediction_gain)
    predictor = None
    if mode == "single_akf":
        predictor = single_akf(seed=config.seed)
    elif mode == "mixture_softmax":
        predictor = softmax_mixture(config.n_experts, seed=config.seed)

    joints = np.empty((n_frames, 3))
    features = np.empty((n_frames, 3))
    measured_effector = np.empty((n_frames, 3))  # v_j + noise, as the camera sees it
    expected_image_moves: deque = deque(maxlen=max(delay, 1))  # B_j^{-1} (q_{j+1} - q_j)
    violations = speed_limited = learned = 0
    predictor_started = False
    q = np.array(q_start, dtype=float)

    for k in range(n_frames):
        joints[k] = q
        features[k] = arm.image_features(q, camera)
        measured_effector[k] = features[k] + effector_noise[k]

        if mode == "oracle":
            if k + 1 < n_frames:
                error = target_features[k + 1] - features[k]
                inverse = np.linalg.inv(arm.image_jacobian(q, camera))
            else:
                error, inverse = np.zeros(3), np.zeros((3, 3))
        else:
            sample = k - delay  # the frame whose images arrive now
            if som is not None and config.online_learning and sample >= 1:
                dv = measured_effector[sample] - measured_effector[sample - 1]
                if np.all(np.isfinite(dv)) and np.linalg.norm(dv) >= config.learning_threshold_px:
                    som.learn(joints[sample - 1], joints[sample] - joints[sample - 1], dv,
                              rate=config.online_rate)
                    learned += 1
            inverse = som.inverse_jacobian(q)
            if sample < 0:
                error = np.zeros(3)
            elif mode == "no_prediction":
                error = target_noisy[sample] - measured_effector[sample]
                if not np.all(np.isfinite(error)):
                    error = np.zeros(3)
            else:
                measurement = target_noisy[sample]
                if predictor_started or np.all(np.isfinite(measurement)):
                    predictor.step(measurement)
                    predictor_started = True
                    target_estimate = predictor.predict(horizon=delay + 1)
                    if not np.all(np.isfinite(target_estimate)):
                        target_estimate = measurement
                else:
                    target_estimate = measurement
                effector_estimate = measured_effector[sample] + (
                    np.sum(list(expected_image_moves)[-delay:], axis=0) if delay else 0.0
                )
                error = target_estimate - effector_estimate
                if not np.all(np.isfinite(error)):
                    error = np.zeros(3)

        requested = gain * (inverse @ error)
        step = arm.limit_step(requested, dt)
        if not np.allclose(step, requested):
            speed_limited += 1
        commanded = q + step
        if not arm.within_limits(commanded):
            violations += 1
        q_next = arm.clip(commanded)
        if mode != "oracle" and delay:
            try:
                expected_image_moves.append(np.linalg.solve(inverse, q_next - q))
            except np.linalg.LinAlgError:
                expected_image_moves.append(np.zeros(3))
        q = q_next
        if tick is not None:
            tick()

    effector_positions = arm.forward(joints)
    error_px = np.linalg.norm(target_features - features, axis=-1)
    error_mm = 1000.0 * np.linalg.norm(target_positions - effector_positions, axis=-1)
    bad = ~np.isfinite(error_px) | (error_px > config.divergence_px)
    first_bad = int(np.argmax(bad)) if np.any(bad) else None
    som_error = None
    if som is not None:
        som_error = float(np.median(som.relative_error(arm, camera, path_joints).values))
    return ModeResult(
        mode=mode,
        joints=joints,
        effector_positions=effector_positions,
        effector_features=features,
        error_px=error_px,
        error_mm=error_mm,
        joint_limit_violations=violations,
        speed_limited_frames=speed_limited,
        diverged=first_bad is not None,
        first_divergence_frame=first_bad,
        online_moves_learned=learned,
        som_relative_error=som_error,
        gain=gain,
        seconds=time.perf_counter() - start_time,
    )


def run_servo(trajectory, *, arm: Arm | None = None, camera=None, config: ServoConfig | None = None,
              som: InverseJacobianSOM | None = None, som_config: SOMConfig | None = None,
              progress: Callable[[str, int, int], None] | None = None,
              som_progress: Callable[[int, int, float], None] | None = None) -> ServoResult:
    """Run every mode of the closed loop on one target trajectory.

    Parameters
    ----------
    trajectory : kalmix.scenarios.Trajectory
        The target (``times``, ``positions`` in metres at 25 Hz).
    arm : Arm, optional
    camera : kalmix.vision.StereoCamera, optional
    config : ServoConfig, optional
    som : InverseJacobianSOM, optional
        A trained SOM (copied, never modified). Default: :func:`train_som` with ``som_config``
        (default settings, seeded by ``config.seed``).
    progress : callable, optional
        ``progress(mode, frame, n_frames)`` after each simulated frame.
    som_progress : callable, optional
        Passed to :meth:`InverseJacobianSOM.fit`.

    Returns
    -------
    ServoResult
    """
    from kalmix.vision import StereoCamera

    arm = Arm() if arm is None else arm
    camera = StereoCamera() if camera is None else camera
    config = ServoConfig() if config is None else config
    times = np.asarray(trajectory.times, dtype=float)
    positions = np.asarray(trajectory.positions, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3 or len(positions) < 2 or len(times) != len(positions):
        raise ValueError(f"trajectory: expected positions of shape (T, 3) with T >= 2 matching times, "
                         f"got {positions.shape} and {times.shape}")
    dt = float(np.median(np.diff(times)))
    if not dt > 0:
        raise ValueError(f"trajectory: expected increasing times, got a median step of {dt}")

    # One noise draw per run, shared by every mode: target features and end-effector features.
    target_seq, effector_seq = np.random.SeedSequence([config.seed, 4]).spawn(2)
    observation = camera.observe(positions, noise_px=config.noise_px, delay_frames=0,
                                 seed=np.random.default_rng(target_seq))
    target_features = observation.clean
    target_noisy = observation.measured  # undelayed here; the loop reads row k - D at frame k
    effector_noise = config.noise_px * np.random.default_rng(effector_seq).standard_normal(positions.shape)

    path_joints = _path_joints(arm, positions)
    q_start = path_joints[0]
    history = None
    if som is None:
        som, history = train_som(arm, camera, seed=config.seed, config=som_config, progress=som_progress)
    validation = path_joints[:: max(1, len(path_joints) // 500)]
    untrained = InverseJacobianSOM(som.config, som.joint_low, som.joint_high)
    untrained_error = float(np.median(untrained.relative_error(arm, camera, validation).values))
    trained_values = som.relative_error(arm, camera, validation).values

    results = {}
    for mode in config.modes:
        tick = None
        if progress is not None:
            counter = iter(range(1, len(positions) + 1))
            tick = functools.partial(lambda mode, counter: progress(mode, next(counter), len(positions)),
                                     mode, counter)
        results[mode] = _simulate(
            mode, arm=arm, camera=camera, config=config, dt=dt,
            target_positions=positions, target_features=target_features,
            target_noisy=target_noisy, effector_noise=effector_noise,
            som=None if mode == "oracle" else _copy_som(som), q_start=q_start,
            path_joints=validation, tick=tick,
        )
    return ServoResult(
        config=config,
        times=times,
        target_positions=positions,
        target_features=target_features,
        modes=results,
        som_history=history,
        som_relative_error_untrained=untrained_error,
        som_relative_error_trained=float(np.median(trained_values)),
        som_relative_error_p90_trained=float(np.percentile(trained_values, 90)),
    )
