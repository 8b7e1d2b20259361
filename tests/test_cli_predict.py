"""``kalmix predict``: formats, stdin streaming == batch, --state resume, bad inputs, a big file in chunks."""

import decimal
import io
import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from cli_helpers import invoke as _run

FAST = ["--experts", "4", "--seed", "1", "--length-unit", "0.01", "--no-progress"]


def _tracks(n_tracks=3, n=50, seed=0, gap=True):
    rng = np.random.default_rng(seed)
    rows = []
    for track in range(n_tracks):
        t = np.round(np.arange(n) * 0.04, 6)
        if gap and track == 1:
            t[n // 2:] += 3.0
        xy = np.cumsum(np.cumsum(rng.normal(size=(n, 2)), 0), 0) * 0.01 + rng.normal(0, 0.01, (n, 2))
        xy[5] = np.nan
        rows += [(100 + track, t[i], *xy[i]) for i in range(n)]
    return pd.DataFrame(rows, columns=["object_id", "t", "px", "py"])


def _write_csv(frame, path):
    frame.to_csv(path, index=False, na_rep="")
    return str(path)


def _read(text):
    return pd.read_csv(io.StringIO(text))


def _defined_alike(frame):
    """Rows whose file pred_ (for the next row's time) is the stream's (one reference interval on): the next
    row is one step (0.04) later; and not the stream's very first row (no interval known yet)."""
    step = frame.groupby("object_id")["t"].diff().shift(-1).to_numpy()
    alike = np.abs(step - 0.04) < 1e-9
    first = frame["t"].to_numpy() == frame["t"].min()
    return alike & ~(first & (frame["object_id"].to_numpy() == frame["object_id"].min()))


def _sorted(frame):
    return frame.sort_values(["object_id", "t"], kind="stable").reset_index(drop=True)


def test_csv_round_trip_keeps_ids_and_times(cli, tmp_path):
    data = _tracks()
    result = _run(cli, ["predict", _write_csv(data, tmp_path / "in.csv"), *FAST, "-H", "5"])
    assert result.exit_code == 0, result.output
    out = _read(result.stdout)
    assert list(out.columns) == ["object_id", "t", "segment", "pred_px", "pred_py", "std_px", "std_py",
                                 "pred5_px", "pred5_py", "std5_px", "std5_py"]
    pd.testing.assert_frame_equal(out[["object_id", "t"]], _sorted(data)[["object_id", "t"]])
    assert out.groupby("object_id")["segment"].max().to_dict() == {100: 0, 101: 1, 102: 0}
    assert np.isfinite(out[["pred_px", "pred_py"]].to_numpy()).all()


def test_parquet_in_and_out_and_jsonl_out(cli, tmp_path):
    data = _tracks()
    data.to_parquet(tmp_path / "in.parquet", index=False)
    csv_out = _read(_run(cli, ["predict", _write_csv(data, tmp_path / "in.csv"), *FAST]).stdout)
    result = _run(cli, ["predict", str(tmp_path / "in.parquet"), *FAST, "-o", str(tmp_path / "out.parquet")])
    assert result.exit_code == 0, result.output
    parquet_out = pd.read_parquet(tmp_path / "out.parquet")
    np.testing.assert_array_equal(parquet_out[["pred_px", "pred_py"]], csv_out[["pred_px", "pred_py"]])
    result = _run(cli, ["predict", str(tmp_path / "in.csv"), *FAST, "-o", str(tmp_path / "out.jsonl")])
    records = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert len(records) == len(data) and set(records[0]) == {"object_id", "t", "segment", "pred_px", "pred_py",
                                                             "std_px", "std_py"}


def test_csv_gz_input(cli, tmp_path):
    data = _tracks(n_tracks=1, gap=False)
    data.to_csv(tmp_path / "in.csv.gz", index=False)
    result = _run(cli, ["predict", str(tmp_path / "in.csv.gz"), *FAST])
    assert result.exit_code == 0 and len(_read(result.stdout)) == len(data)


@pytest.mark.parametrize("extra", [[], ["--max-gap", "none", "--reach", "1.5"]], ids=["default", "reach"])
def test_stdin_csv_streaming_equals_batch(cli, tmp_path, extra):
    """With a reach, across the missing row and the gap only the CV experts predict, in a file and on stdin."""
    # a live feed: rows of all tracks mixed (the file has the same rows in the same order: the population prior
    # follows the order the rows came)
    data = _tracks().sort_values(["t", "object_id"], kind="stable")
    path = _write_csv(data, tmp_path / "in.csv")
    batch = _sorted(_read(_run(cli, ["predict", path, *FAST, "-H", "3", *extra]).stdout))
    if extra:
        plain = _sorted(_read(_run(cli, ["predict", path, *FAST, "-H", "3", "--max-gap", "none"]).stdout))
        assert not np.allclose(plain["pred_px"], batch["pred_px"], equal_nan=True)
    stream = _run(cli, ["predict", "-", *FAST, "-H", "3", *extra], input=data.to_csv(index=False, na_rep=""))
    assert stream.exit_code == 0, stream.output
    stream = _sorted(_read(stream.stdout))
    assert list(stream.columns) == list(batch.columns)
    np.testing.assert_array_equal(stream[["object_id", "segment", "t"]], batch[["object_id", "segment", "t"]])
    lead = ["pred3_px", "pred3_py", "std3_px", "std3_py"]   # defined alike everywhere
    np.testing.assert_array_equal(stream[lead], batch[lead])
    alike = _defined_alike(batch)
    assert alike.sum() >= 140
    nxt = ["pred_px", "pred_py", "std_px", "std_py"]
    # not bit for bit (2.2e-15 measured): a stream forecasts its last time plus an interval, a file the next row's time
    np.testing.assert_allclose(stream.loc[alike, nxt], batch.loc[alike, nxt], rtol=0, atol=1e-9)


def test_stdin_json_lines_equal_batch(cli, tmp_path):
    data = _tracks(n_tracks=2)
    batch = _read(_run(cli, ["predict", _write_csv(data, tmp_path / "in.csv"), *FAST]).stdout)
    lines = "\n".join(json.dumps({"object_id": int(r.object_id), "t": r.t,
                                  "px": None if np.isnan(r.px) else r.px, "py": None if np.isnan(r.py) else r.py})
                      for r in data.itertuples())
    result = _run(cli, ["predict", "-", *FAST], input=lines + "\n")
    assert result.exit_code == 0, result.output
    out = _sorted(pd.DataFrame([json.loads(line) for line in result.stdout.splitlines()]))
    alike = _defined_alike(batch)
    np.testing.assert_allclose(out.loc[alike, ["pred_px", "pred_py", "std_px", "std_py"]],
                               batch.loc[alike, ["pred_px", "pred_py", "std_px", "std_py"]], rtol=0, atol=1e-9)


def test_stdin_prediction_is_written_as_each_line_arrives(tmp_path):
    """Feed a real pipe line by line and read each prediction before sending the next line."""
    import subprocess
    import sys

    process = subprocess.Popen([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        process.stdin.write("t,x,y\n")
        lines = []
        for k in range(3):
            process.stdin.write(f"{k},{0.1 * k},{0.2 * k}\n")
            process.stdin.flush()
            if k == 0:
                assert process.stdout.readline().startswith("t,segment,pred_x")
            lines.append(process.stdout.readline())
        assert [line.split(",")[0] for line in lines] == ["0", "1", "2"]   # the times as given
    finally:
        process.stdin.close()
        process.wait(timeout=60)


def test_line_batches_take_what_has_arrived():
    """A pipe that is ahead gives its lines in batches (up to the limit; the last line may lack its newline);
    a pipe fed line by line gives one line at a time; a stream without a descriptor, a line at a time."""
    import io
    import os
    import threading

    from kalmix.commands._stdin_lines import line_batches

    read, write = os.pipe()
    os.write(write, "".join(f"{i},x\r\n" for i in range(10)).encode() + "é,last".encode())
    os.close(write)
    with os.fdopen(read, encoding="utf-8") as stream:
        batches = list(line_batches(stream, limit=4))
    assert [len(b) for b in batches[:2]] == [4, 4] and max(len(b) for b in batches) == 4
    assert sum(batches, []) == [f"{i},x\r\n" for i in range(10)] + ["é,last"]

    read, write = os.pipe()
    got, sent = [], threading.Event()

    def feed():
        for i in range(3):
            os.write(write, f"{i}\n".encode())
            sent.wait(30)   # the next line only once this one was taken
            sent.clear()
        os.close(write)

    writer = threading.Thread(target=feed)
    writer.start()
    with os.fdopen(read) as stream:
        for batch in line_batches(stream):
            got.append(batch)
            sent.set()
    writer.join()
    assert got == [["0\n"], ["1\n"], ["2\n"]]
    assert list(line_batches(io.StringIO("a\nb\n"))) == [["a\n"], ["b\n"]]


def test_line_batches_split_lines_across_reads_and_stop_at_a_bad_byte():
    """Lines cut anywhere by the reads (inside a multi-byte character, right after a newline) come out whole;
    a line that does not decode raises, naming it, only after the lines before it."""
    import io
    import os
    import threading

    from kalmix.commands._stdin_lines import line_batches, split_lines

    def batches(chunks, errors="strict"):
        read, write = os.pipe()

        def feed():   # from a thread: the pipe holds 64 KiB
            for chunk in chunks:
                os.write(write, chunk)
            os.close(write)

        writer = threading.Thread(target=feed)
        writer.start()
        with os.fdopen(read, encoding="utf-8", errors=errors) as stream:
            out = []
            try:
                for batch in line_batches(stream, limit=3):
                    out.append(batch)
            except ValueError as error:
                out.append(str(error))
        writer.join()
        return out

    text = "t,é\n1,ü€\n\n2,x\n" + "3," + "9" * 200_000 + "\n4,y"
    data = text.encode()
    assert sum(batches([data]), []) == io.StringIO(text).readlines()
    rng = np.random.default_rng(0)
    for cuts in ([4], [3, 9, 10], list(range(1, 30)), [5, 14, 15, 16], sorted(rng.choice(len(data), 40))):
        edges = [0, *cuts, len(data)]
        partial, lines = [], []
        for a, b in zip(edges[:-1], edges[1:]):   # reads ending anywhere: inside a character, after a newline
            lines += split_lines(partial, data[a:b])
        lines += [b"".join(partial)]
        assert [line.decode() for line in lines] == io.StringIO(text).readlines()
    got = batches([b"t,x\n0,1\n1,\xff\n2,3\n"])
    assert got[0] == ["t,x\n", "0,1\n"] and "not valid utf-8" in got[1] and "1,\\xff" in got[1]
    assert sum(batches([b"t,x\n1,\xff\n"], errors="surrogateescape"), [])[1] == "1,\udcff\n"


def test_line_batches_take_a_lone_carriage_return_as_a_line_end():
    """Old Mac text (lines ending in a lone \\r) on a pipe gives the lines of its \\n version, whatever the reads'
    cuts (one between the first \\r and what follows it too); \\r\\n is kept as one line end, as before. The
    CLI gives the same bytes for the three endings."""
    import os
    import subprocess
    import sys
    import threading

    from kalmix.commands._stdin_lines import line_batches

    def lines(data, cuts):
        read, write = os.pipe()
        edges = [0, *cuts, len(data)]

        def feed():
            for a, b in zip(edges[:-1], edges[1:]):
                os.write(write, data[a:b])
            os.close(write)

        writer = threading.Thread(target=feed)
        writer.start()
        with os.fdopen(read, encoding="utf-8") as stream:
            got = sum(line_batches(stream, limit=2), [])
        writer.join()
        return got

    rows = ["t,x", "0,1", "1,2", "2,3"]
    for cuts in ([], [3], [4], [5], [2, 4, 6], list(range(1, 16))):
        assert lines("\r".join(rows).encode(), cuts) == [r + "\n" for r in rows[:-1]] + [rows[-1]]
        assert lines(("\r\n".join(rows) + "\r\n").encode(), cuts) == [r + "\r\n" for r in rows]
    assert lines(b"t,x\r", [3]) == ["t,x\r"]      # a header alone, its end a \r at the stream's end
    text = "time,track_id,x,y{0}0,a,1,2{0}1,a,2,3{0}2,a,3,4{0}3,a,4,5.5{0}"
    outputs = {subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "--length-unit", "1", "-"],
                              input=text.format(end).encode(), capture_output=True, check=True).stdout
               for end in ("\r", "\n", "\r\n")}
    assert len(outputs) == 1 and outputs.pop().count(b"\n") == 5


def test_stdin_bad_line_after_rows_on_a_pipe(tmp_path):
    """On a pipe (rows stepped in batches), with --on-bad-row fail the rows before a bad line are written, then a
    clear error: a JSON integer beyond any float, a CSV line the csv module refuses. By default the bad line is
    skipped: its output line is there, empty, and the feed goes on."""
    import subprocess
    import sys

    good = "".join(json.dumps({"t": k, "x": 0.1 * k}) + "\n" for k in range(3))
    later = "".join(json.dumps({"t": k, "x": 0.1 * k}) + "\n" for k in range(3, 6))
    for feed, message, lines in ((good + '{"t": 1' + "0" * 400 + ', "x": 1}\n' + later,
                                  "must be finite, got an integer of 401", 7),
                                 ("t,x\n0,1\n1,2\n2,3\n3,4\r5\n4,5\n", "line 5: not a CSV row", 1 + 5)):
        done = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST, "--on-bad-row", "fail"],
                              input=feed.encode(), capture_output=True)
        assert done.returncode != 0 and message in done.stderr.decode(), done.stderr.decode()
        assert len(done.stdout.decode().strip().splitlines()) == 3 + (not feed.startswith("{"))
        skipped = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST], input=feed.encode(),
                                 capture_output=True)
        assert skipped.returncode == 0 and "kalmix: warning: 1 bad row(s) skipped" in skipped.stderr.decode()
        assert len(skipped.stdout.decode().strip().splitlines()) == lines   # (a header, then) one per row


@pytest.mark.parametrize("extra", [[], ["--lead", "0.1"]])
def test_stdin_batches_from_a_pipe_equal_rows_one_at_a_time(cli, tmp_path, extra):
    """A whole feed piped in at once (stepped in batches) writes the bytes and warnings of the same feed read a
    line at a time, on interleaved tracks with skipped rows, a row without a time, time glitches, missing
    values and a gap (the warnings in line order)."""
    import subprocess
    import sys

    data = _tracks(n_tracks=4).sort_values(["t", "object_id"], kind="stable")
    rows = data.to_csv(index=False, na_rep="").splitlines(keepends=True)
    rows[40:40] = [rows[39], rows[38]]                     # a repeated row and one back in time: skipped
    rows.insert(60, "101,500.0,0.1,0.2\n")                 # a wrong jump ahead, then rows come back: a glitch
    rows.insert(70, "102,,0.3,0.4\n")                       # no time: skipped
    feed = "".join(rows)
    args = ["predict", "-", *FAST, *extra]
    one_at_a_time = _run(cli, args, input=feed)   # in-memory stdin: read a line at a time
    piped = subprocess.run([sys.executable, "-m", "kalmix.cli", *args], input=feed.encode(), capture_output=True)
    assert piped.returncode == 0 and one_at_a_time.exit_code == 0, piped.stderr
    assert piped.stdout.decode() == one_at_a_time.stdout
    warnings = [line for line in one_at_a_time.stderr.splitlines() if "warning" in line]
    assert any("not after" in w for w in warnings) and any("comes back before" in w for w in warnings)
    assert any("no time" in w for w in warnings)
    assert [line for line in piped.stderr.decode().splitlines() if "warning" in line] == warnings


def test_state_resume_is_bit_for_bit_on_stdin(cli, tmp_path):
    data = _tracks().sort_values(["t", "object_id"], kind="stable")
    whole = _run(cli, ["predict", "-", *FAST, "-H", "2"], input=data.to_csv(index=False, na_rep="")).stdout
    state = str(tmp_path / "state.npz")
    first = _run(cli, ["predict", "-", *FAST, "-H", "2", "--state", state, "--save-every", "7"],
                 input=data.iloc[:77].to_csv(index=False, na_rep=""))
    second = _run(cli, ["predict", "-", "--state", state, "--no-progress"],
                  input=data.iloc[77:].to_csv(index=False, na_rep=""))
    assert first.exit_code == 0 and second.exit_code == 0, second.output
    body = second.stdout.split("\n", 1)[1]  # each run writes its own header
    assert first.stdout + body == whole


def test_a_replayed_feed_warns_in_a_few_lines_and_writes_the_header(cli, tmp_path):
    """Replaying a feed already processed (stdin, --state): every row is skipped. Ten warnings, one line saying
    the rest are counted, the totals at the end (it printed a line per row); and the CSV header, as a file's
    run writes it (it wrote nothing)."""
    data = _tracks(gap=False).sort_values(["t", "object_id"], kind="stable")
    feed = data.to_csv(index=False, na_rep="") + "100,,1,2\n"   # and a row without a time
    state = str(tmp_path / "s.npz")
    assert _run(cli, ["predict", "-", *FAST, "--state", state], input=feed).exit_code == 0
    again = _run(cli, ["predict", "-", "--state", state, "--no-progress"], input=feed)
    assert again.exit_code == 0, again.output
    lines = again.stderr.splitlines()
    assert sum("is not after the previous time of track" in line for line in lines) == 10
    assert sum("further warnings like the last are only counted" in line for line in lines) == 1
    assert f"skipped {len(data)} row(s) at or before" in again.stderr
    assert sum("no time, row skipped" in line for line in lines) == 1
    assert "skipped 1 row(s) without a time" in again.stderr
    first_run = _run(cli, ["predict", _write_csv(data, tmp_path / "d.csv"), *FAST]).stdout
    assert again.stdout == first_run.splitlines(keepends=True)[0]


def test_state_resume_is_bit_for_bit_on_files(cli, tmp_path):
    ordered = _tracks().sort_values(["t", "object_id"], kind="stable")
    whole = _run(cli, ["predict", _write_csv(ordered, tmp_path / "all.csv"), *FAST]).stdout
    state = str(tmp_path / "state.npz")
    first = _run(cli, ["predict", _write_csv(ordered.iloc[:90], tmp_path / "a.csv"), *FAST, "--state", state])
    # the second file repeats 10 rows already processed: they are skipped, not predicted twice
    second = _run(cli, ["predict", _write_csv(ordered.iloc[80:], tmp_path / "b.csv"), "--state", state,
                        "--no-progress"])
    assert "skipped 10 row(s)" in second.stderr
    combined = _sorted(pd.concat([_read(first.stdout), _read(second.stdout)]))
    expected = _sorted(_read(whole))
    # a track's last row in a.csv was forecast one interval on (its next row was not in that file)
    last = ordered.iloc[:90].groupby("object_id")["t"].max()
    cut = combined["t"].to_numpy() == combined["object_id"].map(last).to_numpy()
    assert cut.sum() == 3
    assert combined[~cut].to_csv(index=False) == expected[~cut].to_csv(index=False)
    same = ["object_id", "t", "segment"]
    assert combined.loc[cut, same].to_csv(index=False) == expected.loc[cut, same].to_csv(index=False)


@pytest.mark.parametrize("ids", [
    pd.to_datetime(["2020-01-01", "2020-01-02 03:04:05.000000001", "2021-06-01"], format="ISO8601").tz_localize("UTC"),
    pd.to_timedelta([1, 2, 3], unit="s"), [b"a", b"\xff", b""], [decimal.Decimal("1.50"), decimal.Decimal("2"),
                                                                   decimal.Decimal("-0.1")],
    np.array([0.5, 1.5, 2.5], dtype=np.float16)])
def test_state_keeps_parquet_ids_that_json_has_no_type_for(cli, tmp_path, ids):
    """Dates, durations, bytes and decimals as track ids (Parquet columns): the state file keeps them (it
    failed to save: 'not JSON serializable'), and a resumed run finds its tracks again; float16 ids (pandas
    cannot group them) are read as float32."""
    data = _tracks(gap=False)
    data["object_id"] = data["object_id"].map(dict(zip([100, 101, 102], ids)))
    ordered = data.sort_values(["t", "object_id"], kind="stable").reset_index(drop=True)
    ordered.iloc[:90].to_parquet(tmp_path / "a.parquet")
    ordered.iloc[80:].to_parquet(tmp_path / "b.parquet")
    state = str(tmp_path / "state.npz")
    first = _run(cli, ["predict", str(tmp_path / "a.parquet"), *FAST, "--state", state, "-o", str(tmp_path / "a.csv")])
    assert first.exit_code == 0, first.output
    second = _run(cli, ["predict", str(tmp_path / "b.parquet"), "--state", state, "--no-progress",
                        "-o", str(tmp_path / "b.csv")])
    assert second.exit_code == 0, second.output
    assert "skipped 10 row(s)" in second.stderr   # the rows already processed: their tracks were found again
    assert len(pd.read_csv(tmp_path / "b.csv")) == len(ordered) - 90
    from kalmix.streaming import TrackPredictor

    kept = pd.read_parquet(tmp_path / "a.parquet")["object_id"]   # as Parquet gives them back (decimal scale)
    assert sorted(map(repr, TrackPredictor.load(state).gaps)) == sorted(map(repr, set(kept)))


def test_state_refuses_conflicting_settings(cli, tmp_path):
    data = _tracks(n_tracks=1)
    path = _write_csv(data, tmp_path / "in.csv")
    state = str(tmp_path / "s.npz")
    _run(cli, ["predict", path, *FAST, "--state", state])
    result = _run(cli, ["predict", path, "--state", state, "--experts", "9"])
    assert result.exit_code == 1 and "--experts" in result.stderr and "made with 4" in result.stderr


@pytest.mark.parametrize("made, then, refused", [
    ([], ["--max-gap", "none"], "made with --max-gap auto --max-gap-factor 3, got --max-gap none"),
    ([], ["--max-gap-factor", "50"],
     "made with --max-gap auto --max-gap-factor 3, got --max-gap auto --max-gap-factor 50"),
    (["--max-gap", "none"], ["--max-gap", "auto"], "made with --max-gap none, got --max-gap auto --max-gap-factor 3"),
    (["--max-gap", "2"], ["--max-gap", "1.5"], "made with --max-gap 2, got --max-gap 1.5"),
    (["--max-gap", "2"], ["--max-gap", "2"], None),
    (["--max-gap", "none"], ["--max-gap", "none", "--max-gap-factor", "5"], None),
    (["--max-gap-factor", "4"], [], None),
    (["--max-gap", "5", "--max-gap-factor", "inf"], ["--max-gap", "5"], None),   # (it was refused)
])
def test_state_refuses_another_gap_rule(cli, tmp_path, made, then, refused):
    """--max-gap / --max-gap-factor on a resumed run: refused when they change the state's gap rule, as every
    other setting is (they were ignored: the gap rule the state file holds went on, silently)."""
    data = _tracks(n_tracks=2, gap=False)
    first, rest = data[data["t"] < 1.0], data[data["t"] >= 1.0].copy()
    rest["t"] += 3.0    # a gap of 3 s after 0.04 s steps: a restart for the default rule, none for --max-gap none
    state = str(tmp_path / "s.npz")
    assert _run(cli, ["predict", _write_csv(first, tmp_path / "a.csv"), *FAST, "--state", state, *made]).exit_code == 0
    result = _run(cli, ["predict", _write_csv(rest, tmp_path / "b.csv"), "--state", state, "--no-progress", *then])
    if refused is None:
        assert result.exit_code == 0, result.output
        return
    assert result.exit_code == 1 and refused in result.stderr and "new --state" in result.stderr, result.stderr
    assert "pred_px" not in result.stdout


def test_explicit_column_names(cli, tmp_path):
    data = _tracks(n_tracks=2).rename(columns={"object_id": "boat", "t": "clock", "px": "east", "py": "north"})
    data["speed"] = 1.0
    path = _write_csv(data, tmp_path / "in.csv")
    result = _run(cli, ["predict", path, *FAST, "--time", "clock", "--id", "boat", "--position", "east,north"])
    assert result.exit_code == 0, result.output
    assert list(_read(result.stdout).columns) == ["boat", "clock", "segment", "pred_east", "pred_north", "std_east",
                                                  "std_north"]


@pytest.mark.parametrize("content, args, message", [
    ("t,px,py\n0,1,2\n", ["--position", "px,pz"], "not found; available columns"),
    ("t,a,b\n0,1,2\n", [], "Could not detect position columns"),
    ("t;x;y\n0;1;2\n", [], "looks separated by semicolons: kalmix reads comma-separated CSV; convert it first "
                          "(e.g. pandas.read_csv(path, sep=';', decimal=',')"),
    ("t;x;y\n0;1,5;2\n", ["--position", "x,y"], "not found; available columns: ['t;x;y']. The header looks "
                                                "separated by semicolons"),
    ("0,1,2\n1,1,3\n", [], "The column names are numbers: the first line must be a header"),
    # a used column named as the table's id / time column inside, or one column in two roles, gave
    # silently wrong output (positions in the id column; times as a position)
    ("obj,time,x,track_id\n1,0,1,2\n1,1,2,3\n", ["--id", "obj", "--position", "x,track_id"],
     "column 'track_id' is used as --position, but a track table names its id column 'track_id' (here 'obj')"),
    ("time,x,y\n0,1,2\n1,2,3\n", ["--position", "x,y,time"], "a track table names its time column 'time'"),
    ("t,x,y\n0,1,2\n1,2,3\n", ["--time", "x"], "column 'x' is given both as --time and as --position"),
    ("t,x,y\n0,1,2\n1,abc,3\n", ["--on-bad-row", "fail"], "line 3: column 'x' must hold a number, got 'abc'"),
    ("", [], "empty"),
    ("t,x,y\n", [], "no rows"),
])
def test_bad_files_give_clear_messages(cli, tmp_path, content, args, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    result = _run(cli, ["predict", str(path), *FAST, *args])
    assert result.exit_code == 1
    assert message in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("content, message", [
    ("", "no input"),
    ("t,x,y\n0,1,2\n1,abc,3\n", "line 3: column 'x' must hold a number, got 'abc'"),
    ("t,x,y\n0,1\n", "line 2: expected 3 fields"),
    ("0,1,2\n1,1,3\n", "the first line must be a header"),
    ("t\tx\ty\n0\t1\t2\n", "looks separated by tabs"),
    ('{"t": 0, "x": 1}\n{"t": 1}\n', "line 2: key 'x' missing"),
    ('{"t": 0, "x": 1}\nnot json\n', "line 2: not valid JSON"),
])
def test_bad_stdin_gives_clear_messages(cli, content, message):
    result = _run(cli, ["predict", "-", *FAST, "--on-bad-row", "fail"], input=content)
    assert result.exit_code == 1
    assert message in result.stderr


def test_missing_file(cli):
    result = _run(cli, ["predict", "/nonexistent/tracks.csv"])
    assert result.exit_code == 1 and "no such file" in result.stderr


def test_kalmix_traceback_keeps_an_error_s_traceback(cli, monkeypatch):
    """A one-line error cannot tell a bad input from a kalmix bug raising the same type; KALMIX_TRACEBACK=1
    lets the exception through (a bug report's traceback), and the usual one line comes back without it."""
    from kalmix.commands._common import TRACEBACK_VARIABLE

    monkeypatch.setenv(TRACEBACK_VARIABLE, "1")
    with pytest.raises(FileNotFoundError, match="no such file"):
        _run(cli, ["predict", "/nonexistent/tracks.csv"])
    monkeypatch.setenv(TRACEBACK_VARIABLE, "0")
    result = _run(cli, ["predict", "/nonexistent/tracks.csv"])
    assert result.exit_code == 1 and "no such file" in result.stderr


def test_unsorted_and_duplicate_times_are_handled_with_a_warning(cli, tmp_path):
    data = _tracks(n_tracks=1, gap=False)
    clean = _read(_run(cli, ["predict", _write_csv(data, tmp_path / "clean.csv"), *FAST]).stdout)
    messy = pd.concat([data.iloc[:10].iloc[::-1], data.iloc[10:], data.iloc[[20]]])  # reversed head + a repeat
    result = _run(cli, ["predict", _write_csv(messy, tmp_path / "messy.csv"), *FAST])
    assert result.exit_code == 0
    assert "Times decrease" in result.stderr and "repeat a timestamp" in result.stderr
    # the output rows are the input's, in its order; the earlier row of the repeated time is not predicted
    out = _read(result.stdout)
    np.testing.assert_array_equal(out["t"], messy["t"])
    assert out.iloc[20].isna()[["segment", "pred_px", "pred_py", "std_px", "std_py"]].all()
    kept = out.drop(index=20).astype({"segment": np.int64})   # (read back as floats beside the empty one)
    pd.testing.assert_frame_equal(kept.sort_values("t").reset_index(drop=True), clean)
    # on stdin rows cannot be reordered: an out-of-order or repeated time is skipped with a warning (and its
    # output line has empty predictions)
    result = _run(cli, ["predict", "-", *FAST], input="t,x,y\n0,0,0\n1,1,1\n1,1,1\n0.5,2,2\n2,2,2\n")
    out = _read(result.stdout)
    assert result.exit_code == 0 and len(out) == 5 and out["t"].tolist() == [0, 1, 1, 0.5, 2]
    assert out["pred_x"].isna().tolist() == [False, False, True, True, False]
    assert result.stderr.count("row skipped") == 2


def test_streaming_refuses_parquet_output(cli, tmp_path):
    result = _run(cli, ["predict", "-", "-o", str(tmp_path / "x.parquet")], input="t,x\n0,1\n")
    assert result.exit_code == 1 and "CSV or JSON lines" in result.stderr


@pytest.mark.parametrize("name, hint", [("out.xlsx", "spreadsheets open the .csv"), ("out.csv.gz", "| gzip >"),
                                        ("out.feather", None)])
def test_an_output_name_of_another_format_is_refused(cli, tmp_path, name, hint):
    """``-o out.xlsx`` wrote CSV text under a spreadsheet's name (and ``.csv.gz`` uncompressed text): refused before
    any work, naming what is written; a name without a suffix (a device, a pipe) is still CSV."""
    source = tmp_path / "t.csv"
    source.write_text("t,x\n0,1\n1,2\n2,3\n")
    result = _run(cli, ["predict", str(source), "-o", str(tmp_path / name), *FAST])
    assert result.exit_code == 1 and not (tmp_path / name).exists()
    assert "--output: expected a file name ending in .csv, .parquet or .jsonl" in result.stderr
    assert hint is None or hint in result.stderr
    plain = _run(cli, ["predict", str(source), "-o", str(tmp_path / "predictions"), *FAST])
    assert plain.exit_code == 0 and (tmp_path / "predictions").read_text().startswith("t,segment,pred_x,std_x\n")


def test_big_file_in_chunks_with_bounded_memory(cli, tmp_path):
    """10^5 rows, 200 interleaved tracks, read 20 000 rows at a time == read at once."""
    rng = np.random.default_rng(5)
    n_tracks, n = 200, 500
    t = np.repeat(np.arange(n) * 0.1, n_tracks)
    ids = np.tile(np.arange(n_tracks), n)
    xy = np.cumsum(rng.normal(size=(n, n_tracks, 2)), axis=0).reshape(-1, 2)
    big = pd.DataFrame({"id": ids, "time": t, "x": xy[:, 0], "y": xy[:, 1]})
    path = _write_csv(big, tmp_path / "big.csv")
    args = ["--experts", "2", "--length-unit", "1", "--no-progress", "-o"]
    chunked = _run(cli, ["predict", path, "--chunk-rows", "20000", *args, str(tmp_path / "a.csv")])
    assert chunked.exit_code == 0, chunked.output
    a = pd.read_csv(tmp_path / "a.csv").sort_values(["id", "time"]).reset_index(drop=True)
    assert len(a) == len(big)
    small = big[big["id"] < 5]
    whole = _read(_run(cli, ["predict", _write_csv(small, tmp_path / "s.csv"), *args[:-1]]).stdout)
    whole = whole.sort_values(["id", "time"]).reset_index(drop=True)   # (the output is in the input's order)
    np.testing.assert_array_equal(a[a["id"] < 5][["pred_x", "pred_y"]], whole[["pred_x", "pred_y"]])


def test_progress_bar_goes_to_stderr(cli, tmp_path):
    path = _write_csv(_tracks(n_tracks=1), tmp_path / "in.csv")
    result = _run(cli, ["predict", path, "--experts", "2", "--progress"])
    assert "rows" in result.stderr and "length unit" in result.stderr
    assert "rows" not in result.stdout.splitlines()[0]


def test_mixture_options_pass_through_and_are_validated(cli, tmp_path):
    path = _write_csv(_tracks(n_tracks=1), tmp_path / "in.csv")
    plain = _read(_run(cli, ["predict", path, *FAST]).stdout)
    # options reach the AKF family of the default bank (its own gate is not used there)
    warm = _run(cli, ["predict", path, *FAST, "--option", "order=3", "--option", "forgetting_levels=[0.9]"])
    assert warm.exit_code == 0, warm.output
    assert not np.allclose(_read(warm.stdout)["pred_px"], plain["pred_px"], equal_nan=True)
    bad = _run(cli, ["predict", path, *FAST, "--option", "spectral_radius_bound=-1"])
    assert bad.exit_code == 1 and "spectral_radius_bound" in bad.stderr
    bad = _run(cli, ["predict", path, *FAST, "--option", "nonsense"])
    assert bad.exit_code == 2 and "KEY=VALUE" in bad.output


@pytest.mark.parametrize("option", ["gating=paper", "temperature=4", "gate_share=0.1", "adapt_noise=true"])
def test_the_gates_options_are_refused_as_the_bank_has_no_gate(cli, tmp_path, option):
    """A bank's AKF family has no gate (the rule combines the experts): such an --option changed nothing, and
    said nothing. Now refused by name, with what the family takes; make_bank refuses them too."""
    from kalmix.bank import make_bank

    path = _write_csv(_tracks(n_tracks=1), tmp_path / "in.csv")
    bad = _run(cli, ["predict", path, *FAST, "--option", option])
    key = option.split("=")[0]
    assert bad.exit_code == 2 and f"'{key}' sets the paper's gate" in bad.output and "dynamics, order" in bad.output
    with pytest.raises(ValueError, match=f"akf_options: \\['{key}'\\] set the paper's gate"):
        make_bank(2, akf_options={key: 1.0})


def test_a_state_file_made_with_gate_options_still_resumes(tmp_path):
    """A state saved when gate options were taken (without effect) resumes, without them, to the same numbers."""
    from kalmix.streaming import StreamConfig, TrackPredictor

    rng = np.random.default_rng(0)
    z = np.cumsum(rng.normal(size=(40, 2)), axis=0)
    config = dict(length_unit=0.5, n_experts=4, bank="mixed")
    whole = TrackPredictor(StreamConfig(**config))
    expected = [whole.step_row("a", float(t), z[t]).next for t in range(40)]
    first = TrackPredictor(StreamConfig(**config))
    for t in range(20):
        first.step_row("a", float(t), z[t])
    first.config.options = {"gating": "paper", "temperature": 4.0}   # as such a file was written
    first.save(tmp_path / "old.npz")
    resumed = TrackPredictor.load(tmp_path / "old.npz")
    assert resumed.config.options == {}
    got = [resumed.step_row("a", float(t), z[t]).next for t in range(20, 40)]
    np.testing.assert_array_equal(got, expected[20:])


def test_a_gap_rule_that_cuts_tracks_into_pieces_says_what_to_do(cli, tmp_path):
    """On a track sampled in bursts (steps of 0.1 s, every 12th a pause of 2 s) the default gap rule splits 8 % of
    the rows, and the rows before those splits get intervals holding fewer of the measurements. Such a run says so,
    and what to use instead; a regular track, --max-gap none, or a track sampled at heavy-tailed intervals
    (log-normal steps, sigma 2: the rule's spread keeps it in few segments; bursts with a pause every 8th step,
    whose top tenth of steps are the pauses: the gap floor keeps them) says nothing."""
    rng = np.random.default_rng(7)
    steps = np.where(np.arange(400) % 12 == 11, 2.0, 0.1)
    t = np.cumsum(steps)
    bursts = pd.DataFrame({"track_id": "a", "time": t, "x": t + rng.normal(0, 0.05, 400), "y": 0.0})
    regular = bursts.assign(time=np.arange(400) * 0.1)
    heavy = bursts.assign(time=np.cumsum(0.1 * rng.lognormal(0.0, 2.0, 400) + 0.01))
    eighth = bursts.assign(time=np.cumsum(np.where(np.arange(400) % 8 == 7, 2.0, 0.1)))
    for frame, args, noted in ((bursts, [], True), (bursts, ["--max-gap", "none"], False), (regular, [], False),
                               (heavy, [], False), (eighth, [], False)):
        path = str(tmp_path / "in.csv")
        frame.to_csv(path, index=False)
        result = _run(cli, ["predict", path, *FAST, "--length-unit", "0.05", *args])
        assert result.exit_code == 0, result.output
        said = "the gap rule (--max-gap auto: 3 x each track's reference interval) started a new segment at" \
            in result.stderr
        assert said == noted, (args, result.stderr)
        if noted:
            splits = int(_read(result.stdout)["segment"].max())
            assert f"at {splits} of 400 rows" in result.stderr and "--max-gap none --reach 8" in result.stderr


def test_csv_output_round_trips_every_value_and_quotes_what_needs_it():
    """The Arrow writer: floats round-trip exactly, integral floats keep their ".0" (read back as floats, not
    integers), NaN is an empty field; ids or names with a comma, a quote or a line end are quoted (pandas)."""
    from kalmix.commands._output import csv_text

    values = [1.0, 0.1, 1e-7, np.nan, 1e20, -0.0, 123456789.12345679, 2.5e-310, 1.7e9, 1e15, -3.0]
    frame = pd.DataFrame({"track_id": [f"t{i}" for i in range(len(values))], "time": values,
                          "segment": np.arange(len(values)),
                          "pred_x": np.random.default_rng(0).normal(size=len(values))})
    text = csv_text(frame, header=True)
    assert text.splitlines()[0] == "track_id,time,segment,pred_x" and ",1.0," in text and ",-3.0," in text
    back = pd.read_csv(io.StringIO(text), dtype={"track_id": str})
    pd.testing.assert_frame_equal(back, frame, check_exact=True)
    assert np.signbit(back["time"][5])
    assert csv_text(frame.iloc[:2], header=False).count("\n") == 2
    odd = frame.assign(track_id=['a,b', 'say "hi"', 'two\nlines'] + list(frame["track_id"][3:]))
    back = pd.read_csv(io.StringIO(csv_text(odd, header=True)), dtype={"track_id": str})
    pd.testing.assert_frame_equal(back, odd, check_exact=True)


def test_jsonl_output_is_each_record_as_json_dumps_writes_it():
    """Column by column, the text of json.dumps on each record (NaN/inf null, floats round-tripping, numpy
    numbers and bools as JSON's, escaped text); dates and bytes (Parquet ids) as ISO text and UTF-8."""
    from kalmix.commands._output import json_value, jsonl_text

    frame = pd.DataFrame({
        "track_id": ["a", 'q"u', "é", "x\ny"], "time": [0.0, 1e300, -0.0, 5e-324], "segment": np.arange(4),
        "pred_x": [np.nan, np.inf, -np.inf, 1 / 3], "n": np.array([1, 2, 3, -4], dtype=np.int32),
        "f32": np.array([0.1, np.nan, 2, 3], dtype=np.float32), "b": [True, False, True, False],
        "o": [None, 1, 2.5, "s"], "s": pd.array(["x", pd.NA, "y", "z"], dtype="string"),
        "d": pd.to_datetime(["2020-01-01 00:00:00", None, "2020-01-02 03:04:05", "2021-06-01 00:00:00"]),
        "bytes": [b"ab", b"\xff", b"", b"c"]})
    expected = "".join(json.dumps({k: json_value(v) for k, v in record.items()}) + "\n"
                       for record in frame.to_dict(orient="records"))
    assert jsonl_text(frame) == expected
    rows = [json.loads(line) for line in expected.splitlines()]
    assert rows[0]["pred_x"] is None and rows[2]["time"] == 0.0 and rows[3]["time"] == 5e-324
    assert [r["d"] for r in rows] == ["2020-01-01T00:00:00", None, "2020-01-02T03:04:05", "2021-06-01T00:00:00"]
    assert rows[1]["bytes"] == "\\xff" and rows[0]["b"] is True and rows[3]["n"] == -4
    odd = [pd.DataFrame({"a": pd.array([1, None, 2**62], dtype="Int64"), "b": [1.0, 2.0, 3.0]}),
           pd.DataFrame({"a": np.array([1.0, 2.0, np.inf], dtype=np.longdouble)}),
           pd.DataFrame({"a": np.array([np.datetime64("2020-01-01"), np.datetime64("NaT"), 1], dtype=object)}),
           pd.DataFrame({True: [1.0], None: [2.0], 1.5: [3.0]}), pd.DataFrame(index=range(3)),
           pd.DataFrame({"d": [decimal.Decimal("1.50"), decimal.Decimal("2")], "t": pd.to_timedelta([1, 2], unit="s"),
                         "c": pd.Categorical([1, None])})]
    for other in odd:
        assert jsonl_text(other) == "".join(json.dumps({k: json_value(v) for k, v in record.items()}) + "\n"
                                            for record in other.to_dict(orient="records"))
    assert jsonl_text(odd[0]).splitlines()[2] == '{"a": 4611686018427387904, "b": 3.0}'


@pytest.mark.parametrize("header, option", [("id,segment,x,y", ["--time", "segment"]),
                                            ("segment,t,x,y", ["--id", "segment"]),
                                            ("pred_x,t,x,y", ["--id", "pred_x"]),
                                            ("std3_y,t,x,y", ["--id", "std3_y"]),
                                            ("row,x,y", ["--id", "row"])])
def test_an_input_column_named_like_an_output_column_is_refused(cli, tmp_path, header, option):
    """The id and time columns are kept in the output: one named like a column the predictions add (or like
    the row number without a time column) would write two columns of one name."""
    path = tmp_path / "in.csv"
    path.write_text(header + "\n" + "\n".join(",".join(["1"] * len(header.split(","))) for _ in range(3)) + "\n")
    result = _run(cli, ["predict", str(path), *FAST, *option, "-o", str(tmp_path / "out.jsonl")])
    assert result.exit_code == 1, result.output
    assert ("the name of a column the predictions add" in result.output
            or "the name the output gives the row number" in result.output), result.output
    assert not (tmp_path / "out.jsonl").exists()


def test_jsonl_output_of_a_parquet_file_with_date_ids(cli, tmp_path):
    data = _tracks(n_tracks=2).assign(object_id=lambda f: pd.to_datetime("2020-01-01") + pd.to_timedelta(
        f["object_id"] - 100, unit="D"))
    data.to_parquet(tmp_path / "in.parquet")
    result = _run(cli, ["predict", str(tmp_path / "in.parquet"), *FAST, "-o", str(tmp_path / "out.jsonl")])
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in open(tmp_path / "out.jsonl")]
    assert len(rows) == len(data) and {r["object_id"] for r in rows} == {"2020-01-01T00:00:00", "2020-01-02T00:00:00"}


@pytest.mark.parametrize("frame", [
    pd.DataFrame({"a": [1.5, np.nan, 2.5]}),                                             # one column: a blank line
    pd.DataFrame({"a": np.array([1.0, 2.0], dtype=object), "b": ["p", "q"]}),            # floats as objects
    pd.DataFrame({"track_id": pd.to_datetime(["2020-01-01", "2020-01-02"]), "x": [1.0, 2.0]}),  # Parquet ids
    pd.DataFrame({"a": np.array([0.1, 0.2], dtype=np.float16), "b": [1.0, 2.0]}),
    pd.DataFrame({"a": np.array([2**70, 1], dtype=object), "b": [1.0, 2.0]}),
    pd.DataFrame({"a": pd.array(["x", pd.NA], dtype="string"), "b": [1.0, np.nan]}),
])
def test_csv_output_reads_back_as_pandas_own_for_any_column_type(frame):
    """Columns Arrow would write otherwise (dates, objects, float16, a lone column) go through pandas (bytes are
    their UTF-8 text: test_input_forms)."""
    from kalmix.commands._output import csv_text

    ours = pd.read_csv(io.StringIO(csv_text(frame, header=True)))
    pd.testing.assert_frame_equal(ours, pd.read_csv(io.StringIO(frame.to_csv(index=False))), check_exact=True)


def test_iso_8601_times_are_seconds_since_1970_in_files_on_stdin_and_as_parquet_datetimes(cli, tmp_path):
    """A CSV time column of ISO 8601 date-times (AIS, ADS-B logs) was refused ("must hold finite numbers") while
    the same times as a Parquet datetime column worked: now both are seconds since 1970 UTC, text without an
    offset read as UTC, and a CSV file, the same CSV on stdin and the Parquet file give the same times and the
    same lead forecasts (a definition the file and stdin share). Each output gives the times back as its input
    gave them: the CSV's text, the Parquet file's timestamps."""
    table = _tracks(n_tracks=2, n=30, gap=False)
    stamps = pd.Timestamp("2024-05-01T12:00:00Z") + pd.to_timedelta(table["t"], unit="s")
    text = table.assign(t=stamps.dt.strftime("%Y-%m-%dT%H:%M:%S.%f") + np.where(table.index % 2, "Z", "+00:00"))
    text.to_csv(tmp_path / "iso.csv", index=False)
    table.assign(t=stamps).to_parquet(tmp_path / "dt.parquet", index=False)
    args = [*FAST, "--time-unit", "0.04", "--lead", "0.1"]
    file = _read(_run(cli, ["predict", str(tmp_path / "iso.csv"), *args]).stdout)
    piped = _read(_run(cli, ["predict", "-", *args], input=(tmp_path / "iso.csv").read_text()).stdout)
    parquet = _read(_run(cli, ["predict", str(tmp_path / "dt.parquet"), *args]).stdout)
    assert file["t"].tolist() == piped["t"].tolist() == text["t"].tolist()
    assert (pd.to_datetime(parquet["t"]) == stamps).all()
    assert np.isfinite(file[["lead_px", "lead_py"]].to_numpy()).sum() > 100
    for other in (piped, parquet):
        np.testing.assert_array_equal(other[["lead_px", "lead_py"]], file[["lead_px", "lead_py"]])
    bad = text.copy()
    bad.loc[3, "t"] = "yesterday"
    bad.to_csv(tmp_path / "bad.csv", index=False)
    result = _run(cli, ["predict", str(tmp_path / "bad.csv"), *FAST, "--on-bad-row", "fail"])
    assert result.exit_code == 1 and "line 5: column 't' must hold a number or an ISO 8601" in result.stderr \
        and "'yesterday'" in result.stderr
    piped_bad = _run(cli, ["predict", "-", *FAST, "--on-bad-row", "fail"], input=(tmp_path / "bad.csv").read_text())
    assert piped_bad.exit_code == 1 and "line 5: column 't' must hold a number or an ISO 8601" in piped_bad.stderr
    assert len(_read(piped_bad.stdout)) == 3                     # the rows before it are written
    for given in (["predict", str(tmp_path / "bad.csv")], ["predict", "-"]):   # by default: skipped, in its place
        skipped = _run(cli, [*given, *FAST], input=(tmp_path / "bad.csv").read_text())
        assert skipped.exit_code == 0 and "1 bad row(s) skipped (line 5: column 't'" in skipped.stderr
        out = _read(skipped.stdout)
        assert len(out) == len(bad) and out["segment"].isna().tolist() == [k == 3 for k in range(len(bad))]


@pytest.mark.parametrize("chunk_rows", ["200000", "7"])
def test_a_files_time_unit_is_its_first_chunks_median_step_and_stdin_takes_the_first_step(cli, tmp_path, chunk_rows):
    """Without --time-unit, a file's unit is the median time step of its first chunk (its tracks' steps of 1.0,
    0.3 and 0.7: 0.7), learned before any row is stepped; stdin cannot look ahead and takes the first step to
    arrive (track 101's 0.3). Given the unit, the file and stdin give the same bits."""
    rng = np.random.default_rng(4)
    rows = []
    for track, start, step in ((100, 0.0, 1.0), (101, 0.1, 0.3), (102, 0.2, 0.7)):
        t = start + step * np.arange(30)
        xy = np.cumsum(rng.normal(size=(30, 2)), 0) * 0.01
        rows += [(track, round(t[i], 6), *xy[i]) for i in range(30)]
    feed = pd.DataFrame(rows, columns=["object_id", "t", "px", "py"]).sort_values("t", kind="stable")
    first = feed.iloc[:int(chunk_rows)]
    steps = np.concatenate([np.diff(g.to_numpy()) for _, g in first.groupby("object_id")["t"]])
    path = _write_csv(feed, tmp_path / "in.csv")
    args = [*FAST, "--lead", "0.5", "--state"]
    file = _run(cli, ["predict", path, "--chunk-rows", chunk_rows, *args, str(tmp_path / "f.npz")])
    piped = _run(cli, ["predict", "-", *args, str(tmp_path / "s.npz")], input=feed.to_csv(index=False))
    assert file.exit_code == 0 and piped.exit_code == 0, file.output + piped.output
    units = [_saved_time_unit(tmp_path / name) for name in ("f.npz", "s.npz")]
    assert units == [pytest.approx(np.median(steps), rel=1e-11), pytest.approx(0.3, rel=1e-11)]
    if chunk_rows == "200000":
        assert units[0] == pytest.approx(0.7, rel=1e-11)
    given = [*args[:-1], "--time-unit", "0.7"]
    file = _sorted(_read(_run(cli, ["predict", path, "--chunk-rows", chunk_rows, *given]).stdout))
    piped = _sorted(_read(_run(cli, ["predict", "-", *given], input=feed.to_csv(index=False)).stdout))
    lead = ["lead_px", "lead_py", "lead_std_px", "lead_std_py"]
    assert np.isfinite(file[lead].to_numpy()).sum() > 300
    np.testing.assert_array_equal(piped[["object_id", "t", "segment", *lead]],
                                  file[["object_id", "t", "segment", *lead]])


@pytest.mark.parametrize("bank", ["akf", "mixed"])
def test_a_restart_before_any_step_runs_with_the_files_time_unit(cli, tmp_path, bank):
    """With an absolute --max-gap a track's second row can restart it before any kept step. A file fixes the
    time unit (the median step, 0.3 here) before stepping any row, so that row runs with it too: the numbers
    of a stream given that unit. (A stream without it steps that row before it knows the unit.)"""
    text = "id,t,x,y\n0,0,-0.96,6.43\n0,10,-0.07,3.43\n0,10.3,-1.26,0.95\n0,10.6,-1.0,0.5\n1,10.9,2.0,1.0\n"
    path = tmp_path / "gap.csv"
    path.write_text(text)
    args = ["--bank", bank, "--lead", "0.5", "--max-gap", "3", "--length-unit", "1", "--reach", "none", "--no-progress"]
    file = _read(_run(cli, ["predict", str(path), *args]).stdout)
    piped = _read(_run(cli, ["predict", "-", *args, "--time-unit", "0.3"], input=text).stdout)
    lead = ["segment", "lead_x", "lead_y", "lead_std_x", "lead_std_y"]
    assert np.isfinite(file["lead_std_x"]).sum() >= 3
    np.testing.assert_array_equal(_by_id(piped)[lead], _by_id(file)[lead])


def _by_id(frame):
    return frame.sort_values(["id", "t"], kind="stable").reset_index(drop=True)


def _saved_time_unit(path):
    from kalmix.streaming import TrackPredictor

    return TrackPredictor.load(path).config.time_unit


@pytest.mark.parametrize("name, message", [("t.jsonl", "got the JSON-lines file"), ("t.tsv", "got the tab-separated")])
def test_a_file_input_of_another_format_is_refused_by_name(cli, tmp_path, name, message):
    """A .jsonl or .tsv INPUT was read as CSV: an error listing garbage 'columns'."""
    path = tmp_path / name
    path.write_text("track_id\ttime\tx\ty\na\t0\t1\t2\n")
    for command in ("predict", "evaluate"):
        result = _run(cli, [command, str(path)])
        assert result.exit_code == 1 and message in result.stderr, result.output


def test_iso_times_outside_the_clock_or_mixed_with_numbers_are_named(cli, tmp_path):
    """From a review: a date outside the nanosecond clock (1600, a 9999 sentinel) stopped stdin without a line
    and lost the rows before it, and a file named a valid row; 'now' was read as the clock's time; a column of
    numbers and dates was refused naming a valid date (or taken, on stdin); NaT was missing in a file and an
    error on stdin; a minute of one digit was read as another time."""
    rows = "id,time,x\na,2024-05-01T00:00:00Z,1\na,2024-05-01T00:00:01Z,2\na,{},3\n"
    for value, message in (
            ("1600-01-01T00:00:02Z", "line 4: column 'time' must hold a number or an ISO 8601 date-time (like "
                                     "2024-05-01T12:00:00.5Z), got '1600-01-01T00:00:02Z'"),
            ("now", "line 4: column 'time' must hold a number or an ISO 8601 date-time (like 2024-05-01T12:00:00.5Z), "
                    "got 'now'"),
            # a cut minute (a new user's "08:5" of 08:50) was read as 08:05, 45 minutes back in its track
            ("2024-05-01T00:0", "line 4: column 'time' must hold a number or an ISO 8601 date-time (like "
                                "2024-05-01T12:00:00.5Z), got '2024-05-01T00:0'"),
            ("1714521602.5", "line 4: column 'time' holds a number ('1714521602.5') where its first time is a "
                             "date-time; expected one or the other")):
        path = tmp_path / "t.csv"
        path.write_text(rows.format(value))
        result = _run(cli, ["predict", str(path), "--length-unit", "1", "--on-bad-row", "fail"])
        assert result.exit_code == 1 and message in result.stderr, result.stderr
        piped = _run(cli, ["predict", "-", "--length-unit", "1", "--on-bad-row", "fail"], input=rows.format(value))
        assert piped.exit_code == 1 and message in piped.stderr, piped.stderr
        assert len(_read(piped.stdout)) == 2                      # the rows before it are written
        for given in (["predict", str(path)], ["predict", "-"]):   # by default: the same words, the row skipped
            skipped = _run(cli, [*given, "--length-unit", "1"], input=rows.format(value))
            assert skipped.exit_code == 0 and message.replace("line 4: ", "(line 4: ") in skipped.stderr
            assert _read(skipped.stdout)["segment"].isna().tolist() == [False, False, True]
    path.write_text(rows.format("NaT"))
    out = _read(_run(cli, ["predict", str(path), "--length-unit", "1"]).stdout)
    assert len(out) == 3 and out["pred_x"].isna().tolist() == [False, False, True]   # the row as given, unpredicted
    piped = _run(cli, ["predict", "-", "--length-unit", "1"], input=rows.format("NaT"))
    assert piped.exit_code == 0 and "line 4: no time, row skipped" in piped.stderr


@pytest.mark.parametrize("fmt", ["csv", "jsonl"])
def test_a_run_that_fails_before_its_first_row_leaves_the_output_as_it_was(cli, tmp_path, fmt):
    """A bad first chunk: a new -o file is not left behind empty, an existing one keeps its content (with and
    without --state); a run that succeeds replaces it whole."""
    bad = tmp_path / "bad.csv"
    bad.write_text("t,px,py\n0,1,1\n1,abc,1\n2,3,1\n")
    new, old = tmp_path / f"new.{fmt}", tmp_path / f"old.{fmt}"
    old.write_text("earlier results\n")
    for extra in ([], ["--state", str(tmp_path / "s.npz")]):
        for out in (new, old):
            result = CliRunner().invoke(cli, ["predict", str(bad), "-o", str(out), *FAST, *extra,
                                              "--on-bad-row", "fail"])
            assert result.exit_code != 0 and "must hold a number" in str(result.output) + str(result.exception)
        assert not new.exists()
        assert old.read_text() == "earlier results\n"
    good = tmp_path / "good.csv"
    _write_csv(_tracks(n_tracks=1, n=20), good)
    assert _run(cli, ["predict", str(good), "-o", str(old), *FAST]).exit_code == 0
    text = old.read_text()
    assert "earlier results" not in text and len(text.splitlines()) == 20 + (fmt == "csv")


def test_position_repeated_is_the_comma_list(cli, tmp_path):
    """--position a --position c is --position a,c (it used to keep only the last one, silently)."""
    path = tmp_path / "abc.csv"
    path.write_text("time,a,b,c\n0,1,2,3\n1,2,3,4\n2,3,4,5\n")
    repeated = _run(cli, ["predict", str(path), "--position", "a", "--position", "c", *FAST])
    listed = _run(cli, ["predict", str(path), "--position", "a,c", *FAST])
    assert repeated.exit_code == listed.exit_code == 0
    assert repeated.stdout == listed.stdout and repeated.stdout.startswith("time,segment,pred_a,pred_c,")


def test_a_file_in_several_chunks_counts_its_dropped_rows_once(cli, tmp_path):
    """The first pass over a file of several chunks (the next rows' times) reads each chunk too; the rows
    reading drops (here repeated timestamps) are counted once, by the pass that steps them, and said once, at
    the end, on an error line with the total."""
    rows = ["track_id,time,x,y"] + [f"{track},{i // 2 if i < 4 else i},{0.1 * i},{0.2 * i}"
                                    for track in range(2) for i in range(30)]
    path = tmp_path / "dup.csv"
    path.write_text("\n".join(rows) + "\n")
    result = _run(cli, ["predict", str(path), "--chunk-rows", "20", *FAST])
    assert result.exit_code == 0
    assert result.stderr.count("repeat a timestamp") == 1   # (two of the 3 chunks have repeats)
    assert "kalmix: warning: 4 row(s) repeat a timestamp" in result.stderr
