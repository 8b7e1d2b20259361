"""Nothing lost, nothing silently wrong: stop signals, concurrent state files, bounded work, clear errors, progress.

Issue 15, classes 1, 2, 3, 6, 7 and 8. Stops are made deterministic with the test hook
``KALMIX_TEST_SIGNAL_AFTER=SIGNAME:N`` (the process sends itself SIGNAME after its N-th unit
of work: a piece of a chunk, or a stdin row), or with a real signal sent once the output
shows the process is waiting for input.
"""

import io
import os
import subprocess
import sys
import time
import zipfile

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from kalmix import MixturePredictor, make_params
from kalmix.archive import write_archive
from kalmix.bank import MAX_HORIZON
from kalmix.cli import build
from kalmix.streaming import GapTracker, StreamConfig, TrackPredictor

FAST = ["--experts", "2", "--seed", "1", "--length-unit", "1", "--no-progress"]
SIGNALS = ["SIGINT", "SIGTERM", "SIGHUP"]


@pytest.fixture(scope="module")
def cli():
    return build()


def _run(cli, args, input=None, env=None):
    return CliRunner().invoke(cli, args, input=input, env=env, catch_exceptions=False)


def _feed(n_tracks=6, n=60, seed=0):
    """Rows of all tracks interleaved in time order (a live feed), with a gap and a missing value."""
    rng = np.random.default_rng(seed)
    t = np.repeat(np.arange(n) * 0.1, n_tracks)
    t[t >= 3.0] += 2.0 * (np.tile(np.arange(n_tracks), n)[t >= 3.0] == 1)  # track 1 has a 2 s hole
    ids = np.tile(np.arange(n_tracks), n)
    xy = np.cumsum(rng.normal(size=(n * n_tracks, 2)), axis=0)
    xy[7] = np.nan
    frame = pd.DataFrame({"id": ids, "t": np.round(t, 6), "x": xy[:, 0], "y": xy[:, 1]})
    return frame.sort_values(["t", "id"], kind="stable").reset_index(drop=True)


@pytest.fixture(scope="module")
def feed_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("feed") / "feed.csv"
    _feed().to_csv(path, index=False, na_rep="")
    return str(path)


@pytest.fixture(scope="module")
def reference(cli, feed_csv, tmp_path_factory):
    """Uninterrupted output of the same command (same --chunk-rows: chunks set the row order), cached."""
    out, cache = tmp_path_factory.mktemp("ref"), {}

    def get(fmt="csv", chunk_rows=None):
        key = (fmt, chunk_rows)
        if key not in cache:
            path = out / f"{fmt}{chunk_rows}.{'jsonl' if fmt == 'jsonl' else 'csv'}"
            source = "-" if fmt == "stdin" else feed_csv
            chunks = [] if chunk_rows is None else ["--chunk-rows", str(chunk_rows)]
            result = _run(cli, ["predict", source, *FAST, "-H", "3", *chunks, "-o", str(path)],
                          input=open(feed_csv).read() if fmt == "stdin" else None)
            assert result.exit_code == 0, result.output
            cache[key] = path.read_bytes()
        return cache[key]

    return get


def _subprocess(args, stdin=None, env=None):
    full_env = {**os.environ, **(env or {})}
    return subprocess.run([sys.executable, "-m", "kalmix.cli", *args], input=stdin, capture_output=True,
                          env=full_env, timeout=120)


def test_state_writes_are_unique_fsynced_and_keep_permissions(tmp_path, monkeypatch):
    path = tmp_path / "s.npz"
    path.write_bytes(b"old")
    os.chmod(path, 0o640)
    (tmp_path / "s.npz.tmp").mkdir()  # the old fixed temporary name, taken
    synced, renamed = [], []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(os.path.isdir(f"/proc/self/fd/{fd}")),
                                                 real_fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (renamed.append(a), real_replace(a, b))[1])
    write_archive(path, {"magic": "m"}, {"a": np.arange(3)})
    write_archive(path, {"magic": "m"}, {"a": np.arange(4)})
    assert synced == [False, True, False, True]  # the file, then its directory, each time
    assert len(set(renamed)) == 2 and all(os.path.dirname(a) == str(tmp_path) for a in renamed)
    assert oct(os.stat(path).st_mode & 0o777) == oct(0o640)
    assert sorted(os.listdir(tmp_path)) == ["s.npz", "s.npz.tmp"]


def test_foreign_and_oversized_state_files_are_refused_without_inflating(tmp_path, monkeypatch):
    np.save(tmp_path / "a.npy", np.zeros(3))
    for loader, what in ((TrackPredictor.load, "state"), (MixturePredictor.load, "predictor")):
        with pytest.raises(ValueError, match=f"not a kalmix {what} file"):
            loader(tmp_path / "a.npy")
        with pytest.raises(ValueError, match="got a directory"):
            loader(tmp_path)
    engine = TrackPredictor(StreamConfig(n_experts=2))
    engine.step_row("a", 0.0, [1.0, 2.0])
    engine.save(tmp_path / "s.npz")
    zeros = np.zeros(4_000_000)  # 32 MB that deflate to ~30 kB
    with zipfile.ZipFile(tmp_path / "s.npz", "a", zipfile.ZIP_DEFLATED) as archive:
        with archive.open("junk.npy", "w", force_zip64=True) as member:
            np.lib.format.write_array(member, zeros)
    opened = []
    real_open = zipfile.ZipFile.open
    monkeypatch.setattr(zipfile.ZipFile, "open", lambda self, name, *a, **k: (
        opened.append(getattr(name, "filename", name)), real_open(self, name, *a, **k))[1])
    loaded = TrackPredictor.load(tmp_path / "s.npz")
    assert "junk.npy" not in opened and loaded.track_ids == ["a"]
    # a member the loader needs, but far larger than its shape: refused before decompressing
    with zipfile.ZipFile(tmp_path / "s.npz") as archive:
        members = {name: archive.read(name) for name in archive.namelist() if name != "junk.npy"}
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, zeros)
    members["state/cov.npy"] = buffer.getvalue()
    with zipfile.ZipFile(tmp_path / "big.npz", "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    opened.clear()
    with pytest.raises(ValueError, match=r"field 'cov' expected \d+ bytes .* the archive declares 32000128"):
        TrackPredictor.load(tmp_path / "big.npz")
    assert "state/cov.npy" not in opened


# -------------------------------------------------------------------------- 6: bounded horizons
def test_horizons_have_a_documented_maximum(cli, feed_csv):
    predictor = MixturePredictor(4, backend="numpy")
    predictor.run(np.cumsum(np.ones((50, 2)), axis=0))
    assert np.isfinite(predictor.predict(MAX_HORIZON)).all()
    for bad in (MAX_HORIZON + 1, 10**6, 0, 2.0, True):
        with pytest.raises(ValueError, match=rf"horizon: expected an integer in \[1, {MAX_HORIZON}\], got"):
            predictor.predict(bad)
    with pytest.raises(ValueError, match="horizon"):
        predictor.run(np.zeros((3, 2)), horizon=MAX_HORIZON + 1)
    with pytest.raises(ValueError, match="horizon"):
        StreamConfig(horizon=10**6)
    for command in ("predict", "evaluate"):
        result = _run(cli, [command, feed_csv, "-H", "1000000"])
        assert result.exit_code == 2 and f"1000000 is not in the range 1<=x<={MAX_HORIZON}" in result.stderr


# ---------------------------------------------------------------------------- 7: clear errors
@pytest.mark.parametrize("options, error, message", [
    ({"seed": 2**64}, ValueError, r"seed: expected an integer in \[0, 2\*\*63 - 1\], got 18446744073709551616"),
    ({"seed": -1}, ValueError, r"seed: expected an integer in \[0, 2\*\*63 - 1\], got -1"),
    ({"process_noise_range": 5}, ValueError, r"process_noise_range: expected a pair \(low, high\) .*, got 5"),
    ({"ridge_levels": 0.1}, ValueError, r"ridge_levels: expected a sequence of numbers > 0, got 0.1"),
    ({"length_unit": 1e300}, ValueError, r"length_unit: expected a number in \[1e-100, 1e\+100\]"),
    ({"length_unit": 1e-300}, ValueError, r"length_unit: expected a number in \[1e-100, 1e\+100\]"),
])
def test_bad_bank_arguments_are_refused_at_construction(options, error, message):
    with pytest.raises(error, match=message):
        make_params(2, 4, **options)
    with pytest.raises(error, match=message):
        MixturePredictor(4, **options)
    direct = set(options) <= {"seed", "length_unit"}
    with pytest.raises(error, match=message):
        StreamConfig(n_experts=4, **(options if direct else {"options": options}))


@pytest.mark.parametrize("unit", [1e-100, 1e100])
def test_the_length_unit_range_is_scale_equivariant_at_both_ends(unit):
    z = np.cumsum(np.cumsum(np.random.default_rng(3).normal(size=(120, 2)), 0), 0) * 0.1
    reference = MixturePredictor(4, seed=1, backend="numpy").run(z).predictions
    scaled = MixturePredictor(4, seed=1, backend="numpy", length_unit=unit).run(z * unit).predictions / unit
    np.testing.assert_allclose(scaled[1:], reference[1:], rtol=1e-9, atol=0)


@pytest.mark.parametrize("content", ["t,x\n0,1\n", "t,x\n0,1\n1,2\n", "t,x\n0,1\n0,2\n0,3\n",
                                     "t,x\n0,1\n1,2\n2,3\n3,5\n4,6\n"])
def test_evaluate_on_too_little_data_says_so(cli, tmp_path, content):
    path = tmp_path / "tiny.csv"
    path.write_text(content)
    result = _run(cli, ["evaluate", str(path), "--experts", "2", "--no-peers"])
    assert result.exit_code == 1 and "All-NaN" not in result.stderr
    assert "too little data to tune the predictors on" in result.stderr.splitlines()[-1]


@settings(max_examples=40, deadline=None)
@given(steps=st.lists(st.floats(0.01, 2.0), min_size=3, max_size=40), where=st.integers(0, 39),
       jump=st.floats(1e3, 1e12))
def test_one_wrong_future_timestamp_loses_no_later_row(steps, where, jump):
    """The row after a jump ahead that comes back in between marks the jump as a wrong timestamp."""
    times = list(np.cumsum(steps))
    where = where % len(times)
    glitched = times[:where] + [times[-1] + jump] + times[where + 1:]
    config = StreamConfig(n_experts=1)
    tracker = GapTracker()
    flags = [tracker.advance(t, config) for t in glitched]
    later = flags[where + 1:]
    assert None not in later and tracker.glitches == (1 if later else 0)
    assert tracker.last_time == glitched[-1]
    clean = GapTracker()
    assert None not in [clean.advance(t, config) for t in times] and clean.glitches == 0


def test_ids_are_text_as_written_in_files_and_on_stdin_and_a_bom_is_ignored(cli, tmp_path):
    text = "id,t,x\n1,0,1\n01,0,5\n1,1,2\n01,1,6\n1,2,3\n01,2,7\n"
    (tmp_path / "ids.csv").write_text(text)
    from_file = _run(cli, ["predict", str(tmp_path / "ids.csv"), *FAST])
    from_stdin = _run(cli, ["predict", "-", *FAST], input=("\ufeff" + text).encode("utf-8"))
    assert from_file.exit_code == from_stdin.exit_code == 0
    assert "skipped" not in from_file.stderr + from_stdin.stderr
    file_rows, stdin_rows = (pd.read_csv(io.StringIO(out), dtype={"id": str}).sort_values(["id", "t"], kind="stable")
                             for out in (from_file.stdout, from_stdin.stdout))
    assert sorted(set(file_rows["id"])) == ["01", "1"]
    pd.testing.assert_frame_equal(file_rows.reset_index(drop=True), stdin_rows.reset_index(drop=True),
                                  check_exact=True)


def test_engine_calls_are_all_or_nothing(monkeypatch):
    """An exception inside a step leaves trackers, counters and states as they were."""
    import kalmix.streaming as streaming

    table = _feed(n_tracks=3, n=30).rename(columns={"id": "track_id", "t": "time"})
    config = StreamConfig(n_experts=2, seed=1, horizon=2)
    real_step, calls = streaming.step, []

    def failing(*args):
        calls.append(1)
        if len(calls) == 7:
            raise KeyboardInterrupt
        return real_step(*args)

    expected = TrackPredictor(config).process_table(table)
    engine = TrackPredictor(config)
    monkeypatch.setattr(streaming, "step", failing)
    with pytest.raises(KeyboardInterrupt):
        engine.process_table(table)
    assert (engine.rows, engine.skipped, engine.gaps, engine.states) == (0, 0, {}, {})
    monkeypatch.setattr(streaming, "step", real_step)
    pd.testing.assert_frame_equal(engine.process_table(table), expected, check_exact=True)

    clean, engine = TrackPredictor(config), TrackPredictor(config)
    rows = list(table.itertuples())
    expected = [clean.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows]
    calls.clear()
    monkeypatch.setattr(streaming, "step", failing)
    got = [engine.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows[:6]]
    before = (engine.rows, {t: g.to_json() for t, g in engine.gaps.items()}, dict(engine.states))
    with pytest.raises(KeyboardInterrupt):
        engine.step_row(rows[6].track_id, rows[6].time, [rows[6].x, rows[6].y])
    assert (engine.rows, {t: g.to_json() for t, g in engine.gaps.items()}, dict(engine.states)) == before
    monkeypatch.setattr(streaming, "step", real_step)
    got += [engine.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows[6:]]
    assert np.array_equal(np.array(got), np.array(expected), equal_nan=True)
