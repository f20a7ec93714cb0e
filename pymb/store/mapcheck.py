"""A map id keeps one text in a database: the samples of a map device are
stored as raw registers and decoded (by the views, ``pymb export``, the MQTT
forwarder) through the map text stored under the map's id, so a changed map
logged under the same id would change how the old samples read. Logging with
a map whose text differs from the stored one is refused before anything is
written (at the start, and for a SIGHUP reload before the reload)."""

from __future__ import annotations

import contextlib
import os
import sqlite3
from collections.abc import Mapping

from pymb.errors import InvalidArgument
from pymb.store.readonly import open_readonly

__all__ = ["changed_map_message", "check_stored_maps"]


def changed_map_message(path: str | os.PathLike[str], map_id: str) -> str:
    """The one line that refuses a changed map for ``map_id``."""
    return (f"{path}: map '{map_id}' was logged with other text; give the changed map a "
            f"new device id, or log to a new database")


def stored_map_texts(db: sqlite3.Connection) -> dict[str, str]:
    """The map texts a database holds, by map id (none in a database without maps)."""
    with contextlib.suppress(sqlite3.OperationalError):  # no maps table (yet)
        return {str(i): str(s) for i, s in db.execute("SELECT id, source FROM maps")}
    return {}


def check_stored_maps(path: str | os.PathLike[str], texts: Mapping[str, str]) -> None:
    """InvalidArgument if the database at ``path`` holds one of the map ids of
    ``texts`` (map id -> the map's text) with other text. Nothing to check if
    there is no such file, or it is not a database (what opens it says so)."""
    if not texts or not os.path.isfile(path):  # False too where the folder is not searchable
        return
    try:
        db = open_readonly(path)
        try:
            stored = stored_map_texts(db)
        finally:
            db.close()
    except sqlite3.Error:
        return  # not a database, or a damaged one: opening it for the log says so
    for map_id, text in texts.items():
        if map_id in stored and stored[map_id] != text:
            raise InvalidArgument(changed_map_message(path, map_id))
