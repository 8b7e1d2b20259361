"""Helpers shared by the sub-commands: one-line errors, checked options, JSON output, progress bars and the
notice while kalmix's kernels compile."""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import shutil
import sys
import threading
import warnings

import click
import numpy as np

#: ``--seed`` of every command: what :func:`kalmix.bank.make_params` takes (``MAX_SEED``).
SEED = click.IntRange(0, 2**63 - 1)


class Finite(click.ParamType):
    """A finite number (click's FloatRange lets nan and inf through), at least ``minimum`` (above it if ``open``)
    and at most ``maximum``."""

    name = "number"

    def __init__(self, minimum: float | None = None, open: bool = False, maximum: float | None = None):
        self.minimum, self.open, self.maximum = minimum, open, maximum

    def convert(self, value, param, ctx):
        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"expected a number, got {value!r}", param, ctx)
        if not math.isfinite(number):
            self.fail(f"expected a finite number, got {value!r}", param, ctx)
        if self.minimum is not None and (number <= self.minimum if self.open else number < self.minimum):
            self.fail(f"expected a number {'>' if self.open else '>='} {self.minimum:g}, got {value!r}", param, ctx)
        if self.maximum is not None and number > self.maximum:
            self.fail(f"expected a number <= {self.maximum:g}, got {value!r}", param, ctx)
        return number


def position_names(text):
    """``--position``: 1 to 3 comma-separated column names as a list (None when not given);
    ``click.BadParameter`` otherwise."""
    if text is None:
        return None
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not 1 <= len(names) <= 3:
        raise click.BadParameter(f"expected 1 to 3 comma-separated column names, got {text!r}",
                                 param_hint="--position")
    return names


def missing_directory(path) -> tuple[str, bool] | None:
    """``(directory, taken)`` when the directory a file ``path`` would be written in is not one (``taken``:
    something else, a file, stands there); None when it is a directory."""
    directory = os.path.dirname(os.path.abspath(path))
    return None if os.path.isdir(directory) else (directory, os.path.exists(directory))


def output_file(ctx, param, value):
    """click callback: a file to write, whose directory exists and is writable, checked before the work, so a
    missing directory fails at once, not after the whole run."""
    if value is not None:
        check_output_file(value)
    return value


def check_output_file(value, made_directory=None) -> None:
    """:func:`output_file`'s checks (``click.BadParameter``). ``made_directory``: a directory the command makes
    before it writes (and checks itself): a file directly in it may name it before it exists."""
    if not str(value).strip():
        raise click.BadParameter("expected a file name, got ''")
    if str(value) == "-":
        raise click.BadParameter("expected a file name, got '-' (standard output is not taken here: /dev/stdout "
                                 "is; ./- names a file called -)")
    if str(value).endswith(("/", os.sep)):
        raise click.BadParameter(f"expected a file name, got {value!r}, which names a directory")
    directory = os.path.dirname(os.path.abspath(value))
    if made_directory is not None and directory == os.path.abspath(made_directory) and not os.path.lexists(directory):
        return
    problem = missing_directory(value)
    if problem:
        directory, taken = problem
        raise click.BadParameter(f"the directory {directory!r} of {value!r} "
                                 f"{'is not a directory' if taken else 'does not exist'}")
    if os.path.isfile(value) or os.path.abspath(value).startswith(("/dev/", "/proc/")):
        if not os.access(value, os.W_OK):
            raise click.BadParameter(f"{value!r} is not writable")
    elif not os.access(directory, os.W_OK):
        raise click.BadParameter(f"the directory {directory!r} of {value!r} is not writable")


def figure_format_problem(path) -> str | None:
    """What is wrong with ``path`` as a figure to write (its extension names a format matplotlib does not write),
    or None (none: PNG, :func:`kalmix.archive.save_figure`)."""
    extension = os.path.splitext(str(path))[1].lstrip(".").lower()
    if not extension:
        return None
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = dict(FigureCanvasBase.get_supported_filetypes())
    kinds.pop("pgf", None)   # needs a LaTeX installation: it failed after the work with a 120-line traceback
    if extension in kinds:
        return None
    return (f"expected a figure file ending in .png (or {', '.join('.' + k for k in sorted(kinds) if k != 'png')}), "
            f"got {str(path)!r}")


def figure_file(ctx, param, value):
    """click callback: :func:`output_file` in a format matplotlib writes (:func:`figure_format_problem`), checked
    before the work, so ``--out fig.txt`` fails at once."""
    value = output_file(ctx, param, value)
    problem = None if value is None else figure_format_problem(value)
    if problem:
        raise click.BadParameter(problem)
    return value


def output_directory(ctx, param, value):
    """click callback: a directory to write into (made with its missing parents), checked before the work: its
    nearest existing ancestor must be a writable directory."""
    if not str(value).strip():
        raise click.BadParameter("expected a directory name, got ''")
    ancestor = os.path.abspath(value)
    while not os.path.exists(ancestor):
        if os.path.islink(ancestor):   # a link to nothing: makedirs would fail after the work ("File exists")
            raise click.BadParameter(f"{ancestor!r} is a symbolic link to nothing (to make or fill {value!r})")
        ancestor = os.path.dirname(ancestor)
    if not os.path.isdir(ancestor):
        raise click.BadParameter(f"{value!r} lies under {ancestor!r}, which is not a directory")
    if not os.access(ancestor, os.W_OK):
        raise click.BadParameter(f"{ancestor!r} is not writable (to make or fill {value!r})")
    return value


#: Set to 1: errors keep their traceback (a bug report needs it; a one-line error cannot tell a bad input from a
#: kalmix bug that raises the same type).
TRACEBACK_VARIABLE = "KALMIX_TRACEBACK"


@contextlib.contextmanager
def user_errors():
    """ValueError / FileNotFoundError / ImportError / MemoryError become one clear line (unless
    :data:`TRACEBACK_VARIABLE` is 1); warnings go to stderr."""
    if os.environ.get(TRACEBACK_VARIABLE, "0") == "1":
        with _warnings_to_stderr():
            yield
        return
    with _warnings_to_stderr():
        try:
            yield
        except (ValueError, TypeError, FileNotFoundError, ImportError) as error:
            raise click.ClickException(str(error)) from error
        except MemoryError as error:
            raise click.ClickException(f"not enough memory for this run ({error or 'MemoryError'}); ask for fewer "
                                       "experts, targets or rows") from error
        except EOFError as error:  # pandas on a truncated .gz; click would print a bare 'Aborted!'
            raise click.ClickException(f"the input ends early (a truncated or corrupt file?): {error}") from error
        except BrokenPipeError:   # the reader stopped early (``kalmix servo | head``): what it wanted it has
            silence_stdout()
            raise SystemExit(1) from None
        except OSError as error:  # a disk, permission or device error: one line, not a traceback
            where = f" {error.filename!r}" if error.filename else ""
            raise click.ClickException(f"{error.strerror or error}{where}") from error


def silence_stdout():
    """After a broken pipe, send what is left in stdout's buffer nowhere (no second error at exit)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real file descriptor (e.g. a test runner's buffer)
        pass


@contextlib.contextmanager
def _warnings_to_stderr():
    """Warnings as ``kalmix: warning: ...`` lines on stderr, every time."""
    def show(message, category, filename, lineno, file=None, line=None):
        click.echo(f"kalmix: warning: {message}", err=True)

    previous = warnings.showwarning
    warnings.showwarning = show
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", RuntimeWarning)
            # the command's own warnings (warnings.warn: UserWarning) are said every time: an "ignore" filter a
            # library or an earlier command in the same process added hid them (an order-dependent test)
            warnings.simplefilter("always", UserWarning)
            warnings.showwarning = show
            yield
    finally:
        warnings.showwarning = previous


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_json(path: str, data) -> None:
    """Write ``data`` (numpy scalars and arrays allowed) as indented JSON, whole or not at all (a Ctrl-C while it
    writes leaves the previous file)."""
    from ..archive import replaced_file

    try:
        with replaced_file(path, "w", what="a JSON file path", output=True) as handle:
            json.dump(data, handle, indent=1, default=_json_default)
            handle.write("\n")
    except OSError as error:   # a full disk, a device: which file (it said "No space left on device" alone)
        raise ValueError(f"cannot write the JSON file {path!r}: {error.strerror or error}") from None


def one_line_errors(function):
    """A command whose body runs inside :func:`user_errors` (bad input: one line, not a traceback)."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with user_errors():
            return function(*args, **kwargs)
    return wrapper


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):   # a closed or replaced stream
        return False


@contextlib.contextmanager
def progress_bar(total: int, description: str, unit: str):
    """A tqdm bar on stderr (absent if tqdm is missing); yields ``update(n=1, postfix=None)``."""
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is in the cli extra
        yield lambda n=1, postfix=None: None
        return
    # on a terminal only, as predict's: redirected to a log, every redraw would be a line of \r updates
    with tqdm(total=total, desc=description, unit=unit, leave=False, dynamic_ncols=True,
              disable=not _is_terminal(sys.stderr)) as bar:
        def update(n=1, postfix=None):
            if postfix:
                bar.set_postfix_str(postfix, refresh=False)
            bar.update(n)
        yield update


# ------------------------------------------------------------------------------------------ compile notice
class CompileDisplay:
    """The command line's stderr display of kalmix's kernel compiles (:mod:`kalmix.core.compiled._notice`).

    Not on a terminal (a log, a pipe): one line when the compile starts and one with its time when it ends.
    On a terminal: one line that counts the seconds (redrawn from the notice's thread) and becomes the
    end line; while it is drawn, ``sys.stderr`` (and ``sys.stdout`` if it is a terminal too) is wrapped so
    that another writer's text (a warning, click's ``Aborted!`` after a Ctrl-C) clears the line first, then
    goes through unchanged. While a tqdm progress bar is up on stderr (``kalmix predict``'s rows,
    ``reproduce``'s runs), the start and end lines are written above the bars and the bars are redrawn every
    tick, so their elapsed time counts. Nothing is written to standard output.
    """

    def __init__(self, stream=None):
        self.stream = sys.stderr if stream is None else stream
        self.terminal = _is_terminal(self.stream)
        self.lock = threading.RLock()
        self.open = False       # between start and done
        self.drawn = 0          # width of the status line now on the terminal (0: none)
        self.announced = False  # the start line was written whole (not a status line)
        self.first = True
        self.proxies: dict = {}   # "stderr" / "stdout": its _ClearingStream

    # -- texts
    def _start_text(self) -> str:
        from ..core.compiled._notice import START, START_MORE

        return "kalmix: " + (START if self.first else START_MORE)

    def _status_text(self, elapsed: float) -> str:
        text = f"kalmix: compiling kalmix's kernels for this machine, once per setting ... {elapsed:.0f} s"
        width = shutil.get_terminal_size(fallback=(80, 24)).columns - 1
        return text if len(text) <= width else text[:max(width, 1)]

    @staticmethod
    def _done_text(elapsed: float, finished: bool) -> str:
        from ..core.compiled._notice import seconds_text

        took = seconds_text(elapsed)
        if finished:
            return f"kalmix: compiled kalmix's kernels in {took} (cached: later runs start at once)"
        return f"kalmix: compiling kalmix's kernels stopped after {took}"

    # -- the notice's calls (start and done from the compiling thread or at exit, tick from the notice's thread)
    def start(self, first: bool) -> None:
        with self.lock:
            self.open, self.first, self.drawn = True, first, 0
            self.announced = not self.terminal or bool(self._bars())
        if self.announced:
            self._line(self._start_text())
        else:
            self._draw(0.0)

    def tick(self, elapsed: float) -> None:
        if not self.terminal:
            return
        bars = self._bars()
        if not bars:
            self._draw(elapsed)
            return
        # a bar is up (drawn over the status line, which its first write cleared): the start line above the bars
        with self.lock:
            if not self.open:
                return
            self._erase()
            self._unwrap()
            announce, self.announced = not self.announced, True
        if announce:
            self._line(self._start_text())
        for bar in bars:
            with contextlib.suppress(Exception):
                bar.refresh()

    def done(self, elapsed: float, finished: bool) -> None:
        with self.lock:
            self.open = False
            self._erase()
            self._unwrap()
        self._line(self._done_text(elapsed, finished))

    # -- drawing
    def _draw(self, elapsed: float) -> None:
        with self.lock:
            if not self.open:   # (a tick that comes after done)
                return
            text = self._status_text(elapsed).ljust(self.drawn)   # (covers a longer line drawn before)
            self.stream.write("\r" + text)
            self.stream.flush()
            self.drawn = max(len(text), 1)
            self._wrap()

    def _erase(self) -> None:
        """Clear the status line, if drawn (under the lock)."""
        if self.drawn:
            self.stream.write("\r" + " " * self.drawn + "\r")
            self.stream.flush()
            self.drawn = 0

    def _line(self, text: str) -> None:
        """A whole line on the stream, above the progress bars on it (cleared, then redrawn: tqdm.write's way,
        without its matching of streams, which a wrapped stream defeats)."""
        bars = self._bars()
        lock = sys.modules["tqdm"].tqdm.get_lock() if bars else contextlib.nullcontext()
        with lock:   # (tqdm's lock, then this display's: the order a bar writing through the wrapper takes too)
            for bar in bars:
                with contextlib.suppress(Exception):
                    bar.clear(nolock=True)
            with self.lock:
                self.stream.write(text + "\n")
                self.stream.flush()
            for bar in bars:
                with contextlib.suppress(Exception):
                    bar.refresh(nolock=True)

    def _bars(self) -> list:
        """The tqdm bars drawn on this display's stream (tqdm drops a disabled bar from its instances)."""
        tqdm_module = sys.modules.get("tqdm")
        if tqdm_module is None:
            return []
        try:
            bars = list(tqdm_module.tqdm._instances)
        except (AttributeError, TypeError, RuntimeError):   # (RuntimeError: a bar came or went meanwhile)
            return []
        return [bar for bar in bars if not getattr(bar, "disable", False) and self._ours(getattr(bar, "fp", None))]

    def _ours(self, stream) -> bool:
        """Whether ``stream`` (a bar's, which tqdm wraps) writes to this display's stream."""
        for _ in range(4):
            if stream is self.stream:
                return True
            if isinstance(stream, _ClearingStream):
                stream = stream._stream
            else:
                stream = getattr(stream, "_wrapped", None)   # tqdm's wrapper of a bar's file
                if stream is None:
                    return False
        return False

    def _wrap(self) -> None:
        """Wrap ``sys.stderr``, and ``sys.stdout`` if it is a terminal too (the same screen), in a
        :class:`_ClearingStream` (under the lock)."""
        for name in ("stderr", "stdout"):
            stream = getattr(sys, name)
            if isinstance(stream, _ClearingStream) or (name == "stdout" and not _is_terminal(stream)):
                continue
            if name == "stderr" and stream is not self.stream:
                continue
            proxy = self.proxies.get(name)
            if proxy is None or proxy._stream is not stream:
                proxy = self.proxies[name] = _ClearingStream(stream, self)
            setattr(sys, name, proxy)

    def _unwrap(self) -> None:
        for name, proxy in self.proxies.items():
            if getattr(sys, name) is proxy:
                setattr(sys, name, proxy._stream)


class _ClearingStream:
    """``sys.stderr`` (and a terminal's ``sys.stdout``) while the status line is drawn: a write clears the line
    first (the next tick redraws it), then goes through unchanged; the rest is the stream's. (No ``==`` to
    the stream: click keys its stream cache on it, and would write past the wrapper.)"""

    def __init__(self, stream, display: CompileDisplay):
        self._stream = stream
        self._display = display

    def write(self, text):
        with self._display.lock:
            self._display._erase()
            return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def show_compiling(stream=None) -> CompileDisplay:
    """Show kalmix's kernel compiles on stderr (:class:`CompileDisplay`); the display."""
    from ..core.compiled import _notice

    display = CompileDisplay(stream)
    _notice.add_display(display)
    return display
