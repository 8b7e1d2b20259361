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


# ---------------------------------------------------------------- the numpy IMM against filterpy's own objects

def _filterpy_imm(measurements, cv_process_noise, ca_process_noise, measurement_noise, switch_probability,
                  initial_variance=(1.0, 100.0, 10.0), length_unit=1.0):
    """filterpy's ``IMMEstimator`` stepped row by row: the reference :func:`kalmix.peers.imm_predictions` follows."""
    from filterpy.common import Q_discrete_white_noise
    from filterpy.kalman import IMMEstimator, KalmanFilter
    from scipy.linalg import block_diag

    z = np.asarray(measurements, dtype=float)
    unit2 = length_unit**2
    t_count, p = z.shape
    f_cv = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    f_ca = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    q_cv = np.zeros((3, 3))
    q_cv[:2, :2] = Q_discrete_white_noise(dim=2, dt=1.0, var=cv_process_noise * unit2)
    q_ca = Q_discrete_white_noise(dim=3, dt=1.0, var=ca_process_noise * unit2)
    h = np.zeros((p, 3 * p))
    h[np.arange(p), 3 * np.arange(p)] = 1.0
    p0 = np.array(initial_variance) * unit2
    filters = []
    for f, q in ((f_cv, q_cv), (f_ca, q_ca)):
        kf = KalmanFilter(dim_x=3 * p, dim_z=p)
        kf.F, kf.Q, kf.H = block_diag(*([f] * p)), block_diag(*([q] * p)), h.copy()
        kf.R = np.eye(p) * measurement_noise * unit2
        filters.append(kf)
    s = switch_probability
    imm = IMMEstimator(filters, [0.5, 0.5], np.array([[1.0 - s, s], [s, 1.0 - s]]))
    predictions, modes = np.full((t_count, p), np.nan), np.full((t_count, 2), np.nan)
    started = False
    for t in range(t_count):
        valid = bool(np.isfinite(z[t]).all())
        if not started:
            if not valid:
                continue
            for kf in filters:
                kf.x = np.zeros((3 * p, 1))
                kf.x[0::3, 0] = z[t]
                kf.P = np.diag(np.tile(p0, p))
            started = True
        elif valid:
            imm.update(z[t])
        else:
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
        imm.predict()
        predictions[t] = (h @ sum(c * kf.x for c, kf in zip(imm.cbar, filters)))[:, 0]
        modes[t] = imm.cbar
    return predictions, modes


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("options", [
    {"cv_process_noise": 0.3, "ca_process_noise": 3.0, "measurement_noise": 0.5, "switch_probability": 0.03},
    {"cv_process_noise": 0.01, "ca_process_noise": 100.0, "measurement_noise": 4.0, "switch_probability": 0.1,
     "length_unit": 0.01},
])
def test_imm_predictions_equal_filterpys_imm_estimator(p, options):
    """The batched numpy IMM gives filterpy's numbers (a manoeuvring track, missing rows, a partly missing row)."""
    rng = np.random.default_rng(p)
    unit = options.get("length_unit", 1.0)
    t = np.arange(150.0)[:, None]
    z = (5.0 + np.array([0.5, -1.0, 2.0])[:p] * t + 3.0 * np.sin(t / 12.0 + np.arange(p))) * unit
    z += rng.normal(0, 0.7 * unit, z.shape)
    z[:2] = np.nan
    z[60:64] = np.nan
    z[90, 0] = np.nan
    ours, our_modes = peers.imm_predictions(z, **options, return_mode_probabilities=True)
    theirs, their_modes = _filterpy_imm(z, **options)
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
    scale = np.nanmax(np.abs(z))
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(our_modes, their_modes, rtol=0, atol=1e-9)


def test_imm_many_equals_one_run_at_a_time():
    """Candidates and pieces of different lengths batched together give each run's own numbers."""
    rng = np.random.default_rng(3)
    pieces = [np.cumsum(rng.normal(size=(n, 2)), axis=0) for n in (40, 7, 120, 1, 65)]
    candidates = [{"cv_process_noise": q, "ca_process_noise": 1.0, "measurement_noise": 0.5,
                   "switch_probability": s} for q in (0.1, 3.0) for s in (0.02, 0.1)]
    batched = peers.imm_predictions_many(pieces, candidates, 2.0)
    for c, candidate in enumerate(candidates):
        for i, z in enumerate(pieces):
            np.testing.assert_array_equal(batched[c][i], peers.imm_predictions(z, **candidate, length_unit=2.0))
