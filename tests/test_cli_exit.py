"""The ``kalmix`` program's exit (:func:`kalmix.cli.script`): after a command that succeeded, no interpreter
teardown, but threads joined, atexit handlers run and output flushed; the usual exit otherwise."""

import os
import subprocess
import sys

import pytest

PROGRAM = """
import atexit, sys
class Teardown:
    def __del__(self):
        sys.stdout.write("torn down\\n")
keep = Teardown()   # a global: destroyed only by the interpreter's teardown
atexit.register(lambda: sys.stdout.write("atexit ran\\n"))
sys.argv = ["kalmix", *sys.argv[1:]]
from kalmix.cli import script
script()
"""


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", PROGRAM, *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd)


def test_success_skips_the_teardown_but_runs_atexit_and_flushes():
    done = _run("--version")
    assert done.returncode == 0, done.stderr
    assert "version" in done.stdout and "atexit ran" in done.stdout
    assert "torn down" not in done.stdout


def test_large_output_to_a_pipe_arrives_whole(tmp_path):
    """A quick exit must not lose what is still in stdout's buffer (``-o -`` is stdout, not a file named '-')."""
    rows = ["time,x"] + [f"{i},{0.01 * i * i}" for i in range(3000)]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    done = _run("predict", "t.csv", "-o", "-", "--length-unit", "1", "--no-progress", "--bank", "kinematic",
                cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("time,segment,pred_x") and len(lines) == 1 + 3000 + 1   # header, rows, atexit's
    assert lines[-2].startswith("2999,") and lines[-1] == "atexit ran"   # the time as given
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize("args", [("predict", "no-such-file.csv"), ("no-such-command",)])
def test_failure_exits_the_usual_way(args):
    done = _run(*args)
    assert done.returncode != 0
    assert "torn down" in done.stdout and "atexit ran" in done.stdout


def test_a_profiler_gets_its_results(tmp_path):
    """Under cProfile (or coverage, a debugger) the process exits the usual way, so they write theirs."""
    out = tmp_path / "profile.out"
    done = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(out), "-m", "kalmix.cli", "--version"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert out.stat().st_size > 0


def test_predict_from_a_closed_stdin_is_one_line():
    """``kalmix predict - <&-``: one line naming the problem, not a traceback."""
    done = subprocess.run([sys.executable, "-m", "kalmix.cli", "predict", "-"], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=300, preexec_fn=lambda: os.close(0))
    assert done.returncode == 1
    assert "stdin: closed" in done.stderr and "Traceback" not in done.stderr


def test_a_stop_before_any_row_says_no_state_was_saved(tmp_path):
    """Stopped before the first row, with --state: the message says no state file was written (it used to say
    'state saved to ...'), and none was."""
    import signal

    state = tmp_path / "s.npz"
    process = subprocess.Popen([sys.executable, "-m", "kalmix.cli", "predict", "-", "--state", str(state)],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    process.stdin.write("id,time,x,y\n")
    process.stdin.flush()
    # the header is read: the run is waiting for rows (on a cold cache a compile notice may come first)
    assert any("length unit" in process.stderr.readline() for _ in range(5))
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130
    assert f"no state saved to {state}" in err and not state.exists()
