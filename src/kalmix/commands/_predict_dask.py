"""The body of ``kalmix predict --engine dask``: a partitioned archive in, a partitioned Parquet dataset out.

The work is :func:`kalmix.dask_predict.predict_dask` on a Dask cluster (``--scheduler``) or a
local one; this module checks the arguments, starts and stops the cluster, shows progress
and moves the finished dataset into place.

The output is written to ``<OUTPUT_DIR>.kalmix-partial`` and renamed to OUTPUT_DIR when every
partition is written: OUTPUT_DIR is complete or absent. A partition recomputed after a lost
worker is written again with the same rows; a stopped run leaves nothing and the same
command starts again (there is no ``--state``: the run is idempotent).
"""

from __future__ import annotations

import contextlib
import fnmatch
import logging
import os
import shutil
import sys
import time

import click

from ._common import position_names
from ._durable import Interrupted
from ._predict_notes import gap_note

#: Shuffle partitions per worker thread at least (smaller tasks balance the load across workers).
PARTITIONS_PER_WORKER = 4


def check_options(input_path, output, state_path, given):
    """``ValueError`` for what the Dask engine cannot do, before anything starts (``given``: options set)."""
    try:
        import dask.dataframe  # noqa: F401
        import distributed  # noqa: F401
    except ImportError as error:
        raise ImportError(f"--engine dask needs the 'dask' extra ({error.name} is missing): "
                          "pip install 'kalmix[dask]'") from None
    if state_path is not None or "save_every" in given:
        flag = "--state" if state_path is not None else "--save-every"
        raise ValueError(f"{flag}: the Dask engine keeps no state file: its run is idempotent (a lost worker's "
                         f"partitions are recomputed by Dask, a stopped run is run again); drop {flag}")
    if input_path == "-":
        raise ValueError("INPUT: --engine dask reads files (a directory or a glob), not stdin")
    if output is None:
        raise ValueError("--output: --engine dask writes a partitioned Parquet dataset: give -o OUTPUT_DIR")
    if "workers" in given and "scheduler" in given:
        raise ValueError("--workers: sets the size of a local cluster; with --scheduler the cluster has its own")
    if not os.path.isdir(output) and output.lower().endswith((".csv", ".csv.gz", ".parquet", ".pq", ".jsonl", ".json")):
        raise ValueError(f"--output: --engine dask writes a partitioned Parquet dataset, a directory; got the file "
                         f"name {output!r} (give a directory name, e.g. {os.path.splitext(output)[0]!r})")
    output = os.path.abspath(output)
    if os.path.lexists(output) and not os.path.isdir(output):
        raise ValueError(f"--output: {output!r} exists and is not a directory; give a new directory")
    if os.path.isdir(output) and os.listdir(output):
        raise ValueError(f"--output: the directory {output!r} exists and is not empty; give a new or empty one")
    parent = os.path.dirname(output)
    if not os.path.isdir(parent):
        raise ValueError(f"--output: the directory {parent!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"--output: the directory {parent!r} is not writable")
    inside = os.path.realpath(output)
    if os.path.isdir(input_path):
        source = os.path.realpath(input_path)
        inside = inside == source or inside.startswith(source + os.sep)
    else:  # a glob's '*' also matches '/' here: anything the pattern could match later is refused
        inside = fnmatch.fnmatchcase(os.path.join(inside, "part.0.parquet"), os.path.abspath(input_path))
    if inside:
        raise ValueError(f"--output: {output!r} is inside INPUT {input_path!r}; a later run would read it")


def _partial_dir(output):
    output = os.path.abspath(output)
    return os.path.join(os.path.dirname(output), os.path.basename(output) + ".kalmix-partial")


@contextlib.contextmanager
def _client(scheduler, workers):
    from distributed import Client, LocalCluster

    if scheduler:  # its workers and their threads are the cluster's
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as error:
            raise ValueError(f"--scheduler: cannot reach the Dask scheduler at {scheduler!r}: {error}") from None
        with client:
            yield client
        return
    cores = os.cpu_count() or 1
    workers = workers or cores
    # the compiled engine runs a call's tracks on numba's threads: the workers share the cores, not each take all
    threads = os.environ.get("NUMBA_NUM_THREADS") or str(max(1, cores // workers))
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.CRITICAL, env={"NUMBA_NUM_THREADS": threads}) as cluster, \
            Client(cluster) as client:
        yield client


def _rows_written(directory):
    import pyarrow.parquet as pq

    files = [os.path.join(directory, name) for name in os.listdir(directory) if name.endswith(".parquet")]
    return sum(pq.read_metadata(path).num_rows for path in files), len(files)


def run_dask(input_path, output, settings, unit, time_column, position_columns, id_column, chunk_rows,
             progress, scheduler, workers, partitions):
    """Predict INPUT's archive into OUTPUT_DIR on a Dask cluster; one summary line on stderr.

    A stop signal (the caller's :class:`._durable.SignalGuard`) cancels the work, removes what
    was written and exits with 128 + the signal number; nothing is left to resume from.
    """
    from distributed import KilledWorker

    from ..dask_predict import archive_files, read_archive
    from ..io.tables import column_notes, read_header

    started = time.perf_counter()
    partial = _partial_dir(output)
    try:
        frame, columns, fmt = read_archive(input_path, time=time_column, positions=position_names(position_columns),
                                           track_id=id_column)
        for note in column_notes(columns, read_header(archive_files(input_path)[0][0], fmt)):
            _note(note)
        with _client(scheduler, workers) as client:
            total, splits, work = _compute(client, frame, columns, fmt, partial, settings, unit, chunk_rows,
                                           progress, scheduler, partitions)
    except Interrupted as stop:
        shutil.rmtree(partial, ignore_errors=True)
        _note(f"stopped by {stop.name}; nothing was written to {output}: run the same command again "
              "(the Dask run is idempotent)")
        raise SystemExit(stop.exit_code) from None
    except KilledWorker as error:  # one task took its worker down, again and again
        shutil.rmtree(partial, ignore_errors=True)
        raise ValueError(f"the task {error.task!r} killed its worker {error.allowed_failures + 1} times (out of "
                         "memory? see 'Memory per worker' in the documentation: more --partitions, a smaller "
                         "--chunk-rows)") from None
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    written, files = _rows_written(partial)
    target = os.path.abspath(output)
    if os.path.isdir(target):
        os.rmdir(target)  # checked empty at start
    os.rename(partial, target)
    dropped = total - written
    why = (f" ({dropped} dropped: a repeated timestamp of a track keeps the last row, a row without a time is "
           "dropped)" if dropped else "")
    _note(f"{total} row(s) in, {written} prediction(s) written to {output} in {files} file(s){why}; "
          f"{time.perf_counter() - started:.1f} s ({work:.1f} s of work on the cluster after the start and "
          "the first chunk)")
    gap_note(settings["max_gap"], settings["max_gap_factor"], splits, written)   # rows kept, as a local run counts


def _note(text):
    click.echo(f"kalmix: {text}", err=True)


def gap_splits(part, track_id) -> int:
    """New segments the gap rule started in a partition of whole tracks (each track's segments count from 0)."""
    if not len(part):
        return 0
    if track_id is None:
        return max(int(part["segment"].max()), 0)
    return int(part.groupby(track_id, sort=False)["segment"].max().clip(lower=0).sum())


def _compute(client, frame, columns, fmt, partial, settings, unit, chunk_rows, progress, scheduler, partitions):
    """Write the predictions into ``partial``; the number of input rows, the gap rule's new segments and the seconds
    the cluster took."""
    from distributed import progress as progress_bar

    from ..dask_predict import predict_dask

    threads = sum(client.nthreads().values())
    count = partitions or max(frame.npartitions, PARTITIONS_PER_WORKER * threads)
    result = predict_dask(frame, columns, prepared=True, first_appearance=fmt == "csv", length_unit=unit,
                          chunk_rows=chunk_rows, partitions=count, log=_note, **settings)
    shutil.rmtree(partial, ignore_errors=True)  # what a killed run left
    write = result.to_parquet(partial, write_index=False, compute=False)
    rows_in = frame.map_partitions(len).sum()
    # the gap rule's new segments (a partition holds whole tracks), from the same tasks as the written rows
    splits = result.map_partitions(gap_splits, columns.track_id, meta=(None, "int64")).sum()
    where = client.scheduler.address if scheduler else "a local cluster"
    _note(f"{frame.npartitions} input partition(s) -> {count} partition(s) by track, {threads} worker thread(s) "
          f"on {where}; without the population prior (a partition does not see the other partitions' tracks): "
          "the numbers of --engine local --no-population-prior")
    futures = client.compute([write, rows_in, splits])
    submitted = time.perf_counter()
    try:
        if sys.stderr.isatty() if progress is None else progress:
            with contextlib.redirect_stdout(sys.stderr):  # the bar is drawn on stdout
                progress_bar(futures)
            click.echo("", err=True)
        _, total, split = client.gather(futures)
        return int(total), int(split), time.perf_counter() - submitted
    finally:
        client.cancel(futures)
