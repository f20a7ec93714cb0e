"""What pymb reads out of a database, as text, for tests/store/test_release_files.py:
the export layouts, the reader's samples as JSON, the two MQTT profiles'
messages, series and the summary. The same function made the expected
outputs (tests/store/release/make.py) with the release that wrote the files."""

from __future__ import annotations

import gzip
import io
import json
import math
import sqlite3
from collections.abc import Callable
from pathlib import Path
from unittest import mock

from pymb.commands.info import text as info_text
from pymb.fleet.config import MqttConfig
from pymb.fleet.profiles import PlainProfile, SparkplugProfile
from pymb.store import StoredSample, export_csv, sample_dict, samples_after, series, summarize

DATABASES = ("every.db", "onchange.db")
_KINDS = ("long.csv", "wide.csv", "chosen.csv", "hub7.csv", "jsonl", "plain", "sparkplug",
          "series", "info")
#: every output's name (a file NAME.gz in tests/store/release/)
OUTPUTS = tuple(f"{db}.{k}" for db in DATABASES for k in _KINDS)


def _csv(db: Path, **kw: object) -> str:
    out = io.StringIO()
    rows = export_csv(str(db), out, **kw)  # type: ignore[arg-type]
    return f"{rows} rows\n{out.getvalue()}"


def messages(db: Path, reader: Callable[..., list[StoredSample]] = samples_after
             ) -> tuple[str, str]:
    """The plain and Sparkplug profiles' messages of every sample ``reader`` reads."""
    recs = reader(db, 0, limit=1_000_000)
    plain = PlainProfile(MqttConfig("mqtt://127.0.0.1", node="n"))
    spark = SparkplugProfile(MqttConfig("mqtt://127.0.0.1", profile="sparkplug", node="n"))
    p, s = [], []
    with mock.patch("pymb.fleet.profiles.time.time", return_value=1_900_000_000.0):
        for r in recs:
            for m in plain.data(r, False):
                p.append(f"{m.topic} {m.qos} {m.retain} {m.payload.decode()}")
            for m in spark.data(r, r.id % 3 == 0):
                s.append(f"{m.topic} {m.qos} {m.retain} {m.payload.hex()}")
    return "\n".join(p) + "\n", "\n".join(s) + "\n"


def _series(db: Path) -> str:
    out = []
    for device, quantity, channel in (("hub-7", "humidity_pct", 2), ("hub-7", "temperature_c", 6),
                                      ("big-hub", "pressure_kpa", 100),
                                      ("coolpro-40", "input_voltage_v", None),
                                      ("coolpro-40", "uptime_s", None)):
        s = series(db, device, quantity, channel=channel)
        vals = ["nan" if math.isnan(v) else repr(v) for v in s.values]
        out.append(f"{s.device} {s.type} {s.quantity} {s.channel} {s.unit!r} "
                   f"{[repr(t) for t in s.times]} {vals}")
    return "\n".join(out) + "\n"


def _info(db: Path) -> str:
    s = summarize(db)
    lines = info_text(s, now=1_900_000_000.0).splitlines()
    keep = [ln for ln in lines if ln.startswith(("    ", "  samples", "  devices", "  faults",
                                                  "  events", "  time span"))]
    return "\n".join(keep) + "\n"


def outputs(folder: Path) -> dict[str, str]:
    """Every output of the databases in ``folder``, by name."""
    got: dict[str, str] = {}
    for name in DATABASES:
        db = folder / name
        got[f"{name}.long.csv"] = _csv(db, events=True)
        got[f"{name}.wide.csv"] = _csv(db, layout="wide")
        got[f"{name}.chosen.csv"] = _csv(db, channels=[2, 5], quantities=[
            "humidity_pct", "temperature2_c", "output_current_a", "status"])
        got[f"{name}.hub7.csv"] = _csv(db, device="hub-7", layout="wide", channels=[1, 6])
        got[f"{name}.jsonl"] = "".join(
            json.dumps(sample_dict(s), allow_nan=False) + "\n"
            for s in samples_after(db, 0, limit=1_000_000))
        got[f"{name}.plain"], got[f"{name}.sparkplug"] = messages(db)
        got[f"{name}.series"] = _series(db)
        got[f"{name}.info"] = _info(db)
    return got

# -- the databases as the text kept in git (NAME.sql.gz) and back: the settings a dump
# leaves out (page size, auto_vacuum, the journal mode) first, then SQLite's own dump

_SETTINGS = ("page_size", "auto_vacuum", "journal_mode")


def dump(db: Path, to: Path) -> None:
    """Write ``db`` as gzipped SQL text to ``to``."""
    con = sqlite3.connect(db)
    try:
        head = [f"PRAGMA {k} = {con.execute(f'PRAGMA {k}').fetchone()[0]};" for k in _SETTINGS]
        text = "\n".join([*head, *con.iterdump()]) + "\n"
    finally:
        con.close()
    to.write_bytes(gzip.compress(text.encode(), mtime=0))


def restore(sql_gz: Path, db: Path) -> None:
    """Make the database ``db`` from the gzipped SQL text ``sql_gz``."""
    text = gzip.decompress(sql_gz.read_bytes()).decode()
    con = sqlite3.connect(db, isolation_level=None)
    try:
        con.executescript(text)
    finally:
        con.close()
