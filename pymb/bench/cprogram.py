"""The software floor: a plain C program on libmodbus doing the same sweep.

Six ``modbus_read_registers`` calls of at most 125 registers, a trivial C
decode loop, and the CoolPro telemetry read, timed inside the program with
``clock_gettime(CLOCK_MONOTONIC)`` (wall, per sweep) and
``getrusage(RUSAGE_SELF)`` (its own CPU, per batch). It speaks the bench
workers' line protocol (see :mod:`pymb.bench.worker`) on stdin/stdout.

No pymb code is linked in: this is what a C programmer writes against the
system's libmodbus. The layout (first register, count, channels, block
kinds) comes from the hub's map on the command line.
"""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess

__all__ = ["CBuildError", "build", "compiler_version", "source_path"]

CFLAGS = ("-O2", "-std=c99", "-Wall", "-Wextra")


def source_path() -> str:
    """The program's C source: ``csrc/examples/bench_sweep.c``, which ``make -C
    csrc`` also builds with -Werror (and the sanitizers). The package carries it
    as ``pymb/bench/bench_sweep.c`` (a link to it in the source tree)."""
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "bench_sweep.c")


class CBuildError(Exception):
    """The C contender cannot be built here (the message says why)."""


def compiler_version(cc: str = "cc") -> str:
    """The compiler's first ``--version`` line, or ``""``."""
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return out.stdout.splitlines()[0].strip() if out.stdout else ""


def build(directory: str, cc: str | None = None) -> tuple[str, str]:
    """Compile :func:`source_path` into ``directory`` with the system compiler
    and ``pkg-config --cflags --libs libmodbus``; returns the program's path
    and the compiler's warnings (``""`` when clean, as it is with gcc 12).

    Raises :class:`CBuildError` with the reason when there is no compiler, no
    pkg-config, no libmodbus development files, or the build fails.
    """
    cc = cc or os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise CBuildError(f"no C compiler ({cc!r} not found; install gcc)")
    if shutil.which("pkg-config") is None:
        raise CBuildError("pkg-config not found (apt install pkg-config libmodbus-dev)")
    pc = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"],
                        capture_output=True, text=True, timeout=30)
    if pc.returncode != 0:
        raise CBuildError("libmodbus development files not found by pkg-config "
                          "(apt install libmodbus-dev)")
    src = source_path()
    if not os.path.exists(src):
        raise CBuildError(f"the C program's source is missing ({src})")
    exe = os.path.join(directory, "sweep")
    # PYMB_BENCH_CFLAGS: more flags (the tests build it under the sanitizers).
    extra = shlex.split(os.environ.get("PYMB_BENCH_CFLAGS", ""))
    cmd = [*shlex.split(cc), *CFLAGS, *extra, "-o", exe, src, *shlex.split(pc.stdout), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if done.returncode != 0:
        raise CBuildError(f"{' '.join(cmd)} failed:\n{done.stderr.strip()}")
    return exe, done.stderr.strip()
