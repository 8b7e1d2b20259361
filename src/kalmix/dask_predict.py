"""``kalmix predict --engine dask``: a partitioned archive over a Dask cluster, the numbers of one machine.

Tracks are independent, so the work partitions by track. The rows (from many files, one
track's rows possibly spread over many of them) are shuffled by track id with
``dask.dataframe``'s shuffle, so that every partition holds whole tracks; each partition is
then sorted by time and stepped through the same :class:`kalmix.streaming.TrackPredictor`
(the compiled engine) that single-machine ``kalmix predict`` uses, in bounded batches.

Equal to single-machine ``kalmix predict`` on the same rows written as one file (tested
to 1e-12, in practice bit for bit), because everything that run derives from the data as
a whole is derived here the same way, before the shuffle:

- the **length unit** (``auto``): the rule of :func:`kalmix.streaming.auto_length_unit` on the
  *first chunk*, the first ``chunk_rows`` rows of the data in order (files in sorted path
  order, rows in file order), exactly the chunk a single-machine run reads first;
- the **time unit** (when not given): the median time step of the first chunk that has one,
  as a single-machine run learns it before stepping that chunk (see
  :meth:`kalmix.streaming.TrackPredictor.learn_time_unit`); the partitions then get it fixed
  from the start.

Everything else is per track (the gap rule, repeated timestamps, the states), so it does not
matter which worker holds a track. Rows of one track are put in order the same way: the rows
of the whole archive in file order, a repeated timestamp keeps the last row, a row without a
time is dropped, a time-less track counts its rows. (A single-machine run cannot reorder a
track's rows across its chunks, and leaves a row that comes late unpredicted; here the whole
archive is sorted.)

Memory: a partition of the shuffle is held whole by one worker thread, about 300 bytes per
row at its peak with 2 positions (its rows, the time sort, the output); it is stepped in
batches of at most ``batch_tracks`` tracks (the bank states, 3-60 KB per track, are dropped
after each batch), each batch in engine calls of at most ``chunk_rows`` cells of the dense
(time step x track) array, about 700 bytes per cell at the default bank: a track's k-th rows
of a batch go together, so tracks of very different lengths do not pad each other. So a worker
thread needs about ``300 B x rows per partition + 700 B x chunk_rows + 3 x batch_tracks x state
size``; rows per partition is the archive's rows / ``partitions`` (more for an unusually long
track: a track is never split).

Idempotent: the output is a function of the input rows and the settings alone (no state is
carried between partitions), so a partition Dask computes again after losing a worker is
written again identically, and a stopped run is simply run again (no ``--state``).
"""

from __future__ import annotations

import glob
import itertools
import os
import warnings
from dataclasses import asdict, replace

import numpy as np
import pandas as pd

from .io.tables import (TrackColumns, check_output_names, check_unique_columns, csv_options, detect_columns,
                        normalise_table, read_header, to_float)

__all__ = ["predict_dask", "read_archive", "archive_files", "prepare", "data_units", "PARTITION_ROWS",
           "BATCH_TRACKS"]

#: Rows of a Parquet archive read as one input partition (whole row groups; a CSV file is one partition).
PARTITION_ROWS = 1_000_000
#: Tracks stepped together in one batch of a partition (their states are dropped after it).
BATCH_TRACKS = 1_024
#: Row number inside an input partition; the partition's number goes above it (file order of every row).
_ORDER_BITS = 40
_EXTENSIONS = {".parquet": "parquet", ".pq": "parquet", ".csv": "csv", ".csv.gz": "csv", ".txt": "csv",
               ".txt.gz": "csv"}


# ------------------------------------------------------------------------------------ input files
def _format_of(path: str) -> str | None:
    name = path.lower()
    for ending, fmt in sorted(_EXTENSIONS.items(), key=lambda item: -len(item[0])):
        if name.endswith(ending):
            return fmt
    return None


def archive_files(source: str) -> tuple[list[str], str]:
    """The track files of ``source`` (a directory, searched recursively, a glob or one file) and their format.

    Files come in sorted path order, which is the order of the archive's rows. Files whose name
    starts with ``_`` or ``.`` (``_SUCCESS``, ``_metadata``, ``.crc``) are not data. ``ValueError``
    when nothing matches, a match is not a track file, or CSV and Parquet are mixed.
    """
    source = os.fspath(source)
    if os.path.isdir(source):
        found = []
        for root, dirs, names in os.walk(source):
            dirs[:] = sorted(d for d in dirs if not d.startswith((".", "_")))
            found += [os.path.join(root, name) for name in names if not name.startswith((".", "_"))]
        files = sorted(f for f in found if _format_of(f) is not None)
        if not files:
            raise ValueError(f"INPUT: the directory {source!r} holds no .parquet, .pq, .csv or .csv.gz file")
    else:
        matches = [f for f in glob.glob(source, recursive=True) if not os.path.basename(f).startswith((".", "_"))]
        matched = {os.path.normpath(f) for f in matches if os.path.isfile(f)}
        for match in sorted(f for f in matches if os.path.isdir(f)):   # its track files would be left out unsaid
            # (a '**' glob matches the directories and their files alike: only files it misses count)
            inside = next((os.path.join(root, name) for root, _, names in os.walk(match) for name in sorted(names)
                           if _format_of(name) is not None and not name.startswith((".", "_"))
                           and os.path.normpath(os.path.join(root, name)) not in matched), None)
            if inside is not None:
                raise ValueError(f"INPUT: the glob {source!r} matches the directory {match!r}, whose track files "
                                 f"(e.g. {inside!r}) a glob does not read; give the directory itself, or a glob "
                                 "that matches the files (e.g. 'DIR/**/*.parquet')")
        files = sorted(f for f in matches if os.path.isfile(f))
        if not files:
            raise ValueError(f"INPUT: no file matches {source!r}")
        other = [f for f in files if _format_of(f) is None]
        if other:
            raise ValueError(f"INPUT: {other[0]!r} is not a track file (expected .parquet, .pq, .csv or .csv.gz)")
    formats = {_format_of(f) for f in files}
    if len(formats) > 1:
        first = {fmt: next(f for f in files if _format_of(f) == fmt) for fmt in sorted(formats)}
        raise ValueError(f"INPUT: mixes CSV ({first['csv']!r}) and Parquet ({first['parquet']!r}) files; "
                         "give one format per run")
    return files, formats.pop()


def _type_kind(kind, is_id: bool) -> str:
    """The kind of a Parquet column's type that files of one archive must share: any integer or float for a time
    or position (each read as float64); for a track id, integers of any width (read as int64), floats (float64)
    or text (string, large_string); a timestamp's zone, not its unit; other types as they are."""
    import pyarrow as pa

    if pa.types.is_integer(kind) or pa.types.is_floating(kind):
        return ("integer" if pa.types.is_integer(kind) else "float") if is_id else "number"
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return "text"
    if pa.types.is_timestamp(kind):
        return f"timestamp (zone {kind.tz})"
    if pa.types.is_duration(kind):
        return "duration"
    return str(kind)


def _unreadable(path, error) -> ValueError:
    """A file that cannot be read, named (pyarrow's error alone does not name it)."""
    return ValueError(f"INPUT: {path!r} cannot be read as {'Parquet' if _format_of(path) == 'parquet' else 'CSV'} "
                      f"(a corrupt or truncated file?): {error}")


def _check_files(files, fmt, columns):
    """``ValueError`` naming the first file that cannot be read, lacks a column in use or, in Parquet, types it
    with another kind (:func:`_type_kind`: a float32 beside a float64 column is read as float64 too)."""
    reference = None
    for path in files:
        if fmt == "csv" and os.path.getsize(path) == 0:
            raise ValueError(f"INPUT: {path!r} is empty (no header, no rows)")
        try:
            header = read_header(path, fmt)
        except (OSError, ValueError) as error:   # (pyarrow's ArrowInvalid is a ValueError)
            raise _unreadable(path, error) from None
        missing = [name for name in columns.names if name not in header]
        if missing:
            raise ValueError(f"INPUT: {path!r} has no column {missing[0]!r}: expected the columns "
                             f"{columns.names} (as in {files[0]!r}), got {header}")
        check_unique_columns(path, fmt, columns)
        if fmt == "parquet":
            import pyarrow.parquet as pq

            schema = pq.read_schema(path)
            types = {name: schema.field(name).type for name in columns.names}
            kinds = {name: _type_kind(types[name], name == columns.track_id) for name in columns.names}
            if reference is None:
                reference = types, kinds
            for name in columns.names:
                if kinds[name] != reference[1][name]:
                    raise ValueError(f"INPUT: column {name!r} of {path!r} is {types[name]}; expected "
                                     f"{reference[0][name]} as in {files[0]!r}"
                                     + (" (an id column of integers and one of floats would split tracks: 1 is "
                                        "not 1.0 when rows are shuffled by id)" if {kinds[name], reference[1][name]}
                                        == {"integer", "float"} else ""))


def _pieces(files, fmt, partition_rows):
    """``(index, path, row groups or None, first row)``: whole files (CSV) or runs of row groups (Parquet)."""
    pieces = []
    for path in files:
        if fmt == "csv":
            pieces.append((len(pieces), path, None, 0))
            continue
        import pyarrow.parquet as pq

        try:
            meta = pq.read_metadata(path)
        except (OSError, ValueError) as error:
            raise _unreadable(path, error) from None
        groups, rows, start = [], 0, 0
        for g in range(meta.num_row_groups):
            n = meta.row_group(g).num_rows
            if groups and rows + n > partition_rows:
                pieces.append((len(pieces), path, groups, start))
                groups, start, rows = [], start + rows, 0
            groups.append(g)
            rows += n
        if groups:
            pieces.append((len(pieces), path, groups, start))
    return pieces


def _read_raw(path, fmt, columns, groups=None, nrows=None):
    try:
        if fmt == "parquet":
            import pyarrow.parquet as pq

            with pq.ParquetFile(path) as parquet:
                if nrows == 0:
                    raw = parquet.schema_arrow.empty_table().select(columns.names).to_pandas()
                else:
                    raw = parquet.read_row_groups(groups, columns=columns.names).to_pandas()
        else:
            raw = pd.read_csv(path, usecols=columns.names, nrows=nrows, **csv_options(columns, True))
    except (OSError, EOFError, pd.errors.ParserError, UnicodeDecodeError) as error:
        raise _unreadable(path, error) from None
    except ValueError as error:   # pyarrow's ArrowInvalid: a corrupt page, a bad footer
        if type(error).__module__.startswith("pyarrow"):
            raise _unreadable(path, error) from None
        raise
    if columns.track_id is not None and fmt == "parquet":   # one id type over the archive's files (see _type_kind)
        ids = raw[columns.track_id]
        if pd.api.types.is_integer_dtype(ids) and isinstance(ids.dtype, np.dtype):
            raw[columns.track_id] = ids.astype(np.int64)
        elif pd.api.types.is_float_dtype(ids):
            raw[columns.track_id] = ids.astype(np.float64)
    return raw


def _canonical(raw, columns: TrackColumns, base: int, where: str, offset: int = 0) -> pd.DataFrame:
    """``track_id``, ``time`` (absent when the data has none), the positions as float64, and ``_order``.

    The conversions and their errors are :mod:`kalmix.io.tables`' (a value that is not a number
    names its column, row and value), prefixed by ``where`` (the file). Nothing is dropped
    or sorted here: that happens per track after the shuffle.
    """
    n = len(raw)
    try:
        if columns.track_id is None:
            ids = pd.Series(np.zeros(n, dtype=np.int64))
        else:
            ids = raw[columns.track_id].reset_index(drop=True)
            if ids.isna().any():
                i = int(np.argmax(ids.isna().to_numpy()))
                raise ValueError(f"Column {columns.track_id!r} (track id) must not be empty; row {offset + i} "
                                 "(counted from 0 after the header) has no id")
        out = pd.DataFrame({"track_id": ids})
        for name, source in ((("time", columns.time),) if columns.time is not None else ()) + tuple(
                (p, p) for p in columns.positions):
            out[name] = to_float(raw[source].reset_index(drop=True), source, offset, dates=name == "time")
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    out["_order"] = (np.int64(base) << _ORDER_BITS) + np.arange(n, dtype=np.int64)
    return out


def _check_partitions(count):
    if count >= 1 << (63 - _ORDER_BITS):
        raise ValueError(f"the input has {count} partitions; at most {(1 << (63 - _ORDER_BITS)) - 1} are supported "
                         "(the file order of a row is kept in 63 bits): give larger partitions")


def _read_piece(piece, fmt, track_columns):
    columns = track_columns
    index, path, groups, start = piece
    return _canonical(_read_raw(path, fmt, columns, groups), columns, index, path, start)


def read_archive(source, *, time=None, positions=None, track_id=None,
                 partition_rows: int = PARTITION_ROWS):
    """A partitioned archive as a dask DataFrame ready for :func:`predict_dask`.

    Parameters
    ----------
    source : str
        A directory (searched recursively), a glob (``'reports/2024-*.parquet'``) or a file,
        of Parquet or CSV (``.csv.gz`` too) track files with the same columns.
    time : str, optional
        The time column's name, detected as in ``kalmix predict`` when omitted.
    positions : str or sequence of str, optional
        The position columns' names, detected when omitted.
    track_id : str, optional
        The track id column's name, detected when omitted.
    partition_rows : int
        Rows of Parquet row groups read as one partition (a CSV file is one partition).

    Returns
    -------
    (dask.dataframe.DataFrame, TrackColumns, str)
        Canonical rows (``track_id``, ``time``, positions, ``_order``: the file order), the
        columns in use and the format (``'csv'`` or ``'parquet'``).
    """
    import dask.dataframe as dd

    files, fmt = archive_files(source)
    columns = detect_columns(read_header(files[0], fmt), time=time, positions=positions, track_id=track_id)
    check_output_names(columns)
    _check_files(files, fmt, columns)
    meta = _canonical(_read_raw(files[0], fmt, columns, nrows=0), columns, 0, files[0])
    pieces = _pieces(files, fmt, partition_rows)
    _check_partitions(len(pieces))
    frame = dd.from_map(_read_piece, pieces, fmt=fmt, track_columns=columns, meta=meta,
                        label="kalmix-read", enforce_metadata=False)
    return frame, columns, fmt


def _prepare_partition(raw, columns, partition_info=None):
    number = partition_info["number"] if partition_info else 0
    return _canonical(raw, columns, number, f"partition {number}")


def prepare(frame, columns: TrackColumns):
    """A user's dask DataFrame (``columns`` naming its id, time and positions) in canonical form.

    Row order is the frame's (partitions in order, rows in order): it decides which row a
    repeated timestamp keeps and, with no time column, each row's time.
    """
    _check_partitions(frame.npartitions)
    meta = _canonical(frame._meta, columns, 0, "meta")
    return frame.map_partitions(_prepare_partition, columns, meta=meta, enforce_metadata=False)


# ----------------------------------------------------------------------------------- data units
def _engine_columns(columns: TrackColumns) -> TrackColumns:
    return TrackColumns(time="time" if columns.time is not None else None, positions=columns.positions,
                        track_id="track_id")


def _first_chunks(prepared, chunk_rows):
    """The archive's raw rows in order, ``chunk_rows`` at a time (the chunks of a single-machine read).

    Partitions are read 1, 2, 4, ... at a time (in parallel), as many as the chunks asked for need.
    """
    import dask

    held, count, start, step = [], 0, 0, 1
    while start < prepared.npartitions:
        stop = min(prepared.npartitions, start + step)
        for part in dask.compute(*[prepared.partitions[i] for i in range(start, stop)]):
            held.append(part)
            count += len(part)
            while count >= chunk_rows:
                rows = pd.concat(held, ignore_index=True)
                yield rows.iloc[:chunk_rows]
                held, count = [rows.iloc[chunk_rows:]], count - chunk_rows
        start, step = stop, 2 * step
    if count:
        yield pd.concat(held, ignore_index=True)


def data_units(prepared, columns: TrackColumns, config, *, derive_length: bool = True, chunk_rows: int = 200_000,
               first_appearance: bool = False):
    """The length unit, time unit and reach single-machine ``kalmix predict`` derives from these rows.

    Parameters
    ----------
    prepared : dask.dataframe.DataFrame
        Canonical rows (:func:`read_archive` or :func:`prepare`).
    columns : TrackColumns
        The columns in use.
    config : kalmix.streaming.StreamConfig
        The settings: the gap rule's, a given ``time_unit`` (kept, not learned) and, unless
        ``derive_length``, the length unit.
    derive_length : bool
        Derive the length unit (``--length-unit auto``).
    chunk_rows : int
        The single-machine run's ``--chunk-rows``: the first chunk's size.
    first_appearance : bool
        Tracks of a chunk in order of first appearance (a CSV read with ids as text), else sorted
        by id (Parquet): the order the single-machine run steps them in.

    Returns
    -------
    (float, str or None, float or None, tuple, pandas.DataFrame)
        The length unit; why it fell back to 1 (else None); the time unit (None: no track has a
        positive time step); the reach and the gap floor (the config's, or what ``"auto"`` settles
        at); the first chunk's first rows (a sample of the data's types).
    """
    from .io import in_file_order, to_arrays
    from .streaming import learned_sampling, length_unit_rule

    canon = _engine_columns(columns)
    counts = {} if columns.time is None else None

    def chunks():  # normalised as a single-machine read normalises each of its chunks
        for raw in _first_chunks(prepared, chunk_rows):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # the single-machine run warns; here the units only
                chunk = normalise_table(raw.drop(columns="_order"), canon, counts=counts,
                                        first_appearance=first_appearance)
            yield chunk

    read = chunks()
    first = next(read, None)
    if first is None:
        raise ValueError("The track files have no rows (only headers or nothing at all)")
    unit, why = config.length_unit, None
    if derive_length:
        arrays = to_arrays(first, columns.positions)
        unit, why = length_unit_rule(arrays.values, times=arrays.times)
    time_unit, sampling = config.time_unit, (config.reach, config.gap_floor)
    if time_unit is None or "auto" in sampling:  # from the first chunk with a step, as a single machine
        time_unit, *sampling = learned_sampling((in_file_order(chunk) for chunk in itertools.chain([first], read)),
                                                replace(config, length_unit=unit), columns.positions)
    return unit, why, time_unit, tuple(sampling), first.iloc[:3]


# --------------------------------------------------------------------------------- per partition
def _rank_major_chunks(table, cells):
    """Index arrays into ``table`` (tracks contiguous, each in time order): each track's k-th rows together.

    Each chunk covers whole ranks ``[r0, r1)`` of the tracks still going at ``r0`` with at most
    ``cells`` (ranks x tracks) cells, or part of one rank's tracks when a rank alone has more.
    """
    codes = pd.factorize(table["track_id"], sort=False)[0]
    rank = table.groupby(codes, sort=False).cumcount().to_numpy()
    order = np.lexsort((codes, rank))
    per_rank = np.bincount(rank)
    starts = np.concatenate(([0], np.cumsum(per_rank)))
    chunks, r0 = [], 0
    while r0 < len(per_rank):
        width = int(per_rank[r0])
        if width >= cells:
            for a in range(starts[r0], starts[r0 + 1], cells):
                chunks.append(order[a:min(a + cells, starts[r0 + 1])])
            r0 += 1
            continue
        r1 = min(len(per_rank), r0 + max(1, cells // width))
        chunks.append(order[starts[r0]:starts[r1]])
        r0 = r1
    return chunks


def predict_table(table, config: dict, positions, *, chunk_rows: int = 200_000, batch_tracks: int = BATCH_TRACKS):
    """Step a track table (whole tracks, contiguous, each in time order) in bounded batches.

    The same :meth:`kalmix.streaming.TrackPredictor.process_table` as single-machine
    ``kalmix predict``; batches of ``batch_tracks`` tracks, each a fresh predictor (states
    dropped after it), in engine calls of at most ``chunk_rows`` cells. Returns the engine's
    columns in the table's order.
    """
    from .streaming import StreamConfig, TrackPredictor, next_row_times

    codes = pd.factorize(table["track_id"], sort=False)[0]
    bounds = np.searchsorted(codes, np.arange(0, codes.max() + 1 + batch_tracks, batch_tracks))
    frames = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        if a == b:
            continue
        batch = table.iloc[a:b]
        engine = TrackPredictor(StreamConfig(**config), positions)
        engine.warn_skipped = False   # (as kalmix predict: the rows are read sorted, skipped ones counted there)
        parts = [batch.iloc[rows] for rows in _rank_major_chunks(batch, chunk_rows)]
        for part, later in zip(parts, next_row_times(parts)):   # a track's next row may be in a later part
            frames.append(engine.process_table(part, list(positions), later))
    out = pd.concat(frames, ignore_index=True)
    order = pd.Index(pd.unique(table["track_id"])).get_indexer(out["track_id"])
    return out.iloc[np.lexsort((out["time"].to_numpy(), order))].reset_index(drop=True)


def _predict_partition(frame, columns, config, chunk_rows, batch_tracks, first_appearance, meta):
    from .streaming import with_input_names

    if columns.time is not None:
        frame = frame[frame["time"].notna()]  # a row without a time is dropped (as the file reader does)
    if frame.empty:
        return meta
    frame = frame.sort_values("_order", kind="stable").drop(columns="_order")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # sorting and repeated times: as a single-machine read
        table = normalise_table(frame, _engine_columns(columns), first_appearance=first_appearance)
    out = predict_table(table, config, columns.positions, chunk_rows=chunk_rows, batch_tracks=batch_tracks)
    return with_input_names(out, columns).astype(meta.dtypes.to_dict())


# --------------------------------------------------------------------------------------- the API
def predict_dask(frame, columns: TrackColumns | None = None, *, length_unit: float | None = None,
                 chunk_rows: int = 200_000, batch_tracks: int = BATCH_TRACKS, partitions: int | None = None,
                 first_appearance: bool = False, prepared: bool = False, log=None, **settings):
    """Predict every track of a dask DataFrame: the rows and columns single-machine ``kalmix predict`` writes.

    Lazy: returns a dask DataFrame (``.to_parquet(...)``, ``.compute()``); only the first
    ``chunk_rows`` rows are read now, to derive the length and time units (see the module
    docstring). Each output partition holds whole tracks, each in time order.

    Parameters
    ----------
    frame : dask.dataframe.DataFrame
        One row per measurement: track id, time and 1-3 position columns (any names, see
        ``columns``), rows of a track in any partitions and any order.
    columns : TrackColumns, optional
        Which columns are which; detected from the column names as ``kalmix predict`` does.
    length_unit : float, optional
        Measurement-noise size in data units; None derives it as ``kalmix predict`` does (``auto``).
    chunk_rows : int
        The first chunk's size for the units (the ``--chunk-rows`` of the single-machine run to
        match) and the largest engine call (cells).
    batch_tracks : int
        Tracks stepped together (bounds the states held).
    partitions : int, optional
        Partitions of the shuffle (default: the input's).
    first_appearance : bool
        Order of the tracks inside a chunk when the units are derived: first appearance (a CSV
        read by ``kalmix predict``), else sorted by id (Parquet, the default).
    prepared : bool
        ``frame`` is already canonical (:func:`read_archive`).
    log : callable, optional
        Called with one line when the length unit is derived.
    **settings
        :class:`kalmix.streaming.StreamConfig` arguments (``n_experts``, ``seed``, ``horizon``,
        ``max_gap``, ``max_gap_factor``, ``options``, ``bank``, ``rule``, ``time_unit``); None
        ``time_unit`` is learned as ``kalmix predict`` learns it. Without the population prior
        (``population_prior`` False, refused if True): a partition's tracks do not see the others'.

    Returns
    -------
    dask.dataframe.DataFrame
    """
    import dask

    from .bank import check_automatic_length_unit
    from .streaming import StreamConfig

    chunk_rows, batch_tracks = int(chunk_rows), int(batch_tracks)
    if chunk_rows < 1 or batch_tracks < 1:
        raise ValueError(f"chunk_rows, batch_tracks: expected integers >= 1, got {chunk_rows}, {batch_tracks}")
    if partitions is not None and int(partitions) < 1:
        raise ValueError(f"partitions: expected an integer >= 1, got {partitions}")
    settings = {"population_prior": False, **settings}
    config = StreamConfig(length_unit=1.0 if length_unit is None else length_unit, **settings)  # checked now
    if config.population_prior:
        raise ValueError("population_prior: not with Dask (a partition's tracks do not see the other partitions' "
                         "tracks); run TrackPredictor.process_table on one machine")
    if columns is None:
        columns = detect_columns([str(c) for c in frame.columns])
    check_output_names(columns)
    if not prepared:
        frame = prepare(frame, columns)
    unit, why, time_unit, (reach, gap_floor), sample = data_units(frame, columns, config,
                                                                  derive_length=length_unit is None,
                                                                  chunk_rows=chunk_rows,
                                                                  first_appearance=first_appearance)
    if log is not None and length_unit is None:
        log(f"length unit {unit:.6g} (auto; pass --length-unit to override)" if why is None else
            f"length unit 1 (auto could not estimate it: the first chunk has {why}; pass --length-unit)")
    check_automatic_length_unit(unit)
    settings = {**asdict(config), "length_unit": unit, "time_unit": time_unit, "reach": reach, "gap_floor": gap_floor}
    meta = dask.delayed(_meta)(sample, columns, settings).compute()  # on a worker, which loads the engine now
    shuffled = frame.shuffle(on="track_id", npartitions=int(partitions or frame.npartitions))
    return shuffled.map_partitions(_predict_partition, columns, settings, chunk_rows, batch_tracks,
                                   first_appearance, meta, meta=meta, enforce_metadata=False)


def _meta(sample, columns, settings):
    """The output's empty frame, with the columns and types the partitions give (whatever columns they add)."""
    from .streaming import with_input_names

    out = predict_table(sample, settings, columns.positions)
    return with_input_names(out, columns).iloc[:0]
