"""``kalmix predict``: a user's own track files in, predictions out.

The logic lives in :mod:`kalmix.streaming` (the per-track predictors, gap rule, state
file); this module checks the options and a resumed state file's settings, and hands the
run to :mod:`._predict_run` (this process) or :mod:`._predict_dask` (a Dask cluster).
"""

from __future__ import annotations

import contextlib
import math
import os

import click

from ..bank import BANK_KINDS, DEFAULT_BANK, MAX_HORIZON, MAX_SEED, recipe_parts
from ..core.aggregators import RULES
from ._common import position_names, user_errors as _user_errors
from ._input import output_format, sample_reader
from ._options import (GAP_HELP, REACH_HELP, check_directory, column_options, distinct_files, parse_length_unit,
                       parse_max_gap, parse_mixture_options, parse_reach, reach_setting)

_LENGTH_UNIT_HELP = ("Typical measurement-noise size in data units (1 for pixels; ~0.01-0.05 for metres; metres for "
                     "geographic coordinates). "
                     "Default 'auto': median |second difference| / (0.6745*sqrt(6)) of the first chunk "
                     "(files) or 1 (stdin, unless a --state file holds one).")


_BANK_OPTION_HELP = ("A kalmix.bank.make_params argument of the bank's AKF family, KEY=VALUE (JSON value), "
                     "repeatable, e.g. --option dynamics=literal --option order=3 (the gate's arguments are refused: "
                     "--rule combines the experts).")


def _check_options(input_path, output, state_path, rejects, on_bad_row, engine_kind, backend, given) -> None:
    """Refuse the options that do not go together (``given``: those set on the command line), and files that
    cannot be the run's, before any work."""
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
    if rejects is not None and os.path.splitext(rejects)[1].lower() not in ("", ".csv", ".txt"):
        raise click.BadParameter(f"expected a .csv file name (the rows skipped are written as CSV), got {rejects!r}",
                                 param_hint="--rejects")
    if rejects is not None and on_bad_row == "fail":
        raise click.BadParameter("lists the bad rows skipped, and --on-bad-row fail skips none",
                                 param_hint="--rejects")
    distinct_files(("INPUT", input_path), ("--output", output), ("--state", state_path), ("--rejects", rejects))
    check_directory("--rejects", rejects)


def _check_state(engine, state_path, *, n_experts, seed, unit, horizon, lead, bank_kind, rule, time_unit, geographic,
                 reach, options) -> None:
    """A ``ValueError`` for an option given with another value than the one the state file was made with."""
    stored = engine.config
    for name, given, have in (("--experts", n_experts, stored.n_experts), ("--seed", seed, stored.seed),
                              ("--length-unit", unit, stored.length_unit),
                              ("--horizon", horizon if horizon != 1 else None, stored.horizon),
                              ("--lead", lead, stored.lead),
                              ("--bank", bank_kind, stored.bank), ("--rule", rule, stored.rule),
                              ("--time-unit", time_unit, stored.time_unit),
                              ("--geographic" if geographic else "--no-geographic", geographic,
                               engine.axes is not None),
                              ("--reach", None if stored.reach == "auto" else reach,   # (not settled yet: given)
                               math.inf if stored.reach is None else stored.reach),
                              ("--option", options or None, stored.options)):
        if given is not None and given != have:
            if name == "--reach":
                have, given = (("none" if isinstance(v, float) and math.isinf(v) else v) for v in (have, given))
            if name in ("--geographic", "--no-geographic"):
                have, given = (("geographic positions" if v else "flat positions") for v in (have, given))
            raise ValueError(f"{name}: the state file {state_path} was made with {have}, got {given}; "
                             "use a new --state file to change it")


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
@column_options
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
                   "one of them alone, with adaptive AR models of the velocity (+ar, ar), coordinated-turn "
                   "extrapolations (+turn, turn) and coordinated-turn Kalman filters (+ct, ct) "
                   f"[default: {DEFAULT_BANK['kind']}].")
@click.option("--rule", default=None, type=click.Choice(list(RULES)),
              help="Aggregation rule: boa_blend, BOA on the linearised and on the exact regrets, blended (follows "
                   "the right expert where the others are far off at some rows: constant acceleration at irregular "
                   "steps); BOA alone (up to 12 % faster, 4-5 kB less per track); ML-Poly; fixed share "
                   f"[default: {DEFAULT_BANK['rule']}].")
@click.option("--time-unit", default=None, type=click.FloatRange(min=0, min_open=True),
              help="Typical sampling interval (the time unit, in the time column's units) that scales the CV/CA "
                   "experts' noise "
                   "[default: the median time step of a file's first chunk; on stdin, the first time step].")
@click.option("--experts", "n_experts", default=None, type=click.IntRange(min=1),
              help="Experts of the AKF family [default: 40].")
@click.option("--seed", default=None, type=click.IntRange(0, MAX_SEED), help="Seed of the bank [default: 0].")
@click.option("--length-unit", default="auto", show_default=True, help=_LENGTH_UNIT_HELP)
@click.option("--max-gap", default="auto", show_default=True, help=GAP_HELP + " 'none' never splits.")
@click.option("--max-gap-factor", default=3.0, show_default=True, type=click.FloatRange(min=1.0, min_open=True),
              help="Gap threshold as a multiple of the reference interval (the upper quartile of a track's first "
                   "16 steps times their spread, the upper over the lower quartile, to the power 1.5).")
@click.option("--reach", default=None, help=REACH_HELP)
@click.option("--population-prior/--no-population-prior", default=None,
              help="A new track's aggregation rule starts from what the tracks before it learned (in the order the "
                   "rows came: a file, its chunks and the same rows on stdin learn alike), instead of empty: a large "
                   "gain on files of many short tracks [default: on; a resumed --state run as it started; "
                   "--engine dask: off].")
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
            time_unit, n_experts, seed, length_unit, max_gap, max_gap_factor, reach, population_prior, state_path,
            save_every, chunk_rows, progress, on_bad_row, rejects, mixture_options, engine_kind, backend, scheduler,
            workers, partitions):
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

    unit = parse_length_unit(length_unit)
    gap, never = parse_max_gap(max_gap)
    reach = parse_reach(reach)
    options = parse_mixture_options(mixture_options, bank=True)
    output = None if output == "-" else output   # stdout, as '-' for INPUT is stdin
    given = _given(("save_every", "scheduler", "workers", "partitions", "on_bad_row", "rejects"))
    with _user_errors():
        _check_options(input_path, output, state_path, rejects, on_bad_row, engine_kind, backend, given)
        out_fmt = output_format(output) if output and engine_kind != "dask" else "csv"
    with _user_errors(), SignalGuard() as guard, \
            (StateLock(state_path) if state_path else contextlib.nullcontext()):
        engine = None
        if state_path and os.path.exists(state_path):
            engine = TrackPredictor.load(state_path, backend=backend)
            if unit is None and isinstance(engine.config.length_unit, float):   # (said as a new run says its own)
                metres = " m" if engine.config.geographic else ""
                click.echo(f"kalmix: length unit {engine.config.length_unit:.6g}{metres} (from the state file "
                           f"{state_path})", err=True)
            _check_state(engine, state_path, n_experts=n_experts, seed=seed, unit=unit, horizon=horizon, lead=lead,
                         bank_kind=bank_kind, rule=rule, time_unit=time_unit, geographic=geographic, reach=reach,
                         options=options)
            if reach is not None:   # a reach given to a file whose reach is not settled yet (only first rows seen)
                engine.settle_reach(None if math.isinf(reach) else reach)
            _check_gap_rule(engine.config, state_path, gap, never, max_gap_factor,
                            _given(("max_gap", "max_gap_factor")))
            if population_prior is not None and population_prior != engine.config.population_prior:
                flag = "--population-prior" if population_prior else "--no-population-prior"
                raise ValueError(f"{flag}: the state file {state_path} was started "
                                 f"{'without' if population_prior else 'with'} the population prior; resume without "
                                 "the option, or start a new state file")
        kind = bank_kind or (engine.config.bank if engine is not None else DEFAULT_BANK["kind"])
        if "akf" not in recipe_parts(kind) and (n_experts is not None or options):
            raise ValueError(f"{'--experts' if n_experts is not None else '--option'}: sets the AKF family, "
                             f"and --bank {kind} has none (use --bank mixed, mixed+ar, mixed+ar+turn, "
                             "mixed+ar+turn+ct or akf)")
        if reach is not None and math.isfinite(reach) and "kinematic" not in recipe_parts(kind):
            click.echo(f"kalmix: warning: --reach: --bank {kind} has no constant-velocity experts to keep across "
                       "long steps, so the reach changes nothing", err=True)
        if lead is not None and horizon != 1:
            raise ValueError(f"--lead and --horizon: give one of them (--horizon H is the lead of H time units), "
                             f"got --lead {lead:g} and --horizon {horizon}")
        settings = dict(n_experts=40 if n_experts is None else n_experts, seed=0 if seed is None else seed,
                        horizon=horizon, lead=lead, max_gap=gap, max_gap_factor=math.inf if never else max_gap_factor,
                        options=options, time_unit=time_unit, reach=reach_setting(reach), geographic=geographic,
                        population_prior=True if population_prior is None else population_prior)
        if bank_kind is not None:
            settings["bank"] = bank_kind
        if rule is not None:
            settings["rule"] = rule
        if engine is None and options:
            from ..bank import make_params
            make_params(1, settings["n_experts"], **options)  # a bad option fails before any output
        if engine_kind == "dask":
            from ._predict_dask import run_dask
            if population_prior:
                raise ValueError("--population-prior: not with --engine dask (a partition's tracks do not see the "
                                 "other partitions' tracks); use --engine local")
            settings["population_prior"] = False   # (said with the cluster's first line, _predict_dask)
            _dask_flat(input_path, time_column, position_columns, geographic)
            id_column = _dask_id(input_path, time_column, position_columns, id_column)
            return run_dask(input_path, output, settings, unit, time_column, position_columns, id_column,
                            chunk_rows, progress, scheduler, workers, partitions)
        if input_path == "-" and out_fmt == "parquet":
            raise ValueError("--output: streaming from stdin writes CSV or JSON lines, got a .parquet name")
        run_predict(guard, engine, settings, unit, input_path, state_path, save_every, output, out_fmt,
                    time_column, position_columns, id_column, chunk_rows, progress, backend,
                    on_bad_row=on_bad_row, rejects=rejects)


