"""The bank's reach: across a step longer than it, only the CV experts make the one-step forecast."""

import math

import numpy as np
import pandas as pd
import pytest

from kalmix.bank import DEFAULT_BANK, DEFAULT_REACH, make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce

REACH = 8.0   # what the README advises on tracks sampled at irregular intervals


def _sparse_track(seed=0, rows=120):
    """Two targets moving at constant speed on a gentle curve, reported after 1 or (one row in five) 20 units."""
    rng = np.random.default_rng(seed)
    steps = np.where(rng.uniform(size=(rows, 2)) < 0.2, 20.0, 1.0)
    t = np.cumsum(steps, axis=0)
    z = np.stack([3.0 * t + 0.01 * t ** 1.5, -2.0 * t], axis=-1) + rng.normal(0, 0.5, (rows, 2, 2))
    return z, t


def _far_columns(bank):
    return np.concatenate([np.full(f.n_experts, f.kind != "cv") for f in bank.families])


@pytest.mark.parametrize("run", [engine.run, ce.run], ids=["spec", "compiled"])
def test_across_a_long_step_only_the_cv_experts_weigh(run):
    z, t = _sparse_track()
    bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4, reach=REACH)
    assert bank.reach == REACH * 1.0
    result = run(bank, z, t, record_experts=True)
    step = np.diff(t, axis=0, prepend=np.nan)
    far = _far_columns(bank)
    long_rows = (step > bank.reach) & np.isfinite(result.forecasts).all(-1)
    long_rows[:2] = False   # a target needs two learned rows before anything is out of reach
    assert long_rows.sum() > 20
    weights = result.weights[long_rows]
    assert np.all(weights[:, far] == 0.0)
    assert np.allclose(weights[:, ~far].sum(-1), 1.0)
    # on the other rows every family may weigh, and the recorded forecasts are the experts' own
    short = (step <= bank.reach) & np.isfinite(result.forecasts).all(-1)
    assert (result.weights[short][:, far] > 0).any()
    assert np.isfinite(result.experts[long_rows][:, far]).all()


def test_the_reach_changes_only_the_one_step_weights():
    """Same experts (the families learn every row as before) and the same lead weights (the lead forecasts blend
    them with the one-step weights', which the reach changes); better one-step forecasts here, where the AR / CA /
    turn / AKF experts extrapolate their fits across 20 units."""
    z, t = _sparse_track(seed=1, rows=200)
    common = dict(**DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4, lead=3.0)
    near, everyone = (ce.run(make_bank(2, reach=reach, **common), z, t, record_experts=True)
                      for reach in (REACH, None))
    assert np.array_equal(near.experts, everyone.experts, equal_nan=True)
    for mine, theirs in zip(near.state.lead.rule, everyone.state.lead.rule):
        assert np.array_equal(mine, theirs)
    step = np.diff(t, axis=0, prepend=np.nan)
    late = (np.arange(len(t))[:, None] > 40) & np.isfinite(near.forecasts).all(-1)
    rms = lambda f, rows: float(np.sqrt(np.mean((f - z)[rows] ** 2)))  # noqa: E731
    long_rows = late & (step > REACH)
    assert rms(near.forecasts, long_rows) < rms(everyone.forecasts, long_rows)
    assert not np.array_equal(near.forecasts, everyone.forecasts, equal_nan=True)


def test_a_bank_without_cv_experts_or_without_others_is_unchanged():
    z, t = _sparse_track(seed=2)
    for kind in ("ar", "akf", "turn"):
        a, b = (ce.run(make_bank(2, kind, length_unit=0.5, n_akf=4, reach=reach), z, t) for reach in (1.0, None))
        assert np.array_equal(a.forecasts, b.forecasts, equal_nan=True), kind
    bank = make_bank(2, "kinematic", length_unit=0.5, reach=1.0)
    assert bank.far_experts() is not None
    cv_only = engine.Bank(2, bank.families[:1], bank.rule, bank.rule_params, reach=1.0)
    assert cv_only.far_experts() is None


def test_span_needs_two_learned_rows():
    """From one position no expert extrapolates anything: the forecast after a track's first row is the same
    whatever the reach (so it does not depend on a time unit learned later)."""
    bank = make_bank(2, **DEFAULT_BANK, length_unit=1.0, n_akf=4, reach=0.5)
    state = engine.init_bank_state(bank, 1)
    state, _ = engine.step(bank, state, np.array([[0.0, 0.0]]), 0.0)
    assert np.isnan(engine.span(state.screen, 5.0)).all()
    mean, _ = engine.forecast(bank, state, 5.0)
    plain = make_bank(2, **DEFAULT_BANK, length_unit=1.0, n_akf=4, reach=None)
    assert np.array_equal(mean, engine.forecast(plain, state, 5.0)[0])
    state, _ = engine.step(bank, state, np.array([[1.0, 0.5]]), 1.0)
    assert engine.span(state.screen, 5.0)[0] == 4.0


def test_the_default_bank_has_no_reach():
    assert DEFAULT_REACH is None and make_bank(2, **DEFAULT_BANK).reach == math.inf
    assert make_bank(2, **DEFAULT_BANK).far_experts() is None


def test_forecast_at_a_time_uses_the_reach_as_the_row_forecast_does():
    z, t = _sparse_track(seed=3, rows=60)
    bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4, reach=REACH)
    state = engine.init_bank_state(bank, 2)
    for i in range(40):
        state, _ = engine.step(bank, state, z[i], t[i])
    later = t[39] + 25.0
    mean, cov = engine.forecast(bank, state, later)
    _, out = engine.step(bank, state, np.full((2, 2), np.nan), later)   # a missing row at that time
    assert np.array_equal(mean, out.forecast) and np.array_equal(cov, out.covariance)


@pytest.mark.parametrize("bad,error", [(0.0, ValueError), (-1.0, ValueError), (-math.inf, ValueError),
                                       (math.nan, ValueError), ("3", TypeError), (True, TypeError)])
def test_reach_is_checked(bad, error):
    with pytest.raises(error, match="reach"):
        make_bank(2, reach=bad)


def test_reach_is_in_time_units_and_in_the_description():
    bank = make_bank(2, time_unit=10.0, reach=2.5)
    assert bank.reach == 25.0 and bank.description["reach"] == 2.5
    assert make_bank(2, **bank.description).reach == 25.0   # a saved bank is rebuilt from its description
    assert make_bank(2, reach=None).reach == math.inf
    assert make_bank(2, reach=math.inf).reach == math.inf and make_bank(2, reach=math.inf).description["reach"] is None


# ------------------------------------------------------------------------------------------------ command line
def _reports(rows=150):
    """Two vessels reported after 10 s, and one time in five after 180 s (the time unit learned: 10 s)."""
    rng = np.random.default_rng(6)
    frames = []
    for vessel in range(2):
        steps = np.where(rng.uniform(size=rows) < 0.2, 180.0, 10.0)
        steps[0] = 10.0
        t = np.cumsum(steps)
        xy = np.stack([5.0 * t, 0.5 * t + 1e-3 * t ** 1.4], axis=1) + rng.normal(0, 5, (rows, 2))
        frames.append(pd.DataFrame({"vessel": f"v{vessel}", "t": t, "x": xy[:, 0], "y": xy[:, 1]}))
    return pd.concat(frames).sort_values("t", kind="stable")


def _predict(tmp_path, *extra, name="out.csv"):
    from click.testing import CliRunner

    from kalmix.cli import build

    path = tmp_path / "reports.csv"
    if not path.exists():
        _reports().to_csv(path, index=False)
    result = CliRunner().invoke(build(), ["predict", str(path), "--id", "vessel", "--max-gap", "none",
                                          "--no-progress", "-o", str(tmp_path / name), *extra])
    return result, (pd.read_csv(tmp_path / name) if result.exit_code == 0 else None)


def test_cli_reach_none_and_a_number(tmp_path):
    """--reach 8 lets only the CV experts predict across the 180 s steps: better here than every expert (AR /
    CA / turn / AKF extrapolated over 18 report intervals, --reach none). These steps are heavy-tailed, so the
    default settles a reach of 1.5 time units, and is better too."""
    table = _reports()
    auto = _predict(tmp_path)[1]
    assert auto.equals(_predict(tmp_path, "--reach", "1.5", name="same.csv")[1])
    off = _predict(tmp_path, "--reach", "none", name="none.csv")[1]
    eight = _predict(tmp_path, "--reach", "8", name="eight.csv")[1]
    assert not eight.equals(off) and not auto.equals(off)

    def rms(out):
        merged = table.merge(out, on=["vessel", "t"])
        nxt = merged.groupby("vessel")[["x", "y"]].shift(-1).to_numpy()
        pred = merged[["pred_x", "pred_y"]].to_numpy()
        ok = np.isfinite(nxt).all(1) & np.isfinite(pred).all(1) & (merged.groupby("vessel").cumcount() > 30)
        return float(np.sqrt(np.mean((nxt[ok] - pred[ok]) ** 2)))

    assert rms(eight) < 0.8 * rms(off) and rms(auto) < 0.8 * rms(off)


def test_cli_reach_with_a_bank_without_cv_experts_warns(tmp_path):
    result, out = _predict(tmp_path, "--reach", "8", "--bank", "ar")
    assert result.exit_code == 0 and "--reach" in result.output and "changes nothing" in result.output
    assert out.equals(_predict(tmp_path, "--bank", "ar", name="plain.csv")[1])


@pytest.mark.parametrize("bad", ["0", "-2", "abc", "nan"])
def test_cli_reach_refuses_bad_values(tmp_path, bad):
    result, _ = _predict(tmp_path, "--reach", bad)
    assert result.exit_code == 2 and "--reach" in result.output and "'none'" in result.output


def test_cli_reach_is_kept_in_the_state(tmp_path):
    state = str(tmp_path / "s.kmx")
    first, _ = _predict(tmp_path, "--reach", "none", "--state", state)
    assert first.exit_code == 0, first.output
    again, _ = _predict(tmp_path, "--reach", "4", "--state", state, name="again.csv")
    assert again.exit_code == 1 and "--reach" in again.output and "new --state" in again.output
    assert "made with none, got 4.0" in again.output


def test_evaluate_takes_the_reach(tmp_path):
    from click.testing import CliRunner

    from kalmix.cli import build

    path = tmp_path / "reports.csv"
    _reports().to_csv(path, index=False)
    rms = {}
    for reach in ("8", "none"):
        out = tmp_path / f"r{reach}.json"
        result = CliRunner().invoke(build(), ["evaluate", str(path), "--id", "vessel", "--max-gap", "none",
                                              "--no-peers", "--no-per-track", "--experts", "4", "--reach", reach,
                                              "--json", str(out)])
        assert result.exit_code == 0, result.output
        import json
        rms[reach] = json.loads(out.read_text())["overall"]["mixture"]["one_step"]["rms"]
    assert rms["8"] < 0.8 * rms["none"]


def test_compiled_equals_the_spec_across_long_steps_restarts_and_missing_rows():
    """Bit for bit, with long steps right after restarts (a target with one learned row has no span) and
    after missing rows, ahead times past the reach, and a lead head."""
    z, t = _sparse_track(seed=4, rows=150)
    z[30:33, 0] = np.nan
    restart = np.zeros(t.shape, dtype=bool)
    restart[[20, 60, 61, 100], 0] = True
    restart[[45, 90], 1] = True
    t[[21, 46, 91], [0, 1, 1]] = t[[20, 45, 90], [0, 1, 1]] + 30.0   # a long step right after a restart
    t = np.maximum.accumulate(t, axis=0)
    t[1:] += np.cumsum(np.diff(t, axis=0) <= 0, axis=0) * 1e-3   # keep the times increasing
    bank = make_bank(2, **DEFAULT_BANK, length_unit=0.5, time_unit=1.0, n_akf=4, lead=2.0, reach=REACH)
    row = np.arange(len(t))[:, None] % 3
    ahead = t + np.where(row == 0, 12.0, np.where(row == 1, REACH - 0.5, 1.0))   # past, just within, well within
    ref = engine.run(bank, z, t, ahead_times=ahead, restart=restart, record_experts=True)
    fast = ce.run(bank, z, t, ahead_times=ahead, restart=restart, record_experts=True)
    for name in ("forecasts", "std", "ahead", "ahead_std", "lead", "lead_std", "weights", "experts"):
        assert np.array_equal(getattr(ref, name), getattr(fast, name), equal_nan=True), name
    plain = ce.run(make_bank(2, **{**DEFAULT_BANK, "reach": None}, length_unit=0.5, time_unit=1.0, n_akf=4,
                             lead=2.0), z, t, ahead_times=ahead, restart=restart)
    assert not np.array_equal(plain.ahead, fast.ahead, equal_nan=True)   # the reach was crossed
