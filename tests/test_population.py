"""The population prior (kalmix.stream.population) and the young tracks' gap rule (StreamConfig.gap_min_steps):
a new track starts from what the tracks before it learned, the same whether a file comes in one table, in chunks
or row by row, and resumes exactly from a state file."""

import numpy as np
import pandas as pd
import pytest

from kalmix import StreamConfig, TrackPredictor
from kalmix.core.engine import tree_leaves
from kalmix.stream import population


def _short_tracks(tracks=60, rows=12, seed=8):
    """Constant-velocity vessels (5 m/s spread) seen 12 times each, 10-60 min apart, 10 m noise, one track
    after the other (as a file sorted by track lists them)."""
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(tracks):
        t = np.concatenate([[0.0], np.cumsum(rng.uniform(600.0, 3600.0, rows - 1))]) + rng.uniform(0, 100)
        x0, v = rng.normal(0.0, 1000.0, 2), rng.normal(0.0, 5.0, 2)
        z = x0 + t[:, None] * v + rng.normal(0.0, 10.0, (rows, 2))
        frames.append(pd.DataFrame({"track_id": f"t{k:03d}", "time": t, "x": z[:, 0], "y": z[:, 1]}))
    return pd.concat(frames, ignore_index=True)


def _one_step_rms(table, out, skip=2):
    """RMS per coordinate of each row's forecast of its track's next row, from each track's row ``skip`` on."""
    nxt = table.assign(i=table.groupby("track_id").cumcount() - 1)
    scored = out.assign(i=out.groupby("track_id").cumcount()).merge(nxt, on=["track_id", "i"], suffixes=("", "_t"))
    scored = scored[scored.i >= skip]
    return float(np.sqrt(np.mean(np.concatenate([scored.pred_x - scored.x, scored.pred_y - scored.y]) ** 2)))


def _same_states(a, b):
    assert list(a.states) == list(b.states)
    for track in a.states:
        for (name, x), (_, y) in zip(tree_leaves(a.states[track]), tree_leaves(b.states[track])):
            np.testing.assert_array_equal(x, y, err_msg=f"{track} {name}")


def test_snapshot_points_double_then_keep_a_fixed_pace():
    first, every = population.FIRST_SNAPSHOT, population.SNAPSHOT_EVERY
    assert population.snapshot_points(0, first - 1) == []
    assert population.snapshot_points(0, 4 * first) == [first, 2 * first, 4 * first]
    assert population.snapshot_points(first, 4 * first - 1) == [2 * first]
    points = population.snapshot_points(0, 3 * every)
    assert points[-3:] == [every, 2 * every, 3 * every] and points == sorted(set(points))
    assert population.snapshot_points(every, 2 * every) == [2 * every]


def test_summarise_takes_tracks_with_enough_rows_per_row_times_the_pseudo_rows():
    k = 3
    regret = np.array([[1.0, 2.0, 3.0], [10.0, 10.0, 10.0], [5.0, 5.0, 5.0]])
    variance = regret * 2.0
    bound = np.array([[1.0, 1.0, 1.0], [3.0, 3.0, 3.0], [100.0, 100.0, 100.0]])
    rows = np.array([2, 4, population.MIN_ROWS - 1])   # the first and the last have too few rows
    rows[0] = population.MIN_ROWS
    prior = population.summarise([(regret[:2], variance[:2], bound[:2], rows[:2]),
                                  (regret[2:], variance[2:], bound[2:], rows[2:])])
    per_row = (regret[0] / rows[0] + regret[1] / rows[1]) / 2
    np.testing.assert_allclose(prior.regret, per_row * population.POPULATION_ROWS, rtol=1e-15)
    np.testing.assert_allclose(prior.variance, 2 * per_row * population.POPULATION_ROWS, rtol=1e-15)
    np.testing.assert_array_equal(prior.bound, np.full(k, 2.0))   # the median of 1 and 3
    assert prior.tracks == 2 and prior.calibration is None
    assert population.summarise([(regret[2:], variance[2:], bound[2:], rows[2:])]) is None


def test_summarise_keeps_the_mean_calibration_of_the_same_tracks():
    """With the tracks' calibration states, the prior keeps their plain mean over the tracks taken (errors' variances
    and counts are means already, not sums over rows as the rule's regrets)."""
    rng = np.random.default_rng(0)
    n, k, p = 5, 3, 2
    regret, bound = rng.normal(size=(n, k)), np.ones((n, k))
    cal = (rng.uniform(1.0, 9.0, (n, k, p)), rng.uniform(1.0, 50.0, (n, k)), rng.normal(size=n))
    rows = np.array([population.MIN_ROWS, 1, 10, 40, population.MIN_ROWS - 1])
    use = rows >= population.MIN_ROWS
    prior = population.summarise([(regret[:2], regret[:2], bound[:2], rows[:2], tuple(a[:2] for a in cal)),
                                  (regret[2:], regret[2:], bound[2:], rows[2:], tuple(a[2:] for a in cal))])
    assert prior.tracks == 3
    for kept, states in zip(prior.calibration, cal):
        np.testing.assert_allclose(kept, np.atleast_1d(states[use].mean(axis=0)), rtol=1e-15)
    assert [a.shape for a in prior.calibration] == [(k, p), (k,), (1,)]


@pytest.mark.parametrize("calibration_prior", [True, False])
def test_the_prior_starts_a_new_tracks_calibration(calibration_prior):
    """A new track's calibration (the experts' error variances and counts, the intervals' scale) starts as the mean of
    the tracks before it (``calibration_prior``), its count at most ``CALIBRATION_ERRORS`` (tracks started so carry
    their count on: 40-row tracks take the population's mean count to the window); without it, from the length
    unit."""
    table = _short_tracks(tracks=60, rows=40).sort_values("time", kind="stable")
    engine = TrackPredictor(StreamConfig(length_unit=27.0, time_unit=1800.0, calibration_prior=calibration_prior))
    engine.process_table(table)
    assert engine.priors
    fresh, prior = engine._new_states(1).calibration, engine.priors[-1]
    if calibration_prior:
        variance, count, log_scale = prior.calibration
        np.testing.assert_array_equal(fresh.variance[0], variance)
        np.testing.assert_array_equal(fresh.log_scale, log_scale)
        assert count.max() > population.CALIBRATION_ERRORS
        np.testing.assert_array_equal(fresh.count[0], np.minimum(count, population.CALIBRATION_ERRORS))
        assert np.all(fresh.count > 0) and np.any(fresh.variance != 27.0 ** 2)
    else:
        assert prior.calibration is None
        assert np.all(fresh.variance == 27.0 ** 2) and not np.any(fresh.count) and not np.any(fresh.log_scale)


@pytest.mark.parametrize("prior", [True, False])
def test_a_file_in_one_table_in_chunks_and_row_by_row_learn_the_same_bits(prior):
    table = _short_tracks(tracks=40)
    # (the units and reach given: a table learns them from its own steps, a stream from its first step)
    config = StreamConfig(length_unit=27.0, time_unit=1800.0, reach=1.5, population_prior=prior)
    whole = TrackPredictor(config)
    whole.process_table(table, ["x", "y"])
    chunks = TrackPredictor(config)
    for begin in range(0, len(table), 37):
        chunks.process_table(table.iloc[begin:begin + 37], ["x", "y"])
    rows = TrackPredictor(config)
    for begin in range(0, len(table), 5):
        part = table.iloc[begin:begin + 5]
        rows.step_rows(part.track_id.tolist(), part.time.to_numpy(), part[["x", "y"]].to_numpy())
    assert len(whole.priors) == (4 if prior else 0)   # after rows 32, 64, 128 and 256 of 480
    for other in (chunks, rows):
        assert len(other.priors) == len(whole.priors)
        for a, b in zip(whole.priors, other.priors):
            np.testing.assert_array_equal(a.regret, b.regret)
            np.testing.assert_array_equal(a.variance, b.variance)
            np.testing.assert_array_equal(a.bound, b.bound)
        _same_states(whole, other)


def test_new_tracks_start_from_the_population_and_predict_better():
    """On 60 short tracks the prior takes the one-step RMS from 361 m to 18 m per coordinate (measured; BOA alone
    21 m; the noise is 10 m); the rows before the first summary are the same either way."""
    table = _short_tracks()
    with_prior = TrackPredictor(StreamConfig(length_unit=27.0, population_prior=True))
    without = TrackPredictor(StreamConfig(length_unit=27.0, population_prior=False))
    a, b = with_prior.process_table(table, ["x", "y"]), without.process_table(table, ["x", "y"])
    first = table.index[:population.FIRST_SNAPSHOT]   # rows before the first summary: no prior yet
    np.testing.assert_array_equal(a.loc[first, ["pred_x", "pred_y"]], b.loc[first, ["pred_x", "pred_y"]])
    rms_with, rms_without = _one_step_rms(table, a), _one_step_rms(table, b)
    assert rms_with < 0.1 * rms_without, (rms_with, rms_without)


def test_only_boa_has_a_prior():
    table = _short_tracks(tracks=10)
    predictor = TrackPredictor(StreamConfig(length_unit=27.0, rule="mlpoly", population_prior=True))
    predictor.process_table(table, ["x", "y"])
    assert predictor.priors == [] and predictor.prior is None


def test_a_saved_predictor_resumes_its_population_exactly(tmp_path):
    table = _short_tracks(tracks=30)
    config = StreamConfig(length_unit=27.0, time_unit=1800.0, reach=1.5, population_prior=True)   # (a half may differ)
    whole = TrackPredictor(config)
    expected = whole.process_table(table, ["x", "y"])
    half = len(table) // 2 + 7
    first = TrackPredictor(config)
    head = first.process_table(table.iloc[:half], ["x", "y"])
    first.save(tmp_path / "state.kalmix")
    resumed = TrackPredictor.load(tmp_path / "state.kalmix")
    tail = resumed.process_table(table.iloc[half:], ["x", "y"])
    _same_states(whole, resumed)
    assert len(resumed.priors) == len(whole.priors)
    got = pd.concat([head, tail], ignore_index=True)
    inner = np.ones(len(table), dtype=bool)
    inner[half - 1] = False   # the head's last row forecast without the next row's time
    np.testing.assert_array_equal(got.loc[inner, ["pred_x", "pred_y"]], expected.loc[inner, ["pred_x", "pred_y"]])


def test_a_young_track_is_not_cut_by_its_first_steps():
    """Steps of 10 to 60 minutes: with one step of 866 s known, a step of 3,000 s is over 3 times it; it is not
    a gap before the track has ``gap_min_steps`` steps."""
    times = [0.0, 866.0, 3866.0, 5000.0, 8000.0, 9000.0, 200000.0]
    table = pd.DataFrame({"track_id": "a", "time": times, "x": np.arange(7.0), "y": np.zeros(7)})
    segments = TrackPredictor(StreamConfig(length_unit=1.0)).process_table(table, ["x", "y"])["segment"]
    assert segments.tolist() == [0, 0, 0, 0, 0, 0, 1]   # the last step (about 2 days) is a gap
    cut = TrackPredictor(StreamConfig(length_unit=1.0, gap_min_steps=1)).process_table(table, ["x", "y"])["segment"]
    assert cut.tolist() == [0, 0, 1, 1, 1, 1, 2]


@pytest.mark.parametrize("value, error", [(0, ValueError), (17, ValueError), (2.5, ValueError), (True, ValueError)])
def test_gap_min_steps_is_checked(value, error):
    with pytest.raises(error, match="gap_min_steps: expected an integer in"):
        StreamConfig(gap_min_steps=value)


def test_population_prior_is_checked():
    with pytest.raises(TypeError, match="population_prior: expected True or False, got str"):
        StreamConfig(population_prior="no")


def test_the_command_line_has_the_prior_by_default(tmp_path):
    from click.testing import CliRunner

    from kalmix.cli import build

    table = _short_tracks(tracks=40)
    source = tmp_path / "tracks.csv"
    table.to_csv(source, index=False)
    runner = CliRunner()
    outputs = {}
    for name, flags in (("default", []), ("prior", ["--population-prior"]), ("none", ["--no-population-prior"])):
        result = runner.invoke(build(), ["predict", str(source), "-o", str(tmp_path / f"{name}.csv"),
                                         "--length-unit", "27", "--state", str(tmp_path / f"{name}.kalmix"), *flags])
        assert result.exit_code == 0, result.output
        outputs[name] = pd.read_csv(tmp_path / f"{name}.csv")
    pd.testing.assert_frame_equal(outputs["default"], outputs["prior"])
    assert _one_step_rms(table, outputs["prior"]) < 0.5 * _one_step_rms(table, outputs["none"])
    assert TrackPredictor.load(tmp_path / "default.kalmix").config.population_prior is True
    assert TrackPredictor.load(tmp_path / "none.kalmix").priors == []
    # a resumed run goes on as it started, and says so if asked otherwise
    again = runner.invoke(build(), ["predict", str(source), "-o", str(tmp_path / "again.csv"), "--length-unit", "27",
                                    "--state", str(tmp_path / "none.kalmix"), "--population-prior"])
    assert again.exit_code == 1 and "--population-prior: the state file" in again.stderr
    assert "started without the population prior" in again.stderr
    again = runner.invoke(build(), ["predict", str(source), "-o", str(tmp_path / "again.csv"), "--length-unit", "27",
                                    "--state", str(tmp_path / "default.kalmix"), "--no-population-prior"])
    assert again.exit_code == 1 and "started with the population prior" in again.stderr
    archive = tmp_path / "archive"
    archive.mkdir()
    table.to_parquet(archive / "part.parquet")
    dask = runner.invoke(build(), ["predict", str(archive), "--engine", "dask", "-o", str(tmp_path / "d"),
                                   "--population-prior"])
    assert dask.exit_code != 0 and "--population-prior: not with --engine dask" in dask.stderr


def _file_chunks_and_stdin(tmp_path, table):
    """``kalmix predict`` of ``table`` as a CSV file in one chunk ("one"), in chunks of 45 and 100 rows ("chunks",
    "more") and on stdin ("stdin"), each with a lead and a state file: ``(outputs, states)`` by name."""
    from click.testing import CliRunner

    from kalmix.cli import build

    source = tmp_path / "tracks.csv"
    table.to_csv(source, index=False)
    runner = CliRunner()
    fixed = ["--length-unit", "27", "--time-unit", "1800", "--reach", "1.5", "--lead", "1800"]
    outputs = {}
    for name, flags in (("one", []), ("chunks", ["--chunk-rows", "45"]), ("more", ["--chunk-rows", "100"])):
        result = runner.invoke(build(), ["predict", str(source), "-o", str(tmp_path / f"{name}.csv"), *fixed,
                                         "--state", str(tmp_path / f"{name}.kalmix"), *flags])
        assert result.exit_code == 0, result.output
        outputs[name] = pd.read_csv(tmp_path / f"{name}.csv")
    result = runner.invoke(build(), ["predict", "-", "-o", str(tmp_path / "stdin.csv"), *fixed,
                                     "--state", str(tmp_path / "stdin.kalmix")], input=source.read_text())
    assert result.exit_code == 0, result.output
    outputs["stdin"] = pd.read_csv(tmp_path / "stdin.csv")
    return outputs, {name: TrackPredictor.load(tmp_path / f"{name}.kalmix") for name in outputs}


def test_a_file_its_chunks_and_stdin_learn_in_the_order_the_rows_came(tmp_path):
    """Rows of interleaved tracks (a feed sorted by time): the population is summarised after the same rows of
    the file, whatever its chunks (each chunk is stepped track by track), and on stdin; the lead forecasts (made
    alike in files and on stdin) and the learned state are the same bits."""
    outputs, states = _file_chunks_and_stdin(tmp_path, _short_tracks(tracks=40).sort_values("time", kind="stable"))
    whole = states["one"]
    # stdin summarises after rows 64, 128 and 256 of 480 (at row 32 no track has learned 3 rows); every track
    # starts in the first 40 rows, so a file makes only the summary a later row could start from, the last
    assert (len(states["stdin"].priors), len(whole.priors)) == (3, 1)
    for name in ("chunks", "more"):
        pd.testing.assert_frame_equal(outputs[name], outputs["one"])
    lead = ["lead_x", "lead_y", "lead_std_x", "lead_std_y"]
    pd.testing.assert_frame_equal(outputs["stdin"][lead], outputs["one"][lead])
    for name in ("chunks", "more", "stdin"):
        _same_prior(states[name].priors[-1], whole.priors[-1])
        _same_states(whole, states[name])


def _same_prior(x, y):
    """The same bits in two population priors, their calibrations included."""
    for field in ("regret", "variance", "bound"):
        np.testing.assert_array_equal(getattr(x, field), getattr(y, field))
    assert x.tracks == y.tracks and (x.calibration is None) == (y.calibration is None)
    for a, b in zip(x.calibration or (), y.calibration or ()):
        np.testing.assert_array_equal(a, b)


def _same_priors_and_states(a, b):
    assert len(a.priors) == len(b.priors) > 0
    for x, y in zip(a.priors, b.priors):
        _same_prior(x, y)
    assert sorted(a.states) == sorted(b.states)
    for track in a.states:
        for (name, x), (_, y) in zip(tree_leaves(a.states[track]), tree_leaves(b.states[track])):
            np.testing.assert_array_equal(x, y, err_msg=f"{track} {name}")


def test_a_summary_does_not_depend_on_the_order_the_tracks_are_stored_in():
    """A new track cut by a time gap in its first table is stored after the tracks that began with it (``A, C,
    B``), row by row in arrival order (``A, B, C``): the summary adds the tracks up in one order all the same,
    so its bits (and those of a track that starts from it) are the same."""
    rng = np.random.default_rng(5)
    rows = []

    def track(name, times):
        v, x0 = rng.normal(0, 5, 2), rng.normal(0, 1000, 2)
        rows.extend((name, t, *(x0 + v * t + rng.normal(0, 10, 2))) for t in times)

    for k in range(4):
        track(f"p{k}", 1000.0 * np.arange(4))
    track("A", 1000.0 * np.arange(3))
    track("B", np.r_[1000.0 * np.arange(6), 200000.0 + 1000.0 * np.arange(3)])   # a gap: B restarts
    track("C", 1000.0 * np.arange(4))   # its last row is the stream's 32nd: the first summary
    track("D", 1000.0 * np.arange(5))   # starts from it
    table = pd.DataFrame(rows, columns=["track_id", "time", "x", "y"])
    config = StreamConfig(length_unit=27.0, time_unit=1000.0, n_experts=2)
    whole, by_row = TrackPredictor(config), TrackPredictor(config)
    whole.process_table(table, ["x", "y"])
    for r in table.itertuples():
        by_row.step_row(r.track_id, r.time, [r.x, r.y])
    assert list(whole.states) != list(by_row.states)   # stored in another order
    _same_priors_and_states(whole, by_row)


def test_a_parquet_file_sorted_by_id_learns_as_its_rows_came(tmp_path):
    """A Parquet chunk holds its tracks sorted by id, here the reverse of the order they came in: whole, one row
    at a time and as CSV it learns the same bits."""
    from click.testing import CliRunner

    from kalmix.cli import build

    rng = np.random.default_rng(3)
    rows = []
    for k in range(20):   # track k starts at k * 1500 s; the ids sort opposite to arrival
        t = k * 1500.0 + np.r_[0, np.cumsum(rng.uniform(600, 3600, 9))]
        v, x0 = rng.normal(0, 5, 2), rng.normal(0, 1000, 2)
        rows += [(f"z{99 - k}", s, *(x0 + v * s + rng.normal(0, 10, 2))) for s in t]
    table = pd.DataFrame(rows, columns=["track_id", "time", "x", "y"]).sort_values("time", kind="stable")
    table.to_parquet(tmp_path / "feed.parquet", index=False)
    table.to_csv(tmp_path / "feed.csv", index=False)
    runner = CliRunner()
    fixed = ["--experts", "2", "--length-unit", "27", "--time-unit", "1800", "--reach", "1.5"]
    runs = {"whole": ("feed.parquet", []), "rows": ("feed.parquet", ["--chunk-rows", "1"]), "csv": ("feed.csv", [])}
    outputs, states = {}, {}
    for name, (source, flags) in runs.items():
        result = runner.invoke(build(), ["predict", str(tmp_path / source), "-o", str(tmp_path / f"{name}.csv"),
                                         *fixed, "--state", str(tmp_path / f"{name}.kalmix"), *flags])
        assert result.exit_code == 0, result.output
        outputs[name] = pd.read_csv(tmp_path / f"{name}.csv")
        states[name] = TrackPredictor.load(tmp_path / f"{name}.kalmix")
    for name in ("rows", "csv"):
        pd.testing.assert_frame_equal(outputs[name], outputs["whole"])
        _same_priors_and_states(states["whole"], states[name])


def test_summaries_a_later_track_starts_from_are_made_in_a_file_as_on_stdin(tmp_path):
    """Tracks that start one after another through the feed: a file makes (and its new tracks start from) the
    summaries a new track comes after, whatever its chunks; the forecasts and states are a stream's bits."""
    table = _short_tracks(tracks=60)
    table["time"] += 3000.0 * table["track_id"].str[1:].astype(int)   # track k starts k x 50 min in
    outputs, states = _file_chunks_and_stdin(tmp_path, table.sort_values("time", kind="stable"))
    whole = states["one"]
    # after rows 32, 64, ..., 512 of 720: a new track starts after each
    assert len(whole.priors) == len(states["stdin"].priors) == 5
    for name in ("chunks", "more"):
        pd.testing.assert_frame_equal(outputs[name], outputs["one"])
    lead = ["lead_x", "lead_y", "lead_std_x", "lead_std_y"]
    pd.testing.assert_frame_equal(outputs["stdin"][lead], outputs["one"][lead])
    for name in ("chunks", "more", "stdin"):
        for a, b in zip(whole.priors, states[name].priors):
            _same_prior(a, b)
        _same_states(whole, states[name])


def test_with_a_lead_head_the_prior_starts_the_lead_weights_and_their_blend():
    """A new track's lead rule and blend start from the population's (``lead_prior``), not even; without it, only
    its one-step rule does."""
    table = _short_tracks(tracks=30)
    table = table.sort_values("time", kind="stable")
    for lead_prior in (True, False):
        engine = TrackPredictor(StreamConfig(length_unit=27.0, time_unit=1800.0, horizon=3, lead_prior=lead_prior,
                                             rule="boa"))   # (the layout below is BOA's)
        engine.process_table(table)
        assert engine.priors
        fresh = engine._new_states(1)
        prior, k = engine.priors[-1], engine.params.n_experts
        np.testing.assert_array_equal(fresh.rule.regret[0], prior.regret[:k])
        if lead_prior:
            assert prior.regret.shape == (2 * k + 2,)
            np.testing.assert_array_equal(fresh.lead.rule.regret[0], prior.regret[k:2 * k])
            np.testing.assert_array_equal(fresh.lead.blend.regret[0], prior.regret[2 * k:])
            assert np.any(fresh.lead.rule.regret != 0) and np.any(fresh.lead.blend.regret != 0)
        else:
            assert prior.regret.shape == (k,)
            assert not np.any(fresh.lead.rule.regret) and not np.any(fresh.lead.blend.regret)
