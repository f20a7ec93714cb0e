"""Children forked from the bench's own process, for ``--quick``.

A ``python -m pymb...`` child (a simulator, a contender's worker) spends
most of its start importing what the bench has imported already: Python
and pymb's modules, about 0.4 s of CPU each, several seconds of wall time
on a loaded machine, and a quick run starts dozens. A forked child starts
with them loaded: it runs the module as ``python -m`` would
(afresh, as ``__main__``), in its own session, with
``PR_SET_PDEATHSIG``, its own stdin, stdout and stderr, the environment
and folder asked for and nothing else of the bench's open files.

Only ``--quick`` forks (its figures are indicative): a full run's workers
are fresh interpreters, as a user's program would be.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import importlib.util
import os
import re
import signal
import stat
import subprocess
import sys
import threading
import time
import traceback
import types
from collections.abc import Sequence
from typing import IO, NoReturn

from pymb.child import Process, _die_with_parent

__all__ = ["FORKABLE", "PRELOAD", "Forked", "can_fork", "fork_module", "fork_safe",
           "holds_no_file", "preload"]

#: what the forked children import (the simulator, pymb log, the workers and
#: the contenders' libraries): imported once, before the first fork
PRELOAD = ("pymb.cli", "pymb.commands.simulate", "pymb.commands.log", "pymb.aio",
           "pymb.logger", "pymb.store", "pymb.bench.worker", "pymb.bench.aioworker",
           "pymb.bench.scale", "pymb.bench.logbench", "pymb.bench.gateworker",
           "pymodbus.client", "pymodbus.framer", "serial", "minimalmodbus")

#: a parent's stdio objects a child replaced: kept alive (never flushed
#: into the child's pipes by their finaliser)
_OLD_STDIO: list[object] = []
_FORK_LOCK = threading.Lock()


def preload() -> None:
    """Import :data:`PRELOAD` (what is not installed is left to the child)."""
    for name in PRELOAD:
        with contextlib.suppress(Exception):  # a broken install is the child's to report
            importlib.import_module(name)


#: what is forked at any time: the simulator and the workers that open no
#: database. SQLite's own state (its table of open files and their locks, per
#: process) goes with a fork: a child that opens a database while the bench
#: has one open can meet the bench's locks as its own (SQLITE_PROTOCOL, when
#: the new file has the inode number of one the bench holds). The others
#: (pymb log, the logger, SD wear and gateway workers) are forked only while
#: the bench holds no file open (:func:`holds_no_file`), else started anew.
FORKABLE = ("pymb.bench.worker", "pymb.bench.aioworker", "pymb.bench.scale")
#: the files the bench holds that are not SQLite's: its children's stderr
#: (temporary files: named pymb-child-..., or unnamed where O_TMPFILE made them,
#: which SQLite never does)
_OWN_FILES = "pymb-child-"
_UNNAMED = re.compile(r"#\d+ \(deleted\)")


def holds_no_file() -> bool:
    """True if this process has no regular file open but its children's
    stderr files (after a garbage collection: a connection left to it is
    closed), hence no SQLite state a fork would hand down."""
    gc.collect()
    try:
        names = os.listdir("/proc/self/fd")
    except OSError:
        return False
    for name in names:
        where = f"/proc/self/fd/{name}"
        try:
            if not stat.S_ISREG(os.stat(where).st_mode):
                continue
            target = os.readlink(where)
        except OSError:
            continue  # closed meanwhile (the listing's own descriptor)
        base = os.path.basename(target)
        if not (base.startswith(_OWN_FILES) or _UNNAMED.fullmatch(base)):
            return False
    return True


def can_fork(argv: Sequence[str]) -> bool:
    """True for ``[this python, -m, pymb...]`` whose module has its source
    here: a module this process can run (anything else is started anew)."""
    if not (len(argv) >= 3 and argv[0] == sys.executable and argv[1] == "-m"
            and (argv[2] == "pymb" or argv[2].startswith("pymb."))):
        return False
    try:
        return _source(argv[2]) is not None
    except (ImportError, ValueError):
        return False


def fork_safe(argv: Sequence[str]) -> bool:
    """True if ``argv`` (see :func:`can_fork`) may be forked now: the
    simulator and :data:`FORKABLE` always, the rest while
    :func:`holds_no_file`."""
    if not can_fork(argv):
        return False
    if (argv[2] == "pymb" and argv[3:4] == ["simulate"]) or argv[2] in FORKABLE:
        return True
    return holds_no_file()


def _source(module: str) -> tuple[str, str] | None:
    """(the module ``python -m`` runs, its source file), None if not a .py file."""
    spec = importlib.util.find_spec(module)
    if spec is not None and spec.submodule_search_locations is not None:
        module = f"{module}.__main__"
        spec = importlib.util.find_spec(module)
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    return module, spec.origin


class Forked:
    """The :class:`subprocess.Popen` face of a forked child."""

    def __init__(self, pid: int, argv: Sequence[str], stdin: IO[bytes] | None,
                 stdout: IO[bytes] | None) -> None:
        self.pid = pid
        self.args = list(argv)
        self.stdin = stdin
        self.stdout = stdout
        self.returncode: int | None = None

    def poll(self) -> int | None:
        """The exit code, or None while it runs."""
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                self.returncode = -1  # reaped elsewhere: gone, its code unknown
                return self.returncode
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the exit (:class:`subprocess.TimeoutExpired` after ``timeout``)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            time.sleep(0.005)
        return code

    def send_signal(self, sig: int) -> None:
        """Signal it, if it still runs."""
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        """SIGTERM."""
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        """SIGKILL."""
        self.send_signal(signal.SIGKILL)


def _run_as_main(module: str, args: Sequence[str]) -> None:
    """Run ``module`` (a package: its ``__main__``) afresh as ``__main__``,
    as ``python -m`` does, from its source (whatever import hooks the
    parent has, a test runner's included)."""
    found = _source(module)
    if found is None:
        raise ImportError(f"{module!r} has no source to run")
    module, path = found
    main = types.ModuleType("__main__")
    main.__file__ = path
    main.__package__ = module.rpartition(".")[0]
    sys.modules["__main__"] = main
    sys.argv = [path, *args]
    with open(path, "rb") as f:
        code = compile(f.read(), path, "exec")
    exec(code, main.__dict__)


def _child(module: str, args: Sequence[str], fds: tuple[int, int, int], env: dict[str, str],
           cwd: str | None) -> NoReturn:
    """In the forked child: become ``python -m module args`` and exit with its code."""
    code = 1
    try:
        os.setsid()
        _die_with_parent()
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
        for name in os.listdir("/proc/self/fd"):
            fd = int(name)
            if fd > 2:
                with contextlib.suppress(OSError):
                    os.close(fd)
        if cwd is not None:
            os.chdir(cwd)
        os.environ.clear()
        os.environ.update(env)
        # a fresh interpreter's signal handling (the bench's own is not the child's)
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1,
                    signal.SIGUSR2, signal.SIGALRM, signal.SIGCHLD):
            signal.signal(sig, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)
        _OLD_STDIO.extend((sys.stdin, sys.stdout, sys.stderr))
        sys.stdin = open(0, closefd=False)  # noqa: SIM115
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
        sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
        _run_as_main(module, args)
        code = 0
    except SystemExit as e:
        if e.code is None or isinstance(e.code, int):
            code = e.code or 0
        else:
            print(e.code, file=sys.stderr)
    except BaseException:
        with contextlib.suppress(BaseException):
            traceback.print_exc()
    finally:
        for f in (sys.stdout, sys.stderr):
            with contextlib.suppress(BaseException):
                f.flush()
        os._exit(code)


def fork_module(argv: Sequence[str], *, stdin: bool, err: IO[bytes] | int | None,
                env: dict[str, str], cwd: str | None) -> Process:
    """Fork a child running ``argv`` (``[python, -m, module, args...]``, see
    :func:`can_fork`) as :class:`Child` would start it; ``err`` is its
    stderr: a file, :data:`subprocess.DEVNULL` or None (this process's)."""
    module, args = argv[2], list(argv[3:])
    in_r, in_w = os.pipe() if stdin else (os.open(os.devnull, os.O_RDONLY), -1)
    out_r, out_w = os.pipe()
    if err is None:
        err_fd, close_err = 2, False
    elif isinstance(err, int):
        err_fd, close_err = os.open(os.devnull, os.O_WRONLY), True
    else:
        err_fd, close_err = err.fileno(), False
    with _FORK_LOCK:
        for f in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                f.flush()
        pid = os.fork()
        if pid == 0:
            _child(module, args, (in_r, out_w, err_fd), env, cwd)
    os.close(in_r)
    os.close(out_w)
    if close_err:
        os.close(err_fd)
    return Forked(pid, argv, os.fdopen(in_w, "wb") if stdin else None, os.fdopen(out_r, "rb"))
