"""Two different DCMDs for one device with the same payload timestamp and no
seq (a host's commands sent within one millisecond; Sparkplug puts no seq on
commands) are two commands: the second is executed (here: refused, its device
offline) and recorded on its own, not taken for the first delivered again.
The same DCMD delivered again is still answered from the record."""

from __future__ import annotations

import sqlite3
from typing import Any

from mqtt_broker import sparkplug_pb  # noqa: F401 (fixture)

from pymb import maps
from pymb.logger.commands import CommandDesk
from pymb.logger.refusal import Target
from pymb.store.commands import CommandLog

INVERTER = """
schema = "pymb.map/1"
[device]
id = "inv"
table = "holding"
[[point]]
name = "power_limit_pct"
address = 100
type = "u16"
access = "rw"
valid = [0, 100]
"""


def test_two_dcmds_in_one_millisecond_are_two_commands(sparkplug_pb: Any) -> None:  # noqa: F811
    db = sqlite3.connect(":memory:", isolation_level=None)
    events: list[str] = []
    target = Target("inv", maps.loads(INVERTER), lambda: None, lambda: True)
    desk = CommandDesk(CommandLog(lambda f, durable: f(db)), {"inv": target}, ["inv/*"],
                       events.append)
    desk.births = lambda device: {"power_limit_pct": 1}

    def dcmd(value: int) -> bytes:
        p = sparkplug_pb()
        p.timestamp = 1796299201234
        m = p.metrics.add()
        m.name, m.datatype, m.int_value = "power_limit_pct", 6, value
        return bytes(p.SerializeToString())

    for payload in (dcmd(10), dcmd(20), dcmd(20)):
        desk.handle("sparkplug", "inv", payload)
    again = [e for e in events if "was received before" in e]
    assert len(again) == 1, events  # the third only: the second is a command of its own
    requested = [r[0] for r in db.execute(
        "SELECT requested FROM writes WHERE point = 'power_limit_pct' ORDER BY rowid")]
    assert [str(v) for v in requested] == ["10", "20"], requested
