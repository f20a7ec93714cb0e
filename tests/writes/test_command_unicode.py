"""A command whose id or point name holds what UTF-8 cannot carry (a lone
surrogate, which JSON's \\uD800 escape can say) is answered with a result of
reason ``invalid``, as any malformed command, never left unanswered."""

from __future__ import annotations

import json
import sqlite3

from pymb import maps
from pymb.logger.commands import CommandDesk
from pymb.logger.refusal import Target
from pymb.store.commands import CommandLog


def _desk() -> CommandDesk:
    db = sqlite3.connect(":memory:", isolation_level=None)
    log = CommandLog(lambda f, durable: f(db))
    dev = Target("dev", maps.builtin("coolpro"), lambda: None, lambda: True)
    return CommandDesk(log, {"dev": dev}, ["dev/*"], lambda text: None)


def test_an_id_with_a_lone_surrogate_gets_an_invalid_result() -> None:
    out = _desk().run_command("mqtt", "dev", b'{"id": "\\ud800x", "values": {"a": 1}}')
    assert out is not None
    doc = json.loads(out)
    assert doc["id"] == "\ud800x"  # the id as sent, so the sender can match it
    assert (doc["ok"], doc["reason"]) == (False, "invalid")
    assert "printable" in doc["error"]


def test_a_point_name_with_a_lone_surrogate_gets_an_invalid_result() -> None:
    desk = _desk()
    out = desk.run_command("mqtt", "dev", b'{"id": "c-1", "values": {"\\udc00": 1}}')
    assert out is not None
    doc = json.loads(out)
    assert (doc["id"], doc["ok"], doc["reason"]) == ("c-1", False, "invalid")
