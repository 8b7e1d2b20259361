import numpy as np
import pytest


def smooth_tracks(seed: int, steps: int, targets: int = 1, dim: int = 3, scale: float = 50.0):
    """Smooth random curves in pixel-like units with measurement noise, shape (T, N, p)."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps)[:, None, None]
    freq = rng.uniform(0.01, 0.08, size=(1, targets, dim))
    phase = rng.uniform(0, 2 * np.pi, size=(1, targets, dim))
    return 300 + scale * np.sin(freq * t + phase) + 0.5 * rng.normal(size=(steps, targets, dim))


@pytest.fixture
def tracks():
    return smooth_tracks


@pytest.fixture(scope="module")
def arm():
    """The default 3-joint arm of the servo tests."""
    from kalmix.servo import Arm

    return Arm()


@pytest.fixture(scope="module")
def camera():
    """The default stereo camera."""
    from kalmix.vision import StereoCamera

    return StereoCamera()
