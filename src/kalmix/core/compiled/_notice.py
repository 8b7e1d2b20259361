"""Saying so while kalmix's kernels compile (a fresh install's first run, or the first after an upgrade).

numba compiles a kernel the first time it is called, unless its on-disk cache (see
:mod:`kalmix.core.compiled`) holds it already. Measured on two cores shared with other work
(load average ~5), an empty cache: ``kalmix predict`` of a 1,000-row file 53 s, ``kalmix
reproduce table1`` 2 min, nearly all of it compiling; once. This module tells the user,
instead of minutes of silence.

How a compile is seen: numba fires a ``numba:compile`` event around every compile that its
cache could not serve, and none when the cache serves the kernel, so a run with a warm cache
pays one dictionary look-up and says nothing. :func:`watch` (called where the compiled engine
and the paper's mixture are entered: :func:`kalmix.core.compiled.engine.run`,
:func:`kalmix.core.fast.run_fast`) listens to those events, for kalmix's own functions only;
:func:`compiling` marks the time spent waiting for a kernel that another process compiles
(:mod:`._warm`). Compiles that follow one another within :data:`QUIET_SECONDS` make one
*episode*, told once.

Where it is told:

- The ``kalmix`` logger (:mod:`logging`): when an episode starts, ``"compiling kalmix's kernels
  for this machine, once per setting ..."``; when it ends, the elapsed time (INFO). The first
  start of a process is logged at WARNING, the lowest level that Python shows when no
  logging is configured (its last-resort handler writes WARNING and above to stderr): an
  API user who set nothing up sees that one line, once per process and only when kernels
  compile, rather than a minute without a word; a program that configured logging gets the
  record like any other. It is a message, not a :mod:`warnings` warning: ``-W error`` and
  test suites' warning filters do not turn it into an error. Later starts, and every start
  while a display (below) shows it, are logged at INFO. To hide it:
  ``logging.getLogger("kalmix").setLevel(logging.ERROR)``; to see the end too:
  ``logging.basicConfig(level=logging.INFO)``.
- Displays registered with :func:`add_display` (the command line's stderr display,
  :class:`kalmix.commands._common.CompileDisplay`): ``start(first)`` when an episode starts,
  ``tick(elapsed)`` about every :data:`TICK_SECONDS` while it lasts (from a daemon thread),
  ``done(elapsed, finished)`` when it ends (``finished`` false when it ended by an error or
  a Ctrl-C). An episode still open when the process exits is ended then.

Nothing here imports numba until :func:`watch` is called.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import threading
import time

__all__ = ["QUIET_SECONDS", "TICK_SECONDS", "add_display", "compiling", "remove_display", "seconds_text", "watch"]

logger = logging.getLogger("kalmix")

#: An episode ends when nothing has compiled for this long (the gaps between one run's kernels are milliseconds).
QUIET_SECONDS = 1.5
#: How often displays are told the elapsed time.
TICK_SECONDS = 1.0

START = "compiling kalmix's kernels for this machine, once per setting (a minute or two) ..."
START_MORE = "compiling more of kalmix's kernels for this machine, once per setting ..."

_lock = threading.Lock()
_active = 0          # kalmix compiles in progress (numba's events, nested ones too) plus open compiling() blocks
_episode = None      # the open episode, or None
_episodes = 0        # episodes started in this process
_displays: list = []
_watching = False
_exit_hook: list = []   # non-empty once _close_at_exit is registered


class _Episode:
    __slots__ = ("start", "last_end", "failed", "wake")

    def __init__(self, now: float):
        self.start = now
        self.last_end = now
        self.failed = False
        self.wake = threading.Event()


def add_display(display) -> None:
    """Tell ``display`` (``start(first)``, ``tick(elapsed)``, ``done(elapsed, finished)``) of every episode."""
    with _lock:
        if display not in _displays:
            _displays.append(display)


def remove_display(display) -> None:
    with _lock:
        if display in _displays:
            _displays.remove(display)


def watch() -> None:
    """Listen to numba's compile events (once per process; nothing if numba is missing)."""
    global _watching
    if _watching:
        return
    with _lock:
        if _watching:
            return
        try:
            from numba.core import event
        except ImportError:   # numba missing, or without events: no notice, the rest works
            _watching = True
            return
        event.register("numba:compile", _make_listener(event.Listener)())
        _watching = True


def seconds_text(elapsed: float) -> str:
    """How long a compile took, as the notices say it: ``"0.4 s"`` under 10 s (not ``"0 s"``), else ``"28 s"``."""
    return f"{elapsed:.1f} s" if elapsed < 9.95 else f"{elapsed:.0f} s"


def _ours(data) -> bool:
    """Whether a compile event is of a kalmix function (not of the user's own numba code)."""
    try:
        module = data["dispatcher"].py_func.__module__ or ""
    except (AttributeError, KeyError, TypeError):
        return False
    return module == "kalmix" or module.startswith("kalmix.")


def _make_listener(base):
    class Listener(base):
        # called inside numba's compile: a notice must never break it (a Ctrl-C, BaseException, goes through)
        def on_start(self, event):
            try:
                if _ours(event.data):
                    _begin()
            except Exception:   # noqa: BLE001
                pass

        def on_end(self, event):
            try:
                if _ours(event.data):
                    # (not Event.is_failed: in numba 0.68 it is true when there was no exception)
                    _end(failed=getattr(event, "_exc_details", None) is not None)
            except Exception:   # noqa: BLE001
                pass

    return Listener


@contextlib.contextmanager
def compiling():
    """A block that waits for a kernel being compiled elsewhere (another process): part of an episode."""
    _begin()
    failed = True
    try:
        yield
        failed = False
    finally:
        _end(failed)


def _begin() -> None:
    """A compile starts: opens an episode if none is open (and tells the logger and the displays)."""
    global _active, _episode, _episodes
    try:
        with _lock:
            _active += 1
            if _episode is not None:
                return
            episode = _episode = _Episode(time.monotonic())
            _episodes += 1
            first = _episodes == 1
            displays = list(_displays)
        if not _exit_hook:
            _exit_hook.append(atexit.register(_close_at_exit))   # an episode open at exit ends there
        level = logging.WARNING if first and not displays else logging.INFO
        logger.log(level, START if first else START_MORE)
        for display in displays:
            _call(display.start, first)
        threading.Thread(target=_follow, args=(episode,), name="kalmix-compile-notice", daemon=True).start()
    except Exception:   # noqa: BLE001 - runs inside numba's compile (a logging handler that fails, no thread)
        pass


def _end(failed: bool = False) -> None:
    global _active
    with _lock:
        _active = max(0, _active - 1)
        if _episode is not None:
            _episode.last_end = time.monotonic()
            _episode.failed |= failed


def _follow(episode: _Episode) -> None:
    """The episode's clock: ticks the displays; ends the episode once nothing has compiled for QUIET_SECONDS."""
    while not episode.wake.wait(TICK_SECONDS):
        with _lock:
            if _episode is not episode:
                return
            quiet = _active == 0 and time.monotonic() - episode.last_end >= QUIET_SECONDS
            displays = list(_displays)
        if quiet:
            _close(episode)
            return
        elapsed = time.monotonic() - episode.start
        for display in displays:
            _call(display.tick, elapsed)


def _close(episode: _Episode) -> None:
    global _episode
    with _lock:
        if _episode is not episode:
            return
        _episode = None
        finished = not episode.failed and _active == 0
        displays = list(_displays)
    episode.wake.set()
    elapsed = (episode.last_end if finished else time.monotonic()) - episode.start
    if finished:
        logger.info("compiled kalmix's kernels in %s (cached: later runs load them)", seconds_text(elapsed))
    else:
        logger.info("compiling kalmix's kernels stopped after %s", seconds_text(elapsed))
    for display in displays:
        _call(display.done, elapsed, finished)


def settle() -> None:
    """End the open episode now if nothing compiles (tests: without waiting for QUIET_SECONDS)."""
    with _lock:
        episode = _episode
        if episode is None or _active:
            return
    _close(episode)


def _close_at_exit() -> None:
    episode = _episode
    if episode is not None:
        _close(episode)


def _call(method, *args) -> None:
    try:
        method(*args)
    except Exception:   # noqa: BLE001 - a display that fails (a closed stream) must not stop the work
        pass


def _reset() -> None:
    """Forget the episodes of this process (tests): the next start is a first one again."""
    global _episode, _episodes, _active
    with _lock:
        episode, _episode = _episode, None
        _episodes = 0
        _active = 0
    if episode is not None:
        episode.wake.set()
