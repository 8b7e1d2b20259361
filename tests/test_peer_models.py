"""kalmix.peer_models: the peers of ``kalmix evaluate``, their conventions and their tuning."""

import itertools
import json

import numpy as np
import pytest

from kalmix import peer_models
from kalmix.peer_models import PEERS, kinematic, row_budget
from kalmix.peer_models._common import one_step_rms, tuning_rows

#: Hand-set parameters per peer for the convention tests (tuning has its own tests).
PARAMS = {
    "cv_dt": {"process_noise": 0.05, "measurement_noise": 0.3, "time_unit": 1.3},
    "ca_dt": {"process_noise": 0.01, "measurement_noise": 0.3, "time_unit": 1.3},
    "imm_dt": {"cv_process_noise": 0.01, "ca_process_noise": 0.01, "measurement_noise": 0.3,
               "switch_probability": 0.05, "time_unit": 1.3},
    "mmae_dt": {"process_noise": 0.05, "spread": 10.0, "measurement_noise": 0.3, "time_unit": 1.3},
    "holt_winters": {"alpha": 0.7, "beta": 0.3},
    "rls_ar": {"order": 2, "forgetting": 0.98, "unit": 0.5, "time_unit": 1.3},
    "ucm_llt": {"sigma2_irregular": 0.3, "sigma2_level": 0.01, "sigma2_trend": 0.01, "unit": 0.5},
}


def _peer(name):
    peer = PEERS[name]
    for module in peer.needs:
        pytest.importorskip(module)
    return peer


def _smooth(seed, t_count=120, p=2):
    """A smooth curve in continuous time, sampled at irregular times, with noise and missing rows."""
    rng = np.random.default_rng(seed)
    times = 10.0 + np.cumsum(rng.uniform(0.3, 2.5, t_count))
    freq, phase = rng.uniform(0.02, 0.06, p), rng.uniform(0, 6, p)
    values = 100 + 20 * np.sin(freq * times[:, None] + phase) + 0.5 * rng.normal(size=(t_count, p))
    values[:3] = np.nan
    if t_count > 70:
        values[40:44] = np.nan
        values[70, 0] = np.nan  # a partly missing row is missing
    return values, times


def _simulate_cv(rng, t_count, q, r, p, time_unit):
    """A CV track from the model itself (q per time_unit³), sampled at irregular times."""
    times = np.cumsum(rng.uniform(0.3, 1.7, t_count)) * time_unit
    state, out = np.zeros((p, 2)), np.empty((t_count, p))
    for t in range(t_count):
        if t:
            dt = (times[t] - times[t - 1]) / time_unit
            chol = np.linalg.cholesky(q * kinematic.process_noise_shape(dt, 2))
            state = state @ kinematic.transition(dt, 2).T + rng.normal(size=(p, 2)) @ chol.T
        out[t] = state[:, 0] + np.sqrt(r) * rng.normal(size=p)
    return out, times


# ---------------------------------------------------------------- cv_dt / ca_dt against filterpy

def _filterpy_kinematic(values, times, q, r, order, time_unit, horizon):
    from filterpy.kalman import KalmanFilter
    from scipy.linalg import block_diag

    t_count, p = values.shape
    kf = KalmanFilter(dim_x=order * p, dim_z=p)
    kf.H = np.zeros((p, order * p))
    kf.H[np.arange(p), order * np.arange(p)] = 1.0
    kf.R = r * np.eye(p)
    out, started = np.full(values.shape, np.nan), False
    p0 = np.diag([r] + [r * kinematic.INITIAL_VARIANCE_RATIO] * (order - 1))
    for t in range(t_count - 1):
        valid = np.isfinite(values[t]).all()
        if not started and valid:
            kf.x = np.zeros((order * p, 1))
            kf.x[0::order, 0] = values[t]
            kf.P, started = block_diag(*[p0] * p), True
        elif started and valid:
            kf.update(values[t][:, None])
        if not started:
            continue
        ahead = kf.x.copy()
        for k in range(t, min(t + horizon, t_count - 1)):
            ahead = block_diag(*[kinematic.transition((times[k + 1] - times[k]) / time_unit, order)] * p) @ ahead
        if t + horizon < t_count:
            out[t] = (kf.H @ ahead)[:, 0]
        dt = (times[t + 1] - times[t]) / time_unit
        kf.predict(F=block_diag(*[kinematic.transition(dt, order)] * p),
                   Q=block_diag(*[q * kinematic.process_noise_shape(dt, order)] * p))
    return out


@pytest.mark.parametrize("name, order", [("cv_dt", 2), ("ca_dt", 3)])
@pytest.mark.parametrize("horizon", [1, 4])
def test_kinematic_equals_filterpy(name, order, horizon):
    pytest.importorskip("filterpy")
    values, times = _smooth(0, 150, p=2)
    params = PARAMS[name]
    ours = PEERS[name].predict(values, times, params, horizon)
    theirs = _filterpy_kinematic(values, times, params["process_noise"], params["measurement_noise"], order,
                                 params["time_unit"], horizon)
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
    assert np.isfinite(ours[3:-horizon]).all()
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", ["cv_dt", "ca_dt"])
def test_predict_many_equals_predict(name):
    pieces = [_smooth(seed, n) for seed, n in ((1, 90), (2, 150), (3, 2), (4, 120), (5, 400))]
    assert len(list(kinematic.segment_batches([len(t) for _, t in pieces]))) > 1  # padding is bounded
    batched = PEERS[name].predict_many(pieces, PARAMS[name], horizon=2)
    for (values, times), ours in zip(pieces, batched):
        np.testing.assert_allclose(ours, PEERS[name].predict(values, times, PARAMS[name], 2), rtol=1e-12, atol=1e-12)


def test_noiseless_constant_velocity_and_acceleration_with_irregular_dt_are_learnt_exactly():
    rng = np.random.default_rng(5)
    times = np.cumsum(rng.uniform(0.3, 2.0, 80))
    line = 3.0 + np.array([1.5, -0.7]) * times[:, None]
    parabola = line + np.array([0.05, 0.02]) * times[:, None] ** 2
    params = {"process_noise": 1e-4, "measurement_noise": 1.0, "time_unit": 1.0}
    cv_errors = np.abs(line[1:] - kinematic.predict_cv(line, times, params)[:-1])
    ca_errors = np.abs(parabola[1:] - kinematic.predict_ca(parabola, times, params)[:-1])
    assert cv_errors[:3].max() > 1e-4  # it starts from zero velocity ...
    assert cv_errors[-5:].max() < 1e-8  # ... and ends exact
    assert ca_errors[-5:].max() < 1e-7


def test_predictions_depend_on_q_over_r_only():
    values, times = _smooth(6)
    params = PARAMS["cv_dt"]
    scaled = {**params, "process_noise": params["process_noise"] * 37.0,
              "measurement_noise": params["measurement_noise"] * 37.0}
    np.testing.assert_allclose(kinematic.predict_cv(values, times, scaled), kinematic.predict_cv(values, times, params),
                               rtol=1e-11)


@pytest.mark.parametrize("q_true", [0.01, 100.0])
def test_tune_cv_recovers_the_simulated_noises(q_true):
    rng = np.random.default_rng(7)
    unit, time_unit = 2.0, 0.1
    segments = []
    for _ in range(4):
        values, times = _simulate_cv(rng, 500, q_true * unit**2, unit**2, 2, time_unit)
        segments.append((values, times, np.arange(500) < 400))
    tuned = kinematic.tune_cv(segments, unit=unit, time_unit=time_unit)
    assert abs(np.log10(tuned["process_noise"] / (q_true * unit**2))) < 0.5  # within a step of the grid
    assert abs(np.log(tuned["measurement_noise"] / unit**2)) < np.log(1.25)
    json.dumps(tuned)


# ---------------------------------------------------------------- imm_dt / mmae_dt against filterpy's objects

def _filterpy_filters(p, order, r, z0, count):
    from filterpy.kalman import KalmanFilter

    h = np.zeros((p, order * p))
    h[np.arange(p), order * np.arange(p)] = 1.0
    x0 = np.zeros((order * p, 1))
    x0[0::order, 0] = z0
    p0 = np.kron(np.eye(p), np.diag([r] + [r * kinematic.INITIAL_VARIANCE_RATIO] * (order - 1)))
    filters = []
    for _ in range(count):
        kf = KalmanFilter(dim_x=order * p, dim_z=p)
        kf.H, kf.R, kf.x, kf.P = h.copy(), np.eye(p) * r, x0.copy(), p0.copy()
        filters.append(kf)
    return filters, h


def _filterpy_imm_models(dt, p, q_cv, q_ca):
    f_cv = kinematic.transition(dt, 3)
    f_cv[1, 2] = f_cv[0, 2] = f_cv[2, 2] = 0.0
    q_shape = np.zeros((3, 3))
    q_shape[:2, :2] = kinematic.process_noise_shape(dt, 2)
    eye = np.eye(p)
    return ((np.kron(eye, f_cv), np.kron(eye, q_cv * q_shape)),
            (np.kron(eye, kinematic.transition(dt, 3)), np.kron(eye, q_ca * kinematic.process_noise_shape(dt, 3))))


def _filterpy_imm_dt(values, times, params, horizon):
    """filterpy's ``IMMEstimator`` stepped row by row: the reference ``imm_dt`` follows."""
    from filterpy.kalman import IMMEstimator

    q_cv, q_ca, r, s, time_unit = (params[k] for k in ("cv_process_noise", "ca_process_noise", "measurement_noise",
                                                       "switch_probability", "time_unit"))
    t_count, p = values.shape
    out = np.full(values.shape, np.nan)
    markov = np.array([[1.0 - s, s], [s, 1.0 - s]])
    imm = filters = None
    for t in range(t_count):
        valid = bool(np.isfinite(values[t]).all())
        if imm is None:
            if not valid:
                continue
            filters, h = _filterpy_filters(p, 3, r, values[t], 2)
            imm = IMMEstimator(filters, [0.5, 0.5], markov)
        elif valid:
            imm.update(values[t][:, None])
        else:
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
        if t + 1 >= t_count:
            break
        for kf, (f, q) in zip(filters, _filterpy_imm_models((times[t + 1] - times[t]) / time_unit, p, q_cv, q_ca)):
            kf.F, kf.Q = f, q
        imm.predict()
        if t + horizon >= t_count:
            continue
        saved = [(kf.x.copy(), kf.P.copy()) for kf in filters], imm.mu.copy(), imm.cbar.copy(), imm.omega.copy()
        for k in range(t + 1, t + horizon):
            imm.mu = imm.cbar.copy()
            imm._compute_mixing_probabilities()
            for kf, (f, q) in zip(filters, _filterpy_imm_models((times[k + 1] - times[k]) / time_unit, p, q_cv,
                                                                 q_ca)):
                kf.F, kf.Q = f, q
            imm.predict()
        out[t] = (h @ sum(c * kf.x for c, kf in zip(imm.cbar, filters)))[:, 0]
        for kf, (x, cov) in zip(filters, saved[0]):
            kf.x, kf.P = x, cov
        imm.mu, imm.cbar, imm.omega = saved[1:]
    return out


def _filterpy_mmae_dt(values, times, params, horizon):
    """filterpy's ``MMAEFilterBank`` stepped row by row: the reference ``mmae_dt`` follows."""
    from filterpy.kalman import MMAEFilterBank

    from kalmix.peer_models.multiple_model import MMAE_FILTERS

    q, spread, r, time_unit = (params[k] for k in ("process_noise", "spread", "measurement_noise", "time_unit"))
    t_count, p = values.shape
    out = np.full(values.shape, np.nan)
    qs = q * spread ** (np.arange(MMAE_FILTERS) - MMAE_FILTERS // 2)
    bank = filters = None
    eye = np.eye(p)
    for t in range(t_count):
        valid = bool(np.isfinite(values[t]).all())
        if bank is None:
            if not valid:
                continue
            filters, h = _filterpy_filters(p, 2, r, values[t], MMAE_FILTERS)
            bank = MMAEFilterBank(filters, np.full(MMAE_FILTERS, 1.0 / MMAE_FILTERS), dim_x=2 * p)
        elif valid:
            bank.update(values[t][:, None])
        if t + horizon < t_count:
            jump = np.kron(eye, kinematic.transition((times[t + horizon] - times[t]) / time_unit, 2))
            out[t] = (h @ jump @ sum(w * kf.x for w, kf in zip(bank.p, filters)))[:, 0]
        if t + 1 < t_count:
            dt = (times[t + 1] - times[t]) / time_unit
            f, shape = np.kron(eye, kinematic.transition(dt, 2)), np.kron(eye, kinematic.process_noise_shape(dt, 2))
            for kf, qi in zip(filters, qs):
                kf.F, kf.Q = f, qi * shape
            bank.predict()
    return out


_FILTERPY_REFERENCES = {"imm_dt": _filterpy_imm_dt, "mmae_dt": _filterpy_mmae_dt}


@pytest.mark.parametrize("name", ["imm_dt", "mmae_dt"])
@pytest.mark.parametrize("p", [1, 3])
@pytest.mark.parametrize("horizon", [1, 3])
def test_multiple_model_peers_equal_filterpys_objects(name, p, horizon):
    """The batched numpy IMM and MMAE give the numbers of filterpy's IMMEstimator and MMAEFilterBank (irregular
    Δt, missing and partly missing rows), within rounding: a change of 1 ulp in the input moves filterpy's own
    IMM by ~1e-11 of the data's scale on such tracks."""
    _peer(name)
    values, times = _smooth(20 + p, 150, p=p)
    params = {**PARAMS[name], "switch_probability": 0.05} if name == "imm_dt" else PARAMS[name]
    ours = PEERS[name].predict(values, times, params, horizon)
    theirs = _FILTERPY_REFERENCES[name](values, times, params, horizon)
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
    scale = np.nanmax(np.abs(values))
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9 * scale)


@pytest.mark.parametrize("name", ["imm_dt", "mmae_dt"])
def test_multiple_model_tuning_picks_filterpys_candidate(name):
    """The batched grid search scores every candidate as filterpy's objects do: same choice, same tuning RMS."""
    from kalmix.peer_models import multiple_model

    _peer(name)
    segments = [(*_smooth(seed, 70), np.arange(70) < 50) for seed in (30, 31)]
    tuned = PEERS[name].tune(segments, unit=0.5, time_unit=1.3)
    pieces = tuning_rows(segments, multiple_model.TUNE_ROWS)
    keys = ("cv_process_noise", "ca_process_noise", "switch_probability") if name == "imm_dt" else ("spread",)
    fixed = {k: v for k, v in tuned.items() if k not in keys + ("tuning_rms",)}
    if name == "imm_dt":
        cv = kinematic.tune_cv(segments, unit=0.5, time_unit=1.3)
        ca = kinematic.tune_ca(segments, unit=0.5, time_unit=1.3)
        ca_q = ca["process_noise"] * cv["measurement_noise"] / ca["measurement_noise"]
        grid = {"cv_process_noise": [f * cv["process_noise"] for f in multiple_model._IMM_CV_FACTORS],
                "ca_process_noise": [f * ca_q for f in multiple_model._IMM_CA_FACTORS],
                "switch_probability": multiple_model._IMM_SWITCH}
    else:
        grid = {"spread": multiple_model._MMAE_SPREADS}
    reference = {}
    for values in itertools.product(*grid.values()):
        candidate = {**dict(zip(grid, values)), **fixed}
        reference[values] = one_step_rms(pieces, [_FILTERPY_REFERENCES[name](z, t, candidate, 1) for z, t, _ in pieces])
    best = min(reference, key=reference.get)
    assert tuple(tuned[k] for k in keys) == pytest.approx(best, rel=1e-12)
    assert tuned["tuning_rms"] == pytest.approx(reference[best], rel=1e-9)
    ranked = sorted(reference.values())
    assert len(ranked) == 1 or ranked[1] > ranked[0] * (1 + 1e-6)   # the choice is not a rounding-level tie


@pytest.mark.parametrize("name", ["imm_dt", "mmae_dt", "holt_winters", "rls_ar"])
def test_loop_peers_predict_many_equals_predict(name):
    _peer(name)
    pieces = [_smooth(seed, n) for seed, n in ((1, 90), (2, 150), (3, 2), (4, 120))]
    batched = PEERS[name].predict_many(pieces, PARAMS[name], horizon=2)
    for (values, times), ours in zip(pieces, batched):
        np.testing.assert_array_equal(ours, PEERS[name].predict(values, times, PARAMS[name], 2))


def _river_holt_winters(values, times, params, horizon):
    """river's ``HoltWinters`` fed row by row: the reference ``holt_winters`` follows."""
    from river.time_series import HoltWinters

    from kalmix.peer_models._common import frame_steps

    t_count, p = values.shape
    valid = np.isfinite(values).all(axis=1)
    steps = frame_steps(valid, horizon)
    models = [HoltWinters(alpha=params["alpha"], beta=params["beta"]) for _ in range(p)]
    out, seen, last = np.full(values.shape, np.nan), 0, None
    for t in range(t_count - horizon):
        if valid[t]:
            for model, y in zip(models, values[t].tolist()):
                model.learn_one(y)
            seen, last = seen + 1, values[t]
        if seen == 1:
            out[t] = last
        elif seen > 1:
            out[t] = [model.forecast(int(steps[t]))[-1] for model in models]
    return out


def _padasip_rls_ar(values, times, params, horizon):
    """padasip's ``FilterRLS`` adapted row by row: the reference ``rls_ar`` follows."""
    from padasip.filters import FilterRLS

    order, forgetting, unit, time_unit = (params[k] for k in ("order", "forgetting", "unit", "time_unit"))
    t_count, p = values.shape
    steps = np.diff(times) / time_unit
    filters = [FilterRLS(order + 1, mu=forgetting, w="zeros") for _ in range(p)]
    history = np.zeros((p, order + 1))
    history[:, -1] = 1.0
    out, last = np.full(values.shape, np.nan), None
    for t in range(t_count - horizon):
        if np.isfinite(values[t]).all():
            if last is not None:
                velocity = (values[t] - values[last]) / (times[t] - times[last]) * time_unit / unit
                for j, rls in enumerate(filters):
                    rls.adapt(velocity[j], history[j])
                history[:, 1:order] = history[:, :order - 1]
                history[:, 0] = velocity
            last = t
        if last is None:
            continue
        position, ahead = values[last].copy(), history.copy()
        for k in range(last, t + horizon):
            guess = np.array([rls.predict(ahead[j]) for j, rls in enumerate(filters)])
            position += guess * steps[k] * unit
            ahead[:, 1:order] = ahead[:, :order - 1]
            ahead[:, 0] = guess
        out[t] = position
    return out


_LOOP_REFERENCES = {"holt_winters": _river_holt_winters, "rls_ar": _padasip_rls_ar}


@pytest.mark.parametrize("name, params", [
    ("holt_winters", {"alpha": 0.7, "beta": 0.3}), ("holt_winters", {"alpha": 1.0, "beta": 0.02}),
    ("rls_ar", {"order": 1, "forgetting": 0.9, "unit": 0.5, "time_unit": 1.3}),
    ("rls_ar", {"order": 5, "forgetting": 0.999, "unit": 0.5, "time_unit": 1.3}),
])
@pytest.mark.parametrize("horizon", [1, 3])
def test_loop_peers_equal_their_libraries(name, params, horizon):
    """Holt-Winters and the RLS AR model, batched in numpy, give river's and padasip's numbers (irregular Δt,
    missing and partly missing rows, a gap of several rows)."""
    _peer(name)
    values, times = _smooth(40, 150, p=3)
    values[100:105] = np.nan
    ours = PEERS[name].predict(values, times, params, horizon)
    theirs = _LOOP_REFERENCES[name](values, times, params, horizon)
    np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(values)))


@pytest.mark.parametrize("name", ["holt_winters", "rls_ar"])
def test_loop_peers_tuning_picks_the_librarys_candidate(name):
    """The batched grid search scores every candidate as river's / padasip's objects do."""
    from kalmix.peer_models import holt_winters, rls_ar

    _peer(name)
    module = {"holt_winters": holt_winters, "rls_ar": rls_ar}[name]
    segments = [(*_smooth(seed, 60), np.arange(60) < 45) for seed in (32, 33)]
    tuned = PEERS[name].tune(segments, unit=0.5, time_unit=1.3)
    pieces = tuning_rows(segments, module.TUNE_ROWS)
    fixed = {"unit": 0.5, "time_unit": 1.3} if name == "rls_ar" else {}
    reference = {}
    for values in itertools.product(*module.GRID.values()):
        candidate = {**dict(zip(module.GRID, values)), **fixed}
        reference[values] = one_step_rms(pieces, [_LOOP_REFERENCES[name](z, t, candidate, 1) for z, t, _ in pieces])
    best = min(reference, key=reference.get)
    assert tuple(tuned[k] for k in module.GRID) == pytest.approx(best, rel=1e-12)
    assert tuned["tuning_rms"] == pytest.approx(reference[best], rel=1e-12)


# ---------------------------------------------------------------- every peer: the convention

@pytest.mark.parametrize("name", list(PEERS))
@pytest.mark.parametrize("horizon", [1, 3])
def test_strictly_causal(name, horizon):
    peer = _peer(name)
    values, times = _smooth(8)
    before = peer.predict(values, times, PARAMS[name], horizon)
    rng = np.random.default_rng(9)
    for t in (20, 60):
        changed = values.copy()
        changed[t + 1:] = rng.normal(0, 1e3, size=changed[t + 1:].shape)
        changed[t + 5:t + 8] = np.nan
        after = peer.predict(changed, times, PARAMS[name], horizon)
        np.testing.assert_array_equal(after[:t + 1], before[:t + 1])
        assert not np.allclose(after[t + 10:-horizon], before[t + 10:-horizon])


@pytest.mark.parametrize("name", list(PEERS))
@pytest.mark.parametrize("horizon", [1, 3])
def test_missing_rows_and_edges(name, horizon):
    peer = _peer(name)
    values, times = _smooth(10)
    predictions = peer.predict(values, times, PARAMS[name], horizon)
    assert predictions.shape == values.shape
    assert np.isnan(predictions[:3]).all()  # before the first valid measurement
    assert np.isnan(predictions[-horizon:]).all()  # no target row
    assert np.isfinite(predictions[3:-horizon]).all()  # missing rows still predicted
    # a partly missing row is a missing row
    whole = values.copy()
    whole[70] = np.nan
    np.testing.assert_array_equal(peer.predict(whole, times, PARAMS[name], horizon), predictions)
    assert np.isnan(peer.predict(np.full((5, 2), np.nan), times[:5], PARAMS[name], horizon)).all()


@pytest.mark.parametrize("name", list(PEERS))
def test_horizon_is_open_loop(name):
    """Row t's h-step prediction is the one-step prediction of row t+h-1 when rows t+1..t+h-1 are missing."""
    peer = _peer(name)
    values, times = _smooth(11)
    horizon = 4
    ahead = peer.predict(values, times, PARAMS[name], horizon)
    for t in (10, 30, 50, 90):
        blind = values.copy()
        blind[t + 1:t + horizon] = np.nan
        one = peer.predict(blind, times, PARAMS[name], 1)
        np.testing.assert_allclose(ahead[t], one[t + horizon - 1], rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- the filterpy, river, padasip, statsmodels peers

def test_mmae_with_equal_filters_is_the_cv_filter():
    _peer("mmae_dt")
    values, times = _smooth(12)
    cv = PARAMS["cv_dt"]
    mmae = {**cv, "spread": 1.0}
    for horizon in (1, 3):
        np.testing.assert_allclose(PEERS["mmae_dt"].predict(values, times, mmae, horizon),
                                   kinematic.predict_cv(values, times, cv, horizon), rtol=0, atol=1e-10)


def test_imm_learns_a_noiseless_constant_acceleration():
    _peer("imm_dt")
    rng = np.random.default_rng(13)
    times = np.cumsum(rng.uniform(0.3, 2.0, 80))
    parabola = 3.0 + np.array([1.5, -0.7]) * times[:, None] + np.array([0.05, 0.02]) * times[:, None] ** 2
    params = {**PARAMS["imm_dt"], "switch_probability": 1e-6, "ca_process_noise": 1e-6, "time_unit": 1.0}
    errors = np.abs(parabola[1:] - PEERS["imm_dt"].predict(parabola, times, params)[:-1])
    assert errors[-5:].max() < 1e-4 * errors[:5].max()


def test_holt_winters_extrapolates_a_straight_line_exactly():
    _peer("holt_winters")
    line = 3.0 + np.array([1.5, -0.7]) * np.arange(40.0)[:, None]
    predictions = PEERS["holt_winters"].predict(line, np.arange(40.0), {"alpha": 1.0, "beta": 1.0}, 2)
    np.testing.assert_allclose(predictions[5:-2], line[7:], rtol=1e-12)


def test_rls_ar_learns_a_noiseless_constant_velocity_with_irregular_dt():
    _peer("rls_ar")
    rng = np.random.default_rng(14)
    times = np.cumsum(rng.uniform(0.3, 2.0, 80))
    line = 3.0 + np.array([1.5, -0.7]) * times[:, None]
    errors = np.abs(line[1:] - PEERS["rls_ar"].predict(line, times, PARAMS["rls_ar"])[:-1])
    assert errors[0].max() > 0.1 and errors[-5:].max() < 1e-6


def test_ucm_maximum_likelihood_recovers_the_simulated_variances():
    _peer("ucm_llt")
    rng = np.random.default_rng(15)
    unit, true = 3.0, np.array([1.0, 0.1, 0.01])
    segments = []
    for _ in range(3):
        noise = rng.normal(size=(3, 1500, 2)) * np.sqrt(true * unit**2)[:, None, None]
        trend = np.cumsum(noise[2], axis=0)
        level = np.cumsum(trend + noise[1], axis=0)
        segments.append((level + noise[0], np.arange(1500.0), np.arange(1500) < 1200))
    tuned = PEERS["ucm_llt"].tune(segments, unit=unit, time_unit=1.0)
    fitted = np.array([tuned["sigma2_irregular"], tuned["sigma2_level"], tuned["sigma2_trend"]]) / unit**2
    np.testing.assert_allclose(fitted, true, rtol=0.3)


@pytest.mark.parametrize("name", list(PEERS))
def test_tune_returns_the_best_candidate_and_its_tuning_rms(name):
    peer = _peer(name)
    segments = []
    for seed in (16, 17):
        values, times = _smooth(seed, 90)
        segments.append((values, times, np.arange(90) < 60))
    tuned = peer.tune(segments, unit=0.5, time_unit=1.3)
    json.dumps(tuned)
    pieces = tuning_rows(segments)
    own = one_step_rms(pieces, [peer.predict(v, t, tuned) for v, t, _ in pieces])
    assert tuned["tuning_rms"] == pytest.approx(own, rel=1e-9)
    assert own < 2.0  # noise 0.5 on a smooth curve: far below the motion between samples
    # no hand-set alternative beats the tuned grid winner on the tuning rows (ML for ucm_llt)
    other = [peer.predict(v, t, PARAMS[name]) for v, t, _ in pieces]
    assert own <= one_step_rms(pieces, other)


# ---------------------------------------------------------------- registry, budgets and validation

def test_registry():
    assert set(PEERS) == {"cv_dt", "ca_dt", "imm_dt", "mmae_dt", "holt_winters", "rls_ar", "ucm_llt"}
    for name, peer in PEERS.items():
        assert peer.name == name and callable(peer.tune) and callable(peer.predict)
        assert (peer.max_rows is not None) == (name in ("imm_dt", "mmae_dt"))  # the filterpy loops
    assert peer_models.available("cv_dt")
    with pytest.raises(ValueError, match="peer: expected one of"):
        peer_models.available("kalman")


def test_row_budget_keeps_the_first_rows_of_every_segment():
    np.testing.assert_array_equal(row_budget([10, 3, 50], None), [10, 3, 50])
    np.testing.assert_array_equal(row_budget([10, 3, 50], 25), [10, 3, 12])
    np.testing.assert_array_equal(row_budget([10, 3, 50], 20), [8, 3, 8])
    assert row_budget([10, 3, 50], 20).sum() <= 20


@pytest.mark.parametrize("values, times, horizon, message", [
    (np.zeros((5, 4)), np.arange(5.0), 1, r"values: expected shape \(T, p\) with p in 1..3, got \(5, 4\)"),
    (np.zeros((5, 2)), np.arange(4.0), 1, r"times: expected shape \(5,\) like values, got \(4,\)"),
    (np.zeros((3, 2)), np.array([0.0, 2.0, 2.0]), 1, "times: expected strictly increasing times, got 2.0 at row 2"),
    (np.full((3, 2), np.inf), np.arange(3.0), 1, "values: expected finite numbers or NaN"),
    (np.zeros((3, 2)), np.arange(3.0), 0, "horizon: expected an integer >= 1, got 0"),
])
def test_validation_names_the_argument(values, times, horizon, message):
    with pytest.raises(ValueError, match=message):
        kinematic.predict_cv(values, times, PARAMS["cv_dt"], horizon)


def test_validation_of_params_and_segments():
    values, times = _smooth(18, 30)
    with pytest.raises(ValueError, match="params: expected keys process_noise, measurement_noise, time_unit"):
        kinematic.predict_cv(values, times, {"process_noise": 1.0})
    with pytest.raises(ValueError, match=r"params\['measurement_noise'\]: expected a finite number > 0, got -1"):
        kinematic.predict_cv(values, times, {**PARAMS["cv_dt"], "measurement_noise": -1})
    with pytest.raises(ValueError, match=r"mask of segments\[0\]: expected a bool array of shape \(30,\)"):
        kinematic.tune_cv([(values, times, np.ones(29, bool))], unit=1.0, time_unit=1.0)
    with pytest.raises(ValueError, match="unit: expected a finite number > 0, got 0"):
        kinematic.tune_cv([(values, times, np.ones(30, bool))], unit=0, time_unit=1.0)
    with pytest.raises(ValueError, match="segments: expected at least one tuning row"):
        kinematic.tune_cv([(values, times, np.zeros(30, bool))], unit=1.0, time_unit=1.0)
