"""Opening an output by format name."""

from __future__ import annotations

from pymb.errors import InvalidArgument
from pymb.store.guard import check_output
from pymb.store.influx import InfluxSink
from pymb.store.onchange import OnChange
from pymb.store.records import Sink
from pymb.store.text import CsvSink, JsonlSink
from pymb.store.writer import SqliteSink

__all__ = ["FORMATS", "open_sink"]

FORMATS = ("sqlite", "csv", "jsonl", "influx")


def open_sink(fmt: str, path: str, *, max_bytes: int | None = None,
              max_age: float | None = None, on_change: OnChange | None = None) -> Sink:
    """A sink of format ``sqlite``, ``csv``, ``jsonl`` or ``influx`` at ``path``
    (``-``: stdout)."""
    if fmt == "sqlite":
        if path == "-":
            check_output(fmt, path)  # SQLite to stdout: refused, with the message
        return SqliteSink(path, max_bytes=max_bytes, max_age=max_age, on_change=on_change)
    if on_change is not None:
        raise InvalidArgument("--on-change needs the SQLite format")
    if max_bytes is not None or max_age is not None:  # a text file is never trimmed
        raise InvalidArgument("--max-mb and --max-age-days (TOML max_mb, max_age_days) need "
                              f"the SQLite format: {fmt} output is never trimmed")
    if fmt == "csv":
        return CsvSink(path)
    if fmt == "jsonl":
        return JsonlSink(path)
    if fmt == "influx":  # InfluxDB line protocol (pymb.store.influx)
        return InfluxSink(path)
    raise InvalidArgument(f"unknown output format {fmt!r}; use one of {', '.join(FORMATS)}")
