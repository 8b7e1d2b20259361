"""The input of ``kalmix predict`` and ``kalmix evaluate``: a track file's format, its first rows, and the
columns to use, with the notes a user hears on stderr. Reading the header is :func:`kalmix.io.tables.read_header`'s
job; this module decides what the command line makes of it."""

from __future__ import annotations

import os

import click

from ._common import position_names


def file_format(path) -> str:
    """``"parquet"``, ``"jsonl"`` or ``"csv"``, by a file name's extension (an output's, or an input's)."""
    name = os.fspath(path).lower()
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith((".jsonl", ".ndjson", ".json")):
        return "jsonl"
    return "csv"


def output_format(path) -> str:
    """``"csv"``, ``"parquet"`` or ``"jsonl"`` for ``-o PATH`` by its suffix (:func:`file_format`; CSV for ``.csv``,
    ``.txt`` or a name without one: a device, a pipe); ``ValueError`` for a suffix of another format, which would
    get CSV under its name."""
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    kind = file_format(path)
    if kind != "csv" or suffix in ("", ".csv", ".txt"):
        return kind
    hint = {".xlsx": "spreadsheets open the .csv", ".xls": "spreadsheets open the .csv",
            ".tsv": "kalmix writes comma-separated values"}.get(suffix)
    if suffix in (".gz", ".zip", ".bz2", ".xz", ".zst"):
        hint = ("kalmix writes no compressed text: write .parquet (compressed), or pipe the CSV, e.g. "
                "'kalmix predict INPUT | gzip > out.csv.gz'")
    raise ValueError(f"--output: expected a file name ending in .csv, .parquet or .jsonl ('-' or none: CSV on "
                     f"stdout), got {os.fspath(path)!r}" + (f" ({hint})" if hint else ""))


def input_format(path) -> str:
    """``"parquet"`` or ``"csv"`` for a track file INPUT; ``ValueError`` for what is read otherwise."""
    name, kind = os.fspath(path).lower(), file_format(path)
    if kind == "jsonl":
        raise ValueError(f"INPUT: expected CSV (.csv, .csv.gz) or Parquet, got the JSON-lines file {path!r} (kalmix "
                         f"predict reads JSON lines from stdin: 'kalmix predict - < {os.path.basename(path)}')")
    if name.endswith((".tsv", ".tab", ".tsv.gz")):
        raise ValueError(f"INPUT: expected CSV (comma-separated) or Parquet, got the tab-separated {path!r}; convert "
                         "it first (e.g. pandas.read_csv(path, sep='\\t').to_csv('tracks.csv', index=False))")
    return kind


def sample_reader(path, fmt):
    """``sample(names, rows)``: the first ``rows`` rows of those columns of a track file (a CSV's as text); None
    where they cannot be read (the reading proper says why)."""
    import pandas as pd

    def read(names, rows):
        try:
            if fmt == "parquet":
                import pyarrow.parquet as pq

                with pq.ParquetFile(path) as parquet:
                    batch = next(parquet.iter_batches(batch_size=rows, columns=list(dict.fromkeys(names))), None)
                return None if batch is None else batch.to_pandas()
            frame = pd.read_csv(path, nrows=rows, dtype=str, keep_default_na=False, na_values=[""],
                                encoding_errors="surrogateescape")   # (bytes not UTF-8: as on stdin)
            return frame[[name for name in dict.fromkeys(names) if name in frame.columns]]
        except (ValueError, UnicodeDecodeError, OSError, pd.errors.ParserError):
            return None

    return read


def input_columns(header, time_column, position_columns, id_column, sample=None):
    """The columns to use (:func:`kalmix.streaming.find_columns`, the Python API's too), its notes told on
    stderr; ``sample(names, rows)``: the input's first rows of those columns (None: stdin, whose rows are yet
    to come)."""
    from ..streaming import find_columns

    columns, notes = find_columns(header, time=time_column, positions=position_names(position_columns),
                                  track_id=id_column, sample=sample)
    for note in notes:
        click.echo(f"kalmix: {note}", err=True)
    if position_columns is None and sample is not None:
        columns = _without_empty_positions(columns, sample)
    return columns


def track_file(path, time_column, position_columns, id_column):
    """The format and the columns of the track file ``path`` (CSV or Parquet) as the options name them;
    ``FileNotFoundError`` / ``ValueError`` naming INPUT for a missing file or a directory."""
    from ..io.tables import read_header

    if not os.path.exists(path):
        raise FileNotFoundError(f"INPUT: no such file {path!r}")
    if os.path.isdir(path):
        raise ValueError(f"INPUT: expected a track file (CSV or Parquet), got the directory {path!r}")
    fmt = input_format(path)
    return fmt, input_columns(read_header(path, fmt), time_column, position_columns, id_column,
                              sample_reader(path, fmt))


def _without_empty_positions(columns, sample):
    """``columns`` without the detected position columns that are empty in every row of the input's first rows
    (an exported ``z`` of 2-D tracks), with a note naming them: each row would be a missing measurement and
    every prediction empty. Unchanged when none is empty, or all are (said at the end of the run)."""
    import dataclasses

    from ..io.tables import ID_SAMPLE_ROWS, MISSING_TEXT

    if len(columns.positions) < 2:
        return columns
    rows = sample(list(columns.positions), ID_SAMPLE_ROWS)
    if rows is None or not len(rows) or any(name not in rows.columns for name in columns.positions):
        return columns
    empty = [name for name in columns.positions
             if (rows[name].isna() | rows[name].astype(str).str.strip().str.lower().isin(MISSING_TEXT)).all()]
    if not empty or len(empty) == len(columns.positions):
        return columns
    kept = tuple(name for name in columns.positions if name not in empty)
    which = ", ".join(repr(name) for name in empty)
    click.echo(f"kalmix: note: the position column{'s' if len(empty) > 1 else ''} {which} "
               f"{'are' if len(empty) > 1 else 'is'} empty in the first {len(rows):,} rows: predicting "
               f"{', '.join(kept)} only (--position {','.join(columns.positions)} keeps "
               f"{'them' if len(empty) > 1 else 'it'})", err=True)
    return dataclasses.replace(columns, positions=kept)
