"""The notice while kalmix's kernels compile (:mod:`kalmix.core.compiled._notice`, the command line's
:class:`kalmix.commands._common.CompileDisplay`): said on a cold cache, silent on a warm one, never on stdout."""

import io
import logging
import os
import subprocess
import sys

import pytest

from kalmix.commands._common import CompileDisplay
from kalmix.core.compiled import _notice

numba = pytest.importorskip("numba")


@pytest.fixture
def notice():
    """The notice with no episode yet in this process (the next start is a first one), no display."""
    _notice._reset()
    displays = list(_notice._displays)
    _notice._displays.clear()
    yield _notice
    _notice._reset()
    _notice._displays[:] = displays


class Recorder:
    def __init__(self):
        self.calls = []

    def start(self, first):
        self.calls.append(("start", first))

    def tick(self, elapsed):
        pass   # from the notice's thread, as time passes: not recorded (no wall-clock in these tests)

    def done(self, elapsed, finished):
        self.calls.append(("done", finished))


def _kalmix_function(module="kalmix._notice_test"):
    """A new numba function that numba takes for one of kalmix's (its module), compiled at its first call."""
    function = lambda x: x + 1   # noqa: E731 - a fresh function object: compiled anew, not found in memory
    function.__module__ = module
    return numba.njit(function)


def test_the_api_logs_a_compile_once_at_warning_then_its_time(notice, caplog):
    """Python shows WARNING and above with no logging set up: the first compile of a process is a WARNING
    (one line), its end INFO; a second call, compiled already, says nothing."""
    caplog.set_level(logging.INFO, logger="kalmix")
    notice.watch()
    function = _kalmix_function()
    assert function(1) == 2
    notice.settle()
    records = [(r.name, r.levelno, r.getMessage()) for r in caplog.records if r.name == "kalmix"]
    assert records[0] == ("kalmix", logging.WARNING, notice.START)
    assert records[1][1] == logging.INFO and records[1][2].startswith("compiled kalmix's kernels in ")
    assert len(records) == 2
    caplog.clear()
    assert function(2) == 3   # compiled: no numba compile event
    notice.settle()
    assert [r for r in caplog.records if r.name == "kalmix"] == []
    # a later episode of the same process: INFO only
    _kalmix_function()(1)
    notice.settle()
    assert [(r.levelno, r.getMessage()) for r in caplog.records][0] == (logging.INFO, notice.START_MORE)


def test_other_numba_code_is_not_kalmix_s(notice, caplog):
    caplog.set_level(logging.INFO, logger="kalmix")
    notice.watch()
    _kalmix_function(module="someone_else")(1)
    notice.settle()
    assert [r for r in caplog.records if r.name == "kalmix"] == []


def test_displays_hear_of_episodes_and_of_a_stopped_compile(notice, caplog):
    """A display is told start / done; while one shows it, the logger's start is INFO (not said twice); a
    compile stopped by Ctrl-C ends as not finished."""
    caplog.set_level(logging.INFO, logger="kalmix")
    recorder = Recorder()
    notice.add_display(recorder)
    with notice.compiling():
        with notice.compiling():   # nested: one episode
            pass
    notice.settle()
    with pytest.raises(KeyboardInterrupt):
        with notice.compiling():
            raise KeyboardInterrupt
    notice.settle()
    assert recorder.calls == [("start", True), ("done", True), ("start", False), ("done", False)]
    assert [r.levelno for r in caplog.records] == [logging.INFO] * 4
    assert "stopped" in caplog.records[-1].getMessage()


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_display_off_a_terminal_is_a_start_and_an_end_line():
    stream = io.StringIO()
    display = CompileDisplay(stream)
    display.start(True)
    display.tick(3.0)
    display.done(41.6, True)
    assert stream.getvalue().splitlines() == [
        "kalmix: " + _notice.START, "kalmix: compiled kalmix's kernels in 42 s (cached: later runs start at once)"]


def test_display_on_a_terminal_counts_and_clears_its_line_for_other_writers(monkeypatch):
    import click

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(sys, "stdout", io.StringIO())   # not a terminal: left alone
    click.echo("kalmix: length unit 1", err=True)   # (click keeps the stream it found: the display's wrapper differs)
    display = CompileDisplay()
    display.start(True)
    assert terminal.getvalue().endswith(
        "\n\rkalmix: compiling kalmix's kernels for this machine, once per setting ... 0 s")
    display.tick(2.4)
    assert terminal.getvalue().endswith("once per setting ... 2 s")
    width = display.drawn
    click.echo("kalmix: warning: something", err=True)   # a warning while the line is drawn: the line goes first
    assert terminal.getvalue().endswith("... 2 s\r" + " " * width + "\rkalmix: warning: something\n")
    display.tick(3.0)
    assert terminal.getvalue().endswith("\rkalmix: warning: something\n\r" + display._status_text(3.0))
    display.done(3.2, True)
    assert sys.stderr is terminal
    end = "\rkalmix: compiled kalmix's kernels in 3.2 s (cached: later runs start at once)\n"
    assert terminal.getvalue().endswith(end)
    display.tick(4.0)   # a tick that comes after the end (the notice's thread): draws nothing
    assert terminal.getvalue().endswith(end) and sys.stderr is terminal
    assert sys.stdout.getvalue() == ""


def test_display_under_a_progress_bar_writes_above_it(monkeypatch):
    """With a tqdm bar up (predict's rows), the lines go above the bar and the bar is redrawn each tick (its
    elapsed time counts); no status line of its own is drawn over the bar."""
    tqdm = pytest.importorskip("tqdm").tqdm
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    display = CompileDisplay()
    with tqdm(total=10, desc="rows bar", file=terminal, mininterval=0) as bar:
        display.start(True)
        drawn = terminal.getvalue().count("rows bar")
        display.tick(5.0)
        assert terminal.getvalue().count("rows bar") > drawn   # redrawn
        display.done(5.0, True)
        bar.update(10)
    screen = terminal.getvalue()
    assert "kalmix: " + _notice.START + "\n" in screen and "kalmix: compiled kalmix's kernels in 5.0 s" in screen
    assert "once per setting ... " not in screen and sys.stderr is terminal
    with tqdm(total=10, file=io.StringIO()) as elsewhere:   # a bar on another stream is not this display's
        assert elsewhere in tqdm._instances and display._bars() == []


def test_the_program_says_so_on_a_cold_cache_only(tmp_path):
    """``kalmix predict`` with an empty cache (the smallest bank: a few kernels) says so on stderr, stdout is
    the CSV alone; the same run again, the cache now warm, says nothing of it, and writes the same CSV."""
    rows = ["track_id,time,x,y"] + [f"{k},{t},{0.1 * t * t + k},{t - k}" for k in (1, 2) for t in range(50)]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    env = dict(os.environ, KALMIX_CACHE_DIR=str(tmp_path / "cache"))

    def run():
        return subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "t.csv", "--bank", "kinematic",
                               "--length-unit", "1"], capture_output=True, text=True, timeout=600, cwd=tmp_path,
                              env=env, stdin=subprocess.DEVNULL)

    cold = run()
    assert cold.returncode == 0, cold.stderr
    lines = cold.stderr.splitlines()
    start = lines.index("kalmix: " + _notice.START)
    assert lines[start + 1].startswith("kalmix: compiled kalmix's kernels in ")
    assert cold.stdout.startswith("track_id,time,segment,pred_x") and "kalmix" not in cold.stdout
    warm = run()
    assert warm.returncode == 0, warm.stderr
    assert "compil" not in warm.stderr and warm.stdout == cold.stdout
