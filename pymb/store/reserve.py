"""Room kept for a full disk: a file ``.NAME.reserve`` of :data:`RESERVE`
bytes beside the database. When the disk fills and a size bound
(``--max-mb``) must trim the database, the trim needs room: to copy the WAL
into the database (which grows by what the WAL holds, at most the WAL's
checkpoint size) and for its own WAL. The reserve is deleted to give it that
room, and made again once there is space.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from pymb.store.schema import WAL_MAX

__all__ = ["RESERVE", "Reserve"]

RESERVE = WAL_MAX // 2  #: bytes kept in reserve: the most the WAL holds before a checkpoint


class Reserve:
    """The reserve file of the database at ``path``."""

    def __init__(self, path: Path) -> None:
        self.path = path.with_name(f".{path.name}.reserve")

    def keep(self) -> None:
        """Make the reserve if it is missing and the disk has the room (else
        later: never an error)."""
        if self.path.exists():
            return
        tmp = self.path.with_name(self.path.name + ".new")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
            try:
                os.posix_fallocate(fd, 0, RESERVE)
            finally:
                os.close(fd)
            os.replace(tmp, self.path)
        except OSError:
            with contextlib.suppress(OSError):
                tmp.unlink()

    def give_up(self) -> bool:
        """Delete the reserve to free its room; False if there was none."""
        try:
            self.path.unlink()
        except OSError:
            return False
        return True
