"""kalmix.peers: filterpy's IMM over CV and CA models, and the fair-tuning helpers."""

import numpy as np
import pytest

pytest.importorskip("filterpy")

from kalmix import peers  # noqa: E402


def _parabola(t_count=60, p=3):
    t = np.arange(t_count, dtype=float)[:, None]
    return 5.0 + np.array([0.5, -1.0, 2.0])[:p] * t + np.array([0.05, 0.02, -0.03])[:p] * t**2


def test_shape_and_first_row():
    z = _parabola()
    z[:3] = np.nan
    predictions = peers.imm_predictions(z)
    assert predictions.shape == z.shape
    assert np.isnan(predictions[:3]).all()
    assert np.isfinite(predictions[3:]).all()


def test_noiseless_constant_velocity_is_exact():
    z = _parabola(80) - np.array([0.05, 0.02, -0.03]) * np.arange(80.0)[:, None] ** 2  # a straight line
    errors = z[1:] - peers.imm_predictions(z)[:-1]
    assert np.abs(errors[-10:]).max() < 1e-3


def test_strong_constant_acceleration_is_carried_by_the_ca_mode():
    t = np.arange(80.0)[:, None]
    z = 5.0 + np.array([0.5, -1.0, 2.0]) * t + np.array([2.0, 0.8, -1.2]) * t**2
    predictions, modes = peers.imm_predictions(z, return_mode_probabilities=True)
    assert modes[-1, 1] > 0.9
    # with (almost) no switching the CA mode alone predicts a parabola exactly
    predictions = peers.imm_predictions(z, switch_probability=1e-6)
    assert np.abs(z[1:] - predictions[:-1])[-10:].max() < 1e-3


def test_missing_rows_predict_only():
    z = _parabola(60)
    gapped = z.copy()
    gapped[30:33] = np.nan
    predictions, modes = peers.imm_predictions(gapped, return_mode_probabilities=True)
    assert np.isfinite(predictions).all()
    np.testing.assert_allclose(modes.sum(axis=1), 1.0)
    # the rows before the gap are unaffected
    np.testing.assert_array_equal(predictions[:30], peers.imm_predictions(z)[:30])
    # during the gap the IMM extrapolates (no learning), still close on a smooth parabola
    assert np.abs(predictions[30:32] - z[31:33]).max() < 1.0


def test_scale_equivariance_with_length_unit():
    rng = np.random.default_rng(0)
    z = _parabola(50) + rng.normal(0, 0.5, size=(50, 3))
    scale = 0.001
    np.testing.assert_allclose(peers.imm_predictions(z * scale, length_unit=scale),
                               peers.imm_predictions(z) * scale, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("bad", [np.zeros(5), np.zeros((4, 2, 3))])
def test_bad_shape(bad):
    with pytest.raises(ValueError, match=r"expected shape \(T, p\)"):
        peers.imm_predictions(bad)


@pytest.mark.parametrize("name", ["cv_process_noise", "ca_process_noise", "measurement_noise"])
def test_bad_noise(name):
    with pytest.raises(ValueError, match=name):
        peers.imm_predictions(_parabola(), **{name: -1.0})


def test_bad_switch_probability():
    with pytest.raises(ValueError, match="switch_probability"):
        peers.imm_predictions(_parabola(), switch_probability=1.5)


def test_tune_returns_grid_argmin():
    rng = np.random.default_rng(1)
    z = _parabola(40) + rng.normal(0, 0.5, size=(40, 3))
    grid = {"cv_process_noise": (0.1, 10.0), "measurement_noise": (0.25,)}
    result = peers.tune(z, grid=grid)
    assert len(result["results"]) == 2
    best_rms = min(rms for _, rms in result["results"])
    assert result["rms"] == best_rms
    assert peers.one_step_rms(peers.imm_predictions(z, **result["best"]), z) == pytest.approx(best_rms)


def test_tune_fixed_returns_grid_argmin():
    rng = np.random.default_rng(2)
    z = _parabola(40) + rng.normal(0, 0.5, size=(40, 3))
    result = peers.tune_fixed("cv", z, grid={"process_noise": (0.01, 1.0, 100.0), "measurement_noise": (0.25,)})
    assert result["rms"] == min(rms for _, rms in result["results"])
    with pytest.raises(ValueError, match="model"):
        peers.tune_fixed("xx", z)


def test_defaults_come_from_the_documented_grids_and_a_separate_seed():
    for name, value in peers.IMM_DEFAULTS.items():
        assert value in peers.IMM_GRID[name]
    for defaults in (peers.CV_DEFAULTS, peers.CA_DEFAULTS):
        for name, value in defaults.items():
            assert value in peers.FIXED_GRID[name]
    assert peers.TUNING_SEED >= 100  # evaluation seeds of `kalmix reproduce` are 0 .. N-1
