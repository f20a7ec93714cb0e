"""``pymb export FILE.sqlite --csv OUT``: get logged data back out.

Never destroys anything: the CSV is written to a temporary file beside OUT
and renamed over it only when complete; OUT may not be the database itself;
an existing OUT that is not a CSV written by pymb is kept unless ``--force``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sqlite3
import sys
import tempfile
from datetime import UTC, datetime

from pymb.devices.spec import device_parts
from pymb.errors import InvalidArgument
from pymb.store import CSV_COLUMNS, export_csv, is_pymb_database
from pymb.store.readonly import open_readonly


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``pymb export``."""
    p.add_argument("database", help="a database written by pymb log / pymb demo")
    p.add_argument("--csv", required=True, metavar="OUT",
                   help="write long-format CSV here ('-' for stdout)")
    p.add_argument("--device", metavar="DEVICE",
                   help="only this device: TYPE[:ADDRESS] as logged (e.g. hub:250) or its "
                        "name (e.g. hub-250)")
    p.add_argument("--since", help="only data from this UTC time on (ISO 8601)")
    p.add_argument("--events", action="store_true", help="include the events (faults etc.)")
    p.add_argument("--force", action="store_true",
                   help="overwrite OUT even if it is not a CSV written by pymb")


def _check_database(path: str) -> None:
    if os.path.isdir(path):
        raise InvalidArgument(f"{path} is a directory, not a database")
    if not os.path.exists(path):
        raise InvalidArgument(f"no such database: {path}")
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as e:
        raise InvalidArgument(f"cannot read {path}: {e.strerror}") from None
    if head != b"SQLite format 3\x00" or not is_pymb_database(path):
        raise InvalidArgument(f"{path} is not a database written by pymb")


def _devices(path: str) -> list[tuple[str, str, int, str]]:
    """(name, type, address, bus) of every device in the database."""
    db = open_readonly(path)
    try:
        return [(str(n), str(t), int(a), str(b)) for n, t, a, b in db.execute(
            "SELECT name, type, address, bus FROM devices ORDER BY id")]
    except sqlite3.Error as e:
        raise InvalidArgument(f"{path} is not a readable pymb database: {e}") from None
    finally:
        db.close()


def resolve_device(path: str, wanted: str) -> str:
    """The name of the device ``wanted`` (a name or TYPE[:ADDRESS]) in the
    database; an error listing the devices there if it is not one of them."""
    devices = _devices(path)
    names = [d[0] for d in devices]
    if wanted in names:
        return wanted
    matches: list[str] = []
    try:
        kind, options = device_parts(wanted)
    except InvalidArgument:
        kind, options = "", {}
    if kind:
        address = options.get("address")
        matches = [n for n, t, a, _ in devices
                   if t == kind and (address is None or a == address)]
    if len(matches) == 1:
        return matches[0]
    listing = ", ".join(f"{n} ({t}:{a} on {b})" for n, t, a, b in devices) or "none"
    if len(matches) > 1:
        raise InvalidArgument(f"--device {wanted!r} matches several devices in {path}: "
                              f"{', '.join(matches)}; give one of those names")
    raise InvalidArgument(f"no device {wanted!r} in {path}; it has: {listing}")


def _is_pymb_csv(path: str) -> bool:
    try:
        with open(path, encoding="utf-8", newline="") as f:
            first = f.readline().rstrip("\r\n")
    except (OSError, UnicodeDecodeError):
        return False
    return first == ",".join(CSV_COLUMNS)


def run(args: argparse.Namespace) -> int:
    """Export; prints how many rows went out."""
    since = None
    if args.since is not None:  # '' is no time either: an error, never "no filter"
        try:
            t = datetime.fromisoformat(args.since.replace("Z", "+00:00"))
        except ValueError:
            raise InvalidArgument(f"--since needs an ISO 8601 time, got {args.since!r}") from None
        if t.tzinfo is None:
            t = t.replace(tzinfo=UTC)
        since = t.timestamp()
    _check_database(args.database)
    device = resolve_device(args.database, args.device) if args.device is not None else None
    if args.csv == "-":
        export_csv(args.database, sys.stdout, device=device, since=since, events=args.events)
        return 0
    out = args.csv
    if os.path.isdir(out):
        raise InvalidArgument(f"--csv {out} is a directory; give a file name")
    if os.path.exists(out):
        if os.path.samefile(out, args.database):
            raise InvalidArgument(f"--csv {out} is the database being exported: refusing to "
                                  "write onto it")
        if os.path.isfile(out) and os.path.getsize(out) and not _is_pymb_csv(out) \
                and not args.force:
            raise InvalidArgument(f"{out} exists and is not a CSV written by pymb: refusing "
                                  "to overwrite it (--force to do it anyway)")
    if os.path.exists(out) and not os.path.isfile(out):
        # A FIFO, a device: write to it directly.
        try:
            with open(out, "w", encoding="utf-8", newline="") as f:
                rows = export_csv(args.database, f, device=device, since=since,
                                  events=args.events)
        except OSError as e:
            raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    else:
        rows = _export_atomically(args, out, device, since)
    print(f"exported {rows:,} rows to {out}", file=sys.stderr)
    return 0


def _export_atomically(args: argparse.Namespace, out: str, device: str | None,
                       since: float | None) -> int:
    """Write a temporary file beside ``out``, rename it over ``out`` when done."""
    folder = os.path.dirname(os.path.abspath(out))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".pymb-export-", suffix=".csv.tmp", dir=folder)
    except OSError as e:
        raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    def terminated(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)  # as a kill would, but the temporary file goes

    old = {s: signal.signal(s, terminated) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            rows = export_csv(args.database, f, device=device, since=since, events=args.events)
        if os.path.exists(out):
            with contextlib.suppress(OSError):
                os.chmod(tmp, os.stat(out).st_mode & 0o7777)
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, out)
    except OSError as e:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise InvalidArgument(f"cannot write {out}: {e.strerror}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    return rows
