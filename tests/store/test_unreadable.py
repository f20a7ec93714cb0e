"""A file that is no SQLite database, handed to the readers (``export_csv``,
``summarize``, ``series``): one InvalidArgument naming the file and what
SQLite said, never an ``sqlite3`` error."""

from __future__ import annotations

import io
from collections.abc import Callable
from pathlib import Path

import pytest

from pymb import InvalidArgument
from pymb.store import export_csv, series, summarize

READERS: dict[str, Callable[[Path], object]] = {
    "export_csv": lambda p: export_csv(str(p), io.StringIO()),
    "summarize": summarize,
    "series": lambda p: series(p, "hub", "temperature"),
}


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_file_that_is_no_database_is_said_in_one_line(tmp_path: Path, reader: str) -> None:
    junk = tmp_path / "junk.db"
    junk.write_bytes(bytes(range(256)) * 16)  # no SQLite header
    with pytest.raises(InvalidArgument) as got:
        READERS[reader](junk)
    assert str(got.value) == f"{junk} is not a readable pymb database: file is not a database"
