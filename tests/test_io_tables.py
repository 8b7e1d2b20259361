import gzip
import io
import warnings

import numpy as np
import pandas as pd
import pytest

from kalmix.io import (
    TrackArrays,
    TrackColumns,
    detect_columns,
    from_arrays,
    iter_track_chunks,
    read_tracks,
    split_on_gaps,
    to_arrays,
)


def write(tmp_path, text, name="tracks.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------- detect_columns
@pytest.mark.parametrize("columns, expected", [
    (["t", "x", "y"], TrackColumns("t", ("x", "y"), None)),
    (["Time", "X", "Y", "Z", "ID"], TrackColumns("Time", ("X", "Y", "Z"), "ID")),
    (["timestamp", "track_id", "position_x", "position_y"],
     TrackColumns("timestamp", ("position_x", "position_y"), "track_id")),
    (["frame", "object_id", "px", "py", "pz"], TrackColumns("frame", ("px", "py", "pz"), "object_id")),
    (["seconds", "target", "u", "v"], TrackColumns("seconds", ("u", "v"), "target")),
    (["lat", "lon", "time"], TrackColumns("time", ("lat", "lon"), None)),
    (["u_left", "u_right", "v", "t"], TrackColumns("t", ("u_left", "u_right", "v"), None)),
    ([" x ", " y "], TrackColumns(None, (" x ", " y "), None)),
    # the logs of the users' domains: AIS (MarineCadastre), ADS-B (OpenSky), storm best tracks (IBTrACS)
    (["MMSI", "BaseDateTime", "LAT", "LON", "SOG"], TrackColumns("BaseDateTime", ("LAT", "LON"), "MMSI")),
    (["time", "icao24", "lat", "lon", "callsign"], TrackColumns("time", ("lat", "lon"), "icao24")),
    (["SID", "SEASON", "ISO_TIME", "LAT", "LON"], TrackColumns("ISO_TIME", ("LAT", "LON"), "SID")),
])
def test_detect_columns(columns, expected):
    assert detect_columns(columns) == expected


def test_a_file_whose_id_or_time_column_is_not_found_is_told_so(tmp_path):
    """An AIS file with its vessel column named 'vessel' was one track, every vessel's rows mixed, without a
    word: ``kalmix predict`` and ``evaluate`` now say which columns they left unused (nothing when every
    column is in use)."""
    from kalmix.cli import build
    from click.testing import CliRunner
    from kalmix.io.tables import column_notes

    assert column_notes(detect_columns(["t", "x", "y"]), ["t", "x", "y"]) == []
    assert column_notes(detect_columns(["x", "y"]), ["x", "y"]) == []
    notes = column_notes(detect_columns(["vessel", "when", "lat", "lon"]), ["vessel", "when", "lat", "lon"])
    assert len(notes) == 2 and "pass --id" in notes[0] and "pass --time" in notes[1]
    assert all("'vessel', 'when'" in note for note in notes)
    rows = "".join(f"{v},{t},{t * 0.1 + v},{v},{0.5 * t + 0.1 * v}\n" for t in range(6) for v in (1, 2))
    path = write(tmp_path, "vessel,t,x,y,heading\n" + rows)
    # a column named like an id is taken as the id, with a note (more in tests/test_as_given.py)
    for command in (["predict", str(path), "--length-unit", "1"], ["evaluate", str(path), "--no-peers"]):
        result = CliRunner().invoke(build(), command)
        assert result.exit_code == 0 and "taking 'vessel' as the track id" in result.stderr, result.output
        assert "no time column" not in result.stderr
    assert result.stdout.count("track 1") == result.stdout.count("track 2") == 1   # evaluate: two tracks
    result = CliRunner().invoke(build(), ["predict", str(path), "--length-unit", "1", "--id", "vessel"])
    assert result.exit_code == 0 and "no track id" not in result.stderr and "taking" not in result.stderr
    # an unused column that does not look like an id (fractional numbers): the note that names it
    path = write(tmp_path, "t,x,y,heading\n" + "".join(f"{t},{t},{t},{0.5 * t + 0.1}\n" for t in range(6)))
    result = CliRunner().invoke(build(), ["predict", str(path), "--length-unit", "1"])
    assert result.exit_code == 0 and "no track id column found" in result.stderr
    assert "unused columns: 'heading'" in result.stderr


def test_detect_columns_explicit_wins():
    cols = detect_columns(["t", "frame", "x", "y", "a", "id"], time="frame", positions=["a"],
                          track_id="id")
    assert cols == TrackColumns("frame", ("a",), "id")


def test_detect_columns_nothing_matches_lists_columns():
    with pytest.raises(ValueError, match=r"Could not detect position columns.*\['time', 'foo', 'bar'\]"):
        detect_columns(["time", "foo", "bar"])


def test_detect_columns_explicit_missing_lists_columns():
    with pytest.raises(ValueError, match=r"positions=\['x', 'q'\].*\['q'\] not found.*\['t', 'x', 'y'\]"):
        detect_columns(["t", "x", "y"], positions=["x", "q"])
    with pytest.raises(ValueError, match=r"time='when'.*available columns: \['t', 'x', 'y'\]"):
        detect_columns(["t", "x", "y"], time="when")


def test_options_name_columns_as_detection_matches_them():
    """A header with spaces around its names (`` Time ``, `` X ``) was detected, but ``--time time`` or ``--position
    X,Y`` were 'not found': a name given matches a column exactly, else ignoring case and surrounding spaces."""
    from kalmix.streaming import find_columns

    header = [" Track_ID ", " Time ", " X ", " Y "]
    detected = TrackColumns(" Time ", (" X ", " Y "), " Track_ID ")
    assert detect_columns(header) == detected
    assert detect_columns(header, time="time", positions=["X", "y"], track_id="TRACK_ID") == detected
    assert detect_columns(header, positions="x") == TrackColumns(" Time ", (" X ",), " Track_ID ")
    assert find_columns(header, time="Time", positions=["X", "Y"], track_id="track_id")[0] == detected
    # an exact match wins over one that ignores case or spaces; two of those are an error naming both
    assert detect_columns(["t", "x", "X", "y"], positions=["X", "y"]).positions == ("X", "y")
    with pytest.raises(ValueError, match=r"--position\): 'x' matches the columns ' x' and 'X ' .*exactly"):
        detect_columns(["t", " x", "X ", "y"], positions=["x", "y"])
    with pytest.raises(ValueError, match=r"time='when'.*available columns"):
        detect_columns(header, time="when")


def test_predictions_are_named_from_the_position_names_without_their_spaces():
    """`` X `` gave ``pred_ X ``; now ``pred_X``. Two positions that differ only by spaces would give two columns
    of one name: refused, as an id named like an added column is."""
    from kalmix.io.columns import check_output_names
    from kalmix.streaming import StreamConfig, TrackPredictor

    table = pd.DataFrame({" id ": [1, 1, 1, 2, 2, 2], " t ": [0.0, 1, 2, 0, 1, 2], " X ": [0.0, 1, 2, 5, 6, 7],
                          " Y ": [0.0, 0, 0.1, 5, 5, 5.1]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = TrackPredictor(StreamConfig(length_unit=1.0, n_experts=2, seed=0)).process_table(table)
    assert list(out.columns) == [" id ", " t ", "segment", "pred_X", "pred_Y", "std_X", "std_Y"]
    assert out[" id "].tolist() == table[" id "].tolist() and out[" t "].tolist() == table[" t "].tolist()
    with pytest.raises(ValueError, match=r"differ only by surrounding spaces"):
        check_output_names(TrackColumns("t", ("x", " x"), None))
    with pytest.raises(ValueError, match=r"the track id column is named 'pred_X'"):
        check_output_names(TrackColumns("t", (" X ", "Y"), "pred_X"))


def _one_track(n=2000, seed=0):
    """One target's fixes (a random walk with drift) at irregular times, as CSV text columns."""
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.5, 1.5, n))
    xy = np.cumsum(rng.normal(0, 1, (n, 2)) + [1.0, 0.3], 0)
    return rng, times, xy


def _candidates(times, xy, **others):
    from kalmix.io.columns import id_candidates

    sample = pd.DataFrame({"time": [f"{v:.6f}" for v in times], "x": [f"{v:.3f}" for v in xy[:, 0]],
                           "y": [f"{v:.3f}" for v in xy[:, 1]], **{k: [str(v) for v in c] for k, c in others.items()}})
    header = list(sample.columns)
    return id_candidates(detect_columns(header), header, sample)


def test_whole_numbers_that_change_where_the_positions_jump_are_ids():
    """Tracks whose fixes never share a time (GPS collars, AIS, ADS-B) told apart by a column of whole numbers
    that is not detected: the rows of one value move a little, the rows where the value changes jump between
    targets. They were one track, silently; the column is now named as an id (interleaved, or one track after
    another with the time going back)."""
    rng = np.random.default_rng(3)
    rows = []
    for unit in range(40):
        start, times = rng.uniform(0, 50_000, 2), rng.uniform(0, 10) + np.arange(60) * rng.uniform(5, 15)
        path = start + np.cumsum(rng.normal(5, 2, (60, 2)), 0)
        rows += [(times[k], 366_000_000 + unit, path[k]) for k in range(60)]
    for order in (lambda row: row[0], lambda row: (row[1], row[0])):
        rows.sort(key=order)
        found = _candidates(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]), unit=[r[1] for r in rows])
        assert [name for name, _ in found] == ["unit"]
        assert found[0][1].startswith("whole numbers that change where the positions jump: a median step of ")
    # two collars 500 apart, 0.37 s out of step
    rows = sorted((k + offset, unit, (2.0 * k, y)) for unit, offset, y in ((1001, 0.0, 0), (1002, 0.37, 500))
                  for k in range(30))
    found = _candidates(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]), collar=[r[1] for r in rows])
    assert found == [("collar", "whole numbers that change where the positions jump: a median step of 500 where "
                                "the value changes, 2 between rows of one value")]


def test_a_row_number_is_not_taken_for_ids():
    """A saved pandas index (header ``,time,x,y``: ``Unnamed: 0``) beside two targets at each time tells apart
    the rows of one time, but every value is its own: taken for an id it made one-row tracks of every row (the
    run stopped, advising ``--id 'Unnamed: 0'``). A column of whole numbers that repeat still is one."""
    times = np.repeat(np.arange(40.0), 2)
    xy = np.column_stack([np.arange(80.0), np.tile([0.0, 100.0], 40)])
    assert _candidates(times, xy, **{"Unnamed: 0": list(range(80))}) == []
    assert [name for name, _ in _candidates(times, xy, unit=[7, 9] * 40)] == ["unit"]


def test_a_column_of_one_track_is_not_taken_for_ids():
    """The whole numbers a single track's file holds beside its positions change where the target moves as
    usual, never, rarely, at every row, or where a bad fix (or a burst of them, each somewhere else) jumps away and
    back: not ids."""
    rng, times, xy = _one_track()
    n = len(times)
    bad = rng.random(n) < 0.1
    outliers = xy + np.where(bad[:, None], rng.normal(0, 300, (n, 2)), 0)
    quality = rng.integers(0, 3, n)
    moving = (np.arange(n) // 20) % 2
    halts = np.cumsum(np.where(moving[:, None] == 1, rng.normal(2, 0.5, (n, 2)), rng.normal(0, 0.01, (n, 2))), 0)
    trip = np.arange(n) // 100
    bursts = (np.arange(n) % 40 >= 20) & (np.arange(n) % 40 < 23)   # bad fixes 3 rows at a time, each burst moved
    burst_xy = xy + np.where(bursts[:, None], np.repeat(rng.normal(0, 50, (n // 40 + 1, 2)), 40, axis=0)[:n], 0)
    cases = [
        (xy, {"status": rng.integers(0, 3, n)}),                                   # a status code
        (xy, {"sats": np.clip(8 + np.cumsum(rng.integers(-1, 2, n)) // 10, 4, 14)}),  # a satellite count
        (xy, {"counter": np.arange(n)}),                                            # a frame counter
        (xy, {"const": np.full(n, 7)}),                                             # constant
        (xy, {"mode": np.arange(n) // 500}),                                        # changes rarely
        (outliers, {"fix": np.where(bad, 0, 1)}),                                   # a flag on jumping bad fixes
        (xy + np.where(quality[:, None] == 0, rng.normal(0, 200, (n, 2)), 0), {"quality": quality}),
        (halts, {"moving": moving}),                                                # stopped / moving
        (xy + trip[:, None] * 1000.0, {"trip": trip}),                              # trips one after another
        (xy + (np.arange(n) % 2)[:, None] * 5.0, {"receiver": np.arange(n) % 2}),   # two receivers 5 apart
        (burst_xy, {"fix": np.where(bursts, 1, 3)}),                               # a flag on bursts of bad fixes
        (burst_xy, {"sats": np.where(bursts, 4, 9)}),                              # a count that drops in them
    ]
    for positions, column in cases:
        assert _candidates(times, positions, **column) == [], list(column)
    # and the positions decide nothing with too few rows or changes
    assert _candidates(times[:6], xy[:6], unit=[1, 2, 1, 2, 1, 2]) == []


def test_more_than_three_positions():
    with pytest.raises(ValueError, match=r"Expected 1 to 3 position columns, got 4"):
        detect_columns(["a", "b", "c", "d"], positions=["a", "b", "c", "d"])
    with pytest.raises(ValueError, match=r"Expected 1 to 3 position columns, got 4"):
        TrackColumns("t", ("a", "b", "c", "d"), None)


# ----------------------------------------------------------------------------- read_tracks
def test_read_csv_canonical(tmp_path):
    path = write(tmp_path, "id,t,x,y\nb,0,1,2\na,0,3,4\nb,1,5,6\na,1,7,8\n")
    df = read_tracks(path)
    assert list(df.columns) == ["track_id", "time", "x", "y"]
    assert df["track_id"].tolist() == ["a", "a", "b", "b"]
    assert df["time"].tolist() == [0, 1, 0, 1]
    assert df["x"].tolist() == [3, 7, 1, 5]
    assert df["x"].dtype == np.float64 and df["time"].dtype == np.float64


def test_read_gz_and_buffer(tmp_path):
    text = "t,x\n0,1\n1,2\n"
    path = tmp_path / "one.csv.gz"
    with gzip.open(path, "wt") as fh:
        fh.write(text)
    expected = pd.DataFrame({"track_id": [0, 0], "time": [0.0, 1.0], "x": [1.0, 2.0]})
    pd.testing.assert_frame_equal(read_tracks(path), expected)
    pd.testing.assert_frame_equal(read_tracks(io.StringIO(text)), expected)


def test_parquet_roundtrip(tmp_path):
    df = pd.DataFrame({"track_id": ["a"] * 3 + ["b"] * 2, "time": [0.0, 0.5, 1.0, 0.0, 1.0],
                       "x": [1.0, np.nan, 3.0, 4.0, 5.0], "y": [0.0, 1.0, 2.0, 3.0, 4.0]})
    df.to_parquet(tmp_path / "t.parquet")
    pd.testing.assert_frame_equal(read_tracks(tmp_path / "t.parquet"), df, check_dtype=False)
    buffer = io.BytesIO()
    df.to_parquet(buffer)
    buffer.seek(0)
    pd.testing.assert_frame_equal(read_tracks(buffer, format="parquet"), df, check_dtype=False)


def test_no_time_column_means_row_order(tmp_path):
    df = read_tracks(write(tmp_path, "id,x\na,1\nb,2\na,3\n"))
    assert df["time"].tolist() == [0, 1, 0] and df["x"].tolist() == [1, 3, 2]


def test_datetime_time_in_parquet(tmp_path):
    raw = pd.DataFrame({"timestamp": pd.to_datetime(["2024-01-01 00:00:00", "2024-01-01 00:00:02"]),
                        "x": [1.0, 2.0]})
    raw.to_parquet(tmp_path / "d.parquet")
    assert np.diff(read_tracks(tmp_path / "d.parquet")["time"]).tolist() == [2.0]


def test_dates_are_read_to_the_float_nearest_the_instant(tmp_path):
    """Dates (ISO text, datetime and duration columns) are seconds to the float nearest the instant, as the same
    instants written as numbers. Dividing the nanoseconds as one float lost up to ~2.4e-7 s (steps of
    0.25 s read as 0.25000024 / 0.24999976, and a 3-step gap rule then split a track where the numbers did not)."""
    from kalmix.io.tables import iso_seconds

    instants = 1714564800 + np.array([0.0, 0.25, 0.5, 1.25, 1.5])   # exactly representable
    text = ["2024-05-01T12:00:00Z", "2024-05-01T12:00:00.25Z", "2024-05-01T14:00:00.5+02:00",
            "2024-05-01T12:00:01.250Z", "2024-05-01T12:00:01.5"]
    np.testing.assert_array_equal(iso_seconds(text), instants)
    nanoseconds = 1714564800 * 10**9 + np.array([0, 250, 500, 1250, 1500]) * 10**6
    dates = pd.to_datetime(nanoseconds).tz_localize("UTC").tz_convert("Asia/Kolkata")
    raw = pd.DataFrame({"time": dates, "x": np.arange(5.0)})
    raw.to_parquet(tmp_path / "d.parquet")
    np.testing.assert_array_equal(read_tracks(tmp_path / "d.parquet")["time"], instants)
    durations = pd.DataFrame({"time": pd.to_timedelta(instants - instants[0], unit="s") + pd.Timedelta(days=20000),
                              "x": np.arange(5.0)})
    durations.to_parquet(tmp_path / "t.parquet")
    np.testing.assert_array_equal(read_tracks(tmp_path / "t.parquet")["time"], instants - instants[0] + 1.728e9)
    path = write(tmp_path, "t,x\n" + "".join(f"{t},{i}\n" for i, t in enumerate(text)))
    np.testing.assert_array_equal(read_tracks(path)["time"], instants)
    seconds = iso_seconds(["1969-12-31T23:59:59.75Z", "2262-04-11T23:47:16.854775807Z", None,
                           "1969-12-31T23:59:59.9Z", "1969-12-31T23:59:59.999999999Z"])
    np.testing.assert_array_equal(seconds[[0, 3, 4]], [-0.25, -0.1, -1e-9])   # no cancellation below 1970 (review)
    assert seconds[1] == 9223372036.854775807 and np.isnan(seconds[2])
    # a duration column in seconds beyond 292 years (nanoseconds overflow there): read in its own unit
    long = pd.DataFrame({"time": np.array([0, 400 * 365 * 86400], dtype="timedelta64[s]"), "x": [0.0, 1.0]})
    long.to_parquet(tmp_path / "long.parquet")
    np.testing.assert_array_equal(read_tracks(tmp_path / "long.parquet")["time"], [0.0, 1.26144e10])


def test_missing_column_lists_available(tmp_path):
    path = write(tmp_path, "t,x,y\n0,1,2\n")
    with pytest.raises(ValueError, match=r"\['z'\] not found; available columns: \['t', 'x', 'y'\]"):
        read_tracks(path, columns=TrackColumns("t", ("x", "z"), None))


def test_non_numeric_names_column_row_value(tmp_path):
    path = write(tmp_path, "t,x,y\n0,1,2\n1,2,3\n2,oops,4\n")
    with pytest.raises(ValueError, match=r"^line 4: column 'x' must hold a number, got 'oops'$"):
        read_tracks(path)
    path = write(tmp_path, "t,x\n0,1\nnoon,2\n")
    with pytest.raises(ValueError, match=r"^line 3: column 't' must hold a number or an ISO 8601 date-time .*got "
                                         r"'noon'$"):
        read_tracks(path)
    with pytest.raises(ValueError, match=r"^row 1 \(counted from 0 after the header\): column 't' .* 'noon'$"):
        read_tracks(io.StringIO("t,x\n0,1\nnoon,2\n"))


def test_empty_cells_and_nan_are_missing(tmp_path):
    df = read_tracks(write(tmp_path, "t,x,y\n0,1,\n1,nan,2\n2,NaN,3\n3, ,4\n"))
    assert np.isnan(df["y"].iloc[0]) and np.isnan(df["x"].iloc[1:]).all()
    assert df["y"].iloc[1:].tolist() == [2, 3, 4]


def test_missing_time_row_dropped_with_warning(tmp_path):
    with pytest.warns(RuntimeWarning, match=r"Dropped 1 row\(s\) with a missing time"):
        df = read_tracks(write(tmp_path, "t,x\n0,1\n,2\n2,3\n"))
    assert df["time"].tolist() == [0, 2]


def test_unsorted_times_sorted_with_warning(tmp_path):
    path = write(tmp_path, "id,t,x\na,2,20\na,0,0\na,1,10\nb,5,1\nb,3,2\n")
    with pytest.warns(RuntimeWarning, match=r"Times decrease at 2 row\(s\) within tracks"):
        df = read_tracks(path)
    assert df["time"].tolist() == [0, 1, 2, 3, 5] and df["x"].tolist() == [0, 10, 20, 2, 1]


def test_duplicate_times_keep_last_with_warning(tmp_path):
    path = write(tmp_path, "id,t,x\na,0,1\na,1,2\na,1,3\nb,1,4\na,1,5\n")
    with pytest.warns(RuntimeWarning, match=r"2 row\(s\) repeat a timestamp .* kept the last"):
        df = read_tracks(path)
    assert df["x"].tolist() == [1, 5, 4]


def test_clean_file_gives_no_warning(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_tracks(write(tmp_path, "t,x\n0,1\n1,2\n"))


def test_empty_file(tmp_path):
    with pytest.raises(ValueError, match="no rows"):
        read_tracks(write(tmp_path, ""))
    with pytest.raises(ValueError, match="no rows"):
        read_tracks(write(tmp_path, "t,x,y\n"))
    with pytest.raises(ValueError, match="no rows"):
        read_tracks(io.StringIO(""))


def test_unknown_format(tmp_path):
    with pytest.raises(ValueError, match=r"Cannot tell the format of .*tracks.json"):
        read_tracks(write(tmp_path, "{}", "tracks.json"))
    with pytest.raises(ValueError, match=r"Expected format in \['csv', 'parquet'\], got 'xls'"):
        read_tracks(write(tmp_path, "t,x\n0,1\n"), format="xls")


# ----------------------------------------------------------------------------- chunks
def big_table(seed=0):
    rng = np.random.default_rng(seed)
    n = 257
    df = pd.DataFrame({"id": np.tile([3, 1, 2], n), "t": np.repeat(np.arange(n) * 0.1, 3),
                       "x": rng.normal(size=3 * n), "y": rng.normal(size=3 * n)})
    df.loc[5, "x"] = np.nan
    return df


@pytest.mark.parametrize("ext", ["csv", "parquet"])
def test_chunks_equal_whole_read(tmp_path, ext):
    raw = big_table()
    path = tmp_path / f"big.{ext}"
    raw.to_csv(path, index=False) if ext == "csv" else raw.to_parquet(path)
    chunks = list(iter_track_chunks(path, chunk_rows=100))
    assert len(chunks) == 8 and all(len(c) <= 100 for c in chunks)
    whole = pd.concat(chunks).sort_values(["track_id", "time"], kind="stable").reset_index(drop=True)
    pd.testing.assert_frame_equal(whole, read_tracks(path))


def test_chunks_row_order_time_continues(tmp_path):
    path = write(tmp_path, "id,x\n" + "".join(f"{i % 2},{i}\n" for i in range(10)))
    chunks = list(iter_track_chunks(path, chunk_rows=3))
    whole = pd.concat(chunks).sort_values(["track_id", "time"], kind="stable")
    assert whole.groupby("track_id")["time"].apply(list).to_dict() == {0: [0, 1, 2, 3, 4],
                                                                      1: [0, 1, 2, 3, 4]}


def test_chunks_time_back_across_chunks(tmp_path):
    path = write(tmp_path, "t,x\n0,0\n1,1\n2,2\n1.5,3\n")
    with pytest.raises(ValueError, match=r"Track 0: time 1.5 in the chunk starting at row 3 is not after"):
        list(iter_track_chunks(path, chunk_rows=3))


def test_chunks_bad_value_row_counts_from_file_start(tmp_path):
    path = write(tmp_path, "t,x\n0,0\n1,1\n2,2\n3,bad\n")
    with pytest.raises(ValueError, match=r"^line 5: column 'x' must hold a number, got 'bad'"):
        list(iter_track_chunks(path, chunk_rows=2))


def test_chunks_empty(tmp_path):
    with pytest.raises(ValueError, match="no rows"):
        list(iter_track_chunks(write(tmp_path, "t,x\n")))


# ----------------------------------------------------------------------------- arrays
def test_to_arrays_and_back():
    df = pd.DataFrame({"track_id": ["a", "a", "a", "b", "b"], "time": [0.0, 1.0, 3.0, 0.5, 1.5],
                       "x": [1.0, 2.0, 3.0, 4.0, np.nan], "y": [5.0, 6.0, 7.0, 8.0, 9.0]})
    arrays = to_arrays(df, ["x", "y"])
    assert isinstance(arrays, TrackArrays)
    assert arrays.values.shape == (3, 2, 2) and arrays.times.shape == (3, 2)
    assert arrays.track_ids.tolist() == ["a", "b"] and arrays.lengths.tolist() == [3, 2]
    np.testing.assert_array_equal(arrays.values[:, 0, 0], [1, 2, 3])
    np.testing.assert_array_equal(arrays.values[:, 1, 1], [8, 9, np.nan])
    np.testing.assert_array_equal(arrays.times[:, 1], [0.5, 1.5, np.nan])
    back = from_arrays(arrays, arrays.values * 10)
    assert list(back.columns) == ["track_id", "time", "pred_x", "pred_y"]
    pd.testing.assert_frame_equal(back[["track_id", "time"]], df[["track_id", "time"]])
    np.testing.assert_array_equal(back["pred_x"], df["x"] * 10)
    other = from_arrays(arrays, np.zeros((3, 2, 1)), prefix="p")
    assert list(other.columns) == ["track_id", "time", "p0"] and len(other) == 5
    with pytest.raises(ValueError, match=r"Expected predictions of shape \(3, 2, q\), got \(2, 2, 2\)"):
        from_arrays(arrays, np.zeros((2, 2, 2)))


def test_to_arrays_default_positions():
    arrays = to_arrays(pd.DataFrame({"track_id": [0], "time": [0.0], "u": [1.0]}))
    assert arrays.position_names == ("u",) and arrays.values.shape == (1, 1, 1)


# ----------------------------------------------------------------------------- gaps
def test_split_on_gaps():
    t = np.r_[np.arange(10) * 0.1, 5 + np.arange(5) * 0.1, 5.4 + 0.31, 5.71 + 0.29]
    seg = split_on_gaps(t)
    assert seg.tolist() == [0] * 10 + [1] * 5 + [2, 2]
    assert split_on_gaps(t, max_gap_factor=4.0).tolist() == [0] * 10 + [1] * 7
    assert split_on_gaps([0.0]).tolist() == [0]
    assert split_on_gaps([]).tolist() == []
    with pytest.raises(ValueError, match=r"Expected max_gap_factor > 1, got 0.5"):
        split_on_gaps(t, 0.5)


def test_split_on_gaps_per_track_uses_own_median():
    times = [0, 1, 2, 10, 11, 0, 10, 20, 30]
    ids = ["a"] * 5 + ["b"] * 4
    assert split_on_gaps(times, track_ids=ids).tolist() == [0, 0, 0, 1, 1, 0, 0, 0, 0]


@pytest.mark.parametrize("first_appearance", [False, True])
def test_repeated_times_are_dropped_as_pandas_duplicated_keeps_the_last(first_appearance):
    """The normalised table drops the rows whose (track, time) repeats later, keeping the last, as pandas'
    ``duplicated(keep="last")`` does on the sorted table (numeric and text ids, -0.0 and 0.0, runs of three)."""
    from kalmix.io.tables import normalise_table

    rng = np.random.default_rng(5)
    for trial in range(60):
        n = int(rng.integers(2, 40))
        ids = rng.choice(["a", "b", " c"], n) if trial % 2 else rng.integers(0, 3, n)
        times = rng.integers(0, 5, n).astype(float) * np.where(rng.random(n) < 0.2, -0.0, 1.0)
        raw = pd.DataFrame({"track_id": ids, "time": times, "x": rng.normal(size=n)})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out = normalise_table(raw, TrackColumns("time", ("x",), "track_id"), first_appearance=first_appearance)
        if first_appearance:
            order = np.lexsort((times, pd.factorize(raw["track_id"], sort=False)[0]))
        else:
            order = raw.sort_values(["track_id", "time"], kind="stable").index.to_numpy()
        expected = raw.iloc[order]
        expected = expected[~expected.duplicated(["track_id", "time"], keep="last").to_numpy()]
        assert out["track_id"].astype(str).tolist() == expected["track_id"].astype(str).tolist()
        assert np.array_equal(out[["time", "x"]].to_numpy(), expected[["time", "x"]].to_numpy())
