"""The contenders: who races, how to find them, how to start them."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import sys
from dataclasses import dataclass

from pymb.extras import install_hint

__all__ = ["CONTENDERS", "NAMES", "Contender", "probe"]

_EXTRA = install_hint("bench")


@dataclass(frozen=True)
class Contender:
    """One stack in the race."""

    name: str  #: what ``--only`` takes
    label: str  #: what the table shows
    modules: tuple[str, ...]  #: Python modules it needs (none for the C program)
    dist: str | None  #: distribution whose version the header shows
    how: str  #: one line: what it does and how it was set up


CONTENDERS: tuple[Contender, ...] = (
    Contender("c", "C (libmodbus)", (), None,
              "plain C: 6 x modbus_read_registers + a C decode loop, built now with cc -O2"),
    Contender("pymb", "pymb", (), "pymb",
              "SensorHub.read_all(into=r) / CoolPro.read_telemetry(): one C call per sweep, "
              "decoded in C"),
    Contender("pylibmodbus", "pylibmodbus", ("pylibmodbus",), "pylibmodbus",
              "ModbusRtu.read_registers x6 (libmodbus via ABI-mode cffi) + Python decode"),
    Contender("pyserial", "pyserial (hand-written)", ("serial",), "pyserial",
              "pyserial, frames and table CRC in pure Python, exact-length reads + Python "
              "decode"),
    Contender("pymodbus", "pymodbus", ("pymodbus", "serial"), "pymodbus",
              "sync ModbusSerialClient (RTU) read_holding_registers x6 + Python decode; "
              "polls in >= 1 ms sleeps"),
    Contender("minimalmodbus", "minimalmodbus", ("minimalmodbus", "serial"), "minimalmodbus",
              "Instrument.read_registers x6 + Python decode; >= 1.75 ms silent period "
              "before each request"),
)

NAMES = tuple(c.name for c in CONTENDERS)


def _version(dist: str) -> str:
    if dist == "pymb":
        from pymb import __version__
        return __version__
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "?"


def probe(c: Contender) -> tuple[str | None, str]:
    """(reason it cannot run or None, version) for a Python contender; the
    C program's availability is known only once it is built."""
    for module in c.modules:
        if importlib.util.find_spec(module) is None:
            return f"not installed ({module!r} not importable by {sys.executable}; {_EXTRA})", ""
    return None, _version(c.dist) if c.dist else ""
