"""A hostile pass over the new options and the engine API: each fix of what was not handled well.

Every case here was found by feeding kalmix a bad input, option, or call: before the fix it gave
a traceback-like message, a wrong silent result, or an error after all the work.
"""

import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from kalmix.bank import make_bank
from kalmix.core import engine
from kalmix.core.compiled import engine as ce
from kalmix.streaming import StreamConfig, TrackPredictor

FAST = ["--experts", "2", "--seed", "1", "--no-progress"]
ENGINES = {"reference": engine.run, "compiled": ce.run}


def _run(cli, args):
    return CliRunner().invoke(cli, args, catch_exceptions=False)


@pytest.fixture(scope="module")
def tracks_csv(tmp_path_factory):
    rng = np.random.default_rng(0)
    rows = []
    for track in ("a", "b"):
        xy = np.cumsum(rng.normal(size=(40, 2)), axis=0)
        rows += [(track, 0.1 * i, *xy[i]) for i in range(40)]
    path = tmp_path_factory.mktemp("hostile") / "tracks.csv"
    pd.DataFrame(rows, columns=["track_id", "time", "x", "y"]).to_csv(path, index=False)
    return str(path)


# ---------------------------------------------------------------------------------------- engine API
def _data(n=2, p=2, t_count=30):
    z = np.cumsum(np.random.default_rng(1).normal(size=(t_count, n, p)), axis=0)
    return z, np.broadcast_to(np.arange(t_count, dtype=float)[:, None], (t_count, n)).copy()


@pytest.mark.parametrize("run", ENGINES.values(), ids=ENGINES.keys())
@pytest.mark.parametrize("call, message", [
    (lambda run, bank, z, t: run(bank, z[:, :, 0], t), r"measurements: expected shape \(T, N, p\).*got \(30, 2\)"),
    (lambda run, bank, z, t: run(bank, z[..., :1], t), "measurements: expected 2 coordinates per row"),
    (lambda run, bank, z, t: run(bank, z, np.arange(31.0)), r"times: expected shape \(T, N\) = \(30, 2\)"),
    (lambda run, bank, z, t: run(bank, z, t, lengths=np.array([3])), r"lengths: expected shape \(N,\) = \(2,\)"),
    (lambda run, bank, z, t: run(bank, z, t, engine.init_bank_state(make_bank(2, "kinematic"), 2)),
     "state: expected a BankState of this bank .* with 2 families"),
    (lambda run, bank, z, t: run(bank, z, t, engine.init_bank_state(bank, 3)),
     r"state: state.families\[0\].mean has shape \(3, "),
])
def test_engine_arguments_are_checked_by_name(run, call, message):
    """Before: 'not enough values to unpack', a numpy broadcast error, a state of another bank
    used silently by the reference (zip cut it short), data of the wrong dimension run silently."""
    z, t = _data()
    with pytest.raises(ValueError, match=message):
        call(run, make_bank(2, "mixed", n_akf=2), z, t)


#: The start of step_row's error for a time it cannot take (a regular expression).
TIME_EXPECTED = r"time: expected a number, a date and time \(datetime, ISO text\) or a duration, "


@pytest.mark.parametrize("args, error, message", [
    (("a", 0.0, ["1", "x"]), ValueError, r"z: expected numbers .*got \['1', 'x'\]"),
    ((["a"], 0.0, [1.0, 2.0]), TypeError, r"track_id: expected a track id .*got list \['a'\]"),
    (("a", "noon", [1.0, 2.0]), ValueError, TIME_EXPECTED + "got 'noon'"),
    # True and 1+1j ran at time 1.0; a UUID or a Period id was taken and then refused by save()
    (("a", True, [1.0, 2.0]), ValueError, TIME_EXPECTED + "got True"),
    (("a", 1 + 1j, [1.0, 2.0]), ValueError, TIME_EXPECTED + r"got \(1\+1j\)"),
    ((__import__("uuid").UUID(int=5), 0.0, [1.0, 2.0]), TypeError, "track_id: expected a track id .*got UUID"),
    ((pd.Period("2024-01"), 0.0, [1.0, 2.0]), TypeError, "track_id: expected a track id .*got Period"),
])
def test_step_row_names_a_bad_argument(args, error, message):
    predictor = TrackPredictor(StreamConfig(bank="kinematic", length_unit=1.0))
    with pytest.raises(error, match=message):
        predictor.step_row(*args)
    assert predictor.rows == 0 and not predictor.track_ids


# ---------------------------------------------------------------------------------------- predict
def test_a_duplicated_column_is_refused_not_read_silently(cli, tmp_path):
    """pandas renames the copy 'x.1' and reads the first: the user would never know which one was used."""
    path = tmp_path / "dup.csv"
    path.write_text("track_id,time,x,x,y\n" + "".join(f"a,{i},{i},{-i},{i}\n" for i in range(20)))
    for command in ("predict", "evaluate"):
        result = _run(cli, [command, str(path), *FAST] if command == "predict" else
                      [command, str(path), "--experts", "2", "--no-peers"])
        assert result.exit_code == 1
        assert "Column 'x' appears 2 times in the header" in result.output


def test_an_unused_duplicated_column_is_fine(cli, tmp_path):
    path = tmp_path / "dup.csv"
    path.write_text("track_id,time,x,y,note,note\n" + "".join(f"a,{i},{i},{i},n,m\n" for i in range(20)))
    result = _run(cli, ["predict", str(path), *FAST])
    assert result.exit_code == 0 and sum(line.startswith("a,") for line in result.output.splitlines()) == 20


@pytest.mark.parametrize("content, args, why", [
    ("t,x,y\n" + "".join(f"{i},3,4\n" for i in range(30)), [], "second differences that are all 0"),
    ("id,t,x,y\n" + "".join(f"{i},0,{i},{i}\n" for i in range(5)), [], "fewer than 3 samples of a track"),
    (None, ["--chunk-rows", "1"], "fewer than 3 samples of a track"),
])
def test_the_length_unit_note_says_when_auto_could_not_estimate_it(cli, tmp_path, tracks_csv, content, args, why):
    """Before: 'length unit 1 (auto; ...)', as if 1 had been estimated from the data."""
    path = tracks_csv
    if content is not None:
        path = tmp_path / "in.csv"
        path.write_text(content)
    result = _run(cli, ["predict", str(path), *FAST, *args])
    assert result.exit_code == 0
    assert f"length unit 1 (auto could not estimate it: the first chunk has {why}" in result.output


def test_values_near_the_largest_double_give_no_numpy_warning_and_finite_predictions(cli, tmp_path, tracks_csv):
    """Before: 'kalmix: warning: overflow encountered in multiply' (from the length-unit rule)."""
    table = pd.read_csv(tracks_csv)
    table.loc[5, "x"], table.loc[6, "x"] = 1.7e308, -1.7e308
    path = tmp_path / "max.csv"
    table.to_csv(path, index=False)
    out = tmp_path / "out.csv"
    result = _run(cli, ["predict", str(path), *FAST, "-o", str(out)])
    assert result.exit_code == 0 and "overflow" not in result.output
    predictions = pd.read_csv(out)[["pred_x", "pred_y"]].to_numpy()
    assert np.isfinite(predictions).all()


@pytest.mark.parametrize("args, message", [
    (["--bank", "kinematic", "--experts", "4"], "--experts: sets the AKF family, and --bank kinematic has none"),
    (["--bank", "kinematic", "--option", "order=3"], "--option: sets the AKF family, and --bank kinematic has none"),
])
def test_akf_settings_with_a_kinematic_bank_are_refused(cli, tracks_csv, args, message):
    """Before: silently ignored (the kinematic bank has no AKF family)."""
    result = _run(cli, ["predict", tracks_csv, "--no-progress", *args])
    assert result.exit_code == 1 and message in result.output and "pred_x" not in result.output


def test_a_kinematic_state_resumed_with_experts_is_refused(cli, tracks_csv, tmp_path):
    state = str(tmp_path / "s.npz")
    assert _run(cli, ["predict", tracks_csv, "--no-progress", "--bank", "kinematic", "--state", state,
                      "-o", str(tmp_path / "a.csv")]).exit_code == 0
    result = _run(cli, ["predict", tracks_csv, "--no-progress", "--experts", "40", "--state", state,
                        "-o", str(tmp_path / "b.csv")])
    assert result.exit_code == 1 and "--bank kinematic has none" in result.output


@pytest.mark.parametrize("option, message", [
    ("bogus=1", "unknown option 'bogus'; expected one of dynamics, order"),
    ("seed=3", "use --seed for the seed"),
])
def test_unknown_options_are_named_with_the_known_ones(cli, tracks_csv, option, message):
    """Before: "make_params() got an unexpected keyword argument 'bogus'"."""
    result = _run(cli, ["predict", tracks_csv, *FAST, "--option", option])
    assert result.exit_code == 2 and message in result.output


def test_an_empty_track_id_is_reported_in_a_whole_sentence(cli, tmp_path):
    path = tmp_path / "ids.csv"
    path.write_text("track_id,time,x,y\n,0,1,2\na,1,2,3\n")
    result = _run(cli, ["predict", str(path), *FAST, "--on-bad-row", "fail"])
    assert result.exit_code == 1
    assert "line 2: column 'track_id' (track id) is empty" in result.output
    result = _run(cli, ["predict", str(path), *FAST])   # by default a bad row, skipped in its place
    assert result.exit_code == 0 and "1 bad row(s) skipped (line 2: column 'track_id' (track id) is empty" \
        in result.stderr


@pytest.mark.parametrize("args, message", [
    (["demo", "--experts", "0"], "Invalid value for '--experts': 0 is not in the range x>=1"),
    (["demo", "--seed", "-1"], "Invalid value for '--seed': -1 is not in the range 0<=x<=9223372036854775807"),
    (["reproduce", "figure2", "--seed", str(2**64), "--out", "f.png"], "Invalid value for '--seed'"),
    (["reproduce", "table1", "--quick", "--seeds", "1", "--json", "nodir/t.json"],
     "Invalid value for '--json': the directory"),
    (["reproduce", "ablations", "--json", "nodir/a.json"], "Invalid value for '--json': the directory"),
    (["reproduce", "figure2", "--out", "in.csv/f.png"], "of 'in.csv/f.png' is not a directory"),
    (["servo", "--noise", "nan"], "Invalid value for '--noise': expected a finite number, got 'nan'"),
    (["servo", "--gain", "inf"], "Invalid value for '--gain': expected a finite number, got 'inf'"),
    # 1e200 px failed after the SOM's training naming no option; a gain of 1e308 printed 1,021 warnings
    (["servo", "--noise", "1e200"], "Invalid value for '--noise': expected a number <= 10000, got '1e200'"),
    (["servo", "--gain", "1e308"], "Invalid value for '--gain': expected a number <= 1e+06, got '1e308'"),
    (["servo", "--prediction-gain", "0"], "Invalid value for '--prediction-gain': expected a number > 0"),
    (["servo", "--out-dir", ""], "Invalid value for '--out-dir': expected a directory name, got ''"),
    (["servo", "--out-dir", "in.csv/figures"], "lies under"),
    (["servo", "--json", "nodir/s.json"], "Invalid value for '--json': the directory"),
    (["servo", "--delay", "1000"], "Invalid value for '--delay': expected fewer frames than the run's 1000"),
    (["bench", "--quick", "--png", "nodir/b.png"], "Invalid value for '--png': the directory"),
])
def test_the_other_commands_check_their_arguments_before_the_work(cli, tmp_path, monkeypatch, args, message):
    """A missing output directory was a traceback after the whole run (the table printed, the servo's
    PNGs written); a negative or huge seed, --experts 0, a nan or inf noise or gain were tracebacks from the
    library; --delay 1000 on a 1,000-frame run froze every mode and called them all diverged."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in.csv").write_text("t,x\n0,1\n")
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert "scenario" not in result.output and "mixture" not in result.output   # before the work
    assert not list(tmp_path.glob("servo_out*"))


def test_servo_makes_a_nested_output_directory(cli, tmp_path, monkeypatch):
    """The --out-dir check must not refuse what os.makedirs makes (a nested new directory was refused
    by the first version of the check)."""
    import kalmix.commands.servo as servo_command

    def stop(*args, **kwargs):
        raise ValueError("stopped here: the options were taken")

    monkeypatch.setattr(servo_command, "progress_bar", stop)
    result = CliRunner().invoke(cli, ["servo", "--out-dir", str(tmp_path / "new" / "nested")])
    assert result.exit_code == 1 and "stopped here: the options were taken" in result.output
    # --json inside the --out-dir it makes was refused (its directory did not exist yet); elsewhere it still is
    made = tmp_path / "made"
    result = CliRunner().invoke(cli, ["servo", "--json", str(made / "s.json"), "--out-dir", str(made)])
    assert result.exit_code == 1 and "stopped here: the options were taken" in result.output
    result = CliRunner().invoke(cli, ["servo", "--json", str(tmp_path / "other" / "s.json"), "--out-dir", str(made)])
    assert result.exit_code == 2 and "Invalid value for '--json': the directory" in result.output
    # only the out-dir itself is made for it (a typo'd subdirectory of an existing one is still refused),
    # a name ending in / or the out-dir itself is refused before the work, as is an out-dir that is a broken link
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    for args, message in ((["--out-dir", str(tmp_path), "--json", str(tmp_path / "typo" / "s.json")], "does not exist"),
                          (["--out-dir", str(made), "--json", str(made / "s.json") + "/"], "which names a directory"),
                          (["--out-dir", str(made), "--json", str(made)], "is the --out-dir; give a file name"),
                          (["--out-dir", str(tmp_path / "dangling")], "is a symbolic link to nothing")):
        result = CliRunner().invoke(cli, ["servo", *args])
        assert result.exit_code == 2 and message in result.output, result.output
    assert not (tmp_path / "typo").exists() and not made.exists()
    (tmp_path / "F").write_text("")
    result = CliRunner().invoke(cli, ["servo", "--out-dir", str(tmp_path / "F" / "sub"), "--help"])
    assert result.exit_code == 0 and "--out-dir" in result.output   # --help first, whatever comes before it


def test_servo_cells_never_read_zero_for_a_small_gain():
    """--gain 0.004 printed 0.00 in the gain column (and the option refuses a gain of 0)."""
    from kalmix.commands.servo import _cell

    assert _cell(0.004, 6, 2).strip() == "0.004"
    assert _cell(0.8, 6, 2).strip() == "0.80" and _cell(0.0, 6, 2).strip() == "0.00"
    assert _cell(1e6, 6, 2).strip() == "1e+06"


def test_reproduce_writes_its_json_before_a_closed_stdout_ends_it(cli, tmp_path, monkeypatch):
    """`kalmix reproduce table1 --json t.json | head -1` (and servo's figures) lost every file: the
    tables were echoed first and the closed pipe ended the command there. The files now come first."""
    import kalmix.commands.reproduce as reproduce_command

    def closed(*args, **kwargs):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(reproduce_command.click, "echo", closed)
    target = tmp_path / "t.json"
    result = CliRunner().invoke(cli, ["reproduce", "table1", "--quick", "--seeds", "1", "--json", str(target)])
    assert result.exit_code != 0 and json.loads(target.read_text())["scenario"] == "quick"


def test_a_reader_that_stops_early_ends_a_command_quietly(cli, tmp_path, monkeypatch):
    """`kalmix servo | head` ended with "Error: Broken pipe" (exit 1) after head had what it wanted: a closed stdout
    now ends the command with exit 1 and no message, as predict does."""
    import click as click_module

    import kalmix.commands.reproduce as reproduce_command

    echo = click_module.echo

    def closed_stdout(message=None, *args, err=False, **kwargs):
        if not err:
            raise BrokenPipeError(32, "Broken pipe")
        echo(message, *args, err=err, **kwargs)

    monkeypatch.setattr(reproduce_command.click, "echo", closed_stdout)
    result = CliRunner().invoke(cli, ["reproduce", "table1", "--quick", "--seeds", "1"])
    assert result.exit_code == 1 and "Broken pipe" not in result.output and "Error" not in result.output


@pytest.mark.parametrize("args, message", [
    (["reproduce", "figure2", "--out", "fig.txt"], "expected a figure file ending in .png"),
    (["bench", "--quick", "--png", "b.txt"], "expected a figure file ending in .png"),
    (["reproduce", "figure2", "--out", "new.png/"], "which names a directory"),
    (["reproduce", "table1", "--json", "new.json/"], "which names a directory"),
    (["reproduce", "table1", "--json", "-"], "got '-' (standard output is not taken here"),
])
def test_a_figure_or_json_name_that_cannot_be_written_is_refused_before_the_work(cli, tmp_path, monkeypatch, args,
                                                                                 message):
    """A .txt figure failed after the whole run (bench: ~2 min, its JSON already written); 'x.png/' gave
    'No such file or directory: x.png/.png' after it."""
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2 and message in result.output
    assert not list(tmp_path.iterdir())


def test_a_library_error_in_the_other_commands_is_one_line(cli, monkeypatch):
    """What the options cannot check (here a library refusal) is one line, as in predict, not a traceback."""
    import kalmix.baselines

    def refuse(*args, **kwargs):
        raise ValueError("n_experts: expected an integer >= 1, got 0")

    monkeypatch.setattr(kalmix.baselines, "softmax_mixture", refuse)
    result = CliRunner().invoke(cli, ["demo"])
    assert result.exit_code == 1 and result.output.strip().splitlines()[-1] == \
        "Error: n_experts: expected an integer >= 1, got 0"
    assert result.exception is None or isinstance(result.exception, SystemExit)


# ---------------------------------------------------------------------------------------- evaluate
def test_evaluate_refuses_an_unknown_plot_track_before_the_work(cli, tracks_csv, tmp_path):
    """Before: every predictor ran, the tables were printed, and then the error came."""
    result = _run(cli, ["evaluate", tracks_csv, "--experts", "2", "--no-peers", "--plot", str(tmp_path / "p.png"),
                        "--track", "zz"])
    assert result.exit_code == 1
    assert "--track: expected one of ['a', 'b'], got 'zz'" in result.output
    assert "overall" not in result.output and "tuning" not in result.output


def test_evaluate_with_no_tuning_part_says_the_peers_are_tuned_in_hindsight(cli, tracks_csv):
    """Before: 'first 0% of each track tunes the peers', while they were tuned on the scored rows."""
    result = _run(cli, ["evaluate", tracks_csv, "--experts", "2", "--no-peers", "--tuning-fraction", "0",
                        "--no-per-track"])
    assert result.exit_code == 0
    assert "no tuning part (--tuning-fraction 0): the peers are tuned on the scored rows, in hindsight" \
        in result.output
    assert "tuning on the scored rows themselves" in result.output and "first 0%" not in result.output


def test_evaluate_says_a_small_tuning_fraction_as_given(cli, tracks_csv):
    """Before: --tuning-fraction 0.004 was said 'the first 0% of each track', as if there were no tuning part
    (here the error that 40-row tracks leave it no rows)."""
    result = _run(cli, ["evaluate", tracks_csv, "--experts", "2", "--no-peers", "--tuning-fraction", "0.004",
                        "--no-per-track"])
    assert result.exit_code == 1
    assert "the first 0.4% of each track (--tuning-fraction) holds no two" in result.output
    assert "first 0%" not in result.output


def test_an_all_empty_file_warns(cli, tmp_path):
    path = tmp_path / "empty_positions.csv"
    path.write_text("id,t,x,y\n1,0,,\n1,1,nan,nan\n2,0,,\n")
    result = _run(cli, ["predict", str(path), *FAST, "--length-unit", "1"])
    assert result.exit_code == 0
    assert "none of the 3 input row(s) has a position" in result.stderr
    stdin = CliRunner().invoke(cli, ["predict", "-", *FAST, "--length-unit", "1"], input=path.read_text(),
                               catch_exceptions=False)
    assert "none of the 3 input row(s) has a position" in stdin.stderr


def test_a_state_resumed_with_renamed_positions_is_refused(cli, tracks_csv, tmp_path):
    state = str(tmp_path / "s.npz")
    assert _run(cli, ["predict", tracks_csv, *FAST, "--state", state]).exit_code == 0
    renamed = tmp_path / "renamed.csv"
    frame = pd.read_csv(tracks_csv)
    frame.rename(columns={"x": "east", "y": "north"}).to_csv(renamed, index=False)
    result = _run(cli, ["predict", str(renamed), "--state", state, "--no-progress", "--position", "east,north"])
    assert result.exit_code == 1 and "the state file tracks the coordinates" in result.stderr


# -- a hostile pass over the Python API: each test fails on the code before its fix --------------------
def _table(n=8, ids=1, **columns):
    base = {"track_id": ids, "time": np.arange(float(n)), "x": np.arange(float(n)), "y": 0.0}
    return pd.DataFrame({**base, **columns})


def test_a_missing_row_given_as_none():
    """z=None was refused, though None is a missing value; it is the whole row missing once the predictor
    knows how many coordinates a row has, and a named error before."""
    fresh = TrackPredictor(StreamConfig(length_unit=0.1))
    with pytest.raises(ValueError, match=r"z: None \(a missing row\) needs the number of coordinates"):
        fresh.step_row("a", 0.0, None)
    assert fresh.rows == 0
    with_none, with_nan = TrackPredictor(StreamConfig(length_unit=0.1)), TrackPredictor(StreamConfig(length_unit=0.1))
    rows = [[0.0, 0.0], [1.0, 0.5], None, [3.0, 1.5], [4.0, 2.0]]
    for k, z in enumerate(rows):
        a = with_none.step_row("a", float(k), z)
        b = with_nan.step_row("a", float(k), [np.nan, np.nan] if z is None else z)
        assert np.array_equal(a.next, b.next, equal_nan=True)


def test_times_empty_masked_or_boolean_in_a_list():
    """An empty text time made the whole step_rows call fail (a file skips such a row), a masked time's
    hidden value was used, and True among numbers was read as 1.0."""
    predictor = TrackPredictor(StreamConfig(length_unit=0.1))
    got = predictor.step_rows(["a"] * 3, ["0", " ", "2.0"], [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    assert got[1] is None and got[2].time == 2.0 and predictor.skipped == 1
    assert predictor.step_row("a", "", [3.0, 3.0]) is None
    times = np.ma.masked_array([3.0, 4.0], mask=[1, 0])
    got = predictor.step_rows(["a", "a"], times, [[3.0, 3.0], [4.0, 4.0]])
    assert got[0] is None and got[1].time == 4.0
    with pytest.raises(ValueError, match=r"times: expected numbers, dates and times \(datetime, ISO text\) or "
                                         r"durations, got \[5.0, True\]"):
        predictor.step_rows(["a", "a"], [5.0, True], [[5.0, 5.0], [6.0, 6.0]])


def test_step_rows_refuses_text_ids_and_two_dimensional_times():
    """step_rows("ab", ...) took the letters for the rows' ids, and times of shape (1, 2) were flattened."""
    predictor = TrackPredictor(StreamConfig(bank="kinematic", length_unit=1.0))
    with pytest.raises(TypeError, match="track_ids: expected a sequence of track ids, one per row, got the text 'ab'"):
        predictor.step_rows("ab", [0.0, 1.0], [[1.0, 2.0], [1.0, 2.0]])
    with pytest.raises(ValueError, match=r"times: expected one time per row, a 1-D sequence, got shape \(1, 2\)"):
        predictor.step_rows(["a", "b"], [[0.0, 1.0]], [[1.0, 2.0], [1.0, 2.0]])
    assert predictor.rows == 0 and not predictor.track_ids


def test_masked_values_are_missing_and_iso_text_times_are_dates():
    """A masked array's masked value was learned (np.asarray keeps it), and step_row refused ISO 8601
    text, which a file and stdin take."""
    z = np.ma.masked_array([[0.0, 0.0], [1.0, 0.5], [99.0, 99.0], [3.0, 1.5]], mask=[[0, 0], [0, 0], [1, 1], [0, 0]])
    masked, nan = TrackPredictor(StreamConfig(length_unit=0.1)), TrackPredictor(StreamConfig(length_unit=0.1))
    got = masked.step_rows(["a"] * 4, [0.0, 1.0, 2.0, 3.0], z)
    want = nan.step_rows(["a"] * 4, [0.0, 1.0, 2.0, 3.0], z.filled(np.nan))
    assert all(np.array_equal(a.next, b.next) for a, b in zip(got, want))
    rows = TrackPredictor(StreamConfig(length_unit=0.1))   # a list of masked rows (masks lost)
    got = rows.step_rows(["a"] * 4, [0.0, 1.0, 2.0, 3.0], [z[k] for k in range(4)])
    assert all(np.array_equal(a.next, b.next) for a, b in zip(got, want))
    text, dates = TrackPredictor(StreamConfig(length_unit=0.1)), TrackPredictor(StreamConfig(length_unit=0.1))
    stamps = ["2024-05-01T12:00:00Z", "2024-05-01T12:00:00.5Z", "2024-05-01T14:00:01+02:00"]
    for k, stamp in enumerate(stamps):
        a = text.step_row("a", stamp, [k, 0.0])
        b = dates.step_row("a", pd.Timestamp(stamp, tz="UTC") if k < 2 else pd.Timestamp(stamp), [k, 0.0])
        assert a.time == b.time == 1714564800 + 0.5 * k and np.array_equal(a.next, b.next, equal_nan=True)


def test_a_table_with_tuple_ids_is_refused_as_step_row_refuses_them():
    """process_table took tuple ids, save() wrote them as JSON lists and load() failed ('unhashable type')."""
    table = _table(ids=[1, 1, 1] + [(1, 2)] * 5)
    engine_ = TrackPredictor(StreamConfig(length_unit=0.1))
    with pytest.raises(TypeError, match=r"expected a track id .* got tuple \(1, 2\) in row 3"):
        engine_.process_table(table, ["x", "y"])
    assert not engine_.gaps   # all or nothing


def test_errors_name_the_row_of_the_callers_table_when_the_table_sets_the_time_unit():
    """The table is stepped in two parts around the row that fixes the time unit: rows were counted from the second
    part's start (an inf at row 9 was 'row 8'); a text value was quoted as the column's first value."""
    x = np.arange(12.0)
    x[9] = np.inf
    with pytest.raises(ValueError, match=r"in row 9 \(counted from 0\)"):
        TrackPredictor(StreamConfig(length_unit=0.1)).process_table(_table(12, x=x), ["x", "y"])
    with pytest.raises(ValueError, match=r"position column 'x' must hold numbers, got 'abc' in row 2"):
        TrackPredictor(StreamConfig(length_unit=0.1)).process_table(_table(4, x=["1.0", "2", "abc", "3"]), ["x", "y"])


def test_a_position_column_named_twice_is_refused():
    """With two columns x, process_table built a bank of three coordinates and pred_y was the second x's."""
    table = _table(5)
    table.insert(4, "x2", 100.0)
    table.columns = ["track_id", "time", "x", "y", "x"]
    with pytest.raises(ValueError, match=r"got \['x'\] more than once"):
        TrackPredictor(StreamConfig(length_unit=0.1)).process_table(table, ["x", "y"])


def test_step_rows_and_step_row_take_dates_as_process_table_does():
    """step_rows read datetime64 times in the array's unit (1.7e15 µs): a spurious new segment, a time unit of 1e6;
    step_row refused dates."""
    times = pd.date_range("2024-01-01", periods=6, freq="500ms")
    table = pd.DataFrame({"track_id": "a", "time": times, "x": np.arange(6.0), "y": 0.0})
    whole = TrackPredictor(StreamConfig(length_unit=0.1)).process_table(table, ["x", "y"])
    rows, one = TrackPredictor(StreamConfig(length_unit=0.1)), TrackPredictor(StreamConfig(length_unit=0.1))
    rows.process_table(table.iloc[:4], ["x", "y"])
    one.process_table(table.iloc[:4], ["x", "y"])
    got = rows.step_rows(["a", "a"], np.array(times[4:].to_numpy(), dtype="datetime64[us]"), table[["x", "y"]][4:])
    singles = [one.step_row("a", times[4], [4.0, 0.0]), one.step_row("a", times[5].tz_localize("UTC"), [5.0, 0.0])]
    assert rows.config.time_unit == 0.5 and [r.segment for r in got] == [0, 0]
    for a, b, k in zip(got, singles, (4, 5)):
        assert np.array_equal(a.next, b.next)
        assert np.array_equal(a.next, whole[["pred_x", "pred_y"]].to_numpy()[k])


def test_a_lead_longer_than_max_horizon_steps_of_one_waits_for_the_learned_unit():
    """StreamConfig(lead=2e4) was taken, then the first row failed: the bank of a unit still to be learned was
    built with a unit of 1 (20,000 units); with rows 10 s apart it is 2,000."""
    engine_ = TrackPredictor(StreamConfig(length_unit=0.1, lead=2e4))
    for i in range(6):
        result = engine_.step_row(1, 10.0 * i, [float(i), 0.0])
    assert engine_.config.time_unit == 10.0 and np.isfinite(result.ahead).all()
    too_long = TrackPredictor(StreamConfig(length_unit=0.1, lead=2e5))
    too_long.step_row(1, 0.0, [0.0, 0.0])
    with pytest.raises(ValueError, match="lead: expected at most 10000 time units"):
        too_long.step_row(1, 10.0, [1.0, 0.0])


def test_a_lead_shorter_than_half_the_time_unit_is_warned_of():
    """No row comes within half a unit of t + lead, so the lead's weights stayed uniform, silently."""
    with pytest.warns(RuntimeWarning, match="lead: 4 is shorter than half the time unit"):
        engine_ = TrackPredictor(StreamConfig(length_unit=0.1, lead=4.0))
        for i in range(4):
            engine_.step_row(1, 10.0 * i, [float(i), 0.0])


def test_forecast_checks_its_arguments():
    """engine.forecast took frames 0 or -3 (as 1) and 1e9 (minutes), a NaN or earlier time (the last row's
    forecast), and another bank's state (a raw broadcast error)."""
    bank = make_bank(2, "kinematic", length_unit=0.1)
    z = np.cumsum(np.ones((10, 1, 2)), 0)
    z[7:] = np.nan
    state = engine.run(bank, z, np.arange(10.0)[:, None]).state
    assert np.isfinite(engine.forecast(bank, state, 6.5)[0]).all()   # after the last learned row (6)
    for time, frames, message in ((np.nan, 1, "time: expected finite times"), (5.0, 1, "got 5.0 for target 0"),
                                  (8.0, 0, "frames: expected an integer in"), (8.0, 10**9, "frames: expected"),
                                  ([1.0, 2.0], 1, r"time: expected a number or one per target, shape \(1,\)")):
        with pytest.raises(ValueError, match=message):
            engine.forecast(bank, state, time, frames)
    with pytest.raises(ValueError, match="state: expected a BankState of this bank"):
        engine.forecast(make_bank(2, "mixed", length_unit=0.1), state, 8.0)


@pytest.mark.parametrize("lengths", [np.array([2**63, 2**64 - 1, 5], dtype=np.uint64), np.array([2.0**70, -3.0, 30.0])])
def test_lengths_beyond_the_rows_are_every_row_in_both_engines(lengths):
    """The compiled engine cast a length of 2**63 or more to a negative int64 (all NaN); the reference ran."""
    bank = make_bank(2, "kinematic", length_unit=0.1)
    z = np.cumsum(np.random.default_rng(0).normal(size=(30, 3, 2)), 0)
    results = [run(bank, z, np.arange(30.0)[:, None], lengths=lengths) for run in ENGINES.values()]
    every = engine.run(bank, z, np.arange(30.0)[:, None], lengths=np.clip(lengths, 0, 30).astype(np.int64))
    for result in results:
        assert np.array_equal(result.forecasts, every.forecasts, equal_nan=True)
    assert np.isfinite(results[1].forecasts[5:, 0]).all()


@pytest.mark.parametrize("call, error, message", [
    (lambda: TrackPredictor({"length_unit": 0.1}), TypeError, "config: expected a StreamConfig, got dict"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1)).process_table({"a": 1}), TypeError,
     "table: expected a pandas DataFrame"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1)).process_table(_table(3), ["x", "y"], {1: "x"}), ValueError,
     "next_times: expected a mapping of track id -> time"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1)).warm_up(2.5), ValueError,
     "measurement_dim: expected an integer >= 1"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1)).warm_up(-1), ValueError,
     "measurement_dim: expected an integer >= 1"),
    (lambda: __import__("kalmix.streaming").streaming.auto_length_unit(5.0), ValueError,
     r"values: expected shape \(T, p\)"),
    (lambda: engine.run(make_bank(2, "kinematic", length_unit=0.1), np.zeros((3, 1, 2)), "a"), ValueError,
     "times: expected numbers"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1), ["x", "y", "z"]).step_row(1, 0.0, [1.0, 2.0]), ValueError,
     r"expected 3 coordinates per row \(the position names"),
    (lambda: TrackPredictor(StreamConfig(length_unit=0.1), ["x", "x"]), ValueError,
     "position_names: expected distinct"),
])
def test_more_bad_calls_are_named(call, error, message):
    """Each raised AttributeError / IndexError / a numpy message, or (three names, two coordinates) was taken."""
    with pytest.raises(error, match=message):
        call()


def test_step_rows_takes_pandas_na_as_a_missing_measurement_as_step_row_does():
    """step_rows refused a nullable DataFrame with pd.NA, which a table and step_row take as missing."""
    values = pd.DataFrame({"x": pd.array([1.0, None, 3.0], dtype="Float64"),
                           "y": pd.array([1.0, 2.0, None], dtype="Float64")})
    rows, one = TrackPredictor(StreamConfig(length_unit=0.1)), TrackPredictor(StreamConfig(length_unit=0.1))
    got = rows.step_rows([1, 1, 1], [0.0, 1.0, 2.0], values)
    singles = [one.step_row(1, float(i), [pd.NA if pd.isna(v) else v for v in values.iloc[i]]) for i in range(3)]
    assert all(np.array_equal(a.next, b.next) for a, b in zip(got, singles))
    with pytest.raises(ValueError, match="z: expected numbers"):
        one.step_row(1, 3.0, ["a", 1.0])


def test_the_short_lead_warning_comes_from_the_data_not_from_the_warm_up(recwarn):
    """The warm-up's made-up rows are 1 apart, and its throwaway predictor learned a unit of 1 from them:
    a lead of 0.4 on rows 0.5 apart was said to be too short. A lead just over MAX_HORIZON steps of its interim unit
    (rounding) failed at the first row, and warm_up failed for a lead over MAX_HORIZON."""
    import warnings as w

    engine_ = TrackPredictor(StreamConfig(length_unit=0.1, lead=0.4))
    engine_.warm_up(2)
    for i in range(4):
        engine_.step_row(1, 0.5 * i, [float(i), 0.0])
    assert not [x for x in recwarn if "shorter than half" in str(x.message)]
    with w.catch_warnings():
        w.simplefilter("error")
        long = TrackPredictor(StreamConfig(lead=2668641.420200003, length_unit=0.1, bank="kinematic"))
        long.warm_up(2)
        assert long.step_row(1, 0.0, [0.0, 0.0]).segment == 0


def test_forecast_of_a_frame_based_bank_takes_any_time():
    """Only the time-based families read the time: an AKF bank's forecast does not refuse one."""
    bank = make_bank(2, "akf", length_unit=0.1, n_akf=2)
    state = engine.run(bank, np.cumsum(np.ones((10, 1, 2)), 0), np.arange(10.0)[:, None]).state
    assert np.array_equal(engine.forecast(bank, state, np.nan)[0], engine.forecast(bank, state, 3.0)[0])


def _walked(**config):
    predictor = TrackPredictor(StreamConfig(length_unit=0.01, bank="kinematic", **config), position_names=["x", "y"])
    for k in range(20):
        predictor.step_row(0, float(k), [float(k), 100.0])
    return predictor


def test_labelled_coordinates_are_taken_by_name():
    """A Series labelled y, x (or a DataFrame with those columns in step_rows) was taken in its own
    order, swapping the coordinates silently (process_table takes columns by name). Now by position_names, a dict
    too; labels that are not the names are refused; integer labels are positions."""
    plain = _walked().step_row(0, 20.0, [20.0, 100.0]).next
    assert np.array_equal(_walked().step_row(0, 20.0, pd.Series({"y": 100.0, "x": 20.0})).next, plain)
    assert np.array_equal(_walked().step_row(0, 20.0, {"y": 100.0, "x": 20.0}).next, plain)
    assert np.array_equal(_walked().step_row(0, 20.0, pd.Series([20.0, 100.0])).next, plain)
    rows = _walked().step_rows([0, 0], [20.0, 21.0], pd.DataFrame({"y": [100.0, 100.0], "x": [20.0, 21.0]}))
    plain_rows = _walked().step_rows([0, 0], [20.0, 21.0], [[20.0, 100.0], [21.0, 100.0]])
    assert all(np.array_equal(a.next, b.next) for a, b in zip(rows, plain_rows))
    with pytest.raises(ValueError,
                       match=r"z: expected the coordinates \['x', 'y'\] \(position_names\), got \['a', 'x'\]"):
        _walked().step_row(0, 20.0, pd.Series({"a": 1.0, "x": 2.0}))
    with pytest.raises(ValueError, match="need distinct text labels, or the predictor's position_names"):
        TrackPredictor(StreamConfig(length_unit=0.01)).step_row(0, 0.0, {"x": 1.0, 2: 2.0})


def test_lists_of_labelled_rows_and_first_labels_are_taken_by_name():
    """A list of Series (or of dicts) in step_rows was taken by position, and so was a Series given to a
    predictor without position_names: y, x learned as x, y. Now each row by name, and with no names yet the first
    labelled row's labels become position_names (as a table's columns do); a failed step adopts nothing."""
    plain = _walked().step_rows([0, 0], [20.0, 21.0], [[20.0, 100.0], [21.0, 100.0]])
    for rows in ([pd.Series({"y": 100.0, "x": 20.0}), pd.Series({"x": 21.0, "y": 100.0})],
                 [{"y": 100.0, "x": 20.0}, {"x": 21.0, "y": 100.0}],
                 [{"y": 100.0, "x": 20.0}, [21.0, 100.0]]):
        got = _walked().step_rows([0, 0], [20.0, 21.0], rows)
        assert all(np.array_equal(a.next, b.next) for a, b in zip(got, plain))
    with pytest.raises(ValueError, match=r"values\[1\]: expected the coordinates \['x', 'y'\]"):
        _walked().step_rows([0, 0], [20.0, 21.0], [[20.0, 100.0], {"x": 21.0, "z": 100.0}])

    def unnamed(first):
        predictor = TrackPredictor(StreamConfig(length_unit=0.01, bank="kinematic"))
        predictor.step_row(0, 0.0, first)
        for k in range(1, 20):
            predictor.step_row(0, float(k), pd.Series({"y": 100.0, "x": float(k)}))
        return predictor

    named = unnamed(pd.Series({"x": 0.0, "y": 100.0}))
    assert named.position_names == ("x", "y")
    assert np.array_equal(named.step_row(0, 20.0, {"y": 100.0, "x": 20.0}).next,
                          _walked().step_row(0, 20.0, [20.0, 100.0]).next)
    fresh = TrackPredictor(StreamConfig(length_unit=0.01))
    with pytest.raises(ValueError):
        fresh.step_row(0, 0.0, {"x": 1.0, "y": float("inf")})
    assert fresh.position_names is None
    fresh.step_row(0, 0.0, {"b": 1.0, "a": 2.0})
    assert fresh.position_names == ("b", "a")


def test_a_none_row_in_a_list_of_rows_is_a_missing_row():
    """MixturePredictor.run and TrackPredictor.step_rows refused a list of rows holding None, which step(None) and
    step_row(..., None) take as a missing row; now the same numbers as a row of NaN. Ragged rows are still refused."""
    from kalmix import MixturePredictor

    rows, nan_rows = [[1.0, 2.0], None, [3.0, 4.0]], [[1.0, 2.0], [np.nan, np.nan], [3.0, 4.0]]
    assert np.array_equal(MixturePredictor(4, seed=1).run(rows).predictions,
                          MixturePredictor(4, seed=1).run(nan_rows).predictions, equal_nan=True)
    got = TrackPredictor(StreamConfig(length_unit=0.1)).step_rows([0, 0, 0], [0.0, 1.0, 2.0], rows)
    want = TrackPredictor(StreamConfig(length_unit=0.1)).step_rows([0, 0, 0], [0.0, 1.0, 2.0], nan_rows)
    assert all(np.array_equal(a.next, b.next, equal_nan=True) for a, b in zip(got, want))
    with pytest.raises(TypeError, match="measurements: expected numbers"):
        MixturePredictor(4, seed=1).run([[1.0, 2.0], None, [3.0]])
    # rows that are all None: as wide as the predictor's coordinates, once it knows them
    mixture = MixturePredictor(4, seed=1)
    mixture.run(rows)
    assert mixture.run([None, None]).predictions.shape == (2, 2)
    tracks = TrackPredictor(StreamConfig(length_unit=0.1))
    tracks.step_row("a", 0.0, [5.0, 5.0])
    assert np.isnan(tracks.step_rows(["a", "b"], [5.0, 5.0], [None, None])[1].next).all()


def test_labels_are_not_adopted_once_rows_were_taken_by_position():
    """Names were adopted from a labelled row after rows taken by position (x, y rows, then a row
    labelled y, x: the coordinates swapped), and from a list that mixed labelled and plain rows (the plain rows
    re-read in the adopted order); a dict of columns in step_rows was read as rows (transposed)."""
    predictor = TrackPredictor(StreamConfig(length_unit=0.01, bank="kinematic"))
    for k in range(5):
        predictor.step_row(0, float(k), [float(k), 10.0 * k])
    with pytest.raises(ValueError, match="need the predictor's position_names: rows were already taken by position"):
        predictor.step_row(0, 5.0, {"y": 50.0, "x": 5.0})
    assert predictor.position_names is None and predictor.rows == 5
    with pytest.raises(ValueError, match="among rows by position need the predictor's position_names"):
        TrackPredictor(StreamConfig(length_unit=0.01)).step_rows(
            [0, 0, 0], [0.0, 1.0, 2.0], [[0.0, 0.0], {"y": 10.0, "x": 1.0}, [2.0, 20.0]])
    plain = _walked().step_rows([0, 0], [20.0, 21.0], [[20.0, 100.0], [21.0, 100.0]])
    columns = _walked().step_rows([0, 0], [20.0, 21.0], {"y": [100.0, 100.0], "x": [20.0, 21.0]})
    assert all(np.array_equal(a.next, b.next) for a, b in zip(columns, plain))
    fresh = TrackPredictor(StreamConfig(length_unit=0.01, bank="kinematic"))
    fresh.step_rows([0, 0], [0.0, 1.0], {"x": [0.0, 1.0], "y": [0.0, 10.0]})
    assert fresh.position_names == ("x", "y") and fresh.states[0] is not None
    with pytest.raises(ValueError, match="expected columns of one length"):
        _walked().step_rows([0, 0], [20.0, 21.0], {"x": [20.0, 21.0], "y": [100.0]})


def test_mixture_predictor_takes_missing_values_as_the_track_predictor_does():
    """MixturePredictor learned the value under a mask (np.asarray keeps it), refused None and pd.NA
    (TrackPredictor takes them as missing) and learned booleans as 1 and 0; run() with the wrong width named
    neither `measurements` nor (T, p)."""
    from kalmix import MixturePredictor

    def walked():
        predictor = MixturePredictor(4, seed=1)
        for k in range(20):
            predictor.step([k * 1.0, 2.0])
        return predictor

    missing = walked().step([np.nan, 2.0])
    assert np.array_equal(walked().step(np.ma.masked_array([500.0, 2.0], [True, False])), missing)
    assert np.array_equal(walked().step([pd.NA, 2.0]), missing)
    assert np.array_equal(walked().step(None), walked().step([np.nan, np.nan]))
    for booleans in ([True, False], np.array([True, False])):
        with pytest.raises(TypeError, match="z: expected numbers"):
            walked().step(booleans)
    with pytest.raises(ValueError, match=r"measurements: expected shape \(T, 2\) for this predictor, got \(5, 3\)"):
        walked().run(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="z: None .* needs the number of coordinates"):
        MixturePredictor(4).step(None)


def test_values_too_large_for_a_float_and_booleans_are_named_errors():
    """10**400 as a coordinate or a time gave a bare OverflowError; a non-sequence of ids 'int object is
    not iterable'; booleans were learned as 1 and 0 (bool times were already refused)."""
    with pytest.raises(ValueError, match="z: expected numbers"):
        _walked().step_row(0, 20.0, [10**400, 1.0])
    with pytest.raises(ValueError, match="time: expected a number"):
        _walked().step_row(0, 10**400, [1.0, 1.0])
    with pytest.raises(ValueError, match="values: expected numbers"):
        _walked().step_rows([0], [20.0], [[10**400, 1.0]])
    with pytest.raises(TypeError, match="track_ids: expected a sequence of track ids"):
        _walked().step_rows(7, [20.0], [[1.0, 2.0]])
    for booleans in ([True, False], [True, 1.0], np.array([True, False], dtype=object),   # the last
                     pd.Series([True, False], index=["x", "y"], dtype="boolean")):           # three were taken
        with pytest.raises(ValueError, match="z: expected numbers"):
            _walked().step_row(0, 20.0, booleans)


def test_a_short_first_step_does_not_make_every_later_row_a_gap():
    """A second frame 10 ms after the first, then 33 ms frames: the reference interval was that first
    step alone, every later step was a gap (3 x 10 ms < 33 ms) and a gap never entered the reference, so the track
    restarted at every row, for good, in step_row and process_table alike. While the reference is incomplete a
    gap's step now enters it: with every step judged (``gap_min_steps`` 1), one early restart, then the track goes
    on; by default a track's first 4 steps are not judged, and it is never cut. A real gap still splits."""
    times = [0.0, 0.010] + [0.010 + k / 30 for k in range(1, 300)]
    table = pd.DataFrame({"track_id": "cam", "time": times, "x": [2 * t for t in times], "y": 1.0})
    gapped = times[:100] + [t + 5.0 for t in times[100:]]   # 5 s lost after 100 rows
    for min_steps, early in ((1, 1), (4, 0)):
        config = StreamConfig(length_unit=0.01, gap_min_steps=min_steps)
        predictor = TrackPredictor(config)
        rows = [predictor.step_row("cam", t, [2 * t, 1.0]) for t in times]
        assert rows[-1].segment == early and max(r.segment for r in rows) == early
        out = TrackPredictor(config).process_table(table, ["x", "y"])
        assert out["segment"].max() == early
        again = TrackPredictor(config)
        assert [again.step_row("cam", t, [2 * t, 1.0]) for t in gapped][-1].segment == early + 1
    # a row coming back inside an early gap is a wrong timestamp, as after any gap (the first version
    # judged it as a first step is judged and skipped the row at 8)
    from kalmix.streaming import GapTracker

    tracker, codes = GapTracker(), []
    for t in (0, 1, 2, 3, 4, 5, 9, 8, 10):
        new = tracker.advance(float(t), StreamConfig())
        codes.append("S" if new is None else "G" if new else ".")
    assert "".join(codes) == "G.....G.." and tracker.glitches == 1


def test_a_clock_that_restarts_is_said_once():
    """Rows at or before their track's last time are skipped; a sensor clock that restarts at 0 skipped every later
    row of the track with only `skipped` to show for it. The first such row now warns (once per predictor); a
    repeated time in a fresh predictor warns too; kalmix predict on stdin says them line by line instead."""
    import warnings as w

    from kalmix.streaming import SkippedRowWarning

    predictor = _walked()
    with pytest.warns(SkippedRowWarning, match=r"track 0: time 3.0 is not after the track's last time 19.0"):
        assert predictor.step_row(0, 3.0, [3.0, 100.0]) is None
    assert predictor.warn_skipped is False and predictor.skipped == 1
    with w.catch_warnings():
        w.simplefilter("error")
        assert predictor.step_rows([0, 0], [4.0, 5.0], [[4.0, 100.0], [5.0, 100.0]]) == [None, None]
        assert predictor.step_row(0, float("nan"), [1.0, 1.0]) is None   # a missing time: not out of order
    assert predictor.skipped == 4
    with pytest.warns(SkippedRowWarning, match="time 19.0 is not after"):
        _walked().step_rows([0, 1], [19.0, 0.0], [[1.0, 1.0], [2.0, 2.0]])
    # a skip inside a call that then fails (rolled back) warned, and then a kept skip did not
    leading = TrackPredictor(StreamConfig(lead=1000.0, length_unit=0.01, bank="kinematic"))
    with w.catch_warnings():
        w.simplefilter("error")
        with pytest.raises(ValueError):
            leading.step_rows([0, 0, 0], [0.0, 0.0, 1e-9], [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    assert leading.rows == 0 and leading.warn_skipped
    fresh = _walked()
    with pytest.warns(SkippedRowWarning):
        fresh.step_rows([0, 0], [20.0, 20.0], [[20.0, 100.0], [20.0, 100.0]])
