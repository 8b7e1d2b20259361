"""The calibration's rows: it learns the errors of forecasts made from two rows of a segment or more, on the spec and
on the compiled engine alike."""

import numpy as np
import pytest

from kalmix.bank import make_bank
from kalmix.core import engine as spec


def _compiled_run():
    pytest.importorskip("numba")
    from kalmix.core.compiled.engine import run

    return run


def _counts(run, bank, z, t):
    return run(bank, z, t).state.calibration.count[0]


@pytest.mark.parametrize("engine", ["spec", "compiled"])
def test_a_tracks_first_forecast_does_not_calibrate(engine):
    """The forecast of a track's second row is made from its first alone: every expert's miss is the target's whole
    displacement (here 1,000 length units a step). The calibration leaves it out and learns from the next row on,
    so the experts' counts are one less than their learned errors, and their variances stay near the noise's;
    ``calibration_from_points=0`` learns it too, as state files before format 18 ran."""
    run = spec.run if engine == "spec" else _compiled_run()
    rng = np.random.default_rng(0)
    rows = 8
    z = (1000.0 * np.arange(rows)[:, None, None] * np.array([1.0, 0.5]) + rng.normal(0.0, 1.0, (rows, 1, 2)))
    t = np.arange(float(rows))[:, None]
    bank = make_bank(2, "kinematic", length_unit=1.0)
    every = make_bank(2, "kinematic", length_unit=1.0, calibration_from_points=0)
    counted, all_counted = _counts(run, bank, z, t), _counts(run, every, z, t)
    assert np.all(all_counted - counted == 1.0)   # every expert forecast the second row: all lost one error
    variance = run(bank, z, t).state.calibration.variance[0]
    all_variance = run(every, z, t).state.calibration.variance[0]
    assert np.all(all_variance > 1e4 * variance.min()) and variance.max() < 1e5
    two = _counts(run, bank, z[:2], t[:2])
    assert not np.any(two) and np.all(_counts(run, every, z[:2], t[:2]) == 1.0)


def test_calibration_from_points_is_checked():
    with pytest.raises(ValueError, match="calibration_from_points"):
        make_bank(2, "kinematic", calibration_from_points=-1)
    with pytest.raises(TypeError, match="calibration_from_points"):
        make_bank(2, "kinematic", calibration_from_points=1.5)


def test_calibration_from_points_beyond_what_the_screen_counts_is_refused():
    """The screen counts a segment's rows up to 3 (``MAX_POINTS``): from 4 rows on, the calibration would learn no
    row at all, and every interval would stay at the length unit's width."""
    from kalmix.core.screen import MAX_POINTS

    make_bank(2, "kinematic", calibration_from_points=int(MAX_POINTS))
    with pytest.raises(ValueError, match="calibration_from_points"):
        make_bank(2, "kinematic", calibration_from_points=int(MAX_POINTS) + 1)
