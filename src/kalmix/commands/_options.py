"""The options ``kalmix predict`` and ``kalmix evaluate`` share: the input's columns, the gap rule, the reach,
the length unit, ``--option`` pairs, and the checks of the files they name, each refusing a bad value with the
option's name."""

from __future__ import annotations

import json
import math
import os

import click

from ..bank import GATE_OPTIONS, LENGTH_UNIT_RANGE
from ._common import missing_directory


GAP_HELP = ("A time step larger than this (in the time column's units) starts a new segment: the track's predictor "
            "restarts. "
            "Default: --max-gap-factor times the track's reference interval.")


_GEOGRAPHIC_HELP = ("Positions are latitude and longitude in degrees (and altitude in metres), predicted in metres "
                    "in each track's local frame: latitudes beyond +-90 or longitudes beyond +-180 are errors, "
                    "std_east_m / std_north_m in metres [default: when the position columns are named so: lat, "
                    "lon, latitude, longitude, lng, alt, altitude]. --no-geographic: flat numbers.")


def column_options(function):
    """The input's column options (--time, --position, --id, --geographic) on a command."""
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


def parse_mixture_options(pairs, bank: bool = False):
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


def parse_length_unit(text):
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


REACH_HELP = ("Across a time step longer than this many time units (--time-unit) only the constant-velocity experts "
              "make the one-step prediction (the others extrapolate fits made on the usual steps); 'none': every "
              "expert at every step [default: 1.5 where the first chunk's time steps are heavy-tailed (the top "
              "tenth over 4 times the median) and a pilot run on its first rows predicts better so, else none; on "
              "stdin none].")


def parse_reach(text):
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


def reach_setting(value):
    """The reach a bank takes: None for 'none' (math.inf here), ``"auto"`` when not given
    (:class:`kalmix.streaming.StreamConfig`'s)."""
    return "auto" if value is None else (None if math.isinf(value) else value)


def parse_max_gap(text):
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


def distinct_files(*named):
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


def check_directory(name, path):
    """``ValueError`` at start when an output file's directory does not exist (not after all the work)."""
    problem = missing_directory(path) if path else None
    if problem:
        directory, taken = problem
        raise ValueError(f"{name}: the directory {directory!r} "
                         f"{'is a file, not a directory' if taken else 'does not exist'}")
