"""``kalmix predict`` and ``kalmix evaluate``: a user's own track files in, predictions and a comparison out.

The logic lives in :mod:`kalmix.streaming` (the per-track predictors, gap rule, state
file) and :mod:`kalmix.experiments.evaluate` (the comparison); this module only reads,
writes and prints.
"""

from __future__ import annotations

import contextlib
import json
import math
import os

import click
import numpy as np

from ..archive import save_figure
from ..bank import (BANK_KINDS, DEFAULT_BANK, DEFAULT_REACH, GATE_OPTIONS, LENGTH_UNIT_RANGE, MAX_HORIZON, MAX_SEED,
                    recipe_parts)
from ._common import figure_format_problem, missing_directory, position_names, user_errors as _user_errors
from ._input import file_format, input_columns, input_format, sample_reader

_LENGTH_UNIT_HELP = ("Typical measurement-noise size in data units (1 for pixels; ~0.01-0.05 for metres; metres for "
                     "geographic coordinates). "
                     "Default 'auto': median |second difference| / (0.6745*sqrt(6)) of the first chunk "
                     "(files) or 1 (stdin, unless a --state file holds one).")
_GAP_HELP = ("A time step larger than this (in the time column's units) starts a new segment: the track's predictor "
             "restarts. "
             "Default: --max-gap-factor times the track's reference interval.")


_GEOGRAPHIC_HELP = ("Positions are latitude and longitude in degrees (and altitude in metres), predicted in metres "
                    "in each track's local frame: latitudes beyond +-90 or longitudes beyond +-180 are errors, "
                    "std_east_m / std_north_m in metres [default: when the position columns are named so: lat, "
                    "lon, latitude, longitude, lng, alt, altitude]. --no-geographic: flat numbers.")


def _column_options(function):
    for option in reversed((
        click.option("--time", "time_column", default=None, help="Time column (default: detected: time, t, "
                     "timestamp, frame, ...; none found = row order)."),
        click.option("--position", "position_columns", multiple=True,
                     callback=lambda ctx, param, given: ",".join(given) if given else None,
                     help="Position columns, comma-separated or the option repeated, 1 to 3 (default: detected: "
                          "x,y[,z], u,v, lat,lon, ...)."),
        click.option("--id", "id_column", default=None, help="Track id column (default: detected: track_id, id, "
                     "track, mmsi, ..., else an unused column named like vessel or player, with a note; an unused "
                     "column whose values look like ids, repeated words say, stops the run, naming it). 'none': the "
                     "input is one track."),
        click.option("--geographic/--no-geographic", default=None, help=_GEOGRAPHIC_HELP),
    )):
        function = option(function)
    return function


def _mixture_options(pairs, bank: bool = False):
    """``--option key=value`` pairs to :func:`kalmix.bank.make_params` keyword arguments; with ``bank``, those of
    a bank's AKF family (the gate's are refused: the family has none)."""
    options = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise click.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint="--option")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        options[key.strip().replace("-", "_")] = value
    for key, flag in (("length_unit", "--length-unit"), ("seed", "--seed")):
        if key in options:
            raise click.BadParameter(f"use {flag} for the {key.replace('_', ' ')}", param_hint="--option")
    known = _option_names(bank)
    for key in options:
        if bank and key in GATE_OPTIONS:
            raise click.BadParameter(f"{key!r} sets the paper's gate, and the bank's AKF family has none: --rule "
                                     f"combines the experts (the family takes {', '.join(known)})",
                                     param_hint="--option")
        if key not in known:
            raise click.BadParameter(f"unknown option {key!r}; expected one of {', '.join(known)}",
                                     param_hint="--option")
    return options


def _option_names(bank: bool = False) -> list[str]:
    """The keyword arguments of :func:`kalmix.bank.make_params` that --option may set (``bank``: of an AKF family)."""
    import inspect

    from ..bank import make_params

    return [name for name, p in inspect.signature(make_params).parameters.items()
            if p.kind == p.KEYWORD_ONLY and name not in ("seed", "length_unit")
            and not (bank and name in GATE_OPTIONS)]


_OPTION_HELP = ("A kalmix.bank.make_params argument, KEY=VALUE (JSON value), repeatable: of the bank's AKF family "
                "(as predict's --option) and of the 'AKF mixture (paper)' and 'single AKF' rows; the "
                "gate's (e.g. --option temperature=4 --option gating=paper) reach only those rows.")
_BANK_OPTION_HELP = ("A kalmix.bank.make_params argument of the bank's AKF family, KEY=VALUE (JSON value), "
                     "repeatable, e.g. --option dynamics=literal --option order=3 (the gate's arguments are refused: "
                     "--rule combines the experts).")


def _length_unit(text):
    if text is None or str(text).lower() == "auto":
        return None
    low, high = LENGTH_UNIT_RANGE
    expected = f"expected a number in [{low:g}, {high:g}] or 'auto', got {text!r}"
    try:
        value = float(text)
    except ValueError:
        raise click.BadParameter(expected, param_hint="--length-unit") from None
    if not low <= value <= high:
        raise click.BadParameter(expected, param_hint="--length-unit")
    return value


_REACH_HELP = ("Across a time step longer than this many time units (--time-unit) only the constant-velocity experts "
               "make the "
               "one-step prediction (the others extrapolate fits made on the usual steps); 'none': every expert "
               "at every step. 8 suits tracks sampled at irregular intervals, with --max-gap none "
               "[default: none].")


def _reach(text):
    """--reach: None (not given), a number of time units > 0, or 'none' (-> math.inf, no reach)."""
    if text is None:
        return None
    if str(text).lower() in ("none", "inf", "never"):
        return math.inf
    expected = f"expected a number of time units > 0 or 'none', got {text!r}"
    try:
        value = float(text)
    except ValueError:
        raise click.BadParameter(expected, param_hint="--reach") from None
    if not (math.isfinite(value) and value > 0):
        raise click.BadParameter(expected, param_hint="--reach")
    return value


def _reach_setting(value):
    """The reach a bank takes: None for 'none' (math.inf here), the default when not given."""
    return DEFAULT_REACH if value is None else (None if math.isinf(value) else value)


def _gap_text(max_gap, factor):
    """A gap rule (``StreamConfig.max_gap`` / ``max_gap_factor``) as the options that give it."""
    if max_gap is not None:
        return f"--max-gap {max_gap:g}" + ("" if factor == 3.0 else f" --max-gap-factor {factor:g}")
    return "--max-gap none" if math.isinf(factor) else f"--max-gap auto --max-gap-factor {factor:g}"


def _check_gap_rule(stored, state_path, gap, never, factor, given):
    """A ``ValueError`` if ``--max-gap`` / ``--max-gap-factor`` (those in ``given``) change a resumed gap rule."""
    want_gap, want_factor = stored.max_gap, stored.max_gap_factor
    if "max_gap" in given:
        want_gap = gap
        if never:
            want_factor = math.inf
        elif stored.max_gap is None and math.isinf(stored.max_gap_factor):   # from 'none' to a rule that splits
            want_factor = factor
    if "max_gap_factor" in given and not never:
        want_factor = factor
    if (want_gap, want_factor) != (stored.max_gap, stored.max_gap_factor):
        name = "--max-gap" if "max_gap" in given else "--max-gap-factor"
        raise ValueError(f"{name}: the state file {state_path} was made with "
                         f"{_gap_text(stored.max_gap, stored.max_gap_factor)}, got {_gap_text(want_gap, want_factor)}; "
                         "use a new --state file to change it")


def _max_gap(text):
    if text is None or str(text).lower() == "auto":
        return None, False
    if str(text).lower() in ("none", "inf", "never"):
        return None, True
    try:
        value = float(text)
    except ValueError:
        raise click.BadParameter(f"expected a time step > 0, 'auto' or 'none', got {text!r}",
                                 param_hint="--max-gap") from None
    if not value > 0:
        raise click.BadParameter(f"expected a time step > 0, 'auto' or 'none', got {text!r}", param_hint="--max-gap")
    return value, False


def _distinct_files(*named):
    """``ValueError`` when two of the ``(option, path)`` pairs (path None or '-': unused) are one file.

    ``kalmix predict data.csv -o data.csv`` would empty the input before reading it, and
    ``--state x -o x`` would replace the predictions by the state at the first save.
    """
    named = [(name, os.fspath(path)) for name, path in named if path not in (None, "-")]
    for i, (first, a) in enumerate(named):
        for second, b in named[i + 1:]:
            same = os.path.realpath(a) == os.path.realpath(b)
            if not same and os.path.exists(a) and os.path.exists(b):
                same = os.path.samefile(a, b)
            if same:
                raise ValueError(f"{second}: {b!r} is the same file as {first} {a!r}; give another name")


def _directory_exists(name, path):
    """``ValueError`` at start when an output file's directory does not exist (not after all the work)."""
    problem = missing_directory(path) if path else None
    if problem:
        directory, taken = problem
        raise ValueError(f"{name}: the directory {directory!r} "
                         f"{'is a file, not a directory' if taken else 'does not exist'}")


def _guess_id(columns, header, sample):
    """:func:`kalmix.streaming.guess_id`, its note told on stderr."""
    from ..streaming import guess_id

    columns, notes = guess_id(columns, header, sample)
    for note in notes:
        click.echo(f"kalmix: {note}", err=True)
    return columns


def _dask_id(input_path, time_column, position_columns, id_column):
    """The --id a Dask run passes on: an archive's first file decides an id that is neither named nor detected
    as a single file does (:func:`_guess_id`: taken with a note, or an error naming the columns). ``--id
    none`` where an id column is detected: an error (the Dask engine reads a detected id column)."""
    from ..dask_predict import archive_files
    from ..io.tables import detect_columns, read_header

    if id_column is not None and id_column.strip().lower() != "none":
        return id_column
    files, fmt = archive_files(input_path)
    header = read_header(files[0], fmt)
    if id_column is not None and id_column in header:
        return id_column
    columns = detect_columns(header, time=time_column, positions=position_names(position_columns))
    if id_column is not None:   # none
        if columns.track_id is not None:
            raise ValueError(f"--id none: --engine dask reads the id column it detects ({columns.track_id!r}); "
                             "run --engine local for one track, or rename that column")
        return None
    if columns.track_id is None:
        columns = _guess_id(columns, header, sample_reader(files[0], fmt))
    return columns.track_id


def _dask_flat(input_path, time_column, position_columns, geographic):
    """``ValueError`` when an archive's positions are geographic (--geographic, or named so): the Dask engine
    takes positions as flat numbers (--engine local predicts them in metres)."""
    if geographic is False:
        return
    from ..dask_predict import archive_files
    from ..io.geo import resolve_axes
    from ..io.tables import detect_columns, read_header

    files, fmt = archive_files(input_path)
    columns = detect_columns(read_header(files[0], fmt), time=time_column,
                             positions=position_names(position_columns))
    if resolve_axes(list(columns.positions), geographic) is not None:
        raise ValueError(f"--engine dask: takes positions as flat numbers, and {list(columns.positions)} are "
                         "geographic coordinates; use --engine local (which predicts them in metres), or "
                         "--no-geographic to take them as flat numbers")


def _given(names):
    """Which of the current command's parameters ``names`` were set on the command line (not defaults)."""
    context = click.get_current_context()
    return {name for name in names
            if context.get_parameter_source(name) not in (None, click.core.ParameterSource.DEFAULT)}


def _local_only(given, output):
    """``click.BadParameter`` for the Dask engine's options without it, or a directory as a file output."""
    for name in ("scheduler", "workers", "partitions"):
        if name in given:
            raise click.BadParameter("needs --engine dask", param_hint=f"--{name}")
    if output is not None and os.path.isdir(output):
        raise click.BadParameter(f"File {output!r} is a directory (a directory is --engine dask's output).",
                                 param_hint="'--output' / '-o'")


# --------------------------------------------------------------------------------------- predict
@click.command()
@click.argument("input_path", metavar="INPUT")
@_column_options
@click.option("--horizon", "-H", default=1, show_default=True, type=click.IntRange(1, MAX_HORIZON),
              help=f"Also predict H time units ahead, H x --time-unit in the time column's units (columns "
                   f"pred<H>_<pos>, std<H>_<pos>); at most {MAX_HORIZON}.")
@click.option("--lead", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Also predict L time-column units after each row (columns lead_<pos>, lead_std_<pos>), with "
                   "weights and intervals learned on lead-L errors. Not with --horizon.")
@click.option("--output", "-o", default=None, type=click.Path(),
              help="Output file: .csv, .parquet or .jsonl (default, or '-': CSV on stdout); with --engine dask a "
                   "new directory (a partitioned Parquet dataset).")
@click.option("--bank", "bank_kind", default=None, type=click.Choice(list(BANK_KINDS)),
              help="Expert families: CV/CA Kalman filters in real time and the paper's AKFs (mixed), "
                   "one of them alone, with adaptive AR models of the velocity (+ar, ar) and coordinated-turn "
                   f"experts (+turn, turn) [default: {DEFAULT_BANK['kind']}].")
@click.option("--rule", default=None, type=click.Choice(["boa", "mlpoly", "fixed_share"]),
              help="Aggregation rule [default: boa].")
@click.option("--time-unit", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Typical sampling interval (the time unit, in the time column's units) that scales the CV/CA "
                   "experts' noise "
                   "[default: the first positive time step of a track, in the order the rows come].")
@click.option("--experts", "n_experts", default=None, type=click.IntRange(min=1),
              help="Experts of the AKF family [default: 40].")
@click.option("--seed", default=None, type=click.IntRange(0, MAX_SEED), help="Seed of the bank [default: 0].")
@click.option("--length-unit", default="auto", show_default=True, help=_LENGTH_UNIT_HELP)
@click.option("--max-gap", default="auto", show_default=True, help=_GAP_HELP + " 'none' never splits.")
@click.option("--max-gap-factor", default=3.0, show_default=True, type=click.FloatRange(min=1.0, min_open=True),
              help="Gap threshold as a multiple of the reference interval (the upper quartile of a track's first "
                   "16 steps).")
@click.option("--reach", default=None, help=_REACH_HELP)
@click.option("--state", "state_path", default=None, type=click.Path(dir_okay=False),
              help="State file: resumed from if it exists, written on exit and every --save-every rows.")
@click.option("--save-every", default=10_000, show_default=True, type=click.IntRange(min=1),
              help="Rows between state saves.")
@click.option("--chunk-rows", default=200_000, show_default=True, type=click.IntRange(min=1),
              help="Rows read at a time from a file (bounded memory); --engine dask: the first chunk "
                   "(the units) and the cells of one engine call.")
@click.option("--progress/--no-progress", default=None, help="Progress bar on stderr [default: when a terminal].")
@click.option("--on-bad-row", default="skip", show_default=True, type=click.Choice(["skip", "fail"]),
              help="A bad row (a field count not the header's, a JSON line without a used key, an empty id, a time "
                   "or position that is not a finite number): skip it (its output row keeps its place with empty "
                   "predictions; the bad rows are counted on stderr at the end, with their lines) or fail: stop at "
                   "it, naming its line.")
@click.option("--rejects", default=None, type=click.Path(dir_okay=False),
              help="Write the skipped bad rows to this CSV file: their line (a Parquet file: row), why, and the row "
                   "as given (a resumed --state run adds to it).")
@click.option("--option", "mixture_options", multiple=True, help=_BANK_OPTION_HELP)
@click.option("--engine", "engine_kind", default="local", show_default=True, type=click.Choice(["local", "dask"]),
              help="local: this process, a file chunk by chunk or stdin; dask: INPUT a directory or glob of "
                   "Parquet or CSV files, shuffled by track over a Dask cluster (the 'dask' extra), the same "
                   "numbers; -o names the output directory.")
@click.option("--backend", default="cpu", show_default=True, type=click.Choice(["cpu", "gpu"]),
              help="--engine local: where the engine runs, the compiled CPU engine or the GPU engine (the 'gpu' "
                   "extra and an NVIDIA GPU; the same numbers, the GPU for many tracks at once).")
@click.option("--scheduler", default=None, help="--engine dask: address of a Dask scheduler "
              "(tcp://host:8786) [default: a local cluster on this machine's cores].")
@click.option("--workers", default=None, type=click.IntRange(min=1),
              help="--engine dask: worker processes of the local cluster [default: the cores].")
@click.option("--partitions", default=None, type=click.IntRange(min=1),
              help="--engine dask: partitions of the shuffle by track [default: the input's, at least "
                   "4 per worker thread].")
def predict(input_path, time_column, position_columns, id_column, geographic, horizon, lead, output, bank_kind, rule,
            time_unit, n_experts, seed, length_unit, max_gap, max_gap_factor, reach, state_path, save_every, chunk_rows,
            progress, on_bad_row, rejects, mixture_options, engine_kind, backend, scheduler, workers, partitions):
    """Predict the next position of every track in INPUT (CSV, Parquet, or - for stdin).

    Output: one row per input row, in the input's order, with the input's id and time columns
    as given (text as written, Parquet types kept), then 'segment', pred_<position> and
    std_<position>: the prediction for the time of the track's next row and its calibrated
    standard deviation (pred +- 1.96 std is a 95 % interval). A row that is not predicted (no
    time, an earlier row of a repeated time, a time not after its track's last) has them empty;
    a resumed --state run leaves out the rows an earlier run did. A bad row (see --on-bad-row)
    is skipped the same way, and the run says at the end how many and on which lines. In a file the next row's time
    is known; on stdin, which must answer first, and for a track's last row, it is one reference
    interval on.
    --lead L adds lead_<position> / lead_std_<position> at time + L (--horizon H: pred<H>_ /
    std<H>_ at H time units), the same in files and on stdin. A file is processed in chunks,
    all tracks at once through the batched core; '-' reads CSV rows (header first) or JSON
    lines from stdin and writes each prediction as soon as its measurement arrives (lines that
    arrive together, a frame or a piped file, are stepped together, with the same results).

    Stopped by Ctrl-C, SIGTERM or SIGHUP, it saves the --state file to match what it wrote
    (a chunk in progress is rolled back, stdin rows already read are finished) and exits with
    128 + the signal number; the same command then continues (-o is continued, not rewritten).

    With --engine dask, INPUT is a directory or glob of Parquet (or CSV) files, rows of a track
    in any of them, and -o a new directory that receives a partitioned Parquet dataset of the
    predicted rows with the same columns and numbers, grouped by track (each partition holds
    whole tracks, each in time order) and the time column in seconds (see 'Beyond one machine'
    in the documentation).
    """
    from ..streaming import TrackPredictor
    from ._durable import SignalGuard, StateLock
    from ._predict_run import run_predict

    unit = _length_unit(length_unit)
    gap, never = _max_gap(max_gap)
    reach = _reach(reach)
    options = _mixture_options(mixture_options, bank=True)
    output = None if output == "-" else output   # stdout, as '-' for INPUT is stdin
    out_fmt = file_format(output) if output else "csv"
    given = _given(("save_every", "scheduler", "workers", "partitions", "on_bad_row", "rejects"))
    with _user_errors():
        if engine_kind == "dask":
            from ._predict_dask import check_options
            check_options(input_path, output, state_path, given)
            for name in ("on_bad_row", "rejects"):
                if name in given:
                    raise click.BadParameter("runs with --engine local (the Dask engine stops at a bad value, "
                                             "naming its file)", param_hint=f"--{name.replace('_', '-')}")
            if backend != "cpu":
                raise ValueError(f"--backend {backend}: runs with --engine local (each Dask worker runs the CPU "
                                 "engine)")
        else:
            _local_only(given, output)
        from ..streaming import check_backend
        check_backend(backend)
        if backend == "gpu":
            click.echo("kalmix: --backend gpu compiles its kernels once in each run, at the first rows (about 4 "
                       "minutes for the default bank on an H100)", err=True)
        if rejects is not None and on_bad_row == "fail":
            raise click.BadParameter("lists the bad rows skipped, and --on-bad-row fail skips none",
                                     param_hint="--rejects")
        _distinct_files(("INPUT", input_path), ("--output", output), ("--state", state_path), ("--rejects", rejects))
        _directory_exists("--rejects", rejects)
    with _user_errors(), SignalGuard() as guard, \
            (StateLock(state_path) if state_path else contextlib.nullcontext()):
        engine = None
        if state_path and os.path.exists(state_path):
            engine = TrackPredictor.load(state_path, backend=backend)
            stored = engine.config
            for name, given, have in (("--experts", n_experts, stored.n_experts), ("--seed", seed, stored.seed),
                                      ("--length-unit", unit, stored.length_unit),
                                      ("--horizon", horizon if horizon != 1 else None, stored.horizon),
                                      ("--lead", lead, stored.lead),
                                      ("--bank", bank_kind, stored.bank), ("--rule", rule, stored.rule),
                                      ("--time-unit", time_unit, stored.time_unit),
                                      ("--geographic" if geographic else "--no-geographic", geographic,
                                       engine.axes is not None),
                                      ("--reach", reach, math.inf if stored.reach is None else stored.reach),
                                      ("--option", options or None, stored.options)):
                if given is not None and given != have:
                    if name == "--reach":
                        have, given = (("none" if math.isinf(v) else v) for v in (have, given))
                    if name in ("--geographic", "--no-geographic"):
                        have, given = (("geographic positions" if v else "flat positions") for v in (have, given))
                    raise ValueError(f"{name}: the state file {state_path} was made with {have}, got {given}; "
                                     "use a new --state file to change it")
            _check_gap_rule(stored, state_path, gap, never, max_gap_factor, _given(("max_gap", "max_gap_factor")))
        kind = bank_kind or (engine.config.bank if engine is not None else DEFAULT_BANK["kind"])
        if "akf" not in recipe_parts(kind) and (n_experts is not None or options):
            raise ValueError(f"{'--experts' if n_experts is not None else '--option'}: sets the AKF family, "
                             f"and --bank {kind} has none (use --bank mixed, mixed+ar, mixed+ar+turn or akf)")
        if reach is not None and math.isfinite(reach) and "kinematic" not in recipe_parts(kind):
            click.echo(f"kalmix: warning: --reach: --bank {kind} has no constant-velocity experts to keep across "
                       "long steps, so the reach changes nothing", err=True)
        if lead is not None and horizon != 1:
            raise ValueError(f"--lead and --horizon: give one of them (--horizon H is the lead of H time units), "
                             f"got --lead {lead:g} and --horizon {horizon}")
        settings = dict(n_experts=40 if n_experts is None else n_experts, seed=0 if seed is None else seed,
                        horizon=horizon, lead=lead, max_gap=gap, max_gap_factor=math.inf if never else max_gap_factor,
                        options=options, time_unit=time_unit, reach=_reach_setting(reach), geographic=geographic)
        if bank_kind is not None:
            settings["bank"] = bank_kind
        if rule is not None:
            settings["rule"] = rule
        if engine is None and options:
            from ..bank import make_params
            make_params(1, settings["n_experts"], **options)  # a bad option fails before any output
        if engine_kind == "dask":
            from ._predict_dask import run_dask
            _dask_flat(input_path, time_column, position_columns, geographic)
            id_column = _dask_id(input_path, time_column, position_columns, id_column)
            return run_dask(input_path, output, settings, unit, time_column, position_columns, id_column,
                            chunk_rows, progress, scheduler, workers, partitions)
        if input_path == "-" and out_fmt == "parquet":
            raise ValueError("--output: streaming from stdin writes CSV or JSON lines, got a .parquet name")
        run_predict(guard, engine, settings, unit, input_path, state_path, save_every, output, out_fmt,
                    time_column, position_columns, id_column, chunk_rows, progress, backend,
                    on_bad_row=on_bad_row, rejects=rejects)


# -------------------------------------------------------------------------------------- evaluate
@click.command()
@click.argument("input_path", metavar="[INPUT]", required=False)
@click.option("--dataset", default=None, help="A shipped recording instead of INPUT: hawkeye_ball, skillcorner, "
              "cycling (needs the 'data' extra).")
@_column_options
@click.option("--horizon", "-H", default=1, show_default=True, type=click.IntRange(1, MAX_HORIZON),
              help=f"Also report the H-step errors; at most {MAX_HORIZON}.")
@click.option("--experts", "n_experts", default=40, show_default=True, type=click.IntRange(min=1),
              help="Experts of the bank's AKF family (as predict's --experts) and of the AKF mixture row.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(0, MAX_SEED),
              help="Seed of the bank and of the AKF mixture row.")
@click.option("--length-unit", default="auto", show_default=True,
              help="The mixtures' length unit (and the other AKF rows'; the peers' noise grids keep the "
                   "rule's); 'auto': the second-difference rule on the tuning part.")
@click.option("--tuning-fraction", default=0.2, show_default=True, type=click.FloatRange(0.0, 1.0, max_open=True),
              help="Leading share of each track used to tune the peers (and the length unit), not scored.")
@click.option("--max-gap", default="auto", show_default=True, help=_GAP_HELP + " 'none' never splits.")
@click.option("--max-gap-factor", default=3.0, show_default=True, type=click.FloatRange(min=1.0, min_open=True),
              help="Gap threshold as a multiple of the reference interval (the upper quartile of a track's first "
                   "16 steps).")
@click.option("--reach", default=None, help=_REACH_HELP)
@click.option("--max-samples", default=None, type=click.IntRange(min=3),
              help="Use only the first N samples of each track (quicker).")
@click.option("--tracks", default=None, help="Comma-separated track ids to keep.")
@click.option("--peers/--no-peers", default=True, show_default=True,
              help="Include the peers (CV/CA Kalman filters in real time; where installed, filterpy's IMM and MMAE "
                   "bank, river's Holt-Winters, padasip's RLS AR, statsmodels' local linear trend), each tuned on "
                   "the tuning part; --no-peers: the mixture and kalmix's own baselines only.")
@click.option("--json", "json_path", default=None, type=click.Path(dir_okay=False), help="Write the results as JSON.")
@click.option("--per-coordinate", is_flag=True, default=False,
              help="Errors per coordinate (each coordinate's |e| pooled) instead of each row's distance |e|.")
@click.option("--plot", "plot_path", default=None, type=click.Path(dir_okay=False),
              help="PNG of the one-step error over time for --track.")
@click.option("--plot-row", "plot_rows", multiple=True,
              help="A row to draw in --plot, by its name in the table (repeat for several; 'all': every row). "
                   "Default: kalmix, the best tuned peer, CV Kalman and no prediction.")
@click.option("--plot-intervals", "intervals_path", default=None, type=click.Path(dir_okay=False),
              help="PNG of --track's positions, the mixture's one-step predictions and their 95 % ellipses.")
@click.option("--track", "plot_track", default=None, help="Track id to plot (default: the first).")
@click.option("--per-track/--no-per-track", default=True, show_default=True, help="Print the per-track tables.")
@click.option("--option", "mixture_options", multiple=True, help=_OPTION_HELP)
def evaluate(input_path, dataset, time_column, position_columns, id_column, geographic, horizon, n_experts, seed,
             length_unit, tuning_fraction, max_gap, max_gap_factor, reach, max_samples, tracks, peers, json_path,
             per_coordinate, plot_path, plot_rows, intervals_path, plot_track, per_track, mixture_options):
    """Compare the mixture's prediction errors with the predictors you would use instead.

    Every predictor runs online over each track segment; the first --tuning-fraction of each
    track tunes the CV/CA Kalman filters and the IMM (grid search, one-step RMS) and the
    length unit, and is not scored. The output starts with the verdict, kalmix's RMS against
    the best tuned peer's, then ranks the rows. Errors are each row's distance between forecast
    and measurement (--per-coordinate: each coordinate's), in data units.
    """
    import pandas as pd

    from ..experiments.evaluate import PREDICTORS, evaluate_table, format_result

    unit = _length_unit(length_unit)
    gap, never = _max_gap(max_gap)
    reach = _reach(reach)
    options = _mixture_options(mixture_options)
    with _user_errors():
        if (input_path is None) == (dataset is None):
            raise ValueError("give either INPUT or --dataset NAME")
        _distinct_files(("INPUT", input_path), ("--json", json_path), ("--plot", plot_path),
                        ("--plot-intervals", intervals_path))
        for flag, named in (("--json", json_path), ("--plot", plot_path), ("--plot-intervals", intervals_path)):
            if named == "-":   # it would write a file named '-' (predict's '-' is standard output)
                raise ValueError(f"{flag}: expected a file name, got '-' (standard output is not taken here: "
                                 "/dev/stdout is; ./- names a file called -)")
        _directory_exists("--json", json_path)
        _directory_exists("--plot", plot_path)
        _directory_exists("--plot-intervals", intervals_path)
        if dataset is not None:
            from ..io import load_dataset
            table = load_dataset(dataset)
            label = dataset
        else:
            from ..io import read_tracks
            from ..io.tables import read_header
            if not os.path.exists(input_path):
                raise FileNotFoundError(f"INPUT: no such file {input_path!r}")
            if os.path.isdir(input_path):
                raise ValueError(f"INPUT: expected a track file (CSV or Parquet), got the directory {input_path!r}")
            fmt = input_format(input_path)
            columns = input_columns(read_header(input_path, fmt), time_column, position_columns, id_column,
                                    sample_reader(input_path, fmt))
            import warnings

            from ..io.tables import BadRowWarning

            with warnings.catch_warnings():   # said below, as kalmix predict says it
                warnings.simplefilter("ignore", BadRowWarning)
                table = read_tracks(input_path, columns=columns, format=fmt, ids_as_text=True, on_bad_row="skip")
            if "bad_rows" in table.attrs:
                click.echo(f"kalmix: error: {table.attrs['bad_rows'].summary()}: not evaluated", err=True)
            label = os.path.basename(input_path)
            _check_file_degrees(table, list(columns.positions), geographic)
        if tracks is not None and not tracks.strip(", "):
            raise ValueError(f"--tracks: expected comma-separated track ids, got {tracks!r}")
        wanted = _wanted_tracks(tracks, table) if tracks else None
        if plot_track is not None and not (plot_path or intervals_path):
            raise ValueError("--track: picks the track of --plot or --plot-intervals; give one of them")
        shown = "all" if "all" in plot_rows else list(plot_rows) or None
        if plot_rows and not plot_path:
            raise ValueError("--plot-row: picks the rows of --plot; give it")
        known = (*PREDICTORS, "mixture, one-step weights")
        unknown = [r for r in plot_rows if r not in (*known, "all")]
        if unknown:
            raise ValueError(f"--plot-row: expected 'all' or a row's name ({'; '.join(known)}), got {unknown[0]!r}")
        for flag, path in (("--plot", plot_path), ("--plot-intervals", intervals_path)):   # before the work
            if path:
                _check_figure_path(flag, path)
        positions = [c for c in table.columns if c not in ("track_id", "time")]
        if intervals_path and len(positions) < 2:
            raise ValueError(f"--plot-intervals: needs two position coordinates, the data has {len(positions)}")
        if (plot_path or intervals_path) and plot_track is not None:  # before the work, not after it
            names = [str(t) for t in pd.unique(table["track_id"])]
            names = [t for t in names if wanted is None or t in wanted]
            if str(plot_track) not in names:
                raise ValueError(f"--track: expected one of {names[:20]}{' ...' if len(names) > 20 else ''}, "
                                 f"got {plot_track!r}")
            rows = int((table["track_id"].astype(str) == str(plot_track)).sum())
            rows = rows if max_samples is None else min(rows, int(max_samples))
            if max(rows, 1) <= max(math.ceil(tuning_fraction * rows), 1):   # nothing after its tuning part
                raise ValueError(f"--track {plot_track}: no scored error to plot (its {rows} row(s) are in the tuning "
                                 "part, or alone); pick a longer track")
        result = evaluate_table(table, horizon=horizon, n_experts=n_experts, seed=seed, length_unit=unit,
                                tuning_fraction=tuning_fraction, max_gap=gap,
                                max_gap_factor=math.inf if never else max_gap_factor, max_samples=max_samples,
                                tracks=wanted, peers=peers, options=options, geographic=geographic,
                                metric="per-coordinate" if per_coordinate else "euclidean",
                                bank_options={**DEFAULT_BANK, "reach": _reach_setting(reach)},
                                log=lambda message: click.echo(f"kalmix: {message}", err=True))
        result.dataset = label
        click.echo(format_result(result, per_track=per_track))
        if json_path:
            from ..archive import replaced_file

            try:
                with replaced_file(json_path, "w", what="a JSON file path", output=True) as handle:
                    json.dump(result.to_json(), handle, indent=2)
            except OSError as error:   # a full disk, a device: name the option and the path, not only the OS error
                raise ValueError(f"--json: cannot write {json_path!r}: {error.strerror or error}") from None
        if plot_path:
            from ..experiments.evaluate import plot_rows, track_columns
            from ..plots import evaluate_errors

            track, columns = track_columns(result, plot_track)
            evaluate_errors(result, plot_path, track=track, columns=columns, rows=plot_rows(result, shown))
            click.echo(f"wrote {plot_path}")
        if intervals_path:
            plot_intervals(result, intervals_path, plot_track)
            click.echo(f"wrote {intervals_path}")


def _check_file_degrees(table, names, geographic) -> None:
    """A ``ValueError`` naming the first file row (counted from 0 after the header) whose latitude is beyond ±90° or
    longitude beyond ±180°, when the positions are geographic."""
    from ..io.geo import check_degrees, resolve_axes

    axes = resolve_axes(names, geographic)
    if axes is None:
        return
    order = table.attrs.get("file_order")
    places = np.asarray(getattr(order, "places", np.arange(len(table))))
    if len(places) != len(table):
        places = np.arange(len(table))
    rank = np.argsort(places, kind="stable")
    check_degrees(table[names].to_numpy(np.float64)[rank], axes, names,
                  lambda i: f"row {int(places[rank[i]])} (counted from 0 after the header)")


def _wanted_tracks(tracks: str, table) -> list[str]:
    """``--tracks``' ids: each as written when the data has it (" 7" is not "7"), else without the spaces around
    it ("a, b"); empty entries (a trailing comma) are skipped."""
    have = set(table["track_id"].astype(str))
    return [entry if entry in have else entry.strip() for entry in tracks.split(",") if entry.strip()]


def _track_columns(result, track):
    """The plotted track (given, else the first with a scored error) and its segments' columns."""
    from ..experiments.evaluate import track_columns

    return track_columns(result, track)


def _check_figure_path(flag, path):
    """``ValueError`` unless matplotlib can write ``path``'s format (its extension: .png, .pdf, .svg, ...)."""
    problem = figure_format_problem(path)
    if problem:
        raise ValueError(f"{flag}: {problem}")


def plot_intervals(result, path, track=None, rows: int = 30):
    """PNG: ``rows`` scored samples of a track (the first two coordinates), the mixture's one-step
    predictions and their 95 % ellipses (chi-square with 2 degrees of freedom on the calibrated covariance)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    streams = result.streams
    track, columns = _track_columns(result, track)
    if streams.values.shape[2] < 2:
        raise ValueError("--plot-intervals: needs two position coordinates, the data has one")
    forecasts, covariance = result.intervals
    j = max(columns, key=lambda c: streams.lengths[c])        # the track's longest segment
    n = int(streams.lengths[j])
    # the scored rows (the track's first tuning_fraction is not scored), as many as there are up to ``rows``
    track_rows = int(streams.lengths[streams.track_of == streams.track_of[j]].sum())
    scored = np.flatnonzero(streams.sample_index[:n, j] >= np.ceil(result.tuning_fraction * track_rows))
    start = min(int(scored[0]), max(0, n - rows)) if scored.size else max(0, n - rows)
    part = slice(start, min(n, start + rows))
    z, mean, cov = streams.values[part, j, :2], forecasts[part, j, :2], covariance[part, j, :2, :2]
    inside = []
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    for m, c, actual in zip(mean, cov, z):
        if not (np.isfinite(m).all() and np.isfinite(c).all() and np.isfinite(actual).all()):
            continue
        values, vectors = np.linalg.eigh(c)
        width, height = 2 * np.sqrt(5.991464547107979 * np.maximum(values, 0))
        angle = np.degrees(np.arctan2(vectors[1, 1], vectors[0, 1]))
        ax.add_patch(Ellipse(m, width[()] if np.ndim(width) else width, height, angle=angle, fill=False, lw=0.6,
                             color="tab:orange", alpha=0.7))
        inside.append(float((actual - m) @ np.linalg.solve(c, actual - m)) <= 5.991464547107979)
    names = streams.position_names
    ax.plot(z[:, 0], z[:, 1], ".-", color="black", lw=0.8, ms=3, label="measurements")
    ax.plot(mean[:, 0], mean[:, 1], "x", color="tab:blue", ms=4, label="one-step predictions")
    ax.plot([], [], color="tab:orange", lw=0.8, label=f"95 % ellipses ({np.mean(inside):.0%} hold the measurement)")
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"{result.dataset}: track {track}, samples {start}-{part.stop - 1} of a segment")
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
