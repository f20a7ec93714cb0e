"""The one device syntax every command takes, ``TYPE[:ADDRESS][,key=value...]``
(``coolpro``, ``coolpro:41``, ``hub:250,channels=50,humidity_unit=1``,
``eastron-sdm120:3``): its grammar, the address as written, and the "did you
mean" of an unknown key. What a TYPE and its keys mean is its map's
(:mod:`pymb.devices.mapspec`)."""

from __future__ import annotations

from collections.abc import Sequence

from pymb.errors import InvalidArgument, closest_hint

__all__ = ["closest", "parse_address", "split_spec"]


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
    return closest_hint(key, known) or f"; known: {', '.join(known)}"


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
