"""What keeps ``kalmix predict`` consistent when it is stopped: signals and the state lock.

The unit of work is a *chunk* (a file) or a *row* (stdin). It is computed, then committed:
its output is written and, every ``--save-every`` rows and at exit, the state file is
saved with the position of the output it matches. A chunk that is stopped before its
commit is rolled back (:meth:`kalmix.streaming.TrackPredictor.rollback`), so the state
file, the trackers and the output always describe the same rows.

- :class:`SignalGuard`: SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` at once
  while the work in progress can be rolled back (reading, computing a chunk), and only
  after the commit in progress otherwise (writing, saving, one stdin row).
- :class:`StateLock`: one process per ``--state`` file (``flock`` on ``<state>.lock``), and
  the checks that would otherwise fail only at the first save (missing directory,
  read-only file).
- :class:`kalmix.commands._output.Output`: the ``-o`` file (or stdout), written one committed
  piece at a time, with the byte and line count of the last commit, which the state file
  records; a resumed run checks the file against that record and continues it.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import stat
import threading

from ._interrupt import send_again_later, swallowing

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None

__all__ = ["Interrupted", "SignalGuard", "StateLock", "TEST_HOOK"]

_STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))
#: Test hook, ``SIGNAME:N``: after the N-th unit of work (a slice of a chunk, a stdin batch) the
#: process sends itself SIGNAME, at a known point instead of after a sleep.
TEST_HOOK = "KALMIX_TEST_SIGNAL_AFTER"


class Interrupted(BaseException):
    """A stop signal arrived. A ``BaseException`` like ``KeyboardInterrupt``: no ``except Exception`` swallows it."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def _parse_hook(text):
    if not text:
        return None
    name, _, count = text.partition(":")
    try:
        return signal.Signals[name.strip().upper()].value, int(count)
    except (KeyError, ValueError):
        raise ValueError(f"{TEST_HOOK}: expected SIGNAME:N (e.g. SIGTERM:3), got {text!r}") from None


class SignalGuard:
    """Stop signals become :class:`Interrupted`: at once, or after the commit in progress (:meth:`deferred`)."""

    def __init__(self):
        self.received: int | None = None
        self.raised = False   # an Interrupted was raised (see _handle)
        self._deferring = 0
        self._previous: dict = {}
        self._ticks = 0
        self._hook = _parse_hook(os.environ.get(TEST_HOOK))

    def __enter__(self) -> "SignalGuard":
        if threading.current_thread() is threading.main_thread():
            for sig in _STOP_SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> bool:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        return False

    def _handle(self, signum, frame):
        if self.received is None:
            self.received = signum
        if self._deferring:
            return
        if swallowing(frame):   # where Python would print the exception and go on: raised a moment later
            send_again_later(signum, lambda: bool(self._previous) and not self.raised)
            return
        self.raised = True
        raise Interrupted(signum)

    @contextlib.contextmanager
    def deferred(self, deliver: bool = True):
        """A commit: signals wait until it is done; then (``deliver``) the first one is raised."""
        self._deferring += 1
        try:
            yield
        finally:
            self._deferring -= 1
        if deliver and not self._deferring and self.received is not None:
            self.raised = True
            raise Interrupted(self.received)

    def tick(self) -> None:
        """One unit of work done (see :data:`TEST_HOOK`); a stop signal that arrived and was not raised (or
        was raised where Python ignored it) is raised here."""
        if self.received is not None and not self._deferring:
            self.raised = True
            raise Interrupted(self.received)
        if self._hook is not None:
            self._ticks += 1
            if self._ticks == self._hook[1]:
                os.kill(os.getpid(), self._hook[0])


class StateLock:
    """Exclusive use of a ``--state`` file by this process, checked before any work.

    ``ValueError`` (naming ``--state``) when the directory is missing or not writable, the
    file is read-only or not a regular file, or another process holds the lock. The lock
    file ``<state>.lock`` stays on disk (removing it would race with the next writer); the
    lock itself goes with the process.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        # beside the file a save replaces (write_archive follows a symbolic link): a link and its target share it
        self.lock_path = os.path.realpath(self.path) + ".lock"
        self._fd: int | None = None

    def __enter__(self) -> "StateLock":
        # where a save writes: a symbolic link's target, which need not exist yet (write_archive makes it)
        directory = os.path.dirname(os.path.realpath(self.path))
        if not os.path.isdir(directory):
            raise ValueError(f"--state: the directory {directory!r} does not exist (state file {self.path!r})")
        if os.path.exists(self.path):
            if not os.path.isfile(self.path):
                raise ValueError(f"--state: expected a state file, got {self.path!r}, which is not a regular file")
            mode = os.stat(self.path).st_mode
            if not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH) or not os.access(self.path, os.W_OK):
                raise ValueError(f"--state: {self.path!r} is read-only (mode {stat.S_IMODE(mode):04o}) and every save "
                                 "replaces it; make it writable or give another --state file")
        if not os.access(directory, os.W_OK):
            raise ValueError(f"--state: the directory {directory!r} is not writable")
        try:
            self._fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as error:
            raise ValueError(f"--state: cannot open the lock file {self.lock_path!r}: {error.strerror}") from None
        if fcntl is not None:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(self._fd)
                self._fd = None
                raise ValueError(f"--state: {self.path!r} is in use by another kalmix process (it holds "
                                 f"{self.lock_path!r}); wait for it to finish or give another --state file") from None
        # only under the lock: without flock (Windows) another writer's temporary file may be in use
        self.removed = remove_stale_temporaries(self.path) if fcntl is not None else 0
        return self

    def __exit__(self, *exc) -> bool:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        return False


def remove_stale_temporaries(path) -> int:
    """Remove the temporary files that saves of the state file ``path`` killed mid-write left beside it
    (``.NAME.`` + 8 random characters + ``.tmp``, :func:`kalmix.archive.write_archive`); how many. Only the holder
    of the state's lock saves, so none of them is in use: each is a dead process's."""
    directory, name = os.path.split(os.path.realpath(path))
    pattern = re.compile(re.escape(f".{name}.") + r"[a-z0-9_]{8}\.tmp")
    removed = 0
    try:
        names = os.listdir(directory)
    except OSError:
        return 0
    for entry in names:
        if pattern.fullmatch(entry):
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(directory, entry))
                removed += 1
    return removed

