"""What the command desk (:mod:`pymb.logger.commands`) and its Sparkplug
half (:mod:`pymb.logger.dcmd`) share: the device a command writes
(:class:`Target`), the desk as the Sparkplug half uses it (:class:`Desk`),
and what they raise for a command refused before anything was sent."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from pymb.devices.mapdevice import MapDevice
from pymb.fleet.protobuf import MetricValue
from pymb.maps import Map
from pymb.store.commands import CommandLog

__all__ = ["Desk", "Refused", "Target", "unrecorded"]


class Refused(Exception):
    """A command (or one value of it) refused before anything was sent: its ``reason``."""

    def __init__(self, reason: str, error: str) -> None:
        super().__init__(error)
        self.reason = reason


def unrecorded(e: Exception) -> str:
    """Why a command was not executed: its record could not be read or written
    (``e``: the store's :class:`~pymb.errors.OutputError`)."""
    return f"not executed: it could not be put on record ({e}); nothing was written"


def _nothing() -> None:
    """Nothing to give back."""


@dataclass
class Target:
    """A logged map device commands may write: its map, its MapDevice (None
    while its line is not open), whether it is offline now, and what gives
    the line back to its polls once a command that got the MapDevice is
    done with it (``release``)."""

    name: str
    map: Map
    device: Callable[[], MapDevice | None]
    offline: Callable[[], bool]
    release: Callable[[], None] = _nothing


class Desk(Protocol):
    """The command desk as a Sparkplug DCMD's execution needs it
    (:class:`pymb.logger.commands.CommandDesk` is the one)."""

    log: CommandLog
    targets: dict[str, Target]
    event: Callable[[str], None]
    answer: Callable[[str, dict[str, MetricValue], list[str]], None] | None
    births: Callable[[str], dict[str, int] | None]

    def check_point(self, t: Target, name: str, value: object) -> None:
        """One value checked: a :class:`Refused` when it may not be written."""
        ...

    def check_command(self, t: Target, values: Mapping[str, object]) -> MapDevice:
        """A whole command checked: the device to write, or a :class:`Refused`."""
        ...
