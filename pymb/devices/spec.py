"""The one device syntax every command takes, ``TYPE[:ADDRESS][,key=value...]``
(``coolpro``, ``coolpro:41``, ``hub:250,channels=50,humidity_unit=1``), the
device types it knows, and the "did you mean" of an unknown key."""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pymb.devices.maps import COOLPRO, HUB
from pymb.errors import InvalidArgument

__all__ = [
    "DEVICE_KEYS",
    "DEVICE_SYNTAX",
    "DEVICE_TYPES",
    "DeviceConfig",
    "closest",
    "default_address",
    "device_parts",
    "parse_address",
    "parse_device",
    "split_spec",
]

DEVICE_TYPES = ("coolpro", "hub")

#: keys a device takes after its ``TYPE[:ADDRESS]`` (command line) or in TOML
DEVICE_KEYS: dict[str, tuple[str, ...]] = {
    "coolpro": ("name",),
    "hub": ("channels", "humidity_unit", "name"),
}
DEVICE_SYNTAX = "TYPE[:ADDRESS][,key=value...] (TYPE coolpro or hub)"


def _map(kind: str) -> Any:
    return COOLPRO if kind == "coolpro" else HUB


def default_address(kind: str) -> int:
    """The address a device of this type has out of the box."""
    return int(_map(kind).default_address)


@dataclass
class DeviceConfig:
    """One device on a bus. ``address`` None: the type's default address."""

    type: str
    address: int | None = None
    name: str = ""
    channels: int = HUB.channels
    humidity_unit: float | list[float] = 0.1

    def __post_init__(self) -> None:
        if self.type not in DEVICE_TYPES:
            raise InvalidArgument(f"unknown device type {self.type!r}; use coolpro or hub")
        if self.address is None:
            self.address = default_address(self.type)
        low, high = _map(self.type).addresses
        if isinstance(self.address, bool) or not isinstance(self.address, int) or not (
            low <= self.address <= high
        ):
            raise InvalidArgument(
                f"{self.type} address must be {low}..{high}, got {self.address!r}")
        if self.type == "hub":
            if isinstance(self.channels, bool) or not isinstance(self.channels, int) or not (
                    1 <= self.channels <= HUB.channels):
                raise InvalidArgument(f"hub channels must be 1..{HUB.channels}, "
                                      f"got {self.channels!r}")
            units = (self.humidity_unit if isinstance(self.humidity_unit, list)
                     else [self.humidity_unit])
            if isinstance(self.humidity_unit, list) and len(units) != self.channels:
                raise InvalidArgument(f"{len(units)} humidity units given for "
                                      f"{self.channels} channels")
            for u in units:
                if isinstance(u, bool) or not isinstance(u, (int, float)) or u not in (1, 0.1):
                    raise InvalidArgument(f"hub humidity_unit must be 1 or 0.1 (%), got {u!r}")
        if not self.name:
            self.name = f"{self.type}-{self.address}"

    @property
    def spec(self) -> str:
        """The device in the one command-line syntax, e.g. ``hub:250,channels=50``."""
        out = f"{self.type}:{self.address}"
        if self.type == "hub" and self.channels != HUB.channels:
            out += f",channels={self.channels}"
        if self.type == "hub" and not isinstance(self.humidity_unit, list) and \
                self.humidity_unit != 0.1:
            out += f",humidity_unit={self.humidity_unit:g}"
        return out


def _number(text: str, what: str, spec: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InvalidArgument(f"{spec!r}: {what} must be a number, got {text!r}") from None


def _integer(text: str, what: str, spec: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise InvalidArgument(f"{spec!r}: {what} must be a whole number, got {text!r}") from None


#: words users write for a known key
_SYNONYMS = {"file": "path", "filename": "path", "out": "path", "output": "path",
             "addr": "address", "slave": "address", "unit": "address", "id": "address",
             "kind": "type", "speed": "baud", "baudrate": "baud", "baud_rate": "baud",
             "serial": "port", "device": "port", "host": "tcp", "devices": "device",
             "buses": "bus", "interval_s": "interval", "timeout_s": "timeout",
             "humidity": "humidity_unit", "channel": "channels"}


def closest(key: str, known: Sequence[str]) -> str:
    """``; did you mean 'x'?`` (or the list of known keys) for an unknown ``key``."""
    if _SYNONYMS.get(key.lower()) in known:
        return f"; did you mean {_SYNONYMS[key.lower()]!r}?"
    near = difflib.get_close_matches(key, list(known), n=1, cutoff=0.5)
    if near:
        return f"; did you mean {near[0]!r}?"
    return f"; known: {', '.join(known)}"


def split_spec(spec: str) -> tuple[str, str | None, list[tuple[str, bool, str]]]:
    """The one grammar of a device, ``TYPE[:ADDRESS][,key=value...]``, split:
    (TYPE in lower case, the ADDRESS text or None, and each option as
    (key with ``-`` read as ``_``, whether it had ``=``, value)), all stripped.
    What the keys and values mean is the caller's (a device to read, to
    simulate, a map's device)."""
    head, *opts = spec.strip().split(",")
    kind, colon, addr = head.partition(":")
    options = []
    for opt in opts:
        key, eq, value = opt.partition("=")
        options.append((key.strip().replace("-", "_"), bool(eq), value.strip()))
    return kind.strip().lower(), addr.strip() if colon else None, options


def parse_address(text: str, spec: str) -> int:
    """A device's address as written after ``TYPE:``: decimal (``40``, ``040``)
    or with a base prefix (``0x28``, ``0o50``, ``0b101000``)."""
    try:
        return int(text, 10)
    except ValueError:
        pass
    try:
        return int(text, 0)
    except ValueError:
        raise InvalidArgument(
            f"{spec!r}: the address must be a whole number, got {text!r}") from None


def parse_device(spec: str) -> DeviceConfig:
    """``TYPE[:ADDRESS][,key=value...]`` -> DeviceConfig.

    ``coolpro``, ``coolpro:42``, ``hub:250,channels=50,humidity_unit=1``;
    keys: ``name`` (both), ``channels`` and ``humidity_unit`` (hub).
    """
    kind, options = device_parts(spec)
    return DeviceConfig(kind, **options)


def device_parts(spec: str) -> tuple[str, dict[str, Any]]:
    """``TYPE[:ADDRESS][,key=value...]`` -> (type, the options given:
    ``address``, ``name``, ``channels``, ``humidity_unit``), checked for syntax."""
    kind, addr, opts = split_spec(spec)
    if kind not in DEVICE_TYPES:
        raise InvalidArgument(f"unknown device {spec!r}: a device is {DEVICE_SYNTAX}")
    kwargs: dict[str, Any] = {}
    if addr is not None:
        kwargs["address"] = parse_address(addr, spec)
    for key, eq, value in opts:
        if key not in DEVICE_KEYS[kind] or not eq or not value:
            what = "bad option" if key in DEVICE_KEYS[kind] else f"unknown key {key!r}"
            raise InvalidArgument(
                f"{spec!r}: {what}; {kind} takes "
                f"{', '.join(k + '=...' for k in DEVICE_KEYS[kind])}"
                + (closest(key, DEVICE_KEYS[kind]) if what != "bad option" else ""))
        if key in kwargs:
            raise InvalidArgument(f"{spec!r}: {key} given twice")
        if key == "channels":
            kwargs[key] = _integer(value, key, spec)
        elif key == "humidity_unit":
            kwargs[key] = _number(value, key, spec)
        else:
            kwargs[key] = value
    return kind, kwargs
