"""``kalmix predict`` gives the input's rows back as they came, in the input's order; ids never merge silently.

Issue 41: times came back as epoch floats (ISO text), ``0.0`` (integer frames) and floats
(Parquet datetimes), rows grouped by track, so joining the predictions back needed a merge on
float times; and an id column that was not detected (``vessel``) merged every track into one
with exit 0. The output is now a row-for-row companion of the input (files, Parquet, stdin):
its rows in its order, the id and time columns exactly as they came, the prediction columns
beside them; an unused column that looks like an id is taken with a note or stops the run.
"""

import io
import json
import signal

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from kalmix.commands._durable import TEST_HOOK

FAST = ["--experts", "4", "--seed", "1", "--length-unit", "0.01", "--time-unit", "0.04", "--no-progress"]
PREDICTED = ["segment", "pred_x", "pred_y", "std_x", "std_y"]


def _run(cli, args, input=None, env=None):
    return CliRunner().invoke(cli, args, input=input, env=env, catch_exceptions=False)


def _rows(n=40, seed=0):
    """Three tracks (ids ``007``, ``7``, ``b12``: text, as written) sampled every 0.04 s, the times written with
    two decimals (``0.00``, ``0.04``), a missing measurement; as (id, time text, x, y) in time order."""
    rng = np.random.default_rng(seed)
    rows = []
    for track, start in (("007", 0), ("7", 3), ("b12", 5)):
        xy = np.cumsum(np.cumsum(rng.normal(size=(n, 2)), 0), 0) * 0.01 + rng.normal(0, 0.01, (n, 2))
        xy[7] = np.nan
        rows += [(track, f"{0.04 * (start + k):.2f}", float(xy[k, 0]), float(xy[k, 1])) for k in range(n)]
    return sorted(rows, key=lambda row: float(row[1]))


def _csv(rows, header="track_id,time,x,y"):
    return header + "\n" + "".join(f"{a},{b},{'' if np.isnan(x) else repr(x)},{'' if np.isnan(y) else repr(y)}\n"
                                   for a, b, x, y in rows)


def _orders(rows):
    rng = np.random.default_rng(1)
    return {"interleaved": rows, "sorted": sorted(rows, key=lambda row: (row[0], float(row[1]))),
            "shuffled": [rows[i] for i in rng.permutation(len(rows))]}


def _text(output):
    """A CSV output read as text (ids and times exactly as written), predictions as numbers."""
    frame = pd.read_csv(io.StringIO(output), dtype=str, keep_default_na=False)
    for name in PREDICTED:
        frame[name] = pd.to_numeric(frame[name])
    return frame


@pytest.mark.parametrize("chunk_rows", ["200000", "7"])
def test_rows_come_back_in_the_input_order_with_ids_and_times_as_written(cli, tmp_path, chunk_rows):
    """Interleaved, sorted and shuffled inputs: the output's rows are the input's rows in the input's order,
    ids (``007``) and times (``0.00``) as written, and each row's prediction the same whatever the order (the
    engine steps each track in time order; without the population prior, which follows the order the rows
    came). In chunks too (a shuffled file cannot be read in chunks: its tracks' times go back across them)."""
    rows = _rows()
    by_row = {}
    for name, ordered in _orders(rows).items():
        if name == "shuffled" and chunk_rows != "200000":
            continue
        path = tmp_path / f"{name}.csv"
        path.write_text(_csv(ordered))
        result = _run(cli, ["predict", str(path), *FAST, "--chunk-rows", chunk_rows, "--no-population-prior"])
        assert result.exit_code == 0, result.output
        out = _text(result.stdout)
        assert list(out.columns) == ["track_id", "time", *PREDICTED]
        assert list(zip(out["track_id"], out["time"])) == [(a, b) for a, b, _, _ in ordered]
        assert out[PREDICTED].notna().all().all()
        by_row[name] = out.set_index(["track_id", "time"]).sort_index()
    for name, out in by_row.items():
        pd.testing.assert_frame_equal(out, by_row["interleaved"], check_exact=True, obj=name)


def test_stdin_answers_in_arrival_order_with_ids_and_times_as_given(cli, tmp_path):
    """CSV on stdin: each line's answer in arrival order, ids and times as written (as a file's run gives them);
    JSON lines: the JSON values as given (a number stays a number, ``"007"`` text)."""
    ordered = _orders(_rows())["interleaved"]
    text = _csv(ordered)
    piped = _run(cli, ["predict", "-", *FAST], input=text)
    (tmp_path / "in.csv").write_text(text)
    file = _run(cli, ["predict", str(tmp_path / "in.csv"), *FAST])
    assert piped.exit_code == file.exit_code == 0, piped.output
    a, b = _text(piped.stdout), _text(file.stdout)
    assert list(zip(a["track_id"], a["time"])) == [(row[0], row[1]) for row in ordered]
    pd.testing.assert_frame_equal(a[["track_id", "time", "segment"]], b[["track_id", "time", "segment"]])
    lines = "".join(json.dumps({"id": row[0] if row[0] != "7" else 7, "t": float(row[1]) if row[0] != "007"
                                else row[1], "x": row[2] if not np.isnan(row[2]) else None, "y": row[3]}) + "\n"
                    for row in ordered if not np.isnan(row[3]))
    result = _run(cli, ["predict", "-", *FAST], input=lines)
    assert result.exit_code == 0, result.output
    sent = [json.loads(line) for line in lines.splitlines()]
    got = [json.loads(line) for line in result.stdout.splitlines()]
    assert [(r["id"], r["t"]) for r in got] == [(r["id"], r["t"]) for r in sent]   # 7 a number, "0.04" text


def test_iso_times_with_offsets_and_integer_frames_come_back_as_written(cli, tmp_path):
    """ISO 8601 text with its offset (``+02:00``, ``Z``) comes back as that text in CSV, JSON lines and Parquet
    outputs; integer frames as ``0`` (JSON: 0, Parquet: numbers); the same numbers as before inside (seconds)."""
    iso = ("track_id,time,x,y\n007,2024-05-01T12:00:00+02:00,0,0\nb,2024-05-01T10:00:00Z,5,5\n"
           "007,2024-05-01T12:00:01+02:00,1,1\nb,2024-05-01T10:00:01.5Z,6,6\n007,2024-05-01T12:00:02+02:00,2,2\n")
    frames = "frame,x,y\n0,0,0\n1,1,1\n2,2,2\n3,3,3\n"
    for name, text in (("iso", iso), ("frames", frames)):
        (tmp_path / f"{name}.csv").write_text(text)
        given = [line.split(",")[-3] for line in text.splitlines()[1:]]
        args = ["predict", str(tmp_path / f"{name}.csv"), "--length-unit", "1", "--no-progress"]
        csv_out = _run(cli, args)
        assert csv_out.exit_code == 0, csv_out.output
        column = "time" if name == "iso" else "frame"
        assert _text(csv_out.stdout)[column].tolist() == given
        piped = _run(cli, ["predict", "-", *args[2:]], input=text)
        assert _text(piped.stdout)[column].tolist() == given
        assert _run(cli, [*args, "-o", str(tmp_path / f"{name}.jsonl")]).exit_code == 0
        rows = [json.loads(line) for line in (tmp_path / f"{name}.jsonl").read_text().splitlines()]
        assert [r[column] for r in rows] == (given if name == "iso" else [0, 1, 2, 3])
        assert _run(cli, [*args, "-o", str(tmp_path / f"{name}.parquet")]).exit_code == 0
        back = pd.read_parquet(tmp_path / f"{name}.parquet")[column].tolist()
        assert back == (given if name == "iso" else [0.0, 1.0, 2.0, 3.0])
    # the numbers are those of the instants: the +02:00 track steps 1 s, its first prediction is for 1 s later
    out = _text(_run(cli, ["predict", str(tmp_path / "iso.csv"), "--length-unit", "1", "--lead", "1"]).stdout)
    assert out["track_id"].tolist() == ["007", "b", "007", "b", "007"] and out["lead_x"].notna().sum() >= 3


def test_parquet_timestamps_and_integer_times_keep_their_types(cli, tmp_path):
    """A Parquet datetime (with its zone) comes back as that datetime, integer times with a missing one as
    integers (not floats), rows in the file's order; a CSV output writes them as pandas writes them."""
    t0 = pd.Timestamp("2024-05-01T12:00:00", tz="Europe/Paris")
    rows = _orders(_rows(n=20))["shuffled"]
    frame = pd.DataFrame(rows, columns=["track_id", "time", "x", "y"])
    stamps = t0 + pd.to_timedelta(frame["time"].astype(float), unit="s")
    frame.assign(time=stamps).to_parquet(tmp_path / "dt.parquet", index=False)
    result = _run(cli, ["predict", str(tmp_path / "dt.parquet"), *FAST, "-o", str(tmp_path / "out.parquet")])
    assert result.exit_code == 0, result.output
    out = pd.read_parquet(tmp_path / "out.parquet")
    assert out["time"].dtype == stamps.dtype and (out["time"] == stamps).all()
    assert out["track_id"].tolist() == frame["track_id"].tolist()
    as_csv = _text(_run(cli, ["predict", str(tmp_path / "dt.parquet"), *FAST]).stdout)
    assert (pd.to_datetime(as_csv["time"]) == stamps).all() and as_csv["time"][0].endswith("+02:00")
    np.testing.assert_array_equal(as_csv["pred_x"], out["pred_x"])

    frames = pd.DataFrame({"id": ["a", "b"] * 4, "frame": pd.array([0, 0, 1, None, 2, 2, 3, 3], dtype="Int64"),
                           "x": np.arange(8.0), "y": np.arange(8.0) ** 1.5})
    frames.to_parquet(tmp_path / "frames.parquet", index=False)
    for suffix in ("parquet", "csv"):
        target = tmp_path / f"frames-out.{suffix}"
        assert _run(cli, ["predict", str(tmp_path / "frames.parquet"), "--length-unit", "1", "-o",
                          str(target)]).exit_code == 0
        back = pd.read_parquet(target) if suffix == "parquet" else pd.read_csv(target, dtype={"frame": "Int64"})
        assert back["frame"].dtype == "Int64" and back["frame"].tolist() == frames["frame"].tolist()
        assert back["pred_x"].isna().tolist() == [False, False, False, True, False, False, False, False]
        assert pd.isna(back["segment"][3])


def test_rows_not_predicted_keep_their_place_with_empty_predictions(cli, tmp_path):
    """A row without a time and the earlier row of a repeated time are in the output, in their places, with
    empty predictions; in JSON lines their segment and predictions are null."""
    text = ("track_id,time,x,y\na,0,0,0\nb,0,5,5\na,1,1,1\na,1,1.5,1.5\nb,,6,6\nb,1,6,6\na,2,2,2\nb,2,7,7\n")
    (tmp_path / "in.csv").write_text(text)
    result = _run(cli, ["predict", str(tmp_path / "in.csv"), "--length-unit", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    out = _text(result.stdout)
    assert list(zip(out["track_id"], out["time"])) == [tuple(line.split(",")[:2]) for line in text.splitlines()[1:]]
    assert out["pred_x"].isna().tolist() == [False, False, True, False, True, False, False, False]
    assert "repeat a timestamp" in result.stderr and "have no time" in result.stderr
    assert _run(cli, ["predict", str(tmp_path / "in.csv"), "--length-unit", "1", "-o",
                      str(tmp_path / "out.jsonl")]).exit_code == 0
    rows = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert rows[4] == {"track_id": "b", "time": None, "segment": None, "pred_x": None, "pred_y": None,
                       "std_x": None, "std_y": None}
    assert rows[2]["time"] == 1 and rows[2]["segment"] is None


@pytest.mark.parametrize("fmt", ["csv", "jsonl"])
def test_a_stopped_run_resumes_to_the_same_rows_as_given(cli, tmp_path, fmt):
    """Stopped after its second chunk (a file of chunks of 9 rows with rows not predicted), then resumed with
    --state and the same -o: the bytes of an uninterrupted run, no row written twice (a row without a time
    and a repeated time's earlier row go with the rows they follow)."""
    rows = _orders(_rows(n=15))["interleaved"]
    lines = _csv(rows).splitlines(keepends=True)
    lines.insert(5, lines[4])                    # a repeated time
    lines.insert(12, "b12,,1.0,2.0\n")           # a row without a time
    lines.insert(20, "7,,1.0,2.0\n")
    (tmp_path / "in.csv").write_text("".join(lines))
    args = ["predict", str(tmp_path / "in.csv"), *FAST, "--chunk-rows", "9", "--save-every", "1"]
    whole = tmp_path / f"whole.{fmt}"
    assert _run(cli, [*args, "-o", str(whole)]).exit_code == 0
    out, state = tmp_path / f"out.{fmt}", str(tmp_path / "s.npz")
    first = _run(cli, [*args, "--state", state, "-o", str(out)], env={TEST_HOOK: "SIGTERM:2"})
    assert first.exit_code == 128 + signal.SIGTERM, first.output
    assert 0 < len(out.read_bytes()) < len(whole.read_bytes())
    second = _run(cli, [*args, "--state", state, "-o", str(out)])
    assert second.exit_code == 0, second.output
    assert out.read_bytes() == whole.read_bytes()
    assert len(whole.read_text().splitlines()) == len(lines) - (fmt == "jsonl")


def test_an_id_column_named_like_one_is_taken_with_a_note(cli, tmp_path):
    """No id named or detected, a column named ``vessel``: taken as the id, with a note; the same output as
    ``--id vessel``, the tracks not merged (they were: one track, rows dropped as repeated timestamps)."""
    rows = _orders(_rows())["interleaved"]
    path = tmp_path / "in.csv"
    path.write_text(_csv(rows, header="vessel,time,x,y"))
    taken = _run(cli, ["predict", str(path), *FAST])
    named = _run(cli, ["predict", str(path), *FAST, "--id", "vessel"])
    assert taken.exit_code == named.exit_code == 0, taken.output
    assert "taking 'vessel' as the track id" in taken.stderr and "repeat a timestamp" not in taken.stderr
    assert taken.stdout == named.stdout and taken.stdout.startswith("vessel,time,")
    piped = _run(cli, ["predict", "-", *FAST], input=path.read_text())
    assert "taking 'vessel' as the track id" in piped.stderr and piped.stdout.startswith("vessel,time,")
    single = _run(cli, ["predict", str(path), *FAST, "--id", "none"])   # the user's choice: one track
    assert single.exit_code == 0 and "repeat a timestamp" in single.stderr and single.stdout.startswith("time,")
    assert "no track id column was found" not in single.stderr
    bare = tmp_path / "bare.csv"   # no id column at all: the repeated times say the rows may be several targets'
    bare.write_text("\n".join(line.split(",", 1)[1] for line in _csv(rows, header="id,time,x,y").splitlines()))
    merged = _run(cli, ["predict", str(bare), *FAST])
    assert merged.exit_code == 0 and "repeat a timestamp within their track" in merged.stderr
    assert "no track id column was found, so every row is taken as one target's: rows of several targets need an " \
           "id column" in merged.stderr


@pytest.mark.parametrize("header, column, why", [
    ("craft,time,x,y", "craft", "repeated text values: '007', '7', 'b12'"),
    ("n,time,x,y", "n", "whole numbers that tell apart rows of one time"),
])
def test_an_unnamed_column_that_looks_like_an_id_stops_the_run(cli, tmp_path, header, column, why):
    """An unused column of repeated words, or of whole numbers that tell apart rows of one time: the run stops
    with an error that names it (exit 1, no output), rather than merge its tracks; --id or --id none go on."""
    rows = _orders(_rows())["interleaved"]
    if column == "n":
        rows = [(str({"007": 1, "7": 2, "b12": 3}[a]), b, x, y) for a, b, x, y in rows]
    path = tmp_path / "in.csv"
    path.write_text(_csv(rows, header=header))
    result = _run(cli, ["predict", str(path), *FAST, "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 1 and f"{column!r} ({why}" in result.stderr, result.output
    assert f"pass --id {column}, or --id none" in result.stderr and not (tmp_path / "out.csv").exists()
    assert _run(cli, ["predict", str(path), *FAST, "--id", column]).exit_code == 0
    assert _run(cli, ["predict", str(path), *FAST, "--id", "none"]).exit_code == 0
    evaluate = _run(cli, ["evaluate", str(path), "--no-peers"])
    assert evaluate.exit_code == 1 and f"pass --id {column}" in evaluate.stderr


def _collars(offsets=(0.0, 0.37)):
    """Two GPS collars 500 apart whose fixes never share a time (the second 0.37 s later), their ids in a column
    not named like ids: ``time,collar,x,y`` rows in time order."""
    rows = sorted((k + offset, unit, 2 * k, y) for unit, offset, y in zip((1001, 1002), offsets, (0, 500))
                  for k in range(30))
    return "time,collar,x,y\n" + "".join(f"{t:.2f},{unit},{x},{y}\n" for t, unit, x, y in rows)


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_ids_of_fixes_that_never_share_a_time_stop_the_run(cli, tmp_path, suffix):
    """GPS collars, AIS and ADS-B almost never repeat a time exactly: an undetected id column of whole numbers
    merged the tracks with a note and exit 0 (one track jumping 500 between rows). Its values change where the
    positions jump, far more than the rows of one value move: the run stops naming it, in Python too."""
    from kalmix.streaming import StreamConfig, TrackPredictor

    table = pd.read_csv(io.StringIO(_collars()))
    path = tmp_path / f"in.{suffix}"
    table.to_parquet(path) if suffix == "parquet" else path.write_text(_collars())
    result = _run(cli, ["predict", str(path), "--length-unit", "1", "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 1 and "'collar' (whole numbers that change where the positions jump: a median step " \
        "of 500 where the value changes, 2 between rows of one value)" in result.stderr, result.output
    assert "pass --id collar, or --id none" in result.stderr and not (tmp_path / "out.csv").exists()
    evaluate = _run(cli, ["evaluate", str(path), "--no-peers"])
    assert evaluate.exit_code == 1 and "pass --id collar" in evaluate.stderr
    with pytest.raises(ValueError, match="pass --id collar"):
        TrackPredictor(StreamConfig(length_unit=1.0)).process_table(table)
    named = _run(cli, ["predict", str(path), "--length-unit", "1", "--id", "collar"])
    assert named.exit_code == 0 and named.stdout.startswith("collar,time,segment,pred_x"), named.output
    assert _run(cli, ["predict", str(path), "--length-unit", "1", "--id", "none"]).exit_code == 0


def test_one_track_with_columns_of_whole_numbers_runs(cli, tmp_path):
    """A single target's file with a status code, a satellite count, a fix-quality flag (its bad fixes jumping
    away) and a frame counter beside the positions is one track: it runs, as before, each column named in the
    note on unused columns."""
    rng = np.random.default_rng(5)
    n = 300
    xy = np.cumsum(rng.normal(0, 1, (n, 2)) + [1.0, 0.3], 0)
    bad = rng.random(n) < 0.1
    xy[bad] += rng.normal(0, 300, (bad.sum(), 2))
    times = np.cumsum(rng.uniform(0.5, 1.5, n))
    status, sats = rng.integers(0, 3, n), np.clip(8 + np.cumsum(rng.integers(-1, 2, n)) // 10, 4, 14)
    path = tmp_path / "in.csv"
    path.write_text("time,x,y,status,sats,fix,frame_count\n" + "".join(
        f"{times[k]:.3f},{xy[k, 0]:.3f},{xy[k, 1]:.3f},{status[k]},{sats[k]},{int(not bad[k])},{k}\n"
        for k in range(n)))
    result = _run(cli, ["predict", str(path), "--length-unit", "1", "--no-progress"])
    assert result.exit_code == 0 and result.stdout.startswith("time,segment,pred_x"), result.output
    assert "unused columns: 'status', 'sats', 'fix', 'frame_count'" in result.stderr


def test_a_header_with_spaces_around_its_names(cli, tmp_path):
    """`` Track_ID , Time , X , Y ``: detected, but ``--position X,Y`` and ``--time time`` were 'not found' and the
    output named ``pred_ X ``. Options now match names as detection does; the added columns are named from the
    names without their spaces (``pred_X``), the id and time columns keep their names as given, and a stopped run
    resumes to the same bytes."""
    rows = _orders(_rows(n=15))["interleaved"]
    path = tmp_path / "in.csv"
    path.write_text(_csv(rows, header=" Track_ID , Time , X , Y "))
    detected = _run(cli, ["predict", str(path), *FAST])
    assert detected.exit_code == 0, detected.output
    assert detected.stdout.startswith(" Track_ID , Time ,segment,pred_X,pred_Y,std_X,std_Y\n")
    out = pd.read_csv(io.StringIO(detected.stdout), dtype=str, keep_default_na=False)
    assert list(zip(out[" Track_ID "], out[" Time "])) == [(a, b) for a, b, _, _ in rows]
    for options in (["--position", "X,Y"], ["--time", "time", "--id", "track_id", "--position", "x", "--position",
                                                                            "y"]):
        named = _run(cli, ["predict", str(path), *FAST, *options])
        assert named.exit_code == 0 and named.stdout == detected.stdout, (options, named.output)
    evaluate = _run(cli, ["evaluate", str(path), "--no-peers", "--time", "TIME", "--position", "X,Y"])
    assert evaluate.exit_code == 0, evaluate.output
    args = ["predict", str(path), *FAST, "--chunk-rows", "9", "--save-every", "1", "--position", "X,Y"]
    whole, out, state = tmp_path / "whole.csv", tmp_path / "out.csv", str(tmp_path / "s.npz")
    assert _run(cli, [*args, "-o", str(whole)]).exit_code == 0
    assert whole.read_text() == detected.stdout
    first = _run(cli, [*args, "--state", state, "-o", str(out)], env={TEST_HOOK: "SIGTERM:2"})
    assert first.exit_code == 128 + signal.SIGTERM, first.output
    second = _run(cli, [*args, "--state", state, "-o", str(out)])
    assert second.exit_code == 0 and out.read_bytes() == whole.read_bytes(), second.output


def test_stdin_stops_at_the_line_that_shows_a_second_word_in_an_unused_column(cli):
    """On stdin the rows are not there to be read ahead: the line that shows a second word in an unused column
    stops the run, before it is stepped; the rows before it (one word: one track) are answered."""
    feed = "t,x,y,craft\n0,0,0,alpha\n1,1,1,alpha\n1,5,5,bravo\n2,2,2,alpha\n"
    result = _run(cli, ["predict", "-", "--length-unit", "1"], input=feed)
    assert result.exit_code == 1 and "line 4: no track id column named or detected" in result.stderr
    assert "'craft'" in result.stderr and "'alpha', 'bravo'" in result.stderr
    assert len(_text(result.stdout)) == 2
    assert _run(cli, ["predict", "-", "--length-unit", "1", "--id", "craft"], input=feed).exit_code == 0
    # text that is not words: numbers, dates, true/false, one value only
    for column in ("1.5\n2.5\n1.5\n2.5", "2024-05-01\n2024-05-02\n2024-05-01\n2024-05-02", "true\nfalse\ntrue\nx",
                   "gps\ngps\ngps\ngps"):
        values = column.splitlines()
        quiet = "t,x,y,other\n" + "".join(f"{k},{k},{k},{v}\n" for k, v in enumerate(values[:3]))
        assert _run(cli, ["predict", "-", "--length-unit", "1"], input=quiet).exit_code == 0, column


def test_the_output_keeps_only_the_id_and_time_of_the_input(cli, tmp_path):
    """Other input columns are not repeated: the output is the input's companion, row for row, and a reader puts
    them side by side by position."""
    rows = _orders(_rows(n=10))["shuffled"]
    path = tmp_path / "in.csv"
    path.write_text("".join(line + ",note\n" for line in _csv(rows).splitlines()))
    source = pd.read_csv(path, dtype=str, keep_default_na=False)
    result = _run(cli, ["predict", str(path), *FAST])
    assert result.exit_code == 0, result.output
    out = _text(result.stdout)
    assert list(out.columns) == ["track_id", "time", *PREDICTED]
    side = pd.concat([source, out.drop(columns=["track_id", "time"])], axis=1)
    assert list(side.columns) == ["track_id", "time", "x", "y", "note", *PREDICTED]
    assert (out["track_id"] == source["track_id"]).all() and (out["time"] == source["time"]).all()


def _typed_outputs(cli, tmp_path, text, chunk_rows, stem="in"):
    """``text`` (a CSV file) predicted to CSV, JSON lines and Parquet with ``--chunk-rows``: the CSV read as text,
    the JSON lines' records, the Parquet table (pyarrow)."""
    import pyarrow.parquet as pq

    path = tmp_path / f"{stem}.csv"
    path.write_text(text)
    outs = {}
    for suffix in ("csv", "jsonl", "parquet"):
        target = tmp_path / f"{stem}-{chunk_rows}.{suffix}"
        result = _run(cli, ["predict", str(path), "--length-unit", "0.05", "--no-progress", "--chunk-rows",
                            str(chunk_rows), "-o", str(target)])
        assert result.exit_code == 0, result.output
        outs[suffix] = target
    rows = [json.loads(line) for line in outs["jsonl"].read_text().splitlines()]
    return _text(outs["csv"].read_text()), rows, pq.read_table(outs["parquet"])


SEVEN = "track_id,time,x,y\n0,0.0,0,0\n0,0.1,0.1,0\n0,0.2,0.2,0\n0,0.3,0.3,0\n0,{bad},0.4,0\n0,0.5,0.5,0\n0,0.6,0.6,0\n"


@pytest.mark.parametrize("bad", ["ERR", "abc", "2024-05-01T00:00:00Z", "1e0x", "inf", "NA"])
@pytest.mark.parametrize("chunk_rows", [3, 100])
def test_a_bad_time_keeps_the_time_column_one_type_in_every_chunk(cli, tmp_path, bad, chunk_rows):
    """A time that is not read (text, a stray date-time, an infinity, a missing one), in the second chunk of
    three or in the only one: the Parquet output is written (it failed on a schema that changed from double to
    text midway) with a float64 time column, JSON lines' times are numbers in every chunk (they turned into
    text in the chunk with the bad cell), the row that could not be read has a null time and empty predictions,
    and each format has the CSV output's rows and predictions, bit for bit."""
    import pyarrow as pa

    csv_out, rows, table = _typed_outputs(cli, tmp_path, SEVEN.format(bad=bad), chunk_rows)
    assert csv_out["time"].tolist() == ["0.0", "0.1", "0.2", "0.3", bad, "0.5", "0.6"]   # CSV: as written
    assert table.schema.field("time").type == pa.float64()
    expected = [0.0, 0.1, 0.2, 0.3, None, 0.5, 0.6]
    assert table.column("time").to_pylist() == expected
    assert [row["time"] for row in rows] == expected
    assert all(type(row["time"]) in (float, type(None)) for row in rows)
    parquet = table.to_pandas()
    for name in PREDICTED:
        want = csv_out[name].to_numpy(np.float64)
        np.testing.assert_array_equal(parquet[name].to_numpy(np.float64), want)
        np.testing.assert_array_equal(np.array([np.nan if row[name] is None else row[name] for row in rows]), want)
    assert csv_out["pred_x"].isna().tolist() == [i == 4 for i in range(7)]
    piped = _run(cli, ["predict", "-", "--length-unit", "0.05", "--no-progress", "-o", str(tmp_path / "piped.jsonl")],
                 input=SEVEN.format(bad=bad))   # stdin's JSON lines: the same times (it gave the bad text)
    assert piped.exit_code == 0, piped.output
    assert [json.loads(line)["time"] for line in (tmp_path / "piped.jsonl").read_text().splitlines()] == expected


def test_a_date_time_column_stays_text_when_its_first_chunk_has_no_time(cli, tmp_path):
    """A column of date-times whose first chunk holds no time that can be read (missing, bad) and whose third
    holds only missing ones: text in every chunk of the Parquet output (a first chunk written as float64 made
    the rest fail), the times not read null in Parquet and JSON lines, and as written in CSV."""
    import pyarrow as pa

    given = ["NA", "ERR", "2024-05-01T00:00:02Z", "2024-05-01T00:00:03+02:00", "", "null", "7",
             "2024-05-01T00:00:07Z"]
    text = "track_id,time,x,y\n" + "".join(f"a,{t},{i * 0.1:.1f},0\n" for i, t in enumerate(given))
    csv_out, rows, table = _typed_outputs(cli, tmp_path, text, 2)
    assert csv_out["time"].tolist() == given
    expected = [None, None, "2024-05-01T00:00:02Z", "2024-05-01T00:00:03+02:00", None, None, None,
                "2024-05-01T00:00:07Z"]
    assert table.schema.field("time").type in (pa.string(), pa.large_string())
    assert table.column("time").to_pylist() == expected
    assert [row["time"] for row in rows] == expected


def test_missing_time_texts_come_back_as_written_from_a_file_and_from_stdin(cli, tmp_path):
    """``NA``, ``null``, ``nan``, ``N/A``, ``None`` (pandas' missing-value texts) in a time column: a missing time,
    its row not predicted; in a CSV output the text as written from a file (it came back empty) as from stdin,
    in JSON lines null from both (stdin gave the text); numbers as written (``0.10``)."""
    missing = ["NA", "null", "nan", "N/A", "None"]
    times = ["0.00", "0.10", *missing, "0.20", "0.30"]
    text = "track_id,time,x,y\n" + "".join(f"a,{t},{i * 0.1:.2f},0\n" for i, t in enumerate(times))
    csv_out, rows, table = _typed_outputs(cli, tmp_path, text, 100)
    assert csv_out["time"].tolist() == times
    assert csv_out["pred_x"].isna().tolist() == [t in missing for t in times]
    expected = [None if t in missing else float(t) for t in times]
    assert [row["time"] for row in rows] == expected and table.column("time").to_pylist() == expected
    args = ["--length-unit", "0.05", "--no-progress"]
    piped = _run(cli, ["predict", "-", *args], input=text)
    assert piped.exit_code == 0, piped.output
    given = ["track_id", "time", "segment"]   # (stdin forecasts a row for a time it cannot know yet: other numbers)
    pd.testing.assert_frame_equal(_text(piped.stdout)[given], csv_out[given])
    piped = _run(cli, ["predict", "-", *args, "-o", str(tmp_path / "piped.jsonl")], input=text)
    assert piped.exit_code == 0, piped.output
    assert [{name: json.loads(line)[name] for name in given}
            for line in (tmp_path / "piped.jsonl").read_text().splitlines()] == [
        {name: row[name] for name in given} for row in rows]
