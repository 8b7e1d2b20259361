"""One bad row never ends a run (issue 41, point 7): each finding of a hostile pass, as a repro.

A bad row (a field count not the header's, an empty id, a time or position that is not a finite number, a
stdin line that does not parse) is skipped, keeps its place in the output with empty predictions, and is
counted on an error line at the end with its line; ``--on-bad-row fail`` stops at it; ``--rejects`` lists it.
"""

import io
import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pandas as pd
import pytest

from kalmix.io.tables import BadRowWarning, DroppedRowWarning, iter_track_chunks, read_tracks
from kalmix.streaming import SkippedRowWarning, StreamConfig, TrackPredictor
from cli_helpers import invoke as _run

FAST = ["--experts", "2", "--seed", "1", "--no-progress", "--length-unit", "0.5"]


def _lines(n=600):
    """A header and ``n`` rows of two tracks, a and b, 0.1 apart."""
    rng = np.random.default_rng(0)
    xy = np.cumsum(rng.normal(size=(n, 2)), axis=0)
    half = n // 2
    return ["track_id,time,x,y"] + [f"{'ab'[i // half]},{0.1 * (i % half):.1f},{xy[i, 0]:.4f},{xy[i, 1]:.4f}"
                                    for i in range(n)]


def _write(path, lines):
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _with(lines, line, text):
    """``lines`` with file line ``line`` (counted from 1, the header's) replaced by ``text``."""
    out = list(lines)
    out[line - 1] = text
    return out


def _read(text):
    import io

    return pd.read_csv(io.StringIO(text), dtype={"track_id": str, "time": str})


# ---------------------------------------------------------------------------------------- files
@pytest.mark.parametrize("cell, said", [("inf", "be finite, got inf"), ("abc", "hold a number, got 'abc'"),
                                        ("-Infinity", "be finite, got -inf")])
@pytest.mark.parametrize("chunk_rows", ["200000", "100"])
def test_one_bad_cell_near_the_end_of_a_file_skips_that_row_only(cli, tmp_path, cell, said, chunk_rows):
    """Before: one 'inf' or 'abc' cell in row 599 of 600 ended the run with no output at all."""
    lines = _lines()
    row = lines[599].split(",")
    path = _write(tmp_path / "t.csv", _with(lines, 600, ",".join([*row[:3], cell])))
    result = _run(cli, ["predict", path, *FAST, "--chunk-rows", chunk_rows])
    assert result.exit_code == 0, result.stderr
    out = _read(result.stdout)
    assert len(out) == 600 and out["time"].tolist() == [line.split(",")[1] for line in lines[1:]]
    assert out["segment"].isna().tolist() == [i == 598 for i in range(600)]   # the bad row, in its place
    assert out["pred_x"].notna().sum() == 599
    assert f"kalmix: warning: 1 bad row(s) skipped (line 600: column 'y' must {said}" in result.stderr
    good = _run(cli, ["predict", _write(tmp_path / "good.csv", lines[:-2] + lines[-1:]), *FAST])
    np.testing.assert_array_equal(_read(good.stdout)["pred_x"].to_numpy()[:598], out["pred_x"].to_numpy()[:598])


def test_a_file_none_of_whose_times_can_be_read_says_why(cli, tmp_path):
    """Every row bad (a time format not taken: ``... UTC``): the error gives the first bad row's line and reason,
    not only a count."""
    lines = ["track_id,time,x,y"] + [f"a,2024-03-01 00:00:{i:02d} UTC,{i},0" for i in range(5)]
    result = _run(cli, ["predict", _write(tmp_path / "utc.csv", lines), *FAST])
    assert result.exit_code == 1
    assert "has no row to read (5 bad row(s) skipped; the first, line 2: column 'time' must hold a number or an " \
           "ISO 8601 date-time" in result.stderr and "got '2024-03-01 00:00:00 UTC'" in result.stderr


def test_a_file_of_bad_rows_fails_without_leaving_an_output_file(cli, tmp_path):
    """Every position unreadable: the error names the bad rows (not the times, which are fine), and the ``-o`` file
    the run created holds no prediction, so it is removed rather than left as if the run had written something."""
    lines = ["time,x,y"] + [f"{i},{i},{'north' if i % 2 else 'south'}" for i in range(4)]
    out = tmp_path / "out.csv"
    result = _run(cli, ["predict", _write(tmp_path / "texty.csv", lines), *FAST, "-o", str(out)])
    assert result.exit_code == 1
    assert "has no row to read (4 bad row(s) skipped; the first, line 2: column 'y' must hold a number, got " \
           "'south')" in result.stderr
    assert not out.exists()


@pytest.mark.parametrize("fmt", ["csv", "jsonl", "parquet"])
def test_a_file_of_bad_rows_leaves_an_earlier_output_as_it_was(cli, tmp_path, fmt):
    """The output rows of a file without a row to step are held back until one comes: a file that has none fails
    with the -o file it names as it was (an old one unchanged: it was cut to the bad rows' empty predictions; a new
    Parquet file not made: it was left holding them)."""
    bad = _write(tmp_path / "bad.csv", ["id,t,x,y", "1,0,a,b", "1,1,c,d"])
    fresh, old = tmp_path / f"fresh.{fmt}", tmp_path / f"old.{fmt}"
    assert _run(cli, ["predict", _write(tmp_path / "good.csv", _lines(40)), *FAST, "-o", str(old)]).exit_code == 0
    before = old.read_bytes()
    for out in (fresh, old):
        result = _run(cli, ["predict", bad, *FAST, "-o", str(out)])
        assert result.exit_code == 1 and "has no row to read" in result.stderr
    assert not fresh.exists() and old.read_bytes() == before


def test_a_resumed_run_leaves_out_the_bad_rows_its_first_run_wrote(cli, tmp_path):
    """Bad rows at a file's head, in chunks of their own: a resumed run of the same file wrote them again (and
    listed them again in --rejects), as if they were its own; they share the fate of the first row after them."""
    rows = ["id,t,x,y", "1,abc,0,0", "1,,1,0", "1,NA,2,0"] + [f"1,{k},{k},{0.1 * k}" for k in range(3, 24)]
    path = _write(tmp_path / "t.csv", rows)
    out, state, rejects = tmp_path / "out.csv", str(tmp_path / "s.npz"), tmp_path / "rejects.csv"
    args = ["predict", path, *FAST, "--chunk-rows", "3", "-o", str(out), "--state", state, "--rejects", str(rejects)]
    assert _run(cli, args).exit_code == 0
    written, listed = out.read_bytes(), rejects.read_bytes()
    assert len(written.splitlines()) == len(rows)
    again = _run(cli, args)   # nothing left to do
    assert again.exit_code == 0 and out.read_bytes() == written and rejects.read_bytes() == listed
    assert "have no time" not in again.stderr and "bad row" not in again.stderr   # nor counted again
    whole = tmp_path / "whole.csv"
    half = _write(tmp_path / "half.csv", rows[:13])
    assert _run(cli, ["predict", half, *FAST, "--chunk-rows", "3", "-o", str(whole), "--state", str(tmp_path / "h.npz")]
                ).exit_code == 0
    assert _run(cli, ["predict", path, *FAST, "--chunk-rows", "3", "-o", str(whole), "--state", str(tmp_path / "h.npz")]
                ).exit_code == 0
    assert whole.read_bytes() == written


@pytest.mark.parametrize("name", ["rejects.parquet", "rejects.jsonl", "rejects.csv.gz"])
def test_rejects_of_another_format_are_refused(cli, tmp_path, name):
    """--rejects writes CSV: a name of another format (it got CSV under that name) is refused before any work."""
    result = _run(cli, ["predict", _write(tmp_path / "t.csv", _lines(20)), *FAST, "--rejects", str(tmp_path / name)])
    assert result.exit_code == 2 and "expected a .csv file name" in result.output
    assert not (tmp_path / name).exists()


def test_a_quote_never_closed_names_the_file(cli, tmp_path):
    """A quote opened in a field and never closed takes the rest of a file into it: the error names the file and
    says so (it was pandas' bare 'Error tokenizing data'); on stdin the line is a bad row."""
    lines = ["t,x,y,note"] + [f"{k},{k},{k},ok" for k in range(9)] + ['9,9,9,"unclosed'] + [
        f"{k},{k},{k},ok" for k in range(10, 14)]
    result = _run(cli, ["predict", _write(tmp_path / "q.csv", lines), *FAST])
    assert result.exit_code == 1 and "Traceback" not in result.stderr
    assert "The track file" in result.stderr and "q.csv' cannot be read as CSV" in result.stderr
    assert "a quote opened in a field and never closed" in result.stderr


def test_on_bad_row_fail_stops_at_the_row_naming_its_line(cli, tmp_path):
    lines = _lines(40)
    path = _write(tmp_path / "t.csv", _with(lines, 30, "b,0.8,abc,1.0"))
    result = _run(cli, ["predict", path, *FAST, "--on-bad-row", "fail"])
    assert result.exit_code == 1 and "line 30: column 'x' must hold a number, got 'abc'" in result.stderr
    assert "Traceback" not in result.stderr
    refused = _run(cli, ["predict", path, *FAST, "--on-bad-row", "fail", "--rejects", str(tmp_path / "r.csv")])
    assert refused.exit_code == 2 and "--rejects" in refused.output


def test_field_counts_are_checked_in_a_file_as_on_stdin(cli, tmp_path):
    """Before: the file reader took a 6-field row silently and a 3-field row as a missing coordinate, while
    stdin refused both (and stopped)."""
    lines = _lines(40)
    lines = _with(_with(lines, 5, lines[4] + ",7"), 9, lines[8].rsplit(",", 1)[0])
    path = _write(tmp_path / "t.csv", lines)
    rejects = tmp_path / "rejects.csv"
    for given, feed in ((path, None), ("-", "\n".join(lines) + "\n")):
        result = _run(cli, ["predict", given, *FAST, "--rejects", str(rejects)], input=feed)
        assert result.exit_code == 0, result.stderr
        out = _read(result.stdout)
        assert len(out) == 40 and out["segment"].isna().tolist() == [i in (3, 7) for i in range(40)]
        assert f"2 bad row(s) skipped (lines 5, 9; see --rejects {rejects})" in result.stderr
        listed = pd.read_csv(rejects, dtype=str)
        assert listed.columns.tolist() == ["line", "reason", "input"]
        assert listed["line"].tolist() == ["5", "9"]
        assert listed["reason"].tolist() == ["expected 4 fields like the header, got 5",
                                             "expected 4 fields like the header, got 3"]
        assert listed["input"].tolist() == [lines[4], lines[8]]


def test_lines_are_the_files_own_with_blank_lines_and_quoted_line_breaks(tmp_path):
    """A bad row is named by its line in the file, counted as an editor counts, past blank lines and a quoted
    field that holds a line break."""
    text = 'id,t,x,y\n"a\nb",0,1,2\n\n"a\nb",1,2,3\n"a\nb",2,oops,4\n'
    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match="^line 7: column 'x' must hold a number, got 'oops'$"):
        read_tracks(path, ids_as_text=True)
    with pytest.warns(BadRowWarning, match=r"1 bad row\(s\) skipped \(line 7;"):
        table = read_tracks(path, ids_as_text=True, on_bad_row="skip")
    assert len(table) == 2 and table.attrs["bad_rows"].places == ["line 7"]


def test_a_parquet_file_names_the_bad_rows_by_their_index(cli, tmp_path):
    frame = pd.read_csv(_write(tmp_path / "t.csv", _lines(40)))
    frame["x"] = frame["x"].astype(str)   # (a text column of numbers, as some exports write them)
    frame.loc[7, "x"] = "n/a?"
    frame.loc[20, "y"] = np.inf
    frame.to_parquet(tmp_path / "t.parquet", index=False)
    rejects = tmp_path / "rejects.csv"
    result = _run(cli, ["predict", str(tmp_path / "t.parquet"), *FAST, "--rejects", str(rejects)])
    assert result.exit_code == 0, result.stderr
    assert "2 bad row(s) skipped (rows 7, 20, counted from 0; see --rejects" in result.stderr
    listed = pd.read_csv(rejects)
    assert listed["row"].tolist() == [7, 20] and json.loads(listed["input"][0])["x"] == "n/a?"
    strict = json.loads(listed["input"][1], parse_constant=lambda name: pytest.fail(f"not strict JSON: {name}"))
    assert strict["y"] == "inf"   # an infinite position as text (JSON has no Infinity)
    failed = _run(cli, ["predict", str(tmp_path / "t.parquet"), *FAST, "--on-bad-row", "fail"])
    assert failed.exit_code == 1 and "row 7 (counted from 0): column 'x' must hold a number, got 'n/a?'" \
        in failed.stderr


def test_a_chunk_of_bad_rows_only_keeps_its_places(cli, tmp_path):
    """A chunk whose every row is bad (here the whole first chunk) is written as empty rows, and the run goes on."""
    lines = _lines(60)
    for line in range(2, 12):
        lines[line - 1] = lines[line - 1].rsplit(",", 1)[0] + ",bad"
    result = _run(cli, ["predict", _write(tmp_path / "t.csv", lines), *FAST, "--chunk-rows", "10"])
    assert result.exit_code == 0, result.stderr
    out = _read(result.stdout)
    assert len(out) == 60 and out["segment"].isna().sum() == 10 and out["pred_x"].iloc[10:].notna().all()
    assert "10 bad row(s) skipped (lines 2, 3, 4, 5, 6, 7, 8, 9, 10, 11;" in result.stderr


@pytest.mark.parametrize("empty", [[0, 1], [2, 3]])
def test_a_parquet_chunk_whose_ids_are_all_empty_fits_the_parquet_output(cli, tmp_path, empty):
    """A Parquet file of binary ids, one chunk of two bad rows with no id (the first or a later one): the Parquet
    output keeps the ids' type in every chunk (the chunk without an id had no type, and the writer refused it
    midway, or the rest of the file after it), the rows in their places."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    ids = [None if i in empty else b"a" for i in range(6)]
    frame = pd.DataFrame({"track_id": ids, "time": np.arange(6.0), "x": np.arange(6.0), "y": np.zeros(6)})
    frame.to_parquet(tmp_path / "in.parquet", index=False)
    result = _run(cli, ["predict", str(tmp_path / "in.parquet"), *FAST, "--chunk-rows", "2", "-o",
                        str(tmp_path / "out.parquet")])
    assert result.exit_code == 0, result.output
    table = pq.read_table(tmp_path / "out.parquet")
    assert table.schema.field("track_id").type == pa.binary() and table.column("track_id").to_pylist() == ids
    assert table.column("segment").to_pylist() == [None if i in empty else 0 for i in range(6)]


def test_a_resumed_run_reports_and_rejects_a_bad_row_once(cli, tmp_path):
    """The rows an earlier run wrote are left out of a resumed run's output, its bad rows with them."""
    lines = _with(_lines(60), 11, "a,0.9,oops,1")
    state, rejects, out = str(tmp_path / "s.npz"), str(tmp_path / "r.csv"), str(tmp_path / "o.csv")
    args = [*FAST, "--state", state, "--rejects", rejects, "-o", out]
    first = _run(cli, ["predict", _write(tmp_path / "first.csv", lines[:31]), *args])
    assert first.exit_code == 0 and "1 bad row(s) skipped (line 11" in first.stderr
    second = _run(cli, ["predict", _write(tmp_path / "all.csv", lines), *args])
    assert second.exit_code == 0 and "bad row" not in second.stderr
    assert pd.read_csv(rejects)["line"].tolist() == [11]
    whole = _run(cli, ["predict", str(tmp_path / "all.csv"), *FAST])
    assert (tmp_path / "o.csv").read_text() == whole.stdout


def test_rows_dropped_for_any_reason_are_one_warning_line_with_a_count(cli, tmp_path):
    """Rows not predicted for want of a time, or as the earlier rows of a repeated time: one warning line each at
    the end, with the run's count (not one per chunk), and the run succeeds (exit 0: --on-bad-row fail stops)."""
    lines = _lines(40)
    lines = _with(_with(lines, 4, lines[2]), 8, "a,,1,2")
    result = _run(cli, ["predict", _write(tmp_path / "t.csv", lines), *FAST, "--chunk-rows", "5"])
    assert result.exit_code == 0
    assert "kalmix: warning: 1 row(s) have no time: not predicted" in result.stderr
    assert "kalmix: warning: 1 row(s) repeat a timestamp within their track" in result.stderr
    assert result.stderr.count("kalmix: warning:") == 2 and "error" not in result.stderr


# ---------------------------------------------------------------------------------------- stdin
@pytest.mark.parametrize("bad, why", [
    ("0.5,1", "expected 3 fields like the header, got 2"),
    ("0.5,1,2,3", "expected 3 fields like the header, got 4"),
    ("0.5," + "9" * 140_000 + ",1", "not a CSV row: field larger than field limit"),
    ("0.5,abc,1", "column 'x' must hold a number, got 'abc'"),
])
def test_a_bad_csv_line_does_not_end_a_live_stream(cli, bad, why):
    """Before: any one bad line ended the stream (the rows after it were never read)."""
    feed = "t,x,y\n" + "".join(f"{0.1 * k:.1f},{k},{2 * k}\n" for k in range(5)) + bad + "\n" + "".join(
        f"{0.1 * k:.1f},{k},{2 * k}\n" for k in range(6, 12))
    result = _run(cli, ["predict", "-", *FAST], input=feed)
    assert result.exit_code == 0, result.stderr
    out = _read(result.stdout)
    assert len(out) == 12 and out["segment"].isna().tolist() == [k == 5 for k in range(12)]
    assert f"line 7: bad row skipped: {why}" in result.stderr
    assert "kalmix: warning: 1 bad row(s) skipped (line 7" in result.stderr


@pytest.mark.parametrize("bad, why", [
    ({"t": 0.5, "x": 1}, "key 'y' missing"),
    ({"t": 0.5, "x": {"a": 1}, "y": 2}, "column 'x' must hold a number, got {'a': 1}"),
    ({"t": 0.5, "x": [1], "y": 2}, "column 'x' must hold a number, got [1]"),
    ("{not json", "not valid JSON"),
    ({"id": True, "t": 0.5, "x": 1, "y": 2}, "column 'id' (track id) must hold an id (text or a number), got true"),
])
def test_a_bad_json_line_does_not_end_a_live_stream(cli, tmp_path, bad, why):
    rows = [{"id": 1, "t": 0.1 * k, "x": k, "y": 2 * k} for k in range(12)]
    text = [json.dumps(row) for row in rows]
    text[5] = bad if isinstance(bad, str) else json.dumps({"id": 1, **bad})
    rejects = tmp_path / "r.csv"
    result = _run(cli, ["predict", "-", *FAST, "--rejects", str(rejects)], input="\n".join(text) + "\n")
    assert result.exit_code == 0, result.stderr
    out = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(out) == 12 and [row["segment"] is None for row in out] == [k == 5 for k in range(12)]
    assert f"line 6: bad row skipped: {why}" in result.stderr
    listed = pd.read_csv(rejects, dtype=str, keep_default_na=False)
    assert listed["line"].tolist() == ["6"] and listed["input"].tolist() == [text[5]]


def test_a_line_that_is_not_utf8_is_a_bad_row_on_a_pipe():
    feed = b"t,x,y\n0,1,2\n1,\xff\xfe,3\n2,3,4\n"
    done = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST], input=feed,
                          capture_output=True, env={**os.environ, "PYTHONIOENCODING": "utf-8"})
    assert done.returncode == 0, done.stderr.decode()
    assert len(done.stdout.decode().splitlines()) == 4 and "1 bad row(s) skipped (line 3" in done.stderr.decode()


# ---------------------------------------------------------------------------------------- columns
@pytest.mark.parametrize("empty, kept", [("z", "x, y"), ("y", "x")])
def test_an_empty_detected_position_column_is_dropped_with_a_note(cli, tmp_path, empty, kept):
    """Before: an exported all-empty z (or y) was taken as a coordinate: every prediction empty, exit 0."""
    frame = pd.read_csv(_write(tmp_path / "t.csv", _lines(60)))
    frame[empty] = np.nan
    frame.to_csv(tmp_path / "t.csv", index=False)
    result = _run(cli, ["predict", str(tmp_path / "t.csv"), *FAST])
    assert result.exit_code == 0
    assert f"the position column '{empty}' is empty in the first 60 rows: predicting {kept} only" in result.stderr
    out = _read(result.stdout)
    assert f"pred_{empty}" not in out.columns and out["pred_x"].notna().all()
    named = _run(cli, ["predict", str(tmp_path / "t.csv"), *FAST, "--position", "x,y,z" if empty == "z" else "x,y"])
    assert "every prediction is empty" in named.stderr   # named: kept, and said at the end
    piped = _run(cli, ["predict", "-", *FAST], input=(tmp_path / "t.csv").read_text())
    assert f"the position column(s) '{empty}' have been empty on each of the first 100 rows" not in piped.stderr
    long = pd.concat([frame] * 2, ignore_index=True)
    long["time"] = np.arange(len(long)) * 0.1
    piped = _run(cli, ["predict", "-", *FAST], input=long.to_csv(index=False))
    assert f"the position column(s) '{empty}' have been empty on each of the first 100 rows" in piped.stderr


# ---------------------------------------------------------------------------------------- ids
def test_ids_that_differ_only_in_how_they_are_written_are_two_tracks_and_said_so(cli, tmp_path):
    """Before: ' 0' and '0' became two interleaved half-tracks without a word (ids are read as written: kept,
    now said once); a resumed file writing '1.0' started a new track beside the state file's '1'."""
    lines = ["id,t,x,y"] + [f"{' 0' if k % 2 else '0'},{k // 2},{k},{k}" for k in range(20)]
    result = _run(cli, ["predict", _write(tmp_path / "t.csv", lines), *FAST])
    assert result.exit_code == 0
    assert result.stderr.count("track ids '0' and ' 0' differ only by the spaces around them: they are two "
                               "tracks") == 1
    state = str(tmp_path / "s.npz")
    _run(cli, ["predict", _write(tmp_path / "a.csv", ["id,t,x,y", *(f"1,{k},{k},0" for k in range(10))]), *FAST,
               "--state", state, "-o", str(tmp_path / "a_out.csv")])
    resumed = _run(cli, ["predict",
                         _write(tmp_path / "b.csv", ["id,t,x,y", *(f"1.0,{k},{k},0" for k in range(10, 20))]),
                         "--state", state, "--no-progress", "-o", str(tmp_path / "b_out.csv")])
    assert "track ids '1' and '1.0' differ only in how a number is written: they are two tracks" in resumed.stderr


def test_equal_numbers_of_two_types_are_one_track_said_once_and_a_bool_is_no_id(cli):
    """In JSON lines 1 and 1.0 are one track (as a number is one value): said once. ``true`` was track 1 (True ==
    1 as a key): on stdin now a bad row, in Python a TypeError."""
    feed = "".join(json.dumps({"id": 1.0 if k % 2 else 1, "t": k, "x": k, "y": 0}) + "\n" for k in range(6))
    result = _run(cli, ["predict", "-", *FAST], input=feed)
    assert result.exit_code == 0 and result.stderr.count("are equal numbers of two types: they continue one "
                                                         "track") == 1
    assert [json.loads(line)["segment"] for line in result.stdout.splitlines()] == [0] * 6
    predictor = TrackPredictor(StreamConfig(length_unit=1.0, n_experts=2))
    predictor.step_row(1, 0.0, [0.0, 0.0])
    with pytest.raises(TypeError, match="a bool is not one"):
        predictor.step_row(True, 1.0, [1.0, 0.0])
    with pytest.raises(TypeError, match="a bool is not one"):
        predictor.step_rows([np.True_], [1.0], [[1.0, 0.0]])


# ---------------------------------------------------------------------------------------- API
@pytest.mark.parametrize("time", [None, float("nan")])
def test_step_row_warns_of_a_row_without_a_time(time):
    """Before: a time of None or NaN was skipped without the SkippedRowWarning the documentation promises."""
    predictor = TrackPredictor(StreamConfig(length_unit=1.0, n_experts=2))
    predictor.step_row("a", 0.0, [0.0, 0.0])
    with pytest.warns(SkippedRowWarning, match=r"track 'a': a row without a time \((None|nan)\) was skipped"):
        assert predictor.step_row("a", time, [1.0, 0.0]) is None
    assert predictor.skipped == 1


def test_iter_track_chunks_skips_with_one_warning_per_chunk(tmp_path):
    lines = _with(_with(_lines(40), 3, "a,0.1,1,inf"), 30, ",0.8,1,2")
    path = _write(tmp_path / "t.csv", lines)
    with pytest.raises(ValueError, match="^line 3: column 'y' must be finite, got inf$"):
        list(iter_track_chunks(path, chunk_rows=10, ids_as_text=True))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        chunks = list(iter_track_chunks(path, chunk_rows=10, ids_as_text=True, on_bad_row="skip"))
    said = [str(w.message) for w in caught if issubclass(w.category, BadRowWarning)]
    assert said == ["1 bad row(s) skipped (line 3; the first: column 'y' must be finite, got inf)",
                    "1 bad row(s) skipped (line 30; the first: column 'track_id' (track id) is empty)"]
    assert sum(len(chunk) for chunk in chunks) == 38


# ---------------------------------------------------------------------------------------- dask
def test_dask_names_a_corrupt_file_and_reads_float32_beside_float64(tmp_path):
    pytest.importorskip("dask.dataframe")
    from kalmix.dask_predict import read_archive

    archive = tmp_path / "archive"
    archive.mkdir()
    frame = pd.read_csv(_write(tmp_path / "t.csv", _lines(40)))
    frame.iloc[:20].to_parquet(archive / "part-0.parquet", index=False)
    frame.iloc[20:].astype({"x": np.float32}).to_parquet(archive / "part-1.parquet", index=False)
    rows, _, _ = read_archive(str(archive))
    got = rows.compute(scheduler="sync")
    assert len(got) == 40 and got["x"].dtype == np.float64
    np.testing.assert_allclose(got["x"].to_numpy(), frame["x"].to_numpy(), rtol=1e-6)
    (archive / "part-2.parquet").write_bytes((archive / "part-0.parquet").read_bytes()[:200])
    with pytest.raises(ValueError, match=r"part-2.parquet' cannot be read as Parquet \(a corrupt or truncated"):
        read_archive(str(archive))
    (archive / "part-2.parquet").unlink()
    frame.iloc[20:].assign(track_id=1.0).to_parquet(archive / "part-1.parquet", index=False)
    frame.iloc[:20].assign(track_id=1).to_parquet(archive / "part-0.parquet", index=False)
    with pytest.raises(ValueError, match="an id column of integers and one of floats would split tracks"):
        read_archive(str(archive))


# ---------------------------------------------------------------------------------------- clocks
def _restarted(tmp_path):
    """Track a's clock restarts at line 52 (times 0..49, then 0..49), the target moving on; track b is regular."""
    rows = ["id,t,x,y"]
    for k in range(100):
        rows.append(f"a,{k % 50},{k * 1.0},{0.5 * k}")
        rows.append(f"b,{k},{-k * 1.0},{k * 0.25}")
    return _write(tmp_path / "reset.csv", rows)


@pytest.mark.parametrize("chunk_rows", ["200000", "45"])
def test_a_clock_that_restarts_starts_a_new_segment_instead_of_losing_half_the_track(cli, tmp_path, chunk_rows):
    """Before: times 0..49 then 0..49 were sorted together, and half the track went as repeated timestamps."""
    result = _run(cli, ["predict", _restarted(tmp_path), *FAST, "--chunk-rows", chunk_rows])
    assert result.exit_code == 0
    assert "track 'a': its time goes back from 49 to 0 at line 102 and goes on from there" in result.stderr
    assert "repeat a timestamp" not in result.stderr
    out = _read(result.stdout)
    a = out[out["id"] == "a"]
    assert len(a) == 100 and a["t"].tolist() == [k % 50 for k in range(100)]   # as given
    assert a["segment"].tolist() == [0] * 50 + [1] * 50 and a["pred_x"].notna().all()
    assert (out.loc[out["id"] == "b", "segment"] == 0).all()


def _twice(tmp_path, rows=None):
    """Track a: times 0..19, then 0..19 again (the clock restarts at line 22)."""
    lines = ["track_id,time,x,y"] + [f"a,{k % 20},{0.5 * k},{0.25 * k}" for k in range(40)]
    return _write(tmp_path / "twice.csv", lines if rows is None else lines[:1] + lines[1:][rows])


def test_a_resumed_run_goes_on_with_a_clock_that_restarted(cli, tmp_path):
    """Before: the resumed run read the new clock's times as given (10, 11, ...), before the moved times the
    state saved, and skipped every row left as already done."""
    whole = _run(cli, ["predict", _twice(tmp_path), *FAST])
    assert whole.exit_code == 0, whole.stderr
    state, out = str(tmp_path / "s.json"), str(tmp_path / "out.csv")
    for part in (slice(0, 30), slice(30, 40)):
        result = _run(cli, ["predict", _twice(tmp_path, part), *FAST, "--state", state, "-o", out])
        assert result.exit_code == 0 and "skipped" not in result.stderr, result.stderr
    assert open(out).read() == whole.stdout
    again = _run(cli, ["predict", _twice(tmp_path), *FAST, "--state", state, "-o", out])   # from the start
    assert again.exit_code == 0 and open(out).read() == whole.stdout


@pytest.mark.parametrize("chunk_rows", ["19", "20", "21"])
def test_a_clock_that_restarts_at_the_end_of_a_chunk_is_found(cli, tmp_path, chunk_rows):
    """Before: a restart in a chunk's last two rows was not found, and the run stopped (the file not sorted) or
    sorted the new clock's first rows into the old one."""
    whole = _run(cli, ["predict", _twice(tmp_path), *FAST])
    chunked = _run(cli, ["predict", _twice(tmp_path), *FAST, "--chunk-rows", chunk_rows])
    assert chunked.exit_code == 0, chunked.stderr
    assert chunked.stdout == whole.stdout


def test_a_clock_that_restarts_on_stdin_costs_one_row(cli, tmp_path):
    path = _restarted(tmp_path)
    result = _run(cli, ["predict", "-", *FAST], input=open(path).read())
    assert result.exit_code == 0
    assert "track 'a': its time goes back from 49 to 0 at line 102 (that line skipped)" in result.stderr
    out = _read(result.stdout)
    a = out[out["id"] == "a"]
    assert a["segment"].isna().tolist() == [k == 50 for k in range(100)]   # only the row that went back
    assert a["segment"].dropna().tolist() == [0] * 50 + [1] * 49
    assert "skipped 1 row(s) at or before their track's last time" in result.stderr


def test_rows_that_come_late_are_still_sorted_into_place(cli, tmp_path):
    """A block of earlier rows after later ones (halves swapped), or one late row, is disorder, not a restart."""
    swapped = ["id,t,x,y"] + [f"a,{k},{k},0" for k in range(50, 100)] + [f"a,{k},{k},0" for k in range(50)]
    late = (["id,t,x,y"] + [f"a,{k},{k},0" for k in range(30)] + ["a,5.5,5.5,0"]
            + [f"a,{k},{k},0" for k in range(30, 60)])
    for name, rows in (("swapped", swapped), ("late", late)):
        result = _run(cli, ["predict", _write(tmp_path / f"{name}.csv", rows), *FAST])
        assert result.exit_code == 0 and "goes back" not in result.stderr and "Times decrease" in result.stderr
        assert (_read(result.stdout)["segment"] == 0).all()
    twice = ["id,t,x,y"] + [f"a,{k},{k},0" for k in range(50)] * 2   # a block given twice: repeated rows
    result = _run(cli, ["predict", _write(tmp_path / "twice.csv", twice), *FAST])
    assert "goes back" not in result.stderr and "kalmix: warning: 50 row(s) repeat a timestamp" in result.stderr


def test_a_row_that_goes_back_across_a_chunk_boundary_keeps_its_place_with_empty_predictions(cli, tmp_path):
    """A track whose time repeats or goes back across a chunk boundary stopped the run ("sort the file") while the
    same file read whole was sorted: the chunks cannot be reordered, so the late rows keep their places, not
    predicted, counted on one warning line; every other row is predicted, in any --chunk-rows."""
    lines = _lines(40)   # a: lines 2-21, b: lines 22-41
    late = lines[:12] + [lines[11], lines[6]] + lines[12:]   # a's time 1.0 again, then 0.5, after line 12
    path = _write(tmp_path / "late.csv", late)
    for chunk in ("11", "12", "5"):
        result = _run(cli, ["predict", path, *FAST, "--chunk-rows", chunk])
        assert result.exit_code == 0, result.stderr
        out = pd.read_csv(io.StringIO(result.stdout))
        assert len(out) == len(late) - 1 and out["time"].tolist() == [float(x.split(",")[1]) for x in late[1:]]
        # out[10] and out[11] repeat a's time 1.0 (one of them predicted: the first across a boundary, the last
        # within a chunk), out[12] goes back to 0.5 after them: not predicted
        empty = np.flatnonzero(out["pred_x"].isna().to_numpy()).tolist()
        assert empty == ([11, 12] if chunk == "11" else [10, 12])
        late_line = "row(s) came at or before their track's last time in the rows read before them"
        assert (f"2 {late_line}" if chunk == "11" else f"1 {late_line}") in result.stderr
    with pytest.raises(ValueError, match="not after the time"):
        list(iter_track_chunks(path, chunk_rows=12))
    with pytest.warns(DroppedRowWarning, match="at or before their track's last time"):
        chunks = list(iter_track_chunks(path, chunk_rows=12, late_rows="skip"))
    assert [c.attrs["dropped"]["late"] for c in chunks] == [0, 1, 0, 0]
    assert sum(map(len, chunks)) == len(late) - 1 - 2


def _cp1252_tracks(first="Jos\xe9", second="b"):
    """Text of two tracks whose ids are ``first`` and ``second``, with a column not used ("note") that holds an
    accented word: to be written in Windows-1252, as a Windows export."""
    return "track_id,time,x,y,note\n" + "".join(f"{i},{k},{k * 0.5 + o},{k * 0.1},caf\xe9\n" for k in range(10)
                                                for i, o in (("a", 0), (first, 100)))


def test_a_csv_file_not_in_utf8_names_its_line_and_how_to_convert_it(cli, tmp_path):
    """Before: "Error: 'utf-8' codec can't decode byte 0xe9 in position 3: unexpected end of data", naming
    neither the file, nor the line, nor what to do. Bytes that are not UTF-8 in a column not used were read and
    still are (pandas reads only the columns used), as on stdin."""
    path = tmp_path / "export.csv"
    path.write_bytes(_cp1252_tracks().encode("cp1252"))
    said = (f"The track file {str(path)!r} is not UTF-8 text: line 3: column 'track_id' holds bytes that are not "
            f"UTF-8, b'Jos\\xe9' ('José' if they are Windows-1252). Convert it to UTF-8 first: iconv -f cp1252 -t "
            f"utf-8 {path} > {tmp_path / 'export-utf8.csv'}")
    for args in (["predict", str(path), *FAST], ["predict", str(path), *FAST, "--chunk-rows", "4"],
                 ["evaluate", str(path), "--no-peers"]):
        result = _run(cli, args)
        assert result.exit_code == 1 and said in result.stderr, result.stderr
    with pytest.raises(ValueError, match="line 3: column 'track_id' holds bytes that are not UTF-8"):
        read_tracks(path)
    header = tmp_path / "header.csv"
    header.write_bytes("track_id,time,x,y,caf\xe9\na,0,1,2,3\n".encode("cp1252"))
    result = _run(cli, ["predict", str(header), *FAST])
    assert result.exit_code == 1 and "is not UTF-8 text: line 1: the header holds bytes that are not UTF-8, " \
                                      "b'caf\\xe9'" in result.stderr
    path.write_bytes(_cp1252_tracks(first="b").encode("cp1252"))   # only the unused column: predicted
    result = _run(cli, ["predict", str(path), *FAST])
    assert result.exit_code == 0 and "bad row" not in result.stderr
    assert _read(result.stdout)["segment"].notna().all()
    piped = _run(cli, ["predict", "-", *FAST], input=path.read_bytes())
    assert piped.exit_code == 0 and piped.stdout == result.stdout and "bad row" not in piped.stderr


def test_bytes_not_utf8_on_stdin_make_bad_rows_and_valid_output(cli, tmp_path):
    """Before: under a C.UTF-8 locale (stdin's errors 'surrogateescape') the bytes came back raw in the output, the
    rows not bad; -o out.csv crashed ("surrogates not allowed") and JSON lines out held lone surrogates
    ("Jos\\udce9") that strict parsers refuse. As docs/your-data.md says, a row whose id, time or position
    holds bytes that are not UTF-8 is a bad row, whatever the locale; a column not used may hold them."""
    feed = _cp1252_tracks().encode("cp1252")
    out, rejects = tmp_path / "out.csv", tmp_path / "rejects.csv"
    result = _run(cli, ["predict", "-", *FAST, "-o", str(out), "--rejects", str(rejects)], input=feed)
    assert result.exit_code == 0, result.stderr
    assert ("line 3: bad row skipped: column 'track_id' holds bytes that are not UTF-8, b'Jos\\xe9' ('José' if "
            "they are Windows-1252); convert the input to UTF-8 first (... | iconv -f cp1252 -t utf-8 | kalmix "
            "predict -)") in result.stderr
    predicted = pd.read_csv(out, dtype={"track_id": str}, encoding="utf-8")
    assert len(predicted) == 20 and predicted["segment"].isna().tolist() == [k % 2 == 1 for k in range(20)]
    assert predicted["track_id"].isna().tolist() == [k % 2 == 1 for k in range(20)]
    listed = pd.read_csv(rejects, dtype=str, encoding="utf-8")
    assert listed["line"].tolist()[:2] == ["3", "5"] and listed["input"][0] == "Jos\\xe9,0,100.0,0.0,caf\\xe9"
    lines = "".join(json.dumps({"id": i, "t": k, "x": k + o, "y": 0, "name": "caf\xe9"}, ensure_ascii=False) + "\n"
                    for k in range(6) for i, o in (("Jos\xe9", 0), ("b", 100))).encode("cp1252")
    result = _run(cli, ["predict", "-", *FAST], input=lines)
    assert result.exit_code == 0 and "\\udc" not in result.stdout and result.stdout.isascii()
    rows = [json.loads(line) for line in result.stdout.splitlines()]
    assert [row["id"] for row in rows] == [None, "b"] * 6 and [row["segment"] is None for row in rows] == [True,
                                                                                                          False] * 6
    # a real pipe, under a locale whose stdin keeps such bytes as surrogates
    done = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "-", *FAST, "-o", str(out)], input=feed,
                          capture_output=True, env={**os.environ, "PYTHONIOENCODING": "utf-8:surrogateescape"})
    assert done.returncode == 0, done.stderr.decode()
    assert out.read_bytes().decode("utf-8") and "10 bad row(s) skipped (lines 3, 5," in done.stderr.decode()


def test_a_quoted_field_that_holds_a_line_break_is_one_row_on_stdin(cli, tmp_path):
    """Before: on stdin each line was a row, so a quoted note over two lines gave an extra ',,,,,,' output row and
    'line 4: bad row skipped: expected 5 fields like the header, got 2'; a file read it as one record. Now one
    output row per record (RFC 4180), named by its first line, as in a file."""
    text = 'track_id,time,x,y,note\nA,0,0,0,"ok"\nA,1,1,0,"multi\nline, note"\nA,2,2,0.01,x\nA,3,3,0,""""\n'
    path = tmp_path / "notes.csv"
    path.write_text(text)
    piped = _run(cli, ["predict", "-", *FAST], input=text)
    filed = _run(cli, ["predict", str(path), *FAST])
    assert piped.exit_code == 0 and "bad row" not in piped.stderr, piped.stderr
    assert piped.stdout == filed.stdout and len(_read(piped.stdout)) == 4
    text = 'id,t,x,y\n"a\nb",0,1,2\n\n"a\nb",1,2,3\n"a\nb",2,oops,4\n'   # (the file's test above)
    piped = _run(cli, ["predict", "-", *FAST], input=text)
    assert piped.exit_code == 0 and "line 7: bad row skipped: column 'x' must hold a number, got 'oops'" \
        in piped.stderr
    assert _read(piped.stdout)["id"].tolist() == ["a\nb"] * 3
    text = 'track_id,time,x,y,note\nA,0,0,0,ok\nA,1,1,0,"never closed\nA,2,2,0,x\nA,3,3,0,x\n'
    piped = _run(cli, ["predict", "-", *FAST], input=text)
    assert piped.exit_code == 0 and "line 3: bad row skipped: a quoted field is not closed" in piped.stderr
    assert len(_read(piped.stdout)) == 2


@pytest.mark.parametrize("text, open_", [
    ('a,1,2\n', False), ('a,"1,2"\n', False), ('a,"multi\n', True), ('"a\n', True), ('a,5" screen\n', False),
    ('a,"x""\n', True), ('a,"x"""\n', False), ('a,"x"y,"z\n', True), ('a,"x"y,z\n', False)])
def test_a_csv_line_ends_inside_quotes_as_pythons_csv_reads_it(text, open_):
    import csv

    from kalmix.commands._stdin_lines import CsvRecords, Unclosed, ends_quoted

    assert ends_quoted(text) is open_
    assert (len(list(csv.reader(io.StringIO(text + "next,line\n")))) == 1) is open_   # the record goes on
    records = CsvRecords(limit=20)
    assert records.add(1, 'a,"x\n') is None and records.add(2, 'y",z\n') == (1, 'a,"x\ny",z\n')
    assert records.add(3, 'a,"xx\n') is None
    over = records.add(4, "x" * 20 + "\n")   # over the limit, still open: taken as it is (a bad row)
    assert over == (3, 'a,"xx\n' + "x" * 20 + "\n") and isinstance(over[1], Unclosed) and records.rest() is None
    assert not isinstance(records.add(5, 'a,"x\n') or records.add(6, 'x"\n')[1], Unclosed)
