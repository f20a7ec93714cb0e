"""``pymb info DB``: what a database holds, at a glance: its devices, the time
span, the samples, the faults by kind, the database and WAL sizes, and each
forwarder's backlog. Reads without writing (read-only media included)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

from pymb.commands._data import readable_database
from pymb.store import Summary, summarize

__all__ = ["add_arguments", "age_text", "iso", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb info``."""
    p.add_argument("database", help="a database written by pymb log / pymb demo")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")


def iso(t: float | None) -> str:
    """UTC seconds as ISO 8601 with milliseconds and ``Z``; "-" for none."""
    if t is None:
        return "-"
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"


def _size(n: int) -> str:
    if n < 1000:
        return f"{n} B"
    x = float(n)
    for unit in ("kB", "MB", "GB"):
        x /= 1000
        if x < 1000 or unit == "GB":
            break
    return f"{x:.1f} {unit}"


def _counts(counts: dict[str, int]) -> str:
    total = sum(counts.values())
    if not total:
        return "none"
    return f"{total:,}: " + ", ".join(f"{n:,} {k}" for k, n in
                                       sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def age_text(seconds: float) -> str:
    """A duration as a person says it: ``4.2 s``, ``3 min 10 s``, ``2 h 5 min``, ``3 d 4 h``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    s = int(seconds)
    for unit, size, sub_unit, sub_size in (("d", 86400, "h", 3600), ("h", 3600, "min", 60),
                                           ("min", 60, "s", 1)):
        if s >= size:
            return f"{s // size} {unit} {s % size // sub_size} {sub_unit}"
    return f"{s} s"  # pragma: no cover (seconds >= 60 took a branch)


def newest_age(s: Summary, now: float) -> float | None:
    """Seconds since the newest committed sample (None: no sample)."""
    return None if s.last is None else now - s.last


def _writer_line(s: Summary, now: float) -> str:
    age = newest_age(s, now)
    if age is None:
        newest = "no sample committed yet"
    elif age < -1:
        newest = f"the newest sample is {age_text(-age)} in the future (a clock step?)"
    else:
        newest = f"the newest committed sample is {age_text(max(0.0, age))} old"
    if s.writer is None:
        return f"  writer      none: no logger writes it now; {newest}"
    return (f"  writer      {s.writer} is writing it; {newest} (what it logged since "
            "shows once committed)")


def text(s: Summary, now: float | None = None) -> str:
    """The summary as lines of text (``now``: UTC seconds, for the newest sample's age)."""
    now = time.time() if now is None else now
    span = "-" if s.first is None or s.last is None else (
        f"{iso(s.first)} .. {iso(s.last)} ({s.last - s.first:,.1f} s)")
    lines = [f"{s.path}: pymb database, format {s.schema} (pymb {s.pymb_version})",
             _writer_line(s, now),
             f"  time span   {span}",
             f"  samples     {s.samples:,}",
             f"  devices     {len(s.devices)}"]
    width = max((len(d.name) for d in s.devices), default=0)
    for d in s.devices:
        what = f"{d.type}:{d.address} on {d.bus} ({d.port})"
        if d.channels:
            what += f", {d.channels} channels"
        by_group = ""
        if len(d.groups) > 1:
            by_group = " (" + ", ".join(f"{n:,} {g or 'all points'}" for g, n in d.groups) + ")"
        lines.append(f"    {d.name:<{width}}  {what}: {d.samples:,} samples{by_group}, "
                     f"{iso(d.first)} .. {iso(d.last)}")
    other = {k: n for k, n in s.events.items() if k not in s.faults}
    lines += [f"  faults      {_counts(s.faults)}",
              f"  events      {_counts(other)} (not faults)",
              f"  size        {_size(s.size)} database, {_size(s.wal)} WAL"]
    if s.writes != (0, 0):
        lines.append(f"  writes      {s.writes[0]:,} point(s) applied, {s.writes[1]:,} refused "
                     "or failed (pymb export --writes)")
    if s.backlog:
        lines += [f"  forwarder   {name}: {n:,} sample(s) not yet sent"
                  for name, n in s.backlog.items()]
    else:
        lines.append("  forwarder   none")
    return "\n".join(lines)


def as_json(s: Summary, now: float | None = None) -> dict[str, Any]:
    """The summary as JSON (times as UTC seconds and ISO 8601)."""
    now = time.time() if now is None else now
    return {
        "writer": s.writer, "newest_age_s": newest_age(s, now),
        "path": s.path, "format": s.schema, "pymb_version": s.pymb_version,
        "first": s.first, "last": s.last, "first_iso": iso(s.first) if s.first else None,
        "last_iso": iso(s.last) if s.last else None, "samples": s.samples,
        "devices": [{"name": d.name, "type": d.type, "address": d.address, "bus": d.bus,
                     "port": d.port, "channels": d.channels, "samples": d.samples,
                     "groups": dict(d.groups), "first": d.first, "last": d.last}
                    for d in s.devices],
        "faults": s.faults, "events": s.events, "size_bytes": s.size, "wal_bytes": s.wal,
        "backlog": s.backlog,
        "writes": {"applied": s.writes[0], "refused": s.writes[1]},
    }


def run(args: argparse.Namespace) -> int:
    """Print the summary."""
    with readable_database(args.database, "info") as db:
        s = summarize(db)
        if db != args.database:  # what was read of a damaged file: its own name and sizes
            wal = Path(f"{args.database}-wal")
            s = dataclasses.replace(s, path=args.database,
                                    size=os.path.getsize(args.database),
                                    wal=wal.stat().st_size if wal.exists() else 0)
    print(json.dumps(as_json(s), indent=2) if args.json else text(s))
    return 0
