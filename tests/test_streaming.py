"""The per-track engine: row-by-row == batched table, gap rule, state save/resume, length-unit rule."""

import math

import numpy as np
import pandas as pd
import pytest

from kalmix import MixturePredictor
from kalmix.streaming import (STATE_FORMAT_VERSION, GapTracker, SkippedRowWarning, StreamConfig, TrackPredictor,
                              auto_length_unit)


def _table(seed=0, scale=0.01):
    rng = np.random.default_rng(seed)
    rows = []
    for track, n in (("a", 40), ("b", 60), ("c", 12)):
        t = np.arange(n) * 0.1
        if track == "b":
            t[30:] += 5.0  # a 5 s hole: new segment
        xy = np.cumsum(np.cumsum(rng.normal(size=(n, 2)), 0), 0) * scale
        xy[4] = np.nan  # a missing measurement
        rows += [(track, t[i], *xy[i]) for i in range(n)]
    return pd.DataFrame(rows, columns=["track_id", "time", "x", "y"])


def _rows(engine, table):
    out = [engine.step_row(r.track_id, r.time, [r.x, r.y]) for r in table.itertuples()]
    return out


CONFIG = dict(n_experts=6, seed=3, length_unit=0.01, horizon=3)
#: State members that older files lack: the lead's issued intervals (before 6), the warm-up audit's (before 7).
OLDER_MEMBERS = ("state/lead/issued", "state/screen/low", "state/screen/high")
#: BOA's running error scale, which files before version 10 lack (their BOA did not clip).
CLIP_MEMBERS = ("state/rule/error_scale", "state/rule/error_count", "state/lead/rule/error_scale",
                "state/lead/rule/error_count")
#: The lead head's blend and the forecasts it blended, which files before version 14 lack.
BLEND_MEMBERS = ("state/lead/blend/", "state/lead/candidates")


def test_the_front_door_needs_no_arguments():
    """``TrackPredictor()`` runs ``kalmix predict``'s defaults (it asked for a config every field of which has a
    default), and ``dir(kalmix)`` lists the names imported on first use (tab completion)."""
    import kalmix

    engine = TrackPredictor()
    assert engine.config == StreamConfig()
    assert {"TrackPredictor", "StreamConfig", "RowPrediction", "MixturePredictor"} <= set(dir(kalmix))
    with pytest.raises(TypeError, match="config: expected a StreamConfig, got dict"):
        TrackPredictor({"n_experts": 4})


def test_rows_equal_batched_table():
    """stdin (step_row) and a file (process_table) agree wherever their definitions agree: the lead
    (here the horizon of 3 time units) on every row, pred_/std_ where the next row comes one reference
    interval later (a file forecasts the next row's time; a stream, which cannot know it, one interval on)."""
    table = _table()
    batch = TrackPredictor(StreamConfig(**CONFIG)).process_table(table)
    rows = _rows(TrackPredictor(StreamConfig(**CONFIG)), table)
    nxt = np.array([r.next for r in rows])
    nxt_std = np.array([r.next_std for r in rows])
    ahead = np.array([r.ahead for r in rows])
    ahead_std = np.array([r.ahead_std for r in rows])
    np.testing.assert_array_equal(ahead, batch[["pred3_x", "pred3_y"]].to_numpy())
    np.testing.assert_array_equal(ahead_std, batch[["std3_x", "std3_y"]].to_numpy())
    step = table.groupby("track_id")["time"].diff().shift(-1).to_numpy()   # to the track's next row
    regular = np.abs(step - 0.1) < 1e-9
    last = np.isnan(step)
    same = regular | last
    same[0] = False   # the stream's first row: no interval known yet, a stream forecasts one time unit (1) on
    assert regular.sum() > 100 and (~same).sum() == 2   # and the row before b's 5 s hole
    # not bit for bit (1.8e-15 and 1.1e-16 measured): a stream forecasts its last time plus an interval, a file the
    # next row's time
    np.testing.assert_allclose(nxt[same], batch[["pred_x", "pred_y"]].to_numpy()[same], atol=1e-9, rtol=0)
    np.testing.assert_allclose(nxt_std[same], batch[["std_x", "std_y"]].to_numpy()[same], atol=1e-9, rtol=0)
    assert np.all(np.isfinite(batch[["std_x", "std_y"]].to_numpy()[4:]))
    assert list(batch["segment"]) == [r.segment for r in rows]
    assert batch.groupby("track_id")["segment"].max().to_dict() == {"a": 0, "b": 1, "c": 0}


@pytest.mark.parametrize("bank", ["kinematic", "mixed"])
def test_track_equals_the_reference_engine_on_that_track(bank):
    """A track's predictions equal the numpy reference engine run on that track alone: pred_ of a row is the
    engine's forecast of the next row; the last row's is the forecast one reference interval on."""
    from kalmix.bank import DEFAULT_BANK, make_bank
    from kalmix.core import engine

    table = _table()
    batch = TrackPredictor(StreamConfig(**{**CONFIG, "horizon": 1, "bank": bank})).process_table(table)
    rows = table.track_id == "a"
    z, t = table.loc[rows, ["x", "y"]].to_numpy(), table.loc[rows, "time"].to_numpy()
    unit = float(np.diff(t)[0])
    reference = make_bank(2, bank, rule=DEFAULT_BANK["rule"], length_unit=0.01, time_unit=unit, seed=3, n_akf=6)
    result = engine.run(reference, z[:, None], t[:, None])
    mean, cov = engine.forecast(reference, result.state, [t[-1] + float(np.median(np.diff(t)[:16]))])
    expected = np.concatenate([result.forecasts[1:, 0], mean])
    expected_std = np.concatenate([result.std[1:, 0], np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))])
    got = batch.loc[batch.track_id == "a"]
    np.testing.assert_array_equal(got[["pred_x", "pred_y"]].to_numpy(), expected)
    np.testing.assert_array_equal(got[["std_x", "std_y"]].to_numpy(), expected_std)


@pytest.mark.parametrize("time_unit", [None, 0.1])
def test_chunks_equal_one_table_and_interleaved_order(time_unit):
    """Chunks change nothing, with the time unit given or learned (in row order, from the first time step: only
    first rows of tracks come before it, and nothing they leave depends on it). Without the population prior the
    tracks are independent, so neither does the order of the rows; with it, a track starts from the tracks whose
    rows came before (kalmix.stream.population)."""
    table = _table()
    config = {**CONFIG, "time_unit": time_unit}
    interleaved = table.sort_values(["time", "track_id"], kind="stable")
    for prior in (True, False):
        settings = StreamConfig(**config, population_prior=prior)
        whole = TrackPredictor(settings).process_table(table if not prior else interleaved)
        engine = TrackPredictor(settings)
        parts = [engine.process_table(interleaved.iloc[i:i + 23]) for i in range(0, len(interleaved), 23)]
        chunked = pd.concat(parts).sort_values(["track_id", "time"]).reset_index(drop=True)
        pd.testing.assert_frame_equal(chunked, whole.sort_values(["track_id", "time"]).reset_index(drop=True),
                                      check_exact=True)


def test_save_and_resume_is_bit_for_bit(tmp_path):
    table = _table()
    whole = [r.next for r in _rows(TrackPredictor(StreamConfig(**CONFIG)), table)]
    first = TrackPredictor(StreamConfig(**CONFIG))
    part = [r.next for r in _rows(first, table.iloc[:70])]
    first.save(tmp_path / "s.npz")
    second = TrackPredictor.load(tmp_path / "s.npz")
    part += [r.next for r in _rows(second, table.iloc[70:])]
    assert np.array_equal(np.array(part), np.array(whole), equal_nan=True)
    # learned from the first time step, kept; a stream's reach is settled at none
    assert second.config == StreamConfig(**CONFIG, time_unit=0.1, reach=None, gap_floor=None)


def _as_older_file(tmp_path, config, cut, version, members=(), settings=()):
    """Rows of a predictor over the whole table, and of one over its first ``cut`` rows, saved, made into a
    version-``version`` file (without the archive ``members`` and the ``settings``), loaded and run over the
    rest: ``(whole, resumed, loaded predictor, the saved archive)``. Both run as such a file ran: before
    version 9, the lead head learned at the one-step rate (``lead_delay`` 1, a setting those files lack);
    before version 10, BOA did not clip (``clip`` inf, and no error scale in the state); before version 11 there was
    no ``geographic`` setting (positions were flat); before version 12 the gap rule's reference interval was the
    median of a track's first steps (``gap_reference`` "median", a setting those files lack); before version 13
    any step of a track could be a gap (``gap_min_steps`` 1) and no track started from a population prior
    (``population_prior`` False, and no learned rows or priors in the file). Before version 14 there was no blend
    of the lead forecasts: such a file resumes with the blend started again, so ``whole`` is then the run whose
    blend starts again at the save (the same file as version 13, resumed; the uninterrupted run but for the lead
    forecasts after the save: test_version_13_files_resume_with_the_blend_started_again). Before version 15 the
    screen counted a track's learned rows up to 2: the file's counts are capped so. Before version 16 there was no
    ``gap_floor`` setting (none). Before version 17 the population prior started a new track's one-step rule only
    (``lead_prior`` False). Before version 18 the calibration learned every error, a track's first forecast's
    too (``calibration_from_points`` 0), and the prior did not start it (``calibration_prior`` False, and no
    calibration in the file's priors)."""
    import json

    config = {"rule": "boa", **config}   # the default rule when files of these versions were written
    if version < 18:   # every error calibrated; the prior started the rules only
        config = {**config, "calibration_prior": False, "calibration_from_points": 0}
        settings = (*settings, "calibration_prior", "calibration_from_points")
    if version < 17:   # the population prior started the one-step rule only
        config, settings = {**config, "lead_prior": False}, (*settings, "lead_prior")
    if version < 16:   # no gap floor setting (a stream settles it at none)
        settings = (*settings, "gap_floor")
    if version < 9:
        config, settings = {**config, "lead_delay": 1.0}, (*settings, "lead_delay")
    if version < 11:
        settings = (*settings, "geographic")
    if version < 12:
        config, settings = {**config, "gap_reference": "median"}, (*settings, "gap_reference")
    elif version < 15:   # files of versions 12 to 14 hold the rule they ran with, the upper quartile alone
        config = {**config, "gap_reference": "upper quartile"}
    if version < 13:
        config = {**config, "gap_min_steps": 1, "population_prior": False}
        settings = (*settings, "gap_min_steps", "population_prior")
    if version < 10:
        config = {**config, "rule_options": {"clip": float("inf"), **config.get("rule_options", {})}}
        members = (*members, *CLIP_MEMBERS)
    table = _table()
    whole = _rows(TrackPredictor(StreamConfig(**config)), table)
    first = TrackPredictor(StreamConfig(**config))
    part = _rows(first, table.iloc[:cut])
    first.save(tmp_path / "s.npz")
    saved = dict(np.load(tmp_path / "s.npz"))
    meta = json.loads(str(saved["meta"]))
    assert meta["format_version"] == STATE_FORMAT_VERSION == 18
    if version < 14:
        whole = part + _rows(_without_blend(tmp_path, saved, dict(meta, format_version=13)), table.iloc[cut:])
    meta["format_version"] = version
    if version < 13:
        assert meta.pop("priors") == []   # (population_prior False)
        for entry in meta["tracks"]:
            del entry["rows"]
    for name in settings:
        del meta["config"][name]
    if version < 10 and "rule_options" in meta["config"]:
        del meta["config"]["rule_options"]["clip"]
    older = {name: value for name, value in saved.items() if name not in members and name != "meta"
             and not (version < 14 and name.startswith(BLEND_MEMBERS))}
    if version < 15:   # the screen counted learned rows up to 2
        older["state/screen/points"] = np.minimum(older["state/screen/points"], 2.0)
    np.savez(tmp_path / "older.npz", **older, meta=np.array(json.dumps(meta)))
    second = TrackPredictor.load(tmp_path / "older.npz")
    assert second.loaded_version == version
    return whole, part + _rows(second, table.iloc[cut:]), second, saved


def _without_blend(tmp_path, saved, meta):
    """The predictor of the archive ``saved`` without the blend's members, loaded with ``meta``."""
    import json

    kept = {name: value for name, value in saved.items() if not name.startswith(BLEND_MEMBERS) and name != "meta"}
    np.savez(tmp_path / "without_blend.npz", **kept, meta=np.array(json.dumps(meta)))
    return TrackPredictor.load(tmp_path / "without_blend.npz")


def _saved(predictor, path):
    """``predictor``'s state file, as arrays."""
    predictor.save(path)
    return dict(np.load(path))


def _next(rows):
    return np.array([r.next for r in rows])


def test_version_4_files_resume_as_they_ran(tmp_path):
    """Version 4 state files were written when BOA's bound did not forget: resumed with bound_forgetting 1."""
    original = dict(CONFIG, rule_options={"bound_forgetting": 1.0})
    whole, resumed, second, _ = _as_older_file(tmp_path, original, 70, 4, OLDER_MEMBERS,
                                               ("rule_options", "reach"))
    assert second.config.rule_options == {"bound_forgetting": 1.0, "clip": float("inf")}
    assert np.array_equal(_next(resumed), _next(whole), equal_nan=True)
    # the default now forgets the bound, and that changes the forecasts
    default = _rows(TrackPredictor(StreamConfig(**CONFIG, rule="boa")), _table())
    assert not np.array_equal(_next(default), _next(whole), equal_nan=True)


def test_version_5_files_resume_without_issued_intervals(tmp_path):
    """Version 5 state files kept no issued interval with a pending lead forecast: they resume (those
    forecasts are scored against today's interval, as they were then), the one-step forecasts as they ran."""
    whole, part, second, saved = _as_older_file(tmp_path, CONFIG, 70, 5, OLDER_MEMBERS)
    assert np.isfinite(saved["state/lead/issued"]).any()   # forecasts were pending at the save
    for field in ("next", "next_std", "ahead"):   # the lead's weights do not depend on the intervals
        assert np.array_equal(np.array([getattr(r, field) for r in part]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field
    resumed, uninterrupted = (np.array([r.ahead_std for r in rows]) for rows in (part, whole))
    assert np.array_equal(np.isnan(resumed), np.isnan(uninterrupted))
    # each forecast pending at the save moves log s by at most the rate either way
    bound = np.exp(second.params.calibration_params.rate * second.params.lead.capacity)
    ok = np.isfinite(resumed)
    assert np.all(resumed[ok] <= bound * uninterrupted[ok]) and np.all(resumed[ok] >= uninterrupted[ok] / bound)


def test_version_6_files_resume_without_the_warm_up_audit(tmp_path):
    """Version 6 state files had no warm-up audit in the screen: a track past its warm-up resumes as it ran (its
    audit never comes); one still in it (clean, here) is audited over the rest of it only."""
    for cut in (70, 4):
        whole, resumed, _, _ = _as_older_file(tmp_path, CONFIG, cut, 6, OLDER_MEMBERS[1:])
        assert np.array_equal(_next(resumed), _next(whole), equal_nan=True), cut


def test_version_7_files_resume_without_a_reach(tmp_path):
    """Version 7 settings had no reach: such a file resumes without one (as it ran), bit for bit; today's files
    keep the reach they were made with."""
    whole, resumed, second, saved = _as_older_file(tmp_path, CONFIG, 70, 7, settings=("reach",))
    assert second.config.reach is None
    assert np.array_equal(_next(resumed), _next(whole), equal_nan=True)
    reaching = TrackPredictor(StreamConfig(**{**CONFIG, "reach": 8.0}))
    _rows(reaching, _table().iloc[:10])
    reaching.save(tmp_path / "r.npz")
    assert TrackPredictor.load(tmp_path / "r.npz").config.reach == 8.0


def test_version_8_files_resume_with_the_lead_learning_at_the_one_step_rate(tmp_path):
    """Version 8 settings had no lead delay: such a file resumes with the lead head's rule at the one-step rate
    (lead_delay 1, as it ran), bit for bit, lead forecasts included; today's default (the lead's rows) differs."""
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 8)
    assert second.config.lead_delay == 1.0 and second.params.lead_rule_params.delay == 1.0
    for field in ("next", "ahead"):
        assert np.array_equal(np.array([getattr(r, field) for r in resumed]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field
    today = TrackPredictor(StreamConfig(**CONFIG, rule="boa", rule_options={"clip": float("inf")}, gap_min_steps=1,
                                        population_prior=False))   # as version 9 ran
    rows = _rows(today, _table())
    assert today.params.lead.frames == 3 and today.params.lead_rule_params.delay == 3.0
    assert np.array_equal(_next(rows), _next(whole), equal_nan=True)   # the one-step rule did not change
    ahead = np.array([r.ahead for r in rows])
    assert not np.array_equal(ahead, np.array([r.ahead for r in whole]), equal_nan=True)
    today.save(tmp_path / "today.npz")
    assert TrackPredictor.load(tmp_path / "today.npz").config.lead_delay is None


def test_version_9_files_resume_without_the_clip(tmp_path):
    """Version 9 files were written when BOA did not clip its errors: such a file resumes with ``clip`` off and no
    error scale (as it ran), bit for bit, lead forecasts included; today's default clips and its files keep the
    scale (resumed bit for bit by test_save_and_resume_is_bit_for_bit). (On this short table no error reaches
    3 RMS after a warm-up, so today's rows are the same: the settings carry the difference.)"""
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 9)
    assert second.config.rule_options == {"clip": float("inf")}
    assert second.params.rule_params.clip == second.params.lead_rule_params.clip == float("inf")
    for field in ("next", "ahead"):
        assert np.array_equal(np.array([getattr(r, field) for r in resumed]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field
    today = TrackPredictor(StreamConfig(**CONFIG, rule="boa"))
    _rows(today, _table())
    today.save(tmp_path / "today.npz")
    saved = np.load(tmp_path / "today.npz")
    assert (saved["state/rule/error_count"] > 0).all()
    assert (saved["state/lead/rule/error_count"] == 0).all()   # the lead head learns its errors whole
    assert TrackPredictor.load(tmp_path / "today.npz").params.rule_params.clip == 3.0


def test_version_13_files_resume_with_the_blend_started_again(tmp_path):
    """Version 13 files had no blend of the lead forecasts (nor the two forecasts kept with a pending one): such a
    file resumes with the blend at its start (even weights; the forecasts pending at the save teach it nothing).
    The one-step forecasts and the lead weights go on as uninterrupted, bit for bit; the lead forecasts after the
    save differ (they blend the same two forecasts with other weights) but stay finite where those were."""
    import json

    table, cut = _table(), 70
    whole = TrackPredictor(StreamConfig(**CONFIG))
    uninterrupted = _rows(whole, table)
    first = TrackPredictor(StreamConfig(**CONFIG))
    part = _rows(first, table.iloc[:cut])
    saved = _saved(first, tmp_path / "s.npz")
    assert np.isfinite(saved["state/lead/candidates"]).any()   # forecasts were pending at the save
    assert (saved["state/lead/blend/variance"] > 0).any()      # and the blend had learned
    meta = json.loads(str(saved["meta"]))
    second = _without_blend(tmp_path, saved, dict(meta, format_version=13))
    assert second.loaded_version == 13
    resumed = part + _rows(second, table.iloc[cut:])
    assert np.array_equal(_next(resumed), _next(uninterrupted), equal_nan=True)
    ends = _saved(second, tmp_path / "resumed.npz"), _saved(whole, tmp_path / "whole.npz")
    for name in [name for name in ends[1] if name.startswith("state/lead/rule/")]:
        assert np.array_equal(ends[0][name], ends[1][name], equal_nan=True), name
    assert not np.array_equal(ends[0]["state/lead/blend/regret"], ends[1]["state/lead/blend/regret"])
    ahead, expected = (np.array([r.ahead for r in rows]) for rows in (resumed, uninterrupted))
    assert np.array_equal(ahead[:cut], expected[:cut], equal_nan=True)
    assert np.array_equal(np.isnan(ahead), np.isnan(expected)) and not np.array_equal(ahead, expected, equal_nan=True)


def test_load_rejects_other_files(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a kalmix state file"):
        TrackPredictor.load(bad)
    MixturePredictor(2).run(np.zeros((3, 2)))
    other = MixturePredictor(2)
    other.step([0.0, 0.0])
    other.save(tmp_path / "p.npz")
    with pytest.raises(ValueError, match="magic"):
        TrackPredictor.load(tmp_path / "p.npz")


def test_out_of_order_rows_are_skipped():
    engine = TrackPredictor(StreamConfig(n_experts=2))
    assert engine.step_row(1, 0.0, [0.0]) is not None
    assert engine.step_row(1, 1.0, [1.0]) is not None
    with pytest.warns(SkippedRowWarning, match="time 1.0 is not after the track's last time 1.0"):
        assert engine.step_row(1, 1.0, [1.0]) is None  # repeated timestamp
    assert engine.step_row(1, 0.5, [1.0]) is None  # back in time (not said again)
    assert engine.skipped == 2


def test_gap_rule():
    config = StreamConfig()
    gaps = GapTracker()
    flags = [gaps.advance(t, config) for t in (0.0, 1.0, 2.0, 3.0, 3.5, 20.0, 21.0)]
    # the first row starts segment 0; 3.5 is a short step (kept); 20 is > 3 x median(1, 1, 1, 0.5)
    assert flags == [True, False, False, False, False, True, False]
    assert gaps.segment == 1
    absolute = StreamConfig(max_gap=0.75)
    gaps = GapTracker()
    assert [gaps.advance(t, absolute) for t in (0.0, 0.5, 1.5)] == [True, False, True]
    never = StreamConfig(max_gap_factor=math.inf)
    gaps = GapTracker()
    assert not any([gaps.advance(t, never) for t in (0.0, 1.0, 1000.0)][1:])


def _irregular_times(rng, n=300):
    """Steps uniform in 5-60 s (a vessel's AIS reports) whose first 16 have a median of 17.5 s, then a 3-day silence
    and more such steps."""
    first = np.array([6.0, 7, 9, 11, 12, 14, 15, 17, 18, 20, 22, 25, 55, 58, 59, 60])
    steps = np.concatenate([first, rng.uniform(5.0, 60.0, n), [3 * 86400.0], rng.uniform(5.0, 60.0, n)])
    return np.cumsum(np.concatenate([[0.0], steps]))


def test_irregular_sampling_stays_one_segment_and_an_outage_splits():
    """The reference interval is the upper quartile of a track's first 16 steps: a track sampled every 5 to 60 s
    whose first steps happen to be short (median 17.5 s) is not cut at every long report; a 3-day silence is a gap.
    The median's threshold (52.5 s, a state file before version 12) cut it at every step over 52.5 s."""
    times = _irregular_times(np.random.default_rng(0))
    silence = int(np.argmax(np.diff(times))) + 1
    for reference, splits in (("upper quartile", [0, silence]), ("median", None)):
        gaps = GapTracker()
        config = StreamConfig(gap_reference=reference)
        new = np.flatnonzero([gaps.advance(float(t), config) for t in times])
        if splits is not None:
            assert new.tolist() == splits and gaps.threshold(config) == 3 * 55.0
        else:
            assert len(new) > 20 and silence in new and gaps.threshold(config) == 3 * 17.5
    with pytest.raises(ValueError, match="gap_reference"):
        StreamConfig(gap_reference="mean")


def test_the_length_unit_reads_the_noise_of_irregular_sampling():
    """Uniform motion at 5 m/s sampled every 5 to 60 s with 10 m noise: with the times the rule reads the noise; on
    the sample index alone it reads the speed times the steps' differences. On regular steps the times change
    nothing, bit for bit."""
    from kalmix.streaming import auto_length_unit

    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(5.0, 60.0, 2000))
    values = (5.0 * times[:, None] * np.array([0.6, 0.8]) + rng.normal(0.0, 10.0, (2000, 2)))
    assert auto_length_unit(values, times=times) == pytest.approx(10.0, rel=0.05)
    assert auto_length_unit(values) > 3 * 10.0
    regular = 0.1 * np.arange(2000)
    assert auto_length_unit(values, times=regular) == auto_length_unit(values)


def test_version_11_files_resume_with_the_median_gap_rule(tmp_path):
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 11)
    assert second.config.gap_reference == "median"
    assert np.array_equal(_next(resumed), _next(whole), equal_nan=True)


def test_version_12_files_resume_without_the_population_prior(tmp_path):
    """Version 12 files: any step could be a gap, and new tracks started empty; they resume so."""
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 12)
    assert second.config.gap_min_steps == 1 and second.config.population_prior is False
    assert second.priors == [] and second.track_rows == {}
    assert np.array_equal(_next(resumed), _next(whole), equal_nan=True)


def test_version_16_files_resume_with_the_prior_starting_the_one_step_rule_only(tmp_path):
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 16)
    assert second.config.lead_prior is False and second.priors
    for field in ("next", "ahead"):
        assert np.array_equal(np.array([getattr(r, field) for r in resumed]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field


def test_version_17_files_resume_with_every_error_calibrating_and_the_prior_starting_the_rules_only(tmp_path):
    whole, resumed, second, _ = _as_older_file(tmp_path, CONFIG, 70, 17)
    assert second.config.calibration_prior is False and second.config.calibration_from_points == 0
    assert second.priors and all(prior.calibration is None for prior in second.priors)
    for field in ("next", "next_std", "ahead"):
        assert np.array_equal(np.array([getattr(r, field) for r in resumed]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field


def test_version_14_files_resume_with_their_tracks_warmed_up(tmp_path):
    """Version 14 files counted a track's learned rows up to 2: a track at 2 resumes as one with the 3 rows of the
    experts' longest warm-up (every track here has more than 2 at the save), bit for bit."""
    whole, resumed, second, saved = _as_older_file(tmp_path, CONFIG, 70, 14)
    assert (saved["state/screen/points"] == 3.0).all() and (np.load(tmp_path / "older.npz")["state/screen/points"]
                                                            == 2.0).all()
    assert (_saved(TrackPredictor.load(tmp_path / "older.npz"), tmp_path / "again.npz")["state/screen/points"]
            == 3.0).all()
    for field in ("next", "ahead"):
        assert np.array_equal(np.array([getattr(r, field) for r in resumed]),
                              np.array([getattr(r, field) for r in whole]), equal_nan=True), field


def _adversarial_times(rng, n):
    """Regular steps with jitter, long gaps, repeats, steps back (glitches), wrong jumps ahead, NaN."""
    t = np.cumsum(rng.choice([1.0, 1.0, 1.0, 0.5, 2.0], size=n))
    kinds = rng.random(n)
    t[kinds < 0.05] += rng.choice([50.0, 500.0])           # a gap (the rest of the track moves on)
    t = np.cumsum(np.diff(t, prepend=0.0) * (kinds > 0.02))  # repeats
    wrong = kinds > 0.97
    t[wrong] = t[wrong] + rng.choice([-3.0, 40.0, 1e6], size=wrong.sum())   # single rows back or far ahead
    t[rng.random(n) < 0.01] = np.nan
    return t


@pytest.mark.parametrize("config", [StreamConfig(), StreamConfig(max_gap=1.5), StreamConfig(max_gap_factor=math.inf),
                                    StreamConfig(max_gap_factor=1.2)])
def test_gap_rule_in_bulk_equals_row_by_row(config):
    """advance_many (stretches of regular rows at once) gives the answers and the state of advance row by
    row, on steps that are regular, repeated, back in time, far ahead, or NaN, from any state."""
    rng = np.random.default_rng(0)
    for _ in range(40):
        times = _adversarial_times(rng, int(rng.integers(1, 300)))
        split = int(rng.integers(0, len(times) + 1))
        one, bulk = GapTracker(), GapTracker()
        for part in (times[:split], times[split:]):
            expected = [one.advance(float(t), config) for t in part]
            codes, segments = bulk.advance_many(part, config)
            assert [None if c < 0 else bool(c) for c in codes] == expected
            assert bulk.to_json() == one.to_json()
        check = GapTracker()
        for t, c, s in zip(times, *GapTracker().advance_many(times, config)):
            check.advance(float(t), config)
            assert s == check.segment


def test_table_gap_rule_equals_rows():
    """A table's gap rule (track by track once the time unit is known) keeps the rows, segments, restarts,
    runs and trackers of the rule applied row by row in table order, the time unit learned at the same row."""
    rng = np.random.default_rng(5)
    ids, times = [], []
    for track in range(7):
        t = _adversarial_times(rng, int(rng.integers(1, 120)))
        ids += [f"t{track}"] * len(t)
        times += list(t)
    ids, times = np.array(ids, dtype=object), np.array(times)
    order = np.argsort(np.nan_to_num(times, nan=0.0), kind="stable")   # interleave the tracks
    ids, times = ids[order], times[order]
    for time_unit in (None, 1.0):
        engine = TrackPredictor(StreamConfig(time_unit=time_unit))
        engine.states["t3"] = None   # a track seen in an earlier table
        tracks, runs, segments, gap_rows, keep = engine._gap_rule(ids, times)
        reference = TrackPredictor(StreamConfig(time_unit=time_unit))
        expected_runs: dict = {}
        skipped = 0
        for i in range(len(ids)):
            gaps, new = reference._advance(ids[i], float(times[i]))
            skipped += new is None
            assert keep[i] == (new is not None)
            if new is not None:
                assert segments[i] == gaps.segment
                assert gap_rows[i] == (bool(new) and (ids[i] in expected_runs or ids[i] == "t3"))
                expected_runs.setdefault(ids[i], []).append(i)
        assert tracks == list(expected_runs)
        assert [list(run) for run in runs] == list(expected_runs.values())
        assert engine.skipped == skipped == int((~keep).sum()) > 0
        assert engine.config.time_unit == reference.config.time_unit
        assert {k: g.to_json() for k, g in engine.gaps.items()} == {k: g.to_json() for k, g in reference.gaps.items()}
        assert list(engine.gaps) == list(reference.gaps)


@pytest.mark.parametrize("missing", [None, np.nan, pd.NA])
def test_a_row_without_a_track_id_is_refused_and_changes_nothing(missing):
    table = pd.DataFrame({"track_id": ["a", "a", missing, "a"], "time": [0.0, 1.0, 2.0, 3.0],
                          "x": [0.0, 1.0, 2.0, 3.0]})
    engine = TrackPredictor(StreamConfig(n_experts=2, bank="kinematic"))
    engine.process_table(table.iloc[:2])
    before = {k: g.to_json() for k, g in engine.gaps.items()}, engine.rows, engine.config.time_unit
    with pytest.raises(ValueError, match=r"expected a track id in every row, got a missing value .* in row 0"):
        engine.process_table(table.iloc[2:].reset_index(drop=True))
    assert ({k: g.to_json() for k, g in engine.gaps.items()}, engine.rows, engine.config.time_unit) == before


def test_config_validation():
    with pytest.raises(ValueError, match="horizon"):
        StreamConfig(horizon=0)
    with pytest.raises(ValueError, match="max_gap"):
        StreamConfig(max_gap=-1.0)
    with pytest.raises(ValueError, match="length_unit"):
        StreamConfig(length_unit=0.0)


def test_auto_length_unit_recovers_white_noise():
    rng = np.random.default_rng(1)
    t = np.arange(5000)
    path = np.stack([0.3 * t, 0.001 * t**2], axis=1)
    assert auto_length_unit(path + rng.normal(0, 0.5, path.shape)) == pytest.approx(0.5, rel=0.08)
    assert auto_length_unit(np.zeros((2, 2))) == 1.0          # too short
    steps = np.repeat(np.arange(100.0), 3)[:, None]            # quantised: most second differences are 0
    assert auto_length_unit(steps) > 0


def _step_row_by_definition(engine, track, time, z):
    """A stream row by its definition: learn the row (one run of the core), then forecast a missing row one
    reference interval on from the state after it (a second run). What :meth:`step_row` computed before it
    took both from one run; (segment, next, next_std, time glitch, lead forecast, its std), or None for a
    skipped row."""
    z = np.asarray(z, dtype=np.float64)
    engine._ensure_params(len(z))
    gaps = engine.gaps[track].copy() if track in engine.gaps else GapTracker()
    glitches = gaps.glitches
    new = gaps.advance(float(time), engine.config)
    engine.rows += 1
    if new is None:
        engine.skipped += 1
        return None
    if engine.config.time_unit is None and gaps.intervals:
        engine._learn_time_unit(gaps.intervals[0])
    state = engine.states.get(track)
    fresh = state is None
    state = engine._fresh() if fresh else state
    result = engine._run(z[None, None], np.array([[float(time)]]), None, state, np.array([[bool(new) and not fresh]]))
    nxt, nxt_std = engine._forecast_next(result.state, [float(time) + engine._interval(gaps)])
    ahead = ahead_std = None
    if result.lead is not None:   # none from a track's first row
        ahead, ahead_std = (np.full(len(z), np.nan),) * 2 if fresh else (result.lead[0, 0], result.lead_std[0, 0])
    engine.gaps[track], engine.states[track] = gaps, result.state
    engine.outliers += int(result.state.screen.outliers.sum() - state.screen.outliers.sum())
    return gaps.segment, nxt[0], nxt_std[0], gaps.glitches > glitches, ahead, ahead_std


def _interleaved_feed(seed, n_tracks=5):
    """Tracks of random walks with missing rows, a 1e8 jump and a 1e12 glitch, adversarial times, interleaved."""
    rng = np.random.default_rng(seed)
    ids, times, values, keys = [], [], [], []
    for track in range(n_tracks):
        t = _adversarial_times(rng, int(rng.integers(1, 90)))
        keys += list(np.arange(len(t)) + rng.random())   # interleaved, each track's rows in its own order
        z = np.cumsum(np.cumsum(rng.normal(size=(len(t), 2)), 0), 0) * 0.01
        z[rng.random(len(t)) < 0.1] = np.nan
        if len(t) > 40:
            z[30:] += 1e8
            z[35] = 1e12
        ids += [f"t{track}" if track % 2 else track] * len(t)
        times += list(t)
        values += list(z)
    order = np.argsort(keys, kind="stable")
    return [ids[i] for i in order], np.array(times)[order], np.array(values)[order]


@pytest.mark.filterwarnings("ignore:the time unit:RuntimeWarning")   # its adversarial times include that case
@pytest.mark.filterwarnings("ignore::kalmix.streaming.SkippedRowWarning")   # and rows out of order
@pytest.mark.parametrize("time_unit, lead", [(None, {}), (1.0, {}), (None, {"lead": 2.5}), (1.0, {"horizon": 3})])
def test_step_rows_equal_stream_rows_by_definition(time_unit, lead):
    """Rows stepped in batches of any size (one run of the core each, two with a lead) give every row's
    prediction, std, lead forecast, segment and glitch flag, and the final trackers, states and counters, of
    the rows stepped one at a time by definition (two runs a row): bit for bit, on adversarial times and
    values, every family in the bank, with and without a lead head."""
    config = dict(n_experts=6, seed=3, length_unit=0.01, time_unit=time_unit, **lead)
    for seed in range(3):
        ids, times, values = _interleaved_feed(seed)
        reference = TrackPredictor(StreamConfig(**config))
        expected = [_step_row_by_definition(reference, *row) for row in zip(ids, times, values)]
        engine = TrackPredictor(StreamConfig(**config))
        rng = np.random.default_rng(seed)
        got, begin = [], 0
        while begin < len(ids):
            end = begin + int(rng.integers(1, 60))
            got += engine.step_rows(ids[begin:end], times[begin:end], values[begin:end])
            begin = end
        assert len(got) == len(expected) and sum(g is None for g in got) > 0
        for g, e in zip(got, expected):
            assert (g is None) == (e is None)
            if g is not None:
                assert (g.segment, g.time_glitch) == (e[0], e[3])
                assert np.array_equal(g.next, e[1], equal_nan=True) and np.array_equal(g.next_std, e[2], equal_nan=True)
                if lead:
                    assert np.array_equal(g.ahead, e[4], equal_nan=True)
                    assert np.array_equal(g.ahead_std, e[5], equal_nan=True)
                else:
                    assert g.ahead is None and e[4] is None
        assert sum(g is not None and g.time_glitch for g in got) > 0
        if lead:
            assert sum(g is not None and np.isfinite(g.ahead).all() for g in got) > 100
        assert (engine.rows, engine.skipped, engine.outliers) == (reference.rows, reference.skipped, reference.outliers)
        assert engine.outliers > 0 and engine.config.time_unit == reference.config.time_unit
        assert {k: g.to_json() for k, g in engine.gaps.items()} == {k: g.to_json() for k, g in reference.gaps.items()}
        assert set(engine.states) == set(reference.states)
        for track in engine.states:
            for a, b in zip(_leaves_of(engine.states[track]), _leaves_of(reference.states[track])):
                assert np.array_equal(a, b, equal_nan=True)
        # and one row at a time through step_row (which takes the same path)
        single = TrackPredictor(StreamConfig(**config))
        rows = [single.step_row(*row) for row in zip(ids, times, values)]
        assert all((r is None and g is None) or np.array_equal(r.next, g.next, equal_nan=True)
                   for r, g in zip(rows, got))


def _leaves_of(state):
    from kalmix.core.engine import tree_leaves

    return [array for _, array in tree_leaves(state)]


def test_step_rows_is_all_or_nothing():
    engine = TrackPredictor(StreamConfig(n_experts=2, bank="kinematic", time_unit=1.0))
    engine.step_rows(["a", "b"], [0.0, 0.0], [[0.0, 0.0], [1.0, 1.0]])
    refs = lambda: {t: engine.states.ref(t) for t in engine.states}  # noqa: E731
    before = {k: g.to_json() for k, g in engine.gaps.items()}, engine.rows, refs()
    with pytest.raises(ValueError, match="expected 2 coordinates per row"):
        engine.step_rows(["a", "c"], [1.0, 1.0], [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    with pytest.raises(ValueError, match=r"expected 2 times and a \(2, p\) array"):
        engine.step_rows(["a", "c"], [1.0], [[0.0, 0.0], [1.0, 1.0]])
    with pytest.raises(TypeError, match=r"track_ids\[1\]: expected a track id \(text, a number, or a date\)"):
        engine.step_rows(["a", ["c"]], [1.0, 1.0], [[0.0, 0.0], [1.0, 1.0]])
    assert ({k: g.to_json() for k, g in engine.gaps.items()}, engine.rows, refs()) == before
    assert engine.step_rows([], [], np.empty((0, 2))) == []


def test_python_api_review_fixes():
    """From a hostile review of the Python API: each of these went wrong silently."""
    import warnings

    # the predictor learns its time unit into its own copy of the settings, not into the caller's
    config = StreamConfig(length_unit=0.05)
    first, second = TrackPredictor(config), TrackPredictor(config)
    for i in range(5):
        first.step_row("a", i * 0.1, [i, 0.0])
    assert config.time_unit is None and second.config.time_unit is None and first.config.time_unit == 0.1
    # numpy ids are keys as process_table and the state file hold them; what cannot be an id is refused
    engine = TrackPredictor(StreamConfig(length_unit=0.05, bank="kinematic"))
    engine.step_rows(np.array([1, 2]), [0.0, 0.0], np.ones((2, 2)))
    assert sorted(engine.states) == [1, 2] and all(type(k) is int for k in engine.states)
    for bad, kind in ((None, ValueError), (float("nan"), ValueError), (("t", 1), TypeError)):
        with pytest.raises(kind, match="track_id: expected a track id"):
            engine.step_row(bad, 1.0, [1.0, 2.0])
    # a NaN or infinite time is skipped, and never becomes the clock (every later row was skipped)
    assert engine.step_row("b", float("nan"), [1.0, 2.0]) is None
    assert engine.step_row("b", float("inf"), [1.0, 2.0]) is None
    assert all(engine.step_row("b", float(t), [t, 2.0]) is not None for t in range(1, 4))
    # a lead is checked against the time unit once it is learned: a clear error, nothing changed
    lead = TrackPredictor(StreamConfig(length_unit=0.05, lead=20.0))
    lead.step_row("a", 0.0, [1.0, 2.0])
    with pytest.raises(ValueError, match="the time unit learned from the data's first step, 0.001"):
        lead.step_row("a", 0.001, [1.0, 2.0])
    assert lead.config.time_unit is None and lead.gaps["a"].last_time == 0.0
    assert StreamConfig(length_unit=0.05, lead=1e9).lead == 1e9   # nanosecond clocks: judged once the unit is known
    # a unit learned from a first step that a later row shows to be a wrong timestamp: said
    glitch = TrackPredictor(StreamConfig(length_unit=0.05))
    glitch.step_row("a", 0.0, [0.0, 0.0])
    glitch.step_row("a", 1e9, [0.0, 0.0])
    with pytest.warns(RuntimeWarning, match="learned from the first step of track 'a', which a later row"):
        glitch.step_row("a", 1.0, [1.0, 0.5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # once
        glitch.step_row("a", 2.0, [2.0, 1.0])


def test_process_table_takes_positions_by_name_and_dates_as_seconds():
    """Columns in another order are taken by name (they were taken by place: x learned as y); other names are
    refused; a datetime time column is seconds since 1970 UTC, as files are read (it crashed, or was taken as
    the column's integer microseconds)."""
    import pandas as pd

    rng = np.random.default_rng(0)
    n = 60
    seconds = np.arange(n) * 0.1
    table = pd.DataFrame({"track_id": "a", "time": seconds, "x": np.cumsum(rng.normal(size=n)),
                          "y": 100 + np.cumsum(rng.normal(size=n))})
    plain = TrackPredictor(StreamConfig(length_unit=0.05))
    expected = pd.concat([plain.process_table(table.iloc[:30]), plain.process_table(table.iloc[30:])])
    swapped = TrackPredictor(StreamConfig(length_unit=0.05))
    got = pd.concat([swapped.process_table(table.iloc[:30]),
                     swapped.process_table(table.iloc[30:][["track_id", "time", "y", "x"]])])
    pd.testing.assert_frame_equal(got.reset_index(drop=True), expected.reset_index(drop=True))
    with pytest.raises(ValueError, match=r"expected the position columns \['x', 'y'\] \(as before\), got \['u', 'y'\]"):
        swapped.process_table(table.rename(columns={"x": "u"}))
    dated = TrackPredictor(StreamConfig(length_unit=0.05))
    stamps = pd.Timestamp(0, tz="UTC") + pd.to_timedelta(seconds, unit="s")
    out = dated.process_table(table.assign(time=stamps))
    numeric = TrackPredictor(StreamConfig(length_unit=0.05)).process_table(
        table.assign(time=(stamps - pd.Timestamp(0, tz="UTC")) / pd.Timedelta(seconds=1)))
    pd.testing.assert_frame_equal(out, numeric)


def test_settings_and_rows_that_were_taken_silently_or_failed_late(tmp_path):
    """numpy numbers in the settings are saved as the numbers they stand for (the save failed: 'not JSON
    serializable'); settings of the wrong type or an unknown bank are named; an infinite measurement is refused
    (NaN is missing data), and so is a z of several rows (it was flattened into more coordinates)."""
    from kalmix import MixturePredictor

    config = StreamConfig(n_experts=np.int64(4), length_unit=np.float32(0.5), lead=np.int64(1),
                          options={"forgetting_levels": np.array([0.9, 0.99])})
    engine = TrackPredictor(config)
    for t in range(3):
        engine.step_row("a", float(t), [t, 0.0])
    engine.save(tmp_path / "s.npz")
    loaded = TrackPredictor.load(tmp_path / "s.npz")
    assert loaded.config.n_experts == 4 and loaded.config.options == {"forgetting_levels": [0.9, 0.99]}
    np.testing.assert_array_equal(loaded.step_row("a", 3.0, [3.0, 0.0]).next,
                                  engine.step_row("a", 3.0, [3.0, 0.0]).next)
    mixture = MixturePredictor(4, seed=np.int64(1))
    mixture.step(np.array([1.0, 2.0, 3.0]))
    mixture.save(tmp_path / "m.npz")
    assert MixturePredictor.load(tmp_path / "m.npz").get_config()["seed"] == 1
    for kwargs, kind, message in (({"bank": "x"}, ValueError, "bank: expected one of mixed"),
                                  ({"time_unit": "x"}, TypeError, "time_unit: expected a number, got str"),
                                  ({"max_gap": "x"}, TypeError, "max_gap: expected a number, got str")):
        with pytest.raises(kind, match=message):
            StreamConfig(**kwargs)
    with pytest.raises(ValueError, match="z: expected finite numbers"):
        engine.step_row("a", 4.0, [np.inf, 0.0])
    with pytest.raises(ValueError, match=r"values\[1\]: expected finite numbers"):
        engine.step_rows(["a", "b"], [4.0, 4.0], [[0.0, 0.0], [1.0, -np.inf]])
    with pytest.raises(ValueError, match=r"z: expected one row of coordinates, shape \(p,\), got shape \(2, 2\)"):
        engine.step_row("a", 4.0, np.ones((2, 2)))
    assert engine.step_row("a", 4.0, np.ones((1, 2))) is not None
    with pytest.raises(ValueError, match="table: position column 'name' must hold numbers, got"):
        TrackPredictor(StreamConfig(length_unit=0.5)).process_table(
            pd.DataFrame({"track_id": ["a"], "time": [0.0], "x": [1.0], "name": ["car"]}), ["x", "name"])


def test_ids_that_are_missing_values_and_datetime_helpers():
    """NaT, pd.NA and complex ids were taken (or failed raw, or failed at save); learned_time_unit and
    next_row_times read datetime times as seconds, as process_table does."""
    import pandas as pd

    from kalmix.streaming import learned_time_unit, next_row_times

    engine = TrackPredictor(StreamConfig(length_unit=0.5))
    for bad, kind in ((pd.NaT, ValueError), (np.datetime64("NaT"), ValueError), (pd.NA, ValueError),
                      (1 + 2j, TypeError)):
        with pytest.raises(kind, match="track_id: expected a track id"):
            engine.step_row(bad, 0.0, [1.0, 2.0])
    table = pd.DataFrame({"track_id": ["a"] * 4, "x": range(4),
                          "time": pd.Timestamp(0, tz="UTC") + pd.to_timedelta(np.arange(4) * 1.25, unit="s")})
    assert learned_time_unit([table], StreamConfig(length_unit=0.5)) == 1.25
    assert next_row_times([table.iloc[:2], table.iloc[2:]]) == [{"a": 2.5}, {}]


def _arrival_tables():
    """Tables in arrival order: interleaved tracks of different steps, with a lead, a horizon, an absolute
    max_gap (a restart before the unit is known), and a time glitch before the first step (a review's)."""
    out = []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        rows = []
        for track in range(4):
            n = int(rng.integers(2, 30))
            t = np.round(np.cumsum(rng.uniform(0.05, 3.0, size=n)) + rng.uniform(0, 4), 3)
            xy = np.cumsum(rng.normal(size=(n, 2)), 0) * rng.uniform(0.01, 10)
            rows += [(track, t[i], *xy[i]) for i in range(n)]
        table = pd.DataFrame(rows, columns=["track_id", "time", "x", "y"]).sort_values("time", kind="stable")
        settings = ({"lead": 0.7}, {"horizon": 2}, {"lead": 0.7, "max_gap": 0.5}, {"horizon": 3, "max_gap": 1.0})
        out.append((table.reset_index(drop=True), settings[seed]))
    glitch = pd.DataFrame({"track_id": list("aabbabab"), "time": [10.0, 5.0, 0.0, 2.0, 5.5, 4.0, 6.0, 6.0],
                           "x": [0.0, 1.0, 2.0, 3.0, 1.5, 2.5, 1.0, 3.0],
                           "y": [0.0, 0.5, 1.0, 0.0, 1.0, 2.0, 0.3, 1.0]})
    out.append((glitch, {"horizon": 2}))
    one = pd.DataFrame({"track_id": [0] * 4, "time": [0.0, 10.0, 10.3, 10.6], "x": [-0.96, -0.07, -1.26, -1.0],
                        "y": [6.43, 3.43, 0.95, 0.5]})
    out.append((one, {"lead": 0.5, "max_gap": 3.0, "bank": "akf"}))
    return out


@pytest.mark.parametrize("case", range(6))
def test_a_tables_time_unit_is_its_median_step_and_its_rows_give_the_stream_numbers_in_any_track_order(case,
                                                                                                       tmp_path):
    """A table fixes the time unit before any of its rows is stepped: the median step between consecutive rows of
    its tracks (``learn_time_unit``), and settles an automatic reach from the same steps. ``kalmix predict``
    steps a file's rows track by track; every output and state leaf has the bits of stepping them in arrival
    order, and of a stream of them given that unit and reach (a
    restart by an absolute max_gap, a horizon after a time glitch included). And ``in_file_order`` gives back a
    read file's order."""
    import warnings

    from kalmix.io import in_file_order, read_tracks

    table, settings = _arrival_tables()[case]
    # (without the population prior, whose summaries cut a file's rows in arrival order too: test_population.py)
    config = dict(n_experts=6, seed=3, length_unit=0.05, population_prior=False, **settings)
    steps = np.concatenate([np.diff(g.to_numpy()) for _, g in table.groupby("track_id", sort=False)["time"]])
    median = float(np.median(steps[steps > 0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # the glitch case's time glitch
        learned = TrackPredictor(StreamConfig(**config))
        expected = learned.process_table(table)
        assert learned.config.time_unit == pytest.approx(median, rel=1e-12)
        stepped = TrackPredictor(StreamConfig(**config))
        assert stepped.learn_time_unit(table) == learned.config.time_unit
        parts = [stepped.process_table(table.sort_values("track_id", kind="stable"))]
        assert learned.config.reach in (None, 1.5)   # (settled from the same steps)
        stream = TrackPredictor(StreamConfig(**{**config, "time_unit": learned.config.time_unit,
                                                "reach": learned.config.reach}))
        rows = stream.step_rows(table["track_id"].tolist(), table["time"].to_numpy(), table[["x", "y"]].to_numpy())
    assert sum(r is not None for r in rows) == len(expected)   # the same rows stepped (none skipped but glitches)
    for track in learned.states:
        for a, b in zip(_leaves_of(stream.states[track]), _leaves_of(learned.states[track])):
            assert np.array_equal(a, b, equal_nan=True)
    got = pd.concat(parts, ignore_index=True)
    order = np.lexsort((got["time"], got["track_id"]))
    want = expected.iloc[np.lexsort((expected["time"], expected["track_id"]))]
    pd.testing.assert_frame_equal(got.iloc[order].reset_index(drop=True), want.reset_index(drop=True),
                                  check_exact=True)
    for track in learned.states:
        for a, b in zip(_leaves_of(stepped.states[track]), _leaves_of(learned.states[track])):
            assert np.array_equal(a, b, equal_nan=True)
    if case == 0:
        table.to_csv(tmp_path / "t.csv", index=False)
        read = read_tracks(tmp_path / "t.csv")
        assert not read["time"].is_monotonic_increasing   # sorted by track
        pd.testing.assert_frame_equal(in_file_order(read).reset_index(drop=True), table, check_dtype=False)
        assert in_file_order(read.sort_values("time")).equals(read.sort_values("time"))   # not the table it was
        assert stepped.learn_time_unit(table.iloc[::-1]) == learned.config.time_unit    # once known, it stays


def test_warm_up_loads_every_kernel_a_run_uses_and_changes_nothing(tmp_path, monkeypatch):
    """warm_up runs a throwaway copy: the predictor steps to the same numbers and saves the same file as a twin
    that never warmed up, and its first table needs no kernel it has not loaded (no numba dispatch to compile
    or load; run alone, this is the process's first table). It says what is missing when the number of
    coordinates is unknown."""
    from numba.core import dispatcher

    table = _table()
    warmed, plain = TrackPredictor(StreamConfig(**CONFIG)), TrackPredictor(StreamConfig(**CONFIG))
    with pytest.raises(ValueError, match="measurement_dim"):
        warmed.warm_up()
    warmed.warm_up(2)
    assert warmed.params is None and warmed.rows == 0 and not warmed.states and warmed.config == plain.config
    loads = []
    original = dispatcher._DispatcherBase._compile_for_args
    with monkeypatch.context() as patch:
        patch.setattr(dispatcher._DispatcherBase, "_compile_for_args",
                      lambda self, *args, **kw: loads.append(self.py_func.__qualname__) or original(self, *args, **kw))
        first = warmed.process_table(table.iloc[:50], ["x", "y"])
    assert loads == []
    pd.testing.assert_frame_equal(first, plain.process_table(table.iloc[:50], ["x", "y"]))
    warmed.warm_up()
    pd.testing.assert_frame_equal(warmed.process_table(table.iloc[50:], ["x", "y"]),
                                  plain.process_table(table.iloc[50:], ["x", "y"]))
    warmed.save(tmp_path / "warmed.npz")
    plain.save(tmp_path / "plain.npz")
    a, b = np.load(tmp_path / "warmed.npz"), np.load(tmp_path / "plain.npz")
    assert sorted(a.files) == sorted(b.files)
    assert all(a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes() for k in a.files)   # the same bits


def test_new_tracks_fresh_states_made_at_once_are_the_fresh_state():
    """process_table makes the new tracks' fresh states in one batch: each is the bits of one made alone, and
    known tracks keep theirs (in the order asked)."""
    from kalmix.core.engine import tree_map
    from kalmix.stream.table_steps import _stack

    engine = TrackPredictor(StreamConfig(**CONFIG))
    engine.process_table(_table().iloc[:30], ["x", "y"])   # track "a" is known
    engine.states["a"] = tree_map(lambda x: x + 1.0, engine.states["a"])   # unlike a fresh one
    tracks = ["n1", "a", "n2", "n3"]
    got = engine._states_or_fresh(tracks)
    want = _stack([engine.states["a"] if t == "a" else engine._fresh() for t in tracks])
    leaves = []
    tree_map(lambda x, y: leaves.append(x.dtype == y.dtype and x.tobytes() == y.tobytes()), got, want)
    assert leaves and all(leaves)


def test_idle_tracks_keep_no_per_track_copy_of_leaves_alike_in_every_track(tmp_path):
    """Many short tracks: the states are kept in shared blocks (TrackStates), a leaf alike in every track of a
    block (as new, such as the AKF family's regression statistics before it learns) once per block, not once
    per track; every track's state reads back as the stacked run would give it, and save / load round-trips."""
    import pandas as pd

    from kalmix.core.engine import tree_leaves
    from kalmix.streaming import TRACK_BATCH

    n = TRACK_BATCH + 300   # two batches of tracks
    rng = np.random.default_rng(3)
    table = pd.DataFrame({"track_id": np.repeat([f"t{i}" for i in range(n)], 2), "time": np.tile([0.0, 1.0], n),
                          "x": rng.normal(size=2 * n), "y": rng.normal(size=2 * n)})
    # (without the population prior: after each of its summaries new tracks start from another state, a block each)
    engine = TrackPredictor(StreamConfig(length_unit=1.0, population_prior=False))
    engine.process_table(table, ["x", "y"])
    blocks = {id(engine.states.ref(t)[0]): engine.states.ref(t)[0] for t in engine.states}
    assert len(blocks) == 2
    held = {id(a): a.nbytes for block in blocks.values() for a in block.leaves}
    dense = sum(a.nbytes for _, a in tree_leaves(engine._fresh())) * n
    assert sum(held.values()) < dense / 3
    fresh = dict(tree_leaves(engine._fresh()))
    gram = [name for name in fresh if name.endswith("/gram")]
    assert gram   # the default bank has an AKF family
    for block in blocks.values():   # its statistics as new: one array shared by every block
        names = [name for name, _ in tree_leaves(engine._fresh())]
        assert block.leaves[names.index(gram[0])] is engine.states._template[1][names.index(gram[0])]
    engine.save(tmp_path / "s.npz")
    loaded = TrackPredictor.load(tmp_path / "s.npz")
    for track in ("t0", f"t{n - 1}"):
        for a, b in zip(_leaves_of(engine.states[track]), _leaves_of(loaded.states[track])):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_the_store_keeps_a_part_alike_along_an_axis_once_and_gives_back_the_same_bits():
    """A leaf whose every track holds one value along an axis (bit for bit: a -0.0 among 0.0s, or another NaN
    payload, is not alike) is kept at length 1 on that axis; a block of many tracks is kept read only, apart
    from the engine's arrays; every track's state reads back with the bits it was stored with."""
    from kalmix.core.engine import tree_leaves, tree_map
    from kalmix.stream.store import OWN_MEMORY_BYTES, TrackStates

    engine = TrackPredictor(StreamConfig(length_unit=1.0, time_unit=1.0))
    engine._ensure_params(2)
    n = 400
    rng = np.random.default_rng(5)
    other_nan = np.array([0x7FF8000000000001], dtype=np.int64).view(np.float64)[0]

    count = iter(range(10**6))

    def fill(array):   # every other leaf alike along its axes after the first, the others all different
        if array.dtype.kind != "f" or array.ndim < 2:
            return array
        if next(count) % 2:
            return rng.normal(size=array.shape)
        return np.broadcast_to(rng.normal(size=(n,) + (1,) * (array.ndim - 1)), array.shape).copy()

    state = tree_map(fill, engine._new_states(n))
    leaves = dict(tree_leaves(state))
    alike = [name for name, a in leaves.items() if a.ndim >= 2 and a.shape[1] > 1 and a.dtype.kind == "f"
             and a.size and (a == a[:, :1]).all()]   # (an empty leaf, a 2-D track's third coordinate: 0 bytes)
    signed, payload = alike[0], alike[1]
    leaves[signed][:, 0] = 0.0
    leaves[signed][3, 1] = -0.0   # not alike to 0.0 bit for bit
    leaves[payload][:, 0] = np.nan
    leaves[payload][7, -1] = other_nan
    store = TrackStates()
    tracks = [f"t{i}" for i in range(n)]
    store.put(tracks, state)
    block = store.ref("t0")[0]
    kept = dict(zip(leaves, block.leaves))
    assert sum(a.nbytes for a in block.leaves if len(a) > 1) >= OWN_MEMORY_BYTES   # (a block of its own memory)
    assert all(not a.flags.writeable for a in block.leaves if len(a) > 1)
    cut = [name for name in alike if name not in (signed, payload)]
    assert cut and all(kept[name].shape[1] == 1 for name in cut)
    assert kept[signed].shape[1] == leaves[signed].shape[1] and kept[payload].shape[1] == leaves[payload].shape[1]
    back = dict(tree_leaves(store.gather(tracks, engine._new_states)))
    for name, array in leaves.items():
        assert back[name].dtype == array.dtype and back[name].tobytes() == array.tobytes(), name
    one = dict(tree_leaves(store["t3"]))
    assert np.signbit(one[signed][0, 1]).all() and not np.signbit(one[signed][0, 0]).any()
    assert one[signed].tobytes() == leaves[signed][3:4].tobytes()
    assert dict(tree_leaves(store["t7"]))[payload].tobytes() == leaves[payload][7:8].tobytes()


def test_a_store_that_compacts_keeps_every_tracks_bits_a_batch_at_a_time():
    """Blocks whose tracks moved on hold dead rows; past twice the tracks' rows (plus the slack) the store copies
    the live rows into new blocks, COMPACT_BATCH tracks at a time: every track reads back its own bits."""
    from kalmix.core.engine import tree_leaves, tree_map
    from kalmix.stream.store import TrackStates

    engine = TrackPredictor(StreamConfig(length_unit=1.0, time_unit=1.0))
    engine._ensure_params(2)
    store = TrackStates()
    store.COMPACT_SLACK, store.COMPACT_BATCH = 8, 16
    compactions = []
    compact = store._compact
    store._compact = lambda: (compactions.append(store._rows), compact())
    rng = np.random.default_rng(9)
    want = {}
    for step in range(12):
        tracks = [f"t{i}" for i in rng.choice(100, size=30, replace=False)]
        state = tree_map(lambda a: rng.normal(size=a.shape) if a.dtype.kind == "f" else a, engine._new_states(30))
        store.put(tracks, state)
        for c, track in enumerate(tracks):
            want[track] = [a[c:c + 1].copy() for _, a in tree_leaves(state)]
        assert store._rows <= 2 * len(store) + store.COMPACT_SLACK
    assert compactions and len(store) == len(want)
    assert all(entry[0].rows <= 30 for entry in store._live.values())   # (compacted blocks of at most 16 rows)
    for track, leaves in want.items():
        got = [a for _, a in tree_leaves(store[track])]
        assert all(a.dtype == b.dtype and a.tobytes() == b.tobytes() for a, b in zip(got, leaves)), track


def test_the_gap_threshold_is_the_step_on_regular_sampling_and_beyond_the_spread_of_irregular_sampling():
    """The default reference: the upper quartile of a track's first 16 steps times their spread (upper over lower
    quartile) to the power 1.5. Regular steps: 3 steps; steps spread over a factor of 60 (log-uniform 10 s - 10 min):
    beyond the longest step; "upper quartile" (files of versions 12 to 14): the upper quartile alone."""
    def threshold(steps, **config):
        tracker = GapTracker()
        for t in np.concatenate([[0.0], np.cumsum(steps)]):
            tracker.advance(float(t), StreamConfig(**config))
        return tracker.threshold(StreamConfig(**config))

    assert threshold(np.full(16, 0.125)) == threshold(np.full(16, 0.125), gap_reference="upper quartile") == 0.375
    # steps read back from times carry rounding: a spread of 1 + 1e-15, a threshold the same to 1e-14
    assert threshold(np.full(16, 0.04)) == pytest.approx(threshold(np.full(16, 0.04), gap_reference="upper quartile"),
                                                         rel=1e-14, abs=0)
    steps = np.exp(np.random.default_rng(11).uniform(np.log(10.0), np.log(600.0), 16))
    ordered = np.sort(np.diff(np.concatenate([[0.0], np.cumsum(steps)])))   # (the steps as the times give them)
    assert threshold(steps, gap_reference="upper quartile") == 3 * ordered[12]
    assert threshold(steps) == 3 * ordered[12] * (ordered[12] / ordered[4]) ** 1.5 > 600.0
