"""Stop signals that work during a numba compile.

A Python signal handler runs in the main thread between two bytecodes, wherever they are. During a
numba compile that is often code that LLVM calls back from C (llvmlite's object cache), or a
finaliser freeing LLVM objects: an exception raised there is printed ("Exception ignored in ...")
and dropped: a Ctrl-C during a fresh install's first compile would let ``kalmix predict`` run its
chunk to the end, and leave ``kalmix demo`` without numba's compiled object (a long traceback
instead of "Aborted!"). Handlers that ask :func:`swallowing` do not raise in such a frame; they send the
signal again a moment later (:func:`send_again_later`), to a frame that can stop.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

__all__ = ["REDELIVER_SECONDS", "swallowing", "send_again_later", "install_keyboard_interrupt"]

#: Wait before a stop signal that arrived where it could not be raised is sent again.
REDELIVER_SECONDS = 0.05


def swallowing(frame) -> bool:
    """True when ``frame`` may run where Python prints an exception and ignores it: a finaliser (``__del__``,
    a weakref callback) or llvmlite's code, which LLVM calls back from C during a numba compile."""
    while frame is not None:
        code = frame.f_code
        if (code.co_name == "__del__" or os.path.basename(code.co_filename) == "weakref.py"
                or f"{os.sep}llvmlite{os.sep}" in code.co_filename):
            return True
        frame = frame.f_back
    return False


def send_again_later(signum: int, still) -> None:
    """Send ``signum`` to this process in :data:`REDELIVER_SECONDS`, if ``still()`` is then true."""
    def again():
        if still():
            with contextlib.suppress(OSError):
                os.kill(os.getpid(), signum)

    timer = threading.Timer(REDELIVER_SECONDS, again)
    timer.daemon = True
    timer.start()


def _keyboard_interrupt(signum, frame):
    if swallowing(frame):
        send_again_later(signum, lambda: signal.getsignal(signal.SIGINT) is _keyboard_interrupt)
        return
    raise KeyboardInterrupt


def install_keyboard_interrupt() -> None:
    """Ctrl-C raises ``KeyboardInterrupt`` as usual, but never where it would be dropped (see the module).
    Only from the main thread, and only over Python's own handler."""
    if threading.current_thread() is threading.main_thread() and \
            signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _keyboard_interrupt)
