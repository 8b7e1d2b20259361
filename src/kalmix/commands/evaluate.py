"""``kalmix evaluate``: a user's own track file (or a shipped recording) in, the comparison of the mixture with
the predictors one would use instead out.

The comparison lives in :mod:`kalmix.experiments.evaluate`; this module only reads, checks the
options, writes and prints.
"""

from __future__ import annotations

import json
import math
import os

import click
import numpy as np

from ..archive import save_figure
from ..bank import DEFAULT_BANK, MAX_HORIZON, MAX_SEED
from ..core.aggregators import RULES
from ._common import figure_format_problem, user_errors as _user_errors
from ._input import track_file
from ._options import (GAP_HELP, REACH_HELP, check_directory, column_options, distinct_files, parse_length_unit,
                       parse_max_gap, parse_mixture_options, parse_reach, reach_setting)


_OPTION_HELP = ("A kalmix.bank.make_params argument, KEY=VALUE (JSON value), repeatable: of the bank's AKF family "
                "(as predict's --option) and of the 'AKF mixture (paper)' and 'single AKF' rows; the "
                "gate's (e.g. --option temperature=4 --option gating=paper) reach only those rows.")


@click.command()
@click.argument("input_path", metavar="[INPUT]", required=False)
@click.option("--dataset", default=None, help="A shipped recording instead of INPUT: hawkeye_ball, skillcorner, "
              "cycling (needs the 'data' extra).")
@column_options
@click.option("--horizon", "-H", default=1, show_default=True, type=click.IntRange(1, MAX_HORIZON),
              help=f"Also report the H-step errors; at most {MAX_HORIZON}.")
@click.option("--experts", "n_experts", default=40, show_default=True, type=click.IntRange(min=1),
              help="Experts of the bank's AKF family (as predict's --experts) and of the AKF mixture row.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(0, MAX_SEED),
              help="Seed of the bank and of the AKF mixture row.")
@click.option("--rule", default=DEFAULT_BANK["rule"], show_default=True, type=click.Choice(list(RULES)),
              help="The mixture's aggregation rule, as predict's --rule.")
@click.option("--length-unit", default="auto", show_default=True,
              help="The mixtures' length unit (and the other AKF rows'; the peers' noise grids keep the "
                   "rule's); 'auto': the second-difference rule on the tuning part.")
@click.option("--time-unit", default=None, type=click.FloatRange(min=0, min_open=True),
              help="The mixture's time unit, as predict's --time-unit (the typical sampling interval, in the time "
                   "column's units) [default: learned on the tuning part].")
@click.option("--tuning-fraction", default=0.2, show_default=True, type=click.FloatRange(0.0, 1.0, max_open=True),
              help="Leading share of each track used to tune the peers (and the length unit), not scored.")
@click.option("--max-gap", default="auto", show_default=True, help=GAP_HELP + " 'none' never splits.")
@click.option("--max-gap-factor", default=3.0, show_default=True, type=click.FloatRange(min=1.0, min_open=True),
              help="Gap threshold as a multiple of the reference interval (the upper quartile of a track's first "
                   "16 steps times their spread, the upper over the lower quartile, to the power 1.5).")
@click.option("--reach", default=None, help=REACH_HELP)
@click.option("--max-samples", default=None, type=click.IntRange(min=3),
              help="Use only the first N samples of each track (quicker).")
@click.option("--tracks", default=None, help="Comma-separated track ids to keep.")
@click.option("--peers/--no-peers", default=True, show_default=True,
              help="Include the peers (CV/CA Kalman filters in real time; where installed, filterpy's IMM and MMAE "
                   "bank, river's Holt-Winters, padasip's RLS AR, statsmodels' local linear trend), each tuned on "
                   "the tuning part; --no-peers: the mixture, kalmix's own baselines and the CV/CA Kalman filters in "
                   "real time only (no peer library).")
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
             rule, length_unit, time_unit, tuning_fraction, max_gap, max_gap_factor, reach, max_samples, tracks, peers,
             json_path, per_coordinate, plot_path, plot_rows, intervals_path, plot_track, per_track, mixture_options):
    """Compare the mixture's prediction errors with the predictors you would use instead.

    Every predictor runs online over each track segment; the first --tuning-fraction of each
    track tunes the CV/CA Kalman filters and the IMM (grid search, one-step RMS) and the
    length unit, and is not scored. The output starts with the verdict, kalmix's RMS against
    the best tuned peer's, then ranks the rows. Errors are each row's distance between forecast
    and measurement (--per-coordinate: each coordinate's), in data units.
    """
    from ..experiments.evaluate import evaluate_table, format_result

    unit = parse_length_unit(length_unit)
    gap, never = parse_max_gap(max_gap)
    reach = parse_reach(reach)
    options = parse_mixture_options(mixture_options)
    with _user_errors():
        if (input_path is None) == (dataset is None):
            raise ValueError("give either INPUT or --dataset NAME")
        _check_outputs(input_path, json_path, plot_path, intervals_path)
        table, label = _read_table(input_path, dataset, time_column, position_columns, id_column, geographic)
        if tracks is not None and not tracks.strip(", "):
            raise ValueError(f"--tracks: expected comma-separated track ids, got {tracks!r}")
        wanted = _wanted_tracks(tracks, table) if tracks else None
        shown = _check_plots(table, wanted, plot_path, plot_rows, intervals_path, plot_track, max_samples,
                             tuning_fraction)
        result = evaluate_table(table, horizon=horizon, n_experts=n_experts, seed=seed, length_unit=unit,
                                tuning_fraction=tuning_fraction, max_gap=gap,
                                max_gap_factor=math.inf if never else max_gap_factor, max_samples=max_samples,
                                tracks=wanted, peers=peers, options=options, geographic=geographic,
                                metric="per-coordinate" if per_coordinate else "euclidean",
                                bank_options={**DEFAULT_BANK, "rule": rule, "reach": reach_setting(reach),
                                              **({} if time_unit is None else {"time_unit": time_unit})},
                                log=lambda message: click.echo(f"kalmix: {message}", err=True))
        result.dataset = label
        click.echo(format_result(result, per_track=per_track))
        _write_outputs(result, json_path, plot_path, shown, intervals_path, plot_track)


def _check_outputs(input_path, json_path, plot_path, intervals_path) -> None:
    """A ``ValueError`` for an output file that cannot be written, before the work."""
    distinct_files(("INPUT", input_path), ("--json", json_path), ("--plot", plot_path),
                   ("--plot-intervals", intervals_path))
    for flag, named in (("--json", json_path), ("--plot", plot_path), ("--plot-intervals", intervals_path)):
        if named == "-":   # it would write a file named '-' (predict's '-' is standard output)
            raise ValueError(f"{flag}: expected a file name, got '-' (standard output is not taken here: "
                             "/dev/stdout is; ./- names a file called -)")
    check_directory("--json", json_path)
    check_directory("--plot", plot_path)
    check_directory("--plot-intervals", intervals_path)


def _read_table(input_path, dataset, time_column, position_columns, id_column, geographic):
    """The track table to evaluate (a shipped recording's, or INPUT's, its bad rows skipped and said), and its
    name in the output."""
    if dataset is not None:
        from ..io import load_dataset
        return load_dataset(dataset), dataset
    import warnings

    from ..io import read_tracks
    from ..io.tables import BadRowWarning

    fmt, columns = track_file(input_path, time_column, position_columns, id_column)
    with warnings.catch_warnings():   # said below, as kalmix predict says it
        warnings.simplefilter("ignore", BadRowWarning)
        table = read_tracks(input_path, columns=columns, format=fmt, ids_as_text=True, on_bad_row="skip",
                            geographic=geographic)   # a latitude beyond ±90°, a longitude beyond ±180°: bad rows
    if "bad_rows" in table.attrs:
        click.echo(f"kalmix: warning: {table.attrs['bad_rows'].summary()}: not evaluated", err=True)
    return table, os.path.basename(input_path)


def _check_plots(table, wanted, plot_path, plot_rows, intervals_path, plot_track, max_samples, tuning_fraction):
    """A ``ValueError`` for a figure option that cannot be honoured, before the work; the rows --plot draws
    (:func:`kalmix.experiments.evaluate.plot_rows`' ``rows``)."""
    import pandas as pd

    from ..experiments.evaluate import PREDICTORS

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
    return shown


def _write_outputs(result, json_path, plot_path, shown, intervals_path, plot_track) -> None:
    """The --json file and the figures asked for."""
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


def _wanted_tracks(tracks: str, table) -> list[str]:
    """``--tracks``' ids: each as written when the data has it (" 7" is not "7"), else without the spaces around
    it ("a, b"); empty entries (a trailing comma) are skipped."""
    have = set(table["track_id"].astype(str))
    return [entry if entry in have else entry.strip() for entry in tracks.split(",") if entry.strip()]


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

    from ..experiments.evaluate import track_columns

    streams = result.streams
    track, columns = track_columns(result, track)
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
