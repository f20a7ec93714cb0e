"""What the command desk (:mod:`pymb.logger.commands`) and its Sparkplug
half (:mod:`pymb.logger.dcmd`) raise for a command refused before anything
was sent."""

from __future__ import annotations

__all__ = ["Refused"]


class Refused(Exception):
    """A command (or one value of it) refused before anything was sent: its ``reason``."""

    def __init__(self, reason: str, error: str) -> None:
        super().__init__(error)
        self.reason = reason
