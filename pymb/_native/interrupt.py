"""What stops a line's wait: Python's signal handlers (Ctrl-C) in a wait
in the main thread, and :meth:`LineStop.stop` from any thread (a
close() while a request waits). Both reach C through one interrupt hook,
``pymbi_stop_hook`` (pymb_line_set_interrupt), which C calls when poll() is
interrupted by a signal and at least every PYMB_INTERRUPT_SLICE_US (50 ms)
of waiting: it reads the line's stop flag, then, in the main thread only
(whichever thread opened the line), calls :func:`pymb_py_interrupted`.
"""

from __future__ import annotations

import sys
import threading
from typing import Any

from pymb._pymb_cffi import ffi, lib

__all__ = ["LineStop", "in_line_wait", "take_interrupt"]

_stop_hook = ffi.addressof(lib, "pymbi_stop_hook")

# -- signals -------------------------------------------------------------------
# Running pymb_py_interrupted lets the interpreter run the pending signal
# handlers (it does so on entering a function); a handler that raises
# (SIGINT's KeyboardInterrupt) lands in _interrupt_raised, which keeps the
# exception and tells C to stop. A handler that returns normally changes
# nothing: the wait goes on.

_pending = threading.local()


def _interrupt_raised(exc_type: Any, exc: BaseException | None, tb: Any) -> int:
    _pending.exc = exc if exc is not None else exc_type()
    return 1


@ffi.def_extern(onerror=_interrupt_raised)  # type: ignore[untyped-decorator]
def pymb_py_interrupted(arg: Any) -> int:
    return 0


_HOOK_CODE = pymb_py_interrupted.__code__


def in_line_wait() -> bool:
    """Whether this thread is inside a line's wait: a signal handler run
    from the hook, while C waits on the line (which must not be freed
    under it)."""
    frame = sys._getframe(1)  # noqa: SLF001 - the one way to see the stack
    while frame is not None:
        if frame.f_code is _HOOK_CODE:
            return True
        frame = frame.f_back  # type: ignore[assignment]
    return False


def take_interrupt() -> BaseException | None:
    """The exception a signal handler raised in this thread's wait, once."""
    exc: BaseException | None = getattr(_pending, "exc", None)
    _pending.exc = None
    return exc


class LineStop:
    """One Link's stop flag and hook argument (a ``pymbi_stop``), memory of
    the Link's own: setting it is safe while another thread uses or frees
    the line."""

    __slots__ = ("c",)

    def __init__(self) -> None:
        self.c = ffi.new("pymbi_stop *")

    def arm(self, line: Any) -> None:
        """Give a line just opened the hook, the flag down. Python runs
        signal handlers in the main thread only: a wait in another thread
        would call in for nothing, and a daemon thread's call could meet the
        interpreter's shutdown, so there the hook reads the flag alone, in C
        (whichever thread opened the line)."""
        self.c.stop = 0
        self.c.then = lib.pymb_py_interrupted
        self.c.main_thread = threading.main_thread().ident or 0
        lib.pymb_line_set_interrupt(line, _stop_hook, self.c)

    def stop(self) -> None:
        """From any thread: the line's wait ends within 50 ms with EINTR,
        and so does every wait until :meth:`arm` again."""
        self.c.stop = 1

    @property
    def stopped(self) -> bool:
        """Whether :meth:`stop` was called since the line was armed."""
        return bool(self.c.stop)
