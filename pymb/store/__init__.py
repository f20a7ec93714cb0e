"""Where logged data goes: SQLite (the default), CSV, JSON Lines, InfluxDB
line protocol.

SQLite: WAL journal, ``synchronous=FULL``, commits in batches. A
transaction that committed survives the process being killed (even SIGKILL)
and a power cut, and other connections see it only once it is on the disk;
what was not yet committed, at most one batch, is lost. Format 2 stores the
raw registers once (a BLOB of big-endian 16-bit words, as on the wire, from
the device map's first register) and decodes them in plain-SQL views that
``sqlite3`` queries directly, through the time index::

    SELECT time, device, channel, temperature_c FROM hub_readings
     WHERE channel = 3 ORDER BY time_utc DESC LIMIT 10;

Interfaces other parts of pymb rely on (keep them stable):

- :class:`SqliteSink` (``write``/``event``/``commit``/``close``), with
  ``max_bytes`` (database file plus WAL), ``max_age`` and ``on_change``.
- :func:`samples_after` ``(db, sample_id, limit)``: committed samples after
  an id, in id order, decoded (:class:`StoredSample`): the reader of a
  store-and-forward publisher.
- An ``outbox(name TEXT PRIMARY KEY, sample_id INTEGER)`` table, if a
  forwarder creates one, holds its cursors (the last sample id each sent);
  trimming past the lowest records a ``trim`` event whose code is the
  number of unsent samples deleted (and whose message names their ids).
- :func:`schema_version`; :func:`export_csv` reads formats 1 and 2.

The package, one job a module: :mod:`~pymb.store.records` (samples, events,
the sink protocol), :mod:`~pymb.store.schema` (tables and the decoding
views), :mod:`~pymb.store.onchange` (report by exception),
:mod:`~pymb.store.writer` (the SQLite writer), :mod:`~pymb.store.rows`
(what its rows hold), :mod:`~pymb.store.block` (the TCP loop's polls handed
over in blocks, and a poll's sample), :mod:`~pymb.store.retention`
(size and age limits), :mod:`~pymb.store.files` (atomic creation), :mod:`~pymb.store.guard`
(never writing into a file of another kind),
:mod:`~pymb.store.reader` (reading back), :mod:`~pymb.store.outbox` (a
forwarder's reads and cursors), :mod:`~pymb.store.handoff` (what the writer
and a forwarder beside it hand each other, as data), :mod:`~pymb.store.text` and
:mod:`~pymb.store.influx` (text formats), :mod:`~pymb.store.sinks`
(``open_sink``), :mod:`~pymb.store.export` (a database as CSV),
:mod:`~pymb.store.readonly` (reading without leaving files),
:mod:`~pymb.store.summary` (what a database holds), :mod:`~pymb.store.series`
(a quantity over time, and the lookups the data commands share).
"""

from __future__ import annotations

from pymb.errors import OutputError
from pymb.store.export import LAYOUTS, export_csv
from pymb.store.guard import check_output, is_pymb_database
from pymb.store.onchange import OnChange
from pymb.store.outbox import Outbox
from pymb.store.reader import map_point_names, samples_after
from pymb.store.readonly import open_readonly
from pymb.store.records import (
    FAULT_KINDS,
    DeviceInfo,
    Event,
    Sample,
    Sink,
    SinkBase,
    SinkWrapper,
    StoredSample,
    as_sink,
)
from pymb.store.schema import MIN_BYTES, PAGE_SIZE, SCHEMA_VERSION, schema_version
from pymb.store.series import Series, quantities, resolve_device, series
from pymb.store.sinks import FORMATS, open_sink
from pymb.store.summary import DeviceSummary, Summary, summarize
from pymb.store.text import (
    CSV_COLUMNS,
    CsvSink,
    JsonlSink,
    csv_head,
    csv_value,
    event_dict,
    sample_dict,
    sample_rows,
)
from pymb.store.writer import SqliteSink

__all__ = [
    "CSV_COLUMNS",
    "FAULT_KINDS",
    "FORMATS",
    "LAYOUTS",
    "MIN_BYTES",
    "PAGE_SIZE",
    "SCHEMA_VERSION",
    "CsvSink",
    "DeviceInfo",
    "DeviceSummary",
    "Event",
    "JsonlSink",
    "OnChange",
    "Outbox",
    "OutputError",
    "Sample",
    "Series",
    "Sink",
    "SinkBase",
    "SinkWrapper",
    "SqliteSink",
    "StoredSample",
    "Summary",
    "as_sink",
    "check_output",
    "csv_head",
    "csv_value",
    "event_dict",
    "export_csv",
    "is_pymb_database",
    "map_point_names",
    "open_readonly",
    "open_sink",
    "quantities",
    "resolve_device",
    "sample_dict",
    "sample_rows",
    "samples_after",
    "schema_version",
    "series",
    "summarize",
]
