"""The ``kalmix`` command line: a thin layer over experiments and predictors.

Each sub-command lives in :mod:`kalmix.commands` (one module each) and is registered
here; the heavy imports happen inside the commands, so ``kalmix --help`` is fast.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    # name: (module, attribute)
    "demo": ("kalmix.commands.demo", "demo"),
    "reproduce": ("kalmix.commands.reproduce", "reproduce"),
    "servo": ("kalmix.commands.servo", "servo"),
    "predict": ("kalmix.commands.predict", "predict"),
    "evaluate": ("kalmix.commands.evaluate", "evaluate"),
    "bench": ("kalmix.commands.bench", "bench"),
}


def _missing_cli_extra(error: ImportError) -> None:
    sys.stderr.write(f"kalmix: the command line needs the 'cli' extra ({error.name} is missing): "
                     "pip install 'kalmix[cli]'\n")
    raise SystemExit(2)


def build():
    """The click group with every sub-command whose module is present."""
    try:
        import click
    except ImportError as error:  # pragma: no cover - depends on the environment
        _missing_cli_extra(error)

    @click.group(context_settings={"help_option_names": ["-h", "--help"]})
    @click.version_option(package_name="kalmix")
    def group():
        """kalmix: model-free online motion prediction with a mixture of adaptive Kalman filters."""

    for name, (module_name, attribute) in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as error:
            if error.name == module_name:
                continue  # command not shipped in this build
            raise
        group.add_command(getattr(module, attribute), name)
    return group


def main(argv=None):
    """Entry point of the ``kalmix`` script."""
    try:
        return build()(args=argv, prog_name="kalmix")
    except ImportError as error:
        _missing_cli_extra(error)


def script() -> None:
    """The ``kalmix`` program (the console script, and ``python -m kalmix.cli``): :func:`main`, in a process
    tuned for one run.

    - The cyclic garbage collector runs every 10,000 net container allocations instead of 700:
      loading numba's kernels allocates hundreds of thousands of objects, which would run it hundreds
      of times. Memory is freed as usual; cycles a little later.
    - Ctrl-C stops a numba compile too (:mod:`kalmix.commands._interrupt`).
    - While kalmix's kernels compile (a fresh install's first run), stderr says so, with the elapsed
      seconds (:class:`kalmix.commands._common.CompileDisplay`).
    - After a command that succeeded, the process ends without the interpreter's teardown, which
      frees numba's, pandas' and the data's objects one by one:
      threads are joined, atexit handlers run and stdout/stderr are flushed first, as at a normal
      exit. A command that fails, a flush that fails, or a process under a profiler or tracer
      (cProfile, coverage, a debugger: they write their results after the program) exits the
      usual way.
    """
    import gc

    from .commands._interrupt import install_keyboard_interrupt

    gc.set_threshold(10_000, 10, 10)
    install_keyboard_interrupt()
    try:
        from .commands._common import show_compiling
    except ImportError:   # the cli extra is missing: main() says so
        pass
    else:
        show_compiling()
    try:
        main()
    except SystemExit as stop:
        if stop.code not in (None, 0):
            raise
    _exit_now()


def _exit_now() -> None:
    """A normal exit's work that matters (threads, atexit handlers, flushed stdio), then ``os._exit(0)``."""
    if sys.getprofile() is not None or sys.gettrace() is not None:
        return
    import atexit
    import os
    import threading

    shutdown = getattr(threading, "_shutdown", None)   # what the interpreter calls first at exit: joins threads
    if shutdown is not None:
        shutdown()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:   # noqa: BLE001 - a broken pipe and the like: let the interpreter report it as usual
            return
    os._exit(0)


if __name__ == "__main__":  # pragma: no cover
    script()
