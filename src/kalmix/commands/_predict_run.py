"""The body of ``kalmix predict``: a file chunk by chunk or stdin batch by batch, each committed whole.

A chunk (file) or the stdin lines that have arrived (a batch; one line when they come one at a
time) are computed by :class:`kalmix.streaming.TrackPredictor`,
then committed: its predictions are written and, every ``--save-every`` rows and at exit,
the state file is saved with the output position it matches (:mod:`._durable`). A chunk
stopped before its commit is rolled back; stdin rows, once read, are finished. So after
SIGINT, SIGTERM or SIGHUP the output and the state file describe the same rows, and the
same command run again continues exactly where the first stopped.

The parts: :mod:`._predict_common` (the run: commits, the summary at the end),
:mod:`._predict_file` (a file), :mod:`._predict_stream` (stdin, read by :mod:`._stdin_lines`
and :mod:`._stdin_rows`), :mod:`._predict_notes` (what the run says on stderr) and
:mod:`._output` (the ``-o`` file).
"""

from __future__ import annotations

import sys

from ._common import silence_stdout
from ._durable import Interrupted
from ._output import OutputClosed
from ._predict_common import Run
from ._predict_file import predict_file
from ._predict_stream import predict_stream


def run_predict(guard, engine, settings, unit, input_path, state_path, save_every, output, out_fmt,
                time_column, position_columns, id_column, chunk_rows, progress, backend="cpu", *,
                on_bad_row="skip", rejects=None):
    """Run, commit, and on any exit save what was committed; then report."""
    run = Run(guard, engine, state_path, save_every, output, out_fmt, on_bad_row, rejects)
    run.backend = backend
    failed = False
    try:
        if input_path == "-":
            predict_stream(run, sys.stdin, settings, unit, time_column, position_columns, id_column)
        else:
            predict_file(run, input_path, settings, unit, time_column, position_columns, id_column, chunk_rows,
                         progress)
    except Interrupted as stop:
        run.stopped = stop
    except OutputClosed:
        run.closed = True
        silence_stdout()
    except BaseException:
        failed = True
        raise
    finally:
        with guard.deferred(deliver=False):
            run.finish(failed)
    run.report()
