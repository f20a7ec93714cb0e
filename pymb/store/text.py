"""The text formats: long-format CSV and JSON Lines (rows and objects of a
sample or event, and their sinks)."""

from __future__ import annotations

import contextlib
import csv
import json
import sys
import time
from collections.abc import Iterator
from typing import IO

from pymb.devices.readings import reading_dict
from pymb.errors import InvalidArgument, OutputError
from pymb.jsonvalue import JsonObject
from pymb.maps import Value
from pymb.store.faults import file_open_error
from pymb.store.records import Event, Sample, SinkBase, StoredSample, reading_values

__all__ = ["CSV_COLUMNS", "CsvSink", "JsonlSink", "csv_head", "csv_value", "event_dict",
           "sample_dict", "sample_rows"]

#: A CSV cell as the csv module takes it ("" for nothing).
Cell = str | int | float | bool | None

CSV_COLUMNS = ["time_utc", "time", "bus", "device", "type", "address", "channel", "quantity",
               "value", "state"]


def _iso(t: float) -> str:
    """Seconds since the epoch as ISO 8601 UTC with microseconds (``...Z``)."""
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"


def csv_head(t: float, bus: str, device: str | None, kind: str | None,
             address: int | None) -> list[Cell]:
    """The first columns of every CSV row (CSV_COLUMNS): time, ISO time, bus,
    device, type, address; "" for what an event has no device for. The one
    home of the row layout, for the CSV sink and for ``pymb export``."""
    return [f"{t:.6f}", _iso(t), bus, device or "", kind or "", "" if address is None else address]


def csv_value(v: Value) -> Cell:
    """A value cell: "" for no value (None or NaN); a ``raw`` point's
    registers as one cell, space-separated (``55125 5306``); a "negative
    zero" 0.0."""
    if isinstance(v, list):
        return " ".join(str(x) for x in v)
    if type(v) is float:
        return "" if v != v else v + 0.0
    return "" if v is None else v


def sample_rows(sample: Sample) -> Iterator[list[Cell]]:
    """A sample as long-format rows: one per quantity (a hub's channel by
    channel); the rows of the CSV sink and of ``pymb export``. A hub value that was not read
    (``not_read``: a channel an ``--on-change`` sample did not store) has no
    row; a "negative zero" is written 0.0."""
    d = sample.device
    head = csv_head(sample.time_utc, d.bus, d.name, d.type, d.address)
    return iter([[*head, "" if ch is None else ch, name, csv_value(v), st]
                 for ch, name, v, st in reading_values(sample.data)])


def sample_dict(sample: Sample) -> JsonObject:
    """A sample as one JSON-ready object (None for no value): the line of
    ``--format jsonl`` and, for a sample read back from the database
    (:class:`StoredSample`), with its id as ``sample``, the payload of the
    MQTT plain profile. ``values`` and the rest come from
    :func:`pymb.devices.readings.reading_dict`."""
    d = sample.device
    out: JsonObject = {"time_utc": sample.time_utc, "time": _iso(sample.time_utc),
                           "monotonic": sample.monotonic, "bus": d.bus, "device": d.name,
                           "type": d.type, "address": d.address}
    if isinstance(sample, StoredSample):
        out["sample"] = sample.id
    out.update(reading_dict(sample.data))
    return out


def event_dict(e: Event) -> JsonObject:
    """An event as a JSON-ready object."""
    return {"time_utc": e.time_utc, "time": _iso(e.time_utc), "event": e.kind, "bus": e.bus,
            "device": None if e.device is None else e.device.name, "code": e.code,
            "message": e.message}


class _TextSink(SinkBase):
    keeps_samples = False  #: see :class:`Sink`
    f: IO[str]

    def __init__(self, path: str) -> None:
        self.path = path
        self._own = path != "-"
        try:
            self.f = (open(path, "a", encoding="utf-8", newline="")  # noqa: SIM115
                      if self._own else sys.stdout)
        except IsADirectoryError:
            raise InvalidArgument(f"{path} is a directory; give a file name") from None
        except OSError as e:
            raise file_open_error(path, e) from None

    def _failed(self, e: OSError) -> Exception:
        """The error to raise for a failed write: stdout's reader going away
        (``pymb log --out - | head``) stays a BrokenPipeError, which the
        command line ends quietly with 141 as Unix tools do; anything else is
        an OutputError."""
        if isinstance(e, BrokenPipeError) and not self._own:
            return e
        return OutputError(f"cannot write to {self.path}: {e.strerror}")

    def commit(self) -> None:
        try:
            self.f.flush()
        except OSError as e:
            raise self._failed(e) from None

    def close(self) -> None:
        try:
            self.commit()
        finally:
            if self._own:
                with contextlib.suppress(OSError):
                    self.f.close()


class CsvSink(_TextSink):
    """Long-format CSV (one row per value); events as rows with quantity ``event``."""

    def __init__(self, path: str) -> None:
        super().__init__(path)
        self.w = csv.writer(self.f)
        if not self._own or self.f.tell() == 0:
            self.w.writerow(CSV_COLUMNS)

    def write(self, sample: Sample) -> None:
        try:
            self.w.writerows(sample_rows(sample))
        except OSError as e:
            raise self._failed(e) from None

    def event(self, e: Event) -> None:
        try:
            self._event(e)
        except OSError as err:
            raise self._failed(err) from None

    def _event(self, e: Event) -> None:
        d = e.device
        head = (csv_head(e.time_utc, e.bus, None, None, None) if d is None else
                csv_head(e.time_utc, e.bus, d.name, d.type, d.address))
        self.w.writerow([*head, "", f"event:{e.kind}", "" if e.code is None else e.code,
                         e.message])


class JsonlSink(_TextSink):
    """JSON Lines: one object per sample or event."""

    def write(self, sample: Sample) -> None:
        try:
            self.f.write(json.dumps(sample_dict(sample), allow_nan=False) + "\n")
        except OSError as e:
            raise self._failed(e) from None

    def event(self, e: Event) -> None:
        try:
            self.f.write(json.dumps(event_dict(e)) + "\n")
        except OSError as err:
            raise self._failed(err) from None
