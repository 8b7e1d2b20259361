"""The sampling the data show: the time unit (the median step of the first table that has one) and the automatic
reach (1.5 time units on heavy-tailed steps, none on others), settled before any row is stepped, saved, rolled
back with the rows that settled them, and said by ``kalmix predict``."""

import numpy as np
import pandas as pd
import pytest

from kalmix import StreamConfig, TrackPredictor
from kalmix.streaming import IRREGULAR_REACH, auto_reach, reach_for_steps

CONFIG = dict(n_experts=4, seed=1, length_unit=1.0)


def _table(steps, tracks=3, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(tracks):
        t = np.concatenate([[0.0], np.cumsum(steps(rng, 39))]) + k
        xy = np.cumsum(rng.normal(size=(40, 2)), 0)
        frames.append(pd.DataFrame({"track_id": k, "time": t, "x": xy[:, 0], "y": xy[:, 1]}))
    return pd.concat(frames, ignore_index=True).sort_values("time", kind="stable").reset_index(drop=True)


def _regular(rng, n):
    return 10.0 * rng.uniform(0.9, 1.1, n)   # jittered: regular


def _log_uniform(rng, n):
    return np.exp(rng.uniform(np.log(2.0), np.log(180.0), n))


def test_the_reach_is_set_only_where_the_steps_are_heavy_tailed():
    """Reports every 2 s to 3 min get a reach; regular steps, gaps, and frames dropped at random (whose long steps
    are a few usual ones: constant acceleration there was 3.9x the optimum with the reach, 1.07x without) do
    not."""
    rng = np.random.default_rng(0)
    assert IRREGULAR_REACH == 1.5
    assert reach_for_steps(_regular(rng, 500)) is None
    assert reach_for_steps(np.r_[np.full(100, 0.1), np.full(2, 30.0)]) is None   # a few missed rows or gaps
    for keep in (0.9, 0.6, 0.4, 0.1, 0.03):   # frames dropped at random: geometric steps
        assert reach_for_steps(rng.geometric(keep, 5000).astype(float)) is None, keep
    assert reach_for_steps(rng.uniform(600.0, 3600.0, 500)) is None   # every 10-60 min
    assert reach_for_steps(_log_uniform(rng, 500)) == IRREGULAR_REACH
    assert reach_for_steps(rng.choice([2.0, 3.0, 10.0, 10.0, 10.0, 30.0, 180.0], 500)) == IRREGULAR_REACH   # AIS-like
    assert reach_for_steps([]) is None and reach_for_steps([0.0, -1.0, np.nan]) is None
    assert reach_for_steps(_log_uniform(rng, 49)) is None   # too few steps to tell
    times = np.cumsum(_log_uniform(rng, 60)).reshape(20, 3)
    assert auto_reach(times) == reach_for_steps(np.diff(times, axis=0))


@pytest.mark.parametrize("steps, reach", [(_regular, None), (_log_uniform, IRREGULAR_REACH)])
def test_a_table_settles_the_time_unit_and_the_reach_before_its_rows(steps, reach):
    table = _table(steps)
    predictor = TrackPredictor(StreamConfig(**CONFIG))
    assert predictor.config.reach == "auto"
    predictor.process_table(table)
    gaps = np.concatenate([np.diff(g.to_numpy()) for _, g in table.groupby("track_id")["time"]])
    assert predictor.config.time_unit == pytest.approx(np.median(gaps), rel=1e-11)
    assert predictor.config.reach == reach and predictor.params.reach == (np.inf if reach is None else
                                                                          reach * predictor.config.time_unit)
    given = TrackPredictor(StreamConfig(**CONFIG, reach=None))
    given.process_table(table)
    assert given.config.reach is None   # given: kept
    if reach is not None:   # the reach changes the forecasts across the long steps, and only there
        a, b = predictor.process_table(table.assign(time=table["time"] + 1e4)), given.process_table(
            table.assign(time=table["time"] + 1e4))
        assert not np.allclose(a["pred_x"], b["pred_x"], equal_nan=True)


def test_a_stream_takes_no_reach_and_a_given_time_unit_still_settles_it_from_a_table():
    table = _table(_log_uniform)
    stream = TrackPredictor(StreamConfig(**CONFIG))
    stream.step_row(0, 0.0, [1.0, 2.0])
    assert stream.config.reach is None   # rows one by one: no steps to judge the sampling by
    known = TrackPredictor(StreamConfig(**CONFIG, time_unit=5.0))
    known.process_table(table)
    assert known.config.time_unit == 5.0 and known.config.reach == IRREGULAR_REACH


def test_an_unsettled_reach_is_saved_as_auto_settles_on_resume_and_a_rollback_undoes_it(tmp_path):
    table = _table(_log_uniform)
    firsts = table.groupby("track_id").head(1)   # one row per track: no step yet
    predictor = TrackPredictor(StreamConfig(**CONFIG))
    predictor.process_table(firsts)
    assert predictor.config.reach == "auto" and predictor.config.time_unit is None
    predictor.save(tmp_path / "s.npz")
    resumed = TrackPredictor.load(tmp_path / "s.npz")
    assert resumed.config.reach == "auto"
    rest = table.drop(index=firsts.index)
    resumed.process_table(rest)
    whole = TrackPredictor(StreamConfig(**CONFIG))
    whole.process_table(table)
    assert (resumed.config.time_unit, resumed.config.reach) == (whole.config.time_unit, whole.config.reach)
    bad = rest.assign(x=rest["x"].astype(object))
    bad.loc[bad.index[-1], "x"] = "oops"
    undone = TrackPredictor.load(tmp_path / "s.npz")
    with pytest.raises(ValueError, match="must hold numbers"):
        undone.process_table(bad)
    assert undone.config.reach == "auto" and undone.config.time_unit is None   # all or nothing


def test_predict_says_the_reach_it_settled_on_irregular_steps(tmp_path):
    from click.testing import CliRunner

    from kalmix.cli import build

    path = tmp_path / "in.csv"
    _table(_log_uniform).to_csv(path, index=False)
    runner = CliRunner()
    said = runner.invoke(build(), ["predict", str(path), "-o", str(tmp_path / "a.csv"), "--experts", "4",
                                   "--no-progress", "--state", str(tmp_path / "a.npz")])
    assert said.exit_code == 0, said.output
    assert "the time steps are heavy-tailed: across a step over 1.5 time units" in said.stderr
    assert TrackPredictor.load(tmp_path / "a.npz").config.reach == IRREGULAR_REACH
    off = runner.invoke(build(), ["predict", str(path), "-o", str(tmp_path / "b.csv"), "--experts", "4",
                                  "--no-progress", "--reach", "none"])
    assert off.exit_code == 0 and "heavy-tailed" not in off.stderr
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert not np.allclose(a["pred_x"], b["pred_x"], equal_nan=True)


def test_on_heavy_tailed_sampling_a_young_track_is_not_cut_at_its_usual_long_steps():
    """A vessel whose first reports came 2-5 s apart, then 144 s: a young track's own steps made those usual
    steps gaps, and it restarted twice in its first 7 reports (a new user's finding). On heavy-tailed sampling the
    gap floor (3 x the steps' 90th percentile) keeps them; a day of silence is still a gap; regular data and
    streams get no floor."""
    rng = np.random.default_rng(3)
    table = _table(_log_uniform, tracks=4)
    start = table["time"].max() + 10.0
    moored = np.concatenate([[0.0, 2.0, 5.0, 8.0, 11.0, 155.0, 298.0], 298.0 + np.cumsum(_log_uniform(rng, 30)),
                             [10_000.0]]) + start
    moored[-1] = moored[-2] + 86400.0   # a day of silence
    table = pd.concat([table, pd.DataFrame({"track_id": 9, "time": moored, "x": rng.normal(size=len(moored)),
                                            "y": rng.normal(size=len(moored))})], ignore_index=True)
    steps = np.concatenate([np.diff(g.to_numpy()) for _, g in table.groupby("track_id")["time"]])
    predictor = TrackPredictor(StreamConfig(**CONFIG))
    out = predictor.process_table(table)
    assert predictor.config.gap_floor == pytest.approx(3 * np.quantile(steps, 0.9), rel=1e-12)
    segments = out.loc[out["track_id"] == 9, "segment"].to_numpy()
    assert (segments[:-1] == 0).all() and segments[-1] == 1
    cut = TrackPredictor(StreamConfig(**CONFIG, gap_floor=None)).process_table(table)
    assert cut.loc[cut["track_id"] == 9, "segment"].max() >= 2   # without the floor: cut at its usual steps
    regular = TrackPredictor(StreamConfig(**CONFIG))
    regular.process_table(_table(_regular))
    assert regular.config.gap_floor is None
    stream = TrackPredictor(StreamConfig(**CONFIG))
    stream.step_row(0, 0.0, [1.0, 2.0])
    assert stream.config.gap_floor is None


def test_the_pilot_takes_date_times_and_repeated_timestamps_and_a_given_unit_as_one_machine_does():
    """From a review: the pilot scored rows skipped for a repeated timestamp by merging date-times with seconds
    (an error on AIS-like BaseDateTime); and the settings a split run fixes in advance (learned_sampling) ran the
    pilot with the learned unit where one was given, so a run split over machines could settle another reach."""
    from kalmix.streaming import learned_sampling

    table = _table(_log_uniform, tracks=4)
    dated = table.assign(time=pd.Timestamp("2024-03-01", tz="UTC") + pd.to_timedelta(table["time"], unit="s"))
    dated = pd.concat([dated, dated.iloc[[10]]]).sort_values("time", kind="stable").reset_index(drop=True)
    predictor = TrackPredictor(StreamConfig(**CONFIG))
    out = predictor.process_table(dated)   # (the repeated timestamp's row skipped)
    assert len(out) == len(dated) - 1 and predictor.config.reach in (None, IRREGULAR_REACH)
    for unit in (None, 2.0, 200.0):
        config = StreamConfig(**CONFIG, time_unit=unit)
        whole = TrackPredictor(config)
        whole.process_table(table)
        assert learned_sampling([table], config, ["x", "y"]) == (whole.config.time_unit, whole.config.reach,
                                                                  whole.config.gap_floor)


def test_text_in_a_position_of_a_first_table_is_named_before_the_units_read_it():
    """From a review: the length unit's estimate read the positions first, and text there failed with a bare
    "could not convert string to float", naming neither column nor row."""
    table = _table(_regular).astype({"x": object})
    table.loc[11, "x"] = "abc"
    with pytest.raises(ValueError, match=r"table: position column 'x' must hold numbers, got 'abc' in row 11"):
        TrackPredictor(StreamConfig(n_experts=4)).process_table(table)
