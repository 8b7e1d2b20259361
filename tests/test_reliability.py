"""Nothing lost, nothing silently wrong: stop signals, concurrent state files, bounded work, clear errors, progress.

Issue 15, classes 1, 2, 3, 6, 7 and 8. Stops are made deterministic with the test hook
``KALMIX_TEST_SIGNAL_AFTER=SIGNAME:N`` (the process sends itself SIGNAME after its N-th unit
of work: a piece of a chunk, or a stdin batch), or with a real signal sent once the output
shows the process is waiting for input.
"""

import dataclasses
import io
import json
import os
import re
import signal
import stat
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
from kalmix.bank import LENGTH_UNIT_RANGE, MAX_HORIZON
from kalmix.commands import _predict_file
from kalmix.commands._durable import TEST_HOOK
from kalmix.commands._predict_file import count_rows
from kalmix.streaming import GapTracker, StreamConfig, TrackPredictor

FAST = ["--experts", "2", "--seed", "1", "--length-unit", "1", "--no-progress"]
SIGNALS = ["SIGINT", "SIGTERM", "SIGHUP"]


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


# ---------------------------------------------------------------------- 1 + 2: stop and resume
@pytest.mark.parametrize("sig", SIGNALS)
def test_a_stopped_file_run_resumes_to_exactly_the_uninterrupted_output(sig, feed_csv, reference, tmp_path):
    """A real process, stopped by SIGINT / SIGTERM / SIGHUP in the middle of its third chunk."""
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    args = ["predict", feed_csv, *FAST, "-H", "3", "--chunk-rows", "50", "--state", state, "-o", out]
    first = _subprocess(args, env={TEST_HOOK: f"{sig}:3"})
    assert first.returncode == 128 + signal.Signals[sig].value, first.stderr
    message = first.stderr.decode().strip().splitlines()[-1]
    assert message.startswith(f"kalmix: stopped by {sig} after 100 input row(s)") and "state saved" in message
    assert open(out, "rb").read().count(b"\n") == 1 + 100  # two chunks written, the third rolled back
    second = _subprocess(args)
    assert second.returncode == 0, second.stderr
    assert "skipped 100 row(s)" in second.stderr.decode()  # the rows already written, not those rolled back
    assert open(out, "rb").read() == reference("csv", 50)


@settings(max_examples=10, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(chunk_rows=st.integers(7, 200), piece_rows=st.integers(3, 120), stop_after=st.integers(1, 12),
       sig=st.sampled_from(SIGNALS), fmt=st.sampled_from(["csv", "jsonl"]), save_every=st.integers(1, 400))
def test_any_stop_point_resumes_bit_for_bit(cli, feed_csv, reference, tmp_path_factory, monkeypatch, chunk_rows,
                                            piece_rows, stop_after, sig, fmt, save_every):
    """Stopped after any piece of any chunk, then resumed (maybe stopped again): the same bytes as one run."""
    monkeypatch.setattr(_predict_file, "PIECE_ROWS", piece_rows)
    folder = tmp_path_factory.mktemp("any")
    state, out = str(folder / "s.npz"), str(folder / f"out.{fmt}")
    args = ["predict", feed_csv, *FAST, "-H", "3", "--chunk-rows", str(chunk_rows), "--save-every",
            str(save_every), "--state", state, "-o", out]
    codes = []
    for hook in (f"{sig}:{stop_after}", f"SIGINT:{stop_after + 5}", None):
        result = _run(cli, args, env={TEST_HOOK: hook})
        codes.append(result.exit_code)
        if result.exit_code == 0:
            break
    assert codes[-1] == 0 and set(codes[:-1]) <= {130, 143, 129}
    assert open(out, "rb").read() == reference(fmt, chunk_rows)


def test_rows_written_after_the_last_save_are_cut_and_computed_again(feed_csv, reference, tmp_path):
    """SIGKILL (no chance to save) after chunk 3 was written but only chunks 1-2 were saved."""
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    args = ["predict", feed_csv, *FAST, "-H", "3", "--chunk-rows", "50", "--save-every", "100", "--state", state,
            "-o", out]
    killed = _subprocess(args, env={TEST_HOOK: "SIGKILL:4"})
    assert killed.returncode == -signal.SIGKILL
    assert open(out, "rb").read().count(b"\n") == 1 + 150
    resumed = _subprocess(args)
    assert resumed.returncode == 0, resumed.stderr
    assert "dropped the last 50 line(s)" in resumed.stderr.decode()
    assert open(out, "rb").read() == reference("csv", 50)


def test_a_stopped_stdin_pipeline_loses_no_row(feed_csv, reference, tmp_path):
    """A real SIGTERM while the pipeline waits for input; the replayed feed resumes it exactly."""
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    lines = open(feed_csv).read().splitlines(keepends=True)
    args = [sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST, "-H", "3", "--state", state, "-o", out]
    process = subprocess.Popen(args, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdin.write("".join(lines[:41]).encode())
    process.stdin.flush()
    deadline = time.monotonic() + 60  # wait for the 40 predictions: then it blocks reading stdin
    while not (os.path.exists(out) and open(out, "rb").read().count(b"\n") == 41):
        assert process.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    assert process.wait(60) == 128 + signal.SIGTERM
    assert "stopped by SIGTERM after 40 input row(s)" in process.stderr.read().decode()
    resumed = _subprocess(args[3:], stdin="".join(lines).encode())  # the whole feed again
    assert resumed.returncode == 0, resumed.stderr
    assert open(out, "rb").read() == reference("stdin")


@pytest.mark.parametrize("sig, after", [("SIGINT", 1), ("SIGHUP", 57), ("SIGTERM", 200)])
def test_a_signal_during_a_stdin_row_finishes_that_row(cli, feed_csv, reference, tmp_path, sig, after):
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    args = ["predict", "-", *FAST, "-H", "3", "--save-every", "7", "--state", state, "-o", out]
    feed = open(feed_csv).read()
    first = _run(cli, args, input=feed, env={TEST_HOOK: f"{sig}:{after}"})
    assert first.exit_code == 128 + signal.Signals[sig].value
    assert f"after {after} input row(s) in this run (the rows already read were finished)" in first.stderr
    assert open(out, "rb").read().count(b"\n") == 1 + after
    assert _run(cli, args, input=feed).exit_code == 0
    assert open(out, "rb").read() == reference("stdin")


def test_a_signal_while_stdin_rows_are_stepped_waits_for_their_output_and_warnings(cli, monkeypatch, tmp_path):
    """SIGTERM arriving inside the core's call for a skipped row: the row's warning is still printed (the
    lines read are finished, warnings included), then the run stops with 143 and the state matches."""
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    real, calls = TrackPredictor.step_rows, []

    def step_rows(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:   # the third line: a repeated time, skipped
            os.kill(os.getpid(), signal.SIGTERM)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(TrackPredictor, "step_rows", step_rows)
    result = _run(cli, ["predict", "-", *FAST, "--state", state, "-o", out], input="t,x\n0,0\n1,1\n1,1\n2,2\n")
    assert result.exit_code == 128 + signal.SIGTERM
    assert "line 4: time '1' is not after the previous time of track 0; row skipped" in result.stderr   # as written
    assert "stopped by SIGTERM after 3 input row(s)" in result.stderr
    assert open(out, "rb").read().endswith(b"\n1,,,\n")   # the skipped row's line, with empty predictions
    assert open(out, "rb").read().count(b"\n") == 1 + 3
    assert TrackPredictor.load(state).rows == 3


def test_engine_calls_are_all_or_nothing(monkeypatch):
    """An exception inside an engine call leaves trackers, counters and states as they were."""
    table = _feed(n_tracks=3, n=30).rename(columns={"id": "track_id", "t": "time"})
    config = lambda: StreamConfig(n_experts=2, seed=1, horizon=2)  # noqa: E731  (each learns its time unit)
    real_run, calls, fail_at = TrackPredictor._run, [], [2]

    def failing(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == fail_at[0]:
            raise KeyboardInterrupt
        return real_run(self, *args, **kwargs)

    expected = TrackPredictor(config()).process_table(table)
    engine = TrackPredictor(config())
    # the second call, after the first succeeded (rows before the time unit is learned run first)
    monkeypatch.setattr(TrackPredictor, "_run", failing)
    with pytest.raises(KeyboardInterrupt):
        engine.process_table(table)
    assert (engine.rows, engine.skipped, engine.gaps, engine.states) == (0, 0, {}, {})
    monkeypatch.setattr(TrackPredictor, "_run", real_run)
    pd.testing.assert_frame_equal(engine.process_table(table), expected, check_exact=True)

    clean, engine = TrackPredictor(config()), TrackPredictor(config())
    rows = list(table.itertuples())
    expected = [clean.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows]
    calls.clear()
    fail_at[0] = 14   # two calls a row (the row and its lead; the bank without its lead for the next row): the
    # seventh row's second
    monkeypatch.setattr(TrackPredictor, "_run", failing)
    got = [engine.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows[:6]]
    def snapshot():
        return (engine.rows, {t: g.to_json() for t, g in engine.gaps.items()},
                {t: engine.states.ref(t) for t in engine.states})

    before = snapshot()
    with pytest.raises(KeyboardInterrupt):
        engine.step_row(rows[6].track_id, rows[6].time, [rows[6].x, rows[6].y])
    assert snapshot() == before
    monkeypatch.setattr(TrackPredictor, "_run", real_run)
    got += [engine.step_row(r.track_id, r.time, [r.x, r.y]).next for r in rows[6:]]
    assert np.array_equal(np.array(got), np.array(expected), equal_nan=True)


# ------------------------------------------------------------------------ 1: the -o file on resume
@pytest.mark.parametrize("damage, message", [
    ("truncate", "was truncated or replaced"),
    ("edit", "the file was modified"),
    ("foreign", "is not the output recorded in the state file"),
])
def test_an_output_that_does_not_match_the_state_is_refused(cli, feed_csv, tmp_path, damage, message):
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.csv")
    args = ["predict", feed_csv, *FAST, "--chunk-rows", "50", "--state", state]
    assert _run(cli, [*args, "-o", out], env={TEST_HOOK: "SIGTERM:3"}).exit_code == 143
    text = open(out).read()
    if damage == "truncate":
        open(out, "w").write(text[:-30])
    elif damage == "edit":
        open(out, "w").write(text.replace("\n", "\r\n", 1)[:len(text)] + text[len(text):])
    else:
        out = str(tmp_path / "other.csv")
        open(out, "w").write("unrelated,file\n1,2\n")
    result = _run(cli, [*args, "-o", out])
    assert result.exit_code == 1 and message in result.stderr and len(result.stderr.splitlines()) == 1


def test_a_parquet_output_is_not_continued(cli, feed_csv, tmp_path):
    state, out = str(tmp_path / "s.npz"), str(tmp_path / "out.parquet")
    args = ["predict", feed_csv, *FAST, "--chunk-rows", "50", "--state", state, "-o", out]
    stopped = _run(cli, args, env={TEST_HOOK: "SIGINT:2"})
    assert stopped.exit_code == 130
    assert len(pd.read_parquet(out)) == 50  # a valid file of the committed chunk
    # the stop said "the same command resumes", which then failed as below; it says what does
    assert "the same command with a new -o name resumes (a Parquet file cannot be continued" in stopped.stderr
    result = _run(cli, args)
    assert result.exit_code == 1 and "a Parquet file cannot be continued" in result.stderr
    rest = str(tmp_path / "rest.parquet")
    assert _run(cli, [*args[:-1], rest]).exit_code == 0
    whole = _run(cli, ["predict", feed_csv, *FAST, "--chunk-rows", "50", "-o", str(tmp_path / "whole.parquet")])
    assert whole.exit_code == 0
    both = pd.concat([pd.read_parquet(out), pd.read_parquet(rest)], ignore_index=True)
    pd.testing.assert_frame_equal(both, pd.read_parquet(tmp_path / "whole.parquet"))


def test_temporaries_of_a_killed_save_are_removed_by_the_next_holder_of_the_lock(cli, feed_csv, tmp_path):
    """A SIGKILL in the middle of a save leaves its temporary file, and nothing removed them."""
    state = str(tmp_path / "s.npz")
    stale = [tmp_path / ".s.npz.ab12cd_9.tmp", tmp_path / ".s.npz.zzzzzzzz.tmp"]
    kept = [tmp_path / ".s.npz.notes.tmp", tmp_path / ".other.npz.ab12cd_9.tmp", tmp_path / "s.npz.ab12cd_9.tmp"]
    for path in stale + kept:
        path.write_bytes(b"x" * 100)
    result = _run(cli, ["predict", feed_csv, *FAST, "--state", state, "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 0
    assert not any(path.exists() for path in stale) and all(path.exists() for path in kept)


# ------------------------------------------------------------------- 3: one writer per state file
def test_a_state_file_and_a_link_to_it_share_one_lock(tmp_path):
    """The lock was taken on the path as given, the save on the file it points to, so a run through a link
    and one through the target held different locks (and one's clean-up could remove the other's save)."""
    from kalmix.commands._durable import StateLock

    target = tmp_path / "real" / "s.npz"
    target.parent.mkdir()
    target.write_bytes(b"")
    link = tmp_path / "link.npz"
    link.symlink_to(target)
    with StateLock(str(target)):
        with pytest.raises(ValueError, match="is in use by another kalmix process"):
            with StateLock(str(link)):
                pass
    assert (tmp_path / "real" / "s.npz.lock").exists() and not (tmp_path / "link.npz.lock").exists()
    dangling = tmp_path / "new.npz"   # a link to a state file not made yet: the first save makes it
    dangling.symlink_to(tmp_path / "real" / "later.npz")
    with StateLock(str(dangling)):
        pass


def test_a_second_writer_on_a_state_file_gets_a_clear_error(cli, tmp_path):
    state = str(tmp_path / "s.npz")
    first = subprocess.Popen([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST, "--state", state],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        first.stdin.write(b"t,x\n0,1\n")
        first.stdin.flush()
        assert first.stdout.readline().startswith(b"t,segment")  # it runs, and holds the lock
        second = _run(cli, ["predict", "-", *FAST, "--state", state], input="t,x\n0,1\n")
        assert second.exit_code == 1
        assert "is in use by another kalmix process" in second.stderr and second.stdout == ""
    finally:
        first.stdin.close()
        assert first.wait(60) == 0
    assert _run(cli, ["predict", "-", *FAST, "--state", state], input="t,x\n1,2\n").exit_code == 0


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


def test_a_state_saved_through_a_link_replaces_the_target_and_other_files_are_refused(tmp_path):
    """save() replaced whatever was at the path (run as root, /dev/full became a plain file; a link
    became a file, its target unchanged), and an error named the hidden temporary file."""
    target, link = tmp_path / "target.npz", tmp_path / "link.npz"
    os.symlink(target, link)
    write_archive(link, {"magic": "m"}, {"a": np.arange(3)})
    assert os.path.islink(link) and np.load(target)["a"].tolist() == [0, 1, 2]
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "not a regular file"), (tmp_path, "a directory")):
        with pytest.raises(ValueError, match=f"expected a state file path, and it is {kind}"):
            write_archive(path, {"magic": "m"}, {"a": np.arange(3)})
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    with pytest.raises(OSError, match=re.escape(f"cannot write {str(tmp_path / 'absent' / 's.npz')!r}")):
        write_archive(tmp_path / "absent" / "s.npz", {"magic": "m"}, {"a": np.arange(3)})


@pytest.mark.parametrize("setup, message", [
    ("missing_dir", "the directory"),
    ("read_only", "is read-only (mode 0444)"),
    ("directory", "is a directory"),
])
def test_state_file_problems_fail_before_any_work(cli, feed_csv, tmp_path, setup, message):
    state = tmp_path / "s.npz"
    if setup == "missing_dir":
        state = tmp_path / "absent" / "s.npz"
    elif setup == "read_only":
        assert _run(cli, ["predict", feed_csv, *FAST, "--state", str(state), "-o", os.devnull]).exit_code == 0
        os.chmod(state, 0o444)
    else:
        state.mkdir()
    before = state.read_bytes() if setup == "read_only" else None
    result = _run(cli, ["predict", feed_csv, *FAST, "--state", str(state)])
    assert result.exit_code in (1, 2) and message in result.stderr and result.stdout == ""
    if before is not None:
        assert state.read_bytes() == before


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
    ({"length_unit": 1e300}, ValueError, r"length_unit: expected a number in \[1e-60, 1e\+60\]"),
    ({"length_unit": 1e-300}, ValueError, r"length_unit: expected a number in \[1e-60, 1e\+60\]"),
])
def test_bad_bank_arguments_are_refused_at_construction(options, error, message):
    with pytest.raises(error, match=message):
        make_params(2, 4, **options)
    with pytest.raises(error, match=message):
        MixturePredictor(4, **options)
    direct = set(options) <= {"seed", "length_unit"}
    with pytest.raises(error, match=message):
        StreamConfig(n_experts=4, **(options if direct else {"options": options}))


@pytest.mark.parametrize("unit", LENGTH_UNIT_RANGE)
def test_the_length_unit_range_is_scale_equivariant_at_both_ends(unit):
    z = np.cumsum(np.cumsum(np.random.default_rng(3).normal(size=(120, 2)), 0), 0) * 0.1
    reference = MixturePredictor(4, seed=1, backend="numpy").run(z).predictions
    scaled = MixturePredictor(4, seed=1, backend="numpy", length_unit=unit).run(z * unit).predictions / unit
    np.testing.assert_allclose(scaled[1:], reference[1:], rtol=1e-9, atol=0)
    # the default bank too (the range was 1e+-100, claimed for it, and it departed beyond about 1e-75 and 1e73)
    from kalmix.bank import DEFAULT_BANK, make_bank
    from kalmix.core.compiled import engine as ce

    track, times = z[:, None, :], np.arange(len(z), dtype=float)[:, None]
    plain = ce.run(make_bank(2, **DEFAULT_BANK, length_unit=1.0), track, times)
    both = ce.run(make_bank(2, **DEFAULT_BANK, length_unit=unit), track * unit, times)
    np.testing.assert_allclose(both.forecasts[1:] / unit, plain.forecasts[1:], rtol=1e-9, atol=0)
    np.testing.assert_allclose(both.std[2:] / unit, plain.std[2:], rtol=1e-9, atol=0)


def test_a_state_file_with_a_unit_outside_this_versions_range_says_so(tmp_path, monkeypatch):
    """The range was 1e+-100: a state file saved with 1e-80 was called "incomplete or corrupt"."""
    import kalmix.mixture_recipe
    import kalmix.stream.state_file

    engine = TrackPredictor(StreamConfig(length_unit=1e-50, n_experts=2))
    engine.step_row("a", 0.0, [1e-50, 2e-50])
    wider = dataclasses.replace(kalmix.mixture_recipe.ARGUMENT_CONSTRAINTS["length_unit"], ge=1e-100, le=1e100)
    monkeypatch.setitem(kalmix.mixture_recipe.ARGUMENT_CONSTRAINTS, "length_unit", wider)
    monkeypatch.setattr(kalmix.stream.state_file, "LENGTH_UNIT_RANGE", (1e-100, 1e100))
    engine.config = dataclasses.replace(engine.config, length_unit=1e-80)   # as an older version saved it
    engine.save(tmp_path / "s.kmx")
    monkeypatch.undo()
    with pytest.raises(ValueError, match=r"length unit 1e-80 is outside this version's range \[1e-60, 1e\+60\]"):
        TrackPredictor.load(tmp_path / "s.kmx")


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
    members["state/families/0/cov.npy"] = buffer.getvalue()
    with zipfile.ZipFile(tmp_path / "big.npz", "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    opened.clear()
    with pytest.raises(ValueError,
                       match=r"field 'state/families/0/cov' expected \d+ bytes .* the archive declares 32000128"):
        TrackPredictor.load(tmp_path / "big.npz")
    assert "state/families/0/cov.npy" not in opened


@pytest.mark.parametrize("args, message", [
    (["{dir}"], "INPUT: expected a track file (CSV or Parquet), got the directory"),
    (["{csv}", "-o", "/dev/full"], "--output: cannot write '/dev/full': No space left on device"),
    (["{csv}", "--state", "{npy}"], "not a kalmix state file"),
    (["{csv}", "--length-unit", "1e300"], "expected a number in [1e-60, 1e+60] or 'auto'"),
    (["{csv}", "--seed", str(2**64)], "is not in the range 0<=x<=9223372036854775807"),
    (["{csv}", "--option", "process_noise_range=5"], "process_noise_range: expected a pair"),
])
def test_bad_command_lines_give_one_clear_line(cli, feed_csv, tmp_path, args, message):
    np.save(tmp_path / "s.npy", np.zeros(3))
    names = {"dir": str(tmp_path), "csv": feed_csv, "npy": str(tmp_path / "s.npy")}
    result = _run(cli, ["predict", *FAST, *[a.format(**names) for a in args]])
    assert result.exit_code in (1, 2) and message in result.stderr and "Traceback" not in result.stderr
    if result.exit_code == 1:
        assert len(result.stderr.splitlines()) == 1


@pytest.mark.parametrize("command, args, message", [
    ("predict", ["{csv}", "-o", "{csv}"], "--output: '{csv}' is the same file as INPUT"),
    ("predict", ["{csv}", "--state", "{out}", "-o", "{out}"], "--state: '{out}' is the same file as --output"),
    ("predict", ["{gz}"], "the input ends early (a truncated or corrupt file?)"),
    ("predict", ["{npz}"], "is not a CSV text file (UTF-8 expected"),
    ("evaluate", ["{csv}", "--plot", "{missing}/p.png"], "--plot: the directory"),
])
def test_more_bad_command_lines_fail_at_start_with_one_line(cli, tmp_path, command, args, message):
    import gzip

    data = _feed(n_tracks=2, n=40)
    names = {"csv": str(tmp_path / "in.csv"), "out": str(tmp_path / "out.csv"), "gz": str(tmp_path / "cut.csv.gz"),
             "npz": str(tmp_path / "bin.csv"), "missing": str(tmp_path / "absent")}
    data.to_csv(names["csv"], index=False)
    before = open(names["csv"]).read()
    (tmp_path / "cut.csv.gz").write_bytes(gzip.compress(before.encode())[:200])
    np.savez(tmp_path / "bin.npz", a=np.arange(50))
    os.replace(tmp_path / "bin.npz", names["npz"])
    result = _run(cli, [command, *FAST[:2], *[a.format(**names) for a in args]])
    lines = result.stderr.splitlines()
    assert result.exit_code == 1 and len(lines) == 1 and message.format(**names) in lines[0]
    assert open(names["csv"]).read() == before  # the input is never touched


def test_process_table_names_missing_columns():
    """No position column: an error that names what was expected and the columns there are. No time column: row
    order is time, as in ``kalmix predict``."""
    with pytest.raises(ValueError, match=r"expected 1 to 3 position columns.*'track_id', 'time'"):
        TrackPredictor(StreamConfig(n_experts=2)).process_table(pd.DataFrame({"track_id": [1], "time": [0.0]}))
    out = TrackPredictor(StreamConfig(n_experts=2, length_unit=1.0)).process_table(
        pd.DataFrame({"track_id": [1, 1, 1], "x": [1.0, 2.0, 3.0]}))
    assert list(out["row"]) == [0, 1, 2] and np.isfinite(out["pred_x"]).all()


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
    # regular rows: the file's forecast for the next row's time is the stream's one interval on, same bits
    pd.testing.assert_frame_equal(file_rows.reset_index(drop=True), stdin_rows.reset_index(drop=True),
                                  check_exact=True)


@settings(max_examples=40)
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


def test_a_future_timestamp_on_stdin_costs_no_later_row(cli):
    feed = "t,x\n0,0\n1,1\n2,2\n1e9,3\n4,4\n5,5\n6,6\n"
    result = _run(cli, ["predict", "-", *FAST], input=feed)
    assert result.exit_code == 0
    assert pd.read_csv(io.StringIO(result.stdout))["t"].tolist() == [0, 1, 2, 1e9, 4, 5, 6]
    assert "1 row(s) came back in time after a jump ahead" in result.stderr
    # a repeated or older time is still skipped, and replaying a feed still skips what was done
    result = _run(cli, ["predict", "-", *FAST], input="t,x\n0,0\n1,1\n1,1\n0.5,2\n2,2\n")
    assert result.exit_code == 0 and result.stderr.count("row skipped") == 2


@pytest.mark.parametrize("content", ["t,x\n0,1\n", "t,x\n0,1\n1,2\n", "t,x\n0,1\n0,2\n0,3\n",
                                     "t,x\n0,1\n1,2\n2,3\n3,5\n4,6\n"])
def test_evaluate_on_too_little_data_says_so(cli, tmp_path, content):
    path = tmp_path / "tiny.csv"
    path.write_text(content)
    result = _run(cli, ["evaluate", str(path), "--experts", "2", "--no-peers"])
    assert result.exit_code == 1 and "All-NaN" not in result.stderr
    assert "too little data to tune the predictors on" in result.stderr.splitlines()[-1]


# -------------------------------------------------------------------------------- 8: progress
def test_the_progress_bar_has_a_total_and_moves_within_a_chunk(cli, feed_csv, monkeypatch):
    import functools

    import tqdm

    monkeypatch.setattr(_predict_file, "PIECE_ROWS", 40)
    monkeypatch.setattr(tqdm, "tqdm", functools.partial(tqdm.tqdm, mininterval=0, miniters=1))  # draw every update
    result = _run(cli, ["predict", feed_csv, *FAST[:-1], "--progress", "--chunk-rows", "1000", "-o", os.devnull])
    assert result.exit_code == 0
    shown = set(re.findall(r"(\d+)/360 ", result.stderr))  # the total, counted before the first chunk
    assert {"0", "360"} < shown and len(shown) >= 9  # one chunk, nine pieces: the bar moved inside it


def test_count_rows(tmp_path):
    import gzip

    (tmp_path / "a.csv").write_bytes(b"t,x\n0,1\n1,2\n2,3")  # no final newline
    with gzip.open(tmp_path / "b.csv.gz", "wb") as handle:
        handle.write(b"t,x\n" + b"".join(b"%d,1\n" % i for i in range(300_000)))
    (tmp_path / "c.csv").write_bytes(b"t,x\n")
    assert [count_rows(str(tmp_path / n)) for n in ("a.csv", "b.csv.gz", "c.csv")] == [3, 300_000, 0]


@settings(max_examples=30)
@given(lengths=st.lists(st.integers(1, 30), min_size=1, max_size=8), rows=st.integers(1, 50))
def test_pieces_keep_every_track_in_order_and_merge_back(lengths, rows):
    chunk = pd.DataFrame({"track_id": np.repeat([f"t{i}" for i in range(len(lengths))], lengths),
                          "time": np.concatenate([np.arange(n) * 0.5 for n in lengths])})
    parts = _predict_file.pieces(chunk, rows)
    assert sum(len(p) for p in parts) == len(chunk) and len(parts) <= _predict_file._MAX_PIECES
    for track, n in zip(chunk["track_id"].unique(), lengths):  # a track with enough rows is in every piece
        assert n < len(parts) or all((p["track_id"] == track).any() for p in parts)
    seen = pd.concat(parts)
    assert seen.groupby("track_id", sort=False)["time"].apply(lambda t: t.is_monotonic_increasing).all()
    shuffled = [p.assign(x=1.0) for p in parts[::-1]]
    pd.testing.assert_frame_equal(_predict_file.merge(shuffled, chunk)[["track_id", "time"]],
                                  chunk.reset_index(drop=True))


class _Finaliser:
    """Keeps the frame of its ``__del__``: where Python prints an exception and ignores it."""
    frame = None

    def __del__(self):
        _Finaliser.frame = sys._getframe()


def _finaliser_frame():
    _Finaliser()
    return _Finaliser.frame


def _main_thread_only():
    import threading

    if threading.current_thread() is not threading.main_thread():   # signal handlers live there only
        pytest.skip("needs the main thread (it installs a signal handler and signals this process)")


def _wait_for(exception):
    with pytest.raises(exception):
        for _ in range(500):   # the signal comes again within REDELIVER_SECONDS; 10 s at most here
            time.sleep(0.02)


def test_a_stop_signal_in_a_finaliser_is_raised_again_where_it_stops_the_run():
    """A signal handled inside a finaliser (or llvmlite code, which LLVM calls from C during a numba compile)
    cannot stop the run there: the exception would be printed and dropped, and a Ctrl-C during a fresh
    install's first compile did nothing until the chunk's end (seen: 'Exception ignored ... __del__', then
    the whole compile). The guard sends the signal again a moment later, and raises it then."""
    from kalmix.commands._durable import Interrupted, SignalGuard
    from kalmix.commands._interrupt import swallowing

    _main_thread_only()
    frame = _finaliser_frame()
    assert swallowing(frame) and not swallowing(sys._getframe())
    with SignalGuard() as guard:
        assert guard._handle(signal.SIGTERM, frame) is None   # not raised there
        assert guard.received == signal.SIGTERM
        _wait_for(Interrupted)
    assert guard.raised


def test_a_stop_signal_that_was_dropped_is_raised_at_the_next_unit_of_work():
    """A safety net for places the guard cannot see: a signal received and not raised stops the run at the
    next tick (a slice of a chunk, a stdin batch), not at the chunk's commit; inside a commit it waits."""
    from kalmix.commands._durable import Interrupted, SignalGuard

    guard = SignalGuard()
    guard.tick()   # nothing received: nothing raised
    guard.received = signal.SIGINT
    with guard.deferred(deliver=False):
        guard.tick()
    with pytest.raises(Interrupted):
        guard.tick()


def test_ctrl_c_outside_predict_is_not_dropped_in_a_finaliser(monkeypatch):
    """The command line's Ctrl-C (kalmix demo, evaluate, ... compiling on a fresh install) raises
    KeyboardInterrupt as usual, but where it would be dropped it comes again a moment later. Before, a
    KeyboardInterrupt raised in llvmlite's callback left numba without its compiled object: a 140-line
    'RuntimeError: no compiled object yet' instead of 'Aborted!'."""
    from kalmix.commands import _interrupt

    _main_thread_only()
    previous = signal.getsignal(signal.SIGINT)
    monkeypatch.setattr(signal, "default_int_handler", previous)   # as if Python's own handler were installed
    try:
        _interrupt.install_keyboard_interrupt()
        assert signal.getsignal(signal.SIGINT) is _interrupt._keyboard_interrupt
        assert _interrupt._keyboard_interrupt(signal.SIGINT, _finaliser_frame()) is None
        _wait_for(KeyboardInterrupt)
        with pytest.raises(KeyboardInterrupt):
            _interrupt._keyboard_interrupt(signal.SIGINT, sys._getframe())
    finally:
        signal.signal(signal.SIGINT, previous)


def test_the_command_line_leaves_a_handler_it_did_not_install_alone(monkeypatch):
    """Only over Python's own SIGINT handler: an ignored SIGINT (a background job) stays ignored."""
    from kalmix.commands import _interrupt

    _main_thread_only()
    previous = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        _interrupt.install_keyboard_interrupt()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_figure_or_json_interrupted_while_written_leaves_the_previous_file(tmp_path):
    """Ctrl-C while `reproduce figure2` saved its PNG left it at 0 bytes (table1's JSON cut at 12 of 16
    KB, servo_error.png at 124 bytes): they were written in place. Now every figure and JSON the commands write
    goes through a temporary file renamed over the old one, as the state file does."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kalmix.archive import save_figure
    from kalmix.commands._common import write_json

    target = tmp_path / "out.json"
    write_json(str(target), {"a": 1})
    before = target.read_bytes()

    class Stop(BaseException):
        pass

    original = json.dump

    def interrupted(data, handle, **kwargs):
        handle.write('{"half": ')
        raise Stop

    json.dump = interrupted
    try:
        with pytest.raises(Stop):
            write_json(str(target), {"b": 2})
    finally:
        json.dump = original
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]   # no temporary file left

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    png = save_figure(fig, tmp_path / "figure.png")
    assert open(png, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    bare = save_figure(fig, tmp_path / "figure")   # no extension: PNG, at that very path
    assert open(bare, "rb").read(4) == b"\x89PNG" and bare == str(tmp_path / "figure")
    save_figure(fig, tmp_path / "f.svg")
    assert b"<svg" in (tmp_path / "f.svg").read_bytes()
    if os.path.exists(os.devnull):   # a device is written directly (--json /dev/stdout), not replaced
        save_figure(fig, os.devnull)
        write_json(os.devnull, {"a": 1})
    plt.close(fig)
    # /dev/stdout on a pipe resolves to /proc/<pid>/fd/pipe:[N], which does not exist: it failed
    piped = subprocess.run([sys.executable, "-c", "from kalmix.commands._common import write_json; "
                            "write_json('/dev/stdout', {'a': 1})"], capture_output=True, text=True)
    if os.path.exists("/dev/stdout"):
        assert piped.returncode == 0 and json.loads(piped.stdout) == {"a": 1}, piped.stderr
    # a read-only file is refused, as open() refuses it, not replaced (root may write anyway)
    locked = tmp_path / "locked.json"
    write_json(str(locked), {"a": 1})
    os.chmod(locked, 0o444)
    if not os.access(locked, os.W_OK):
        with pytest.raises(PermissionError):
            write_json(str(locked), {"b": 2})
        assert json.loads(locked.read_text()) == {"a": 1}
