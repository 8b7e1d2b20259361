import os

import numpy as np
import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (a failure in CI is one anyone can rerun), without a
# deadline (a numba kernel compiles on its first example), and print the blob that reproduces a failure. Every
# test takes this profile; HYPOTHESIS_PROFILE=explore draws new examples each run, to look for new failures.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def smooth_tracks(seed: int, steps: int, targets: int = 1, dim: int = 3, scale: float = 50.0):
    """Smooth random curves in pixel-like units with measurement noise, shape (T, N, p)."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps)[:, None, None]
    freq = rng.uniform(0.01, 0.08, size=(1, targets, dim))
    phase = rng.uniform(0, 2 * np.pi, size=(1, targets, dim))
    return 300 + scale * np.sin(freq * t + phase) + 0.5 * rng.normal(size=(steps, targets, dim))


@pytest.fixture(scope="module")
def cli():
    """The kalmix command line, built once per test module."""
    from kalmix.cli import build

    return build()


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


def pytest_configure(config):
    """With pytest-xdist, compile the default kernels once, here in the controller, before the workers start.

    On an empty kernel cache every worker would otherwise compile the same kernels at the same time (the default
    bank, its lead head, the paper's mixture), each paying the whole compile on a shared core; compiled here,
    the workers load them from the cache. The paper's mixture (one AKF kernel of its own) compiles in another
    process at the lowest priority: on two cores it runs once the bank's AKF kernel, compiled in a second process
    of its own, is done, beside the bank's other kernels. A warm cache makes this a second's work; a run without
    xdist compiles as it goes."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    try:
        import numba  # noqa: F401
    except ImportError:
        return
    import subprocess
    import sys

    from kalmix import StreamConfig, TrackPredictor

    mixture = subprocess.Popen([sys.executable, "-c", "import os; os.nice(19) if hasattr(os, 'nice') else None; "
                                "import numpy as np; from kalmix import MixturePredictor; "
                                "MixturePredictor(n_experts=4, seed=0, backend='numba').run(np.cumsum("
                                "np.random.default_rng(0).normal(size=(20, 2)), axis=0))"])
    try:
        for options in ({}, {"lead": 1.0}):
            TrackPredictor(StreamConfig(length_unit=1.0, **options)).warm_up(2)
    except BaseException:   # Ctrl-C: do not wait for the mixture's compile
        mixture.kill()
        raise
    finally:
        mixture.wait()
