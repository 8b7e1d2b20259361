"""Reading users' track files into one canonical long table.

A *track table* is a :class:`pandas.DataFrame` with the columns
``['track_id', 'time', *positions]``: one row per measurement, sorted by
``(track_id, time)``, positions as ``float64`` with ``NaN`` for a missing
measurement. :func:`read_tracks` and :func:`iter_track_chunks` produce it from
CSV (optionally gzip-compressed) or Parquet files; :func:`to_arrays` and
:func:`from_arrays` convert it to and from the dense ``(time_steps, tracks, p)``
arrays the batched predictor consumes.

Validation and handling, applied to every table read:

- a requested column that is not in the file: ``ValueError`` listing the
  available columns;
- a value in a time or position column that is not a number: ``ValueError``
  naming the column, the first offending row (counted from 0 after the header)
  and the value. Empty cells and ``nan`` / ``NA`` / ``null`` are allowed and mean
  a missing measurement (``NaN``); a row whose *time* is missing is dropped with
  a ``RuntimeWarning``;
- times that decrease within a track: the track's rows are sorted by time
  (stable) and a ``RuntimeWarning`` gives the count;
- repeated timestamps within a track: the last row (in file order) is kept and a
  ``RuntimeWarning`` gives the count;
- a file without data rows: ``ValueError`` ("no rows");
- more than 3 position columns: ``ValueError``.

Track ids: with ``ids_as_text=True`` (what ``kalmix predict`` and ``kalmix evaluate`` use)
a CSV id column is read as text exactly as written, so ``01`` and ``1`` are two tracks
(as on stdin) and a column whose chunks look numeric in one place and textual in another
keeps one type; tracks then come in order of first appearance instead of sorted by id.
By default pandas infers the type (``01`` and ``1`` both become the integer 1). Parquet
ids keep their column type either way.

The readers are here; their parts: column detection (:mod:`.columns`), values as numbers and
seconds (:mod:`.values`), a raw chunk checked into a track table (:mod:`.normalise`), clocks that
restart (:mod:`.clock_resets`), CSV lines (:mod:`.csv_lines`), and the dense arrays (:mod:`.arrays`).
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
import pandas as pd

from .arrays import TrackArrays, from_arrays, split_on_gaps, to_arrays
from .clock_resets import ClockResets
from .columns import ID_SAMPLE_ROWS as ID_SAMPLE_ROWS
from .columns import TrackColumns, check_output_names, detect_columns, require_columns
from .columns import column_notes as column_notes
from .columns import id_candidates as id_candidates
from .columns import id_like_name as id_like_name
from .columns import looks_like_a_word as looks_like_a_word
from .csv_lines import CsvLines, binary, not_utf8_error, utf16_file, utf8_chunks
from .normalise import ON_BAD_ROW, BadRows, BadRowWarning, DroppedRowWarning, in_file_order, normalise_table
from .normalise import AsGiven as AsGiven
from .values import MISSING_TEXT as MISSING_TEXT
from .values import iso_seconds as iso_seconds
from .values import to_float as to_float

__all__ = [
    "TrackColumns",
    "TrackArrays",
    "BadRows",
    "BadRowWarning",
    "DroppedRowWarning",
    "ON_BAD_ROW",
    "detect_columns",
    "check_output_names",
    "read_tracks",
    "iter_track_chunks",
    "in_file_order",
    "to_arrays",
    "from_arrays",
    "split_on_gaps",
]

_FORMATS = ("csv", "parquet")


def csv_options(cols: TrackColumns, ids_as_text: bool, time_as_text: bool = False) -> dict:
    """``pd.read_csv`` arguments that read the id column as text exactly as written (empty = missing) and, with
    ``time_as_text``, the time column as text exactly as written too (empty = missing; ``NA``, ``nan``, ... kept
    as their text, which :func:`missing_as_pandas` then makes missing as pandas' own reading would)."""
    text = [name for name, wanted in ((cols.track_id, ids_as_text), (cols.time, time_as_text))
            if wanted and name is not None]
    if not text:
        return {}
    from pandas._libs.parsers import STR_NA_VALUES

    missing = {name: [""] if name in text else sorted(STR_NA_VALUES) for name in cols.names}
    return {"dtype": {name: str for name in text}, "keep_default_na": False, "na_values": missing}


def missing_as_pandas(text: pd.Series) -> pd.Series:
    """A column read as text exactly as written (:func:`csv_options`) with pandas' missing-value texts (``NA``,
    ``nan``, ``null``, ``N/A``, ``None``, ``#N/A``, ...; matched as written, as pandas does) missing: what
    pandas' own reading of the column gives."""
    from pandas._libs.parsers import STR_NA_VALUES

    return text.mask(text.isin(STR_NA_VALUES))


def _format_of(source: Any, format: str | None) -> str:
    if format is not None:
        fmt = format.lower().lstrip(".")
        if fmt not in _FORMATS:
            raise ValueError(f"Expected format in {list(_FORMATS)}, got {format!r}")
        return fmt
    name = source if isinstance(source, (str, os.PathLike)) else getattr(source, "name", None)
    if name is None:
        return "csv"  # an unnamed buffer: CSV unless format='parquet'
    name = os.fspath(name).lower()
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith((".csv", ".csv.gz", ".txt", ".txt.gz", ".gz")):
        return "csv"
    raise ValueError(f"Cannot tell the format of {name!r}: expected a .csv, .csv.gz or .parquet "
                     "file, or pass format='csv' or 'parquet'")


def read_header(source: Any, fmt: str) -> list[str]:
    """The column names of a track file (``fmt``: ``"csv"`` or ``"parquet"``), as text; a ``ValueError`` naming
    the file when it is empty (no header, no rows) or, in CSV, not UTF-8 text."""
    if fmt == "parquet":
        import pyarrow.parquet as pq
        with pq.ParquetFile(source) as parquet:
            return list(parquet.schema_arrow.names)
    name = os.fspath(source) if isinstance(source, (str, os.PathLike)) else getattr(source, "name", "(a buffer)")
    try:
        header = [str(c) for c in pd.read_csv(source, nrows=0).columns]
    except pd.errors.EmptyDataError:
        raise ValueError(f"The track file {name!r} is empty (no header, no rows)") from None
    except UnicodeDecodeError as error:
        if isinstance(source, (str, os.PathLike)) and not binary(source):   # text, not in UTF-8
            raise not_utf8_error(source, []) from None
        raise ValueError(f"The track file {name!r} is not a CSV text file (UTF-8 expected; "
                         f"{error.reason} at byte {error.start})") from None
    if any("\0" in column for column in header) and isinstance(source, (str, os.PathLike)) and utf16_file(source):
        raise not_utf8_error(source, [])   # (UTF-16 without a byte order mark reads as UTF-8 with zeros between)
    return header


def check_unique_columns(source: Any, fmt: str, cols: TrackColumns) -> None:
    """``ValueError`` when a column used appears more than once in a CSV header (pandas would
    silently rename the copies ``x.1``, ``x.2`` and read the first)."""
    if fmt != "csv":
        return
    first = pd.read_csv(source, nrows=1, header=None, dtype=str, keep_default_na=False)
    written = [str(v) for v in first.iloc[0]] if len(first) else []
    for name in cols.names:
        if written.count(name) > 1:
            raise ValueError(f"Column {name!r} appears {written.count(name)} times in the header of "
                             f"{os.fspath(source)!r}; rename the copies (pandas would read the first)")


def _resolve(header: list[str], columns: TrackColumns | None) -> TrackColumns:
    if columns is None:
        return detect_columns(header)
    if not isinstance(columns, TrackColumns):
        raise ValueError(f"Expected columns to be a TrackColumns or None, got {type(columns).__name__}")
    require_columns(header, columns.names, f"columns={columns}")
    return columns


def read_tracks(path_or_buffer: str | os.PathLike | io.IOBase, *, columns: TrackColumns | None = None,
                format: str | None = None, ids_as_text: bool = False, on_bad_row: str = "fail",
                geographic=False) -> pd.DataFrame:
    """Read a CSV (optionally ``.gz``) or Parquet track file into a track table.

    Parameters
    ----------
    path_or_buffer : path or file-like
        The file. The format comes from the extension (``.csv``, ``.csv.gz``,
        ``.parquet``, ``.pq``) or from `format`; an unnamed buffer is CSV unless
        ``format='parquet'``.
    columns : TrackColumns, optional
        Which columns to use; detected with :func:`detect_columns` if omitted.
    format : {'csv', 'parquet'}, optional
        Overrides the extension.
    ids_as_text : bool, default False
        Read a CSV id column as text exactly as written (see the module docstring).
    on_bad_row : {'fail', 'skip'}, default 'fail'
        A bad row (a CSV row whose field count is not the header's, an empty track id, a time or
        position that is not a finite number; see :data:`ON_BAD_ROW`): ``'fail'`` raises a
        ``ValueError`` naming its line (CSV file) or row; ``'skip'`` leaves it out, with a
        :class:`BadRowWarning`, and lists it in ``attrs["bad_rows"]`` (:class:`BadRows`).
    geographic : bool, None or GeoAxes, default False
        Whether the positions are latitude and longitude (:func:`kalmix.io.geo.resolve_axes`: None detects it
        from their names); if so, a latitude beyond ±90° or a longitude beyond ±180° is a bad row too.

    Returns
    -------
    pandas.DataFrame
        Columns ``['track_id', 'time', *columns.positions]``, sorted by
        ``(track_id, time)`` (stable; with ``ids_as_text`` on a CSV file: tracks in order
        of first appearance, then time), time and positions as float64, NaN for a
        missing measurement. See the module docstring for the validation rules.

    Raises
    ------
    ValueError
        Missing columns, non-numeric values, no rows, more than 3 positions.
    """
    fmt = _format_of(path_or_buffer, format)
    is_path = isinstance(path_or_buffer, (str, os.PathLike))
    lines = None
    if is_path:
        cols = _resolve(read_header(path_or_buffer, fmt), columns)
        check_unique_columns(path_or_buffer, fmt, cols)
        if fmt == "parquet":
            import pyarrow.parquet as pq
            raw = pq.read_table(path_or_buffer, columns=cols.names).to_pandas()
        else:
            try:
                raw = pd.read_csv(path_or_buffer, usecols=cols.names, **csv_options(cols, ids_as_text))
            except UnicodeDecodeError:
                raise not_utf8_error(path_or_buffer, cols.names) from None
            if len(raw):
                reader = CsvLines(path_or_buffer, check=_checked_column(path_or_buffer, cols, ids_as_text))
                try:
                    lines = reader.take(len(raw), raw[cols.track_id] if reader.check is not None else None)
                finally:
                    reader.close()
    else:
        if fmt == "parquet":
            raw = pd.read_parquet(path_or_buffer)
        else:
            try:
                raw = pd.read_csv(path_or_buffer)
            except pd.errors.EmptyDataError:
                raise ValueError("The track file has no rows (it is empty)") from None
        cols = _resolve([str(c) for c in raw.columns], columns)
    table = normalise_table(raw, cols, first_appearance=ids_as_text and fmt == "csv" and is_path,
                       on_bad_row=on_bad_row, lines=lines, where="parquet" if fmt == "parquet" else "row",
                       geographic=_axes(cols, geographic))
    bad = table.attrs.get("bad_rows")
    if table.empty:
        raise ValueError("The track file has no rows with a time" if bad is None else
                         f"The track file has no row to read: {bad.summary()}")
    if bad is not None:
        warnings.warn(bad.summary(), BadRowWarning, stacklevel=2)
    return table


def _axes(cols: TrackColumns, geographic):
    """The positions' :class:`~kalmix.io.geo.GeoAxes` by ``geographic`` (the readers' argument), or None."""
    from .geo import GeoAxes, resolve_axes

    return geographic if isinstance(geographic, GeoAxes) else resolve_axes(list(cols.positions), geographic)


def _checked_column(path, cols: TrackColumns, ids_as_text: bool) -> int | None:
    """The header position of the id column, when pandas reads it as text (:class:`CsvLines` compares the
    two readers' rows on it); None otherwise."""
    if not ids_as_text or cols.track_id is None:
        return None
    header = read_header(path, "csv")
    return header.index(cols.track_id) if header.count(cols.track_id) == 1 else None


def iter_track_chunks(path: str | os.PathLike, *, columns: TrackColumns | None = None,
                      chunk_rows: int = 1_000_000, format: str | None = None, ids_as_text: bool = False,
                      as_given: bool = False, on_bad_row: str = "fail", bad_texts: bool = False,
                      clock_resets=None, late_rows: str = "fail", time_kind: dict | None = None,
                      geographic=False) -> Iterator[pd.DataFrame]:
    """Read a huge CSV or Parquet track file in bounded memory, chunk by chunk.

    Chunks of at most `chunk_rows` file rows come in file order (pandas
    ``chunksize`` for CSV, ``pyarrow`` ``iter_batches`` for Parquet), each
    validated and normalised like :func:`read_tracks` (sorted by
    ``(track_id, time)`` *within* the chunk).

    Within a track, rows must come in increasing time order across chunks: a
    chunk cannot reorder rows already yielded, so a track whose time goes back
    (or repeats) across a chunk boundary raises ``ValueError`` (``late_rows``);
    sort the file first or use :func:`read_tracks`. Disorder inside one chunk is sorted with a
    warning as in :func:`read_tracks`. With ``time=None`` each track's row count
    continues across chunks.

    Parameters
    ----------
    path : path
        CSV (optionally ``.gz``) or Parquet file.
    columns : TrackColumns, optional
        Detected from the header if omitted.
    chunk_rows : int, default 1_000_000
        Maximum file rows per chunk.
    format : {'csv', 'parquet'}, optional
        Overrides the extension.
    ids_as_text : bool, default False
        Read a CSV id column as text exactly as written (see the module docstring).
    as_given : bool, default False
        Also keep each chunk's file rows as the file gave them, in ``chunk.attrs["as_given"]``
        (:class:`AsGiven`): a CSV time column is then read as text exactly as written (``NA`` stays ``NA``),
        and read into the same numbers.
    on_bad_row : {'fail', 'skip'}, default 'fail'
        As in :func:`read_tracks`: ``'skip'`` leaves a bad row out of its chunk, lists it in
        ``chunk.attrs["bad_rows"]`` (:class:`BadRows`) and warns (:class:`BadRowWarning`) once a
        chunk; a chunk may then be empty.
    bad_texts : bool, default False
        Keep a skipped CSV row's line as written (:attr:`BadRows.texts`), for a file of rejects.
    clock_resets : callable or ClockResets, optional
        ``step(usual)``: a track's clock that restarts (:class:`ClockResets`) goes on after the rows
        before it by this step (a track's usual step given), instead of being sorted into them; the
        chunk lists its restarts in ``chunk.attrs["clock_resets"]``. A :class:`ClockResets`: that one
        (its tracks' clocks read after each chunk). None: sorted (as any disorder).
    late_rows : {'fail', 'skip'}, default 'fail'
        A row at or before its track's last time in an earlier chunk: ``'fail'`` raises
        ``ValueError``; ``'skip'`` leaves it out of its chunk like a row without a time (counted in
        ``chunk.attrs["dropped"]["late"]``, kept in ``as_given`` as a row not predicted) and warns
        (:class:`DroppedRowWarning`).
    time_kind : dict, optional
        Where the read keeps the time column's kind: ``time_kind["kind"]`` is ``"number"`` or ``"date-time"``
        once the file's first time that can be read decides it (absent before, and for a column of Parquet
        datetimes or durations), for a caller to look at during or after the read.
    geographic : bool, None or GeoAxes, default False
        As in :func:`read_tracks`: latitudes beyond ±90° and longitudes beyond ±180° are bad rows.

    Yields
    ------
    pandas.DataFrame
        Track table chunks (``track_id``, ``time``, positions); ``chunk.attrs["file_rows"]``
        is the number of file rows it was made from (a progress count).
    """
    if int(chunk_rows) < 1:
        raise ValueError(f"Expected chunk_rows >= 1, got {chunk_rows}")
    if late_rows not in ON_BAD_ROW:
        raise ValueError(f"late_rows: expected one of {list(ON_BAD_ROW)}, got {late_rows!r}")
    fmt = _format_of(path, format)
    cols = _resolve(read_header(path, fmt), columns)
    check_unique_columns(path, fmt, cols)
    axes = _axes(cols, geographic)
    last: dict = {}
    counts: dict | None = {} if cols.time is None else None
    time_kind = {} if time_kind is None else time_kind
    clocks = None if clock_resets is None or cols.time is None else (
        clock_resets if isinstance(clock_resets, ClockResets) else ClockResets(clock_resets))
    offset = kept = skipped = 0
    first_bad = None   # the first bad row's reason: what a file none of whose rows could be read is told
    lines = None
    with contextlib.ExitStack() as stack:
        if fmt == "parquet":
            import pyarrow.parquet as pq
            parquet = stack.enter_context(pq.ParquetFile(path))
            batches = ((b.to_pandas(), _given_column(b, cols.time) if as_given else None) for b in
                       parquet.iter_batches(batch_size=int(chunk_rows), columns=cols.names))
        else:
            reader = stack.enter_context(pd.read_csv(path, usecols=cols.names, chunksize=int(chunk_rows),
                                                     **csv_options(cols, ids_as_text, as_given)))
            batches = (_as_written(raw, cols.time) if as_given else (raw, None)
                       for raw in utf8_chunks(reader, path, cols.names))
            lines = CsvLines(path, texts=bad_texts, check=_checked_column(path, cols, ids_as_text))
            stack.callback(lines.close)
        batches = iter(batches)
        following = next(batches, None)
        while following is not None:   # one batch ahead: whether a chunk is the file's last
            (raw, given_time), following = following, next(batches, None)
            if clocks is not None:
                clocks.more = following is not None
            if len(raw) == 0:
                continue
            where = None if lines is None else lines.take(
                len(raw), raw[cols.track_id] if lines.check is not None else None)
            chunk = normalise_table(raw, cols, offset, counts, first_appearance=ids_as_text and fmt == "csv",
                               as_given=as_given, given_time=given_time, on_bad_row=on_bad_row, lines=where,
                               time_kind=time_kind, where="parquet" if fmt == "parquet" else "row", clocks=clocks,
                               after=last if late_rows == "skip" else None, geographic=axes)
            bad = chunk.attrs.get("bad_rows")
            if bad is not None:
                skipped += len(bad)
                first_bad = first_bad or f"{bad.places[0]}: {bad.reasons[0]}"
                warnings.warn(bad.summary(), BadRowWarning, stacklevel=2)
            kept += len(chunk)
            firsts = chunk.groupby("track_id", sort=False)["time"].first()
            prev = firsts.index.map(last).to_numpy(np.float64, na_value=np.nan)
            back = prev >= firsts.to_numpy()
            if back.any():
                i = int(np.argmax(back))
                raise ValueError(
                    f"Track {firsts.index[i:i + 1].tolist()[0]!r}: time {firsts.iloc[i]} in the chunk "
                    f"starting at row {offset} is not after the time {prev[i]} already read; in a "
                    "chunked read each track's rows must come in increasing time order (sort the "
                    "file or use read_tracks)")
            last.update(chunk.groupby("track_id", sort=False)["time"].last().to_dict())
            offset += len(raw)
            chunk.attrs["file_rows"] = len(raw)  # rows read, before dropping rows without a time or repeated
            yield chunk
    if offset == 0:
        raise ValueError(f"The track file {os.fspath(path)!r} has no rows (only a header)")
    if kept == 0:
        raise ValueError(f"The track file {os.fspath(path)!r} has no row to read ({skipped} bad row(s) skipped; the "
                         f"first, {first_bad})" if skipped else
                         f"The track file {os.fspath(path)!r} has no rows with a time")


def _as_written(raw: pd.DataFrame, name: str | None) -> tuple[pd.DataFrame, pd.Series | None]:
    """A CSV chunk whose time column was read as text exactly as written: the chunk with that column's missing
    texts missing (:func:`missing_as_pandas`: the numbers pandas' reading gives), and the text to give back."""
    if name is None:
        return raw, None
    written = raw[name]
    raw[name] = missing_as_pandas(written)
    return raw, written


def _given_column(batch, name: str | None) -> pd.Series | None:
    """A Parquet batch's column ``name`` as pandas gives it, but integers with nulls as nullable integers
    (pandas' default makes them floats: a frame number 7 would come back as 7.0); None where it needs no
    other reading than the batch's."""
    import pyarrow as pa

    if name is None:
        return None
    column = batch.column(batch.schema.get_field_index(name))
    if not (pa.types.is_integer(column.type) and column.null_count):
        return None
    return pd.Series(column.to_pandas(types_mapper=lambda kind: pd.api.types.pandas_dtype(
        str(kind).replace("int", "Int").replace("uInt", "UInt")) if pa.types.is_integer(kind) else None))
